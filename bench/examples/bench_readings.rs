//! The readings `sonar-bench throughput` offers (`sonar_bench::synthetic_reading`: a head standing at the
//! origin, sweeps of 50 from −147° to 147° in 6° steps, forth and back, walls 1.5–3.5 m away, every
//! reading at its own range, so that every reading is a region of its own), fused in this process
//! as `sonar-fusion` fuses them (a sweep's last region closed when the next sweep starts), without
//! snapshots or features: for instruction counts of a long run's fusing at a given point of it
//! (`valgrind --tool=callgrind`, the inclusive count of `bench_readings::measured`).
//!
//!   bench_readings READINGS SKIP   # fuses SKIP readings, then READINGS more in `measured`

use anyhow::{Context, Result};
use sonar_bench::synthetic_reading;
use sonar_common::ipc::Reading;
use sonar_fusion::{FusionConfig, Preset, engine::Engine};

/// A reading fused, the finished sweep's last region closed first if it starts a new one.
#[inline(never)]
fn fuse(engine: &mut Engine, r: &Reading) -> bool {
    if engine.starts_new_sweep(r) {
        engine.close_region();
    }
    engine.fuse(r)
}

fn main() -> Result<()> {
    let number = |i: usize, default: u64| {
        std::env::args()
            .nth(i)
            .map_or(Ok(default), |a| a.parse::<u64>())
            .context("READINGS and SKIP are numbers of readings")
    };
    let (n, skip) = (number(1, 500)?, number(2, 0)?);
    let mut engine =
        Engine::new(FusionConfig::preset(Preset::Recommended), 20_000).context("engine")?;
    for seq in 0..skip {
        fuse(&mut engine, &synthetic_reading(seq, 0));
    }
    println!(
        "fused {} readings after {skip}",
        measured(&mut engine, skip, n)
    );
    Ok(())
}

/// Fuses readings `skip`..`skip + n`; returns how many were fused.
#[inline(never)]
fn measured(engine: &mut Engine, skip: u64, n: u64) -> u32 {
    let mut fused = 0;
    for seq in skip..skip + n {
        fused += u32::from(fuse(engine, &synthetic_reading(seq, 0)));
    }
    fused
}
