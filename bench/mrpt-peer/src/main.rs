//! `sonar-mrpt-peer`: our fusion engine and MRPT's occupancy grid, fed the same sonar readings in
//! one process, interleaved, timed per reading and scored against the scene's true geometry.
//!
//! # What is compared
//!
//! - **Readings**: the pipeline's own simulated head and the driver's decoder
//!   ([`sonar_eval::pipeline`]) scanning two scenes of known geometry: the paper's square room
//!   (full sweeps from its centre) and a scene of the generated suite ([`sonar_eval::scenegen`],
//!   two full sweeps from each of its first three viewpoints, `--views`), and, with `--scenes tour`,
//!   the room toured by a robot that scans while it drives (every reading from a new position,
//!   placed at the robot's true pose of its instant), or with `--scenes arena` an arena of thin
//!   boards of the suite's second family (after the recorded scans of issue 23, whose arena MRPT
//!   mapped at 0.62 recall), heard through a sensor profile (`--profile`). Readings without an
//!   echo are given to both (our recommended preset ignores them; MRPT is told its maximum range
//!   is the sensor's, so it inserts nothing for them either).
//! - **Ours**: [`Engine::fuse`] with the recommended preset (smooth model, log-odds rule), what
//!   `sonar-fusion` calls per reading, no snapshot. A viewpoint's pose is given as the engine's
//!   correction ([`Engine::set_correction`]), outside the timing.
//! - **MRPT** (2.5, Debian's build): `COccupancyGridMap2D::insertObservation` with a
//!   `CObservationRange` of one measurement, cone aperture 2 × the reading's beam half-angle
//!   (60°), `maxDistanceInsertion` = the reading's maximum range (4 m),
//!   `considerInvalidRangesAsFreeSpace` off, every other insertion option at MRPT's default
//!   (8-bit log-odds cells, update certainty 0.65). MRPT 2.5 draws the cone from yaw − aperture to
//!   yaw, so the yaw given is the beam's bearing + aperture / 2: the cone is centred on the beam.
//!   Both grids cover the same square with the same cells.
//! - **Interleaved**: the readings are cut into batches; each batch goes to our engine, then to
//!   MRPT, then the next batch, so both see the same machine load. One pass over the readings is
//!   made unmeasured first (our kernel builds its caches there); then every measured pass starts
//!   from cleared maps (caches kept), and every reading's call is timed on its own.
//! - **Scores**: both maps after the last pass (one pass's readings on cleared maps), with
//!   `sonar-eval`'s own scoring against the scene ([`score_grid`]): precision, recall and median
//!   error, a cell occupied above 0.5, a surface drawn within 5 cm.
//!
//! Prints one Markdown table row per scene. `scripts/bench.sh mrpt` installs MRPT, builds this and
//! runs it at 400² × 2 cm, 1024² × 1 cm and 2048² × 1 cm; `docs/benchmarks.md` has the figures.

use std::time::Instant;

use anyhow::{Context, Result, bail, ensure};
use clap::{Parser, ValueEnum};
use nalgebra::{Isometry2, Vector2};
use sonar_common::ipc::{FusionCommand, FusionCommandKind, Reading};
use sonar_eval::metrics::{MapKind, MapView, quantile};
use sonar_eval::motion::{POSE_RATE_HZ, truth_at};
use sonar_eval::pipeline::{
    Head, ProfileChoice, Scan, capture_tour, capture_with, probability_view,
};
use sonar_eval::scenegen::{self, Family};
use sonar_eval::suite::{GridScore, Reach, score_grid};
use sonar_fusion::engine::Engine;
use sonar_fusion::{FusionConfig, GridConfig, GridGeometry, Preset};
use sonar_sim::{OdometryParams, Pose, Scene};

mod mrpt;

use mrpt::MrptGrid;

/// Full sweeps of the room from its centre: 8 × 50 readings.
const ROOM_SWEEPS: u32 = 8;
/// Full sweeps of the generated scene from each viewpoint: 2 × 50 readings.
const GENERATED_SWEEPS: u32 = 2;
/// Metres the robot of the room tour drives: two laps of its 1.2 m square and a little more.
const TOUR_METRES: f64 = 10.0;
/// Observations `sonar-fusion` keeps for re-fusing by default (`--history`).
const HISTORY: usize = 20_000;

/// Our fusion engine and MRPT's COccupancyGridMap2D fed the same simulated sonar readings in one
/// process, interleaved batch by batch; prints, per scene, the time per reading of each (p50 and
/// p99), their ratio and both maps' scores against the scene (Markdown table rows).
#[derive(Debug, Parser)]
#[command(version)]
struct Cli {
    /// Cells per side of both grids (centred on the origin).
    #[arg(long, default_value_t = 400)]
    cells: u32,
    /// Cell edge of both grids, metres.
    #[arg(long, default_value_t = 0.02)]
    resolution: f32,
    /// Measured passes over the readings, each from cleared maps, after one unmeasured pass.
    #[arg(long, default_value_t = 50)]
    passes: u32,
    /// Readings per batch: a batch goes to our engine, then to MRPT, then the next batch.
    #[arg(long, default_value_t = 25)]
    batch: usize,
    /// Seed of the simulated sensor's noise; the generated scene is `scenegen`'s scene of this
    /// seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Which scenes.
    #[arg(long, value_enum, default_value_t = Scenes::Both)]
    scenes: Scenes,
    /// Viewpoints of the generated scene scanned (its first ones, up to 8), 2 full sweeps each.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=8))]
    views: u32,
    /// The sensor profile that hears the generated scene or arena (srf05, hc-sr04, nxt; default
    /// = the simulator without a profile), as `sonar-eval --suite-profiles` names them.
    #[arg(long, default_value = "default")]
    profile: ProfileChoice,
    /// Print the table's header first.
    #[arg(long)]
    header: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Scenes {
    Room,
    Generated,
    /// Room and generated.
    Both,
    /// The built-in `room-tour`: the head scanning while the robot drives round the room, so
    /// every reading is taken from a new position (not part of `both`).
    Tour,
    /// An arena of thin boards (`sonar-eval --suite-family arenas`) of the seed (not part of
    /// `both`).
    Arena,
}

/// The readings of one scene, where each was taken, and the truth to score against.
#[derive(Debug)]
struct Workload {
    name: String,
    /// The scene in the world frame.
    scene: Scene,
    views: Vec<Pose>,
    /// Each reading with the index of its viewpoint in `views`.
    readings: Vec<(Reading, usize)>,
    max_range_m: f32,
    beam_half_angle_deg: f32,
    /// The head's range and sweep, for the scoring.
    reach: Reach,
}

fn room(seed: u64) -> Result<Workload> {
    let scene = Scene::builtin("room").context("the built-in room scene")?;
    let head = Head::of(&scene);
    let capture = capture_with(scene.clone(), head, Scan::Full, ROOM_SWEEPS, seed)
        .context("scanning the room")?;
    Ok(Workload {
        name: "paper's room".to_owned(),
        scene,
        views: vec![Pose::new(0.0, 0.0, 0.0)],
        readings: capture.readings.into_iter().map(|r| (r, 0)).collect(),
        max_range_m: head.sensor.max_range_m,
        beam_half_angle_deg: head.sensor.beam_half_angle_deg,
        reach: Reach::of(&head.sensor),
    })
}

/// A scene of `family` drawn from `seed`, heard through `profile` from its first `views`
/// viewpoints.
fn generated(family: Family, seed: u64, views: usize, profile: ProfileChoice) -> Result<Workload> {
    let generated = scenegen::generate_in(family, seed).context("generating the scene")?;
    let mut scene = generated.scene;
    if let Some(p) = profile.0 {
        scene.set_profile(p);
    }
    let head = Head::of(&scene);
    let views: Vec<Pose> = generated.viewpoints.into_iter().take(views).collect();
    let mut readings = Vec::new();
    for (k, &view) in views.iter().enumerate() {
        let seen = scenegen::seen_from(&scene, view)?;
        let capture = capture_with(seen, head, Scan::Full, GENERATED_SWEEPS, seed + k as u64)
            .with_context(|| format!("scanning {} from viewpoint {}", scene.name, k + 1))?;
        readings.extend(capture.readings.into_iter().map(|r| (r, k)));
    }
    Ok(Workload {
        name: format!(
            "generated {}{}, {} view{}",
            scene.name,
            profile.0.map_or_else(String::new, |p| format!(" ({p})")),
            views.len(),
            if views.len() == 1 { "" } else { "s" }
        ),
        scene,
        views,
        readings,
        max_range_m: head.sensor.max_range_m,
        beam_half_angle_deg: head.sensor.beam_half_angle_deg,
        reach: Reach::of(&head.sensor),
    })
}

/// The room toured by a robot scanning while it drives (one lap), each reading placed at the
/// robot's true pose of its instant: no two readings from the same position.
fn tour(seed: u64) -> Result<Workload> {
    let scene = Scene::builtin("room-tour").context("the built-in room-tour scene")?;
    let head = Head::of(&scene);
    let tour = capture_tour(
        scene.clone(),
        Scan::Full,
        TOUR_METRES,
        OdometryParams::default(),
        POSE_RATE_HZ,
        seed,
    )
    .context("touring the room")?;
    let mut views = Vec::new();
    let mut readings = Vec::new();
    for reading in tour.capture.readings {
        views.push(truth_at(&tour.poses, reading.host_stamp_ns));
        readings.push((reading, views.len() - 1));
    }
    Ok(Workload {
        name: format!("room tour, {TOUR_METRES} m driven"),
        scene,
        views,
        readings,
        max_range_m: head.sensor.max_range_m,
        beam_half_angle_deg: head.sensor.beam_half_angle_deg,
        reach: Reach::of(&head.sensor),
    })
}

fn isometry(pose: Pose) -> Isometry2<f32> {
    Isometry2::new(
        Vector2::new(pose.at.x as f32, pose.at.y as f32),
        pose.heading_rad as f32,
    )
}

/// Both mappers over the same grid.
struct Peers {
    ours: Engine,
    mrpt: MrptGrid,
    geometry: GridGeometry,
}

impl Peers {
    fn new(cli: &Cli, workload: &Workload) -> Result<Self> {
        let mut config = FusionConfig::preset(Preset::Recommended);
        config.grid = GridConfig {
            cells: cli.cells,
            resolution_m: cli.resolution,
            ..GridConfig::default()
        };
        let ours = Engine::new(config, HISTORY).context("our engine's settings")?;
        let geometry = *ours.mapper().grid().geometry();
        let mrpt = MrptGrid::new(
            &geometry,
            workload.max_range_m,
            2.0 * workload.beam_half_angle_deg.to_radians(),
        )?;
        Ok(Self {
            ours,
            mrpt,
            geometry,
        })
    }

    fn clear(&mut self) -> Result<()> {
        self.ours
            .apply(&FusionCommand::new(FusionCommandKind::Clear, 0))
            .context("clearing our maps")?;
        self.mrpt.clear();
        Ok(())
    }
}

/// What MRPT is given for a reading: its world position, beam bearing and range (the maximum
/// range for a reading without an echo, which MRPT then does not insert).
fn mrpt_input(reading: &Reading, view: Pose) -> (f64, f64, f64, f32) {
    let range = if reading.is_valid_range() {
        reading.distance_m
    } else {
        reading.max_range_m
    };
    (
        view.at.x,
        view.at.y,
        view.heading_rad + f64::from(reading.angle_deg).to_radians(),
        range,
    )
}

/// One reading into our engine: the call that is timed (and counted by callgrind in
/// `scripts/bench.sh mrpt`'s instruction counts; the unmeasured pass does not come here).
#[inline(never)]
fn measured_ours(engine: &mut Engine, reading: &Reading) -> bool {
    engine.fuse(reading)
}

/// One reading into MRPT's grid: the call that is timed (and counted, as [`measured_ours`]).
#[inline(never)]
fn measured_mrpt(grid: &mut MrptGrid, input: (f64, f64, f64, f32)) -> Result<bool> {
    grid.insert(input.0, input.1, input.2, input.3)
}

/// Per-reading times of both, nanoseconds, over the measured passes.
#[derive(Debug, Default)]
struct Times {
    ours: Vec<f64>,
    mrpt: Vec<f64>,
}

/// One pass over the readings from cleared maps, batch by batch: our engine, then MRPT.
fn pass(
    peers: &mut Peers,
    workload: &Workload,
    batch: usize,
    mut times: Option<&mut Times>,
) -> Result<()> {
    peers.clear()?;
    for chunk in workload.readings.chunks(batch) {
        for (reading, view) in chunk {
            peers.ours.set_correction(isometry(workload.views[*view]));
            let fused = match times.as_deref_mut() {
                Some(t) => {
                    let start = Instant::now();
                    let fused = measured_ours(&mut peers.ours, reading);
                    t.ours.push(start.elapsed().as_nanos() as f64);
                    fused
                }
                None => peers.ours.fuse(reading),
            };
            ensure!(fused, "our engine refused reading {}", reading.seq);
        }
        for (reading, view) in chunk {
            let input = mrpt_input(reading, workload.views[*view]);
            match times.as_deref_mut() {
                Some(t) => {
                    let start = Instant::now();
                    measured_mrpt(&mut peers.mrpt, input)?;
                    t.mrpt.push(start.elapsed().as_nanos() as f64);
                }
                None => {
                    peers.mrpt.insert(input.0, input.1, input.2, input.3)?;
                }
            }
        }
    }
    peers.ours.close_region();
    Ok(())
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "?".to_owned())
}

fn micros(ns: Option<f64>) -> String {
    ns.map_or_else(|| "–".to_owned(), |ns| format!("{:.1} µs", ns / 1000.0))
}

fn score_cell(score: &GridScore) -> String {
    let share = |v: Option<f64>| v.map_or_else(|| "–".to_owned(), |v| format!("{v:.2}"));
    let median = score
        .median_error_m
        .map_or_else(|| "–".to_owned(), |m| format!("{:.1} cm", m * 100.0));
    format!(
        "{} / {} / {median}",
        share(score.precision),
        share(score.recall)
    )
}

fn run(cli: &Cli, workload: &Workload) -> Result<String> {
    ensure!(
        !workload.readings.is_empty(),
        "{}: no readings",
        workload.name
    );
    let load_before = load_average();
    let mut peers = Peers::new(cli, workload)?;
    pass(&mut peers, workload, cli.batch, None)?;
    let mut times = Times::default();
    for _ in 0..cli.passes {
        pass(&mut peers, workload, cli.batch, Some(&mut times))?;
    }
    let grown = peers.mrpt.size();
    let n = peers.geometry.cells_per_side();
    if grown != (n, n) {
        eprintln!(
            "mrpt-peer: MRPT grew its grid to {} × {} (readings near the edge); cells read at ours",
            grown.0, grown.1
        );
    }
    let ours_map = probability_view(peers.ours.mapper());
    let mrpt_map = MapView::new(
        peers.geometry,
        MapKind::Probability,
        peers
            .mrpt
            .probabilities(&peers.geometry)
            .into_iter()
            .map(Some)
            .collect(),
    );
    let ours_score = score_grid(&ours_map, &workload.scene, &workload.views, workload.reach);
    let mrpt_score = score_grid(&mrpt_map, &workload.scene, &workload.views, workload.reach);
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        (quantile(v, 0.5), quantile(v, 0.99), mean)
    };
    let (ours50, ours99, ours_mean) = stats(&mut times.ours);
    let (mrpt50, mrpt99, mrpt_mean) = stats(&mut times.mrpt);
    let ratio = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(a), Some(b)) if b > 0.0 => format!("{:.2}×", a / b),
        _ => "–".to_owned(),
    };
    Ok(format!(
        "| {}² × {} cm | {} | {} × {} | {} / {} | {} / {} | {} | {} | {} | {} | {} → {} |",
        n,
        (cli.resolution * 1000.0).round() / 10.0,
        workload.name,
        workload.readings.len(),
        cli.passes,
        micros(ours50),
        micros(ours99),
        micros(mrpt50),
        micros(mrpt99),
        ratio(mrpt50, ours50),
        ratio(Some(mrpt_mean), Some(ours_mean)),
        score_cell(&ours_score),
        score_cell(&mrpt_score),
        load_before,
        load_average(),
    ))
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    if cli.batch == 0 || cli.passes == 0 {
        bail!("--batch and --passes must be at least 1");
    }
    let mut workloads = Vec::new();
    if matches!(cli.scenes, Scenes::Room | Scenes::Both) {
        workloads.push(room(cli.seed)?);
    }
    if matches!(cli.scenes, Scenes::Generated | Scenes::Both) {
        workloads.push(generated(
            Family::Rooms,
            cli.seed,
            cli.views as usize,
            cli.profile,
        )?);
    }
    if cli.scenes == Scenes::Arena {
        workloads.push(generated(
            Family::Arenas,
            cli.seed,
            cli.views as usize,
            cli.profile,
        )?);
    }
    if cli.scenes == Scenes::Tour {
        workloads.push(tour(cli.seed)?);
    }
    if cli.header {
        println!(
            "| grid | scene | readings × passes | ours p50 / p99 | MRPT p50 / p99 | MRPT ÷ ours, p50 | MRPT ÷ ours, mean | ours: precision / recall / median error | MRPT: precision / recall / median error | load average before → after |"
        );
        println!("|---|---|--:|--:|--:|--:|--:|--:|--:|---|");
    }
    for workload in &workloads {
        println!("{}", run(&cli, workload)?);
    }
    Ok(())
}
