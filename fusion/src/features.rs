//! The feature map next to the grid: readings grouped by sweep, each finished sweep handed to
//! [`sonar_features::FeatureMap`], the result flattened into the records of `sonar/features`.
//!
//! A sweep ends when a reading of the next one arrives ([`FeatureTracker::push`]) or when the
//! process has heard nothing for a while and asks for it ([`FeatureTracker::finish_sweep`]): a
//! stopped scan's last sweep still counts. Each sweep is placed at the robot's pose of its first
//! reading: the regions of constant depth need the pings of one place, and a head that scans
//! while the robot drives would need each ping's own pose (the motion issue).

use nalgebra::{Isometry2, Point2, Vector2};
use sonar_common::ipc::Reading;
use sonar_common::ipc::{
    FeatureRecord, FeaturesHeader, LAYOUT_VERSION, MAX_FEATURES, feature_kind,
};
use sonar_features::{FeatureConfig, FeatureError, FeatureKind, FeatureMap, FeatureSummary, Sweep};

use crate::grid::OccupancyGrid;

/// Occupancy probability from which a grid cell lends its position to a wall's segment.
const SUPPORT_PROBABILITY: f32 = 0.8;

/// What one finished sweep did to the feature map.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SweepOutcome {
    pub sweep_id: u32,
    pub readings: usize,
    pub rcds: usize,
    pub refined: usize,
    pub added: usize,
    pub removed: usize,
}

/// Collects one sweep's readings and merges each finished sweep into the feature map.
#[derive(Debug)]
pub struct FeatureTracker {
    map: FeatureMap,
    pending: Vec<Reading>,
    /// Where the pending sweep is taken from.
    pose: Isometry2<f64>,
    last: Option<SweepOutcome>,
}

impl FeatureTracker {
    pub fn new(cfg: FeatureConfig) -> Result<Self, FeatureError> {
        Ok(Self {
            map: FeatureMap::new(cfg)?,
            pending: Vec::new(),
            pose: Isometry2::identity(),
            last: None,
        })
    }

    /// Adds `reading`, taken with the sensor at `pose`. When it starts a new sweep, the finished
    /// one is merged first and what that did is returned.
    pub fn push(&mut self, reading: &Reading, pose: &Isometry2<f32>) -> Option<SweepOutcome> {
        let finished = match self.pending.first() {
            Some(first) if first.sweep_id != reading.sweep_id => self.finish_sweep(),
            _ => None,
        };
        if self.pending.is_empty() {
            self.pose = Isometry2::new(
                Vector2::new(f64::from(pose.translation.x), f64::from(pose.translation.y)),
                f64::from(pose.rotation.angle()),
            );
        }
        self.pending.push(*reading);
        finished
    }

    /// Whether readings of an unfinished sweep are waiting.
    pub fn has_pending(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Merges the pending sweep now (the scan stopped, or went quiet).
    pub fn finish_sweep(&mut self) -> Option<SweepOutcome> {
        let first = *self.pending.first()?;
        let sweep = Sweep::from_readings(&self.pending, self.map.config());
        let report = self.map.update(&sweep, &self.pose);
        let outcome = SweepOutcome {
            sweep_id: first.sweep_id,
            readings: self.pending.len(),
            rcds: report.rcds.len(),
            refined: report.refined,
            added: report.added,
            removed: report.removed,
        };
        self.pending.clear();
        self.last = Some(outcome);
        Some(outcome)
    }

    /// Forgets every feature and the pending sweep (the map was cleared).
    pub fn clear(&mut self) {
        self.map.clear();
        self.pending.clear();
        self.last = None;
    }

    /// Features in the map.
    pub fn len(&self) -> usize {
        self.map.features().len()
    }

    pub fn is_empty(&self) -> bool {
        self.map.features().is_empty()
    }

    /// The snapshot's header and records, most confident first, at most [`MAX_FEATURES`]. The
    /// walls' segments grow along the grid's occupied cells.
    pub fn snapshot(
        &self,
        grid: &OccupancyGrid,
        seq: u64,
        stamp_ns: u64,
    ) -> (FeaturesHeader, Vec<FeatureRecord>) {
        let has_planes = self
            .map
            .features()
            .iter()
            .any(|f| f.kind() == FeatureKind::Plane);
        let support = if has_planes {
            occupied_cells(grid)
        } else {
            Vec::new()
        };
        let mut summaries = self.map.summaries(&support);
        summaries.sort_by(|a, b| b.confidence.total_cmp(&a.confidence));
        let left_out = summaries.len().saturating_sub(MAX_FEATURES);
        summaries.truncate(MAX_FEATURES);
        let records: Vec<FeatureRecord> = summaries.iter().map(record).collect();
        let last = self.last.unwrap_or_default();
        let header = FeaturesHeader {
            seq,
            stamp_ns,
            sweeps: self.map.sweeps(),
            layout_version: LAYOUT_VERSION,
            feature_count: count(records.len()),
            last_sweep_id: last.sweep_id,
            last_sweep_rcds: count(last.rcds),
            last_sweep_refined: count(last.refined),
            last_sweep_added: count(last.added),
            last_sweep_removed: count(last.removed),
            features_left_out: count(left_out),
        };
        (header, records)
    }
}

fn count(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

/// Centres of the cells at least [`SUPPORT_PROBABILITY`] occupied.
fn occupied_cells(grid: &OccupancyGrid) -> Vec<Point2<f64>> {
    let geometry = grid.geometry();
    let n = geometry.cells_per_side();
    let mut points = Vec::new();
    for y in 0..n {
        for x in 0..n {
            if grid
                .probability(x, y)
                .is_some_and(|p| p >= SUPPORT_PROBABILITY)
            {
                let c = geometry.cell_centre(x, y);
                points.push(Point2::new(f64::from(c.x), f64::from(c.y)));
            }
        }
    }
    points
}

/// One feature as its fixed-size record.
fn record(s: &FeatureSummary) -> FeatureRecord {
    let [a, b] = s
        .segment
        .map_or([Point2::new(f64::NAN, f64::NAN); 2], |seg| seg);
    FeatureRecord {
        id: s.id,
        kind: match s.kind {
            FeatureKind::Point => feature_kind::POINT,
            FeatureKind::Corner => feature_kind::CORNER,
            FeatureKind::Plane => feature_kind::PLANE,
        },
        times_seen: s.times_seen,
        x_m: s.x as f32,
        y_m: s.y as f32,
        cov_xx: s.cov_xx as f32,
        cov_xy: s.cov_xy as f32,
        cov_yy: s.cov_yy as f32,
        angle_deg: s.angle_deg as f32,
        angle_sigma_deg: s.angle_sigma_deg.map_or(f32::NAN, |v| v as f32),
        confidence: s.confidence as f32,
        segment_ax_m: a.x as f32,
        segment_ay_m: a.y as f32,
        segment_bx_m: b.x as f32,
        segment_by_m: b.y as f32,
        last_seen_sweep: s.last_seen,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{FusionConfig, Mapper};
    use sonar_common::ipc::ScanMode;

    /// A reading of sweep `sweep_id` centred at `centre_deg` (moving counter-clockwise), its four
    /// pings 1.5° apart hearing a 5 cm post 1 m ahead within ±13.4° at its near face.
    fn post_reading(sweep_id: u32, centre_deg: f32) -> Reading {
        let v = 343.2_f32;
        let mut r = Reading {
            layout_version: LAYOUT_VERSION,
            sweep_id,
            angle_deg: centre_deg,
            direction: 1,
            mode: ScanMode::Full as u8,
            ping_count: 4,
            pings_used: 4,
            speed_of_sound_mps: v,
            min_range_m: 0.03,
            max_range_m: 4.0,
            ..Reading::default()
        };
        for j in 0..4 {
            let bearing = centre_deg + 1.5 * (j as f32 - 1.5);
            if bearing.abs() <= 13.4 {
                r.echo_us[j] = (2.0 * 0.979 / v * 1e6).round() as u32;
            }
        }
        r
    }

    fn sweep(sweep_id: u32) -> Vec<Reading> {
        (0..50)
            .map(|k| post_reading(sweep_id, -147.0 + 6.0 * k as f32))
            .collect()
    }

    #[test]
    fn a_sweep_is_merged_when_the_next_one_starts() {
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        let pose = Isometry2::identity();
        for r in &sweep(1) {
            assert_eq!(tracker.push(r, &pose), None, "no sweep has ended yet");
        }
        assert!(tracker.is_empty() && tracker.has_pending());
        let next = sweep(2);
        let outcome = tracker.push(&next[0], &pose).expect("sweep 1 ended");
        assert_eq!((outcome.sweep_id, outcome.readings), (1, 50));
        assert_eq!((outcome.added, outcome.refined), (1, 0));
        for r in &next[1..] {
            assert_eq!(tracker.push(r, &pose), None);
        }
        let outcome = tracker.finish_sweep().expect("sweep 2 pending");
        assert_eq!(
            (outcome.sweep_id, outcome.added, outcome.refined),
            (2, 0, 1)
        );
        assert!(!tracker.has_pending());
        assert_eq!(tracker.finish_sweep(), None, "nothing left to finish");

        let mapper = Mapper::new(FusionConfig::default()).unwrap();
        let (header, records) = tracker.snapshot(mapper.grid(), 7, 42);
        assert_eq!((header.seq, header.stamp_ns, header.sweeps), (7, 42, 2));
        assert_eq!((header.feature_count, header.last_sweep_id), (1, 2));
        assert_eq!(header.last_sweep_refined, 1);
        let post = records[0];
        assert_eq!((post.kind, post.times_seen), (feature_kind::POINT, 2));
        assert!(
            (post.x_m - 0.975).abs() < 0.005 && post.y_m.abs() < 0.005,
            "{post:?}"
        );
        assert!(post.segment_ax_m.is_nan() && post.angle_sigma_deg.is_nan());
    }

    #[test]
    fn the_sweep_is_placed_at_the_pose_of_its_first_reading() {
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        let moved = Isometry2::new(Vector2::new(2.0, -1.0), std::f32::consts::FRAC_PI_2);
        for (k, r) in sweep(1).iter().enumerate() {
            // A pose arriving mid-sweep does not move the sweep's pings.
            let pose = if k == 0 { moved } else { Isometry2::identity() };
            tracker.push(r, &pose);
        }
        tracker.finish_sweep();
        let mapper = Mapper::new(FusionConfig::default()).unwrap();
        let (_, records) = tracker.snapshot(mapper.grid(), 0, 0);
        let post = records[0];
        assert!(
            (post.x_m - 2.0).abs() < 0.005 && (post.y_m - -0.025).abs() < 0.005,
            "{post:?}"
        );
    }

    #[test]
    fn clearing_forgets_features_and_the_pending_sweep() {
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        let pose = Isometry2::identity();
        for r in sweep(1).iter().chain(&sweep(2)[..3]) {
            tracker.push(r, &pose);
        }
        assert_eq!(tracker.len(), 1);
        tracker.clear();
        assert!(tracker.is_empty() && !tracker.has_pending());
        let mapper = Mapper::new(FusionConfig::default()).unwrap();
        let (header, records) = tracker.snapshot(mapper.grid(), 0, 0);
        assert_eq!((header.feature_count, header.last_sweep_id), (0, 0));
        assert!(records.is_empty());
    }
}
