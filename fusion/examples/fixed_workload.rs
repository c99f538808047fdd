//! A fixed, deterministic workload for instruction counts (`valgrind --tool=callgrind`): a new
//! engine fuses a synthetic recording of a room, takes grid snapshots at one of two paces, and,
//! as the fusion process does by default, follows the readings with the feature map and takes a
//! features snapshot after every sweep. Nothing here depends on time or randomness, so the
//! instruction counts of [`fuse`], [`snapshot`], [`follow`] and [`features_snapshot`] are the same
//! on every run and every machine load, and a later change compares against them
//! (`scripts/bench.sh`, `docs/benchmarks.md`).
//!
//! The paces (`--pace`): at the head's own pace a reading comes every ~240 ms, longer than the
//! fusion's snapshot period (100 ms at the default --max-rate of 10/s), so **every reading gets
//! its own grid snapshot**; at replay pace (readings as fast as a replay sends them, 50 a second
//! and more) the snapshot rate caps them, a snapshot every 5 readings at 50 readings a second.
//!
//! The samples: `sonar-fusion` writes each snapshot into a sample the IPC hands back for reuse,
//! still holding the snapshot it was last sent with, and copies only the cells changed since
//! ([`Engine::copy_grid_changes_into`]). Here the snapshots go into `--sample-slots` buffers in
//! turn (2 by default: the fewest a publisher alternates between while its service's history
//! keeps the last sample sent); `--whole-copies` copies every cell into each, as a sample never
//! written before gets (and as every snapshot did before issue 29).
//!
//! The recording: the head at the origin, sweeps of 50 readings from −147° to 147° in 6° steps,
//! forth and back, of a 6 × 4 m room whose walls are off-centre (so ranges differ by bearing);
//! bearings beyond the 4 m range give no echo; ranges carry a deterministic ±1 cm wobble so no two
//! sweeps are the same. Each reading also carries its four raw pings, 1.5° apart: a ping hears a
//! wall (at its perpendicular distance, as a smooth wall answers) when the wall's normal lies
//! within 28° of the ping, so the feature map finds the three walls the head faces.

use std::hint::black_box;

use anyhow::{Context, Result};
use clap::{Parser, ValueEnum};
use nalgebra::Isometry2;
use sonar_common::ipc::{LAYOUT_VERSION, MAX_PINGS, Reading, ScanMode, flags};
use sonar_features::FeatureConfig;
use sonar_fusion::{
    CellCounts, EncodedVersion, FeatureTracker, FusionConfig, GridConfig, Mapper, ModelConfig,
    ModelKind, Observation, Preset, RuleConfig, RuleKind, engine::Engine,
};

/// How often the grid is snapshot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Pace {
    /// The sensor head's own pace: a reading every ~240 ms, each with its own snapshot.
    Head,
    /// Replay pace, 50 readings a second against the default --max-rate of 10 snapshots a second:
    /// a snapshot every 5 readings.
    Replay,
}

impl Pace {
    fn readings_per_snapshot(self) -> u32 {
        match self {
            Self::Head => 1,
            Self::Replay => 5,
        }
    }
}

/// Fuses a fixed synthetic recording and snapshots it; prints what the last snapshot counted.
#[derive(Debug, Parser)]
struct Args {
    /// Cells per side.
    #[arg(long, default_value_t = 400)]
    cells: u32,
    /// Cell edge, metres.
    #[arg(long, default_value_t = 0.02)]
    resolution: f32,
    /// Readings to fuse (50 per sweep).
    #[arg(long, default_value_t = 500)]
    readings: u32,
    /// Grid snapshots at the head's pace (one per reading) or at replay pace (one per 5 readings).
    #[arg(long, value_enum, default_value_t = Pace::Replay)]
    pace: Pace,
    /// A grid snapshot after every this many readings, instead of the pace's.
    #[arg(long)]
    snapshot_every: Option<u32>,
    /// Without the feature map (no features followed, no features snapshots).
    #[arg(long)]
    no_features: bool,
    /// Sample buffers the grid snapshots go into in turn, each brought up to date with the cells
    /// changed since its last snapshot.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=1024))]
    sample_slots: u32,
    /// Copy every cell into each snapshot's sample, not only those changed since its last one.
    #[arg(long)]
    whole_copies: bool,
    /// The fusion's preset (`paper` or `recommended`).
    #[arg(long, default_value = "recommended")]
    preset: Preset,
    /// The preset's sensor model replaced by this one (`paper`, `log-odds`, `smooth`), with its
    /// defaults.
    #[arg(long)]
    model: Option<ModelKind>,
    /// The preset's combination rule replaced by this one (`bayes`, `log-odds`,
    /// `dempster-shafer`, `himm`), with its defaults.
    #[arg(long)]
    rule: Option<RuleKind>,
    /// Print a fingerprint of the final map (FNV-1a over every cell's probability), to check
    /// that a change leaves the maps bit for bit as they were (not counted work, but it adds to
    /// the program's total).
    #[arg(long)]
    fingerprint: bool,
    /// Also count the grid cells the readings changed, by a second map fed the same readings
    /// (doubles the fusing work: for the count alone, not with the timings or the instruction
    /// counts).
    #[arg(long)]
    count_cells: bool,
}

const READINGS_PER_SWEEP: u32 = 50;
const MAX_RANGE_M: f32 = 4.0;
const SPEED_OF_SOUND_MPS: f32 = 343.2;
/// The room's walls the head can face: (normal's direction in degrees, distance in metres).
const WALLS: [(f32, f32); 4] = [(0.0, 3.5), (90.0, 2.2), (180.0, 2.5), (-90.0, 1.8)];
/// A smooth wall answers a ping within this angle of its normal.
const SPECULAR_DEG: f32 = 28.0;
/// Degrees between a reading's pings (the stepper's 1.5° steps).
const PING_STEP_DEG: f32 = 1.5;

/// Distance from the origin to the walls of the room x ∈ [−2.5, 3.5], y ∈ [−1.8, 2.2] along
/// `angle_deg`.
fn room_range(angle_deg: f32) -> f32 {
    let (s, c) = angle_deg.to_radians().sin_cos();
    let along = |d: f32, wall_pos: f32, wall_neg: f32| {
        if d > 1e-6 {
            wall_pos / d
        } else if d < -1e-6 {
            wall_neg / d
        } else {
            f32::INFINITY
        }
    };
    along(c, 3.5, -2.5).min(along(s, 2.2, -1.8))
}

/// Reading `seq` of the recording.
fn reading(seq: u32) -> Reading {
    let sweep = seq / READINGS_PER_SWEEP;
    let k = seq % READINGS_PER_SWEEP;
    let forth = sweep.is_multiple_of(2);
    let step = if forth { k } else { READINGS_PER_SWEEP - 1 - k };
    let angle_deg = -147.0 + 6.0 * step as f32;
    // ±1 cm, from a multiplicative hash of the reading's number.
    let wobble = (seq.wrapping_mul(2_654_435_761) >> 16) as f32 / 65_535.0 * 0.02 - 0.01;
    let range = room_range(angle_deg) + wobble;
    let direction: i8 = if forth { 1 } else { -1 };
    let mut echo_us = [0u32; MAX_PINGS];
    for (j, echo) in echo_us.iter_mut().enumerate().take(4) {
        let bearing = angle_deg + f32::from(direction) * PING_STEP_DEG * (j as f32 - 1.5);
        if let Some(&(_, distance)) = WALLS.iter().find(|(normal, _)| {
            let off = (bearing - normal + 180.0).rem_euclid(360.0) - 180.0;
            off.abs() <= SPECULAR_DEG
        }) {
            *echo = (2.0 * (distance + wobble) / SPEED_OF_SOUND_MPS * 1e6).round() as u32;
        }
    }
    Reading {
        seq: u64::from(seq),
        layout_version: LAYOUT_VERSION,
        sweep_id: sweep + 1,
        flags: if range > MAX_RANGE_M {
            flags::NO_ECHO
        } else {
            0
        },
        angle_deg,
        beam_half_angle_deg: 30.0,
        distance_m: range.min(MAX_RANGE_M),
        min_range_m: 0.03,
        max_range_m: MAX_RANGE_M,
        speed_of_sound_mps: SPEED_OF_SOUND_MPS,
        echo_us,
        ping_count: 4,
        pings_used: 4,
        direction,
        mode: ScanMode::Full as u8,
        ..Reading::default()
    }
}

#[inline(never)]
fn new_engine(config: FusionConfig) -> Result<Engine> {
    Engine::new(config, 20_000).context("engine")
}

#[inline(never)]
fn fuse(engine: &mut Engine, reading: &Reading) -> bool {
    engine.fuse(reading)
}

/// A sample buffer and the version of the grid's cells it holds (`None`: never written).
struct Sample {
    cells: Vec<u8>,
    held: Option<EncodedVersion>,
}

/// What a snapshot costs the process besides the loan: the cells into the sample (those changed
/// since it was last written, or all with `whole`), and the counts.
#[inline(never)]
fn snapshot(engine: &mut Engine, sample: &mut Sample, whole: bool) -> CellCounts {
    let held = if whole { None } else { sample.held };
    let (counts, version) = engine.copy_grid_changes_into(&mut sample.cells, held);
    sample.held = Some(version);
    counts
}

/// What the feature map costs per reading: the reading added to its sweep, and a finished sweep
/// merged. Returns whether a sweep was merged.
#[inline(never)]
fn follow(tracker: &mut FeatureTracker, engine: &mut Engine, reading: &Reading) -> bool {
    tracker.follow(reading, engine, false).is_some()
}

/// A features snapshot, as the process publishes after every merged sweep; returns the number of
/// features.
#[inline(never)]
fn features_snapshot(tracker: &FeatureTracker, engine: &mut Engine, seq: u64) -> usize {
    let (header, records) = tracker.snapshot(engine.grid_mut(), seq, 0);
    black_box(&records);
    header.feature_count as usize
}

/// FNV-1a over the bits of every cell's probability: equal for equal maps, so a change that must
/// leave the maps bit for bit as they were can be checked on this workload.
fn main() -> Result<()> {
    let args = Args::parse();
    let config = FusionConfig {
        grid: GridConfig {
            cells: args.cells,
            resolution_m: args.resolution,
            ..GridConfig::default()
        },
        ..FusionConfig::preset(args.preset)
    };
    let config = FusionConfig {
        model: args.model.map_or(config.model, ModelConfig::default_for),
        rule: args.rule.map_or(config.rule, RuleConfig::default_for),
        ..config
    };
    let mut engine = new_engine(config)?;
    // The head stands at the origin: every reading is placed there, as the engine places it.
    let mut counter = if args.count_cells {
        Some(Mapper::new(config).context("mapper")?)
    } else {
        None
    };
    let mut cells_changed = 0usize;
    let mut tracker = if args.no_features {
        None
    } else {
        Some(FeatureTracker::new(FeatureConfig::default()).context("feature tracker")?)
    };
    let every = args
        .snapshot_every
        .unwrap_or_else(|| args.pace.readings_per_snapshot())
        .max(1);
    let mut samples: Vec<Sample> = (0..args.sample_slots)
        .map(|_| Sample {
            cells: vec![0u8; engine.grid_len()],
            held: None,
        })
        .collect();
    let mut counts = CellCounts::default();
    let (mut fused, mut snapshots, mut feature_snapshots, mut features) = (0u32, 0u32, 0u64, 0);
    for seq in 0..args.readings {
        let r = reading(seq);
        fused += u32::from(fuse(&mut engine, &r));
        if let Some(counter) = &mut counter
            && let Ok(update) =
                counter.update(&Observation::from_reading(&r, Isometry2::identity()))
        {
            cells_changed += update.cells_updated;
        }
        if let Some(tracker) = &mut tracker
            && follow(tracker, &mut engine, &r)
        {
            feature_snapshots += 1;
            features = features_snapshot(tracker, &mut engine, feature_snapshots);
        }
        if (seq + 1).is_multiple_of(every) {
            let slot = snapshots as usize % samples.len();
            let sample = &mut samples[slot];
            counts = snapshot(&mut engine, sample, args.whole_copies);
            snapshots += 1;
        }
    }
    black_box(&samples);
    println!(
        "fused {fused} readings, {snapshots} grid snapshots; last: {} occupied, {} free, {} \
         unknown; {feature_snapshots} features snapshots, last with {features} features",
        counts.occupied, counts.free, counts.unknown
    );
    if args.fingerprint {
        println!(
            "map fingerprint {:016x}",
            engine.mapper().grid().fingerprint()
        );
    }
    if counter.is_some() {
        println!("grid cells changed: {cells_changed}");
    }
    Ok(())
}
