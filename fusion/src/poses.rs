//! The robot's pose at a reading's instant, from the stream on `robot/pose`.
//!
//! A reading is taken while the robot moves; fusing it at whatever pose arrived last places it up
//! to one pose period (and any delay of the pose stream) off. So the engine keeps the recent poses
//! and places each reading at the pose **interpolated at the reading's `host_stamp_ns`**.
//!
//! # Clocks
//!
//! Both stamps are the host's wall clock in ns since the Unix epoch: the driver stamps a reading
//! with the instant of its last ping (the head's clock mapped onto the host's, not the line's
//! arrival, which a loaded machine delays by up to a second), the pose's publisher stamps the
//! instant the pose describes. On one machine they are one clock; a pose source on another machine
//! must be synchronised to it (NTP/PTP) — an offset shows as readings placed where the robot was
//! that much earlier or later.
//!
//! # Policy
//!
//! - **Between two poses**: linear in position, along the shorter arc in heading.
//! - **Newer than the newest pose**: while a pose stream exists ([`PoseTrack::awaits`]), the
//!   fusion process holds the reading (and the readings after it) until a pose at or after its
//!   stamp arrives, for at most [`MAX_POSE_WAIT`]: the pose covering a reading is usually published
//!   a few ms after it, and a replay's burst may deliver many readings before their poses are
//!   taken. So a reading is interpolated whatever the delivery's timing, and a replay places it
//!   where the live run did. Without any pose (a fixed head) readings never wait.
//! - **After the latest pose** once the wait is over (the pose stream lags or stopped): extrapolated at the last two poses'
//!   velocity for at most [`MAX_EXTRAPOLATION_NS`], then held. A reading more than
//!   [`STALE_AFTER_NS`] after the latest pose is placed there too, and counted as fused with a
//!   *stale* pose: the pose source stopped or is late.
//! - **Before the oldest pose kept** (a late reading): the oldest pose.
//! - **No pose ever**: the pose the engine started with (the origin, or the restored map's).
//! - A pose older than the newest kept is out of order and refused; a pose *jump* (a
//!   localisation's correction) is taken as it comes: readings after it are placed from it,
//!   readings between the two stamps are interpolated across it.
//! - **Every pose a reading still to come may need is kept**: readings arrive in stamp order, so
//!   once a reading is placed ([`PoseTrack::placed`]) only the poses before the last one at or
//!   before its stamp can go. Trimming by the newest pose's age instead let a fusion that lagged
//!   behind its readings (a loaded machine) drop the poses of the readings still in its buffer and
//!   place them at the oldest pose kept: a live run and its replay then differed by where the lag
//!   fell. Memory stays bounded by [`KEPT_POSES`]; a reading older than every pose kept is placed
//!   at the oldest and counted ([`PoseKind::Early`]).
//! - Before any reading is placed, the poses within [`KEPT_NS`] of the newest are kept.
//! - **Lost poses** are estimated, since `Pose2D` has no sequence number: the stream's period is
//!   learnt from its intervals, and an interval longer than [`GAP_FACTOR`] periods counts as a
//!   gap with that many periods less one missing ([`PoseTrack::gaps`]). It assumes a source that
//!   publishes at a steady rate, as odometry does; readings in a gap are interpolated across it.

use std::collections::VecDeque;

use nalgebra::{Isometry2, Vector2};
use sonar_common::ipc::Pose2D;

use crate::geometry::wrap_angle;

/// Longest time a pose is carried forward at the robot's last velocity.
pub const MAX_EXTRAPOLATION_NS: u64 = 100_000_000;
/// A reading this long after the latest pose is placed with a stale pose.
pub const STALE_AFTER_NS: u64 = 500_000_000;
/// Longest a reading newer than the newest pose waits for the pose that covers its instant,
/// after which it is placed as today (extrapolated, or stale). Wall clock: long enough for a pose
/// source descheduled on a loaded machine, short enough that a stopped stream costs little (a
/// reading more than [`STALE_AFTER_NS`] past the newest pose does not wait at all).
pub const MAX_POSE_WAIT: std::time::Duration = std::time::Duration::from_millis(500);
/// Most poses kept: 20 s of a replay at ×40 (800 poses a second), 512 KiB.
pub const KEPT_POSES: usize = 16_384;
/// Before any reading is placed, poses older than this before the newest are dropped.
pub const KEPT_NS: u64 = 5_000_000_000;

/// An interval this many times the stream's period is a gap (poses lost or not sent).
pub const GAP_FACTOR: f64 = 2.5;

/// Gaps in the pose stream: poses lost in transit or never sent.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PoseGaps {
    /// Intervals longer than [`GAP_FACTOR`] periods.
    pub gaps: u64,
    /// Poses missing in them, estimated from the period.
    pub missing: u64,
}

/// Where a reading was placed, and how the pose for it was found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlacedPose {
    pub pose: Isometry2<f32>,
    pub kind: PoseKind,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseKind {
    /// No pose has arrived: the engine's initial pose.
    Initial,
    /// Interpolated between two poses, or exactly one.
    Interpolated,
    /// Past the latest pose, within [`STALE_AFTER_NS`].
    Extrapolated,
    /// Past the latest pose by more than [`STALE_AFTER_NS`].
    Stale,
    /// Before the oldest pose kept.
    Early,
}

/// A refused pose.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum PoseError {
    #[error("pose is not finite")]
    NotFinite,
    #[error("pose stamped {stamp_ns} ns is older than the latest ({latest_ns} ns)")]
    OutOfOrder { stamp_ns: u64, latest_ns: u64 },
}

/// The recent poses.
#[derive(Debug, Clone)]
pub struct PoseTrack {
    initial: Isometry2<f32>,
    poses: VecDeque<Pose2D>,
    /// The stream's usual interval, ns: a running mean of the intervals that are not gaps.
    period_ns: Option<f64>,
    gaps: PoseGaps,
    /// The stamp of the newest reading placed: the poses before it are no longer needed.
    placed_up_to: Option<u64>,
}

impl PoseTrack {
    /// A track that places readings at `initial` until a pose arrives.
    pub fn new(initial: Isometry2<f32>) -> Self {
        Self {
            initial,
            poses: VecDeque::new(),
            period_ns: None,
            gaps: PoseGaps::default(),
            placed_up_to: None,
        }
    }

    /// Gaps in the stream so far.
    pub fn gaps(&self) -> PoseGaps {
        self.gaps
    }

    /// Learns the period from the interval to the previous pose, or counts a gap.
    fn note_interval(&mut self, interval_ns: u64) {
        if interval_ns == 0 {
            return;
        }
        let interval = interval_ns as f64;
        match self.period_ns {
            None => self.period_ns = Some(interval),
            Some(period) if interval > GAP_FACTOR * period => {
                self.gaps.gaps += 1;
                self.gaps.missing += ((interval / period).round() as u64).saturating_sub(1);
            }
            Some(period) => self.period_ns = Some(0.9 * period + 0.1 * interval),
        }
    }

    /// The newest pose received, else the initial one.
    pub fn latest(&self) -> Isometry2<f32> {
        self.poses.back().map_or(self.initial, isometry)
    }

    /// Whether a pose at or after `stamp_ns` is still to come: there are poses and the newest is
    /// older. Without any pose (a fixed head, no pose stream) nothing is awaited.
    /// A reading more than [`STALE_AFTER_NS`] past the newest pose awaits nothing: the stream
    /// stopped, and waiting would only slow every reading down.
    pub fn awaits(&self, stamp_ns: u64) -> bool {
        self.poses
            .back()
            .is_some_and(|p| p.stamp_ns < stamp_ns && stamp_ns - p.stamp_ns <= STALE_AFTER_NS)
    }

    /// Notes that a reading stamped `stamp_ns` was placed: the poses only older readings need go.
    pub fn placed(&mut self, stamp_ns: u64) {
        self.placed_up_to = Some(self.placed_up_to.map_or(stamp_ns, |p| p.max(stamp_ns)));
        self.trim();
    }

    /// Drops the poses no reading to come needs, and any beyond [`KEPT_POSES`].
    fn trim(&mut self) {
        let Some(newest) = self.poses.back().map(|p| p.stamp_ns) else {
            return;
        };
        // A pose can go when the one after it is at or before every reading still to come.
        let needed_from = self
            .placed_up_to
            .unwrap_or_else(|| newest.saturating_sub(KEPT_NS));
        while self.poses.len() > 2
            && (self.poses.len() > KEPT_POSES || self.poses[1].stamp_ns <= needed_from)
        {
            self.poses.pop_front();
        }
    }

    /// Adds a pose; refuses a non-finite one or one older than the newest kept.
    pub fn push(&mut self, pose: Pose2D) -> Result<(), PoseError> {
        if !(pose.x_m.is_finite() && pose.y_m.is_finite() && pose.theta_rad.is_finite()) {
            return Err(PoseError::NotFinite);
        }
        if let Some(last) = self.poses.back()
            && pose.stamp_ns < last.stamp_ns
        {
            return Err(PoseError::OutOfOrder {
                stamp_ns: pose.stamp_ns,
                latest_ns: last.stamp_ns,
            });
        }
        if let Some(last) = self.poses.back() {
            self.note_interval(pose.stamp_ns - last.stamp_ns);
        }
        self.poses.push_back(pose);
        self.trim();
        Ok(())
    }

    /// The pose at `stamp_ns`, by the policy of the module docs.
    pub fn at(&self, stamp_ns: u64) -> PlacedPose {
        let placed = |pose, kind| PlacedPose { pose, kind };
        let (Some(first), Some(last)) = (self.poses.front(), self.poses.back()) else {
            return placed(self.initial, PoseKind::Initial);
        };
        if stamp_ns < first.stamp_ns {
            return placed(isometry(first), PoseKind::Early);
        }
        if stamp_ns == last.stamp_ns {
            return placed(isometry(last), PoseKind::Interpolated);
        }
        if stamp_ns > last.stamp_ns {
            let late = stamp_ns - last.stamp_ns;
            if late > STALE_AFTER_NS {
                return placed(isometry(last), PoseKind::Stale);
            }
            let pose = match self.poses.len() {
                1 => isometry(last),
                n => {
                    let before = &self.poses[n - 2];
                    let ahead = late.min(MAX_EXTRAPOLATION_NS);
                    interpolate(before, last, last.stamp_ns + ahead)
                }
            };
            return placed(pose, PoseKind::Extrapolated);
        }
        // The first pose stamped after `stamp_ns` (there is one, and one before it): of poses
        // with equal stamps, the latest counts.
        let i = self.poses.partition_point(|p| p.stamp_ns <= stamp_ns);
        let pose = interpolate(&self.poses[i - 1], &self.poses[i], stamp_ns);
        placed(pose, PoseKind::Interpolated)
    }
}

fn isometry(p: &Pose2D) -> Isometry2<f32> {
    Isometry2::new(Vector2::new(p.x_m, p.y_m), p.theta_rad)
}

/// The pose at `stamp_ns` on the straight line through `a` and `b` (beyond `b` too), the heading
/// turning the shorter way.
fn interpolate(a: &Pose2D, b: &Pose2D, stamp_ns: u64) -> Isometry2<f32> {
    let span = b.stamp_ns.saturating_sub(a.stamp_ns);
    if span == 0 {
        return isometry(b);
    }
    let s = (stamp_ns as f64 - a.stamp_ns as f64) / span as f64;
    let s = s as f32;
    let turn = wrap_angle(b.theta_rad - a.theta_rad);
    Isometry2::new(
        Vector2::new(a.x_m + s * (b.x_m - a.x_m), a.y_m + s * (b.y_m - a.y_m)),
        a.theta_rad + s * turn,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::PI;

    const MS: u64 = 1_000_000;

    fn pose(stamp_ms: u64, x: f32, y: f32, theta: f32) -> Pose2D {
        Pose2D {
            stamp_ns: stamp_ms * MS,
            x_m: x,
            y_m: y,
            theta_rad: theta,
            layout_version: 1,
        }
    }

    fn close(a: Isometry2<f32>, x: f32, y: f32, theta: f32) -> bool {
        (a.translation.x - x).abs() < 1e-4
            && (a.translation.y - y).abs() < 1e-4
            && wrap_angle(a.rotation.angle() - theta).abs() < 1e-4
    }

    #[test]
    fn gaps_in_a_steady_stream_are_counted_with_the_poses_missing() {
        let mut track = PoseTrack::new(Isometry2::identity());
        // 20 Hz with a little jitter: no gap.
        for k in 0..40u64 {
            let jitter = [0, 3, 0, 2][k as usize % 4];
            track.push(pose(50 * k + jitter, 0.0, 0.0, 0.0)).unwrap();
        }
        assert_eq!(track.gaps(), PoseGaps::default());
        // Two poses lost (150 ms), then seven (400 ms).
        track.push(pose(50 * 39 + 150, 0.0, 0.0, 0.0)).unwrap();
        track.push(pose(50 * 39 + 550, 0.0, 0.0, 0.0)).unwrap();
        assert_eq!(
            track.gaps(),
            PoseGaps {
                gaps: 2,
                missing: 9
            }
        );
        // Two poses of one instant (a replay's burst may stamp alike) are no gap.
        track.push(pose(50 * 39 + 550, 0.0, 0.0, 0.0)).unwrap();
        assert_eq!(track.gaps().gaps, 2);
    }

    #[test]
    fn without_poses_readings_stay_at_the_initial_pose() {
        let start = Isometry2::new(Vector2::new(1.0, 2.0), 0.5);
        let track = PoseTrack::new(start);
        assert_eq!(track.at(123).kind, PoseKind::Initial);
        assert_eq!(track.at(123).pose, start);
        assert_eq!(track.latest(), start);
    }

    #[test]
    fn a_reading_between_two_poses_is_interpolated() {
        let mut track = PoseTrack::new(Isometry2::identity());
        track.push(pose(1000, 0.0, 0.0, 0.0)).unwrap();
        track.push(pose(1100, 0.2, -0.1, 0.4)).unwrap();
        let at = track.at(1025 * MS);
        assert_eq!(at.kind, PoseKind::Interpolated);
        assert!(close(at.pose, 0.05, -0.025, 0.1), "{at:?}");
        assert!(close(track.at(1100 * MS).pose, 0.2, -0.1, 0.4));
        assert!(close(track.at(1000 * MS).pose, 0.0, 0.0, 0.0));
    }

    #[test]
    fn the_heading_turns_the_shorter_way_across_pi() {
        let mut track = PoseTrack::new(Isometry2::identity());
        track.push(pose(0, 0.0, 0.0, PI - 0.1)).unwrap();
        track.push(pose(100, 0.0, 0.0, -PI + 0.1)).unwrap();
        // Half-way is at ±π, not at 0.
        let mid = track.at(50 * MS).pose.rotation.angle();
        assert!((mid.abs() - PI).abs() < 1e-4, "{mid}");
    }

    #[test]
    fn of_poses_with_one_stamp_the_latest_counts() {
        let mut track = PoseTrack::new(Isometry2::identity());
        track.push(pose(0, 0.0, 0.0, 0.0)).unwrap();
        track.push(pose(0, 1.0, 0.0, 0.0)).unwrap();
        assert!(close(track.at(0).pose, 1.0, 0.0, 0.0));
        track.push(pose(100, 2.0, 0.0, 0.0)).unwrap();
        assert!(close(track.at(0).pose, 1.0, 0.0, 0.0));
        assert!(close(track.at(50 * MS).pose, 1.5, 0.0, 0.0));
    }

    #[test]
    fn a_late_pose_stream_is_extrapolated_for_a_bounded_time_then_stale() {
        let mut track = PoseTrack::new(Isometry2::identity());
        track.push(pose(0, 0.0, 0.0, 0.0)).unwrap();
        track.push(pose(100, 0.1, 0.0, 0.0)).unwrap(); // 1 m/s along x
        let soon = track.at(150 * MS);
        assert_eq!(soon.kind, PoseKind::Extrapolated);
        assert!(close(soon.pose, 0.15, 0.0, 0.0), "{soon:?}");
        // Carried forward at most 100 ms.
        let later = track.at(400 * MS);
        assert_eq!(later.kind, PoseKind::Extrapolated);
        assert!(close(later.pose, 0.2, 0.0, 0.0), "{later:?}");
        let stale = track.at(700 * MS);
        assert_eq!(stale.kind, PoseKind::Stale);
        assert!(
            close(stale.pose, 0.1, 0.0, 0.0),
            "held at the latest: {stale:?}"
        );
    }

    #[test]
    fn a_reading_awaits_a_pose_at_or_after_it_only_when_poses_come() {
        let mut track = PoseTrack::new(Isometry2::identity());
        // A fixed head: no pose stream, nothing to wait for.
        assert!(!track.awaits(5 * MS));
        track.push(pose(100, 0.0, 0.0, 0.0)).unwrap();
        assert!(track.awaits(101 * MS));
        assert!(!track.awaits(100 * MS));
        assert!(!track.awaits(50 * MS));
        track.push(pose(150, 0.1, 0.0, 0.0)).unwrap();
        assert!(!track.awaits(101 * MS));
        assert_eq!(track.at(101 * MS).kind, PoseKind::Interpolated);
    }

    #[test]
    fn one_pose_is_held_and_early_readings_take_the_oldest() {
        let mut track = PoseTrack::new(Isometry2::identity());
        track.push(pose(1000, 1.0, 1.0, 1.0)).unwrap();
        let after = track.at(1050 * MS);
        assert_eq!(after.kind, PoseKind::Extrapolated);
        assert!(close(after.pose, 1.0, 1.0, 1.0));
        let early = track.at(900 * MS);
        assert_eq!(early.kind, PoseKind::Early);
        assert!(close(early.pose, 1.0, 1.0, 1.0));
    }

    #[test]
    fn bad_and_out_of_order_poses_are_refused() {
        let mut track = PoseTrack::new(Isometry2::identity());
        track.push(pose(100, 0.0, 0.0, 0.0)).unwrap();
        assert_eq!(
            track.push(pose(50, 1.0, 0.0, 0.0)),
            Err(PoseError::OutOfOrder {
                stamp_ns: 50 * MS,
                latest_ns: 100 * MS
            })
        );
        assert_eq!(
            track.push(pose(200, f32::NAN, 0.0, 0.0)),
            Err(PoseError::NotFinite)
        );
        assert!(close(track.latest(), 0.0, 0.0, 0.0));
    }

    #[test]
    fn memory_is_bounded_in_count_and_time() {
        let mut track = PoseTrack::new(Isometry2::identity());
        // A reading placed at the start keeps every pose after it, up to the cap.
        track.placed(0);
        for k in 0..(KEPT_POSES as u64 + 2000) {
            track.push(pose(k, k as f32, 0.0, 0.0)).unwrap();
        }
        assert_eq!(track.poses.len(), KEPT_POSES);
        let mut sparse = PoseTrack::new(Isometry2::identity());
        for k in 0..20 {
            sparse.push(pose(k * 1000, k as f32, 0.0, 0.0)).unwrap();
        }
        // No reading placed yet: 5 s kept, the poses of 14 s … 19 s.
        assert_eq!(sparse.poses.len(), 6);
        assert_eq!(sparse.at(0).kind, PoseKind::Early);
    }

    /// A fusion that lags behind its readings (a loaded machine) still holds the poses of the
    /// readings in its buffer, however many newer poses it takes meanwhile: where a reading lands
    /// does not depend on how far behind the fusion runs.
    #[test]
    fn poses_are_kept_for_the_readings_still_to_place() {
        let stream: Vec<Pose2D> = (0..4000u64)
            .map(|k| pose(k, 0.001 * k as f32, 0.0, 0.0))
            .collect();
        let readings: Vec<u64> = (0..400u64).map(|k| (10 * k + 3) * MS / 2).collect();
        let place_all = |lag: usize| {
            let mut track = PoseTrack::new(Isometry2::identity());
            let mut placed = Vec::new();
            let mut next_pose = 0;
            for &stamp in &readings {
                // The poses taken before this reading run `lag` poses ahead of its stamp.
                while next_pose < stream.len()
                    && stream[next_pose].stamp_ns <= stamp + lag as u64 * MS
                {
                    track.push(stream[next_pose]).unwrap();
                    next_pose += 1;
                }
                let at = track.at(stamp);
                track.placed(stamp);
                placed.push((at.pose.translation.x, at.kind));
            }
            placed
        };
        let prompt = place_all(1);
        assert!(prompt.iter().all(|(_, k)| *k == PoseKind::Interpolated));
        // 3 s behind: 3000 poses taken ahead of the reading, far more than the old cap of 512.
        assert_eq!(place_all(3000), prompt);
        // Poses before the latest reading's are dropped as readings are placed.
        let mut track = PoseTrack::new(Isometry2::identity());
        for p in &stream[..100] {
            track.push(*p).unwrap();
        }
        track.placed(50 * MS + MS / 2);
        assert_eq!(track.poses.front().map(|p| p.stamp_ns), Some(50 * MS));
    }

    #[test]
    fn a_stopped_pose_stream_is_not_waited_for() {
        let mut track = PoseTrack::new(Isometry2::identity());
        assert!(!track.awaits(MS));
        track.push(pose(1000, 0.0, 0.0, 0.0)).unwrap();
        assert!(track.awaits(1001 * MS));
        assert!(!track.awaits(1000 * MS));
        assert!(!track.awaits(1000 * MS + STALE_AFTER_NS + 1));
    }
}
