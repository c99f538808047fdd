//! Fusing one reading into the probability grid: the fast cone kernel against the paper-style
//! whole-grid pass, per combination rule, on grids of 400² (2 cm cells, ±4 m), 1024² and 2048²
//! (1 cm cells, ±5.12 m and ±10.24 m).
//!
//! The readings are what the sensor head sends: the stepper's reading centres −147° … 147° in 6°
//! steps, swept forth and back, ranges drawn uniformly from 0.3–3.5 m (fixed seed), the sensor at
//! the origin, ±30° beams, 4 m maximum range. One iteration fuses the next reading of that cycle
//! into a map that keeps accumulating, as in a running fusion process.
//!
//! Each case's throughput is the mean number of cells a reading updates (`Update::cells_updated`
//! over one cycle, the same for both kernels), so criterion's "elem/s" is touched cells per
//! second and time ÷ elements is the time per touched cell. `docs/benchmarks.md` has the figures
//! and the targets: ≤ 1 ns per touched cell with log-odds, ≥ 100× faster than the whole-grid pass
//! at 1024², ≤ 100 µs per reading at 1024² with 1 cm cells.
//!
//! A last group measures a cold start: a new mapper and its first sweep, which builds the caches.
//!
//! Run with `cargo bench -p sonar-fusion --bench kernels`; a filter such as `-- grid_1024` picks
//! cases.

use std::hint::black_box;
use std::time::Duration;

use criterion::{BenchmarkGroup, Criterion, SamplingMode, Throughput, measurement::WallTime};
use criterion::{criterion_group, criterion_main};
use nalgebra::Isometry2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sonar_fusion::{
    FusionConfig, GridConfig, Kernel, Mapper, ModelConfig, ModelKind, Observation, RuleConfig,
    RuleKind,
};

/// Grid sizes: (cells per side, cell edge in metres).
const GRIDS: [(u32, f32); 3] = [(400, 0.02), (1024, 0.01), (2048, 0.01)];

/// The model each rule is benchmarked with in the main matrix: the paper's model for the rules
/// that consume probabilities (the paper preset is paper + Bayes), the smooth model for clamped
/// log-odds (the recommended preset), the book's model for HIMM (it consumes log-odds signs).
const PAIRS: [(RuleKind, ModelKind); 4] = [
    (RuleKind::Bayes, ModelKind::Paper),
    (RuleKind::LogOdds, ModelKind::Smooth),
    (RuleKind::DempsterShafer, ModelKind::Paper),
    (RuleKind::Himm, ModelKind::LogOdds),
];

/// Four sweeps, alternating direction, of the stepper's reading centres.
fn readings() -> Vec<Observation> {
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let forth: Vec<f32> = (0..50).map(|i| -147.0 + 6.0 * i as f32).collect();
    let back: Vec<f32> = forth.iter().rev().copied().collect();
    [&forth, &back, &forth, &back]
        .into_iter()
        .flatten()
        .map(|&deg| Observation {
            pose: Isometry2::identity(),
            angle_rad: deg.to_radians(),
            range_m: Some(rng.random_range(0.3..3.5)),
            rejected_echo_m: None,
            beam_half_angle_rad: 30f32.to_radians(),
            max_range_m: 4.0,
        })
        .collect()
}

fn config(cells: u32, resolution_m: f32, model: ModelKind, rule: RuleKind) -> FusionConfig {
    FusionConfig {
        grid: GridConfig {
            cells,
            resolution_m,
            ..GridConfig::default()
        },
        model: ModelConfig::default_for(model),
        rule: RuleConfig::default_for(rule),
        ..FusionConfig::default()
    }
}

fn mapper(config: FusionConfig) -> Mapper {
    match Mapper::new(config) {
        Ok(m) => m,
        Err(e) => panic!("bench configuration refused: {e}"),
    }
}

/// Fuses every reading once into `mapper` with `kernel`; returns the mean number of cells a
/// reading updated.
fn one_cycle(mapper: &mut Mapper, kernel: Kernel, readings: &[Observation]) -> u64 {
    let mut touched = 0;
    for obs in readings {
        match mapper.update_with(obs, kernel) {
            Ok(u) => touched += u.cells_updated,
            Err(e) => panic!("bench reading refused: {e}"),
        }
    }
    ((touched as f64 / readings.len() as f64).round() as u64).max(1)
}

fn bench_case(
    group: &mut BenchmarkGroup<'_, WallTime>,
    config: FusionConfig,
    kernel: Kernel,
    readings: &[Observation],
) {
    // Both kernels update the same cells (the unit tests check it); counted with the fast one.
    let touched = one_cycle(&mut mapper(config), Kernel::Cone, readings);
    let name = match kernel {
        Kernel::Cone => "cone",
        Kernel::WholeGrid => "whole_grid",
    };
    let id = format!("{name}/{}+{}", config.rule.kind(), config.model.kind());
    group.throughput(Throughput::Elements(touched));
    // Built on first use, so a filtered run sets up only the cases it measures; the cycle before
    // measuring builds every cache the kernel keeps.
    let mut warm: Option<Mapper> = None;
    let mut next = readings.iter().cycle();
    group.bench_function(id, |b| {
        let mapper = warm.get_or_insert_with(|| {
            let mut m = mapper(config);
            // The whole-grid pass keeps only the sensor's arrays: one reading fills them.
            let warm_up = if kernel == Kernel::Cone {
                readings
            } else {
                &readings[..1]
            };
            one_cycle(&mut m, kernel, warm_up);
            m
        });
        b.iter(|| {
            let obs = next.next().unwrap_or(&readings[0]);
            black_box(mapper.update_with(black_box(obs), kernel))
        })
    });
}

fn kernels(c: &mut Criterion) {
    let readings = readings();
    for (cells, res) in GRIDS {
        let cm = (res * 100.0).round() as u32;
        let mut group = c.benchmark_group(format!("grid_{cells}_{cm}cm"));
        group
            .warm_up_time(Duration::from_secs(1))
            .measurement_time(Duration::from_secs(3));
        for (rule, model) in PAIRS {
            bench_case(
                &mut group,
                config(cells, res, model, rule),
                Kernel::Cone,
                &readings,
            );
        }
        // Milliseconds per reading: few samples, one reading per iteration.
        group
            .sampling_mode(SamplingMode::Flat)
            .sample_size(10)
            .measurement_time(Duration::from_secs(2));
        for (rule, model) in PAIRS {
            bench_case(
                &mut group,
                config(cells, res, model, rule),
                Kernel::WholeGrid,
                &readings,
            );
        }
        group.finish();
    }

    // Every model with every rule, fast kernel, at the 1024² target size.
    let mut group = c.benchmark_group("models_1024_1cm");
    group
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(2));
    for rule in RuleKind::ALL {
        for model in ModelKind::ALL {
            bench_case(
                &mut group,
                config(1024, 0.01, model, rule),
                Kernel::Cone,
                &readings,
            );
        }
    }
    group.finish();

    // What the steady-state figures leave out: a new mapper (as after a restart) builds its
    // stencil, and each beam direction's spans on its first reading. Mapper::new and one sweep of
    // 50 readings, recommended preset.
    let mut group = c.benchmark_group("cold_1024_1cm");
    group
        .sampling_mode(SamplingMode::Flat)
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3))
        .throughput(Throughput::Elements(50));
    let recommended = config(1024, 0.01, ModelKind::Smooth, RuleKind::LogOdds);
    group.bench_function("new_mapper_and_first_sweep", |b| {
        b.iter(|| {
            let mut m = mapper(recommended);
            black_box(one_cycle(&mut m, Kernel::Cone, &readings[..50]))
        })
    });
    group.finish();
}

criterion_group!(benches, kernels);
criterion_main!(benches);
