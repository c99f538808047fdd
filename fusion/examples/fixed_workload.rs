//! A fixed, deterministic workload for instruction counts (`valgrind --tool=callgrind`): a new
//! engine fuses a synthetic recording of a room and takes a grid snapshot every few readings, as
//! the fusion process does at its default rate. Nothing here depends on time or randomness, so the
//! instruction counts of [`fuse`] and [`snapshot`] are the same on every run and every machine
//! load, and a later change compares against them (`scripts/bench.sh`, `docs/benchmarks.md`).
//!
//! The recording: the head at the origin, sweeps of 50 readings from −147° to 147° in 6° steps,
//! forth and back, of a 6 × 4 m room whose walls are off-centre (so ranges differ by bearing);
//! bearings beyond the 4 m range give no echo; ranges carry a deterministic ±1 cm wobble so no two
//! sweeps are the same.

use std::hint::black_box;

use anyhow::{Context, Result};
use clap::Parser;
use sonar_common::ipc::{LAYOUT_VERSION, Reading, ScanMode, flags};
use sonar_fusion::{CellCounts, FusionConfig, GridConfig, engine::Engine};

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
    /// A snapshot after every this many readings (5: the default --max-rate of 10/s at the head's
    /// 50 readings a second).
    #[arg(long, default_value_t = 5)]
    snapshot_every: u32,
}

const READINGS_PER_SWEEP: u32 = 50;
const MAX_RANGE_M: f32 = 4.0;

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
        direction: if forth { 1 } else { -1 },
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

/// What a snapshot costs the process besides the loan: the cells into the sample, and the counts.
#[inline(never)]
fn snapshot(engine: &mut Engine, sample: &mut [u8]) -> CellCounts {
    engine.encode_grid(sample)
}

fn main() -> Result<()> {
    let args = Args::parse();
    let config = FusionConfig {
        grid: GridConfig {
            cells: args.cells,
            resolution_m: args.resolution,
            ..GridConfig::default()
        },
        ..FusionConfig::default()
    };
    let mut engine = new_engine(config)?;
    let mut sample = vec![0u8; engine.grid_len()];
    let mut counts = CellCounts::default();
    let (mut fused, mut snapshots) = (0u32, 0u32);
    for seq in 0..args.readings {
        fused += u32::from(fuse(&mut engine, &reading(seq)));
        if (seq + 1).is_multiple_of(args.snapshot_every.max(1)) {
            counts = snapshot(&mut engine, &mut sample);
            snapshots += 1;
        }
    }
    black_box(&sample);
    println!(
        "fused {fused} readings, {snapshots} snapshots; last: {} occupied, {} free, {} unknown",
        counts.occupied, counts.free, counts.unknown
    );
    Ok(())
}
