//! The motion evaluation (issue 12): the head on a robot touring a scene, its readings fused at
//! the true poses, at a drifting odometry, and at that odometry corrected by sonar localisation.
//!
//! # The runs
//!
//! A tour scene (`corridor`: stop-and-scan through a corridor and two rooms; `room-tour`: the
//! paper's room, scanning while driving) is captured as `sonar-sim` serves it
//! ([`capture_tour`]): every ping from the robot's true pose of its instant, the odometry with
//! the settings' errors (explicit, not the scene's), both sampled at [`POSE_RATE_HZ`] of the
//! virtual clock, until the first sweep to end after the robot has driven the tour's length.
//! The same capture is then fused three ways, each as `sonar-fusion` does it ([`fuse_tour`]: an
//! [`Engine`] and a [`FeatureTracker`], every reading placed at the pose interpolated at its
//! stamp, the poses handed to the engine as they would have arrived, i.e. all those stamped up
//! to the reading's):
//!
//! - [`Placement::Truth`]: the true poses on `robot/pose`;
//! - [`Placement::Odometry`]: the odometry's;
//! - [`Placement::Localized`]: the odometry's, with [`FeatureTracker::with_localization`] and the
//!   engine's correction set after every sweep (`Features::sweep_done` of the process).
//!
//! The grid is the `recommended` preset's 2 cm cells over the scene's walls plus
//! [`GRID_MARGIN_M`] ([`grid_over`]).
//!
//! # The figures
//!
//! - The map: [`scene_walls`] — median distance of the occupied cells (p > 0.5, as for the room)
//!   to the nearest wall, and the share of the scene's whole wall length with an occupied cell
//!   within [`COVER_TOLERANCE_M`].
//! - The poses: for each sweep, the pose it was placed at (localisation's fix, else the
//!   prediction) against the truth at its stamp (the first reading's); for each reading, the pose
//!   the grid placed it at against the truth at its stamp. Position and heading error, median,
//!   p95 and max over the tour.
//!
//! Over the seeds (each seeds the echo noise and the odometry's noise), a figure is reported as
//! its median and its worst case.

use std::fmt::Write as _;

use anyhow::{Context, Result, ensure};
use nalgebra::{Isometry2, Matrix3, RealField, Vector3};
use sonar_common::ipc::{LAYOUT_VERSION, Pose2D};
use sonar_features::{DriftEstimate, FeatureConfig};
use sonar_fusion::engine::Engine;
use sonar_fusion::{FeatureTracker, FusionConfig, GridConfig, Preset, SweepOutcome};
use sonar_sim::geometry::angle_diff_rad;
use sonar_sim::{OdometryParams, Pose, PoseSample, Scene};

use crate::feature_report::Spread;
use crate::features::scene_feature_config;
use crate::image::{self, Canvas, Window};
use crate::metrics::{MapView, SceneWalls, quantile, scene_walls};
use crate::pipeline::{Scan, TourCapture, capture_tour, probability_view};

/// The built-in scenes with a robot.
pub const TOUR_SCENES: [&str; 2] = ["corridor", "room-tour"];
/// Poses per second of simulated time: `sonar-sim`'s default `--pose-rate`.
pub const POSE_RATE_HZ: f64 = 20.0;
/// A wall sample is covered by an occupied cell centre within this distance.
pub const COVER_TOLERANCE_M: f64 = 0.05;
/// The grid reaches this far beyond the scene's walls.
pub const GRID_MARGIN_M: f64 = 0.5;

/// The aims: localisation keeps every sweep's pose within these …
pub const AIM_POSITION_M: f64 = 0.05;
pub const AIM_HEADING_DEG: f64 = 2.0;
/// … and the map's median wall error within this factor of the true-pose map's.
pub const AIM_WALL_RATIO: f64 = 1.5;

/// How the motion evaluation is run.
#[derive(Debug, Clone, PartialEq)]
pub struct MotionSettings {
    pub scenes: Vec<String>,
    pub seeds: Vec<u64>,
    /// Length of each tour (true distance driven), metres.
    pub metres: f64,
    /// The odometry's errors (the scenes' own `[odometry]` is not used).
    pub odometry: OdometryParams,
    /// Pixels per grid cell in the pictures.
    pub scale: usize,
}

impl MotionSettings {
    /// Both tour scenes, the given seeds and length, 3 % scale error and 2°/m heading drift with
    /// the tour scenes' small white noise (0.5 mm and 0.05° per 50 ms step).
    pub fn drifting(seeds: Vec<u64>, metres: f64, scale: usize) -> Self {
        Self {
            scenes: TOUR_SCENES.iter().map(|s| (*s).to_owned()).collect(),
            seeds,
            metres,
            odometry: OdometryParams {
                scale_error: 0.03,
                heading_drift_deg_per_m: 2.0,
                noise_m: 0.0005,
                noise_deg: 0.05,
            },
            scale,
        }
    }
}

/// Which poses the readings are placed at.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Placement {
    Truth,
    Odometry,
    Localized,
}

impl Placement {
    pub const ALL: [Placement; 3] = [Placement::Truth, Placement::Odometry, Placement::Localized];

    pub fn label(self) -> &'static str {
        match self {
            Placement::Truth => "true poses",
            Placement::Odometry => "odometry",
            Placement::Localized => "odometry + localisation",
        }
    }
}

/// Position and heading error of one pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseError {
    pub position_m: f64,
    /// Absolute, degrees.
    pub heading_deg: f64,
}

impl PoseError {
    /// `used` against `truth`.
    pub fn of<T: RealField + Copy + Into<f64>>(used: &Isometry2<T>, truth: &Pose) -> Self {
        let (x, y) = (used.translation.x.into(), used.translation.y.into());
        Self {
            position_m: (x - truth.at.x).hypot(y - truth.at.y),
            heading_deg: angle_diff_rad(used.rotation.angle().into(), truth.heading_rad)
                .to_degrees()
                .abs(),
        }
    }
}

/// Median, 95th percentile and largest of a set of values (nearest rank).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tail {
    pub median: f64,
    pub p95: f64,
    pub max: f64,
}

impl Tail {
    /// `None` for no values.
    pub fn of(values: impl IntoIterator<Item = f64>) -> Option<Self> {
        let mut v: Vec<f64> = values.into_iter().collect();
        v.sort_by(f64::total_cmp);
        Some(Self {
            median: quantile(&v, 0.5)?,
            p95: quantile(&v, 0.95)?,
            max: quantile(&v, 1.0)?,
        })
    }
}

/// Position and heading tails of a set of pose errors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseTails {
    pub position_m: Tail,
    pub heading_deg: Tail,
}

impl PoseTails {
    pub fn of(errors: &[PoseError]) -> Option<Self> {
        Some(Self {
            position_m: Tail::of(errors.iter().map(|e| e.position_m))?,
            heading_deg: Tail::of(errors.iter().map(|e| e.heading_deg))?,
        })
    }
}

/// One capture fused one way.
#[derive(Debug, Clone)]
pub struct Fused {
    pub placement: Placement,
    /// The probability grid at the end of the tour.
    pub map: MapView,
    pub walls: SceneWalls,
    /// Per sweep: the pose it was placed at against the truth, and how it came about.
    pub sweeps: Vec<SweepPose>,
    /// Per reading: the grid's placement against the truth.
    pub readings: Vec<PoseError>,
    /// Sweeps localisation fixed.
    pub fixes: u32,
    /// The odometry's drift as localisation learnt it by the end (localised runs only).
    pub drift: Option<DriftEstimate>,
}

/// How one sweep was placed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepPose {
    /// The pose it was placed at (the fix, else the prediction) against the truth.
    pub error: PoseError,
    /// The prediction against the truth.
    pub predicted: PoseError,
    /// Localisation fixed it.
    pub fixed: bool,
    /// The robot moved (over 1 cm or 1°) between its first and last reading: its pings were not
    /// taken from one place.
    pub on_the_move: bool,
    /// The fix's normalised estimation error squared against its own covariance (x, y, θ).
    pub fix_nees: Option<f64>,
}

impl SweepPose {
    /// A fix that left the pose further from the truth than the prediction, in position or
    /// heading.
    pub fn fix_made_worse(&self) -> bool {
        self.fixed
            && (self.error.position_m > self.predicted.position_m
                || self.error.heading_deg > self.predicted.heading_deg)
    }
}

/// The normalised estimation error squared of `pose` with covariance `covariance` (x, y, θ)
/// against `truth`; `None` for a covariance that is not invertible.
pub fn nees(pose: &Isometry2<f64>, covariance: &Matrix3<f64>, truth: &Pose) -> Option<f64> {
    let d = Vector3::new(
        pose.translation.x - truth.at.x,
        pose.translation.y - truth.at.y,
        angle_diff_rad(pose.rotation.angle(), truth.heading_rad),
    );
    Some((d.transpose() * covariance.try_inverse()? * d)[(0, 0)])
}

/// A grid of the default cell size over `scene`'s walls and its robot's waypoints, plus
/// [`GRID_MARGIN_M`] on every side: square, centred on their bounding box.
pub fn grid_over(scene: &Scene) -> GridConfig {
    let base = GridConfig::default();
    let points = scene
        .walls()
        .iter()
        .flat_map(|w| [w.a, w.b])
        .chain(scene.robot.iter().flat_map(|r| r.waypoints.iter().copied()));
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points {
        lo = [lo[0].min(p.x), lo[1].min(p.y)];
        hi = [hi[0].max(p.x), hi[1].max(p.y)];
    }
    if !(lo[0] <= hi[0] && lo[1] <= hi[1]) {
        return base;
    }
    let side = (hi[0] - lo[0]).max(hi[1] - lo[1]) + 2.0 * GRID_MARGIN_M;
    GridConfig {
        // Less a hair, so that a whole number of cells is not rounded up by the f32 cell size.
        cells: (side / f64::from(base.resolution_m) - 1e-3).ceil() as u32,
        centre_x_m: ((lo[0] + hi[0]) / 2.0) as f32,
        centre_y_m: ((lo[1] + hi[1]) / 2.0) as f32,
        ..base
    }
}

/// The true pose at `stamp_ns` of the virtual clock, interpolated between the samples around it
/// (linear in position, the shorter way in heading).
pub fn truth_at(poses: &[PoseSample], stamp_ns: u64) -> Pose {
    let t_us = stamp_ns as f64 / 1000.0;
    let i = poses.partition_point(|s| s.t_us as f64 <= t_us);
    match (i.checked_sub(1).and_then(|k| poses.get(k)), poses.get(i)) {
        (Some(a), Some(b)) => {
            let f = (t_us - a.t_us as f64) / (b.t_us - a.t_us) as f64;
            Pose {
                at: a.truth.at + (b.truth.at - a.truth.at) * f,
                heading_rad: a.truth.heading_rad
                    + angle_diff_rad(b.truth.heading_rad, a.truth.heading_rad) * f,
            }
        }
        (Some(only), None) | (None, Some(only)) => only.truth,
        (None, None) => Pose::default(),
    }
}

/// `sample` as `sonar-sim` publishes it on `robot/pose`, with the truth or the odometry.
fn wire(sample: &PoseSample, placement: Placement) -> Pose2D {
    let p = match placement {
        Placement::Truth => sample.truth,
        Placement::Odometry | Placement::Localized => sample.odometry,
    };
    Pose2D {
        stamp_ns: sample.t_us * 1000,
        x_m: p.at.x as f32,
        y_m: p.at.y as f32,
        theta_rad: p.heading_rad as f32,
        layout_version: LAYOUT_VERSION,
    }
}

/// Fuses `tour` as `sonar-fusion` would with `placement`'s poses on `robot/pose` (and, for
/// [`Placement::Localized`], `--localize`), on `grid`, the features with `features`, and
/// measures it against `scene`.
pub fn fuse_tour(
    scene: &Scene,
    tour: &TourCapture,
    placement: Placement,
    grid: GridConfig,
    features: FeatureConfig,
) -> Result<Fused> {
    let config = FusionConfig {
        grid,
        ..FusionConfig::preset(Preset::Recommended)
    };
    let mut engine = Engine::new(config, 0).context("setting up the fusion engine")?;
    let mut tracker = match placement {
        Placement::Localized => FeatureTracker::with_localization(features),
        Placement::Truth | Placement::Odometry => FeatureTracker::new(features),
    }
    .context("setting up the features")?;
    let localize = placement == Placement::Localized;
    let mut sweeps = Vec::new();
    let sweep = |outcome: &SweepOutcome, last_stamp_ns: u64| {
        log_sweep(outcome, &tour.poses, placement);
        let truth = truth_at(&tour.poses, outcome.stamp_ns);
        let last = truth_at(&tour.poses, last_stamp_ns);
        let used = outcome.fix.map_or(outcome.predicted, |f| f.pose);
        SweepPose {
            fix_nees: outcome
                .fix
                .and_then(|f| nees(&f.pose, &f.covariance, &truth)),
            error: PoseError::of(&used, &truth),
            predicted: PoseError::of(&outcome.predicted, &truth),
            fixed: outcome.fix.is_some(),
            on_the_move: (last.at - truth.at).norm() > 0.01
                || angle_diff_rad(last.heading_rad, truth.heading_rad).abs() > 1f64.to_radians(),
        }
    };
    let mut last_stamp_ns = 0;
    let mut readings = Vec::with_capacity(tour.capture.readings.len());
    let mut poses = tour.poses.iter().peekable();
    for r in &tour.capture.readings {
        // As the process does: every pose up to the reading's stamp, and the first after it, for
        // which the fusion waits to place the reading by interpolation (`docs/fusion.md`).
        while let Some(s) = poses
            .next_if(|s| s.t_us * 1000 <= r.host_stamp_ns || engine.awaits_pose(r.host_stamp_ns))
        {
            engine
                .set_pose(&wire(s, placement))
                .with_context(|| format!("pose at {} µs refused", s.t_us))?;
        }
        engine.fuse(r);
        readings.push(PoseError::of(
            engine.pose(),
            &truth_at(&tour.poses, r.host_stamp_ns),
        ));
        // After fusing, as the process does: the sweep is placed where the engine placed its
        // first reading; the correction goes to the engine after every reading.
        let finished = tracker.push(r, engine.pose());
        if localize {
            engine.set_correction(tracker.correction());
        }
        if let Some(outcome) = finished {
            sweeps.push(sweep(&outcome, last_stamp_ns));
        }
        last_stamp_ns = r.host_stamp_ns;
    }
    if let Some(outcome) = tracker.finish_sweep() {
        sweeps.push(sweep(&outcome, last_stamp_ns));
    }
    ensure!(
        engine.rejected_readings() == 0,
        "the kernels refused {} readings",
        engine.rejected_readings()
    );
    let map = probability_view(engine.mapper());
    Ok(Fused {
        placement,
        walls: scene_walls(
            &map,
            scene.walls(),
            |p| scene.distance_to_surface(p),
            COVER_TOLERANCE_M,
        ),
        sweeps,
        readings,
        fixes: tracker.fixes(),
        drift: tracker.drift(),
        map,
    })
}

/// A sweep's prediction and fix against the truth, at debug level (`RUST_LOG=sonar_eval=debug`).
fn log_sweep(outcome: &SweepOutcome, poses: &[PoseSample], placement: Placement) {
    let truth = truth_at(poses, outcome.stamp_ns);
    let predicted = PoseError::of(&outcome.predicted, &truth);
    let fixed = outcome.fix.map(|f| PoseError::of(&f.pose, &truth));
    tracing::debug!(
        placement = placement.label(),
        sweep = outcome.sweep_id,
        t_s = outcome.stamp_ns as f64 / 1e9,
        at = ?(truth.at.x, truth.at.y, truth.heading_rad.to_degrees()),
        predicted_cm = predicted.position_m * 100.0,
        predicted_deg = predicted.heading_deg,
        fixed_cm = fixed.map(|e| e.position_m * 100.0),
        fixed_deg = fixed.map(|e| e.heading_deg),
        matched = outcome.fix.map(|f| f.matched),
        rcds = outcome.rcds,
        ranged = outcome.ranged,
        added = outcome.added,
        refined = outcome.refined,
        "sweep placed"
    );
}

/// One tour of one scene with one seed, fused every way.
#[derive(Debug, Clone)]
pub struct TourRun {
    pub seed: u64,
    pub driven_m: f64,
    pub readings: usize,
    pub sweeps: u32,
    pub simulated_s: f64,
    /// In the order of [`Placement::ALL`].
    pub fused: Vec<Fused>,
}

impl TourRun {
    pub fn get(&self, placement: Placement) -> Option<&Fused> {
        self.fused.iter().find(|f| f.placement == placement)
    }
}

/// Every seed's tour of one scene.
#[derive(Debug, Clone)]
pub struct SceneMotion {
    pub name: String,
    pub description: String,
    pub grid: GridConfig,
    pub runs: Vec<TourRun>,
    /// The first seed's maps: true poses | odometry | localised | actual setup.
    pub picture: Option<Canvas>,
}

/// `run`'s three maps beside the scene's truth, `scale` pixels per cell.
pub fn picture(scene: &Scene, run: &TourRun, scale: usize) -> Option<Canvas> {
    let first = run.fused.first()?;
    let g = first.map.geometry();
    let window = Window::around(scene, g, GRID_MARGIN_M / 2.0);
    let mut row: Vec<Canvas> = run
        .fused
        .iter()
        .map(|f| image::map_panel(&f.map, window, scale, image::probability_rgb))
        .collect();
    row.push(image::truth_panel(scene, g, window, scale));
    Some(image::compose(&[row], Some(0)))
}

/// Captures and fuses `scene`'s tour with `seed`.
pub fn tour_run(scene: &Scene, settings: &MotionSettings, seed: u64) -> Result<TourRun> {
    let tour = capture_tour(
        scene.clone(),
        Scan::for_scene(scene),
        settings.metres,
        settings.odometry,
        POSE_RATE_HZ,
        seed,
    )
    .with_context(|| format!("touring scene {} with seed {seed}", scene.name))?;
    let grid = grid_over(scene);
    let fused = Placement::ALL
        .iter()
        .map(|&p| {
            fuse_tour(scene, &tour, p, grid, scene_feature_config(scene))
                .with_context(|| format!("fusing {} with {}", scene.name, p.label()))
        })
        .collect::<Result<_>>()?;
    Ok(TourRun {
        seed,
        driven_m: tour.driven_m,
        readings: tour.capture.readings.len(),
        sweeps: tour.capture.sweeps,
        simulated_s: tour.capture.duration_s,
        fused,
    })
}

/// Runs every scene of `settings` with every seed.
pub fn evaluate(settings: &MotionSettings) -> Result<Vec<SceneMotion>> {
    settings
        .scenes
        .iter()
        .map(|name| {
            let scene = Scene::builtin(name).with_context(|| format!("loading scene {name}"))?;
            let runs = settings
                .seeds
                .iter()
                .map(|&seed| {
                    let run = tour_run(&scene, settings, seed)?;
                    tracing::info!(
                        scene = %name,
                        seed,
                        driven_m = run.driven_m,
                        sweeps = run.sweeps,
                        "tour done"
                    );
                    Ok(run)
                })
                .collect::<Result<Vec<_>>>()?;
            Ok(SceneMotion {
                name: name.clone(),
                description: scene.description.clone(),
                grid: grid_over(&scene),
                picture: runs
                    .first()
                    .and_then(|r| picture(&scene, r, settings.scale)),
                runs,
            })
        })
        .collect()
}

/// Median and worst (largest, or smallest with `lowest_worst`) over the seeds.
fn over_seeds(values: impl IntoIterator<Item = f64>, lowest_worst: bool) -> Option<(f64, f64)> {
    let sign = if lowest_worst { -1.0 } else { 1.0 };
    Spread::of(values.into_iter().map(|v| sign * v)).map(|s| (sign * s.median, sign * s.worst))
}

/// The runs of `placement` in every seed's tour.
fn fused(scene: &SceneMotion, placement: Placement) -> impl Iterator<Item = &Fused> {
    scene.runs.iter().filter_map(move |r| r.get(placement))
}

/// "median / worst" of a figure over the seeds, times `scale`, with `digits` decimals.
fn cell(
    scene: &SceneMotion,
    placement: Placement,
    figure: impl Fn(&Fused) -> Option<f64>,
    scale: f64,
    digits: usize,
    lowest_worst: bool,
) -> String {
    over_seeds(fused(scene, placement).filter_map(figure), lowest_worst).map_or_else(
        || "–".into(),
        |(m, w)| format!("{:.digits$} / {:.digits$}", m * scale, w * scale),
    )
}

fn sweep_tails(f: &Fused) -> Option<PoseTails> {
    PoseTails::of(&f.sweeps.iter().map(|s| s.error).collect::<Vec<_>>())
}

/// Ratio of the localised map's median wall error to the true-pose map's, per seed.
fn wall_ratios(scene: &SceneMotion) -> Vec<f64> {
    scene
        .runs
        .iter()
        .filter_map(|r| {
            let truth = r.get(Placement::Truth)?.walls.median_distance_m?;
            let localized = r.get(Placement::Localized)?.walls.median_distance_m?;
            (truth > 0.0).then(|| localized / truth)
        })
        .collect()
}

/// The motion evaluation as Markdown: the aims, then one table per scene.
pub fn markdown(settings: &MotionSettings, scenes: &[SceneMotion]) -> String {
    let mut s = String::new();
    let o = settings.odometry;
    let _ = writeln!(
        s,
        "### Motion and localisation on the tour scenes\n\n\
         Each tour scene driven {} m (true distance, to the end of the sweep then under way) with \
         seeds {:?} (echo noise and odometry noise); odometry {:+.1} % on distance, {:+.1}°/m \
         heading drift, white noise σ {:.1} mm and {:.2}° per moving step; poses at {} Hz of \
         simulated time; the `recommended` preset. Each capture fused with the true poses, with \
         the odometry, and with the odometry under localisation. Median / worst over the seeds.\n",
        settings.metres,
        settings.seeds,
        o.scale_error * 100.0,
        o.heading_drift_deg_per_m,
        o.noise_m * 1000.0,
        o.noise_deg,
        POSE_RATE_HZ,
    );
    let _ = writeln!(
        s,
        "| aim | scene | measured (median / worst over seeds) | verdict |\n|---|---|---|---|"
    );
    for scene in scenes {
        let max_of = |p: Placement, heading: bool| {
            over_seeds(
                fused(scene, p).filter_map(sweep_tails).map(|t| {
                    if heading {
                        t.heading_deg.max
                    } else {
                        t.position_m.max
                    }
                }),
                false,
            )
        };
        let loc = (
            max_of(Placement::Localized, false),
            max_of(Placement::Localized, true),
        );
        let odo = (
            max_of(Placement::Odometry, false),
            max_of(Placement::Odometry, true),
        );
        let fmt = |v: Option<(f64, f64)>, scale: f64, unit: &str| {
            v.map_or("–".into(), |(m, w)| {
                format!("{:.1} / {:.1} {unit}", m * scale, w * scale)
            })
        };
        let verdict_pose = match loc {
            (Some((_, p)), Some((_, h))) if p <= AIM_POSITION_M && h <= AIM_HEADING_DEG => {
                "met".to_owned()
            }
            (Some((_, p)), Some((_, h))) => {
                let mut by = Vec::new();
                if p > AIM_POSITION_M {
                    by.push(format!("{:.1} cm", (p - AIM_POSITION_M) * 100.0));
                }
                if h > AIM_HEADING_DEG {
                    by.push(format!("{:.1}°", h - AIM_HEADING_DEG));
                }
                format!("missed by {}", by.join(" and "))
            }
            _ => "no sweeps".to_owned(),
        };
        let _ = writeln!(
            s,
            "| localisation keeps every sweep's pose within {:.0} cm and {:.0}° | {} | largest \
             error over the tour: {}, {} (odometry alone: {}, {}) | {verdict_pose} |",
            AIM_POSITION_M * 100.0,
            AIM_HEADING_DEG,
            scene.name,
            fmt(loc.0, 100.0, "cm"),
            fmt(loc.1, 1.0, "°"),
            fmt(odo.0, 100.0, "cm"),
            fmt(odo.1, 1.0, "°"),
        );
        let ratio = over_seeds(wall_ratios(scene), false);
        let verdict_map = match ratio {
            Some((_, w)) if w <= AIM_WALL_RATIO => "met".to_owned(),
            Some((_, w)) => format!("missed by {:.2}×", w - AIM_WALL_RATIO),
            None => "no map".to_owned(),
        };
        let median_cm = |p| cell(scene, p, |f| f.walls.median_distance_m, 100.0, 1, false);
        let _ = writeln!(
            s,
            "| map's median wall error within {AIM_WALL_RATIO}× the true-pose map's | {} | ratio \
             {} ({} cm localised, {} cm true poses, {} cm odometry alone) | {verdict_map} |",
            scene.name,
            ratio.map_or("–".into(), |(m, w)| format!("{m:.2} / {w:.2}")),
            median_cm(Placement::Localized),
            median_cm(Placement::Truth),
            median_cm(Placement::Odometry),
        );
    }
    for scene in scenes {
        let g = scene.grid;
        let runs = &scene.runs;
        let driven = Spread::of(runs.iter().map(|r| r.driven_m));
        let sweeps = Spread::of(runs.iter().map(|r| f64::from(r.sweeps)));
        let readings = Spread::of(runs.iter().map(|r| r.readings as f64));
        let simulated = Spread::of(runs.iter().map(|r| r.simulated_s));
        let median = |v: Option<Spread>| v.map_or(0.0, |v| v.median);
        let _ = writeln!(
            s,
            "\n#### {}: {}\n\n{:.1} m driven, {:.0} sweeps, {:.0} readings, {:.0} s simulated \
             (medians over the seeds); grid {} × {} cells of {:.0} cm centred on ({}, {}) m.\n",
            scene.name,
            scene.description,
            median(driven),
            median(sweeps),
            median(readings),
            median(simulated),
            g.cells,
            g.cells,
            g.resolution_m * 100.0,
            g.centre_x_m,
            g.centre_y_m,
        );
        let _ = writeln!(
            s,
            "| poses | wall error: median (cm) | walls covered within {:.0} cm (%) | sweep pose \
             position: median / p95 / max (cm) | sweep heading: median / p95 / max (°) | \
             readings placed: largest position (cm) / heading (°) error | sweeps fixed / all \
             (fixes of sweeps taken on the move, fixes that made the pose worse), per seed |\n\
             |---|---|---|---|---|---|---|",
            COVER_TOLERANCE_M * 100.0
        );
        for p in Placement::ALL {
            let tail = |pick: fn(&PoseTails) -> f64, scale: f64, digits: usize| {
                cell(
                    scene,
                    p,
                    |f| sweep_tails(f).map(|t| pick(&t)),
                    scale,
                    digits,
                    false,
                )
            };
            let readings = |pick: fn(&PoseTails) -> f64, scale: f64, digits: usize| {
                cell(
                    scene,
                    p,
                    |f| PoseTails::of(&f.readings).map(|t| pick(&t)),
                    scale,
                    digits,
                    false,
                )
            };
            // Per seed: fixes of all sweeps; fixes of sweeps taken on the move; fixes that made
            // the pose worse.
            let fixes: Vec<String> = runs
                .iter()
                .filter_map(|r| r.get(p))
                .map(|f| {
                    let count =
                        |keep: fn(&SweepPose) -> bool| f.sweeps.iter().filter(|s| keep(s)).count();
                    format!(
                        "{}/{} ({} moving, {} worse)",
                        f.fixes,
                        f.sweeps.len(),
                        count(|s| s.fixed && s.on_the_move),
                        count(SweepPose::fix_made_worse),
                    )
                })
                .collect();
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} · {} · {} | {} · {} · {} | {} · {} | {} |",
                p.label(),
                cell(scene, p, |f| f.walls.median_distance_m, 100.0, 1, false),
                cell(scene, p, |f| Some(f.walls.coverage), 100.0, 0, true),
                tail(|t| t.position_m.median, 100.0, 1),
                tail(|t| t.position_m.p95, 100.0, 1),
                tail(|t| t.position_m.max, 100.0, 1),
                tail(|t| t.heading_deg.median, 1.0, 2),
                tail(|t| t.heading_deg.p95, 1.0, 2),
                tail(|t| t.heading_deg.max, 1.0, 2),
                readings(|t| t.position_m.max, 100.0, 1),
                readings(|t| t.heading_deg.max, 1.0, 2),
                if p == Placement::Localized {
                    fixes.join(", ")
                } else {
                    "–".into()
                },
            );
        }
        // What a robot builder would calibrate: the drift the filter learnt, against the
        // simulator's (its heading drift is per metre driven, the filter's per metre reported).
        let learnt: Vec<String> = runs
            .iter()
            .filter_map(|r| r.get(Placement::Localized)?.drift)
            .map(|d| format!("{:+.1} % and {:+.2}°/m", d.scale * 100.0, d.drift_deg_per_m))
            .collect();
        if !learnt.is_empty() {
            let o = settings.odometry;
            let _ = writeln!(
                s,
                "\nThe odometry's drift learnt by the end of the tour, per seed: {} (the \
                 simulator's: {:+.1} % and {:+.2}°/m of the distance it reports).",
                learnt.join("; "),
                o.scale_error * 100.0,
                o.heading_drift_deg_per_m / (1.0 + o.scale_error),
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_sim::Vec2;

    fn sample(t_us: u64, x: f64, heading_deg: f64) -> PoseSample {
        let p = Pose::new(x, 0.0, heading_deg.to_radians());
        PoseSample {
            t_us,
            truth: p,
            odometry: p,
        }
    }

    #[test]
    fn the_truth_is_interpolated_between_samples_and_held_beyond_them() {
        let poses = [sample(0, 0.0, 170.0), sample(50_000, 0.01, -170.0)];
        let mid = truth_at(&poses, 25_000_000);
        assert!((mid.at - Vec2::new(0.005, 0.0)).norm() < 1e-12);
        // Across ±180° the shorter way.
        assert!((angle_diff_rad(mid.heading_rad, std::f64::consts::PI)).abs() < 1e-9);
        assert_eq!(truth_at(&poses, 90_000_000), poses[1].truth);
        assert_eq!(truth_at(&poses[..1], 90_000_000), poses[0].truth);
        assert_eq!(truth_at(&[], 1), Pose::default());
    }

    #[test]
    fn pose_errors_and_tails() {
        let used = Isometry2::new(nalgebra::Vector2::new(1.03_f32, 0.04), 3.0_f32.to_radians());
        let e = PoseError::of(&used, &Pose::new(1.0, 0.0, (-1.0_f64).to_radians()));
        assert!((e.position_m - 0.05).abs() < 1e-6, "{e:?}");
        assert!((e.heading_deg - 4.0).abs() < 1e-5, "{e:?}");
        let t = Tail::of((1..=100).map(f64::from)).unwrap();
        assert_eq!((t.median, t.p95, t.max), (51.0, 95.0, 100.0));
        assert_eq!(Tail::of([]), None);
    }

    #[test]
    fn the_grid_covers_the_corridor_and_its_rooms() {
        let g = grid_over(&Scene::builtin("corridor").unwrap());
        // x 0…6 m, y −0.6…3.6 m: 6 m + 2 × 0.5 m of 2 cm cells, centred on (3, 1.5).
        assert_eq!(g.cells, 350);
        assert!((g.centre_x_m - 3.0).abs() < 1e-6 && (g.centre_y_m - 1.5).abs() < 1e-6);
        assert_eq!(g.resolution_m, GridConfig::default().resolution_m);
    }
}
