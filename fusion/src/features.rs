//! The feature map next to the grid: readings grouped by sweep, each finished sweep handed to
//! [`sonar_features::FeatureMap`], the result flattened into the records of `sonar/features`.
//!
//! A sweep ends when a reading of the next one arrives ([`FeatureTracker::push`]) or when the
//! readings end ([`FeatureTracker::finish_sweep`]). A process that has heard nothing for
//! [`SWEEP_IDLE`] shows the pending sweep merged ([`FeatureTracker::with_pending_merged`]) but keeps
//! it open: a stopped scan's last sweep is seen at once, and a head that only stalled goes on with
//! the same sweep, so sweeps end where their readings say, however the readings were delivered,
//! and an offline fusion of a recording ends them where the live fusion did. Each sweep is placed at the robot's pose of its first
//! reading, its reference, and every reading's pings are brought from the pose they were taken at
//! to the reference. A sweep taken standing still gives regions of constant depth, classified
//! into walls, corners and posts ([`Sweep::from_readings_at`]). On the move those break up — a
//! wall's foot slides along it with the robot — so a sweep on the move is seen by its walls only,
//! each found with the pings compensated for the motion along its own normal
//! ([`FeatureMap::walls_on_the_move`]). Sweeps on the move add their walls to the map only until
//! a sweep taken standing still has been merged: a robot that stops to scan builds its map from
//! its stops, where what is left of the motion (the odometry's own drift within a sweep) cannot
//! stay in a feature for good; one that never stops builds it on the move.
//!
//! # Localisation
//!
//! With localisation on ([`FeatureTracker::with_localization`]), each reading's odometry step is
//! taken into a [`DriftFilter`], which learns the odometry's scale error, heading drift and turn
//! error from the fixes and takes them out of every step; each finished sweep is matched against
//! the features ([`FeatureMap::localize`]) from the filter's pose at its first reading, with the
//! filter's covariance as the prior, and merged at the corrected pose. The correction (map ←
//! odometry) is handed to the engine after every reading, so the next readings are placed with
//! it: a sweep's own readings are in the grid at the poses predicted before its fix. Between
//! fixes, each ping of a reading taken on the move that faces a well-known wall on its
//! perpendicular measures the distance across it ([`DriftFilter::range_to_wall`]): along a
//! corridor the side walls hold the pose, and through the motion the heading.

use nalgebra::{Isometry2, Matrix3, Point2};
use sonar_common::ipc::Reading;
use sonar_common::ipc::{
    FeatureRecord, FeaturesHeader, LAYOUT_VERSION, MAX_FEATURES, feature_flags, feature_kind,
};
use sonar_features::{
    DriftEstimate, DriftFilter, FeatureConfig, FeatureError, FeatureKind, FeatureMap,
    FeatureSummary, NearRegions, Needs, PoseFix, Sweep, SweepReport,
};

use crate::engine::Engine;
use crate::grid::OccupancyGrid;

/// A reading more than this (m, degrees) from the pose of the sweep's middle reading was taken on
/// the move …
const STILL_M: f64 = 0.01;
const STILL_DEG: f64 = 0.5;
/// … and a sweep with more than this share of such readings is one taken on the move. A few at
/// either end do not count: a reading's stamp is the host's, a millisecond or more after the
/// ping, so the first and last readings of a stop can be placed at the arrival and departure.
const MOVING_SHARE: f64 = 0.1;

/// Quiet time after which the pending sweep is shown merged: the scan stopped (a sweep of the
/// paper's head takes seconds, its readings come every ~0.1 s).
pub const SWEEP_IDLE: std::time::Duration = std::time::Duration::from_secs(2);

/// What one finished sweep did to the feature map.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SweepOutcome {
    pub sweep_id: u32,
    /// `host_stamp_ns` of its first reading.
    pub stamp_ns: u64,
    pub readings: usize,
    pub rcds: usize,
    pub refined: usize,
    pub added: usize,
    pub removed: usize,
    /// Where the sweep was placed before localisation.
    pub predicted: Isometry2<f64>,
    /// The odometry's own pose at its first reading.
    pub odometry: Isometry2<f64>,
    /// Localisation's fix, when it is on and the sweep matched the map.
    pub fix: Option<PoseFix>,
    /// Pings taken on the move that localisation ranged on a known wall.
    pub ranged: usize,
    /// Taken on the move (more than a tenth of its readings away from the middle one's
    /// pose): seen by its walls only, and merged only while no sweep taken standing still has
    /// been.
    pub moving: bool,
    /// Its readings whose pings could not be placed (no raw pings, or no direction): no feature
    /// comes from them.
    pub skipped: usize,
}

/// Localisation's state: the pose with the odometry's drift, and the fixes so far.
#[derive(Debug, Clone)]
struct Localization {
    filter: DriftFilter,
    fixes: u32,
}

/// Collects one sweep's readings and merges each finished sweep into the feature map.
#[derive(Debug, Clone)]
pub struct FeatureTracker {
    map: FeatureMap,
    /// The pending sweep's readings, each with the pose it was placed at relative to the first's.
    pending: Vec<(Reading, Isometry2<f64>)>,
    /// Where the pending sweep is taken from: its first reading's pose, with the correction its
    /// other readings come placed with.
    pose: Isometry2<f64>,
    /// The odometry's own pose at the pending sweep's first reading.
    sweep_odometry: Isometry2<f64>,
    /// Pings of the pending sweep ranged on a known wall.
    ranged: usize,
    /// A sweep taken standing still has been merged: from then on only such sweeps add to the map.
    merged_standing: bool,
    last: Option<SweepOutcome>,
    localization: Option<Localization>,
    /// Readings skipped by every sweep so far ([`SweepOutcome::skipped`]); a clear keeps counting.
    skipped: u64,
}

impl FeatureTracker {
    pub fn new(cfg: FeatureConfig) -> Result<Self, FeatureError> {
        Ok(Self {
            map: FeatureMap::new(cfg)?,
            pending: Vec::new(),
            pose: Isometry2::identity(),
            sweep_odometry: Isometry2::identity(),
            ranged: 0,
            merged_standing: false,
            last: None,
            localization: None,
            skipped: 0,
        })
    }

    /// The tracker with localisation: every sweep is matched against the map before it is
    /// merged, and [`Self::correction`] follows the odometry's drift, learnt from the fixes
    /// ([`DriftFilter`]) with the odometry expected to err as `cfg.odometry` says.
    pub fn with_localization(cfg: FeatureConfig) -> Result<Self, FeatureError> {
        let mut tracker = Self::new(cfg)?;
        tracker.localization = Some(Localization {
            filter: DriftFilter::new(cfg.odometry),
            fixes: 0,
        });
        Ok(tracker)
    }

    /// Map ← odometry: what to apply to the poses of `robot/pose` from now on (identity without
    /// localisation). It changes with every reading, as the odometry's drift is taken out of
    /// each step, and jumps with each fix: hand it to the engine after every [`Self::push`].
    pub fn correction(&self) -> Isometry2<f32> {
        self.correction_f64().cast::<f32>()
    }

    fn correction_f64(&self) -> Isometry2<f64> {
        self.localization
            .as_ref()
            .map_or(Isometry2::identity(), |l| l.filter.correction())
    }

    /// Sweeps localised so far.
    pub fn fixes(&self) -> u32 {
        self.localization.as_ref().map_or(0, |l| l.fixes)
    }

    /// The odometry's drift as localisation has learnt it (`None` without localisation).
    pub fn drift(&self) -> Option<DriftEstimate> {
        self.localization.as_ref().map(|l| l.filter.drift())
    }

    /// Adds `reading`, taken with the sensor at `pose` (the odometry's pose with
    /// [`Self::correction`] as it was before this call). When it starts a new sweep, the finished
    /// one is merged first and what that did is returned.
    pub fn push(&mut self, reading: &Reading, pose: &Isometry2<f32>) -> Option<SweepOutcome> {
        // The odometry's own pose: a fix moves the placed poses, not the robot. Rebuilt from its
        // angle: the placed pose is the engine's f32 product with the correction, and a rotation
        // a little off unit length, undone and applied again at every reading, would shrink to
        // nothing.
        let odometry = rigid(&(self.correction_f64().inverse() * pose.cast::<f64>()));
        let finished = match self.pending.first() {
            Some((first, _)) if first.sweep_id != reading.sweep_id => self.finish_sweep(),
            _ => None,
        };
        if let Some(loc) = &mut self.localization
            && loc.filter.advance(&odometry)
        {
            self.ranged += range_on_walls(&mut loc.filter, &self.map, reading);
        }
        // Placed with the correction of now: after the step's drift is taken out and the finished
        // sweep's fix, neither of which the engine's placement of this reading had yet.
        let placed = self.correction_f64() * odometry;
        let relative = if self.pending.is_empty() {
            if let Some(loc) = &mut self.localization {
                loc.filter.begin_sweep();
            }
            self.pose = placed;
            self.sweep_odometry = odometry;
            Isometry2::identity()
        } else {
            self.pose.inverse() * placed
        };
        self.pending.push((*reading, relative));
        finished
    }

    /// Whether more than [`MOVING_SHARE`] of the pending sweep's readings were taken away from the
    /// pose of its middle one.
    fn taken_on_the_move(&self) -> bool {
        let Some((_, middle)) = self.pending.get(self.pending.len() / 2) else {
            return false;
        };
        let away = self
            .pending
            .iter()
            .filter(|(_, relative)| {
                let d = middle.inverse() * relative;
                d.translation.vector.norm() > STILL_M
                    || d.rotation.angle().abs() > STILL_DEG.to_radians()
            })
            .count();
        away as f64 > MOVING_SHARE * self.pending.len() as f64
    }

    /// Adds a reading `engine` has just fused, at the pose the engine placed it; with `localize`,
    /// hands the engine the correction the next reading is to be placed with, so the odometry's
    /// drift is taken out step by step. The order `sonar-fusion` and the offline exports share.
    pub fn follow(
        &mut self,
        reading: &Reading,
        engine: &mut Engine,
        localize: bool,
    ) -> Option<SweepOutcome> {
        let finished = self.push(reading, engine.pose());
        if localize {
            engine.set_correction(self.correction());
        }
        finished
    }

    /// Whether readings of an unfinished sweep are waiting.
    pub fn has_pending(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Merges the pending sweep now (the readings ended).
    pub fn finish_sweep(&mut self) -> Option<SweepOutcome> {
        let (first, _) = *self.pending.first()?;
        let sweep = Sweep::from_readings_at(
            self.pending.iter().map(|(r, relative)| (r, *relative)),
            self.map.config(),
        );
        let (rcds, classification) = self.map.observe(&sweep);
        let moving = self.taken_on_the_move();
        // On the move, regions of constant depth break up (a wall's foot slides along it with the
        // robot): such a sweep is seen by its walls, found under the motion along each normal.
        let observations = if moving {
            self.map
                .walls_on_the_move(&self.pending, NearRegions::LeftOut)
        } else {
            classification.observations
        };
        let predicted = self.pose;
        let mut pose = predicted;
        // Without localisation the pose is taken as exact.
        let mut pose_covariance = Matrix3::zeros();
        let mut fix = None;
        if let Some(loc) = &mut self.localization {
            // The filter's pose at the sweep's first reading is `predicted`; its covariance is the
            // prior, and what the fix adds to it is the sonar's.
            let (_, prior) = loc.filter.sweep_prior();
            pose_covariance = prior;
            // A sweep on the move needs two matches; against a map built from stops, none is
            // taken: the map's features are better than such a sweep's walls (placed with the
            // odometry's own drift within the sweep, which the prior does not hold), and the
            // filter's prediction usually too. Measured on the corridor tour over 10 seeds and
            // the four signs of 3 % and 2°/m (`sonar-eval --motion-only --motion-seeds 1..10:1
            // --motion-scale-error ±0.03 --motion-heading-drift ±2`): at fd43f66 largest pose
            // error 4.0–8.5 cm and 1.9–2.6° with two matches, 5.0–5.9 cm and 1.6–1.8° with
            // three; since walls are found on sweeps that turn with the head (`Sweep::facing`),
            // three matches are met there and gave 12.7–17.7 cm and 3.0–3.8° (worst over the
            // seeds), none 7.8–9.2 cm and 1.9–2.2°, as before that. The room tour, whose map is
            // built on the move, falls apart with three (23 cm and 15°, once 180°): there such
            // fixes are all it has.
            let needs = match (moving, self.merged_standing) {
                (false, _) => Some(Needs::OneWallOrTwo),
                (true, false) => Some(Needs::Matches(2)),
                (true, true) => None,
            };
            if let Some(needs) = needs
                && let Some(found) = self.map.localize(&observations, needs, &predicted, &prior)
                && loc.filter.apply_fix(&found, &prior)
            {
                loc.fixes += 1;
                pose = found.pose;
                pose_covariance = found.covariance;
                fix = Some(found);
            }
        }
        // A sweep on the move adds its walls to the map only while no sweep taken standing still
        // has: what is left of the motion (the odometry's drift within the sweep) is a small
        // error in one fix but stays in a feature for good. A robot that scans while it drives
        // builds its map from them; one that stops to scan, from its stops. Measured
        // (docs/results.md): merging the walls of every sweep on the move tripled the corridor's
        // largest pose error; merging none leaves the room tour without a map.
        let report = if moving && self.merged_standing {
            SweepReport::default()
        } else {
            self.map
                .merge(&observations, &sweep, &pose, &pose_covariance)
        };
        self.merged_standing |= !moving;
        let outcome = SweepOutcome {
            sweep_id: first.sweep_id,
            stamp_ns: first.host_stamp_ns,
            readings: self.pending.len(),
            rcds: rcds.len(),
            refined: report.refined,
            added: report.added,
            removed: report.removed,
            predicted,
            odometry: self.sweep_odometry,
            fix,
            ranged: self.ranged,
            moving,
            skipped: sweep.skipped_readings(),
        };
        self.skipped += outcome.skipped as u64;
        self.pending.clear();
        self.ranged = 0;
        self.last = Some(outcome);
        Some(outcome)
    }

    /// Forgets every feature and the pending sweep (the map was cleared): the next sweeps build
    /// the map again, on the move too until one is taken standing still. Localisation keeps its
    /// pose and what it learnt of the odometry.
    pub fn clear(&mut self) {
        self.map.clear();
        self.pending.clear();
        self.ranged = 0;
        self.merged_standing = false;
        self.last = None;
    }

    /// A copy with the pending sweep merged now, and what that did (`None` when nothing is
    /// pending): what to show while the readings have stopped. This tracker keeps the sweep open,
    /// so readings that come after a stall join it as they would have without one.
    pub fn with_pending_merged(&self) -> Option<(Self, SweepOutcome)> {
        let mut merged = self.clone();
        let outcome = merged.finish_sweep()?;
        Some((merged, outcome))
    }

    /// Readings whose pings could not be placed, in every sweep so far.
    pub fn readings_skipped(&self) -> u64 {
        self.skipped
    }

    /// Features in the map.
    pub fn len(&self) -> usize {
        self.map.features().count()
    }

    pub fn is_empty(&self) -> bool {
        self.map.features().next().is_none()
    }

    /// The snapshot's header and records, most confident first, at most [`MAX_FEATURES`]. The
    /// walls' segments grow along the grid's confidently occupied cells
    /// ([`OccupancyGrid::confident_cells`]: kept up to date from the cells that changed, so a
    /// snapshot does not read every cell of the grid).
    pub fn snapshot(
        &self,
        grid: &mut OccupancyGrid,
        seq: u64,
        stamp_ns: u64,
    ) -> (FeaturesHeader, Vec<FeatureRecord>) {
        let support = if self.has_planes() {
            support_points(grid)
        } else {
            Vec::new()
        };
        self.snapshot_with(&support, seq, stamp_ns)
    }

    fn has_planes(&self) -> bool {
        self.map.features().any(|f| f.kind() == FeatureKind::Plane)
    }

    /// [`Self::snapshot`] with the walls' segments grown along `support`.
    fn snapshot_with(
        &self,
        support: &[Point2<f64>],
        seq: u64,
        stamp_ns: u64,
    ) -> (FeaturesHeader, Vec<FeatureRecord>) {
        let mut summaries = self.map.summaries(support);
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

/// σ of one ping's range to a wall, for localisation on the move: the detector's jitter (≈ 4 mm)
/// and the wall's own roughness, widened because the pings of a reading and of neighbouring
/// readings hear the same stretch of wall and are not independent.
const RANGING_SIGMA_M: f64 = 0.02;
/// A ping ranges on a wall whose normal lies this far inside the specular cut-off of its axis:
/// near the edge of the cone a wall's echo may be lost and something beyond it heard.
const RANGING_CONE_MARGIN_DEG: f64 = 8.0;
/// … and only while the heading is known to a quarter of that margin (1σ): with the heading
/// uncertain by more, the wall a ping faces is a guess, and one update of the distance across it
/// can turn the heading by tens of degrees through their correlation. Measured (seeds 1–10, the
/// four signs of 3 % and 2°/m): the corridor's largest pose error 4.3–5.9 cm and 1.6–1.8° →
/// 3.6–4.3 cm and 1.0–1.2°.
const RANGING_MAX_HEADING_SIGMA_DEG: f64 = RANGING_CONE_MARGIN_DEG / 4.0;

/// Ranges the pings of `reading`, taken on the move at the filter's current pose, on the walls of
/// `map` they face, while the heading is known well enough; the number used. A sweep taken on the move makes no regions of constant depth
/// (a wall's foot slides along it with the robot), but each ping aimed within a known wall's
/// cone still measures the distance across it: driving along a corridor, its side walls keep the
/// pose and, through the motion, the heading.
fn range_on_walls(filter: &mut DriftFilter, map: &FeatureMap, reading: &Reading) -> usize {
    if filter.heading_sigma_rad() > RANGING_MAX_HEADING_SIGMA_DEG.to_radians() {
        return 0;
    }
    let cfg = map.config();
    let cone = (cfg.echo.specular_cutoff_deg - RANGING_CONE_MARGIN_DEG).to_radians();
    let late = cfg.range_offset_m;
    let pings = Sweep::from_readings_at(std::iter::once((reading, Isometry2::identity())), cfg);
    let mut used = 0;
    for ping in pings.pings() {
        let Some(range) = ping.range_m else { continue };
        let bearing = ping.bearing_deg.to_radians();
        if let Some(wall) = map.wall_ahead(&filter.pose(), bearing, cone)
            && filter.range_to_wall(&wall, range - late, RANGING_SIGMA_M)
        {
            used += 1;
        }
    }
    used
}

/// `pose` with its rotation of unit length again.
fn rigid(pose: &Isometry2<f64>) -> Isometry2<f64> {
    Isometry2::new(pose.translation.vector, pose.rotation.angle())
}

fn count(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

/// Centres of the grid's confidently occupied cells, row by row: the points a wall's segment may
/// grow along.
fn support_points(grid: &mut OccupancyGrid) -> Vec<Point2<f64>> {
    let geometry = *grid.geometry();
    grid.confident_cells()
        .map(|(x, y)| {
            let c = geometry.cell_centre(x, y);
            Point2::new(f64::from(c.x), f64::from(c.y))
        })
        .collect()
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
        flags: if s.confirmed {
            feature_flags::CONFIRMED
        } else {
            0
        },
        reserved: 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{FusionConfig, Mapper};
    use nalgebra::Vector2;
    use sonar_common::ipc::{ScanMode, flags};
    use sonar_features::OdometryErrors;

    /// A reading of sweep `sweep_id` centred at `centre_deg` (moving counter-clockwise), its four
    /// pings 1.5° apart hearing a 5 cm post 1 m ahead within ±13.4° at its near face.
    fn post_reading(sweep_id: u32, centre_deg: f32) -> Reading {
        reading_of(sweep_id, centre_deg, false, 0.0)
    }

    /// [`post_reading`], with a wall 2 m ahead heard within ±28° where the post does not hide it,
    /// all of it `nearer_m` nearer.
    fn reading_of(sweep_id: u32, centre_deg: f32, wall: bool, nearer_m: f32) -> Reading {
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
                r.echo_us[j] = (2.0 * (0.979 - nearer_m) / v * 1e6).round() as u32;
            } else if wall && bearing.abs() <= 28.0 {
                r.echo_us[j] = (2.0 * (2.0043 - nearer_m) / v * 1e6).round() as u32;
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

        let mut mapper = Mapper::new(FusionConfig::default()).unwrap();
        let (header, records) = tracker.snapshot(mapper.grid_mut(), 7, 42);
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
        assert!(!post.is_confirmed(), "heard from one place only: tentative");
        assert_eq!(tracker.readings_skipped(), 0, "every ping placed");

        // The flag is the feature map's: set for a feature heard from two places.
        let summary = |confirmed| FeatureSummary {
            id: 1,
            kind: FeatureKind::Point,
            x: 1.0,
            y: 0.0,
            cov_xx: 1e-4,
            cov_xy: 0.0,
            cov_yy: 1e-4,
            angle_deg: 0.0,
            angle_sigma_deg: None,
            confidence: 0.5,
            times_seen: 2,
            last_seen: 2,
            confirmed,
            segment: None,
        };
        assert!(record(&summary(true)).is_confirmed());
        assert_eq!(record(&summary(false)).flags, 0);
    }

    #[test]
    fn a_pending_sweep_shown_merged_stays_open_for_the_readings_after_a_stall() {
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        let pose = Isometry2::identity();
        let readings = sweep(1);
        assert!(tracker.with_pending_merged().is_none(), "nothing pending");
        for r in &readings[..25] {
            tracker.push(r, &pose);
        }
        let (shown, outcome) = tracker.with_pending_merged().expect("25 readings pending");
        assert_eq!((outcome.sweep_id, outcome.readings), (1, 25));
        assert_eq!((shown.has_pending(), shown.map.sweeps()), (false, 1));
        assert_eq!(tracker.map.sweeps(), 0, "the tracker itself merged nothing");
        // The head goes on after its stall: one sweep of 50, as if it had never stalled.
        for r in &readings[25..] {
            assert_eq!(tracker.push(r, &pose), None);
        }
        let whole = tracker.finish_sweep().expect("the sweep pending");
        assert_eq!((whole.sweep_id, whole.readings), (1, 50));
        let mut unstalled = FeatureTracker::new(FeatureConfig::default()).unwrap();
        for r in &readings {
            unstalled.push(r, &pose);
        }
        assert_eq!(unstalled.finish_sweep(), Some(whole));
    }

    #[test]
    fn readings_whose_pings_cannot_be_placed_are_counted_and_give_nothing() {
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        let pose = Isometry2::identity();
        // Four pings each, but no direction of motion to place them by.
        let undirected = |sweep_id| {
            let mut readings = sweep(sweep_id);
            for r in &mut readings {
                r.direction = 0;
            }
            readings
        };
        for r in undirected(1).iter().chain(&undirected(2)[..1]) {
            tracker.push(r, &pose);
        }
        let outcome = tracker.last.expect("sweep 1 merged");
        assert_eq!(
            (outcome.readings, outcome.skipped, outcome.rcds),
            (50, 50, 0)
        );
        assert!(tracker.is_empty());
        tracker.clear();
        for r in &undirected(2)[1..] {
            tracker.push(r, &pose);
        }
        tracker.finish_sweep();
        // The clear dropped sweep 2's first reading with the pending sweep; the rest is counted on.
        assert_eq!(
            tracker.readings_skipped(),
            50 + 49,
            "a clear keeps counting"
        );
        // One range per angle (the hobby dialect) is one ping on each reading's axis: used.
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        for r in sweep(1).iter().chain(&sweep(2)[..1]) {
            let mut per_angle = *r;
            per_angle.flags |= flags::NO_RAW_PINGS;
            per_angle.ping_count = 1;
            tracker.push(&per_angle, &pose);
        }
        let outcome = tracker.last.expect("sweep 1 merged");
        assert_eq!((outcome.readings, outcome.skipped), (50, 0));
        assert!(outcome.rcds > 0, "{outcome:?}");
    }

    #[test]
    fn a_sweep_is_placed_at_its_pose_and_one_on_the_move_ping_by_ping() {
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        let moved = Isometry2::new(Vector2::new(2.0, -1.0), std::f32::consts::FRAC_PI_2);
        for r in &sweep(1) {
            tracker.push(r, &moved);
        }
        let still = tracker.finish_sweep().unwrap();
        assert!(!still.moving && still.added == 1, "{still:?}");
        let mut mapper = Mapper::new(FusionConfig::default()).unwrap();
        let mut post_at = |tracker: &FeatureTracker| {
            let (_, records) = tracker.snapshot(mapper.grid_mut(), 0, 0);
            (records[0].x_m, records[0].y_m)
        };
        let (x, y) = post_at(&tracker);
        assert!(
            (x - 2.0).abs() < 0.005 && (y - -0.025).abs() < 0.005,
            "{x} {y}"
        );
        // The next sweep drives 30 cm towards the post while the head turns past it (1 cm per
        // reading from the 20th): each reading hears the post nearer. Brought to the first
        // reading's pose ping by ping, the post's run of constant depth is whole; the sweep adds
        // nothing to the map.
        for k in 0..50 {
            let ahead = 0.01 * (k as f32 - 20.0).clamp(0.0, 30.0);
            let r = reading_of(2, -147.0 + 6.0 * k as f32, false, ahead);
            tracker.push(&r, &(moved * Isometry2::translation(ahead, 0.0)));
        }
        let on_the_move = tracker.finish_sweep().unwrap();
        assert!(on_the_move.moving, "{on_the_move:?}");
        assert_eq!(on_the_move.rcds, 1, "{on_the_move:?}");
        assert_eq!((on_the_move.added, on_the_move.refined), (0, 0));
        assert_eq!(tracker.len(), 1);
    }

    /// Pushes `reading` as the engine would have placed it: the odometry's pose with the
    /// tracker's correction.
    fn push_at(
        tracker: &mut FeatureTracker,
        reading: &Reading,
        odometry: &Isometry2<f32>,
        outcomes: &mut Vec<SweepOutcome>,
    ) {
        let placed = tracker.correction() * odometry;
        outcomes.extend(tracker.push(reading, &placed));
    }

    /// Sweep `sweep_id`, in which nothing is heard, while the robot drives 1 m straight out from
    /// `start` and back, turning on the spot at each end; its odometry reports 3 % long and drifts
    /// 2°/m. Returns the odometry's pose at the end, where the robot truly is at `start` again.
    fn drive_out_and_back(
        tracker: &mut FeatureTracker,
        sweep_id: u32,
        start: Isometry2<f32>,
        outcomes: &mut Vec<SweepOutcome>,
    ) -> Isometry2<f32> {
        // Aimed at 100°: nothing there to hear.
        let silent = reading_of(sweep_id, 100.0, false, 0.0);
        let step = Isometry2::new(Vector2::new(0.05 * 1.03, 0.0), 0.05 * 2f32.to_radians());
        let mut odometry = start;
        for _ in 0..2 {
            for _ in 0..20 {
                odometry *= step;
                push_at(tracker, &silent, &odometry, outcomes);
            }
            odometry *= Isometry2::rotation(std::f32::consts::PI);
            push_at(tracker, &silent, &odometry, outcomes);
        }
        odometry
    }

    /// A reading of sweep `sweep_id` centred at `centre_deg` at the end of a room: a wall 2 m
    /// ahead (each wall heard within ±28° of its normal) with the post of [`post_reading`] before
    /// it, both `ahead_m` nearer, a wall 1.5 m to the left and one 1.2 m to the right.
    fn room_reading(sweep_id: u32, centre_deg: f32, ahead_m: f32) -> Reading {
        let mut r = reading_of(sweep_id, centre_deg, true, ahead_m);
        for j in 0..4 {
            let bearing = centre_deg + 1.5 * (j as f32 - 1.5);
            for (normal, range) in [(90.0, 1.5043), (-90.0, 1.2043)] {
                if (bearing - normal).abs() <= 28.0 {
                    r.echo_us[j] = (2.0 * range / r.speed_of_sound_mps * 1e6).round() as u32;
                }
            }
        }
        r
    }

    #[test]
    fn a_stop_whose_first_and_last_readings_are_placed_on_the_move_is_a_standing_sweep() {
        // The host stamps a reading a little after its ping: the stop's first reading lands on
        // the arrival, its last on the departure, 2 cm away.
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        let readings = sweep(1);
        let last = readings.len() - 1;
        for (k, r) in readings.iter().enumerate() {
            let pose = match k {
                0 => Isometry2::translation(-0.02, 0.0),
                k if k == last => Isometry2::translation(0.02, 0.0),
                _ => Isometry2::identity(),
            };
            tracker.push(r, &pose);
        }
        let stop = tracker.finish_sweep().unwrap();
        assert!(!stop.moving && stop.added == 1, "{stop:?}");
    }

    /// Sweep `sweep_id` of [`room_reading`]s while the robot drives 30 cm towards the post and
    /// the wall behind it from `at` (its odometry), between the walls on either side.
    fn driving_sweep(
        tracker: &mut FeatureTracker,
        sweep_id: u32,
        at: Isometry2<f32>,
        outcomes: &mut Vec<SweepOutcome>,
    ) -> SweepOutcome {
        for k in 0..50 {
            let ahead = 0.01 * (k as f32 - 20.0).clamp(0.0, 30.0);
            let r = room_reading(sweep_id, -147.0 + 6.0 * k as f32, ahead);
            push_at(
                tracker,
                &r,
                &(at * Isometry2::translation(ahead, 0.0)),
                outcomes,
            );
        }
        tracker.finish_sweep().unwrap()
    }

    #[test]
    fn a_sweep_on_the_move_is_localised_by_its_walls_against_a_map_built_on_the_move() {
        let mut tracker = FeatureTracker::with_localization(FeatureConfig::default()).unwrap();
        let start = Isometry2::new(Vector2::new(2.0, -1.0), std::f32::consts::FRAC_PI_2);
        let mut outcomes = Vec::new();
        // A robot that never stops: its first sweep's walls make the map.
        let first = driving_sweep(&mut tracker, 1, start, &mut outcomes);
        assert!(first.moving && first.added == 3, "{first:?}");
        // A drive out and back leaves the odometry some centimetres and 4° off; then the same
        // drive towards the post.
        let drifted = drive_out_and_back(&mut tracker, 2, start, &mut outcomes);
        let odometry_error = start.inverse() * drifted;
        assert!(
            odometry_error.rotation.angle().abs() > 3.0_f32.to_radians(),
            "{odometry_error}"
        );
        let outcome = driving_sweep(&mut tracker, 3, drifted, &mut outcomes);
        assert!(outcome.moving, "{outcome:?}");
        let fix = outcome.fix.expect("the sweep on the move is localised");
        assert_eq!(fix.matched, 3, "the three walls, not the post: {fix:?}");
        let err = start.cast::<f64>().inverse() * fix.pose;
        assert!(
            err.translation.vector.norm() < 0.01
                && err.rotation.angle().abs() < 0.5_f64.to_radians(),
            "{fix:?}"
        );
    }

    #[test]
    fn a_sweep_on_the_move_is_not_matched_against_a_map_built_from_stops() {
        let mut tracker = FeatureTracker::with_localization(FeatureConfig::default()).unwrap();
        let start = Isometry2::new(Vector2::new(2.0, -1.0), std::f32::consts::FRAC_PI_2);
        let mut outcomes = Vec::new();
        for sweep_id in 1..=2 {
            for k in 0..50 {
                let r = room_reading(sweep_id, -147.0 + 6.0 * k as f32, 0.0);
                push_at(&mut tracker, &r, &start, &mut outcomes);
            }
        }
        let drifted = drive_out_and_back(&mut tracker, 3, start, &mut outcomes);
        let outcome = driving_sweep(&mut tracker, 4, drifted, &mut outcomes);
        // Its walls would match (the test above), but they carry the odometry's drift within
        // the sweep, which the stops' map does not: the robot localises at its stops.
        assert!(outcome.moving, "{outcome:?}");
        assert!(outcome.fix.is_none(), "{outcome:?}");
        assert_eq!((outcome.added, outcome.refined), (0, 0), "not merged");
    }

    #[test]
    fn sweeps_on_the_move_build_the_map_until_one_is_taken_standing_still() {
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        let moving_sweep = |tracker: &mut FeatureTracker, sweep_id| {
            for k in 0..50 {
                let ahead = 0.01 * (k as f32 - 20.0).clamp(0.0, 30.0);
                let r = room_reading(sweep_id, -147.0 + 6.0 * k as f32, ahead);
                tracker.push(&r, &Isometry2::translation(ahead, 0.0));
            }
            tracker.finish_sweep().unwrap()
        };
        // A robot that never stopped yet: its walls go into the map (not the post, whose range
        // changes with the motion in a way the beam does not tell).
        let first = moving_sweep(&mut tracker, 1);
        assert!(first.moving && first.added == 3, "{first:?}");
        assert!(
            tracker
                .map
                .tracked()
                .iter()
                .all(|f| f.kind() == FeatureKind::Plane)
        );
        // Standing still from the start pose: the post is added, the walls refined.
        for k in 0..50 {
            tracker.push(
                &room_reading(2, -147.0 + 6.0 * k as f32, 0.0),
                &Isometry2::identity(),
            );
        }
        let standing = tracker.finish_sweep().unwrap();
        assert!(!standing.moving && standing.refined == 3, "{standing:?}");
        // From then on a sweep on the move adds nothing.
        let later = moving_sweep(&mut tracker, 3);
        assert_eq!((later.added, later.refined), (0, 0), "{later:?}");
        // A cleared map is built again, on the move too.
        tracker.clear();
        let again = moving_sweep(&mut tracker, 4);
        assert_eq!(again.added, 3, "{again:?}");
    }

    /// A sweep of the post and the wall from `odometry`.
    fn sweep_at(
        tracker: &mut FeatureTracker,
        sweep_id: u32,
        odometry: Isometry2<f32>,
        outcomes: &mut Vec<SweepOutcome>,
    ) {
        for k in 0..50 {
            let r = reading_of(sweep_id, -147.0 + 6.0 * k as f32, true, 0.0);
            push_at(tracker, &r, &odometry, outcomes);
        }
    }

    /// Three sweeps from the origin, a drive out and back (sweep 4, nothing heard) that leaves the
    /// odometry off, then four more from the origin: what each finished sweep did, placed as the
    /// engine would with the tracker's correction.
    fn drifting_run(tracker: &mut FeatureTracker) -> Vec<SweepOutcome> {
        let start = Isometry2::identity();
        let mut outcomes = Vec::new();
        for sweep_id in 1..=3 {
            sweep_at(tracker, sweep_id, start, &mut outcomes);
        }
        let drifted = drive_out_and_back(tracker, 4, start, &mut outcomes);
        for sweep_id in 5..=8 {
            sweep_at(tracker, sweep_id, drifted, &mut outcomes);
        }
        outcomes
    }

    #[test]
    fn localisation_finds_the_odometry_drift_and_keeps_the_post_in_place() {
        let mut plain = FeatureTracker::new(FeatureConfig::default()).unwrap();
        drifting_run(&mut plain);
        // Without localisation the drifted sweeps see the post and the wall off: a second wall,
        // and a second post 4 cm from the first, taken for one target heard as two points
        // (`merge.one_point_m`).
        assert_eq!(plain.len(), 3, "{:?}", plain.map.tracked());
        assert_eq!(
            plain
                .map
                .features()
                .filter(|f| f.kind() == FeatureKind::Plane)
                .count(),
            2,
            "{:?}",
            plain.map.tracked()
        );

        let mut tracker = FeatureTracker::with_localization(FeatureConfig::default()).unwrap();
        let outcomes = drifting_run(&mut tracker);
        assert_eq!(outcomes.len(), 7);
        assert!(outcomes[0].fix.is_none(), "the map was empty");
        assert!(outcomes[3].fix.is_none(), "nothing was heard on the drive");
        let fix = outcomes[4]
            .fix
            .expect("the first sweep after the drive is localised");
        // The robot is back where it started: the fix takes back the odometry's drift, and what is
        // left lies within three of its own standard deviations.
        let (x, y, theta) = (
            fix.pose.translation.x,
            fix.pose.translation.y,
            fix.pose.rotation.angle(),
        );
        assert!(
            x.hypot(y) < 0.02 && theta.abs() < 1.0_f64.to_radians(),
            "{fix:?}"
        );
        for (i, err) in [x, y, theta].into_iter().enumerate() {
            assert!(
                err.abs() <= 3.0 * fix.covariance[(i, i)].sqrt(),
                "{i}: {fix:?}"
            );
        }
        assert_eq!(tracker.len(), 2, "refined, not duplicated");
        assert!(tracker.fixes() >= 4, "{outcomes:?}");
        // The sweeps after the first fix are already placed with the correction.
        let later = outcomes[6].fix.expect("a fix");
        assert!(
            (later.pose.inverse() * outcomes[6].predicted)
                .translation
                .vector
                .norm()
                < 0.005
        );
    }

    #[test]
    fn pings_range_on_known_walls_only_while_the_heading_is_known() {
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        for sweep_id in 1..=3 {
            for k in 0..50 {
                tracker.push(
                    &room_reading(sweep_id, -147.0 + 6.0 * k as f32, 0.0),
                    &Isometry2::identity(),
                );
            }
            tracker.finish_sweep();
        }
        // Aimed at the wall 1.5 m to the left, from the place the map was made at.
        let left = room_reading(9, 90.0, 0.0);
        let mut filter = DriftFilter::new(OdometryErrors::default());
        filter.advance(&Isometry2::identity());
        assert_eq!(range_on_walls(&mut filter, &tracker.map, &left), 4);
        // After 10 m of driving without a fix the heading is known to some 30°: no wall is
        // safely the one a ping faces.
        let mut odometry = Isometry2::identity();
        for _ in 0..200 {
            odometry *= Isometry2::translation(0.05, 0.0);
            filter.advance(&odometry);
        }
        filter.advance(&Isometry2::identity());
        assert!(filter.heading_sigma_rad().to_degrees() > 10.0);
        assert_eq!(range_on_walls(&mut filter, &tracker.map, &left), 0);
    }

    /// The support points as snapshots once found them: every cell's probability read, row by
    /// row.
    fn walked_support_points(grid: &OccupancyGrid) -> Vec<Point2<f64>> {
        let geometry = grid.geometry();
        let n = geometry.cells_per_side();
        let mut points = Vec::new();
        for y in 0..n {
            for x in 0..n {
                if grid
                    .probability(x, y)
                    .is_some_and(|p| p >= crate::grid::CONFIDENT_PROBABILITY)
                {
                    let c = geometry.cell_centre(x, y);
                    points.push(Point2::new(f64::from(c.x), f64::from(c.y)));
                }
            }
        }
        points
    }

    #[test]
    fn snapshots_grow_the_walls_as_a_walk_over_every_cell_did_on_random_grids() {
        use rand::{Rng, SeedableRng};
        use sonar_features::segment::SegmentEnd;
        // Three walls (2 m ahead, 1.5 m left, 1.2 m right) and the post.
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        for sweep_id in 1..=2 {
            for k in 0..50 {
                let r = room_reading(sweep_id, -147.0 + 6.0 * k as f32, 0.0);
                tracker.push(&r, &Isometry2::identity());
            }
        }
        tracker.finish_sweep();
        assert!(tracker.has_planes());
        let mut grew_along_support = 0;
        for seed in 0..6 {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let mut mapper = Mapper::new(FusionConfig::default()).unwrap();
            let grid = mapper.grid_mut();
            let geometry = *grid.geometry();
            let n = geometry.cells_per_side();
            // Stretches of each wall's line confidently occupied, with gaps of random width, and
            // random evidence everywhere.
            for round in 0..3 {
                let mut runs = Vec::new();
                for _ in 0..rng.random_range(5..40) {
                    let along = rng.random_range(-3.5f32..3.5);
                    let len = rng.random_range(0.05f32..0.6);
                    let p = if round == 2 { 0.3 } else { 0.95 };
                    for (from, to) in [
                        ((along, 1.5), (along + len, 1.5)),
                        ((along, -1.2), (along + len, -1.2)),
                    ] {
                        if let (Some((x0, y)), Some((x1, _))) = (
                            geometry.cell_at(Point2::new(from.0, from.1)),
                            geometry.cell_at(Point2::new(to.0, to.1)),
                        ) {
                            runs.push((geometry.index(x0, y)..geometry.index(x1, y) + 1, p));
                        }
                    }
                    let mut y = along;
                    while y < along + len {
                        if let Some((x, yc)) = geometry.cell_at(Point2::new(2.0, y)) {
                            let i = geometry.index(x, yc);
                            runs.push((i..i + 1, p));
                        }
                        y += geometry.resolution();
                    }
                }
                crate::grid::fuse_runs(grid, runs);
                crate::grid::fuse_random_runs(grid, &mut rng, 4 * n);
                let walked = walked_support_points(grid);
                let (header, records) = tracker.snapshot(grid, 3, 9);
                let (old_header, old_records) = tracker.snapshot_with(&walked, 3, 9);
                assert_eq!(support_points(grid), walked, "seed {seed} round {round}");
                // Debug prints every float exactly, NaNs alike.
                assert_eq!(
                    format!("{header:?} {records:?}"),
                    format!("{old_header:?} {old_records:?}"),
                    "seed {seed} round {round}"
                );
                grew_along_support += tracker
                    .map
                    .segments(&walked)
                    .iter()
                    .filter(|s| s.ends.contains(&SegmentEnd::Support))
                    .count();
            }
        }
        assert!(grew_along_support > 10, "{grew_along_support}");
    }

    #[test]
    fn snapshots_of_fused_scans_grow_the_walls_as_a_walk_over_every_cell_did() {
        // The room's sweeps fused by the engine as the process does (each reading fused, then
        // followed), the room a little nearer or farther each sweep so that cells enter and
        // leave the confident set; grid snapshots taken now and then between features snapshots,
        // so the flushes the two trigger interleave.
        let mut engine = Engine::new(FusionConfig::default(), 1000).unwrap();
        let mut tracker = FeatureTracker::new(FeatureConfig::default()).unwrap();
        let (mut compared, mut with_support) = (0, 0);
        for sweep_id in 1..=8u32 {
            let nearer = [0.0, 0.03, -0.02, 0.05, 0.0, 0.1, -0.04, 0.02][sweep_id as usize - 1];
            for k in 0..50 {
                let mut r = room_reading(sweep_id, -147.0 + 6.0 * k as f32, nearer);
                let nearest_us = r.echo_us[..4].iter().copied().filter(|&us| us > 0).min();
                match nearest_us {
                    Some(us) => r.distance_m = us as f32 * 1e-6 * r.speed_of_sound_mps / 2.0,
                    None => {
                        r.flags = flags::NO_ECHO;
                        r.distance_m = r.max_range_m;
                    }
                }
                r.beam_half_angle_deg = 30.0;
                r.seq = u64::from(sweep_id * 50 + k);
                assert!(engine.fuse(&r), "sweep {sweep_id} reading {k}");
                if k % 7 == 3 {
                    engine.encoded_grid();
                }
                if tracker.follow(&r, &mut engine, false).is_none() {
                    continue;
                }
                let walked = walked_support_points(engine.mapper().grid());
                let (header, records) = tracker.snapshot(engine.grid_mut(), 5, 7);
                let (old_header, old_records) = tracker.snapshot_with(&walked, 5, 7);
                assert_eq!(
                    support_points(engine.grid_mut()),
                    walked,
                    "sweep {sweep_id}"
                );
                assert_eq!(
                    format!("{header:?} {records:?}"),
                    format!("{old_header:?} {old_records:?}"),
                    "sweep {sweep_id}"
                );
                compared += 1;
                with_support += usize::from(!walked.is_empty() && tracker.has_planes());
            }
        }
        assert!(
            compared >= 6 && with_support >= 5,
            "{compared} {with_support}"
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
        let mut mapper = Mapper::new(FusionConfig::default()).unwrap();
        let (header, records) = tracker.snapshot(mapper.grid_mut(), 0, 0);
        assert_eq!((header.feature_count, header.last_sweep_id), (0, 0));
        assert!(records.is_empty());
    }
}
