//! The readings `sonar-bench throughput` offers (`sonar_bench::synthetic_reading`: a head standing at the
//! origin, sweeps of 50 from −147° to 147° in 6° steps, forth and back, walls 1.5–3.5 m away, every
//! reading at its own range, so that every reading is a region of its own), fused in this process
//! as `sonar-fusion` fuses them (a sweep's last region closed when the next sweep starts), without
//! snapshots or features: for instruction counts of a long run's fusing at a given point of it
//! (`valgrind --tool=callgrind`, the inclusive count of `bench_readings::measured`).
//!
//!   bench_readings READINGS SKIP           # fuses SKIP readings, then READINGS more in `measured`
//!   bench_readings READINGS SKIP moving    # the same with the robot driving round a room
//!                                          # (`sonar_bench::room_reading`, `moving_pose`)
//!
//! With `SONAR_BENCH_FINGERPRINT=1` it also prints the final map's fingerprint
//! (`OccupancyGrid::fingerprint`, after the counted work), to check that a change leaves a long
//! run's map bit for bit as it was.

use anyhow::{Context, Result};
use sonar_bench::{moving_pose, room_reading, synthetic_reading};
use sonar_common::ipc::Reading;
use sonar_fusion::{FusionConfig, Preset, engine::Engine};

/// A reading fused, the finished sweep's last region closed first if it starts a new one.
#[inline(never)]
fn fuse(engine: &mut Engine, r: &Reading) -> bool {
    engine.close_finished_sweep(r);
    engine.fuse(r)
}

/// Reading `seq` (stamped `seq` µs), the standing head's or, `moving`, the driving robot's with
/// its pose given first (stamped half a microsecond later).
fn next(engine: &mut Engine, seq: u64, moving: bool) -> Result<Reading> {
    let stamp = seq * 1_000;
    if !moving {
        return Ok(synthetic_reading(seq, stamp));
    }
    engine
        .set_pose(&moving_pose(seq, stamp + 500))
        .context("the moving robot's pose")?;
    Ok(room_reading(seq, stamp))
}

fn main() -> Result<()> {
    let number = |i: usize, default: u64| {
        std::env::args()
            .nth(i)
            .map_or(Ok(default), |a| a.parse::<u64>())
            .context("READINGS and SKIP are numbers of readings")
    };
    let (n, skip) = (number(1, 500)?, number(2, 0)?);
    let moving = match std::env::args().nth(3).as_deref() {
        None => false,
        Some("moving") => true,
        Some(other) => anyhow::bail!("the third argument is `moving` or nothing, not {other:?}"),
    };
    let mut engine =
        Engine::new(FusionConfig::preset(Preset::Recommended), 20_000).context("engine")?;
    for seq in 0..skip {
        let reading = next(&mut engine, seq, moving)?;
        fuse(&mut engine, &reading);
    }
    println!(
        "fused {} readings after {skip}",
        measured(&mut engine, skip, n, moving)?
    );
    if std::env::var_os("SONAR_BENCH_FINGERPRINT").is_some() {
        println!(
            "map fingerprint {:016x}",
            engine.mapper().grid().fingerprint()
        );
    }
    Ok(())
}

/// Fuses readings `skip`..`skip + n`; returns how many were fused.
#[inline(never)]
fn measured(engine: &mut Engine, skip: u64, n: u64, moving: bool) -> Result<u32> {
    let mut fused = 0;
    for seq in skip..skip + n {
        let reading = next(engine, seq, moving)?;
        fused += u32::from(fuse(engine, &reading));
    }
    Ok(fused)
}
