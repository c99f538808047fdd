//! One frame of a 2048 × 2048 grid into a 200 × 60 terminal: pooling (about 20 × 20 cells per
//! pixel), colours and the rest of the screen. Target: ≤ 5 ms for a cold frame (a new snapshot
//! every frame); a warm frame (same snapshot, pooled picture cached) shows the steady state.

use std::hint::black_box;
use std::time::Instant;

use criterion::{Criterion, criterion_group, criterion_main};
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use sonar_common::ipc::{CELL_UNKNOWN, GridHeader, LAYOUT_VERSION, encode_probability};
use sonar_viewer::app::{App, View};
use sonar_viewer::heatmap::{ColorMode, Palette, seen_box};
use sonar_viewer::ui::{self, MapCache};

const SIDE: u32 = 2048;

/// A round room of 20 m across: free inside with a gradient, a wall ring, unknown outside.
fn grid() -> (GridHeader, Vec<u8>) {
    let c = f64::from(SIDE) / 2.0;
    let cells = (0..SIDE * SIDE)
        .map(|i| {
            let (x, y) = (f64::from(i % SIDE) - c, f64::from(i / SIDE) - c);
            let r = x.hypot(y);
            match r {
                r if r < 900.0 => encode_probability((r / 2000.0) as f32),
                r if r < 910.0 => encode_probability(0.95),
                _ => CELL_UNKNOWN,
            }
        })
        .collect();
    let header = GridHeader {
        layout_version: LAYOUT_VERSION,
        width: SIDE,
        height: SIDE,
        resolution_m: 0.01,
        origin_x_m: -10.24,
        origin_y_m: -10.24,
        ..GridHeader::default()
    };
    (header, cells)
}

fn frame(c: &mut Criterion) {
    let (header, cells) = grid();
    let now = Instant::now();
    let area = Rect::new(0, 0, 200, 60);
    for (name, mode) in [
        ("truecolor", ColorMode::TrueColor),
        ("256", ColorMode::Indexed256),
    ] {
        let mut app = App::new(Palette::new(mode), View::Map);
        if let Err(e) = app.on_grid(&header, &cells, now) {
            panic!("bench grid refused: {e}");
        }
        let mut buf = Buffer::empty(area);
        let mut cache = MapCache::default();
        c.bench_function(
            &format!("frame 2048² → 200×60, new snapshot, {name}"),
            |b| {
                b.iter(|| {
                    cache.invalidate();
                    black_box(ui::render(area, &mut buf, &app, &mut cache, now))
                })
            },
        );
        c.bench_function(&format!("frame 2048² → 200×60, cached, {name}"), |b| {
            b.iter(|| black_box(ui::render(area, &mut buf, &app, &mut cache, now)))
        });
    }
    let mut app = App::new(Palette::new(ColorMode::TrueColor), View::Map);
    c.bench_function(
        "copy of a 2048² snapshot into the viewer (App::on_grid)",
        |b| b.iter(|| app.on_grid(black_box(&header), black_box(&cells), now)),
    );
    // The part of on_grid that finds what has been seen, for the map's default framing.
    let side = SIDE as usize;
    c.bench_function("seen part of a 2048² snapshot (heatmap::seen_box)", |b| {
        b.iter(|| seen_box(black_box(&cells), side, side))
    });
}

criterion_group!(benches, frame);
criterion_main!(benches);
