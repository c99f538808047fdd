//! Saving the map, against the time of one snapshot, on grids of 400² (2 cm cells, the default)
//! and 2048² (1 cm), with the recommended preset (f32 log-odds cells) and Dempster–Shafer (two
//! f32 per cell, the largest state at a given size).
//!
//! - `snapshot`: encoding the grid into the one-byte snapshot cells, what the fusion does for
//!   every `sonar/grid` sample (the yardstick: a save should hold the readings loop no longer);
//! - `capture`: `Engine::capture`, a fresh copy of the state (the process's first save);
//! - `capture_into`: `Engine::capture_into` an earlier copy, what the readings loop does for every
//!   later save (the saver thread hands each copy back);
//! - `write`: `persist::write` of that copy, what the saver thread does off the loop: encode,
//!   checksum, write the temporary file, fsync, rename, fsync the directory (into the system's
//!   temporary directory; it must be on a disk, not a tmpfs, for the fsyncs to mean anything);
//! - `restore`: reading the file back into an engine at start.
//!
//! The grid is filled by four sweeps of readings first (what the cells hold does not change the
//! cost of copying or encoding them), and the engine keeps 20 000 observations for re-fusing,
//! the process's default, so the saved history is as large as it gets.
//!
//! Run with `cargo bench -p sonar-fusion --bench persist`; `docs/benchmarks.md` has the figures.
#![allow(clippy::expect_used)] // a failed save or restore is a failed benchmark

use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use sonar_common::ipc::{LAYOUT_VERSION, Reading};
use sonar_fusion::engine::Engine;
use sonar_fusion::{FusionConfig, GridConfig, RuleConfig, RuleKind, persist};

const GRIDS: [(u32, f32); 2] = [(400, 0.02), (2048, 0.01)];
const HISTORY: usize = 20_000;

fn filled_engine(config: FusionConfig) -> Engine {
    let mut engine = Engine::new(config, HISTORY).expect("valid settings");
    for seq in 0..HISTORY as u64 {
        let angle_deg = -147.0 + 6.0 * (seq % 50) as f32;
        engine.fuse(&Reading {
            seq,
            layout_version: LAYOUT_VERSION,
            angle_deg,
            beam_half_angle_deg: 30.0,
            distance_m: 0.5 + 3.0 * ((seq * 7919) % 100) as f32 / 100.0,
            min_range_m: 0.03,
            max_range_m: 4.0,
            ..Reading::default()
        });
    }
    engine
}

fn bench(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("sonar-persist-bench-{}", std::process::id()));
    let path: PathBuf = dir.join("fusion-map.bin");
    for (cells, resolution_m) in GRIDS {
        for rule in [RuleKind::LogOdds, RuleKind::DempsterShafer] {
            let config = FusionConfig {
                grid: GridConfig {
                    cells,
                    resolution_m,
                    ..GridConfig::default()
                },
                rule: RuleConfig::default_for(rule),
                ..FusionConfig::default()
            };
            let mut engine = filled_engine(config);
            let mut group = c.benchmark_group(format!("save_{cells}_{rule}"));
            group
                .sample_size(10)
                .warm_up_time(Duration::from_secs(1))
                .measurement_time(Duration::from_secs(5));
            let mut snapshot = vec![0u8; engine.grid_len()];
            group.bench_function("snapshot", |b| {
                b.iter(|| black_box(engine.encode_grid(&mut snapshot)))
            });
            group.bench_function("capture", |b| b.iter(|| black_box(engine.capture())));
            let mut map = engine.capture();
            group.bench_function("capture_into", |b| {
                b.iter(|| engine.capture_into(black_box(&mut map)))
            });
            group.bench_function("write", |b| {
                b.iter(|| persist::write(&path, &map).expect("write the state file"))
            });
            group.bench_function("restore", |b| {
                b.iter(|| persist::restore(&path, config, HISTORY).expect("valid settings"))
            });
            group.finish();
            let size = std::fs::metadata(&path).map_or(0, |m| m.len());
            println!("save_{cells}_{rule}: state file {size} bytes");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, bench);
criterion_main!(benches);
