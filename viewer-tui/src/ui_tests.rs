//! Rendering tests: synthetic grids and radar arrays drawn into ratatui's `TestBackend`, checked
//! by insta snapshots (the glyphs) and by assertions on the colours and positions that matter.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::time::{Duration, Instant};

use crossterm::event::{KeyCode, KeyEvent, KeyModifiers};
use ratatui::Terminal;
use ratatui::backend::TestBackend;
use ratatui::buffer::Buffer;
use sonar_common::ipc::{
    CELL_UNKNOWN, DriverStatus, FeatureRecord, FeaturesHeader, FusionStatus, GridHeader,
    LAYOUT_VERSION, LinkState, LocalizedPose, Radar, Reading, ScanMode, SlamCorrection,
    encode_probability, feature_flags, flags, model_code, preset_code, rule_code, slam_state,
};

use super::*;
use crate::app::{App, Segment, View};
use crate::heatmap::{ColorMode, Palette, Viewport};
use sonar_common::ipc::feature_kind;

const FREE: u8 = 20;
const WALL: u8 = 230;

/// A 6 m × 4 m grid at 5 cm: a room from (-2.5, -1.5) to (2, 1.5) m with one-cell walls, seen
/// free inside, never observed outside; a post inside casts an unobserved shadow. Sensor at (0, 0).
fn room_grid() -> (GridHeader, Vec<u8>) {
    let (w, h) = (120usize, 80usize);
    let mut cells = vec![CELL_UNKNOWN; w * h];
    for y in 10..=70 {
        for x in 10..=100 {
            let wall = x == 10 || x == 100 || y == 10 || y == 70;
            cells[y * w + x] = if wall { WALL } else { FREE };
        }
    }
    for y in 50..=60 {
        for x in 80..=99 {
            let post = x < 83 && y < 53;
            cells[y * w + x] = if post { WALL } else { CELL_UNKNOWN };
        }
    }
    let count = |f: fn(u8) -> bool| cells.iter().filter(|&&c| f(c)).count() as u32;
    let header = GridHeader {
        seq: 42,
        layout_version: LAYOUT_VERSION,
        width: w as u32,
        height: h as u32,
        resolution_m: 0.05,
        origin_x_m: -3.0,
        origin_y_m: -2.0,
        readings_fused: 250,
        model: model_code::PAPER,
        rule: rule_code::BAYES,
        preset: preset_code::PAPER,
        sweep_id: 3,
        occupied_cells: count(|c| c != CELL_UNKNOWN && c > 127),
        free_cells: count(|c| c < 127),
        unknown_cells: count(|c| c == CELL_UNKNOWN),
        ..GridHeader::default()
    };
    (header, cells)
}

/// Range from the origin to the room's walls along `deg`.
fn room_range(deg: f32) -> f32 {
    let (s, c) = deg.to_radians().sin_cos();
    let tx = if c > 0.0 { 2.0 / c } else { -2.5 / c };
    let ty = if s > 0.0 { 1.5 / s } else { -1.5 / s };
    tx.abs().min(ty.abs())
}

/// 6° bins over the full sweep; swept up to 45°, one bin without echo.
fn room_radar() -> Radar {
    let mut radar = Radar {
        seq: 9,
        bin_count: 50,
        first_bin_deg: -147.0,
        bin_width_deg: 6.0,
        beam_half_angle_deg: 30.0,
        max_range_m: 4.0,
        current_angle_deg: 45.0,
        sweep_id: 3,
        direction: 1,
        mode: ScanMode::Full as u32,
        ..Radar::default()
    };
    for i in 0..50 {
        let deg = -147.0 + 6.0 * i as f32;
        radar.distances_m[i] = if deg > 45.0 {
            f32::NAN // not swept yet
        } else if deg == -99.0 {
            f32::INFINITY // no echo
        } else {
            room_range(deg)
        };
    }
    radar
}

fn reading(seq: u64, angle_deg: f32, distance_m: f32, flags: u32) -> Reading {
    Reading {
        seq,
        angle_deg,
        distance_m,
        flags,
        layout_version: LAYOUT_VERSION,
        ..Reading::default()
    }
}

/// Everything running: driver connected and scanning, fusion publishing the room.
fn live_app(t0: Instant) -> App {
    let mut app = App::new(Palette::new(ColorMode::TrueColor), View::Split);
    let (header, cells) = room_grid();
    app.on_grid(&header, &cells, t0).unwrap();
    app.on_radar(&room_radar(), t0).unwrap();
    let status = DriverStatus {
        stamp_ns: 1_000_000_000,
        readings_published: 240,
        lines_ok: 960,
        lines_rejected: 2,
        link_state: LinkState::Connected as u32,
        mode: ScanMode::Full as u32,
        sweep_id: 3,
        angle_deg: 45.0,
        direction: 1,
        layout_version: LAYOUT_VERSION,
        ..DriverStatus::default()
    };
    app.on_driver_status(&status, t0).unwrap();
    let later = DriverStatus {
        stamp_ns: 2_000_000_000,
        readings_published: 245,
        ..status
    };
    app.on_driver_status(&later, t0).unwrap();
    app.on_reading(&reading(243, 33.0, 1.79, 0), t0);
    app.on_reading(&reading(244, 39.0, 0.0, flags::NO_ECHO), t0);
    app.on_reading(&reading(245, 45.0, 2.12, 0), t0);
    app
}

fn draw(app: &mut App, width: u16, height: u16, now: Instant) -> Terminal<TestBackend> {
    let mut terminal = Terminal::new(TestBackend::new(width, height)).unwrap();
    let mut cache = MapCache::default();
    let mut info = DrawInfo::default();
    terminal
        .draw(|f| info = draw_frame(f, app, &mut cache, now))
        .unwrap();
    app.map_px = info.map_px;
    app.map_origin = info.map_origin;
    terminal
}

fn draw_frame(f: &mut Frame, app: &App, cache: &mut MapCache, now: Instant) -> DrawInfo {
    super::draw(f, app, cache, now)
}

fn screen_text(buf: &Buffer) -> String {
    let area = buf.area;
    (0..area.height)
        .map(|y| {
            (0..area.width)
                .map(|x| buf[(x, y)].symbol())
                .collect::<String>()
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// The terminal cell and pixel half showing grid cell (x, y) in a map drawn at `inner`.
fn cell_of(app: &App, inner: Rect, x: u32, y: u32) -> ((u16, u16), bool) {
    let grid = app.grid.as_ref().unwrap();
    let (w, h) = app.map_px;
    let vp: Viewport = app.map.viewport(grid, w, h);
    let (px, py) = vp.pixel_of(x, y, grid.height()).unwrap();
    (
        (inner.x + px as u16, inner.y + (py / 2) as u16),
        py % 2 == 0,
    )
}

#[test]
fn map_view_shows_walls_free_and_unknown_apart() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    app.view = View::Map;
    app.map.cursor = Some((30, 30)); // out of the way of the cells checked below
    let terminal = draw(&mut app, 64, 24, t0);
    insta::assert_snapshot!(terminal.backend());

    let buf = terminal.backend().buffer();
    let inner = Rect::new(1, 1, 62, 20);
    let palette = Palette::new(ColorMode::TrueColor);
    // The east wall (x = 100) at mid height.
    let (pos, _) = cell_of(&app, inner, 100, 40);
    assert_eq!(buf[pos].symbol(), "▄", "wall glyph at {pos:?}");
    let wall_color = palette.color(Some(WALL));
    assert!(buf[pos].fg == wall_color || buf[pos].bg == wall_color);
    // Free space inside, never-observed space outside: different glyphs and colours.
    let (free, _) = cell_of(&app, inner, 40, 40);
    let (unknown, _) = cell_of(&app, inner, 104, 40);
    assert_eq!(buf[free].symbol(), "▀");
    assert_eq!(buf[free].fg, palette.color(Some(FREE)));
    assert_eq!(buf[unknown].symbol(), " ");
    assert_eq!(buf[unknown].bg, palette.color(Some(CELL_UNKNOWN)));
    assert_ne!(buf[free].fg, buf[unknown].bg);
    // The shadow behind the post is never observed either, though inside the room.
    // Issue 16: the map frames what was seen, so the room fills the picture, not a third of it.
    let (west, _) = cell_of(&app, inner, 10, 40);
    let (east, _) = cell_of(&app, inner, 100, 40);
    assert!(east.0 - west.0 >= inner.width * 4 / 5, "{west:?}..{east:?}");
    let (shadow, _) = cell_of(&app, inner, 92, 56);
    assert_eq!(buf[shadow].symbol(), " ");
    // The sensor sits at the origin, its arrow along its 0°: a fixed head's heading is 0.
    let (sensor, _) = cell_of(&app, inner, 60, 40);
    assert_eq!(buf[sensor].symbol(), "→");
}

/// What fusion would find in [`room_grid`]: the north wall seen in part, the west wall without
/// extent yet and heard from one place only (tentative), the south-east corner and the post.
/// Positions are cell centres (x = -3 + 0.05·(cx + 0.5) m).
fn room_features() -> (FeaturesHeader, Vec<FeatureRecord>) {
    let none = FeatureRecord {
        angle_sigma_deg: f32::NAN,
        segment_ax_m: f32::NAN,
        segment_ay_m: f32::NAN,
        segment_bx_m: f32::NAN,
        segment_by_m: f32::NAN,
        flags: feature_flags::CONFIRMED,
        ..FeatureRecord::default()
    };
    let north = FeatureRecord {
        id: 1,
        kind: feature_kind::PLANE,
        x_m: 0.0,
        y_m: 1.525,
        angle_deg: -90.0,
        angle_sigma_deg: 2.0,
        confidence: 0.9,
        segment_ax_m: -1.475, // cell 30
        segment_ay_m: 1.525,  // row 70
        segment_bx_m: 1.525,  // cell 90
        segment_by_m: 1.525,
        ..none
    };
    let west = FeatureRecord {
        id: 2,
        kind: feature_kind::PLANE,
        x_m: -2.475, // cell 10
        y_m: 0.025,
        angle_deg: 0.0,
        angle_sigma_deg: 8.0,
        confidence: 0.4,
        flags: 0,
        ..none
    };
    let corner = FeatureRecord {
        id: 3,
        kind: feature_kind::CORNER,
        x_m: 2.025,  // cell 100
        y_m: -1.475, // row 10
        angle_deg: -37.0,
        confidence: 0.7,
        ..none
    };
    let post = FeatureRecord {
        id: 4,
        kind: feature_kind::POINT,
        x_m: 1.075, // cell 81
        y_m: 0.575, // row 51
        angle_deg: 28.0,
        confidence: 0.8,
        ..none
    };
    let records = vec![west, corner, north, post];
    let header = FeaturesHeader {
        seq: 5,
        sweeps: 12,
        layout_version: LAYOUT_VERSION,
        feature_count: records.len() as u32,
        ..FeaturesHeader::default()
    };
    (header, records)
}

/// The text of the cells inside `area`.
fn area_text(buf: &Buffer, area: Rect) -> String {
    (area.top()..area.bottom())
        .map(|y| {
            (area.left()..area.right())
                .map(|x| buf[(x, y)].symbol())
                .collect::<String>()
        })
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn walls_corners_and_posts_are_drawn_over_the_map() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    let (header, records) = room_features();
    app.on_features(&header, &records, t0).unwrap();
    app.view = View::Map;
    app.map.cursor = Some((30, 30));
    let terminal = draw(&mut app, 64, 24, t0);
    insta::assert_snapshot!(terminal.backend());

    let buf = terminal.backend().buffer();
    let inner = Rect::new(1, 1, 62, 20);
    let green = app.palette.feature();
    let (corner, _) = cell_of(&app, inner, 100, 10);
    assert_eq!((buf[corner].symbol(), buf[corner].fg), ("◆", green));
    let (post, _) = cell_of(&app, inner, 81, 51);
    assert_eq!((buf[post].symbol(), buf[post].fg), ("●", green));
    // The north wall from cell 30 to 90 of row 70, the room's wall glyphs on either side.
    let (from, _) = cell_of(&app, inner, 30, 70);
    let (to, _) = cell_of(&app, inner, 90, 70);
    for x in from.0..=to.0 {
        assert_eq!(
            (buf[(x, from.1)].symbol(), buf[(x, from.1)].fg),
            ("─", green)
        );
    }
    assert_eq!(buf[(from.0 - 2, from.1)].symbol(), "▄");
    assert_eq!(buf[(to.0 + 2, to.1)].symbol(), "▄");
    // The west wall without extent: a short vertical tick on its foot point, tentative (heard from
    // one place only): dim, in its own colour.
    let (foot, _) = cell_of(&app, inner, 10, 40);
    assert_eq!(
        (buf[foot].symbol(), buf[foot].fg),
        ("│", app.palette.tentative_feature())
    );
    assert!(buf[foot].modifier.contains(Modifier::DIM));
    assert!(buf[post].modifier.contains(Modifier::BOLD));
    let ticks = area_text(buf, inner).matches('│').count();
    assert!((2..=5).contains(&ticks), "{ticks} tick cells");
    // Sensor and cursor stay on top.
    let (sensor, _) = cell_of(&app, inner, 60, 40);
    assert_eq!(buf[sensor].symbol(), "→");

    // `o` hides them, and the plain map is back.
    app.on_key(KeyEvent::new(KeyCode::Char('o'), KeyModifiers::NONE));
    let hidden = draw(&mut app, 64, 24, t0);
    let text = area_text(hidden.backend().buffer(), inner);
    assert!(!text.contains(['─', '│', '◆', '●']), "{text}");
    assert_eq!(hidden.backend().buffer()[corner].symbol(), "▄");
}

#[test]
fn the_status_panel_counts_the_features_and_lists_the_most_confident() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    let (header, records) = room_features();
    app.on_features(&header, &records, t0).unwrap();
    let terminal = draw(&mut app, 120, 32, t0);
    let text = screen_text(terminal.backend().buffer());
    for expected in [
        "features 2 walls · 1 corner",
        "         1 post · 1 tentative",
        "merged   12 sweeps",
        // Most confident first; a wall at the middle of its segment.
        "wall     ─ +0.02, +1.52 m  90%",
        "post     ● +1.08, +0.57 m  80%",
        "corner   ◆ +2.03, -1.48 m  70%",
        "wall     ─ -2.47, +0.03 m  40%",
    ] {
        assert!(text.contains(expected), "missing {expected:?} in\n{text}");
    }
    let order: Vec<usize> = ["90%", "80%", "70%", "40%"]
        .iter()
        .filter_map(|c| text.find(c))
        .collect();
    assert!(order.is_sorted() && order.len() == 4, "{order:?}");

    // A shorter panel lists fewer, and the IPC problem still fits under them.
    app.ipc_problem = Some("open sonar/radar: incompatible types".to_owned());
    app.show_features = false;
    let terminal = draw(&mut app, 120, 28, t0);
    let text = screen_text(terminal.backend().buffer());
    assert!(text.contains("12 sweeps · hidden (o)"), "{text}");
    assert!(text.contains("wall     ─ +0.02, +1.52 m  90%"), "{text}");
    assert!(!text.contains("40%"), "{text}");
    assert!(text.contains("ipc      open sonar/radar"), "{text}");
}

#[test]
fn downsampling_keeps_a_single_occupied_cell_visible() {
    let t0 = Instant::now();
    let mut app = App::new(Palette::new(ColorMode::Indexed256), View::Map);
    let (w, h) = (2000u32, 1500u32);
    let mut cells = vec![encode_probability(0.1); (w * h) as usize];
    let (x, y) = (1234u32, 567u32);
    cells[(y * w + x) as usize] = encode_probability(0.9);
    let header = GridHeader {
        layout_version: LAYOUT_VERSION,
        width: w,
        height: h,
        resolution_m: 0.01,
        origin_x_m: -20.0,
        origin_y_m: -15.0,
        ..GridHeader::default()
    };
    app.on_grid(&header, &cells, t0).unwrap();
    app.map.cursor = Some((0, 0));
    let terminal = draw(&mut app, 40, 14, t0);
    insta::assert_snapshot!(terminal.backend());

    // About 57 × 57 cells per pixel, and still exactly one wall glyph, where the cell is.
    let buf = terminal.backend().buffer();
    let text = screen_text(buf);
    assert_eq!(text.matches('▄').count(), 1, "{text}");
    let (pos, upper) = cell_of(&app, Rect::new(1, 1, 38, 10), x, y);
    assert_eq!(buf[pos].symbol(), "▄");
    let occupied = Palette::new(ColorMode::Indexed256).color(Some(encode_probability(0.9)));
    let shown = if upper { buf[pos].bg } else { buf[pos].fg };
    assert_eq!(shown, occupied);
    assert!(matches!(shown, Color::Indexed(_)), "256-colour mode");
}

/// World position of the centre of a terminal cell of a radar drawn at `inner` for `range`.
fn radar_world(inner: Rect, range: f64, col: u16, row: u16) -> (f64, f64) {
    let (w, h) = (f64::from(inner.width), 2.0 * f64::from(inner.height));
    let half = 1.08 * range;
    let (hx, hy) = if w >= h {
        (half * w / h, half)
    } else {
        (half, half * h / w)
    };
    let fx = (f64::from(col - inner.x) + 0.5) / w;
    let fy = (f64::from(row - inner.y) + 0.5) / f64::from(inner.height);
    (-hx + 2.0 * hx * fx, hy - 2.0 * hy * fy)
}

/// World positions (relative to the sensor) of the marks drawn in `color` inside a 4 m radar
/// drawn at `inner`.
fn radar_marks(buf: &Buffer, inner: Rect, color: Color) -> Vec<(f64, f64)> {
    (inner.top()..inner.bottom())
        .flat_map(|y| (inner.left()..inner.right()).map(move |x| (x, y)))
        .filter(|&(x, y)| buf[(x, y)].fg == color && buf[(x, y)].symbol() != " ")
        .map(|(x, y)| radar_world(inner, 4.0, x, y))
        .collect()
}

/// The radar view of [`live_app`] with `segment` as the last local scan asked for.
fn radar_with_local_segment(t0: Instant, segment: Segment) -> App {
    let mut app = live_app(t0);
    app.view = View::Radar;
    app.local_segment = Some(segment);
    app
}

#[test]
fn radar_shows_a_wall_as_an_arc_at_its_range() {
    let t0 = Instant::now();
    let mut app = App::new(Palette::new(ColorMode::TrueColor), View::Radar);
    // A wall 2.5 m away from 20° to 60°, in 1° bins; nothing elsewhere.
    let mut radar = Radar {
        layout_version: LAYOUT_VERSION,
        bin_count: 301,
        first_bin_deg: -150.0,
        bin_width_deg: 1.0,
        beam_half_angle_deg: 30.0,
        max_range_m: 4.0,
        current_angle_deg: 60.0,
        direction: 1,
        mode: ScanMode::Local as u32,
        ..Radar::default()
    };
    for deg in 20..=60 {
        radar.distances_m[(deg + 150) as usize] = 2.5;
    }
    app.on_radar(&radar, t0).unwrap();
    let terminal = draw(&mut app, 60, 26, t0);
    insta::assert_snapshot!(terminal.backend());

    let buf = terminal.backend().buffer();
    let inner = Rect::new(1, 1, 58, 22);
    let echoes = radar_marks(buf, inner, Color::LightRed);
    assert!(echoes.len() >= 6, "the arc is drawn: {echoes:?}");
    for (x, y) in echoes {
        let (r, a) = (x.hypot(y), y.atan2(x).to_degrees());
        // Within a terminal cell (≈ 0.18 m wide, 0.35 m tall here) of the arc.
        assert!((r - 2.5).abs() < 0.3, "echo at r = {r:.2} m");
        assert!((15.0..=65.0).contains(&a), "echo at {a:.0}°");
    }
}

#[test]
fn split_view_with_status_panel() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    let terminal = draw(&mut app, 120, 32, t0 + Duration::from_secs(1));
    insta::assert_snapshot!(terminal.backend());

    let text = screen_text(terminal.backend().buffer());
    for expected in [
        "driver   alive · connected",
        "fusion   alive",
        "scan     full · sweep 3 ccw",
        "5.0 readings/s",
        "2 lines rejected",
        "+45.0°  2.120 m",
        "+39.0°  no echo",
        "model    paper",
        "rule     Bayes",
        "grid     120×80 · 5 cm",
        "occupied",
        "cursor   +0.03, +0.03 m",
        "p = 0.08 free",
    ] {
        assert!(text.contains(expected), "missing {expected:?} in\n{text}");
    }
}

#[test]
fn waiting_for_everything_before_the_other_processes_start() {
    let t0 = Instant::now();
    let mut app = App::new(Palette::new(ColorMode::TrueColor), View::Split);
    let terminal = draw(&mut app, 100, 24, t0);
    insta::assert_snapshot!(terminal.backend());
    let text = screen_text(terminal.backend().buffer());
    assert!(text.contains("waiting for driver…"));
    assert!(text.contains("waiting for fusion…"));
}

#[test]
fn producers_that_stop_are_reported_gone() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    let terminal = draw(&mut app, 120, 32, t0 + Duration::from_secs(12));
    let text = screen_text(terminal.backend().buffer());
    assert!(text.contains("driver   gone for 12 s"), "{text}");
    assert!(text.contains("fusion   gone for 12 s"), "{text}");
    // The last map stays on screen.
    assert!(text.contains('▄'));
}

/// Issue 28: the fusion's health counters (`sonar/fusion_status`) are in the panel, the ones that
/// went wrong in colour, and a repeat that only moves the stamp costs no frame.
#[test]
fn the_fusion_health_counters_are_shown() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    let healthy = FusionStatus {
        stamp_ns: 1,
        readings_received: 250,
        readings_fused: 250,
        saves: 3,
        layout_version: LAYOUT_VERSION,
        ..FusionStatus::default()
    };
    app.on_fusion_status(&healthy, t0).unwrap();
    let text = screen_text(draw(&mut app, 120, 40, t0).backend().buffer());
    assert!(text.contains("health   0 lost · 0 rejected"), "{text}");
    assert!(text.contains("saves    3 saved"), "{text}");
    assert!(!text.contains("seq restarts"), "{text}");

    let drawn = app.drawn(t0);
    app.on_fusion_status(
        &FusionStatus {
            stamp_ns: 2,
            ..healthy
        },
        t0,
    )
    .unwrap();
    assert!(!app.needs_redraw(t0, Some(&drawn)));

    let troubled = FusionStatus {
        stamp_ns: 3,
        readings_lost: 17,
        readings_rejected: 2,
        readings_out_of_order: 1,
        save_failures: 4,
        restored: 1,
        ..healthy
    };
    app.on_fusion_status(&troubled, t0).unwrap();
    assert!(app.needs_redraw(t0, Some(&drawn)));
    let terminal = draw(&mut app, 120, 40, t0);
    let buf = terminal.backend().buffer();
    let text = screen_text(buf);
    for expected in [
        "health   17 lost · 2 rejected",
        "1 seq restarts",
        "saves    3 saved · 4 failed",
        "map restored at start",
    ] {
        assert!(text.contains(expected), "missing {expected:?} in\n{text}");
    }
    let (row, line) = text
        .lines()
        .enumerate()
        .find(|(_, l)| l.contains("17 lost"))
        .unwrap();
    let column = line.find("17 lost").unwrap();
    let column = line[..column].chars().count() as u16;
    assert_eq!(buf[(column, row as u16)].fg, Color::Yellow);

    // Another layout is refused, the counters kept.
    let old = FusionStatus {
        layout_version: 0,
        ..troubled
    };
    assert!(app.on_fusion_status(&old, t0).is_err());
    assert_eq!(app.fusion_status, Some(troubled));
}

/// Issue 28: while nothing has been seen, the panel says on which iceoryx2 prefix and root the
/// viewer looks and what to check; once both producers are there it no longer does.
#[test]
fn waiting_names_where_the_viewer_looks() {
    let t0 = Instant::now();
    let mut app = App::new(Palette::new(ColorMode::TrueColor), View::Split);
    app.namespace = Some("iceoryx2 prefix \"robot_\", root /tmp/sonar-x/".to_owned());
    let text = screen_text(draw(&mut app, 120, 32, t0).backend().buffer());
    let panel: String = text
        .lines()
        .map(|l| {
            l.chars()
                .skip(87)
                .take(32)
                .collect::<String>()
                .trim()
                .to_owned()
        })
        .collect::<Vec<_>>()
        .join(" ");
    for expected in [
        "waiting for driver…",
        "prefix \"robot_\", root",
        "/tmp/sonar-x/",
        "--iox-prefix/--iox-root",
        "sonar services",
    ] {
        assert!(panel.contains(expected), "missing {expected:?} in\n{text}");
    }

    let mut live = live_app(t0);
    live.namespace = app.namespace.clone();
    let text = screen_text(draw(&mut live, 120, 32, t0).backend().buffer());
    assert!(!text.contains("robot_"), "{text}");
}

/// Issue 28: readings from `sonar-replay` that stop mean the recording ended: the panel says the
/// replay finished, not that a driver is gone.
#[test]
fn a_finished_replay_is_not_a_driver_gone() {
    let t0 = Instant::now();
    let mut app = App::new(Palette::new(ColorMode::TrueColor), View::Split);
    let (header, cells) = room_grid();
    app.on_grid(&header, &cells, t0).unwrap();
    app.on_reading(&reading(1, 10.0, 1.5, 0), t0);
    app.on_publishers(true, true, Some(true), t0);
    let text = screen_text(draw(&mut app, 120, 32, t0).backend().buffer());
    assert!(text.contains("driver   replay running"), "{text}");

    // The replay exits: no live publisher of readings is left (`None`: whoever it was stays).
    let later = t0 + Duration::from_secs(12);
    app.on_publishers(false, true, None, later);
    let text = screen_text(draw(&mut app, 120, 32, later).backend().buffer());
    assert!(text.contains("driver   replay finished"), "{text}");
    assert!(!text.contains("gone for"), "{text}");
    let compact = screen_text(draw(&mut app, 70, 14, later).backend().buffer());
    assert!(
        compact.contains(" replay finished · fusion alive"),
        "{compact}"
    );

    // A driver that takes over is a driver again, and its loss is a loss.
    app.on_publishers(true, true, Some(false), later);
    let much_later = later + Duration::from_secs(12);
    app.on_publishers(false, true, None, much_later);
    let text = screen_text(draw(&mut app, 120, 32, much_later).backend().buffer());
    assert!(text.contains("driver   gone for 12 s"), "{text}");
}

#[test]
fn the_head_its_silences_and_its_latest_error_reach_the_status_panel() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    let mut status = *app.driver.as_ref().unwrap();
    sonar_common::ipc::set_padded_text(&mut status.head_id, "3F2A9C0417B6E5D1");
    status.silences = 2;
    status.device_errors = 1;
    sonar_common::ipc::set_padded_text(
        &mut status.last_device_error,
        "RANGE: segment outside the limits -15000..15000",
    );
    status.stamp_ns += 1_000_000_000;
    app.on_driver_status(&status, t0).unwrap();
    let term = draw(&mut app, 160, 50, t0);
    let screen = screen_text(term.backend().buffer());
    // The panel wraps long values onto the next line.
    for shown in [
        "head     3F2A9C0417B6E5D1",
        "silent ×2",
        "head err RANGE: segment outside",
    ] {
        assert!(screen.contains(shown), "{shown:?} in {screen}");
    }
}

/// Issue 24: a head stopped on a hardware fault says so, what it stopped on, and how to go on.
#[test]
fn a_head_stopped_on_a_fault_is_shown_with_what_to_do() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    let mut status = *app.driver.as_ref().unwrap();
    status.device_errors = 1;
    status.head_fault = 1;
    sonar_common::ipc::set_padded_text(
        &mut status.last_device_error,
        "HARDWARE: MIN switch not found in 315 deg",
    );
    status.stamp_ns += 1_000_000_000;
    app.on_driver_status(&status, t0).unwrap();
    let screen = screen_text(draw(&mut app, 160, 50, t0).backend().buffer());
    assert!(
        screen.contains("head err STOPPED: HARDWARE: MIN"),
        "{screen}"
    );
    assert!(screen.contains("R resets it"), "{screen}");
    status.head_fault = 0;
    status.stamp_ns += 1_000_000_000;
    app.on_driver_status(&status, t0).unwrap();
    let screen = screen_text(draw(&mut app, 160, 50, t0).backend().buffer());
    assert!(!screen.contains("STOPPED"), "{screen}");
}

/// Issue 16: a terminal too small for the status panel gets its essentials in one line, the
/// cursor's cell included; problems come first, so they are never the part cut off.
#[test]
fn a_small_terminal_shows_the_essentials_in_one_line() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    let terminal = draw(&mut app, 70, 14, t0);
    insta::assert_snapshot!(terminal.backend());
    let screen = screen_text(terminal.backend().buffer());
    let line = screen.lines().nth(12).unwrap();
    assert_eq!(
        line.trim_end(),
        " driver alive · fusion alive · full 65% · + +0.03, +0.03 m p = 0.08 fr"
    );
    // Low but wide: compact too (the panel would be cut short).
    let screen = screen_text(draw(&mut app, 120, 12, t0).backend().buffer());
    assert!(
        screen.contains("p = 0.08 free · 5.0 readings/s"),
        "{screen}"
    );

    // A producer gone and the head's refusal lead the line.
    let mut status = *app.driver.as_ref().unwrap();
    status.device_errors = 1;
    status.stamp_ns += 1_000_000_000;
    sonar_common::ipc::set_padded_text(&mut status.last_device_error, "RANGE: 100..200");
    app.on_driver_status(&status, t0).unwrap();
    let later = t0 + Duration::from_secs(5);
    app.on_publishers(true, false, None, later);
    let screen = screen_text(draw(&mut app, 70, 14, later).backend().buffer());
    let line = screen.lines().nth(12).unwrap();
    assert!(
        line.starts_with(" driver alive · fusion gone for 5 s · RANGE: 100..200 · full"),
        "{line}"
    );
}

/// Issue 16: `NO_COLOR` draws not one colour, the map's classes told apart by shade glyphs and the
/// radar's rings dotted; 16 colours use only the ANSI ones.
#[test]
fn no_colour_and_sixteen_colours() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    app.palette = Palette::new(ColorMode::Mono);
    app.map.cursor = Some((30, 30));
    let terminal = draw(&mut app, 120, 32, t0);
    insta::assert_snapshot!(terminal.backend());
    let buf = terminal.backend().buffer();
    assert!(
        buf.content()
            .iter()
            .all(|c| c.fg == Color::Reset && c.bg == Color::Reset)
    );
    let map = Rect::new(1, 1, 41, 29);
    for ((x, y), glyph) in [((100, 40), "█"), ((40, 40), "░"), ((104, 40), " ")] {
        let (pos, _) = cell_of(&app, map, x, y);
        assert_eq!(buf[pos].symbol(), glyph, "cell ({x}, {y})");
    }

    app.palette = Palette::new(ColorMode::Ansi16);
    let terminal = draw(&mut app, 120, 32, t0);
    let buf = terminal.backend().buffer();
    assert!(
        buf.content()
            .iter()
            .all(|c| !matches!(c.fg, Color::Rgb(..) | Color::Indexed(_))
                && !matches!(c.bg, Color::Rgb(..) | Color::Indexed(_)))
    );
    let (wall, upper) = cell_of(&app, map, 100, 40);
    let shown = if upper { buf[wall].bg } else { buf[wall].fg };
    assert_eq!((buf[wall].symbol(), shown), ("▄", Color::Red));
}

/// Issue 16: a scale bar and the colour code under the map, what the marks mean under the radar.
#[test]
fn the_map_has_a_scale_bar_and_a_colour_code_and_the_radar_a_key() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    let terminal = draw(&mut app, 120, 32, t0);
    insta::assert_snapshot!(terminal.backend());
    let buf = terminal.backend().buffer();
    // The map's bottom border (row 30, columns 0..43).
    let border: Vec<&str> = (0..43).map(|x| buf[(x, 30)].symbol()).collect();
    let from = border.iter().position(|&c| c == "├").unwrap();
    let to = border.iter().position(|&c| c == "┤").unwrap();
    let label: String = border[to + 2..].concat();
    let label = label
        .split("  ")
        .next()
        .unwrap_or("")
        .trim_end_matches('─')
        .trim();
    let (number, unit) = label.split_once(' ').unwrap();
    let metres = number.parse::<f64>().unwrap() * if unit == "cm" { 0.01 } else { 1.0 };
    // The bar's columns are that many metres, to half a column.
    let per_column = app.viewport().unwrap().scale * 0.05;
    let columns = (to - from + 1) as f64;
    assert!(
        (columns * per_column - metres).abs() <= per_column / 2.0 + 1e-9,
        "{columns} columns of {per_column} m for {label}"
    );
    let text = border.concat();
    assert!(text.contains(" free █████ occ "), "{text}");
    // The ramp's ends in the map's colours.
    let swatch = border.iter().position(|&c| c == "█").unwrap();
    assert_eq!(buf[(swatch as u16, 30)].fg, app.palette.color(Some(0)));
    assert_eq!(
        buf[(swatch as u16 + 4, 30)].fg,
        app.palette.color(Some(254))
    );
    let radar_border: String = (43..86).map(|x| buf[(x, 30)].symbol()).collect();
    for mark in ["echo", "silent", "sweep"] {
        assert!(radar_border.contains(mark), "{radar_border}");
    }
}

/// Issue 16: while a local scan runs, its segment stays on the radar (cyan), not only while it is
/// being chosen (yellow).
#[test]
fn a_running_local_scan_keeps_its_segment_on_the_radar() {
    let t0 = Instant::now();
    let segment = Segment {
        from_deg: -30.0,
        to_deg: 30.0,
    };
    let mut app = radar_with_local_segment(t0, segment);
    let inner = Rect::new(1, 1, 44, 21);
    // The driver still sweeps fully: no segment.
    let terminal = draw(&mut app, 80, 24, t0);
    assert!(radar_marks(terminal.backend().buffer(), inner, Color::Cyan).is_empty());

    let mut status = *app.driver.as_ref().unwrap();
    status.mode = ScanMode::Local as u32;
    status.stamp_ns += 1_000_000_000;
    app.on_driver_status(&status, t0).unwrap();
    let terminal = draw(&mut app, 80, 24, t0);
    insta::assert_snapshot!(terminal.backend());
    let buf = terminal.backend().buffer();
    let marks = radar_marks(buf, inner, Color::Cyan);
    assert!(marks.len() >= 10, "{marks:?}");
    for (x, y) in marks.into_iter().filter(|(x, y)| x.hypot(*y) > 0.8) {
        let a = y.atan2(x).to_degrees();
        assert!((-40.0..=40.0).contains(&a), "a mark at {a:.0}°");
    }
    // Labelled inside, named in the legend below.
    assert!(area_text(buf, inner).contains("local"));
    assert!(screen_text(buf).contains("⣿ local scan"));

    // While a new segment is being chosen, that one (yellow) is drawn instead.
    app.selection = Some(Segment {
        from_deg: 60.0,
        to_deg: 90.0,
    });
    let terminal = draw(&mut app, 80, 24, t0);
    assert!(radar_marks(terminal.backend().buffer(), inner, Color::Cyan).is_empty());
}

#[test]
fn local_scan_selection_is_drawn_on_the_radar() {
    let t0 = Instant::now();
    let segment = Segment {
        from_deg: -30.0,
        to_deg: 30.0,
    };
    let mut app = radar_with_local_segment(t0, segment);
    app.local_segment = None;
    app.selection = Some(segment);
    let terminal = draw(&mut app, 80, 24, t0);
    insta::assert_snapshot!(terminal.backend());
    let buf = terminal.backend().buffer();
    assert!(screen_text(buf).contains("local scan -30°..+30° ←/→ turn"));
    assert!(
        buf.content()
            .iter()
            .any(|c| c.fg == Color::Yellow && c.symbol() != " ")
    );
}

#[test]
fn key_help_overlay() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    app.show_help = true;
    let terminal = draw(&mut app, 100, 24, t0);
    insta::assert_snapshot!(terminal.backend());
}

#[test]
fn tiny_terminals_do_not_break_anything() {
    let t0 = Instant::now();
    for view in [View::Map, View::Radar, View::Split] {
        for (w, h) in [(1, 1), (3, 2), (8, 3), (20, 4), (71, 5)] {
            let mut app = live_app(t0);
            app.view = view;
            app.show_help = true;
            draw(&mut app, w, h, t0);
        }
    }
}

#[test]
fn half_blocks_encode_the_class_in_the_glyph() {
    let p = Palette::new(ColorMode::TrueColor);
    let c = |v| p.color(Some(v));
    assert_eq!(
        half_block(Some(WALL), Some(FREE), &p),
        ('▄', c(FREE), c(WALL))
    );
    assert_eq!(
        half_block(Some(FREE), Some(WALL), &p),
        ('▄', c(WALL), c(FREE))
    );
    assert_eq!(
        half_block(Some(FREE), Some(CELL_UNKNOWN), &p),
        ('▀', c(FREE), c(CELL_UNKNOWN))
    );
    assert_eq!(
        half_block(Some(CELL_UNKNOWN), Some(CELL_UNKNOWN), &p),
        (' ', c(CELL_UNKNOWN), c(CELL_UNKNOWN))
    );
    assert_eq!(
        half_block(None, Some(CELL_UNKNOWN), &p),
        (' ', c(CELL_UNKNOWN), c(CELL_UNKNOWN))
    );
    assert_eq!(
        half_block(None, None, &p),
        (' ', Color::Reset, Color::Reset)
    );
}

#[test]
fn ring_steps_and_lengths() {
    assert_eq!(ring_step(4.0), 1.0);
    assert_eq!(ring_step(1.0), 0.25);
    assert_eq!(ring_step(10.0), 2.0);
    assert_eq!(format_length(0.05), "5 cm");
    assert_eq!(format_length(0.025), "2.5 cm");
    assert_eq!(format_length(2.0), "2 m");
    assert_eq!(format_length(1.5), "1.5 m");
    assert_eq!(format_count(9999), "9999");
    assert_eq!(format_count(12_345), "12.3k");
    assert_eq!(format_count(4_194_304), "4.2M");
    assert_eq!(readings_count(1), "1 reading");
    assert_eq!(readings_count(0), "0 readings");
    assert_eq!(readings_count(12_345), "12.3k readings");
}

#[test]
fn the_sensor_arrow_points_along_the_heading_octant() {
    let deg = |d: f32| heading_glyph(d.to_radians());
    assert_eq!(deg(0.0), '→');
    assert_eq!(deg(22.0), '→');
    assert_eq!(deg(23.0), '↗');
    assert_eq!(deg(90.0), '↑');
    assert_eq!(deg(135.0), '↖');
    assert_eq!(deg(180.0), '←');
    assert_eq!(deg(-180.0), '←');
    assert_eq!(deg(-135.0), '↙');
    assert_eq!(deg(-90.0), '↓');
    assert_eq!(deg(-44.0), '↘');
    assert_eq!(deg(350.0), '→', "a heading past a full turn");
    assert_eq!(deg(-630.0), '↑');
    assert_eq!(heading_glyph(f32::NAN), '@');
    assert_eq!(heading_glyph(f32::INFINITY), '@');
    // Absurd but finite: still an arrow, no panic.
    assert!(HEADING_GLYPHS.contains(&heading_glyph(1e30)));
}

#[test]
fn the_radar_turns_with_the_heading() {
    let mut radar = Radar {
        layout_version: LAYOUT_VERSION,
        bin_count: 2,
        first_bin_deg: 0.0,
        bin_width_deg: 6.0,
        beam_half_angle_deg: 30.0,
        max_range_m: 4.0,
        ..Radar::default()
    };
    radar.distances_m[0] = 2.0;
    radar.distances_m[1] = f32::INFINITY;
    let (fixed, fixed_silent) = radar_points(&radar, 4.0, 0.05, false, Heading::new(0.0));
    let quarter = Heading::new(std::f64::consts::FRAC_PI_2);
    let (turned, turned_silent) = radar_points(&radar, 4.0, 0.05, false, quarter);
    assert!(!fixed.is_empty() && !fixed_silent.is_empty());
    assert_eq!(
        (fixed.len(), fixed_silent.len()),
        (turned.len(), turned_silent.len())
    );
    // Heading 90°: what a fixed head draws at (x, y) is drawn at (-y, x), the echo at 0° of the
    // sensor now north of it, as on the map.
    for (&(x, y), &(tx, ty)) in fixed
        .iter()
        .chain(&fixed_silent)
        .zip(turned.iter().chain(&turned_silent))
    {
        assert!(
            (tx + y).abs() < 1e-9 && (ty - x).abs() < 1e-9,
            "({x}, {y}) → ({tx}, {ty})"
        );
    }
    let (x, y) = turned[turned.len() / 2];
    assert!((y.atan2(x).to_degrees() - 90.0).abs() < 1.0, "({x}, {y})");
    // Heading 0 is no turn at all, so a fixed head's radar is exactly what it was.
    assert_eq!(Heading::new(0.0).turn((1.5, -0.25)), (1.5, -0.25));
}

/// Range from (`x`, `y`) to the walls of [`room_grid`]'s room along world angle `deg`.
fn room_range_from(x: f32, y: f32, deg: f32) -> f32 {
    let (s, c) = deg.to_radians().sin_cos();
    let tx = if c > 0.0 {
        (2.0 - x) / c
    } else {
        (-2.5 - x) / c
    };
    let ty = if s > 0.0 {
        (1.5 - y) / s
    } else {
        (-1.5 - y) / s
    };
    tx.abs().min(ty.abs())
}

/// The robot's path in [`room_grid`]: east from the origin to x = 0.525 m heading 0, then north to
/// y = 0.825 m heading 90°, a grid snapshot every 10 cm (cell centres, so the cells are exact).
fn drive_through_the_room(app: &mut App, t0: Instant) {
    let (header, cells) = room_grid();
    let east = (0..=5).map(|i| (0.025 + 0.1 * i as f32, 0.025, 0.0));
    let north = (1..=8).map(|j| (0.525, 0.025 + 0.1 * j as f32, std::f32::consts::FRAC_PI_2));
    for (i, (x, y, theta)) in east.chain(north).enumerate() {
        let header = GridHeader {
            seq: header.seq + i as u64,
            readings_fused: header.readings_fused + 10 * i as u64,
            pose_x_m: x,
            pose_y_m: y,
            pose_theta_rad: theta,
            ..header
        };
        app.on_grid(&header, &cells, t0).unwrap();
    }
    // The sweep seen from there, in the sensor's angles: 0° is north now.
    let mut radar = room_radar();
    for i in 0..50 {
        let deg = -147.0 + 6.0 * i as f32;
        if deg <= 45.0 {
            radar.distances_m[i] = room_range_from(0.525, 0.825, deg + 90.0);
        }
    }
    app.on_radar(&radar, t0).unwrap();
}

#[test]
fn a_moving_robot_is_drawn_with_its_heading_its_trail_and_its_fix() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    drive_through_the_room(&mut app, t0);
    app.map.cursor = Some((30, 30));
    let fix = LocalizedPose {
        layout_version: LAYOUT_VERSION,
        x_m: 0.525,
        y_m: 0.825,
        theta_rad: std::f32::consts::FRAC_PI_2,
        cov_xx: 0.0004,
        cov_yy: 0.0009,
        cov_thetatheta: 1f32.to_radians().powi(2),
        matched: 6,
        fixes: 4,
        odometry_x_m: 0.585,
        odometry_y_m: 0.745,
        odometry_theta_rad: std::f32::consts::FRAC_PI_2 - 2f32.to_radians(),
        ..LocalizedPose::default()
    };
    app.on_localized_pose(&fix, t0).unwrap();
    assert!(app.map.follow, "moved 0.94 m: followed (when zoomed in)");
    let terminal = draw(&mut app, 120, 32, t0);
    insta::assert_snapshot!(terminal.backend());

    let buf = terminal.backend().buffer();
    let map = Rect::new(1, 1, 41, 29);
    // The arrow on the robot's cell, north; the trail from the start to it, in its colour.
    let (robot, _) = cell_of(&app, map, 70, 56);
    assert_eq!(buf[robot].symbol(), "↑");
    let (start, _) = cell_of(&app, map, 60, 40);
    assert_eq!(
        (buf[start].symbol(), buf[start].fg),
        ("·", app.palette.trail())
    );
    let dots = area_text(buf, map).matches('·').count();
    assert!((4..=14).contains(&dots), "{dots} trail cells");
    assert!(!area_text(buf, map).contains('@'));

    let text = screen_text(buf);
    for expected in [
        "pose     +0.52, +0.82 m  +90°",
        "fix      6 matched",
        "σ x,y,θ  2.0, 3.0 cm, 1.0°",
        "drift    10 cm · +2.0°",
    ] {
        assert!(text.contains(expected), "missing {expected:?} in\n{text}");
    }

    // The radar in the world's frame: every echo lies on the room's walls as seen from the robot
    // (within a terminal cell, ≈ 0.21 m × 0.42 m here). Unturned, the northern echoes would lie
    // east of the robot, inside the room.
    let radar = Rect::new(44, 1, 41, 29);
    let echoes = radar_marks(buf, radar, Color::LightRed);
    assert!(echoes.len() >= 10, "{echoes:?}");
    for (x, y) in echoes {
        let (wx, wy) = (0.525 + x, 0.825 + y);
        let off_wall = [
            (wx - 2.0).abs(),
            (wx + 2.5).abs(),
            (wy - 1.5).abs(),
            (wy + 1.5).abs(),
        ]
        .into_iter()
        .fold(f64::INFINITY, f64::min);
        assert!(
            off_wall < 0.45,
            "echo at ({wx:.2}, {wy:.2}) m, {off_wall:.2} m off the walls"
        );
    }

    // Without a fix the panel says so, and still how far the odometry drifted.
    let no_fix = LocalizedPose {
        matched: 0,
        cov_xx: f32::NAN,
        cov_yy: f32::NAN,
        cov_thetatheta: f32::NAN,
        ..fix
    };
    app.on_localized_pose(&no_fix, t0).unwrap();
    let text = screen_text(draw(&mut app, 120, 32, t0).backend().buffer());
    assert!(text.contains("fix      no fix"), "{text}");
    assert!(!text.contains("σ x,y,θ"), "{text}");
    assert!(text.contains("drift    10 cm · +2.0°"), "{text}");
}

/// Issue 25: with `sonar-slam` running, the status panel says whether its latest sweep is a fix
/// (or why not), with the σ it publishes, fix or not: a robot far off its map says so in
/// centimetres, not "matched". A revision of an earlier sweep changes nothing shown.
#[test]
fn the_slam_s_state_and_sigma_are_shown_fix_or_not() {
    let t0 = Instant::now();
    let mut app = live_app(t0);
    drive_through_the_room(&mut app, t0);
    let fix = SlamCorrection {
        layout_version: LAYOUT_VERSION,
        sweep_id: 7,
        state: slam_state::FIX,
        matched: 3,
        cov_xx: 0.0004,
        cov_yy: 0.0009,
        cov_thetatheta: 1.5f32.to_radians().powi(2),
        landmarks: 12,
        fixes: 5,
        refused: 1,
        ..SlamCorrection::default()
    };
    app.on_slam_correction(&fix).unwrap();
    let text = screen_text(draw(&mut app, 120, 32, t0).backend().buffer());
    for expected in [
        "slam     fix · 3 matched",
        "σ x,y,θ  2.0, 3.0 cm, 1.5°",
        "map      12 landmarks, 1 refused",
    ] {
        assert!(text.contains(expected), "missing {expected:?} in\n{text}");
    }

    let uncertain = SlamCorrection {
        sweep_id: 8,
        state: slam_state::UNCERTAIN,
        matched: 1,
        cov_xx: 0.12f32.powi(2),
        cov_yy: 0.40f32.powi(2),
        cov_thetatheta: f32::NAN,
        ..fix
    };
    app.on_slam_correction(&uncertain).unwrap();
    let revised = SlamCorrection {
        sweep_id: 2,
        state: slam_state::REVISED,
        ..fix
    };
    app.on_slam_correction(&revised).unwrap();
    let text = screen_text(draw(&mut app, 120, 32, t0).backend().buffer());
    assert!(text.contains("slam     no fix: too uncertain"), "{text}");
    assert!(text.contains("σ x,y,θ  12.0, 40.0 cm, –°"), "{text}");
    assert!(!text.contains("matched"), "{text}");

    let old = SlamCorrection {
        layout_version: LAYOUT_VERSION + 1,
        ..fix
    };
    assert!(app.on_slam_correction(&old).is_err());
    assert_eq!(app.slam.map(|c| c.sweep_id), Some(8));
}

/// Issue 16, #10: at 80×24 the radar's ring labels do not run into each other and the titles fit;
/// narrower, the compact line stands in for the status panel; tiny, no label is cut into `90°°`.
#[test]
fn small_terminals_keep_labels_apart_and_say_when_the_panel_is_hidden() {
    let t0 = Instant::now();
    let labels_touch = |screen: &str| {
        let chars: Vec<char> = screen.chars().collect();
        // "… m" directly followed by a digit: two labels run together ("4 m3 m").
        chars
            .windows(3)
            .any(|w| w[0] == ' ' && w[1] == 'm' && w[2].is_ascii_digit())
    };
    for (w, h) in [(80, 24), (100, 30), (120, 40)] {
        for view in [View::Radar, View::Split] {
            let mut app = live_app(t0);
            app.view = view;
            let screen = screen_text(draw(&mut app, w, h, t0).backend().buffer());
            assert!(!labels_touch(&screen), "{w}×{h}:\n{screen}");
            assert!(screen.contains("radar ·"), "{w}×{h}:\n{screen}");
            assert!(screen.contains("┌ status"), "{w}×{h}:\n{screen}");
        }
    }
    let mut app = live_app(t0);
    let screen = screen_text(draw(&mut app, 60, 20, t0).backend().buffer());
    assert!(!screen.contains("┌ status"), "{screen}");
    assert!(
        screen.contains(" driver alive · fusion alive · full 65% · + "),
        "{screen}"
    );
    for (w, h) in [(20, 5), (24, 8), (30, 10)] {
        let mut app = live_app(t0);
        app.view = View::Radar;
        let screen = screen_text(draw(&mut app, w, h, t0).backend().buffer());
        assert!(
            !screen.contains("°°") && !labels_touch(&screen),
            "{w}×{h}:\n{screen}"
        );
    }
}
