//! Sweeps in, pose estimates out: one pose per sweep, landmarks admitted from two viewpoints,
//! data association gated by the joint covariance, the graph solved after every sweep.
//!
//! # One sweep
//!
//! 1. Its readings are collected until a reading of the next sweep arrives (or
//!    [`Slam::finish_sweep`]). Each reading's pings are placed at the odometry's pose of its own
//!    instant, interpolated between the odometry's samples, relative to the sweep's first reading.
//! 2. The features crate extracts what the sweep saw: regions of constant depth classified into
//!    walls, corners and posts when it was taken standing still; walls only, found under the
//!    motion along each normal, when it was taken on the move, a region as wide as a post's cone
//!    included (a hallway's side wall close abeam, [`NearRegions::AsWalls`]: a post's "wall"
//!    turns with the viewpoint and is never admitted, step 5). Such a wall is measured from the
//!    reading that faced it: the sweep's pose, then the odometry to that reading corrected by
//!    the odometry's errors in the graph, so the walls of a sweep on the move teach the graph
//!    those errors as they hold the pose.
//! 3. A pose joins the graph, predicted from the previous one by the odometry with its systematic
//!    errors as estimated so far, tied to it by an odometry factor.
//! 4. **Association.** The joint covariance of the new pose and every landmark (the columns of
//!    H⁻¹ they take) gives each observation–landmark pair its innovation covariance; pairs within
//!    the χ² gate are taken closest first, one to one, and the set as a whole must pass the joint
//!    compatibility test (Neira & Tardós 2001): while the joint innovation fails χ² of its degrees
//!    of freedom, the pair with the largest individual distance is dropped. A landmark seen again
//!    after a loop is found here, with the covariance the loop has grown: that is the loop
//!    closure, and the solve that follows carries it back along the loop.
//!
//!    A region as wide as both a post's cone and a wall's (near the sensor, or with a narrow
//!    cut-off; [`sonar_features::Observation::also_plane`]) is sighted twice, as a point and as
//!    a wall (twins): the wall is kept when both match, and a twin matched or admitted takes
//!    the other out of the sweep's sightings and of the candidates. Seen from several places a
//!    wall's twins agree as a wall (its foot moves along it) and a post's as a point.
//! 5. **Admission.** An observation matched to no landmark waits as a candidate; a later
//!    observation of the same kind from another viewpoint (at least
//!    [`SlamConfig::min_baseline_m`] or [`SlamConfig::min_baseline_deg`] away) that places the
//!    same landmark within the gate makes it a landmark, with both sightings as factors. The two
//!    placements are compared with the joint covariance of the two poses: a wall seen from the
//!    anchor and again from a pose whose heading the odometry knows poorly is gated by that
//!    pose's σ, not by √2 times it (the current pose's covariance once counted for both, and a
//!    room tour took a wall for another seen before and turned by 81°). A phantom of one sweep
//!    (a corner at the edge of a sweep taken for a wall) never anchors a pose. Nor does a wall
//!    seen only on the move from regions cut short at one end: the features take such a region
//!    for a plane placed from its natural end, and a corner or a door's edge cut short gives the
//!    same region, seen alike from nearby viewpoints. A wall needs one of its sightings to
//!    be a region seen whole, or a sweep's standing still (there the features test a plane cut
//!    short as a corner of the sweep's whole planes), or [`SlamConfig::uncertain_views`]
//!    viewpoints that agree; a pair with such a sighting passes only the tighter
//!    [`SlamConfig::uncertain_gate_chi2`]. Every candidate of another viewpoint that places the
//!    landmark alike joins it (closest first, at most one per viewpoint, the group within the
//!    joint compatibility test as in association), each with its factor.
//! 6. **Ranging on the move** ([`SlamConfig::range_pings`], on by default). Each reading of a sweep taken on the move is placed at its own
//!    instant's pose — the sweep's pose, then the odometry to that instant corrected by the
//!    odometry's errors as the graph estimates them — and its pings that face a known wall
//!    (seen in [`SlamConfig::ranging_min_sightings`] sweeps, its normal inside the specular
//!    cut-off of the ping's axis) give the distance across that wall: one range factor per
//!    reading and wall, gated against the joint covariance. So a sweep that lasts a metre or two
//!    of driving is held along its whole length, and the odometry's drift is learnt as it
//!    happens, not only between one sweep's start and the next.
//! 7. The graph is solved (Huber kernel on the landmark and range factors). **Never worse than
//!    odometry**: when the sweep's sightings and ranges raise the odometry's own χ² by more than
//!    [`SlamConfig::odometry_gate_chi2`], the odometry would have to be implausibly wrong for
//!    them: they are taken back, the sweep is placed by odometry, and the refusal is counted.
//!    So are sightings that move the sweep's pose outside the ellipse its prediction allows
//!    (the odometry from the previous pose with its errors as known so far, under the joint
//!    covariance: [`SlamConfig::pose_shift_gate_chi2`]). The rise alone misses a pull that the
//!    graph spreads over the odometry's systematic errors, each residual small: in a driven
//!    hallway at 5 % / 3°/m two phantoms admitted together moved a pose 2.7 m and turned it by
//!    60° from its prediction (χ² 104 under the prediction's covariance) for a rise of 3.9, and
//!    the run ended 6.4 m off against the odometry's 3.3 m.
//! 8. The sweep's estimate is published with its marginal covariance, and as a **fix** only when
//!    it matched a landmark and the covariance is within [`SlamConfig::fix_max_sigma_m`] and
//!    [`SlamConfig::fix_max_sigma_deg`]; otherwise "no fix", with the covariance that says why.

use nalgebra::{DMatrix, DVector, Isometry2, Matrix2, Matrix2x3, Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use sonar_common::ipc::Reading;
use sonar_features::{FeatureConfig, FeatureMap, NearRegions, OdometryErrors, Sweep, wrap_rad};

use crate::error::SlamError;
use crate::graph::{
    Graph, LandmarkKind, Measurement, SeenAfter, Var, compose, place, predict, range_to_wall,
};
use crate::odometry::{OdometryTrack, Step, random_covariance};

/// Settings of the SLAM (`[slam]` in a configuration file); every field has a default.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SlamConfig {
    /// The feature extraction's settings, and in `odometry` the odometry's error model.
    pub features: FeatureConfig,
    /// Added (in quadrature) to every observation's range σ, metres: what the features' own
    /// σ leaves out (the bearing's quantisation repeats between sweeps from one place, the
    /// echo point is not the landmark's exact point from every side).
    pub range_sigma_floor_m: f64,
    /// Added (in quadrature) to every observation's bearing σ, degrees.
    pub bearing_sigma_floor_deg: f64,
    /// Individual compatibility gate, χ² of 2 degrees of freedom (9.21: 99 %).
    pub gate_chi2: f64,
    /// Probability of the joint compatibility test (χ² of 2 per pair).
    pub joint_probability: f64,
    /// Gate of a candidate pair at admission when one of the two sightings is a wall cut short
    /// on the move (`certain` false), χ² of 2 degrees of freedom (5.99: 95 %). Such a sighting
    /// may be a corner or an edge cut short, an error its σ does not hold; under a pose
    /// covariance of 10–20 cm two different walls 45 cm and 10° apart pass the 99 % gate, and
    /// the admission turns the pose by as much (`docs/results.md`, "SLAM").
    pub uncertain_gate_chi2: f64,
    /// A landmark is admitted from sightings of this many viewpoints that agree jointly even when
    /// none of them is certain: a corner or an edge cut short moves along its wall as the
    /// viewpoint moves, and three viewpoints rarely place it alike.
    pub uncertain_views: usize,
    /// Huber threshold of a landmark factor, in σ.
    pub huber_k: f64,
    /// Two sightings are two viewpoints when their poses lie this far apart …
    pub min_baseline_m: f64,
    /// … or differ by this much in heading.
    pub min_baseline_deg: f64,
    /// A candidate not confirmed within this many sweeps is forgotten.
    pub candidate_max_age: usize,
    /// A sweep is a fix only while the largest σ of its position is within this …
    pub fix_max_sigma_m: f64,
    /// … and σ of its heading within this.
    pub fix_max_sigma_deg: f64,
    /// Largest rise of the odometry's χ² one sweep's sightings may cause (χ² of 3 degrees of
    /// freedom at 99.9 %: 16.27).
    pub odometry_gate_chi2: f64,
    /// Largest Mahalanobis distance² (3 degrees of freedom) by which one sweep's sightings may
    /// move its pose from the odometry's prediction, under the prediction's covariance (χ² at
    /// 99.9 %: 16.27). An honest prediction holds the true pose, and so any right correction,
    /// within it.
    pub pose_shift_gate_chi2: f64,
    /// The readings of a sweep taken on the move are ranged on the wall landmarks they face, each
    /// at the pose of its own instant (the sweep's pose, then the odometry to that instant
    /// corrected by the odometry's errors as the graph estimates them). On by default since
    /// 2026-12-06: over twenty layouts × five seeds of each driven tour and sensor it left fewer runs
    /// worse than the odometry (4 of 3200 against 6) and lowered most worst errors, the tours that
    /// stop to scan within ±0.5 cm (`docs/results.md`, "The ranging on the move measured again").
    pub range_pings: bool,
    /// σ of one reading's range to a wall it faces, metres: the pings of neighbouring readings
    /// hear the same stretch of wall and are not independent.
    pub ranging_sigma_m: f64,
    /// A wall landmark is ranged on once it has been seen in this many sweeps.
    pub ranging_min_sightings: u32,
    /// A ping ranges on a wall whose normal lies this far inside the specular cut-off of its
    /// axis, less 1σ of the heading (near the edge of the cone the wall may not answer).
    pub ranging_cone_margin_deg: f64,
    /// A wall seen on the move farther than this from the reading that faced it (metres; half
    /// a metre inside the SRF05's 4 m reach) was heard near the sensor's reach, where how wide a
    /// wall answers changes quickly with its range: driving towards or away from it during the
    /// sweep, its region of constant depth grows on one side, and the region's middle, the
    /// wall's bearing, lies off its normal (7–11° in an open hall, `docs/results.md`, "Open
    /// space"), which the graph would learn as the odometry's drift …
    pub near_reach_m: f64,
    /// … so its bearing σ is at least this, degrees.
    pub near_reach_bearing_sigma_deg: f64,
    /// σ of the sensor's range bias left after `[features] range_offset_m`, metres: one
    /// variable of the graph that every range shares, estimated with the poses and landmarks
    /// (a bias puts a corner or an edge farther from each viewpoint, so several viewpoints tell
    /// it; a wall seen from one side takes it up in its own place). Uncalibrated sensors are off
    /// by a detector's lateness and an arm's length, hobby sensors often by a centimetre or
    /// more, the LEGO NXT's by about 3 cm (`shared/docs/sensor-facts.md`): so 3 cm by default.
    /// 0: not estimated (the ranges taken as calibrated). Measured on `nxt`'s 3 cm
    /// (`docs/results.md`, "The range bias in the graph").
    pub range_bias_sigma_m: f64,
}

impl Default for SlamConfig {
    fn default() -> Self {
        Self {
            features: FeatureConfig::default(),
            range_sigma_floor_m: 0.01,
            bearing_sigma_floor_deg: 1.0,
            gate_chi2: 9.21,
            joint_probability: 0.99,
            uncertain_gate_chi2: 5.99,
            uncertain_views: 3,
            huber_k: 1.5,
            min_baseline_m: 0.1,
            min_baseline_deg: 10.0,
            candidate_max_age: 20,
            fix_max_sigma_m: 0.05,
            fix_max_sigma_deg: 2.0,
            odometry_gate_chi2: 16.27,
            pose_shift_gate_chi2: 16.27,
            range_pings: true,
            ranging_sigma_m: 0.04,
            ranging_min_sightings: 2,
            ranging_cone_margin_deg: 8.0,
            near_reach_m: 3.5,
            near_reach_bearing_sigma_deg: 10.0,
            range_bias_sigma_m: 0.03,
        }
    }
}

impl SlamConfig {
    /// Checks the settings.
    pub fn validate(&self) -> Result<(), SlamError> {
        let positive = [
            ("range_sigma_floor_m", self.range_sigma_floor_m),
            ("bearing_sigma_floor_deg", self.bearing_sigma_floor_deg),
            ("gate_chi2", self.gate_chi2),
            ("uncertain_gate_chi2", self.uncertain_gate_chi2),
            ("huber_k", self.huber_k),
            ("fix_max_sigma_m", self.fix_max_sigma_m),
            ("fix_max_sigma_deg", self.fix_max_sigma_deg),
            ("odometry_gate_chi2", self.odometry_gate_chi2),
            ("pose_shift_gate_chi2", self.pose_shift_gate_chi2),
            ("ranging_sigma_m", self.ranging_sigma_m),
            ("near_reach_m", self.near_reach_m),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(SlamError::Config(format!("{name} must be > 0, got {v}")));
            }
        }
        for (name, v) in [
            ("min_baseline_m", self.min_baseline_m),
            ("min_baseline_deg", self.min_baseline_deg),
            ("ranging_cone_margin_deg", self.ranging_cone_margin_deg),
            (
                "near_reach_bearing_sigma_deg",
                self.near_reach_bearing_sigma_deg,
            ),
            ("range_bias_sigma_m", self.range_bias_sigma_m),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SlamError::Config(format!("{name} must be ≥ 0, got {v}")));
            }
        }
        if self.uncertain_views < 2 {
            return Err(SlamError::Config(format!(
                "uncertain_views must be ≥ 2 (a landmark needs two viewpoints), got {}",
                self.uncertain_views
            )));
        }
        if !(self.joint_probability > 0.0 && self.joint_probability < 1.0) {
            return Err(SlamError::Config(format!(
                "joint_probability must lie in (0, 1), got {}",
                self.joint_probability
            )));
        }
        Ok(())
    }
}

/// Whether a sweep's estimate is a fix.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FixState {
    /// Matched to the map, with a covariance within the limits.
    Fix,
    /// Nothing of the map was seen: placed by odometry.
    NoLandmarks,
    /// Landmarks were seen, but the pose is still too uncertain in some direction (a featureless
    /// corridor's axis, a heading no wall fixes).
    Uncertain,
    /// The sightings would have made the odometry implausible: taken back, placed by odometry.
    Refused,
}

/// What the SLAM says about one sweep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepEstimate {
    pub sweep_id: u32,
    /// `host_stamp_ns` of its first reading: the instant the pose is of.
    pub stamp_ns: u64,
    /// The sensor's pose in the map at that instant, as estimated when the sweep was added.
    pub pose: Isometry2<f64>,
    /// Its marginal covariance (x, y, θ): m², m·rad, rad².
    pub covariance: Matrix3<f64>,
    /// The odometry's own pose at that instant.
    pub odometry: Isometry2<f64>,
    pub state: FixState,
    /// Observations the sweep's features gave.
    pub observations: usize,
    /// Of them, matched to landmarks (after the joint compatibility test) or admitted as new ones.
    pub matched: usize,
    /// Landmarks admitted by this sweep.
    pub admitted: usize,
    /// Readings ranged on a wall landmark (a sweep on the move).
    pub ranged: usize,
    /// Taken on the move (walls only).
    pub moving: bool,
}

impl SweepEstimate {
    /// Map ← odometry at the sweep's instant: what to apply to the odometry's poses until the
    /// next estimate.
    pub fn correction(&self) -> Isometry2<f64> {
        self.pose * self.odometry.inverse()
    }

    /// The covariance of [`Self::correction`]'s (x, y, θ): the pose's carried through
    /// `pose ∘ odometry⁻¹` to first order, the odometry's pose of the instant taken as given.
    pub fn correction_covariance(&self) -> Matrix3<f64> {
        let inverse = self.odometry.inverse();
        let (a, b) = (inverse.translation.x, inverse.translation.y);
        let (sin, cos) = self.pose.rotation.angle().sin_cos();
        let jacobian = Matrix3::new(
            1.0,
            0.0,
            -sin * a - cos * b,
            0.0,
            1.0,
            cos * a - sin * b,
            0.0,
            0.0,
            1.0,
        );
        jacobian * self.covariance * jacobian.transpose()
    }
}

/// One sweep of [`Slam::trajectory`]: its pose in the map as estimated now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepPose {
    pub sweep_id: u32,
    /// `host_stamp_ns` of its first reading.
    pub stamp_ns: u64,
    /// The sensor's pose in the map at that instant.
    pub pose: Isometry2<f64>,
    /// The odometry's pose at that instant.
    pub odometry: Isometry2<f64>,
}

impl SweepPose {
    /// Map ← odometry for this sweep's readings, as [`SweepEstimate::correction`].
    pub fn correction(&self) -> Isometry2<f64> {
        self.pose * self.odometry.inverse()
    }
}

/// A landmark of the map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Landmark {
    pub kind: LandmarkKind,
    /// Point: (x, y). Line: (φ, d), its normal's direction (radians) and distance from the
    /// map's origin.
    pub mean: Vector2<f64>,
    /// Covariance of `mean` (point: m²; line: (φ, d) in rad², rad·m, m²): the landmark's
    /// marginal in the joint estimate of poses and landmarks; `None` while that estimate's
    /// information is singular.
    pub covariance: Option<Matrix2<f64>>,
    pub sightings: u32,
}

#[derive(Debug, Clone, Copy)]
struct LandmarkNode {
    var: Var,
    kind: LandmarkKind,
    sightings: u32,
}

#[derive(Debug, Clone, Copy)]
struct PoseNode {
    var: Var,
    stamp_ns: u64,
    sweep_id: u32,
    /// The odometry's pose at `stamp_ns`.
    odometry: Isometry2<f64>,
}

/// An observation matched to no landmark, waiting for a second viewpoint.
#[derive(Debug, Clone)]
struct Candidate {
    pose: usize,
    sighting: Sighting,
}

/// One reading of a sweep taken on the move, for ranging on walls.
#[derive(Debug, Clone)]
struct ReadingPings {
    /// The odometry from the sweep's first reading to this one.
    steps: Vec<Step>,
    /// Its pings that heard something: bearing in the sensor's frame (rad) and range (m).
    pings: Vec<(f64, f64)>,
}

/// `pairs` (sighting, landmark) with at most one reading of each twin matched: the wall when
/// both readings of a region found a landmark (a point landmark at a wall's foot, seen again
/// from where it was first seen, matches as well as the wall does).
fn one_of_each_twin(sightings: &[Sighting], pairs: Vec<(usize, usize)>) -> Vec<(usize, usize)> {
    let walls: Vec<(u32, usize)> = pairs
        .iter()
        .map(|&(i, _)| &sightings[i])
        .filter(|s| s.kind == LandmarkKind::Line)
        .filter_map(|s| s.twin)
        .collect();
    pairs
        .into_iter()
        .filter(|&(i, _)| {
            let s = &sightings[i];
            s.kind == LandmarkKind::Line || s.twin.is_none_or(|t| !walls.contains(&t))
        })
        .collect()
}

/// One observation as the graph measures it.
#[derive(Debug, Clone)]
struct Sighting {
    kind: LandmarkKind,
    z: Measurement,
    sigma: Vector2<f64>,
    /// Its class is the features' finding, not their guess: everything a sweep standing still
    /// saw (a plane cut short there is tested as a corner of the sweep's whole planes), and the
    /// walls of a sweep on the move whose region was seen whole. A wall on the move whose region
    /// was cut short at one end may be a corner or an edge cut short ([`Observation::whole`]);
    /// two such sightings alone never make a landmark.
    ///
    /// [`Observation::whole`]: sonar_features::Observation::whole
    certain: bool,
    /// One region read two ways: a region as wide as both a post's cone and a wall's, which
    /// one viewpoint cannot tell apart, is sighted as a point and as a wall with the same twin
    /// (its sweep and region). The graph takes at most one of the two: the one that matches a
    /// landmark (the wall when both do), or the one a later viewpoint agrees with.
    twin: Option<(u32, usize)>,
    /// The odometry from the sweep's pose to where it was seen from: a wall of a sweep on the
    /// move is measured from the reading that faced it, `z` in that reading's frame. Empty: from
    /// the sweep's pose.
    after: Vec<Step>,
}

/// A reading more than this (m, degrees) from the pose of the sweep's middle reading was taken
/// on the move, and a sweep with more than [`MOVING_SHARE`] such readings was taken on the move
/// (the same rule as `sonar-fusion`'s feature tracker).
const STILL_M: f64 = 0.01;
const STILL_DEG: f64 = 0.5;
const MOVING_SHARE: f64 = 0.1;

/// The map's origin is the odometry's pose where it starts (its oldest sample kept), taken as
/// known to this (m, rad).
const ANCHOR_SIGMA: f64 = 1e-4;

/// The SLAM: feed it odometry and readings; it returns an estimate for every finished sweep.
#[derive(Debug)]
pub struct Slam {
    cfg: SlamConfig,
    extractor: FeatureMap,
    track: OdometryTrack,
    pending: Vec<Reading>,
    graph: Graph,
    calibration: Option<Var>,
    poses: Vec<PoseNode>,
    landmarks: Vec<LandmarkNode>,
    candidates: Vec<Candidate>,
    refused: u32,
    last: Option<SweepEstimate>,
    /// The pose (index into `poses`) of the latest fix, or the first: where the heading was last
    /// known, from which the published covariance's heading term beyond first order is taken.
    anchor: usize,
}

impl Slam {
    pub fn new(cfg: SlamConfig) -> Result<Self, SlamError> {
        cfg.validate()?;
        Ok(Self {
            extractor: FeatureMap::new(cfg.features)?,
            cfg,
            track: OdometryTrack::default(),
            pending: Vec::new(),
            graph: Graph::new(cfg.huber_k),
            calibration: None,
            poses: Vec::new(),
            landmarks: Vec::new(),
            candidates: Vec::new(),
            refused: 0,
            last: None,
            anchor: 0,
        })
    }

    /// The odometry's pose at `stamp_ns` (the readings' clock); `false` when refused (older than
    /// the last, or not finite).
    pub fn push_odometry(&mut self, stamp_ns: u64, pose: Isometry2<f64>) -> bool {
        self.track.push(stamp_ns, pose)
    }

    /// Adds a reading; when it starts a new sweep, the finished one is estimated first and its
    /// estimate returned.
    pub fn push_reading(&mut self, reading: &Reading) -> Option<SweepEstimate> {
        let finished = match self.pending.first() {
            Some(first) if first.sweep_id != reading.sweep_id => self.finish_sweep(),
            _ => None,
        };
        self.pending.push(*reading);
        finished
    }

    /// Estimates the pending sweep now (the scan stopped). `None` without readings or before
    /// any odometry.
    pub fn finish_sweep(&mut self) -> Option<SweepEstimate> {
        let readings = std::mem::take(&mut self.pending);
        let first = readings.first()?;
        let reference = self.track.at(first.host_stamp_ns)?;
        // Each reading at its own instant's pose relative to the first, by the odometry between
        // as reported. (Corrected by the odometry's errors as estimated so far, the driven
        // hallway's worst run at 5 % / 3°/m rose from 106 to 229 cm on the tuning split.)
        let steps: Vec<Vec<Step>> = readings
            .iter()
            .map(|r| self.track.steps(first.host_stamp_ns, r.host_stamp_ns))
            .collect();
        let placed: Vec<(Reading, Isometry2<f64>)> = readings
            .iter()
            .zip(&steps)
            .map(|(r, steps)| {
                let m = crate::odometry::corrected(steps, &Vector3::zeros());
                (*r, Isometry2::new(Vector2::new(m.x, m.y), m.z))
            })
            .collect();
        let moving = taken_on_the_move(&placed);
        let sweep =
            Sweep::from_readings_at(placed.iter().map(|(r, p)| (r, *p)), &self.cfg.features);
        let observations = if moving {
            self.extractor
                .walls_on_the_move(&placed, NearRegions::AsWalls)
        } else {
            self.extractor.observe(&sweep).1.observations
        };
        self.extractor.learn_noise(&sweep);
        let floor = Vector2::new(
            self.cfg.range_sigma_floor_m,
            self.cfg.bearing_sigma_floor_deg.to_radians(),
        );
        let sightings: Vec<Sighting> = observations
            .iter()
            .flat_map(|o| {
                let twin = o.also_plane.then_some((first.sweep_id, o.rcd));
                let mut sighting = Sighting {
                    kind: LandmarkKind::of(o.kind),
                    z: Vector2::new(o.range_m, o.bearing_deg.to_radians()),
                    sigma: Vector2::new(
                        (o.range_sigma_random_m.powi(2) + o.range_sigma_systematic_m.powi(2))
                            .sqrt(),
                        o.bearing_sigma_deg
                            .hypot(o.bearing_sigma_random_deg)
                            .to_radians(),
                    )
                    .zip_map(&floor, f64::hypot),
                    certain: !moving || o.whole,
                    twin,
                    after: Vec::new(),
                };
                if moving {
                    self.seen_on_the_move(&mut sighting, &placed, &steps);
                }
                let as_wall = twin.map(|_| Sighting {
                    kind: LandmarkKind::Line,
                    ..sighting.clone()
                });
                std::iter::once(sighting).chain(as_wall)
            })
            .collect();
        let ranged: Vec<ReadingPings> = if moving && self.cfg.range_pings {
            let late = self.cfg.features.range_offset_m;
            readings
                .iter()
                .zip(steps)
                .map(|(r, steps)| ReadingPings {
                    steps,
                    pings: Sweep::from_readings_at(
                        std::iter::once((r, Isometry2::identity())),
                        &self.cfg.features,
                    )
                    .pings()
                    .iter()
                    .filter_map(|p| Some((p.bearing_deg.to_radians(), p.range_m? - late)))
                    .collect(),
                })
                .collect()
        } else {
            Vec::new()
        };
        let estimate = self.add_sweep(
            first.sweep_id,
            first.host_stamp_ns,
            reference,
            &sightings,
            &ranged,
            moving,
        );
        self.track.forget_before(first.host_stamp_ns);
        self.last = Some(estimate);
        Some(estimate)
    }

    /// A wall of a sweep on the move, measured from the reading that faced it rather than from
    /// the sweep's first: the features bring every ping to the first reading by the odometry as
    /// reported, so the wall is moved back to the middle one of the readings aimed within the
    /// specular cut-off of its normal (`placed`: each reading at its odometry pose relative to
    /// the first; `steps`: the odometry's steps to each), and tied to the sweep's pose by those
    /// steps corrected by the odometry's errors in the graph. Its σ takes the odometry's random
    /// error over them; the systematic part is the graph's to estimate. (Before, the whole
    /// sweep's odometry error, systematic part included, was added to every wall's σ: 6 cm and
    /// 4° over a 2 m sweep at 3 % / 2°/m, as noise of its own: a wall could neither teach the
    /// graph the odometry's errors nor be corrected by them.) A wall that reading heard near the
    /// sensor's reach gets the bearing σ of [`SlamConfig::near_reach_m`].
    fn seen_on_the_move(
        &self,
        sighting: &mut Sighting,
        placed: &[(Reading, Isometry2<f64>)],
        steps: &[Vec<Step>],
    ) {
        let cutoff = self.cfg.features.echo.specular_cutoff_deg.to_radians();
        let facing: Vec<usize> = placed
            .iter()
            .enumerate()
            .filter(|(_, (r, pose))| {
                let axis = pose.rotation.angle() + f64::from(r.angle_deg).to_radians();
                wrap_rad(axis - sighting.z.y).abs() <= cutoff
            })
            .map(|(i, _)| i)
            .collect();
        let Some(after) = facing.get(facing.len() / 2).and_then(|&i| steps.get(i)) else {
            return;
        };
        let reached = crate::odometry::corrected(after, &Vector3::zeros());
        let wall = place(sighting.kind, &Vector3::zeros(), &sighting.z);
        let Some(z) = predict(sighting.kind, &reached, &wall) else {
            return;
        };
        let random = random_covariance(after, &self.cfg.features.odometry);
        let odometry = Vector2::new(
            (random[(0, 0)] + random[(1, 1)]).max(0.0).sqrt(),
            random[(2, 2)].max(0.0).sqrt(),
        );
        sighting.z = z;
        sighting.sigma = sighting.sigma.zip_map(&odometry, f64::hypot);
        if z.x > self.cfg.near_reach_m {
            let floor = self.cfg.near_reach_bearing_sigma_deg.to_radians();
            sighting.sigma.y = sighting.sigma.y.max(floor);
        }
        sighting.after = after.clone();
    }

    /// Forgets the odometry before `stamp_ns` while no sweep is pending (its readings need the
    /// odometry of their instants): a robot that drives with its sonar stopped would otherwise
    /// keep every pose. Readings stamped before `stamp_ns` are then placed at the oldest pose kept.
    pub fn forget_odometry_before(&mut self, stamp_ns: u64) {
        if self.pending.is_empty() {
            self.track.forget_before(stamp_ns);
        }
    }

    /// The latest sweep's estimate.
    pub fn last(&self) -> Option<&SweepEstimate> {
        self.last.as_ref()
    }

    /// Every sweep's pose as estimated now: later sweeps, a loop closure above all, move the
    /// earlier ones, and a map built with their first estimates should follow.
    pub fn trajectory(&self) -> Vec<SweepPose> {
        self.poses
            .iter()
            .map(|p| SweepPose {
                sweep_id: p.sweep_id,
                stamp_ns: p.stamp_ns,
                pose: self.graph.pose(p.var),
                odometry: p.odometry,
            })
            .collect()
    }

    /// Sweeps whose sightings were refused to keep the odometry plausible.
    pub fn refused(&self) -> u32 {
        self.refused
    }

    /// How many landmarks the map holds.
    pub fn landmark_count(&self) -> usize {
        self.landmarks.len()
    }

    /// The landmarks as currently estimated, with their covariances (one solve of the graph's
    /// normal equations for all of them: as costly as a sweep's own covariance, so once per
    /// sweep, not per reading).
    pub fn landmarks(&self) -> Vec<Landmark> {
        let vars: Vec<(Var, usize)> = self.landmarks.iter().map(|l| (l.var, 2)).collect();
        let joint = if vars.is_empty() {
            None
        } else {
            self.graph.covariance(&vars)
        };
        self.landmarks
            .iter()
            .enumerate()
            .map(|(i, l)| Landmark {
                kind: l.kind,
                mean: self.graph.vector2(l.var),
                covariance: joint
                    .as_ref()
                    .map(|c| c.fixed_view::<2, 2>(2 * i, 2 * i).into_owned()),
                sightings: l.sightings,
            })
            .collect()
    }

    /// The odometry's systematic errors as estimated: scale error, heading drift (rad per metre
    /// reported), turn error.
    pub fn calibration(&self) -> Option<Vector3<f64>> {
        self.calibration.map(|v| self.graph.vector3(v))
    }

    /// The sensor's range bias as estimated ([`SlamConfig::range_bias_sigma_m`]), metres: what
    /// its ranges read beyond the truth after `[features] range_offset_m`; `None` before the first
    /// sweep or when it is not estimated.
    pub fn range_bias(&self) -> Option<f64> {
        self.graph.range_bias_var().map(|_| self.graph.range_bias())
    }

    fn add_sweep(
        &mut self,
        sweep_id: u32,
        stamp_ns: u64,
        odometry: Isometry2<f64>,
        sightings: &[Sighting],
        ranged: &[ReadingPings],
        moving: bool,
    ) -> SweepEstimate {
        let pose = self.add_pose(sweep_id, stamp_ns, &odometry);
        let k = self.poses.len() - 1;
        let checkpoint = self.graph.checkpoint();
        let values = self.graph.values().to_vec();
        let (landmarks_before, candidates_before) =
            (self.landmarks.clone(), self.candidates.clone());
        let chi2_before = self.graph.odometry_chi2();

        let mut vars = vec![(pose, 3)];
        vars.extend(self.landmarks.iter().map(|l| (l.var, 2)));
        vars.extend(self.calibration.map(|c| (c, 3)));
        let joint = self.graph.covariance(&vars);
        let predicted = self.graph.vector3(pose);
        let predicted_cov = joint
            .as_ref()
            .map(|j| j.fixed_view::<3, 3>(0, 0).into_owned());
        let (matched, admitted) = match &joint {
            Some(joint) => {
                let pairs = one_of_each_twin(sightings, self.associate(pose, sightings, joint));
                let mut used = vec![false; sightings.len()];
                for &(i, _) in &pairs {
                    used[i] = true;
                }
                // A region matched one way is not sighted the other.
                let matched_twins: Vec<(u32, usize)> = pairs
                    .iter()
                    .filter_map(|&(i, _)| sightings[i].twin)
                    .collect();
                for (u, s) in used.iter_mut().zip(sightings) {
                    *u |= s.twin.is_some_and(|t| matched_twins.contains(&t));
                }
                for &(i, j) in &pairs {
                    let s = &sightings[i];
                    let seen_after = self.seen_after(&s.after);
                    let l = &mut self.landmarks[j];
                    self.graph
                        .add_landmark_factor(pose, l.var, l.kind, s.z, s.sigma, seen_after);
                    l.sightings += 1;
                }
                let unmatched: Vec<Sighting> = sightings
                    .iter()
                    .zip(&used)
                    .filter(|(_, u)| !**u)
                    .map(|(s, _)| s.clone())
                    .collect();
                let admitted = self.admit(k, &unmatched);
                (pairs.len(), admitted)
            }
            None => (0, 0),
        };
        if matched + admitted > 0 {
            self.graph.optimize();
        }
        let ranges = self.range_on_walls(pose, ranged);
        if ranges > 0 {
            self.graph.optimize();
        }
        let mut state = FixState::NoLandmarks;
        if matched + admitted + ranges > 0 {
            let rise = self.graph.odometry_chi2() - chi2_before;
            let solved = self.graph.vector3(pose);
            let turn = wrap_rad(solved.z - predicted.z);
            let (turn_sigmas, shift_chi2) = predicted_cov.map_or((f64::NAN, f64::NAN), |c| {
                let mut d = solved - predicted;
                d.z = turn;
                let chi2 = c
                    .try_inverse()
                    .map_or(f64::NAN, |inv| (d.transpose() * inv * d)[(0, 0)]);
                (turn / c[(2, 2)].max(0.0).sqrt(), chi2)
            });
            tracing::debug!(
                turn_deg = turn.to_degrees(),
                turn_sigmas,
                shift_chi2,
                sweep_id,
                matched,
                admitted,
                ranges,
                odometry_chi2_rise = rise,
                "sightings solved"
            );
            if rise > self.cfg.odometry_gate_chi2 || shift_chi2 > self.cfg.pose_shift_gate_chi2 {
                self.graph.restore(checkpoint, &values);
                self.landmarks = landmarks_before;
                self.candidates = candidates_before;
                self.refused += 1;
                state = FixState::Refused;
            } else {
                state = FixState::Fix;
            }
        }
        self.candidates
            .retain(|c| k - c.pose <= self.cfg.candidate_max_age);
        let covariance = self
            .graph
            .covariance(&[(pose, 3)])
            .map_or(Matrix3::from_diagonal_element(f64::INFINITY), |c| {
                c.fixed_view::<3, 3>(0, 0).into_owned()
            });
        if state == FixState::Fix {
            let position = covariance.fixed_view::<2, 2>(0, 0).into_owned();
            let largest = position.symmetric_eigenvalues().max().max(0.0).sqrt();
            let heading = covariance[(2, 2)].max(0.0).sqrt();
            if !(largest <= self.cfg.fix_max_sigma_m
                && heading <= self.cfg.fix_max_sigma_deg.to_radians())
            {
                state = FixState::Uncertain;
            }
        }
        if state == FixState::Fix {
            self.anchor = k;
        }
        // Published with what the heading's uncertainty does beyond first order, which the
        // graph's covariance, linear at the estimate, leaves out (nothing at a fix: its path is
        // its own pose).
        let path: Vec<Vector2<f64>> = self.poses[self.anchor.min(k)..=k]
            .iter()
            .map(|p| self.graph.pose(p.var).translation.vector)
            .collect();
        let mut covariance = covariance;
        let curvature = heading_curvature_covariance(&path, covariance[(2, 2)]);
        let mut position = covariance.fixed_view_mut::<2, 2>(0, 0);
        position += curvature;
        let (matched, admitted, ranges) = if state == FixState::Refused {
            (0, 0, 0)
        } else {
            (matched, admitted, ranges)
        };
        SweepEstimate {
            sweep_id,
            stamp_ns,
            pose: self.graph.pose(pose),
            covariance,
            odometry,
            state,
            observations: sightings
                .iter()
                .filter(|s| s.twin.is_none() || s.kind == LandmarkKind::Line)
                .count(),
            matched: matched + admitted,
            admitted,
            ranged: ranges,
            moving,
        }
    }

    /// Ranges each reading of a sweep on the move on the wall landmark its pings face, from the
    /// reading's own pose: the sweep's pose `pose` as estimated now, then the odometry to the
    /// reading corrected by the errors as estimated. A ping faces the nearest wall in front of
    /// it, seen in [`SlamConfig::ranging_min_sightings`] sweeps or more, whose normal lies within
    /// the cut-off less [`SlamConfig::ranging_cone_margin_deg`] and 1σ of the heading of the
    /// ping's axis; the pings of a reading facing one wall give one range (their median), taken
    /// when it passes the χ² gate of one degree of freedom at 99 % against the joint covariance
    /// of pose, odometry errors and wall. The number of ranges added.
    fn range_on_walls(&mut self, pose: Var, ranged: &[ReadingPings]) -> usize {
        let Some(calibration) = self.calibration.filter(|_| self.cfg.range_pings) else {
            return 0;
        };
        let walls: Vec<Var> = self
            .landmarks
            .iter()
            .filter(|l| {
                l.kind == LandmarkKind::Line && l.sightings >= self.cfg.ranging_min_sightings
            })
            .map(|l| l.var)
            .collect();
        if walls.is_empty() || ranged.is_empty() {
            return 0;
        }
        let mut vars = vec![(pose, 3), (calibration, 3)];
        vars.extend(walls.iter().map(|&w| (w, 2)));
        let Some(joint) = self.graph.covariance(&vars) else {
            return 0;
        };
        let heading_sigma = joint[(2, 2)].max(0.0).sqrt();
        let cone = (self.cfg.features.echo.specular_cutoff_deg - self.cfg.ranging_cone_margin_deg)
            .to_radians()
            - heading_sigma;
        if cone <= 0.0 {
            return 0;
        }
        let x = self.graph.vector3(pose);
        let c = self.graph.vector3(calibration);
        let errors = self.cfg.features.odometry;
        let mut added = 0;
        for reading in ranged {
            let at = compose(&x, &crate::odometry::corrected(&reading.steps, &c));
            // The pings facing each wall.
            let mut facing: Vec<(usize, Vec<f64>)> = Vec::new();
            for &(bearing, range) in &reading.pings {
                let axis = at.z + bearing;
                let nearest = walls
                    .iter()
                    .enumerate()
                    .filter_map(|(w, &var)| {
                        let wall = self.graph.vector2(var);
                        let distance = range_to_wall(&at, &wall);
                        (distance > 0.0 && wrap_rad(wall.x - axis).abs() <= cone)
                            .then_some((distance, w))
                    })
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                if let Some((_, w)) = nearest {
                    match facing.iter_mut().find(|(k, _)| *k == w) {
                        Some((_, ranges)) => ranges.push(range),
                        None => facing.push((w, vec![range])),
                    }
                }
            }
            // The odometry's random error from the sweep's pose to this reading.
            let random = random_covariance(&reading.steps, &errors);
            for (w, mut ranges) in facing {
                ranges.sort_by(f64::total_cmp);
                let range = ranges[ranges.len() / 2];
                let wall = self.graph.vector2(walls[w]);
                let n = Vector2::new(wall.x.cos(), wall.x.sin());
                // Across the wall, the odometry's random error in the frame of the sweep's pose.
                let (sin, cos) = x.z.sin_cos();
                let local = Vector2::new(cos * n.x + sin * n.y, -sin * n.x + cos * n.y);
                let odometry_var =
                    (local.transpose() * random.fixed_view::<2, 2>(0, 0) * local)[(0, 0)];
                let sigma = self.cfg.ranging_sigma_m.hypot(odometry_var.max(0.0).sqrt());
                // Jacobian of the predicted range by pose, odometry errors and wall (numerical).
                let state = |x: &Vector3<f64>, c: &Vector3<f64>, wall: &Vector2<f64>| {
                    range_to_wall(
                        &compose(x, &crate::odometry::corrected(&reading.steps, c)),
                        wall,
                    )
                };
                let predicted = state(&x, &c, &wall);
                let mut j = DVector::<f64>::zeros(joint.nrows());
                for k in 0..3 {
                    let mut moved = x;
                    moved[k] += STEP;
                    j[k] = (state(&moved, &c, &wall) - predicted) / STEP;
                    let mut moved = c;
                    moved[k] += STEP;
                    j[3 + k] = (state(&x, &moved, &wall) - predicted) / STEP;
                }
                for k in 0..2 {
                    let mut moved = wall;
                    moved[k] += STEP;
                    j[6 + 2 * w + k] = (state(&x, &c, &moved) - predicted) / STEP;
                }
                let s = (j.transpose() * &joint * &j)[(0, 0)] + sigma * sigma;
                let v = range - self.graph.range_bias() - predicted;
                if v * v <= RANGE_GATE_CHI2 * s {
                    self.graph.add_range_factor(
                        pose,
                        calibration,
                        walls[w],
                        reading.steps.clone(),
                        range,
                        sigma,
                    );
                    added += 1;
                }
            }
        }
        added
    }

    /// Adds the sweep's pose: the first anchors the map's frame at the odometry; the others are
    /// predicted by the odometry since the previous sweep, corrected by its errors as known.
    fn add_pose(&mut self, sweep_id: u32, stamp_ns: u64, odometry: &Isometry2<f64>) -> Var {
        let odo = Vector3::new(
            odometry.translation.x,
            odometry.translation.y,
            odometry.rotation.angle(),
        );
        let errors = self.cfg.features.odometry;
        let (Some(calibration), Some(previous)) = (self.calibration, self.poses.last().copied())
        else {
            if self.cfg.range_bias_sigma_m > 0.0 {
                self.graph.add_range_bias(self.cfg.range_bias_sigma_m);
            }
            let calibration = self.graph.add_variable(&[0.0; 3]);
            let prior = Matrix3::from_diagonal(&calibration_prior_sigma(&errors).map(|v| v * v));
            self.graph
                .add_prior(calibration, Vector3::zeros(), &prior, false);
            let pose = self.graph.add_variable(odo.as_slice());
            let anchor = Matrix3::from_diagonal_element(ANCHOR_SIGMA * ANCHOR_SIGMA);
            match self.track.first() {
                // A robot that drove before its first sweep: the odometry has erred since its
                // start, so the first pose is the odometry's steps from there, not the origin.
                Some((start_ns, start)) if moved(&start, odometry) => {
                    let at = Vector3::new(
                        start.translation.x,
                        start.translation.y,
                        start.rotation.angle(),
                    );
                    let origin = self.graph.add_variable(at.as_slice());
                    self.graph.add_prior(origin, at, &anchor, true);
                    let steps = self.track.steps(start_ns, stamp_ns);
                    let covariance = random_covariance(&steps, &errors);
                    self.graph
                        .add_odometry(origin, pose, calibration, steps, &covariance);
                }
                _ => {
                    self.graph.add_prior(pose, odo, &anchor, true);
                }
            }
            self.calibration = Some(calibration);
            self.poses.push(PoseNode {
                var: pose,
                stamp_ns,
                sweep_id,
                odometry: *odometry,
            });
            return pose;
        };
        let steps = self.track.steps(previous.stamp_ns, stamp_ns);
        let motion = crate::odometry::corrected(&steps, &self.graph.vector3(calibration));
        let predicted = compose(&self.graph.vector3(previous.var), &motion);
        let pose = self.graph.add_variable(predicted.as_slice());
        let covariance = random_covariance(&steps, &errors);
        self.graph
            .add_odometry(previous.var, pose, calibration, steps, &covariance);
        self.poses.push(PoseNode {
            var: pose,
            stamp_ns,
            sweep_id,
            odometry: *odometry,
        });
        pose
    }

    /// How the graph ties a sighting seen `after` the odometry's steps from its sweep's pose.
    fn seen_after(&self, after: &[Step]) -> Option<SeenAfter> {
        let calibration = self.calibration?;
        (!after.is_empty()).then(|| SeenAfter {
            calibration,
            steps: after.to_vec(),
        })
    }

    /// The odometry's errors as estimated now (zero before the first sweep).
    fn calibration_now(&self) -> Vector3<f64> {
        self.calibration().unwrap_or_else(Vector3::zeros)
    }

    /// Pairs (sighting, landmark) by individual compatibility, nearest first and one to one, then
    /// pruned until the set is jointly compatible. `joint` is the covariance of the pose (first
    /// 3), every landmark (2 each, in order) and the odometry's errors (last 3: a sighting on
    /// the move is seen from a pose they move).
    fn associate(
        &self,
        pose: Var,
        sightings: &[Sighting],
        joint: &DMatrix<f64>,
    ) -> Vec<(usize, usize)> {
        let x = self.graph.vector3(pose);
        let c = self.calibration_now();
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (i, s) in sightings.iter().enumerate() {
            for (j, l) in self.landmarks.iter().enumerate() {
                if l.kind != s.kind {
                    continue;
                }
                let Some(d2) = self.innovation_distance(&x, &c, &[(i, j)], sightings, joint) else {
                    continue;
                };
                if d2 <= self.cfg.gate_chi2 {
                    pairs.push((d2, i, j));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut taken: Vec<(f64, usize, usize)> = Vec::new();
        for p in pairs {
            if !taken.iter().any(|t| t.1 == p.1 || t.2 == p.2) {
                taken.push(p);
            }
        }
        while !taken.is_empty() && !self.jointly_compatible(&x, &c, sightings, &taken, joint) {
            // The least compatible pair goes first.
            let worst = taken
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.0.total_cmp(&b.1.0))
                .map(|(k, _)| k);
            if let Some(k) = worst {
                taken.remove(k);
            }
        }
        taken.into_iter().map(|(_, i, j)| (i, j)).collect()
    }

    /// Whether the pairs' joint innovation passes χ² of its degrees of freedom at
    /// [`SlamConfig::joint_probability`], with the cross-covariances between landmarks, pose and
    /// the odometry's errors.
    fn jointly_compatible(
        &self,
        x: &Vector3<f64>,
        c: &Vector3<f64>,
        sightings: &[Sighting],
        pairs: &[(f64, usize, usize)],
        joint: &DMatrix<f64>,
    ) -> bool {
        let pairs: Vec<(usize, usize)> = pairs.iter().map(|&(_, i, j)| (i, j)).collect();
        self.innovation_distance(x, c, &pairs, sightings, joint)
            .is_some_and(|d2| d2 <= chi2_quantile(2 * pairs.len(), self.cfg.joint_probability))
    }

    /// The Mahalanobis distance² of the joint innovation of `pairs` (sighting, landmark) against
    /// `joint` (as in [`Self::associate`]); `None` when a prediction is undefined or the
    /// innovation's covariance singular.
    fn innovation_distance(
        &self,
        x: &Vector3<f64>,
        c: &Vector3<f64>,
        pairs: &[(usize, usize)],
        sightings: &[Sighting],
        joint: &DMatrix<f64>,
    ) -> Option<f64> {
        let m = pairs.len();
        let n = joint.nrows();
        let mut h = DMatrix::zeros(2 * m, n);
        let mut v = DVector::zeros(2 * m);
        let mut r = DMatrix::zeros(2 * m, 2 * m);
        for (row, &(i, j)) in pairs.iter().enumerate() {
            let s = &sightings[i];
            let l = self.graph.vector2(self.landmarks[j].var);
            let i = innovation(s, self.graph.range_bias(), x, c, &l)?;
            h.view_mut((2 * row, 0), (2, 3)).copy_from(&i.by_pose);
            h.view_mut((2 * row, 3 + 2 * j), (2, 2))
                .copy_from(&i.by_landmark);
            if self.calibration.is_some() {
                h.view_mut((2 * row, n - 3), (2, 3))
                    .copy_from(&i.by_calibration);
            }
            v.rows_mut(2 * row, 2).copy_from(&i.v);
            r[(2 * row, 2 * row)] = s.sigma.x * s.sigma.x;
            r[(2 * row + 1, 2 * row + 1)] = s.sigma.y * s.sigma.y;
        }
        stacked_distance(&h, joint, r, &v)
    }

    /// Admits landmarks seen a second time: each sighting against the candidates of other
    /// viewpoints, the two placements compared with the joint covariance of the two poses and
    /// the odometry's errors (a candidate seen from the map's anchor is as sure as its sighting;
    /// two poses on one stretch of odometry share most of their error; a wall seen on the move is
    /// placed from where the odometry's errors put the reading that faced it); the candidates
    /// that agree ([`Self::agreeing_candidates`]) make a landmark with it when one of them is
    /// [`Sighting::certain`] or they come from [`SlamConfig::uncertain_views`] viewpoints; the
    /// rest become candidates. The number admitted.
    fn admit(&mut self, k: usize, unmatched: &[Sighting]) -> usize {
        let pose = self.poses[k].var;
        let x = self.graph.vector3(pose);
        let calibration = self.calibration_now();
        // The poses the candidates were seen from, after this one, then the odometry's errors,
        // in the joint covariance.
        let mut seen_from: Vec<usize> = self
            .candidates
            .iter()
            .map(|c| c.pose)
            .filter(|&p| p != k)
            .collect();
        seen_from.sort_unstable();
        seen_from.dedup();
        let mut vars = vec![(pose, 3)];
        vars.extend(seen_from.iter().map(|&p| (self.poses[p].var, 3)));
        vars.extend(self.calibration.map(|c| (c, 3)));
        let joint = if seen_from.is_empty() {
            None
        } else {
            self.graph.covariance(&vars)
        };
        let mut admitted = 0;
        let mut admitted_twins = Vec::new();
        for s in unmatched {
            if s.twin.is_some_and(|t| admitted_twins.contains(&t)) {
                continue;
            }
            let here = placement(s, self.graph.range_bias(), &x, &calibration);
            let group = joint
                .as_ref()
                .map(|joint| self.agreeing_candidates(s, &here, &calibration, &seen_from, joint))
                .unwrap_or_default();
            let certain = usize::from(s.certain)
                + group
                    .iter()
                    .filter(|&&ci| self.candidates[ci].sighting.certain)
                    .count();
            let views = 1 + group.len();
            let enough = views >= 2 && certain >= 1 || views >= self.cfg.uncertain_views;
            if !enough {
                self.candidates.push(Candidate {
                    pose: k,
                    sighting: s.clone(),
                });
                continue;
            }
            let var = self.graph.add_variable(here.at.as_slice());
            let mut group = group;
            group.sort_unstable_by(|a, b| b.cmp(a));
            let mut settled: Vec<(u32, usize)> = s.twin.into_iter().collect();
            for ci in group {
                let c = self.candidates.remove(ci);
                settled.extend(c.sighting.twin);
                self.graph.add_landmark_factor(
                    self.poses[c.pose].var,
                    var,
                    c.sighting.kind,
                    c.sighting.z,
                    c.sighting.sigma,
                    self.seen_after(&c.sighting.after),
                );
            }
            self.graph.add_landmark_factor(
                pose,
                var,
                s.kind,
                s.z,
                s.sigma,
                self.seen_after(&s.after),
            );
            self.landmarks.push(LandmarkNode {
                var,
                kind: s.kind,
                sightings: u32::try_from(views).unwrap_or(u32::MAX),
            });
            // The other readings of the regions now settled are no longer candidates.
            self.candidates
                .retain(|c| c.sighting.twin.is_none_or(|t| !settled.contains(&t)));
            admitted_twins.extend(settled);
            admitted += 1;
        }
        admitted
    }

    /// The candidates that place the landmark of `s` (placed at `here`) where it does, at most
    /// one from each other viewpoint: each within the gate against the joint covariance `joint`
    /// of this pose, the poses `seen_from` and the odometry's errors, and all of them together
    /// within χ² of their degrees of freedom at [`SlamConfig::joint_probability`] (closest first;
    /// one that breaks the group's agreement is left out). Indices into the candidates.
    fn agreeing_candidates(
        &self,
        s: &Sighting,
        here: &Placement,
        calibration: &Vector3<f64>,
        seen_from: &[usize],
        joint: &DMatrix<f64>,
    ) -> Vec<usize> {
        let n = joint.nrows();
        let k = self.poses.len() - 1;
        // Each pair's difference of placements and how it moves with the joint state.
        let mut pairs: Vec<Agreement> = Vec::new();
        for (ci, c) in self.candidates.iter().enumerate() {
            if c.sighting.kind != s.kind || c.pose == k {
                continue;
            }
            let xc = self.graph.vector3(self.poses[c.pose].var);
            let there = placement(&c.sighting, self.graph.range_bias(), &xc, calibration);
            let (a, b) = (here.from, there.from);
            let apart = Vector2::new(b.x - a.x, b.y - a.y).norm() >= self.cfg.min_baseline_m
                || wrap_rad(b.z - a.z).abs() >= self.cfg.min_baseline_deg.to_radians();
            if !apart {
                continue;
            }
            let Ok(at) = seen_from.binary_search(&c.pose) else {
                continue;
            };
            let mut d = here.at - there.at;
            if s.kind == LandmarkKind::Line {
                d.x = wrap_rad(d.x);
            }
            let mut by = DMatrix::<f64>::zeros(2, n);
            by.view_mut((0, 0), (2, 3)).copy_from(&here.by_pose);
            by.view_mut((0, 3 + 3 * at), (2, 3))
                .copy_from(&(-there.by_pose));
            if self.calibration.is_some() {
                by.view_mut((0, n - 3), (2, 3))
                    .copy_from(&(here.by_calibration - there.by_calibration));
            }
            let mut pair = Agreement {
                d2: f64::NAN,
                candidate: ci,
                d,
                by,
                there: there.sighting,
            };
            let Some(d2) = group_distance(&[&pair], &here.sighting, joint) else {
                continue;
            };
            pair.d2 = d2;
            let gate = if s.certain && c.sighting.certain {
                self.cfg.gate_chi2
            } else {
                self.cfg.uncertain_gate_chi2
            };
            if d2 <= gate {
                pairs.push(pair);
            }
        }
        pairs.sort_by(|a, b| a.d2.total_cmp(&b.d2));
        let mut group: Vec<&Agreement> = Vec::new();
        for p in &pairs {
            let pose = self.candidates[p.candidate].pose;
            if group
                .iter()
                .any(|g| self.candidates[g.candidate].pose == pose)
            {
                continue;
            }
            group.push(p);
            let agree = group_distance(&group, &here.sighting, joint)
                .is_some_and(|d2| d2 <= chi2_quantile(2 * group.len(), self.cfg.joint_probability));
            if !agree {
                group.pop();
            }
        }
        group.into_iter().map(|g| g.candidate).collect()
    }
}

/// A candidate that places a sighting's landmark alike ([`Slam::agreeing_candidates`]).
struct Agreement {
    /// Its Mahalanobis distance², alone.
    d2: f64,
    /// Its index among the candidates.
    candidate: usize,
    /// The sighting's placement less the candidate's.
    d: Vector2<f64>,
    /// ∂d/∂ the joint state (this pose, the candidates' poses, the odometry's errors).
    by: DMatrix<f64>,
    /// The candidate's placement's covariance from its own σ.
    there: Matrix2<f64>,
}

/// The Mahalanobis distance² of the stacked differences of placements `pairs`, against the joint
/// covariance of the state and `here`, the covariance of the sighting's own placement (shared by
/// every difference). `None` when the covariance is singular.
fn group_distance(pairs: &[&Agreement], here: &Matrix2<f64>, joint: &DMatrix<f64>) -> Option<f64> {
    let m = pairs.len();
    let n = joint.nrows();
    let mut by = DMatrix::<f64>::zeros(2 * m, n);
    let mut d = DVector::<f64>::zeros(2 * m);
    let mut r = DMatrix::<f64>::zeros(2 * m, 2 * m);
    for (i, pair) in pairs.iter().enumerate() {
        by.view_mut((2 * i, 0), (2, n)).copy_from(&pair.by);
        d.rows_mut(2 * i, 2).copy_from(&pair.d);
        for j in 0..m {
            r.view_mut((2 * i, 2 * j), (2, 2)).copy_from(here);
        }
        let own = r.fixed_view::<2, 2>(2 * i, 2 * i) + pair.there;
        r.view_mut((2 * i, 2 * i), (2, 2)).copy_from(&own);
    }
    stacked_distance(&by, joint, r, &d)
}

/// The Mahalanobis distance² of `v`, whose covariance is `by` · `joint` · `by`ᵀ + `r`; `None`
/// when that is singular.
fn stacked_distance(
    by: &DMatrix<f64>,
    joint: &DMatrix<f64>,
    r: DMatrix<f64>,
    v: &DVector<f64>,
) -> Option<f64> {
    let inv = (by * joint * by.transpose() + r).try_inverse()?;
    Some((v.transpose() * inv * v)[(0, 0)])
}

/// Step of the numerical Jacobians of a measurement.
const STEP: f64 = 1e-7;

/// χ² of one degree of freedom at 99 %: the gate of a reading's range to a wall.
const RANGE_GATE_CHI2: f64 = 6.63;

/// Where `s` was seen from: the sweep's pose `x`, or the odometry's steps after it corrected by
/// the errors `c`.
fn viewpoint(s: &Sighting, x: &Vector3<f64>, c: &Vector3<f64>) -> Vector3<f64> {
    if s.after.is_empty() {
        *x
    } else {
        compose(x, &crate::odometry::corrected(&s.after, c))
    }
}

/// A sighting's innovation against a landmark, and how the prediction moves with the state.
struct Innovation {
    /// z − h(x, c, l).
    v: Vector2<f64>,
    /// ∂h/∂x, the sweep's pose.
    by_pose: Matrix2x3<f64>,
    /// ∂h/∂l.
    by_landmark: Matrix2<f64>,
    /// ∂h/∂c, the odometry's errors: zero but on the move.
    by_calibration: Matrix2x3<f64>,
}

/// Innovation z − h(x, c, l) of `s` against a landmark at `l` seen from the sweep's pose `x`
/// with the odometry's errors `c`, its range less the range bias `bias` as estimated so far, with
/// the Jacobians of h with respect to the pose, the landmark and the errors; `None` when h is
/// undefined (a wall from behind). (The bias is taken as known: its σ is not in the gates.)
fn innovation(
    s: &Sighting,
    bias: f64,
    x: &Vector3<f64>,
    c: &Vector3<f64>,
    l: &Vector2<f64>,
) -> Option<Innovation> {
    let h = |x: &Vector3<f64>, c: &Vector3<f64>, l: &Vector2<f64>| {
        predict(s.kind, &viewpoint(s, x, c), l)
    };
    let at = h(x, c, l)?;
    let derivative = |moved: Option<Measurement>| {
        moved.map(|m| {
            let mut d = m - at;
            d.y = wrap_rad(d.y);
            d / STEP
        })
    };
    let mut hx = Matrix2x3::zeros();
    let mut hc = Matrix2x3::zeros();
    for k in 0..3 {
        let mut moved = *x;
        moved[k] += STEP;
        hx.set_column(k, &derivative(h(&moved, c, l))?);
        if !s.after.is_empty() {
            let mut moved = *c;
            moved[k] += STEP;
            hc.set_column(k, &derivative(h(x, &moved, l))?);
        }
    }
    let mut hl = Matrix2::zeros();
    for k in 0..2 {
        let mut moved = *l;
        moved[k] += STEP;
        hl.set_column(k, &derivative(h(x, c, &moved))?);
    }
    let mut v = s.z - Vector2::new(bias, 0.0) - at;
    v.y = wrap_rad(v.y);
    Some(Innovation {
        v,
        by_pose: hx,
        by_landmark: hl,
        by_calibration: hc,
    })
}

/// The position covariance a heading error adds beyond first order, which a covariance linear
/// at the estimate leaves out: with the heading off by `u·δ` at the fraction `u` of the way along
/// `path` (the estimated positions from where the heading was last known to now; a drift per
/// metre grows so), δ ~ N(0, `heading_var`), the position is off by Σ (R(u·δ) − I)·s over the
/// path's steps s. Its first-order part, the lateral error, is the graph's; the rest (to second
/// order −½δ²·Σu²·s, the way shortened as it bends) is returned as its second moment about zero,
/// E[r·rᵀ] over δ by Gauss–Hermite quadrature ([`HERMITE_NODES`] nodes). Along a straight path
/// of length L it is L²σ⁴/12 along the way to leading order: 0.7 m of σ for 20 m at σ = 20°,
/// 4.4 m at 50°, where the linear ellipse left 20 m at 50° uncovered by as much
/// (`docs/results.md`, issue 25, "Open space, second order").
fn heading_curvature_covariance(path: &[Vector2<f64>], heading_var: f64) -> Matrix2<f64> {
    let lengths: Vec<f64> = path.windows(2).map(|w| (w[1] - w[0]).norm()).collect();
    let total: f64 = lengths.iter().sum();
    if !(total > 0.0 && heading_var.is_finite() && heading_var > 0.0) {
        return Matrix2::zeros();
    }
    let sigma = heading_var.sqrt();
    let mut second_moment = Matrix2::zeros();
    for &(node, weight) in hermite_rule() {
        let delta = sigma * node;
        let mut along = 0.0;
        let mut beyond_linear = Vector2::zeros();
        for (w, length) in path.windows(2).zip(&lengths) {
            let step = w[1] - w[0];
            let turn = (along + 0.5 * length) / total * delta;
            let (sin, cos) = turn.sin_cos();
            // R(turn)·s − s − turn·J·s, J the quarter turn.
            beyond_linear += Vector2::new(
                (cos - 1.0) * step.x - (sin - turn) * step.y,
                (sin - turn) * step.x + (cos - 1.0) * step.y,
            );
            along += length;
        }
        second_moment += beyond_linear * beyond_linear.transpose() * weight;
    }
    second_moment
}

/// Nodes of the Gauss–Hermite rule of [`heading_curvature_covariance`]: exact for polynomials of
/// δ up to degree 39, so for the expansion of its rotations far beyond the fourth order at the
/// headings σ a dead-reckoned sweep reaches (the third order and up matter past about 50°).
const HERMITE_NODES: usize = 20;

/// The probabilists' Gauss–Hermite rule of [`HERMITE_NODES`] nodes, (node, weight) with weights
/// summing to 1, so that E[f(x)] for x ~ N(0, 1) ≈ Σ weight·f(node): the eigenvalues of the
/// Jacobi matrix of the Hermite polynomials (Golub–Welsch), computed once.
fn hermite_rule() -> &'static [(f64, f64)] {
    static RULE: std::sync::OnceLock<Vec<(f64, f64)>> = std::sync::OnceLock::new();
    RULE.get_or_init(|| {
        let n = HERMITE_NODES;
        let jacobi = DMatrix::from_fn(n, n, |i, j| {
            if i.abs_diff(j) == 1 {
                (i.max(j) as f64).sqrt()
            } else {
                0.0
            }
        });
        let eigen = jacobi.symmetric_eigen();
        (0..n)
            .map(|k| (eigen.eigenvalues[k], eigen.eigenvectors[(0, k)].powi(2)))
            .collect()
    })
}

/// σ of the odometry's systematic errors before any sweep: scale error, drift (rad per metre),
/// turn error.
fn calibration_prior_sigma(errors: &OdometryErrors) -> Vector3<f64> {
    Vector3::new(
        errors.scale_sigma,
        errors.drift_sigma_deg_per_m.to_radians(),
        errors.turn_sigma,
    )
}

/// Where a sighting puts its landmark, and how that place moves with the pose it was seen from.
struct Placement {
    at: Vector2<f64>,
    /// The pose it was seen from (see [`viewpoint`]).
    from: Vector3<f64>,
    /// ∂at/∂pose, the sweep's pose.
    by_pose: Matrix2x3<f64>,
    /// ∂at/∂(the odometry's errors): zero but on the move.
    by_calibration: Matrix2x3<f64>,
    /// at's covariance from the sighting's own σ.
    sighting: Matrix2<f64>,
}

/// Where `s`, seen from the sweep's pose `x` with the odometry's errors `c`, its range less the
/// range bias `bias` as estimated so far, puts its landmark.
fn placement(s: &Sighting, bias: f64, x: &Vector3<f64>, c: &Vector3<f64>) -> Placement {
    let z = s.z - Vector2::new(bias, 0.0);
    let from = viewpoint(s, x, c);
    let at = place(s.kind, &from, &z);
    let derivative = |moved: Vector2<f64>| {
        let mut d = moved - at;
        if s.kind == LandmarkKind::Line {
            d.x = wrap_rad(d.x);
        }
        d / STEP
    };
    let mut by_pose = Matrix2x3::zeros();
    let mut by_calibration = Matrix2x3::zeros();
    for k in 0..3 {
        let mut moved = *x;
        moved[k] += STEP;
        by_pose.set_column(k, &derivative(place(s.kind, &viewpoint(s, &moved, c), &z)));
        if !s.after.is_empty() {
            let mut moved = *c;
            moved[k] += STEP;
            by_calibration.set_column(k, &derivative(place(s.kind, &viewpoint(s, x, &moved), &z)));
        }
    }
    let mut jz = Matrix2::zeros();
    for k in 0..2 {
        let mut moved = z;
        moved[k] += STEP;
        jz.set_column(k, &derivative(place(s.kind, &from, &moved)));
    }
    let r = Matrix2::from_diagonal(&s.sigma.map(|v| v * v));
    Placement {
        at,
        from,
        by_pose,
        by_calibration,
        sighting: jz * r * jz.transpose(),
    }
}

/// Whether more than [`MOVING_SHARE`] of the readings were taken away from the pose of the middle
/// one.
/// Whether `to` lies more than [`STILL_M`] or [`STILL_DEG`] from `from`.
fn moved(from: &Isometry2<f64>, to: &Isometry2<f64>) -> bool {
    let d = from.inverse() * to;
    d.translation.vector.norm() > STILL_M || d.rotation.angle().abs() > STILL_DEG.to_radians()
}

fn taken_on_the_move(placed: &[(Reading, Isometry2<f64>)]) -> bool {
    let Some((_, middle)) = placed.get(placed.len() / 2) else {
        return false;
    };
    let away = placed.iter().filter(|(_, p)| moved(middle, p)).count();
    away as f64 > MOVING_SHARE * placed.len() as f64
}

/// The `p` quantile of χ² with `k` degrees of freedom (Wilson–Hilferty; within 1 % from 2
/// degrees of freedom up at the probabilities used here).
pub fn chi2_quantile(k: usize, p: f64) -> f64 {
    let k = k.max(1) as f64;
    let z = normal_quantile(p);
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + z * a.sqrt()).powi(3)
}

/// The standard normal's `p` quantile (Acklam's rational approximation, relative error < 1.2e-9).
fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.38357751867269e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let p = p.clamp(1e-12, 1.0 - 1e-12);
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_heading_term_is_the_second_moment_a_linear_covariance_leaves_out() {
        // A straight path of 20 m along +x in 200 steps, the heading off by u·δ at the fraction
        // u of the way, δ ~ N(0, σ²): the position error's part beyond first order, integrated
        // over δ (a fine grid weighted by the normal density), against the formula.
        let steps = 200;
        let path: Vec<Vector2<f64>> = (0..=steps)
            .map(|k| Vector2::new(20.0 * k as f64 / steps as f64, 0.0))
            .collect();
        for sigma in [0.1_f64, 0.2, 0.6, 1.0] {
            let mut second_moment = Matrix2::zeros();
            let n = 4001;
            for i in 0..n {
                let delta = sigma * (-8.0 + 16.0 * i as f64 / (n - 1) as f64);
                let weight = (-0.5 * (delta / sigma).powi(2)).exp()
                    / (sigma * (2.0 * std::f64::consts::PI).sqrt())
                    * (16.0 * sigma / (n - 1) as f64);
                let mut beyond_linear = Vector2::zeros();
                for (k, w) in path.windows(2).enumerate() {
                    let step = w[1] - w[0];
                    let turn = (k as f64 + 0.5) / steps as f64 * delta;
                    let (sin, cos) = turn.sin_cos();
                    let exact =
                        Vector2::new(cos * step.x - sin * step.y, sin * step.x + cos * step.y);
                    let linear = step + Vector2::new(-step.y, step.x) * turn;
                    beyond_linear += exact - linear;
                }
                second_moment += beyond_linear * beyond_linear.transpose() * weight;
            }
            let quadrature = heading_curvature_covariance(&path, sigma * sigma);
            for (i, j) in [(0, 0), (1, 1)] {
                assert!(
                    (second_moment[(i, j)] / quadrature[(i, j)] - 1.0).abs() < 1e-3,
                    "σ {sigma}: {second_moment} against {quadrature}"
                );
            }
            // Along the path, L²σ⁴/12 to leading order; across it the third order, smaller.
            let leading = 20.0_f64.powi(2) * sigma.powi(4) / 12.0;
            if sigma <= 0.2 {
                assert!(
                    (quadrature[(0, 0)] / leading - 1.0).abs() < 0.1,
                    "{quadrature}"
                );
            }
            assert!(quadrature[(1, 1)] < quadrature[(0, 0)]);
        }
        let rule = hermite_rule();
        let moment = |k: i32| rule.iter().map(|(x, w)| w * x.powi(k)).sum::<f64>();
        assert!((moment(0) - 1.0).abs() < 1e-12 && (moment(2) - 1.0).abs() < 1e-9);
        assert!((moment(4) - 3.0).abs() < 1e-9 && (moment(8) - 105.0).abs() < 1e-6);
        // No heading uncertainty, or no way travelled: nothing added.
        assert_eq!(heading_curvature_covariance(&path, 0.0), Matrix2::zeros());
        assert_eq!(
            heading_curvature_covariance(&[Vector2::zeros(); 3], 0.5),
            Matrix2::zeros()
        );
    }

    /// Odometry is forgotten only while no sweep is pending: a pending sweep's readings keep the
    /// poses of their instants.
    #[test]
    fn odometry_is_forgotten_only_while_no_sweep_is_pending() {
        let odometry_at = |pending: bool| {
            let mut slam = Slam::new(SlamConfig::default()).unwrap_or_else(|e| panic!("{e}"));
            let reading = Reading {
                host_stamp_ns: 1_500_000_000,
                angle_deg: 0.0,
                distance_m: 1.0,
                ..Reading::default()
            };
            if pending {
                assert!(slam.push_reading(&reading).is_none());
            }
            for k in 0..=4u32 {
                let pose = Isometry2::new(Vector2::new(f64::from(k), 0.0), 0.0);
                assert!(slam.push_odometry(u64::from(k) * 1_000_000_000, pose));
            }
            slam.forget_odometry_before(3_000_000_000);
            if !pending {
                assert!(slam.push_reading(&reading).is_none());
            }
            slam.finish_sweep()
                .map(|e| e.odometry.translation.x)
                .unwrap_or(f64::NAN)
        };
        // Pending: the reading's own instant, between the poses at 1 s and 2 s.
        assert!((odometry_at(true) - 1.5).abs() < 1e-9);
        // Nothing pending: forgotten up to the pose at 3 s, the oldest kept.
        assert!((odometry_at(false) - 3.0).abs() < 1e-9);
    }

    /// The correction's covariance equals the spread of corrections computed from poses drawn
    /// along each axis of the pose's covariance (first order: small σ, central differences).
    #[test]
    fn the_correction_covariance_is_the_poses_carried_through_the_product() {
        let pose = Isometry2::new(Vector2::new(2.0, -1.0), 0.7);
        let odometry = Isometry2::new(Vector2::new(1.5, 0.4), -0.3);
        let covariance = Matrix3::new(4e-4, 1e-4, 2e-5, 1e-4, 9e-4, -3e-5, 2e-5, -3e-5, 1e-4);
        let estimate = SweepEstimate {
            sweep_id: 1,
            stamp_ns: 0,
            pose,
            covariance,
            odometry,
            state: FixState::Fix,
            observations: 0,
            matched: 0,
            admitted: 0,
            ranged: 0,
            moving: false,
        };
        let as_vector =
            |t: &Isometry2<f64>| Vector3::new(t.translation.x, t.translation.y, t.rotation.angle());
        // Numerical Jacobian of the correction with respect to the pose's (x, y, θ).
        let h = 1e-6;
        let mut jacobian = Matrix3::zeros();
        for k in 0..3 {
            let mut step = Vector3::zeros();
            step[k] = h;
            let moved = |sign: f64| {
                let v = as_vector(&pose) + step * sign;
                Isometry2::new(Vector2::new(v.x, v.y), v.z) * odometry.inverse()
            };
            let diff = as_vector(&moved(1.0)) - as_vector(&moved(-1.0));
            jacobian.set_column(k, &(diff / (2.0 * h)));
        }
        let expected = jacobian * covariance * jacobian.transpose();
        let got = estimate.correction_covariance();
        assert!(
            (got - expected).abs().max() < 1e-9,
            "got {got}, expected {expected}"
        );
        // The correction itself maps the odometry's pose onto the map's.
        let placed = estimate.correction() * odometry;
        assert!((as_vector(&placed) - as_vector(&pose)).abs().max() < 1e-12);
    }

    /// A corridor x ∈ [−1, 7] between walls y = ±0.6 with end walls, and posts.
    const WALLS: [(f64, f64); 4] = [
        (std::f64::consts::FRAC_PI_2, 0.6),
        (-std::f64::consts::FRAC_PI_2, 0.6),
        (0.0, 7.0),
        (std::f64::consts::PI, 1.0),
    ];
    const POSTS: [(f64, f64); 3] = [(1.0, 0.4), (3.0, -0.4), (5.0, 0.4)];

    /// What a sensor at `x` sees: every wall, and the posts within 2.5 m, exactly.
    fn seen(x: &Vector3<f64>) -> Vec<Sighting> {
        let sigma = Vector2::new(0.01, 1.0_f64.to_radians());
        let walls = WALLS.iter().filter_map(|&(phi, d)| {
            predict(LandmarkKind::Line, x, &Vector2::new(phi, d)).map(|z| Sighting {
                kind: LandmarkKind::Line,
                z,
                sigma,
                certain: true,
                twin: None,
                after: Vec::new(),
            })
        });
        let posts = POSTS.iter().filter_map(|&(px, py)| {
            let z = predict(LandmarkKind::Point, x, &Vector2::new(px, py))?;
            (z.x < 2.5).then_some(Sighting {
                kind: LandmarkKind::Point,
                z,
                sigma,
                certain: true,
                twin: None,
                after: Vec::new(),
            })
        });
        walls.chain(posts).collect()
    }

    /// Drives along the corridor in 0.5 m legs, odometry 3 % long with 2°/m of drift, a sweep at
    /// each stop, whose sightings `look` makes from the stop's index and what is [`seen`] there;
    /// returns the estimates and the true poses.
    fn tour(
        slam: &mut Slam,
        legs: usize,
        look: impl Fn(usize, Vec<Sighting>) -> Vec<Sighting>,
    ) -> Vec<(SweepEstimate, Vector3<f64>)> {
        let (a, b) = (0.03, 2.0_f64.to_radians());
        let mut truth = Vector3::<f64>::zeros();
        let mut odo = truth;
        let mut stamp = 0;
        let mut out = Vec::new();
        for k in 0..=legs {
            if k > 0 {
                for _ in 0..50 {
                    truth.x += 0.01;
                    let reported = 0.01 * (1.0 + a);
                    let turn = b * reported;
                    odo.x += reported * odo.z.cos();
                    odo.y += reported * odo.z.sin();
                    odo.z += turn;
                    stamp += 1000;
                    slam.push_odometry(stamp, Isometry2::new(Vector2::new(odo.x, odo.y), odo.z));
                }
            } else {
                slam.push_odometry(stamp, Isometry2::identity());
            }
            let sightings = look(k, seen(&truth));
            let odometry = Isometry2::new(Vector2::new(odo.x, odo.y), odo.z);
            let estimate = slam.add_sweep(k as u32, stamp, odometry, &sightings, &[], false);
            out.push((estimate, truth));
        }
        out
    }

    /// The estimate's error against `truth` under its own covariance (3 degrees of freedom).
    fn nees(e: &SweepEstimate, truth: &Vector3<f64>) -> f64 {
        let d = Vector3::new(
            e.pose.translation.x - truth.x,
            e.pose.translation.y - truth.y,
            wrap_rad(e.pose.rotation.angle() - truth.z),
        );
        (d.transpose() * e.covariance.try_inverse().unwrap() * d)[(0, 0)]
    }

    fn error(e: &SweepEstimate, truth: &Vector3<f64>) -> (f64, f64) {
        let p = e.pose;
        (
            (p.translation.vector - Vector2::new(truth.x, truth.y)).norm(),
            wrap_rad(p.rotation.angle() - truth.z).abs().to_degrees(),
        )
    }

    /// The map's origin is where the odometry starts: a robot that drove 3 m (odometry 3 %
    /// long, 2°/m of drift) before its first sweep has that sweep's pose as uncertain as the
    /// odometry's errors since the start, with the truth inside its 95 % ellipse; a robot that
    /// stood still has it exact (before, both were exact: the driven one 9 cm off).
    #[test]
    fn the_first_sweep_after_driving_carries_the_odometrys_errors_since_its_start() {
        let first_sweep = |metres: usize| {
            let mut slam = Slam::new(SlamConfig::default()).unwrap();
            let (a, b) = (0.03, 2.0_f64.to_radians());
            let mut odo = Vector3::<f64>::zeros();
            let mut stamp = 0;
            slam.push_odometry(stamp, Isometry2::identity());
            for _ in 0..metres * 100 {
                let reported = 0.01 * (1.0 + a);
                odo.x += reported * odo.z.cos();
                odo.y += reported * odo.z.sin();
                odo.z += b * reported;
                stamp += 1000;
                slam.push_odometry(stamp, Isometry2::new(Vector2::new(odo.x, odo.y), odo.z));
            }
            let odometry = Isometry2::new(Vector2::new(odo.x, odo.y), odo.z);
            let e = slam.add_sweep(0, stamp, odometry, &[], &[], false);
            let truth = Vector3::new(metres as f64, 0.0, 0.0);
            let mut d = Vector3::new(
                e.pose.translation.x - truth.x,
                e.pose.translation.y - truth.y,
                e.pose.rotation.angle() - truth.z,
            );
            d.z = wrap_rad(d.z);
            let nees = (d.transpose() * e.covariance.try_inverse().unwrap() * d)[(0, 0)];
            (d.xy().norm(), e.covariance[(1, 1)].sqrt(), nees)
        };
        let (error, sigma_y, nees) = first_sweep(3);
        assert!(error > 0.08, "{error}");
        assert!(
            sigma_y > error / 2.0 && nees < 7.81,
            "σ_y {sigma_y}, NEES {nees}"
        );
        let (error, sigma_y, _) = first_sweep(0);
        assert!(
            error < 1e-12 && sigma_y <= ANCHOR_SIGMA * 1.01,
            "{error} {sigma_y}"
        );
    }

    #[test]
    fn landmarks_need_two_viewpoints_and_then_hold_the_pose_against_a_drifting_odometry() {
        let mut slam = Slam::new(SlamConfig::default()).unwrap();
        let run = tour(&mut slam, 12, |_, seen| seen);
        // The first sweep has nothing to match: its sightings wait for a second viewpoint.
        assert_eq!(run[0].0.state, FixState::NoLandmarks);
        assert!(slam.landmarks().len() >= 5, "{:?}", slam.landmarks());
        for (k, (e, truth)) in run.iter().enumerate() {
            let (position, heading) = error(e, truth);
            assert!(
                position < 0.03 && heading < 1.0,
                "sweep {k}: {position} m {heading}° {e:?}"
            );
            if k > 0 {
                assert_eq!(e.state, FixState::Fix, "sweep {k}");
                // The published covariance covers the error (3 dof, 99.9 %).
                let nees = nees(e, truth);
                assert!(nees < 16.27, "sweep {k}: NEES {nees}");
            }
        }
        // The odometry alone ends far worse: 6 m at 2°/m turns it by 12°.
        let (last, truth) = run.last().unwrap();
        let odo = Vector3::new(
            last.odometry.translation.x,
            last.odometry.translation.y,
            last.odometry.rotation.angle(),
        );
        assert!(wrap_rad(odo.z - truth.z).abs().to_degrees() > 10.0);
        // The drift is learnt.
        let c = slam.calibration().unwrap();
        assert!((c.x - 0.03).abs() < 0.01, "{c}");
    }

    /// A sensor whose ranges all read 3 cm long (uncalibrated) tours the corridor: the graph
    /// learns the bias from the posts seen from several stops and holds the poses within a
    /// centimetre, its covariance covering them; with the bias not estimated, the posts'
    /// sightings disagree and the poses are several times as far off.
    #[test]
    fn a_sensor_reading_long_is_told_by_its_posts_and_the_poses_stay_covered() {
        let long = |_: usize, seen: Vec<Sighting>| {
            seen.into_iter()
                .map(|s| Sighting {
                    z: s.z + Vector2::new(0.03, 0.0),
                    ..s
                })
                .collect()
        };
        let worst = |cfg: SlamConfig| {
            let mut slam = Slam::new(cfg).unwrap();
            let run = tour(&mut slam, 12, long);
            let mut worst = (0.0f64, 0.0f64);
            for (e, truth) in run.iter().skip(1) {
                worst = (worst.0.max(error(e, truth).0), worst.1.max(nees(e, truth)));
            }
            (worst, slam.range_bias())
        };
        let ((position, nees), bias) = worst(SlamConfig::default());
        let bias = bias.unwrap();
        assert!((bias - 0.03).abs() < 0.005, "bias {bias}");
        assert!(position < 0.01 && nees < 16.27, "{position} m, NEES {nees}");
        let ((uncorrected, _), bias) = worst(SlamConfig {
            range_bias_sigma_m: 0.0,
            ..SlamConfig::default()
        });
        assert_eq!(bias, None);
        assert!(
            uncorrected > 2.0 * position + 0.01,
            "{uncorrected} m against {position} m"
        );
    }

    /// Three standing sweeps 0.5 m apart admit the corridor's walls; then the robot drives 5 m
    /// sweeping on the move, its sweeps seeing nothing whole (no observations), each reading's
    /// pings hearing the side walls and the end wall ahead. Ranged from each reading's own pose,
    /// the walls hold the pose against the 3 % / 2°/m odometry; without the ranging it drifts.
    #[test]
    fn readings_on_the_move_ranged_on_known_walls_hold_the_pose() {
        let drive = |range_pings: bool| {
            let cfg = SlamConfig {
                range_pings,
                ..SlamConfig::default()
            };
            let mut slam = Slam::new(cfg).unwrap();
            let (a, b) = (0.03, 2.0_f64.to_radians());
            let mut truth = Vector3::<f64>::zeros();
            let mut odo = truth;
            let mut stamp = 0;
            slam.push_odometry(stamp, Isometry2::identity());
            // Drives 1 cm; the odometry's step.
            let mut step_ahead =
                |truth: &mut Vector3<f64>, odo: &mut Vector3<f64>, slam: &mut Slam| {
                    truth.x += 0.01;
                    let reported = 0.01 * (1.0 + a);
                    let step = Vector3::new(reported, 0.0, b * reported);
                    let (sin, cos) = odo.z.sin_cos();
                    *odo += Vector3::new(cos * step.x, sin * step.x, step.z);
                    stamp += 1000;
                    slam.push_odometry(stamp, Isometry2::new(Vector2::new(odo.x, odo.y), odo.z));
                    (stamp, step)
                };
            let as_pose = |v: &Vector3<f64>| Isometry2::new(Vector2::new(v.x, v.y), v.z);
            let mut worst: f64 = 0.0;
            let mut ranged = 0;
            let mut last_stamp = 0;
            for k in 0..3u32 {
                if k > 0 {
                    for _ in 0..50 {
                        last_stamp = step_ahead(&mut truth, &mut odo, &mut slam).0;
                    }
                }
                let e = slam.add_sweep(k, last_stamp, as_pose(&odo), &seen(&truth), &[], false);
                worst = worst.max(error(&e, &truth).0);
            }
            for k in 3..8u32 {
                let (reference, before, sweep_stamp) = (as_pose(&odo), truth, last_stamp);
                // A reading every 5 cm over 1 m, its pings at the side walls and the end wall.
                let mut readings = Vec::new();
                let mut steps: Vec<Step> = Vec::new();
                for _ in 0..20 {
                    for _ in 0..5 {
                        let (at, step) = step_ahead(&mut truth, &mut odo, &mut slam);
                        last_stamp = at;
                        steps.push(step);
                    }
                    let half_pi = std::f64::consts::FRAC_PI_2;
                    let pings = [
                        (half_pi, 0.6 - truth.y),
                        (-half_pi, 0.6 + truth.y),
                        (0.0, 7.0 - truth.x),
                    ];
                    readings.push(ReadingPings {
                        steps: steps.clone(),
                        pings: pings
                            .map(|(bearing, range)| (bearing - truth.z, range))
                            .to_vec(),
                    });
                }
                let e = slam.add_sweep(k, sweep_stamp, reference, &[], &readings, true);
                worst = worst.max(error(&e, &before).0);
                ranged += e.ranged;
            }
            (worst, ranged)
        };
        let (with, ranged) = drive(true);
        let (without, none) = drive(false);
        assert_eq!(none, 0);
        assert!(ranged > 100, "{ranged}");
        assert!(with < 0.01, "{with} m with ranging, {without} m without");
        assert!(without > 0.04, "{with} m with ranging, {without} m without");
    }

    /// A SLAM with its anchor's sweep at the origin and a second sweep (taken on the move or not)
    /// `centimetres` straight on along x, the odometry exact and sampled every centimetre.
    fn anchor_and_a_sweep_ahead(centimetres: u32, moving: bool) -> Slam {
        let mut slam = Slam::new(SlamConfig::default()).unwrap();
        slam.push_odometry(0, Isometry2::identity());
        slam.add_sweep(0, 0, Isometry2::identity(), &[], &[], false);
        for k in 1..=centimetres {
            let x = 0.01 * f64::from(k);
            slam.push_odometry(
                u64::from(k) * 1000,
                Isometry2::new(Vector2::new(x, 0.0), 0.0),
            );
        }
        let odometry = Isometry2::new(Vector2::new(0.01 * f64::from(centimetres), 0.0), 0.0);
        slam.add_sweep(1, u64::from(centimetres) * 1000, odometry, &[], &[], moving);
        slam
    }

    /// The end wall x = 5 straight ahead, a candidate sighting from the anchor (pose 0).
    fn end_wall_from_the_anchor(sigma: Vector2<f64>, certain: bool) -> Candidate {
        Candidate {
            pose: 0,
            sighting: Sighting {
                kind: LandmarkKind::Line,
                z: Vector2::new(5.0, 0.0),
                sigma,
                certain,
                twin: None,
                after: Vec::new(),
            },
        }
    }

    /// How many landmarks `admit` makes of the end wall x = 5 seen straight ahead from the map's
    /// anchor (exact, a whole sighting) and again from a pose 2 m on, whose heading the odometry
    /// knows to σ (> 3°), as if that pose were turned by `turned_sigmas` σ, at the same distance;
    /// the second sighting whole when `certain`.
    fn end_wall_seen_turned(turned_sigmas: f64, certain: bool) -> usize {
        let mut slam = anchor_and_a_sweep_ahead(200, false);
        let pose = slam.poses[1].var;
        let heading_sigma = slam.graph.covariance(&[(pose, 3)]).unwrap()[(2, 2)].sqrt();
        assert!(heading_sigma > 3.0_f64.to_radians(), "{heading_sigma}");
        let sigma = Vector2::new(0.01, 0.2_f64.to_radians());
        slam.candidates.push(end_wall_from_the_anchor(sigma, true));
        let turn = turned_sigmas * heading_sigma;
        let x = slam.graph.vector3(pose);
        let z = Vector2::new(5.0 - x.x * turn.cos() - x.y * turn.sin(), turn - x.z);
        let sighting = Sighting {
            kind: LandmarkKind::Line,
            z,
            sigma,
            certain,
            twin: None,
            after: Vec::new(),
        };
        slam.admit(1, &[sighting])
    }

    /// A wall seen from the map's anchor (exact) and again from a pose 2 m on, whose heading the
    /// odometry knows to σ: the two placements are compared with the two poses' joint covariance,
    /// so the wall is admitted when the second sighting is turned by 1σ and not at 3.5σ. (With
    /// the second pose's covariance taken for both, 3.5σ passed: a room tour took a perpendicular
    /// wall for one seen before and turned by 81°.)
    #[test]
    fn a_wall_is_admitted_from_two_viewpoints_with_their_joint_covariance() {
        assert_eq!(end_wall_seen_turned(1.0, true), 1);
        assert_eq!(end_wall_seen_turned(3.5, true), 0);
    }

    /// As above, with the second sighting a wall cut short on the move (it may be a corner or
    /// an edge cut short): it is admitted within the tighter gate of such a pair (95 %), not
    /// between that and the 99 % gate of two whole sightings.
    #[test]
    fn a_pair_with_a_wall_cut_short_passes_only_the_tighter_gate() {
        // χ² ≈ 7.3: inside 9.21, outside 5.99.
        assert_eq!(end_wall_seen_turned(2.7, true), 1);
        assert_eq!(end_wall_seen_turned(2.7, false), 0);
        assert_eq!(end_wall_seen_turned(1.0, false), 1);
    }

    /// Three viewpoints on the move, 50 cm apart, each seeing the end wall from a region cut
    /// short: two such sightings make no landmark (above), the third that agrees with both makes
    /// one with all three as factors; a third that places the wall 30 cm farther does not.
    #[test]
    fn walls_cut_short_from_three_viewpoints_that_agree_are_admitted() {
        let admitted = |third_offset_m: f64| {
            let mut slam = anchor_and_a_sweep_ahead(50, true);
            for k in 51..=100_u32 {
                let x = 0.01 * f64::from(k);
                slam.push_odometry(
                    u64::from(k) * 1000,
                    Isometry2::new(Vector2::new(x, 0.0), 0.0),
                );
            }
            let odometry = Isometry2::new(Vector2::new(1.0, 0.0), 0.0);
            slam.add_sweep(2, 100_000, odometry, &[], &[], true);
            let sigma = Vector2::new(0.01, 1.0_f64.to_radians());
            let seen = |distance: f64| Sighting {
                kind: LandmarkKind::Line,
                z: Vector2::new(distance, 0.0),
                sigma,
                certain: false,
                twin: None,
                after: Vec::new(),
            };
            slam.candidates.push(end_wall_from_the_anchor(sigma, false));
            slam.candidates.push(Candidate {
                pose: 1,
                sighting: seen(4.5),
            });
            let n = slam.admit(2, &[seen(4.0 + third_offset_m)]);
            (n, slam.landmarks.first().map(|l| l.sightings))
        };
        assert_eq!(admitted(0.0), (1, Some(3)));
        assert_eq!(admitted(0.3), (0, None));
    }

    /// A sweep on the move along x, 10 cm between readings aimed from −150° to 150°: the end
    /// wall x = 3, which the features place 3 m ahead of the first reading, is measured from the
    /// middle reading that faced it (1 m on: 2 m ahead), with the odometry's steps to it.
    #[test]
    fn a_wall_on_the_move_is_measured_from_the_reading_that_faced_it() {
        let slam = Slam::new(SlamConfig::default()).unwrap();
        let placed: Vec<(Reading, Isometry2<f64>)> = (0..21)
            .map(|i| {
                let reading = Reading {
                    angle_deg: -150.0 + 15.0 * i as f32,
                    ..Reading::default()
                };
                (
                    reading,
                    Isometry2::new(Vector2::new(0.1 * i as f64, 0.0), 0.0),
                )
            })
            .collect();
        let steps: Vec<Vec<Step>> = (0..21)
            .map(|i| vec![Vector3::new(0.1, 0.0, 0.0); i])
            .collect();
        let sigma = Vector2::new(0.01, 1.0_f64.to_radians());
        let mut wall = Sighting {
            kind: LandmarkKind::Line,
            z: Vector2::new(3.0, 0.0),
            sigma,
            certain: true,
            twin: None,
            after: Vec::new(),
        };
        slam.seen_on_the_move(&mut wall, &placed, &steps);
        assert_eq!(wall.after, steps[10]);
        assert!(
            (wall.z - Vector2::new(2.0, 0.0)).norm() < 1e-9,
            "{}",
            wall.z
        );
        // Its σ takes the odometry's random error over that metre, and only that.
        assert!(
            wall.sigma.x > sigma.x && wall.sigma.x < 0.03,
            "{}",
            wall.sigma
        );
        assert!(
            wall.sigma.y > sigma.y && wall.sigma.y < 2.0_f64.to_radians(),
            "{}",
            wall.sigma
        );
        // The same wall 2 m farther: heard 4 m from the reading that faced it, near the
        // sensor's reach, its bearing σ is the near-reach floor.
        let mut far = Sighting {
            z: Vector2::new(5.0, 0.0),
            after: Vec::new(),
            ..wall
        };
        far.sigma = sigma;
        slam.seen_on_the_move(&mut far, &placed, &steps);
        assert!((far.z.x - 4.0).abs() < 1e-9, "{}", far.z);
        assert!(
            (far.sigma.y.to_degrees() - SlamConfig::default().near_reach_bearing_sigma_deg).abs()
                < 1e-9,
            "{}",
            far.sigma
        );
    }

    /// A wall seen on the move from two viewpoints 50 cm apart, each time from a region cut
    /// short at one end (what a corner or a door's edge cut short gives too): the two sightings
    /// agree, but make no landmark; with either of them seen whole, they do.
    #[test]
    fn walls_cut_short_on_the_move_need_a_whole_sighting_to_be_admitted() {
        let admitted = |first_certain: bool, second_certain: bool| {
            let mut slam = anchor_and_a_sweep_ahead(50, true);
            // The end wall x = 5 straight ahead, from the anchor and from 0.5 m on.
            let sigma = Vector2::new(0.01, 1.0_f64.to_radians());
            slam.candidates
                .push(end_wall_from_the_anchor(sigma, first_certain));
            let sighting = Sighting {
                kind: LandmarkKind::Line,
                z: Vector2::new(4.5, 0.0),
                sigma,
                certain: second_certain,
                twin: None,
                after: Vec::new(),
            };
            slam.admit(1, &[sighting])
        };
        assert_eq!(admitted(false, false), 0);
        assert_eq!(admitted(true, false), 1);
        assert_eq!(admitted(false, true), 1);
        assert_eq!(admitted(true, true), 1);
    }

    #[test]
    fn a_phantom_of_one_sweep_never_becomes_a_landmark() {
        let mut slam = Slam::new(SlamConfig::default()).unwrap();
        // Sweep 4 alone sees a corner that is not there.
        let phantom = Sighting {
            kind: LandmarkKind::Point,
            z: Vector2::new(0.8, 0.3),
            sigma: Vector2::new(0.01, 0.02),
            certain: true,
            twin: None,
            after: Vec::new(),
        };
        tour(&mut slam, 8, |k, mut seen| {
            if k == 4 {
                seen.push(phantom.clone());
            }
            seen
        });
        assert_eq!(
            slam.landmarks()
                .iter()
                .filter(|l| l.kind == LandmarkKind::Point)
                .count(),
            3,
            "the three posts, not the phantom: {:?}",
            slam.landmarks()
        );
    }

    /// Near the sensor a post's region is as wide as a wall's, and one viewpoint cannot tell
    /// them apart: every side wall and post of the corridor sighted only so, as a point and as
    /// a wall at once (twins), becomes the landmark its viewpoints agree on. The side walls are
    /// walls and the posts points, none of them twice, and the tour stays on course.
    #[test]
    fn a_region_either_a_point_or_a_wall_becomes_what_its_viewpoints_agree_on() {
        let mut slam = Slam::new(SlamConfig::default()).unwrap();
        let run = tour(&mut slam, 12, |k, seen| {
            seen.into_iter()
                .enumerate()
                .flat_map(|(region, s)| {
                    let side_wall = s.kind == LandmarkKind::Line && s.z.x < 1.0;
                    if !side_wall && s.kind == LandmarkKind::Line {
                        return vec![s];
                    }
                    let twin = Some((k as u32, region));
                    [LandmarkKind::Point, LandmarkKind::Line]
                        .into_iter()
                        .map(|kind| Sighting {
                            kind,
                            twin,
                            ..s.clone()
                        })
                        .collect()
                })
                .collect()
        });
        let landmarks = slam.landmarks();
        let count = |kind| landmarks.iter().filter(|l| l.kind == kind).count();
        // The two side walls and the two end walls, and the three posts.
        assert_eq!(count(LandmarkKind::Line), 4, "{landmarks:?}");
        assert_eq!(count(LandmarkKind::Point), 3, "{landmarks:?}");
        for l in landmarks.iter().filter(|l| l.kind == LandmarkKind::Point) {
            let at = |&(x, y): &(f64, f64)| (l.mean - Vector2::new(x, y)).norm() < 0.05;
            assert!(POSTS.iter().any(at), "{l:?} is no post");
        }
        for (e, truth) in &run {
            let (metres, degrees) = error(e, truth);
            assert!(metres < 0.05 && degrees < 2.0, "{metres} m, {degrees}°");
        }
    }

    #[test]
    fn sightings_from_a_wrong_place_do_not_drag_the_pose() {
        let mut slam = Slam::new(SlamConfig::default()).unwrap();
        let run = tour(&mut slam, 6, |_, seen| seen);
        // The corridor as seen from 30 cm further along than the robot is: the end walls and
        // posts fail the gate (the side walls fit either way); the pose stays where it is.
        let last = run.last().unwrap().0;
        let x = Vector3::new(
            last.pose.translation.x + 0.3,
            last.pose.translation.y,
            last.pose.rotation.angle(),
        );
        let stamp = last.stamp_ns + 1000;
        slam.push_odometry(stamp, last.odometry);
        let e = slam.add_sweep(99, stamp, last.odometry, &seen(&x), &[], false);
        assert!(e.matched < e.observations, "{e:?}");
        assert!((e.pose.translation.x - 3.0).abs() < 0.02, "{e:?}");
    }

    #[test]
    fn sightings_that_would_make_the_odometry_implausible_are_refused() {
        // A gate so tight that any pull on the odometry is implausible.
        let cfg = SlamConfig {
            odometry_gate_chi2: 1e-9,
            ..SlamConfig::default()
        };
        let mut slam = Slam::new(cfg).unwrap();
        let run = tour(&mut slam, 3, |_, seen| seen);
        let refused = run
            .iter()
            .filter(|(e, _)| e.state == FixState::Refused)
            .count();
        assert!(refused > 0 && refused as u32 == slam.refused(), "{run:?}");
        for (e, _) in run.iter().filter(|(e, _)| e.state == FixState::Refused) {
            assert_eq!((e.matched, e.admitted), (0, 0));
            // Placed by the odometry, corrected by the errors known so far (none yet): the
            // odometry's own pose.
            assert!((e.pose.translation.vector - e.odometry.translation.vector).norm() < 1e-6);
        }
    }

    #[test]
    fn sightings_that_would_move_the_pose_beyond_its_prediction_are_refused() {
        // The odometry's rise let through, the pose's shift so tightly gated that any pull on
        // the pose is beyond its prediction.
        let cfg = SlamConfig {
            odometry_gate_chi2: f64::MAX,
            pose_shift_gate_chi2: 1e-9,
            ..SlamConfig::default()
        };
        let mut slam = Slam::new(cfg).unwrap();
        let run = tour(&mut slam, 3, |_, seen| seen);
        let refused: Vec<_> = run
            .iter()
            .filter(|(e, _)| e.state == FixState::Refused)
            .collect();
        assert!(
            !refused.is_empty() && refused.len() as u32 == slam.refused(),
            "{run:?}"
        );
        for (e, _) in refused {
            assert!((e.pose.translation.vector - e.odometry.translation.vector).norm() < 1e-6);
        }
        // With the default gates the same tour is fixed.
        let mut slam = Slam::new(SlamConfig::default()).unwrap();
        let run = tour(&mut slam, 3, |_, seen| seen);
        assert_eq!(slam.refused(), 0, "{run:?}");
        assert!(run.iter().any(|(e, _)| e.state == FixState::Fix), "{run:?}");
    }

    #[test]
    fn chi2_quantiles_match_the_tables() {
        for (k, p, table) in [
            (2, 0.99, 9.21),
            (3, 0.999, 16.27),
            (3, 0.95, 7.81),
            (10, 0.99, 23.21),
        ] {
            let q = chi2_quantile(k, p);
            assert!(
                (q - table).abs() / table < 0.02,
                "{k} {p}: {q} against {table}"
            );
        }
    }

    #[test]
    fn bad_settings_are_refused() {
        let cfg = SlamConfig {
            gate_chi2: -1.0,
            ..SlamConfig::default()
        };
        assert!(matches!(Slam::new(cfg), Err(SlamError::Config(_))));
        let cfg = SlamConfig {
            joint_probability: 1.0,
            ..SlamConfig::default()
        };
        assert!(Slam::new(cfg).is_err());
        for cfg in [
            SlamConfig {
                near_reach_m: 0.0,
                ..SlamConfig::default()
            },
            SlamConfig {
                near_reach_bearing_sigma_deg: f64::NAN,
                ..SlamConfig::default()
            },
        ] {
            assert!(Slam::new(cfg).is_err(), "{cfg:?}");
        }
    }
}
