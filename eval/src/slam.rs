//! The SLAM evaluation (issue 25): generated tours driven with a drifting odometry, each capture
//! given to `sonar-slam`'s library and to today's localisation (`sonar-fusion --localize`, as
//! [`crate::motion::fuse_tour`] runs it), every sweep's pose scored against the truth.
//!
//! # The tours
//!
//! [`Family`] makes a scene with a robot from a layout seed: the size, the doorways, the posts and
//! the whole layout's rotation drawn from it. Each layout is driven with every run seed (echo and
//! odometry noise) at every [`OdometryLevel`], the signs of its scale error and drift drawn from
//! the seed ("all signs" over the seeds). Layout seeds split the suite: the SLAM's settings were
//! chosen on one set of layouts and the figures reported on another (`docs/results.md`).
//!
//! # The figures
//!
//! Per run: the largest and the median position and heading error over the sweeps of the pose
//! each method published for the sweep (the SLAM's estimate when the sweep was added — online, as
//! a robot would use it — or the localisation's fix, else its prediction), and the odometry's own
//! at the same instants. Per fix (a sweep the method says it fixed): NEES against the fix's own
//! covariance, whether the truth lies inside the fix's 95 % ellipse (NEES ≤ χ²₃(0.95) = 7.81),
//! and whether the fix is worse than the odometry (more than [`WORSE_M`] farther or [`WORSE_DEG`]
//! more turned than the odometry's pose at that instant).
//!
//! **The maps** ([`TourMaps`]): the tour's readings fused with the recommended preset three ways
//! and each scored against the scene's true surfaces as seen from the sweeps' true poses
//! ([`crate::suite::score_grid`]): with the correction `sonar-slam` had published when each reading
//! arrived (the previous sweep's: what `sonar-fusion --slam-correction` drew before it followed
//! the revisions), with each sweep's own correction as the whole tour finally estimates it (what
//! the fusion's maps converge to as it follows every revision, `fusion/src/history.rs`), and at
//! the true poses (the best any placement can do with this sensor).

use std::f64::consts::PI;
use std::fmt::Write as _;

use anyhow::{Context, Result};
use nalgebra::{Isometry2, Vector2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sonar_common::ipc::Reading;
use sonar_features::FeatureConfig;
use sonar_fusion::{FusionConfig, Mapper, Observation};
use sonar_sim::{OdometryParams, Pose, PoseSample, Scene};
use sonar_slam::{FixState, Landmark, Slam, SlamConfig, SweepEstimate, SweepPose};

use crate::feature_report::Spread;
use crate::features::scene_feature_config;
use crate::landmarks::{self, LandmarkScore};
use crate::motion::{POSE_RATE_HZ, Placement, PoseError, fuse_tour, grid_over, nees, truth_at};
use crate::pipeline::{ProfileChoice, Scan, TourCapture, capture_tour, probability_view};
use crate::scenegen;
use crate::suite::{GridScore, Reach, score_grid};

/// χ² of 3 degrees of freedom at 95 %: a fix whose NEES is within lies inside its 95 % ellipse.
pub const CHI2_3_95: f64 = 7.81;
/// A fix is worse than the odometry when it is this much farther from the truth …
pub const WORSE_M: f64 = 0.01;
/// … or this much more turned.
pub const WORSE_DEG: f64 = 0.5;

/// A generated kind of tour.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Family {
    /// An L-shaped hallway with a doorway, out to its end and back, stopping to scan.
    Hallway,
    /// The same hallway, scanning while driving.
    HallwayDriving,
    /// A ring corridor round a block, driven round and round, stopping to scan: loop closure.
    Loop,
    /// A 10 m corridor without doors or posts, out and back, stopping to scan.
    LongCorridor,
    /// An office with a table (four legs) and a pillar, driven round the table while scanning.
    Office,
    /// A hall 20–28 m long and 10–14 m wide, crossed along its length and back, stopping to
    /// scan: for most of the way no wall within the sensor's reach.
    OpenHall,
    /// The built-in `corridor` tour (stop and scan).
    Corridor,
    /// The built-in `room-tour` (scan while driving).
    RoomTour,
}

impl Family {
    pub const ALL: [Family; 8] = [
        Family::Hallway,
        Family::HallwayDriving,
        Family::Loop,
        Family::LongCorridor,
        Family::Office,
        Family::OpenHall,
        Family::Corridor,
        Family::RoomTour,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Family::Hallway => "hallway",
            Family::HallwayDriving => "hallway-driving",
            Family::Loop => "loop",
            Family::LongCorridor => "long-corridor",
            Family::Office => "office",
            Family::OpenHall => "open-hall",
            Family::Corridor => "corridor",
            Family::RoomTour => "room-tour",
        }
    }

    /// One of the scenes built into the simulator, whose layout does not change.
    pub fn is_builtin(self) -> bool {
        matches!(self, Family::Corridor | Family::RoomTour)
    }

    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.name() == name)
    }

    /// As [`Self::scene`], with about `share` of its walls rough ([`scenegen::with_rough_walls`]:
    /// brick, full shelves), each drawn from the layout on its own, the rest as it was.
    pub fn scene_with_rough_walls(self, layout: u64, share: f64) -> Result<(Scene, f64)> {
        let (scene, metres) = self.scene(layout)?;
        Ok((
            scenegen::with_rough_walls(&scene, share, self.seed(layout))?,
            metres,
        ))
    }

    /// The seed of layout `layout`'s draws.
    fn seed(self, layout: u64) -> u64 {
        layout.wrapping_mul(7919).wrapping_add(self as u64)
    }

    /// The scene of layout `layout`, and the tour's length in metres (three rounds of a loop's
    /// ring, three of the office's table; out and back otherwise).
    pub fn scene(self, layout: u64) -> Result<(Scene, f64)> {
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed(layout));
        let rotation = rng.random_range(0.0..2.0 * PI);
        let (walls, posts, waypoints, mode, metres) = match self {
            Family::Corridor | Family::RoomTour => {
                let scene = Scene::builtin(self.name())
                    .with_context(|| format!("loading scene {}", self.name()))?;
                let metres = if self == Family::Corridor { 24.0 } else { 19.2 };
                return Ok((scene, metres));
            }
            Family::Hallway | Family::HallwayDriving => {
                let w = rng.random_range(1.0..1.4);
                let (l1, l2) = (rng.random_range(4.0..6.0), rng.random_range(3.0..5.0));
                let door = rng.random_range(1.5..l1 - 2.0);
                let h = w / 2.0;
                let walls = vec![
                    [[0.0, -h], [l1 + h, -h]],
                    [[l1 + h, -h], [l1 + h, l2]],
                    [[0.0, h], [door, h]],
                    [[door + 0.8, h], [l1 - h, h]],
                    [[l1 - h, h], [l1 - h, l2]],
                    [[0.0, -h], [0.0, h]],
                    [[l1 - h, l2], [l1 + h, l2]],
                ];
                let out = out_and_back(along(&[[0.5, 0.0], [l1, 0.0], [l1, l2 - 0.5]], 1.0));
                let mode = if self == Family::Hallway {
                    "stop-and-scan"
                } else {
                    "scan-while-driving"
                };
                (walls, Vec::new(), out, mode, 2.0 * (l1 - 0.5 + l2 - 0.5))
            }
            Family::Loop => {
                let (a, b) = (rng.random_range(5.0..7.0), rng.random_range(3.5..5.0));
                let w = 1.2;
                let mut walls = rectangle(0.0, 0.0, a, b);
                walls.extend(rectangle(w, w, a - w, b - w));
                let h = w / 2.0;
                let ring = [[h, h], [a - h, h], [a - h, b - h], [h, b - h], [h, h]];
                let mut waypoints = along(&ring, 1.0);
                waypoints.pop();
                let lap = 2.0 * (a - w + b - w);
                (walls, Vec::new(), waypoints, "stop-and-scan", 3.0 * lap)
            }
            Family::LongCorridor => {
                let w = rng.random_range(1.0..1.4);
                let h = w / 2.0;
                let l = 10.0;
                let walls = vec![
                    [[0.0, -h], [l, -h]],
                    [[0.0, h], [l, h]],
                    [[0.0, -h], [0.0, h]],
                    [[l, -h], [l, h]],
                ];
                let out = out_and_back(along(&[[0.5, 0.0], [l - 0.5, 0.0]], 1.0));
                (walls, Vec::new(), out, "stop-and-scan", 2.0 * (l - 1.0))
            }
            Family::OpenHall => {
                let (a, b) = (rng.random_range(20.0..28.0), rng.random_range(10.0..14.0));
                // A stop every 2 m: the middle is out of the sensor's reach either way.
                let out = out_and_back(along(&[[1.0, b / 2.0], [a - 1.0, b / 2.0]], 2.0));
                (
                    rectangle(0.0, 0.0, a, b),
                    Vec::new(),
                    out,
                    "stop-and-scan",
                    2.0 * (a - 2.0),
                )
            }
            Family::Office => {
                let (a, b) = (rng.random_range(4.5..6.0), rng.random_range(3.5..4.5));
                let walls = rectangle(0.0, 0.0, a, b);
                let (cx, cy) = (a / 2.0, b / 2.0);
                let (tx, ty) = (0.6, 0.4);
                let mut posts: Vec<([f64; 2], f64)> = [(-tx, -ty), (tx, -ty), (tx, ty), (-tx, ty)]
                    .iter()
                    .map(|(dx, dy)| ([cx + dx, cy + dy], 0.025))
                    .collect();
                // A pillar between the wall y = 0 and the robot's path (at least 0.55 m from it).
                posts.push(([cx + rng.random_range(-0.5..0.5), 0.3], 0.1));
                let (rx, ry) = (tx + 0.9, ty + 0.8);
                let waypoints = vec![
                    [cx - rx, cy - ry],
                    [cx + rx, cy - ry],
                    [cx + rx, cy + ry],
                    [cx - rx, cy + ry],
                ];
                let lap = 4.0 * (rx + ry);
                (walls, posts, waypoints, "scan-while-driving", 1.5 * lap)
            }
        };
        let turn = |p: [f64; 2]| {
            let (s, c) = rotation.sin_cos();
            [c * p[0] - s * p[1], s * p[0] + c * p[1]]
        };
        let mut toml = format!(
            "name = \"{}-{layout}\"\ndescription = \"generated {} layout {layout}\"\nscan = {{ mode = \"full\" }}\n",
            self.name(),
            self.name()
        );
        for [from, to] in walls {
            let (f, t) = (turn(from), turn(to));
            let _ = writeln!(
                toml,
                "[[segments]]\nfrom = [{:.4}, {:.4}]\nto = [{:.4}, {:.4}]",
                f[0], f[1], t[0], t[1]
            );
        }
        for (centre, radius) in posts {
            let c = turn(centre);
            let _ = writeln!(
                toml,
                "[[circles]]\ncentre = [{:.4}, {:.4}]\nradius = {radius}",
                c[0], c[1]
            );
        }
        let points: Vec<String> = waypoints
            .iter()
            .map(|&p| {
                let p = turn(p);
                format!("[{:.4}, {:.4}]", p[0], p[1])
            })
            .collect();
        let _ = writeln!(
            toml,
            "[robot]\nwaypoints = [{}]\nspeed_mps = 0.2\nturn_rate_dps = 45\nmode = \"{mode}\"\nloop = true",
            points.join(", ")
        );
        let scene = Scene::from_toml_str(&toml, self.name())
            .with_context(|| format!("generated scene {} {layout}:\n{toml}", self.name()))?;
        Ok((scene, metres))
    }
}

/// The four walls of the rectangle from (x0, y0) to (x1, y1).
fn rectangle(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<[[f64; 2]; 2]> {
    vec![
        [[x0, y0], [x1, y0]],
        [[x1, y0], [x1, y1]],
        [[x1, y1], [x0, y1]],
        [[x0, y1], [x0, y0]],
    ]
}

/// The waypoints `out` followed by the way back to just short of the first (the tour loops).
fn out_and_back(mut out: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
    let back: Vec<[f64; 2]> = out
        .iter()
        .rev()
        .skip(1)
        .take(out.len().saturating_sub(2))
        .copied()
        .collect();
    out.extend(back);
    out
}

/// Points along the polyline `corners`, at most `spacing` apart, corners included.
fn along(corners: &[[f64; 2]], spacing: f64) -> Vec<[f64; 2]> {
    let mut out = vec![corners[0]];
    for pair in corners.windows(2) {
        let (a, b) = (Vector2::from(pair[0]), Vector2::from(pair[1]));
        let n = ((b - a).norm() / spacing).ceil().max(1.0) as usize;
        for k in 1..=n {
            let p = a + (b - a) * (k as f64 / n as f64);
            out.push([p.x, p.y]);
        }
    }
    out
}

/// How much the odometry errs: scale error and heading drift (their signs drawn per run).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometryLevel {
    pub scale: f64,
    pub drift_deg_per_m: f64,
}

impl OdometryLevel {
    pub const GOOD: Self = Self {
        scale: 0.01,
        drift_deg_per_m: 0.5,
    };
    pub const MEDIUM: Self = Self {
        scale: 0.03,
        drift_deg_per_m: 2.0,
    };
    pub const POOR: Self = Self {
        scale: 0.05,
        drift_deg_per_m: 3.0,
    };

    pub fn label(self) -> String {
        format!("{:.0} % / {}°/m", self.scale * 100.0, self.drift_deg_per_m)
    }

    /// The simulator's odometry for run `seed`: this level with signs from the seed, and the tour
    /// scenes' small white noise.
    pub fn params(self, seed: u64) -> OdometryParams {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
        let sign = |b: bool| if b { 1.0 } else { -1.0 };
        OdometryParams {
            scale_error: sign(rng.random_bool(0.5)) * self.scale,
            heading_drift_deg_per_m: sign(rng.random_bool(0.5)) * self.drift_deg_per_m,
            noise_m: 0.0005,
            noise_deg: 0.05,
        }
    }
}

/// One method's account of one sweep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placed {
    pub error: PoseError,
    /// The odometry's own error at the same instant.
    pub odometry: PoseError,
    /// The method called it a fix; with the fix's NEES.
    pub fix: Option<f64>,
    /// The NEES of the pose published for the sweep against the covariance published with it,
    /// fix or not (the SLAM publishes one with every sweep; today's localisation only with a
    /// fix): a sweep that is no fix must still not claim centimetres while metres off.
    pub nees: Option<f64>,
    /// Sweep's share of the tour's time (0 at the start, 1 at the end).
    pub progress: f64,
}

impl Placed {
    fn worse_than_odometry(&self) -> bool {
        self.error.position_m > self.odometry.position_m + WORSE_M
            || self.error.heading_deg > self.odometry.heading_deg + WORSE_DEG
    }
}

/// One tour of one layout with one seed at one odometry level.
#[derive(Debug, Clone)]
pub struct Run {
    pub family: Family,
    pub profile: ProfileChoice,
    pub layout: u64,
    pub seed: u64,
    pub level: OdometryLevel,
    pub odometry: OdometryParams,
    pub slam: Vec<Placed>,
    pub localize: Vec<Placed>,
    /// Sweeps the SLAM refused.
    pub refused: u32,
    pub maps: TourMaps,
    /// Each sweep's pose as the whole tour finally estimates it, against the truth.
    pub revised: Vec<PoseError>,
    /// The SLAM's landmarks at the end of the tour against the true geometry.
    pub landmarks: LandmarkScore,
}

/// The tour's map placed three ways, against the true surfaces (module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TourMaps {
    /// With the correction published when each reading arrived.
    pub online: GridScore,
    /// With each sweep's own correction as estimated at the end of the tour.
    pub revised: GridScore,
    /// At the true poses.
    pub truth: GridScore,
}

/// What the SLAM gave for one tour.
#[derive(Debug, Clone)]
pub struct SlamOutput {
    /// Each sweep's estimate when it was added, in order.
    pub estimates: Vec<SweepEstimate>,
    /// Every sweep as estimated at the end of the tour.
    pub trajectory: Vec<SweepPose>,
    pub refused: u32,
    /// The landmarks at the end of the tour.
    pub landmarks: Vec<Landmark>,
}

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct SlamSettings {
    pub families: Vec<Family>,
    /// The sensors every tour is heard through (the simulator's profiles, or its default).
    pub profiles: Vec<ProfileChoice>,
    pub layouts: Vec<u64>,
    pub seeds: Vec<u64>,
    pub levels: Vec<OdometryLevel>,
    pub config: SlamConfig,
    /// Share of every tour's walls made rough ([`Family::scene_with_rough_walls`]).
    pub rough_share: f64,
}

/// Feeds `tour` to `slam` as a process would get it: every odometry sample up to a reading's
/// stamp before the reading, which `push` hands to the SLAM (`Slam::push_reading`, timed or
/// not); the odometry after the last reading at the end.
pub fn feed_tour(tour: &TourCapture, slam: &mut Slam, mut push: impl FnMut(&mut Slam, &Reading)) {
    let mut poses = tour.poses.iter().peekable();
    let to_iso = |p: &Pose| Isometry2::new(Vector2::new(p.at.x, p.at.y), p.heading_rad);
    for r in &tour.capture.readings {
        while let Some(s) = poses.next_if(|s| s.t_us * 1000 <= r.host_stamp_ns) {
            slam.push_odometry(s.t_us * 1000, to_iso(&s.odometry));
        }
        push(slam, r);
    }
    for s in poses {
        slam.push_odometry(s.t_us * 1000, to_iso(&s.odometry));
    }
}

/// Feeds `tour` to a new SLAM ([`feed_tour`]) and finishes its last sweep.
pub fn run_slam(tour: &TourCapture, config: SlamConfig) -> Result<SlamOutput> {
    let mut slam = Slam::new(config).context("setting up the SLAM")?;
    let mut estimates = Vec::new();
    feed_tour(tour, &mut slam, |slam, r| {
        if let Some(e) = slam.push_reading(r) {
            estimates.push(e);
        }
    });
    if let Some(e) = slam.finish_sweep() {
        estimates.push(e);
    }
    tracing::debug!(
        calibration = ?slam.calibration(),
        range_bias_m = ?slam.range_bias(),
        landmarks = slam.landmark_count(),
        "SLAM at the end of the tour (scale error, drift rad/m, turn error; range bias)"
    );
    Ok(SlamOutput {
        estimates,
        trajectory: slam.trajectory(),
        refused: slam.refused(),
        landmarks: slam.landmarks(),
    })
}

/// The tour's readings fused with the recommended preset, each at `correction(reading) ∘` its
/// odometry pose (or at its true pose with `None`), scored against the scene.
fn tour_map(
    scene: &Scene,
    tour: &TourCapture,
    correction: impl Fn(&Reading) -> Option<Isometry2<f64>>,
) -> Result<GridScore> {
    let config = FusionConfig {
        grid: grid_over(scene),
        ..FusionConfig::default()
    };
    let mut mapper = Mapper::new(config).context("setting up the tour's grid")?;
    let mut views = Vec::new();
    let mut sweep = None;
    let mut max_range_m: f64 = 0.0;
    // The bearings the tour's readings were aimed over (their axes).
    let mut sweep_deg = (f64::INFINITY, f64::NEG_INFINITY);
    for r in &tour.capture.readings {
        let truth = truth_at(&tour.poses, r.host_stamp_ns);
        if sweep != Some(r.sweep_id) {
            if sweep.is_some() {
                mapper.close_region();
            }
            sweep = Some(r.sweep_id);
            views.push(truth);
        }
        let pose = match correction(r) {
            Some(c) => c * pose_iso(&odometry_at(&tour.poses, r.host_stamp_ns)),
            None => pose_iso(&truth),
        };
        let pose = Isometry2::new(
            Vector2::new(pose.translation.x as f32, pose.translation.y as f32),
            pose.rotation.angle() as f32,
        );
        max_range_m = max_range_m.max(f64::from(r.max_range_m));
        let angle = f64::from(r.angle_deg);
        sweep_deg = (sweep_deg.0.min(angle), sweep_deg.1.max(angle));
        mapper
            .update(&Observation::from_reading(r, pose))
            .with_context(|| format!("fusing reading {}", r.seq))?;
    }
    mapper.close_region();
    Ok(score_grid(
        &probability_view(&mapper),
        scene,
        &views,
        Reach {
            max_range_m,
            sweep_deg,
        },
    ))
}

/// [`TourMaps`] of one tour and the SLAM's output for it.
fn tour_maps(scene: &Scene, tour: &TourCapture, slam: &SlamOutput) -> Result<TourMaps> {
    // A sweep is estimated when the next one's first reading arrives: each reading is placed
    // with the latest estimate of an earlier sweep.
    let online = |r: &Reading| {
        Some(
            slam.estimates
                .iter()
                .rev()
                .find(|e| e.sweep_id < r.sweep_id)
                .map_or_else(Isometry2::identity, SweepEstimate::correction),
        )
    };
    let revised = |r: &Reading| {
        slam.trajectory
            .iter()
            .find(|p| p.sweep_id == r.sweep_id)
            .map(SweepPose::correction)
            .or_else(|| online(r))
    };
    Ok(TourMaps {
        online: tour_map(scene, tour, online)?,
        revised: tour_map(scene, tour, revised)?,
        truth: tour_map(scene, tour, |_| None)?,
    })
}

fn odometry_at(poses: &[PoseSample], stamp_ns: u64) -> Pose {
    // The odometry interpolated as the truth is.
    let swapped: Vec<PoseSample> = poses
        .iter()
        .map(|s| PoseSample {
            t_us: s.t_us,
            truth: s.odometry,
            odometry: s.truth,
        })
        .collect();
    truth_at(&swapped, stamp_ns)
}

fn pose_iso(p: &Pose) -> Isometry2<f64> {
    Isometry2::new(Vector2::new(p.at.x, p.at.y), p.heading_rad)
}

/// Captures one tour and runs both methods on it.
pub fn run(
    family: Family,
    layout: u64,
    seed: u64,
    level: OdometryLevel,
    profile: ProfileChoice,
    mut config: SlamConfig,
    rough_share: f64,
) -> Result<Run> {
    let (mut scene, metres) = family.scene_with_rough_walls(layout, rough_share)?;
    if let Some(p) = profile.0 {
        scene.set_profile(p);
    }
    // The SLAM and the localisation are told the sensor's head and echoes, as a robot builder
    // configures them for the sensor they own; the rest of the SLAM's settings stay as given.
    let features = scene_feature_config(&scene);
    config.features = FeatureConfig {
        sensor: features.sensor,
        echo: features.echo,
        ..config.features
    };
    let odometry = level.params(seed);
    let tour = capture_tour(
        scene.clone(),
        Scan::for_scene(&scene),
        metres,
        odometry,
        POSE_RATE_HZ,
        seed,
    )
    .with_context(|| format!("touring {} layout {layout} seed {seed}", family.name()))?;
    let end_ns = tour.poses.last().map_or(1, |s| s.t_us.max(1) * 1000);
    let progress = |stamp_ns: u64| stamp_ns as f64 / end_ns as f64;
    let output = run_slam(&tour, config)?;
    let maps = tour_maps(&scene, &tour, &output)?;
    let revised = output
        .trajectory
        .iter()
        .map(|p| PoseError::of(&p.pose, &truth_at(&tour.poses, p.stamp_ns)))
        .collect();
    let refused = output.refused;
    let landmarks = landmarks::score(&scene, &output.landmarks);
    let slam = output
        .estimates
        .iter()
        .map(|e| {
            let truth = truth_at(&tour.poses, e.stamp_ns);
            let published = nees(&e.pose, &e.covariance, &truth);
            tracing::debug!(
                sweep = e.sweep_id,
                state = ?e.state,
                observations = e.observations,
                matched = e.matched,
                admitted = e.admitted,
                ranged = e.ranged,
                moving = e.moving,
                error_cm = PoseError::of(&e.pose, &truth).position_m * 100.0,
                error_deg = PoseError::of(&e.pose, &truth).heading_deg,
                odometry_cm = PoseError::of(&e.odometry, &truth).position_m * 100.0,
                odometry_deg = PoseError::of(&e.odometry, &truth).heading_deg,
                sigma_cm = ?(e.covariance[(0, 0)].sqrt() * 100.0, e.covariance[(1, 1)].sqrt() * 100.0),
                sigma_deg = e.covariance[(2, 2)].sqrt().to_degrees(),
                nees = published,
                "SLAM sweep"
            );
            Placed {
                error: PoseError::of(&e.pose, &truth),
                odometry: PoseError::of(&e.odometry, &truth),
                fix: published.filter(|_| e.state == FixState::Fix),
                nees: published,
                progress: progress(e.stamp_ns),
            }
        })
        .collect();
    let fused = fuse_tour(
        &scene,
        &tour,
        Placement::Localized,
        grid_over(&scene),
        features,
    )
    .context("today's localisation on the same tour")?;
    let localize = fused
        .sweeps
        .iter()
        .zip(fused_stamps(&tour, fused.sweeps.len()))
        .map(|(s, stamp)| {
            let truth = truth_at(&tour.poses, stamp);
            let odo = odometry_at(&tour.poses, stamp);
            let fix = if s.fixed {
                s.fix_nees.or(Some(f64::INFINITY))
            } else {
                None
            };
            Placed {
                error: s.error,
                odometry: PoseError::of(&pose_iso(&odo), &truth),
                fix,
                nees: fix,
                progress: progress(stamp),
            }
        })
        .collect();
    Ok(Run {
        family,
        profile,
        layout,
        seed,
        level,
        odometry,
        slam,
        localize,
        refused,
        maps,
        revised,
        landmarks,
    })
}

/// The first reading's stamp of each of the first `n` sweeps of `tour` (the sweeps the fusion's
/// tracker reports, in order).
fn fused_stamps(tour: &TourCapture, n: usize) -> Vec<u64> {
    let mut stamps: Vec<u64> = Vec::new();
    let mut last = None;
    for r in &tour.capture.readings {
        if last != Some(r.sweep_id) {
            stamps.push(r.host_stamp_ns);
            last = Some(r.sweep_id);
        }
    }
    stamps.truncate(n);
    stamps
}

/// Every run of `settings`.
pub fn evaluate(settings: &SlamSettings) -> Result<Vec<Run>> {
    let mut runs = Vec::new();
    for (family, profile) in tours(settings) {
        for &layout in &settings.layouts {
            for &level in &settings.levels {
                for &seed in &settings.seeds {
                    // A built-in tour has one layout: the layout seed varies its noise instead,
                    // so that the split into layouts still gives different runs.
                    let seed = if family.is_builtin() {
                        seed + 1000 * layout
                    } else {
                        seed
                    };
                    let r = run(
                        family,
                        layout,
                        seed,
                        level,
                        profile,
                        settings.config,
                        settings.rough_share,
                    )?;
                    tracing::info!(
                        family = family.name(),
                        %profile,
                        layout,
                        seed,
                        level = level.label(),
                        sweeps = r.slam.len(),
                        slam_max_cm = largest(&r.slam, false) * 100.0,
                        revised_max_cm = r.revised.iter().map(|e| e.position_m).fold(0.0, f64::max) * 100.0,
                        localize_max_cm = largest(&r.localize, false) * 100.0,
                        odometry_max_cm = largest_odometry(&r.slam, false) * 100.0,
                        "run done"
                    );
                    runs.push(r);
                }
            }
        }
    }
    Ok(runs)
}

fn largest(p: &[Placed], heading: bool) -> f64 {
    largest_of(p, heading, |s| &s.error)
}

fn largest_odometry(p: &[Placed], heading: bool) -> f64 {
    largest_of(p, heading, |s| &s.odometry)
}

/// The largest heading (or position) of the errors `of` picks from each sweep.
fn largest_of(p: &[Placed], heading: bool, of: impl Fn(&Placed) -> &PoseError) -> f64 {
    p.iter()
        .map(|s| {
            let e = of(s);
            if heading { e.heading_deg } else { e.position_m }
        })
        .fold(0.0, f64::max)
}

fn median(p: &[Placed], heading: bool) -> Option<f64> {
    Spread::of(p.iter().map(|s| {
        if heading {
            s.error.heading_deg
        } else {
            s.error.position_m
        }
    }))
    .map(|s| s.median)
}

/// The runs of one tour heard through one sensor at one odometry level.
fn runs_of(runs: &[Run], tour: Tour, level: OdometryLevel) -> Vec<&Run> {
    runs.iter()
        .filter(|r| (r.family, r.profile) == tour && r.level == level)
        .collect()
}

/// A tour and the sensor it was heard through.
type Tour = (Family, ProfileChoice);

/// Every tour of `settings` in the order of the report.
fn tours(settings: &SlamSettings) -> Vec<Tour> {
    settings
        .families
        .iter()
        .flat_map(|&f| settings.profiles.iter().map(move |&p| (f, p)))
        .collect()
}

/// A tour's name in the report: the family's, and the sensor's unless it is the simulator's
/// default.
fn tour_name((family, profile): Tour) -> String {
    match profile.0 {
        Some(p) => format!("{}, {p}", family.name()),
        None => family.name().to_string(),
    }
}

/// As [`over_runs`] for a figure whose worst is its lowest (precision, recall).
fn over_runs_lowest_worst(
    values: impl IntoIterator<Item = f64>,
    scale: f64,
    digits: usize,
) -> String {
    over_runs(values.into_iter().map(|v| -v), -scale, digits)
}

/// "median / worst" over runs of a per-run figure.
fn over_runs(values: impl IntoIterator<Item = f64>, scale: f64, digits: usize) -> String {
    Spread::of(values).map_or("–".into(), |s| {
        format!(
            "{:.digits$} / {:.digits$}",
            s.median * scale,
            s.worst * scale
        )
    })
}

/// `n` of `of` as a whole percentage, with as many decimals as it takes where the whole one
/// would read as all or none and is not (20 fixes of 9145 outside their ellipse are 99.8 %, not
/// 100 %).
fn share(n: usize, of: usize) -> String {
    if of == 0 {
        return "–".into();
    }
    let percent = 100.0 * n as f64 / of as f64;
    let reads_as = |decimals: usize| format!("{percent:.decimals$}");
    let all_or_none = |text: &str| text.parse::<f64>().is_ok_and(|p| p == 0.0 || p == 100.0);
    let decimals = if n == 0 || n == of {
        0
    } else {
        (0..6).find(|&d| !all_or_none(&reads_as(d))).unwrap_or(6)
    };
    format!("{} % of {of}", reads_as(decimals))
}

/// The figures as Markdown: one table per odometry level, a row per family and method.
pub fn markdown(settings: &SlamSettings, runs: &[Run]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Layouts {:?}, run seeds {:?} (echo and odometry noise; the signs of scale error and drift \
         drawn per seed; the built-in corridor and room-tour, which have one layout, run with seed \
         + 1000 × layout instead), odometry white noise 0.5 mm and 0.05° per 50 ms step. Per run: the \
         largest and the median error of the pose published for each sweep; \"median / worst\" \
         over the runs. Fixes: the sweeps a method calls fixed (the SLAM: matched and within \
         its σ limits; today's: `localize` accepted a fix).\n",
        settings.layouts, settings.seeds
    );
    for &level in &settings.levels {
        let _ = writeln!(
            s,
            "#### Odometry {}\n\n| tour | method | largest position error (cm) | largest heading \
             error (°) | median position error (cm) | fixes inside their 95 % ellipse | fixes \
             worse than odometry | sweeps fixed | sweeps inside their 95 % ellipse, fixed or \
             not | runs whose largest error exceeds odometry's |\n|---|---|---|---|---|---|---|---|---|---|",
            level.label()
        );
        for tour in tours(settings) {
            let these = runs_of(runs, tour, level);
            if these.is_empty() {
                continue;
            }
            type Pick = fn(&Run) -> &Vec<Placed>;
            let methods: [(&str, Pick); 2] = [
                ("SLAM", |r| &r.slam),
                ("today's `--localize`", |r| &r.localize),
            ];
            for (name, pick) in methods {
                let fixes: Vec<&Placed> = these
                    .iter()
                    .flat_map(|r| pick(r).iter())
                    .filter(|p| p.fix.is_some())
                    .collect();
                let inside = fixes
                    .iter()
                    .filter(|p| p.fix.is_some_and(|n| n <= CHI2_3_95))
                    .count();
                let worse = fixes.iter().filter(|p| p.worse_than_odometry()).count();
                let sweeps: usize = these.iter().map(|r| pick(r).len()).sum();
                let published: Vec<f64> = these
                    .iter()
                    .flat_map(|r| pick(r).iter())
                    .filter_map(|p| p.nees)
                    .collect();
                let covered = published.iter().filter(|&&n| n <= CHI2_3_95).count();
                let runs_worse = these
                    .iter()
                    .filter(|r| largest(pick(r), false) > largest_odometry(pick(r), false))
                    .count();
                let _ = writeln!(
                    s,
                    "| {} | {name} | {} | {} | {} | {} | {} | {} | {} | {} |",
                    tour_name(tour),
                    over_runs(these.iter().map(|r| largest(pick(r), false)), 100.0, 1),
                    over_runs(these.iter().map(|r| largest(pick(r), true)), 1.0, 1),
                    over_runs(
                        these.iter().filter_map(|r| median(pick(r), false)),
                        100.0,
                        1
                    ),
                    share(inside, fixes.len()),
                    share(worse, fixes.len()),
                    share(fixes.len(), sweeps),
                    share(covered, published.len()),
                    share(runs_worse, these.len()),
                );
            }
            let _ = writeln!(
                s,
                "| {} | odometry alone | {} | {} | – | – | – | – | – | – |",
                tour_name(tour),
                over_runs(
                    these.iter().map(|r| largest_odometry(&r.slam, false)),
                    100.0,
                    1
                ),
                over_runs(
                    these.iter().map(|r| largest_odometry(&r.slam, true)),
                    1.0,
                    1
                ),
            );
        }
        let _ = writeln!(
            s,
            "\nThe tour's map (recommended preset) against the true surfaces in sight of the \
             sweeps' true poses: precision and median error of the occupied cells, recall of the \
             surfaces (median / worst over runs); placed with the correction published when each \
             reading came (online), with each sweep's own as the whole tour finally estimates it \
             (revised: what the fusion's maps converge to as it follows `sonar-slam`'s \
             revisions), and at the true poses; with the largest error of the sweep poses \
             placing it.\n\n| tour | placement | largest pose error (cm) | largest heading \
             error (°) | precision | median error (cm) | recall |\n|---|---|---|---|---|---|---|"
        );
        for tour in tours(settings) {
            let these = runs_of(runs, tour, level);
            if these.is_empty() {
                continue;
            }
            type PickMap = fn(&TourMaps) -> &GridScore;
            type PickPoses = fn(&Run, bool) -> f64;
            let placements: [(&str, PickMap, PickPoses); 3] = [
                (
                    "online",
                    |m| &m.online,
                    |r, heading| largest(&r.slam, heading),
                ),
                (
                    "revised",
                    |m| &m.revised,
                    |r, heading| {
                        r.revised
                            .iter()
                            .map(|e| if heading { e.heading_deg } else { e.position_m })
                            .fold(0.0, f64::max)
                    },
                ),
                ("true poses", |m| &m.truth, |_, _| 0.0),
            ];
            for (name, pick, poses) in placements {
                let scores = || these.iter().map(|r| pick(&r.maps));
                let _ = writeln!(
                    s,
                    "| {} | {name} | {} | {} | {} | {} | {} |",
                    tour_name(tour),
                    over_runs(these.iter().map(|r| poses(r, false)), 100.0, 1),
                    over_runs(these.iter().map(|r| poses(r, true)), 1.0, 1),
                    over_runs_lowest_worst(scores().filter_map(|g| g.precision), 1.0, 2),
                    over_runs(scores().filter_map(|g| g.median_error_m), 100.0, 1),
                    over_runs_lowest_worst(scores().filter_map(|g| g.recall), 1.0, 2),
                );
            }
        }
        // The loop's laps: the largest error in the first and the last of its three laps (thirds of
        // the tour).
        for tour in tours(settings).into_iter().filter(|t| t.0 == Family::Loop) {
            let loops = runs_of(runs, tour, level);
            if loops.is_empty() {
                continue;
            }
            let third = |r: &Run, last: bool| {
                r.slam
                    .iter()
                    .filter(|p| {
                        if last {
                            p.progress > 2.0 / 3.0
                        } else {
                            p.progress <= 1.0 / 3.0
                        }
                    })
                    .map(|p| p.error.position_m)
                    .fold(0.0, f64::max)
            };
            let no_worse = loops
                .iter()
                .filter(|r| third(r, true) <= third(r, false) + WORSE_M)
                .count();
            let _ = writeln!(
                s,
                "\n{}, SLAM (three laps): largest position error in the first lap {} cm, in the \
                 last lap {} cm (median / worst over runs); the last lap no worse than the \
                 first (within {:.0} cm) in {}.",
                tour_name(tour),
                over_runs(loops.iter().map(|r| third(r, false)), 100.0, 1),
                over_runs(loops.iter().map(|r| third(r, true)), 100.0, 1),
                WORSE_M * 100.0,
                share(no_worse, loops.len()),
            );
        }
        let _ = writeln!(
            s,
            "\nThe SLAM's landmarks at the end of each tour against the true geometry \
             (`eval/src/landmarks.rs`): walls and points per run (median / most); walls on no \
             true wall (none within {:.0}° and {:.0} cm) and points on no surface (none within \
             {:.0} cm), of all over the runs; walls on a true wall whose error lies inside their \
             own 95 % ellipse.\n\n| tour | walls per run | points per run | phantom walls | \
             phantom points | walls inside their 95 % ellipse |\n|---|---|---|---|---|---|",
            landmarks::WALL_DEGREES,
            landmarks::WALL_METRES * 100.0,
            landmarks::POINT_METRES * 100.0,
        );
        for tour in tours(settings) {
            let these = runs_of(runs, tour, level);
            if these.is_empty() {
                continue;
            }
            let sum = |f: fn(&LandmarkScore) -> usize| -> usize {
                these.iter().map(|r| f(&r.landmarks)).sum()
            };
            let per_run = |f: fn(&LandmarkScore) -> usize| {
                let mut n: Vec<usize> = these.iter().map(|r| f(&r.landmarks)).collect();
                n.sort_unstable();
                format!("{} / {}", n[n.len() / 2], n[n.len() - 1])
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} |",
                tour_name(tour),
                per_run(|l| l.walls),
                per_run(|l| l.points),
                share(sum(|l| l.phantom_walls), sum(|l| l.walls)),
                share(sum(|l| l.phantom_points), sum(|l| l.points)),
                share(sum(|l| l.walls_inside_95), sum(|l| l.walls_with_covariance)),
            );
        }
        let refused: Vec<String> = tours(settings)
            .into_iter()
            .map(|t| {
                let n: u32 = runs_of(runs, t, level).iter().map(|r| r.refused).sum();
                format!("{} {n}", tour_name(t))
            })
            .collect();
        let _ = writeln!(
            s,
            "\nSweeps the SLAM refused to keep the odometry plausible: {}.\n",
            refused.join(", ")
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_share_reads_as_all_or_none_only_when_it_is() {
        assert_eq!(share(9145, 9145), "100 % of 9145");
        assert_eq!(share(9125, 9145), "99.8 % of 9145");
        assert_eq!(share(9999, 10000), "99.99 % of 10000");
        assert_eq!(share(1, 3000), "0.03 % of 3000");
        assert_eq!(share(0, 3000), "0 % of 3000");
        assert_eq!(share(87, 100), "87 % of 100");
        assert_eq!(share(0, 0), "–");
    }

    #[test]
    fn every_family_makes_a_valid_tour_scene_and_layouts_differ() {
        let all = Family::ALL
            .into_iter()
            .flat_map(|f| (1..=20).map(move |l| (f, l)));
        for (family, layout) in all {
            let (scene, metres) = family.scene(layout).unwrap();
            assert!(scene.robot.is_some(), "{family:?}");
            assert!(metres > 5.0, "{family:?}: {metres}");
            // Every waypoint lies inside the scene, off its walls.
            for p in &scene.robot.as_ref().unwrap().waypoints {
                assert!(
                    scene.distance_to_surface(*p) > 0.3,
                    "{family:?} {layout}: {p:?}"
                );
            }
        }
        let (a, _) = Family::Hallway.scene(1).unwrap();
        let (b, _) = Family::Hallway.scene(2).unwrap();
        assert_ne!(a.walls()[0].a, b.walls()[0].a);
    }

    #[test]
    fn a_tours_rough_walls_are_drawn_on_their_own_and_change_nothing_else() {
        use sonar_sim::Surface;
        for family in Family::ALL {
            let (smooth, metres) = family.scene(3).unwrap();
            let (rough, rough_metres) = family.scene_with_rough_walls(3, 0.5).unwrap();
            assert_eq!(metres, rough_metres);
            assert_eq!(smooth.robot, rough.robot, "{}", family.name());
            assert_eq!(smooth.walls().len(), rough.walls().len());
            for (a, b) in smooth.walls().iter().zip(rough.walls()) {
                assert_eq!((a.a, a.b, a.surface), (b.a, b.b, Surface::Hard));
                assert!(matches!(b.surface, Surface::Hard | Surface::Rough));
            }
        }
        let all = |f: Family| f.scene_with_rough_walls(3, 1.0).unwrap().0;
        assert!(
            all(Family::Office)
                .walls()
                .iter()
                .all(|w| w.surface == Surface::Rough)
        );
        assert!(Family::Office.scene_with_rough_walls(3, 1.5).is_err());
    }

    /// The structural check CI runs (the figures come from `sonar-eval --slam`, out of CI): a
    /// short stop-and-scan tour through the SLAM gives one estimate per sweep, each with a finite
    /// pose and a symmetric, positive covariance, and fixes only where it matched landmarks.
    #[test]
    fn a_short_tour_gives_an_estimate_per_sweep() {
        let scene = Scene::builtin("corridor").unwrap();
        let tour = capture_tour(
            scene.clone(),
            Scan::for_scene(&scene),
            2.0,
            OdometryLevel::MEDIUM.params(1),
            POSE_RATE_HZ,
            1,
        )
        .unwrap();
        let output = run_slam(&tour, SlamConfig::default()).unwrap();
        let estimates = &output.estimates;
        assert_eq!(estimates.len(), fused_stamps(&tour, usize::MAX).len());
        // The trajectory holds every sweep, in order, and the maps are scored.
        assert_eq!(
            output
                .trajectory
                .iter()
                .map(|p| p.sweep_id)
                .collect::<Vec<_>>(),
            estimates.iter().map(|e| e.sweep_id).collect::<Vec<_>>()
        );
        let maps = tour_maps(&scene, &tour, &output).unwrap();
        for score in [maps.online, maps.revised, maps.truth] {
            assert!(score.occupied > 0 && score.visible > 0, "{score:?}");
        }
        assert!(estimates.len() >= 3, "{}", estimates.len());
        for e in estimates {
            assert!(
                e.pose.translation.vector.iter().all(|v| v.is_finite()),
                "{e:?}"
            );
            let c = e.covariance;
            assert!(
                (c - c.transpose()).amax() < 1e-9 && c.symmetric_eigenvalues().min() > 0.0,
                "{e:?}"
            );
            if e.state == FixState::Fix {
                assert!(e.matched > 0, "{e:?}");
            }
        }
        // The first sweep has nothing to match yet.
        assert_eq!(estimates[0].state, FixState::NoLandmarks);
    }

    /// A tour heard through a sensor profile is captured with that profile's head: the `nxt`'s
    /// two pings per 6° reading and 2.54 m reach, not the paper head's four and 4 m.
    #[test]
    fn a_tour_through_a_profile_is_heard_by_its_head() {
        let (mut scene, _) = Family::Hallway.scene(1).unwrap();
        scene.set_profile(sonar_sim::SensorProfile::Nxt);
        let tour = capture_tour(
            scene.clone(),
            Scan::for_scene(&scene),
            1.0,
            OdometryLevel::MEDIUM.params(1),
            POSE_RATE_HZ,
            1,
        )
        .unwrap();
        let readings = &tour.capture.readings;
        assert!(!readings.is_empty());
        for r in readings {
            assert_eq!((r.ping_count, r.max_range_m), (2, 2.54), "{r:?}");
        }
    }

    /// A driven hallway's second sweep (layout 35, seed 3), taken while the robot turns 90° into
    /// the second leg against the head, read at the true poses: the end wall ahead, 1.88 m from
    /// where the sweep began, is found once and square on. (A normal 4° off once gave it a second
    /// time, whole too, 4.9° off: from it the SLAM turned the pose by 13.6°.)
    #[test]
    fn a_wall_seen_while_turning_into_a_hallway_is_one_wall() {
        let (scene, metres) = Family::HallwayDriving.scene(35).unwrap();
        let tour = capture_tour(
            scene.clone(),
            Scan::for_scene(&scene),
            metres,
            OdometryLevel::MEDIUM.params(3),
            POSE_RATE_HZ,
            3,
        )
        .unwrap();
        let second = tour.capture.readings[0].sweep_id + 1;
        let readings: Vec<&Reading> = tour
            .capture
            .readings
            .iter()
            .filter(|r| r.sweep_id == second)
            .collect();
        let pose = |r: &Reading| pose_iso(&truth_at(&tour.poses, r.host_stamp_ns));
        let reference = pose(readings[0]);
        let placed: Vec<(Reading, Isometry2<f64>)> = readings
            .iter()
            .map(|r| (**r, reference.inverse() * pose(r)))
            .collect();
        let turned = placed.last().unwrap().1.rotation.angle().to_degrees();
        assert!((turned - 90.0).abs() < 10.0, "{turned}");
        let walls = sonar_features::FeatureMap::new(SlamConfig::default().features)
            .unwrap()
            .walls_on_the_move(&placed, sonar_features::NearRegions::AsWalls);
        let end_wall: Vec<_> = walls
            .iter()
            .filter(|o| o.whole && (o.range_m - 1.88).abs() < 0.03)
            .collect();
        assert_eq!(end_wall.len(), 1, "{walls:?}");
        assert!(end_wall[0].bearing_deg.abs() < 1.0, "{walls:?}");
    }

    #[test]
    fn polylines_are_divided_into_short_legs() {
        let p = along(&[[0.0, 0.0], [2.5, 0.0], [2.5, 1.0]], 1.0);
        assert_eq!(p.len(), 5);
        assert!(
            p.windows(2)
                .all(|w| (Vector2::from(w[1]) - Vector2::from(w[0])).norm() <= 1.0 + 1e-12)
        );
    }
}
