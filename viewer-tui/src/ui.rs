//! Rendering: the [`App`] into a ratatui buffer. Nothing here changes the state; the only thing
//! kept between frames is the pooled map picture in [`MapCache`], which is recomputed only when a
//! new grid arrives or the view moves.
//!
//! Layout: the view(s) on the left, the status panel on the right, one status line at the bottom,
//! the key help on top when asked. A terminal narrower than [`PANEL_MIN_TERMINAL_WIDTH`] or lower
//! than [`PANEL_MIN_TERMINAL_HEIGHT`] gets the compact layout instead: the essentials of the panel
//! (liveness, errors, scan, cursor, rate) in one line above the status line.
//!
//! Text without colour (what `tmux capture-pane -p` returns) still tells the map apart: in the map,
//! `▄` marks a terminal cell holding an occupied pixel (a wall), `▀` observed space without walls,
//! a blank never-observed space or the outside of the grid, `+` the cursor and an arrow the sensor,
//! pointing along its heading (`@` if the heading is unknown); `·` the robot's trail. Over it, in
//! green, the features: walls as lines of `─ │ ╱ ╲`, corners `◆`, posts `●`.

use std::time::Instant;

use ratatui::Frame;
use ratatui::buffer::Buffer;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style};
use ratatui::symbols::Marker;
use ratatui::text::{Line, Span};
use ratatui::widgets::canvas::{Canvas, Circle, Context, Line as CanvasLine, Points};
use ratatui::widgets::{Block, Clear, Paragraph, Widget, Wrap};
use sonar_common::ipc::{
    CELL_UNKNOWN, LinkState, LocalizedPose, Radar, Reading, ScanMode, SlamCorrection,
    decode_probability, encode_probability, feature_kind, flags, slam_state,
};
use sonar_mapfiles::picture::scale_bar;

use crate::app::{
    App, Framing, GridSnapshot, KEYS, Liveness, MODELS, PRESETS, RULES, Segment, View,
    setting_name, sweep_progress,
};
use crate::heatmap::{
    FeatureMark, Palette, Pooled, Slope, Viewport, cell_rgb, feature_pixels, is_occupied,
    mono_glyph, tentative_then_confirmed,
};

/// Width of the status panel, borders included.
pub const PANEL_WIDTH: u16 = 34;
/// Narrower terminals show only the view(s) and the status line.
pub const PANEL_MIN_TERMINAL_WIDTH: u16 = 72;
/// Lower terminals show the compact line instead of the panel, which would be cut short.
pub const PANEL_MIN_TERMINAL_HEIGHT: u16 = 16;
/// The radar's inside below which its labels would run into each other (columns, rows).
const RADAR_LABELS_MIN: (u16, u16) = (16, 6);
/// Radar range when the snapshot does not give one (the SRF05's 4 m).
const DEFAULT_RADAR_RANGE_M: f64 = 4.0;

const LABEL: Style = Style::new().fg(Color::DarkGray);
/// The segment of a local scan that runs (the one being chosen is yellow).
const LOCAL_SCAN_COLOR: Color = Color::Cyan;
const WALL_GLYPH: char = '▄';
const OBSERVED_GLYPH: char = '▀';
const CURSOR_GLYPH: char = '+';
/// The sensor by its heading's octant, counter-clockwise from east (the map's x axis).
const HEADING_GLYPHS: [char; 8] = ['→', '↗', '↑', '↖', '←', '↙', '↓', '↘'];
/// The sensor when its heading is not a number.
const SENSOR_GLYPH: char = '@';
const TRAIL_GLYPH: char = '·';
/// Most confident features listed in the status panel, when there is room.
const LISTED_FEATURES: usize = 5;

/// The pooled map picture and what it was computed from.
#[derive(Debug, Default)]
pub struct MapCache {
    key: Option<(u64, Viewport)>,
    pooled: Pooled,
}

impl MapCache {
    /// Forgets the picture, so the next frame pools again (for the benchmark's cold frames).
    pub fn invalidate(&mut self) {
        self.key = None;
    }
}

/// What the frame learned about the layout, for key handling until the next frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DrawInfo {
    /// Pixels of the map picture (0 × 0 when the map is not shown).
    pub map_px: (u32, u32),
    /// The terminal cell (column, row) showing the map's top-left pixel, for the mouse.
    pub map_origin: (u16, u16),
}

pub fn draw(frame: &mut Frame, app: &App, cache: &mut MapCache, now: Instant) -> DrawInfo {
    let area = frame.area();
    render(area, frame.buffer_mut(), app, cache, now)
}

/// Renders the whole screen into `buf`.
pub fn render(
    area: Rect,
    buf: &mut Buffer,
    app: &App,
    cache: &mut MapCache,
    now: Instant,
) -> DrawInfo {
    let compact = area.width < PANEL_MIN_TERMINAL_WIDTH || area.height < PANEL_MIN_TERMINAL_HEIGHT;
    let [main, summary, bottom] = Layout::vertical([
        Constraint::Min(1),
        Constraint::Length(u16::from(compact && area.height >= 3)),
        Constraint::Length(1),
    ])
    .areas(area);
    let (views, panel) = if compact {
        (main, None)
    } else {
        let [views, panel] =
            Layout::horizontal([Constraint::Min(1), Constraint::Length(PANEL_WIDTH)]).areas(main);
        (views, Some(panel))
    };
    let mut info = DrawInfo::default();
    match app.view {
        View::Map => info = render_map(views, buf, app, cache, now),
        View::Radar => render_radar(views, buf, app, now),
        View::Split => {
            let [left, right] =
                Layout::horizontal([Constraint::Percentage(50), Constraint::Percentage(50)])
                    .areas(views);
            info = render_map(left, buf, app, cache, now);
            render_radar(right, buf, app, now);
        }
    }
    if let Some(panel) = panel {
        let block = Block::bordered().title(" status ");
        let inner = block.inner(panel);
        // Wrapped so that a long IPC problem is readable in full.
        Paragraph::new(status_lines(app, now, inner.width, inner.height))
            .wrap(Wrap { trim: false })
            .block(block)
            .render(panel, buf);
    }
    if summary.height > 0 {
        Paragraph::new(compact_line(app, now)).render(summary, buf);
    }
    Paragraph::new(bottom_line(app)).render(bottom, buf);
    if app.show_help {
        render_help(area, buf);
    }
    if app.palette.is_mono() {
        // NO_COLOR: not one colour anywhere, the labels' and warnings' included; every glyph
        // was chosen to carry its meaning without.
        for cell in &mut buf.content {
            cell.set_fg(Color::Reset).set_bg(Color::Reset);
        }
    }
    info
}

/// A centred note inside an empty view.
fn render_note(area: Rect, buf: &mut Buffer, text: String, style: Style) {
    let y = area.y + area.height / 2;
    if area.height > 0 {
        Paragraph::new(Line::styled(text, style).centered())
            .render(Rect::new(area.x, y, area.width, 1), buf);
    }
}

/// What to say in a view that has nothing to show yet.
fn waiting_note(app: &App, now: Instant, what: &str) -> (String, Style) {
    match app.fusion_peer.liveness(now) {
        Liveness::Waiting => (
            "waiting for fusion…".to_owned(),
            Style::new().fg(Color::Yellow),
        ),
        Liveness::Alive => (
            format!("fusion is up, waiting for its first {what}…"),
            Style::new().fg(Color::Yellow),
        ),
        Liveness::Gone(_) => (
            format!("fusion gone before its first {what}"),
            Style::new().fg(Color::Red),
        ),
    }
}

/// The probability map; returns where the picture is and its size in pixels.
fn render_map(
    area: Rect,
    buf: &mut Buffer,
    app: &App,
    cache: &mut MapCache,
    now: Instant,
) -> DrawInfo {
    let title = match &app.grid {
        Some(g) => {
            let zoom = zoom_label(app, g, area);
            // Also over the whole map, where following only shows once zoomed in: `t` toggles
            // a state the user should be able to see.
            let follow = if app.map.follow { " · following" } else { "" };
            let cells = format!("{}×{}", g.width(), g.height());
            let resolution = format_length(g.header.resolution_m);
            fitting_title(
                &[
                    format!(" map {cells} · {resolution}{zoom}{follow} "),
                    format!(" map {resolution}{zoom}{follow} "),
                    format!(" map{zoom}{follow} "),
                ],
                area.width,
            )
        }
        None => " map ".to_owned(),
    };
    let mut block = Block::bordered().title(title);
    let inner = block.inner(area);
    let (w, h) = (u32::from(inner.width), 2 * u32::from(inner.height));
    let info = DrawInfo {
        map_px: (w, h),
        map_origin: (inner.x, inner.y),
    };
    let shown = app.grid.as_ref().map(|g| (g, app.map.viewport(g, w, h)));
    if let Some((grid, vp)) = &shown {
        let (bar, legend) = map_legend(&app.palette, grid.header.resolution_m, vp, inner.width);
        block = block.title_bottom(bar).title_bottom(legend.right_aligned());
    }
    block.render(area, buf);
    let Some((grid, vp)) = shown else {
        let (text, style) = waiting_note(app, now, "map");
        render_note(inner, buf, text, style);
        return info;
    };
    if w == 0 || h == 0 {
        return info;
    }
    let key = (app.grid_generation, vp);
    if cache.key != Some(key) {
        cache.pooled.pool(
            &grid.cells,
            grid.width() as usize,
            grid.height() as usize,
            &vp,
        );
        cache.key = Some(key);
    }
    paint_pixels(inner, buf, &cache.pooled, &app.palette);
    paint_trail(inner, buf, app, grid, &vp, &cache.pooled);
    if let Some(features) = app.features.as_ref().filter(|_| app.show_features) {
        for (confirmed, records) in tentative_then_confirmed(&features.records) {
            paint_features(
                inner,
                buf,
                &feature_pixels(&records, &grid.header, &vp),
                &cache.pooled,
                &app.palette,
                feature_style(&app.palette, confirmed),
            );
        }
    }

    let mut mark = |cell: Option<(u32, u32)>, glyph: char| {
        let Some((px, py)) = cell.and_then(|(x, y)| vp.pixel_of(x, y, grid.height())) else {
            return;
        };
        let pixel = cache.pooled.get(px, py);
        // Black on light colours, white on dark ones.
        let [r, g, b] = pixel.map_or([0; 3], cell_rgb);
        let fg = if 299 * u32::from(r) + 587 * u32::from(g) + 114 * u32::from(b) > 128_000 {
            Color::Black
        } else {
            Color::White
        };
        let pos = (inner.x + px as u16, inner.y + (py / 2) as u16);
        if let Some(cell) = buf.cell_mut(pos) {
            cell.set_char(glyph)
                .set_fg(fg)
                .set_bg(app.palette.color(pixel))
                .set_style(Modifier::BOLD);
        }
    };
    mark(
        grid.sensor_cell(),
        heading_glyph(grid.header.pose_theta_rad),
    );
    mark(app.map.cursor, CURSOR_GLYPH);
    info
}

/// Probabilities the legend's colour ramp shows, free to occupied.
const LEGEND_RAMP: [f32; 5] = [0.0, 0.3, 0.5, 0.7, 1.0];

/// The map's bottom border: on the left a scale bar (`├───┤ 1 m`: a round length of at most a
/// third of the picture's width, chosen as the saved PNG's), on the right the colour code from
/// free to occupied and the colour of never-observed cells (without colours, the shade glyphs).
/// Each only where the border has room for it.
fn map_legend(
    palette: &Palette,
    resolution_m: f32,
    vp: &Viewport,
    width: u16,
) -> (Line<'static>, Line<'static>) {
    let width = usize::from(width);
    let metres_per_column = vp.scale * f64::from(resolution_m);
    let bar = scale_bar(metres_per_column as f32, u32::try_from(width).unwrap_or(0));
    let columns = usize::try_from(bar.pixels).unwrap_or(usize::MAX);
    let bar_line = if columns >= 2 && columns + bar.label.chars().count() + 2 <= width {
        Line::from(vec![
            Span::styled(
                format!("├{}┤", "─".repeat(columns - 2)),
                Style::new().add_modifier(Modifier::BOLD),
            ),
            text(format!(" {} ", bar.label)),
        ])
    } else {
        Line::default()
    };
    let swatch = |cell: u8| {
        if palette.is_mono() {
            text(mono_glyph(Some(cell), None).to_string())
        } else {
            Span::styled("█", Style::new().fg(palette.color(Some(cell))))
        }
    };
    let ramp = |occupied: &str| {
        let mut spans = vec![text(" free ")];
        spans.extend(LEGEND_RAMP.iter().map(|&p| swatch(encode_probability(p))));
        spans.push(text(format!(" {occupied} ")));
        spans
    };
    let mut full = ramp("occupied");
    if !palette.is_mono() {
        full.extend([swatch(CELL_UNKNOWN), text(" unseen ")]);
    }
    // Between the corners, with a column of border left between the two parts.
    let room = width.saturating_sub(bar_line.width() + 1);
    let legend = [full, ramp("occupied"), ramp("occ")]
        .into_iter()
        .map(Line::from)
        .find(|l| l.width() <= room)
        .unwrap_or_default();
    (bar_line, legend)
}

/// The radar's bottom border: what its marks mean, as far as the border's width allows. Without
/// colours, echoes are told from rings by the rings being dotted.
fn radar_legend(app: &App, local_scan: bool, width: u16) -> Line<'static> {
    let mark = |glyph: &str, color: Color, what: &str| {
        vec![
            Span::styled(glyph.to_owned(), Style::new().fg(color)),
            text(format!(" {what} ")),
        ]
    };
    let mut parts = if app.palette.is_mono() {
        vec![vec![text(" ⣿ echo ")], vec![text("⠁⠈ ring ")]]
    } else {
        vec![
            vec![text(" ")],
            mark("⣿", Color::LightRed, "echo"),
            mark("⣿", Color::DarkGray, "silent"),
            mark("─", Color::Green, "sweep"),
        ]
    };
    if local_scan {
        parts.push(mark("⣿", LOCAL_SCAN_COLOR, "local scan"));
    }
    let line = Line::from(parts.concat());
    if line.width() <= usize::from(width) {
        line
    } else {
        Line::default()
    }
}

/// How the map is framed, for its title: " · seen" (what was seen, the default), nothing for the
/// whole grid, else the zoom relative to the whole grid (" · zoom ×4", " · zoom ×2.5").
fn zoom_label(app: &App, grid: &GridSnapshot, area: Rect) -> String {
    let (w, h) = (
        u32::from(area.width.saturating_sub(2)),
        2 * u32::from(area.height.saturating_sub(2)),
    );
    match (app.map.scale, app.map.framing) {
        (None, Framing::Seen) => " · seen".to_owned(),
        (None, Framing::Whole) => String::new(),
        (Some(scale), _) => {
            let factor = Viewport::fit_scale(grid.width(), grid.height(), w, h) / scale;
            if (factor - factor.round()).abs() < 0.05 || factor >= 10.0 {
                format!(" · zoom ×{factor:.0}")
            } else {
                format!(" · zoom ×{factor:.1}")
            }
        }
    }
}

/// The arrow pointing nearest to `theta_rad` (counter-clockwise from the map's x axis); `@` when
/// the heading is not a number.
fn heading_glyph(theta_rad: f32) -> char {
    if !theta_rad.is_finite() {
        return SENSOR_GLYPH;
    }
    let octant = (f64::from(theta_rad).to_degrees() / 45.0)
        .round()
        .rem_euclid(8.0);
    HEADING_GLYPHS
        .get(octant as usize)
        .copied()
        .unwrap_or(SENSOR_GLYPH)
}

/// The robot's trail, a faint dot on the terminal cell of each position, drawn before the features
/// and markers so they stay on top. A cell showing a wall keeps its `▄`: the path must never hide
/// an occupied cell.
fn paint_trail(
    area: Rect,
    buf: &mut Buffer,
    app: &App,
    grid: &GridSnapshot,
    vp: &Viewport,
    pooled: &Pooled,
) {
    let style = Style::new().fg(app.palette.trail());
    let wall = WALL_GLYPH.to_string();
    for (x, y) in app.trail.points() {
        let Some((px, py)) = grid
            .cell_at_m(x, y)
            .and_then(|(cx, cy)| vp.pixel_of(cx, cy, grid.height()))
        else {
            continue;
        };
        let (Ok(col), Ok(row)) = (u16::try_from(px), u16::try_from(py / 2)) else {
            continue;
        };
        if let Some(cell) = buf.cell_mut((area.x + col, area.y + row))
            && cell.symbol() != wall
        {
            cell.set_char(TRAIL_GLYPH)
                .set_style(style.bg(app.palette.color(pooled.get(px, py))));
        }
    }
}

/// How a feature's glyph is drawn: confirmed ones (heard from two places or more) bold in the
/// overlay colour, tentative ones dim in their own (without colours, bold against dim tells them
/// apart).
fn feature_style(palette: &Palette, confirmed: bool) -> Style {
    if confirmed {
        Style::new()
            .fg(palette.feature())
            .add_modifier(Modifier::BOLD)
    } else {
        Style::new()
            .fg(palette.tentative_feature())
            .add_modifier(Modifier::DIM)
    }
}

/// The features over the heatmap: each marked pixel's terminal cell gets the feature's glyph in
/// `style`, on the colour of that pixel, so the map under it still shows.
fn paint_features(
    area: Rect,
    buf: &mut Buffer,
    marks: &[(u32, u32, FeatureMark)],
    pooled: &Pooled,
    palette: &Palette,
    style: Style,
) {
    for &(px, py, mark) in marks {
        let (Ok(col), Ok(row)) = (u16::try_from(px), u16::try_from(py / 2)) else {
            continue;
        };
        if col >= area.width || row >= area.height {
            continue;
        }
        if let Some(cell) = buf.cell_mut((area.x + col, area.y + row)) {
            cell.set_char(feature_glyph(mark))
                .set_style(style.bg(palette.color(pooled.get(px, py))));
        }
    }
}

fn feature_glyph(mark: FeatureMark) -> char {
    match mark {
        FeatureMark::Wall(Slope::Flat) => '─',
        FeatureMark::Wall(Slope::Steep) => '│',
        FeatureMark::Wall(Slope::Rising) => '╱',
        FeatureMark::Wall(Slope::Falling) => '╲',
        FeatureMark::Corner => '◆',
        FeatureMark::Post => '●',
    }
}

/// Two pixels per terminal cell, upper and lower, drawn with half blocks; without colours, one
/// shade glyph for both ([`mono_glyph`]).
fn paint_pixels(area: Rect, buf: &mut Buffer, pooled: &Pooled, palette: &Palette) {
    for row in 0..area.height {
        for col in 0..area.width {
            let upper = pooled.get(u32::from(col), 2 * u32::from(row));
            let lower = pooled.get(u32::from(col), 2 * u32::from(row) + 1);
            let (glyph, fg, bg) = if palette.is_mono() {
                (mono_glyph(upper, lower), Color::Reset, Color::Reset)
            } else {
                half_block(upper, lower, palette)
            };
            if let Some(cell) = buf.cell_mut((area.x + col, area.y + row)) {
                cell.set_char(glyph).set_fg(fg).set_bg(bg);
            }
        }
    }
}

/// Glyph, foreground and background of a cell showing pixel `upper` over pixel `lower`.
///
/// One colour per pixel either way; the glyph is chosen so that the text alone carries the class:
/// `▄` (foreground = lower, background = upper) when a pixel is occupied, `▀` (foreground = upper)
/// when a pixel is observed, else a blank. A never-observed pixel over one outside the grid (only
/// along the grid's edge) is drawn as a blank in the never-observed colour.
fn half_block(upper: Option<u8>, lower: Option<u8>, palette: &Palette) -> (char, Color, Color) {
    let (cu, cl) = (palette.color(upper), palette.color(lower));
    let occupied = |p: Option<u8>| p.is_some_and(is_occupied);
    let observed = |p: Option<u8>| p.is_some_and(|v| v != CELL_UNKNOWN);
    if occupied(upper) || occupied(lower) {
        (WALL_GLYPH, cl, cu)
    } else if observed(upper) || observed(lower) {
        (OBSERVED_GLYPH, cu, cl)
    } else {
        let bg = if upper.is_some() { cu } else { cl };
        (' ', bg, bg)
    }
}

/// The basic method's display: arcs at the latest range per angle, range rings, the sweep line and
/// the local-scan segment being chosen. Drawn in the world's frame like the map (x to the right, y
/// up): the sensor's 0° points along the robot's heading, counter-clockwise positive; for a fixed
/// head (heading 0) that is to the right.
fn render_radar(area: Rect, buf: &mut Buffer, app: &App, now: Instant) {
    let title = match &app.radar {
        Some(r) => {
            let range = format_length(radar_range(r) as f32);
            let sweep = format!("sweep {} {}", r.sweep_id, direction_name(r.direction));
            fitting_title(
                &[
                    format!(" radar · {range} · {sweep} "),
                    format!(" radar · {range} "),
                ],
                area.width,
            )
        }
        None => " radar ".to_owned(),
    };
    // While a local scan runs, its segment stays on the radar (the one being chosen replaces it).
    let running = app
        .local_segment
        .filter(|_| app.selection.is_none() && app.scan_mode() == ScanMode::Local);
    let block = Block::bordered().title(title);
    let inner = block.inner(area);
    let block =
        block.title_bottom(radar_legend(app, running.is_some(), inner.width).right_aligned());
    block.render(area, buf);
    let Some(radar) = &app.radar else {
        let (text, style) = waiting_note(app, now, "radar");
        render_note(inner, buf, text, style);
        return;
    };
    if inner.width == 0 || inner.height == 0 {
        return;
    }
    let range = radar_range(radar);
    // Terminal cells are about twice as tall as wide: scale the bounds so circles stay round.
    let (w, h) = (f64::from(inner.width), 2.0 * f64::from(inner.height));
    let half = 1.08 * range;
    let (hx, hy) = if w >= h {
        (half * w / h, half)
    } else {
        (half, half * h / w)
    };
    // Canvas resolution (braille: 2 × 4 dots per cell), to space the points of the arcs.
    let dot = (2.0 * hx / (2.0 * w)).min(2.0 * hy / (4.0 * f64::from(inner.height)));
    let label_cell = 2.0 * hx / w;
    let labels = inner.width >= RADAR_LABELS_MIN.0 && inner.height >= RADAR_LABELS_MIN.1;
    let selection = app.selection;
    let beam_arcs = app.beam_arcs;
    let heading = Heading::of(app);
    // Without colours rings and echoes would look alike: the rings are drawn dotted.
    let dotted_rings = app.palette.is_mono().then_some(6.0 * dot);
    Canvas::default()
        .marker(Marker::Braille)
        .x_bounds([-hx, hx])
        .y_bounds([-hy, hy])
        .paint(|ctx| {
            paint_rings(ctx, range, label_cell, labels, heading, dotted_rings);
            ctx.layer();
            let (echoes, silent) = radar_points(radar, range, dot, beam_arcs, heading);
            ctx.draw(&Points {
                coords: &silent,
                color: Color::DarkGray,
            });
            ctx.draw(&Points {
                coords: &echoes,
                color: Color::LightRed,
            });
            ctx.layer();
            if radar.current_angle_deg.is_finite() {
                let (x, y) = heading.turn(polar(range, f64::from(radar.current_angle_deg)));
                ctx.draw(&CanvasLine::new(0.0, 0.0, x, y, Color::Green));
            }
            if let Some(s) = selection {
                paint_segment(ctx, s, range, dot, heading, Color::Yellow, "scan");
            } else if let Some(s) = running {
                paint_segment(ctx, s, range, dot, heading, LOCAL_SCAN_COLOR, "local");
            }
        })
        .render(inner, buf);
}

fn radar_range(radar: &Radar) -> f64 {
    let r = f64::from(radar.max_range_m);
    if r.is_finite() && r > 0.0 {
        r
    } else {
        DEFAULT_RADAR_RANGE_M
    }
}

fn polar(r: f64, deg: f64) -> (f64, f64) {
    let a = deg.to_radians();
    (r * a.cos(), r * a.sin())
}

/// The rotation from the sensor's frame (the radar's angles) into the world's (the map's).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Heading {
    sin: f64,
    cos: f64,
}

impl Heading {
    fn new(theta_rad: f64) -> Self {
        let (sin, cos) = theta_rad.sin_cos();
        Self { sin, cos }
    }

    /// The heading of the pose the fusion used last; 0 (no turn) without one.
    fn of(app: &App) -> Self {
        let theta = app
            .grid
            .as_ref()
            .and_then(GridSnapshot::pose)
            .map_or(0.0, |p| f64::from(p.theta_rad));
        Self::new(theta)
    }

    /// The sensor-frame point `p` in the world's frame. Exact for heading 0 (sin 0, cos 1), so a
    /// fixed head's radar is drawn exactly as before.
    fn turn(self, (x, y): (f64, f64)) -> (f64, f64) {
        (self.cos * x - self.sin * y, self.sin * x + self.cos * y)
    }
}

/// Canvas coordinates of points to draw.
type Dots = Vec<(f64, f64)>;

/// Points `dot` apart along the arc of radius `r` from `from_deg` to `to_deg` (sensor angles),
/// turned into the world by `heading`.
fn arc(r: f64, from_deg: f64, to_deg: f64, dot: f64, heading: Heading, out: &mut Dots) {
    let span = (to_deg - from_deg).to_radians().abs();
    let n = ((r * span / dot.max(1e-9)).ceil() as usize).clamp(1, 10_000);
    out.extend((0..=n).map(|i| {
        heading.turn(polar(
            r,
            from_deg + (to_deg - from_deg) * i as f64 / n as f64,
        ))
    }));
}

/// The first of `titles` (longest first) that fits a block `width` wide, else the last.
fn fitting_title(titles: &[String], width: u16) -> String {
    titles
        .iter()
        .find(|t| t.chars().count() + 2 <= usize::from(width))
        .or(titles.last())
        .cloned()
        .unwrap_or_default()
}

/// Rings at round distances, labelled in metres along the blind side behind the sensor (180°);
/// the sensor's 0° and 90° marked where they point. No labels in a canvas too small to hold them
/// apart. With `dotted`, the rings are dots that far apart instead of lines.
fn paint_rings(
    ctx: &mut Context,
    range: f64,
    label_cell: f64,
    labels: bool,
    heading: Heading,
    dotted: Option<f64>,
) {
    let step = ring_step(range);
    let rings = (range / step + 1e-6).floor() as usize;
    // Label every k-th ring counted from the outermost, which is always labelled, so the labels
    // (up to 6 cells) never overlap.
    let every = ((6.0 * label_cell / step).ceil() as usize).max(1);
    for k in 1..=rings {
        let r = k as f64 * step;
        match dotted {
            Some(spacing) => {
                let mut dots = Vec::new();
                arc(r, -180.0, 180.0, spacing, heading, &mut dots);
                ctx.draw(&Points {
                    coords: &dots,
                    color: Color::DarkGray,
                });
            }
            None => ctx.draw(&Circle {
                x: 0.0,
                y: 0.0,
                radius: r,
                color: Color::DarkGray,
            }),
        }
        if labels && (rings - k).is_multiple_of(every) {
            let (x, y) = heading.turn((-r, 0.0));
            ctx.print(x, y, Span::styled(format_length(r as f32), LABEL));
        }
    }
    if !labels {
        return;
    }
    let (x, y) = heading.turn((range, 0.0));
    ctx.print(x, y, Span::styled("0°", LABEL));
    let (x, y) = heading.turn((0.0, range));
    ctx.print(x, y, Span::styled("90°", LABEL));
}

/// The largest round step that still gives at least three rings.
fn ring_step(range: f64) -> f64 {
    const STEPS: [f64; 10] = [50.0, 20.0, 10.0, 5.0, 2.0, 1.0, 0.5, 0.25, 0.1, 0.05];
    STEPS
        .into_iter()
        .find(|&s| range / s >= 3.0)
        .unwrap_or(STEPS[STEPS.len() - 1])
}

/// Arcs of the radar array: echoes at their range; bins whose latest reading heard nothing as a
/// faint arc at the edge, so covered-but-empty sectors differ from never-scanned ones. In the
/// world's frame, turned by `heading`.
fn radar_points(
    radar: &Radar,
    range: f64,
    dot: f64,
    beam_arcs: bool,
    heading: Heading,
) -> (Dots, Dots) {
    let (mut echoes, mut silent) = (Vec::new(), Vec::new());
    let bins = (radar.bin_count as usize).min(radar.distances_m.len());
    let width = f64::from(radar.bin_width_deg);
    let half = if beam_arcs {
        f64::from(radar.beam_half_angle_deg).max(width / 2.0)
    } else {
        width / 2.0
    };
    for (i, &d) in radar.distances_m[..bins].iter().enumerate() {
        let center = f64::from(radar.first_bin_deg) + i as f64 * width;
        let d = f64::from(d);
        if d.is_finite() && d > 0.0 && d <= range {
            arc(d, center - half, center + half, dot, heading, &mut echoes);
        } else if d == f64::INFINITY {
            arc(
                range,
                center - width / 2.0,
                center + width / 2.0,
                dot,
                heading,
                &mut silent,
            );
        }
    }
    (echoes, silent)
}

/// A local-scan segment: its edges, its arc at the edge of the range and `label` inside it; in
/// yellow while it is being chosen, in [`LOCAL_SCAN_COLOR`] while the scan runs.
fn paint_segment(
    ctx: &mut Context,
    s: Segment,
    range: f64,
    dot: f64,
    heading: Heading,
    color: Color,
    label: &'static str,
) {
    let (from, to) = (f64::from(s.from_deg), f64::from(s.to_deg));
    for edge in [from, to] {
        let (x, y) = heading.turn(polar(range, edge));
        ctx.draw(&CanvasLine::new(0.0, 0.0, x, y, color));
    }
    let mut points = Vec::new();
    arc(range, from, to, dot, heading, &mut points);
    ctx.draw(&Points {
        coords: &points,
        color,
    });
    let (x, y) = heading.turn(polar(range * 0.5, (from + to) / 2.0));
    ctx.print(
        x,
        y,
        Span::styled(label, Style::new().fg(color).add_modifier(Modifier::BOLD)),
    );
}

/// Whoever publishes the readings: the driver's liveness, or a replay's (whose readings stop
/// because the recording ended: not a fault).
fn source_span(app: &App, now: Instant) -> Span<'static> {
    match (app.replay, app.driver_peer.liveness(now)) {
        (true, Liveness::Alive) => Span::styled("replay running", Style::new().fg(Color::Green)),
        (true, Liveness::Gone(_)) => Span::styled("replay finished", Style::new().fg(Color::Cyan)),
        (_, liveness) => liveness_span(liveness, "driver"),
    }
}

/// While the driver or the fusion has never been seen: where the viewer looks, and what to check.
fn where_to_look(app: &App, now: Instant) -> Option<Line<'static>> {
    let namespace = app.namespace.as_ref()?;
    let waiting = [app.driver_peer, app.fusion_peer]
        .iter()
        .any(|p| p.liveness(now) == Liveness::Waiting);
    waiting.then(|| {
        row(
            "looking",
            vec![Span::styled(
                format!(
                    "on {namespace}: is a pipeline running there, with the same \
                     --iox-prefix/--iox-root? (`sonar services` lists it)"
                ),
                Style::new().fg(Color::Yellow),
            )],
        )
    })
}

/// The fusion engine's health counters (`sonar/fusion_status`), the ones to look at when the map
/// seems to miss something: readings lost or rejected, maps not published, saves.
fn fusion_health(app: &App) -> Vec<Line<'static>> {
    let Some(s) = &app.fusion_status else {
        return Vec::new();
    };
    let count = |n: u64, what: &str, bad: Color| {
        let style = if n > 0 {
            Style::new().fg(bad)
        } else {
            Style::new()
        };
        Span::styled(format!("{} {what}", format_count(n)), style)
    };
    let mut lines = vec![row(
        "health",
        vec![
            count(s.readings_lost, "lost", Color::Yellow),
            text(" · "),
            count(s.readings_rejected, "rejected", Color::Yellow),
        ],
    )];
    let mut more = Vec::new();
    if s.readings_out_of_order > 0 {
        more.push(count(
            s.readings_out_of_order,
            "seq restarts",
            Color::Yellow,
        ));
    }
    if s.snapshots_skipped > 0 {
        if !more.is_empty() {
            more.push(text(" · "));
        }
        more.push(count(s.snapshots_skipped, "maps skipped", Color::Yellow));
    }
    if !more.is_empty() {
        lines.push(row("", more));
    }
    let mut saves = Vec::new();
    if s.saves > 0 {
        saves.push(text(format!("{} saved", format_count(s.saves))));
    }
    if s.save_failures > 0 {
        if !saves.is_empty() {
            saves.push(text(" · "));
        }
        saves.push(Span::styled(
            format!("{} failed", s.save_failures),
            Style::new().fg(Color::Red).add_modifier(Modifier::BOLD),
        ));
    }
    if !saves.is_empty() {
        lines.push(row("saves", saves));
    }
    if s.restored != 0 {
        lines.push(row("", vec![text("map restored at start")]));
    }
    lines
}

fn liveness_span(liveness: Liveness, name: &str) -> Span<'static> {
    match liveness {
        Liveness::Waiting => Span::styled(
            format!("waiting for {name}…"),
            Style::new().fg(Color::Yellow),
        ),
        Liveness::Alive => Span::styled("alive", Style::new().fg(Color::Green)),
        Liveness::Gone(d) => Span::styled(
            format!("gone for {} s", d.as_secs()),
            Style::new().fg(Color::Red).add_modifier(Modifier::BOLD),
        ),
    }
}

fn row(label: &str, value: Vec<Span<'static>>) -> Line<'static> {
    let mut spans = vec![Span::styled(format!("{label:<9}"), LABEL)];
    spans.extend(value);
    Line::from(spans)
}

fn text(s: impl Into<String>) -> Span<'static> {
    Span::raw(s.into())
}

fn direction_name(direction: i32) -> &'static str {
    match direction.signum() {
        1 => "ccw",
        -1 => "cw",
        _ => "",
    }
}

fn mode_name(mode: ScanMode) -> &'static str {
    match mode {
        ScanMode::Full => "full",
        ScanMode::Local => "local",
        ScanMode::Idle => "stopped",
        ScanMode::Unknown => "unknown",
    }
}

/// Metres as "2.5 cm", "40 cm", "1.5 m".
fn format_length(m: f32) -> String {
    let trim = |v: String| -> String {
        if v.contains('.') {
            v.trim_end_matches('0').trim_end_matches('.').to_owned()
        } else {
            v
        }
    };
    if m < 1.0 {
        format!("{} cm", trim(format!("{:.1}", m * 100.0)))
    } else {
        format!("{} m", trim(format!("{m:.2}")))
    }
}

/// Counts as "9999", "12.3k", "4.2M", so that a large grid's still fit the panel.
fn format_count(n: u64) -> String {
    match n {
        0..10_000 => n.to_string(),
        10_000..1_000_000 => format!("{:.1}k", n as f64 / 1e3),
        _ => format!("{:.1}M", n as f64 / 1e6),
    }
}

/// "1 reading", "2 readings", "12.5k readings".
fn readings_count(n: u64) -> String {
    match n {
        1 => "1 reading".to_owned(),
        _ => format!("{} readings", format_count(n)),
    }
}

fn format_reading(r: &Reading) -> String {
    let range = if r.is_valid_range() {
        format!("{:.3} m", r.distance_m)
    } else if r.has(flags::OUT_OF_RANGE) {
        "out of range".to_owned()
    } else {
        "no echo".to_owned()
    };
    format!("{:+6.1}°  {range}", r.angle_deg)
}

fn progress_bar(fraction: f32, cells: usize) -> String {
    let full = ((fraction.clamp(0.0, 1.0) * cells as f32).round() as usize).min(cells);
    format!("{}{}", "█".repeat(full), "░".repeat(cells - full))
}

/// "1 wall", "2 walls".
fn count_of(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// Terminal rows `line` takes in a panel `width` columns wide, wrapped.
fn rows_of(line: &Line, width: u16) -> usize {
    line.width().div_ceil(usize::from(width.max(1))).max(1)
}

/// Counts per kind and sweeps merged.
fn feature_summary(app: &App) -> Vec<Line<'static>> {
    let Some(f) = &app.features else {
        return vec![row("features", vec![text("–")])];
    };
    let of_kind = |kind: u32| f.records.iter().filter(|r| r.kind == kind).count();
    let tentative = f.records.iter().filter(|r| !r.is_confirmed()).count();
    let mut merged = vec![text(count_of(
        usize::try_from(f.header.sweeps).unwrap_or(usize::MAX),
        "sweep",
        "sweeps",
    ))];
    if f.header.features_left_out > 0 {
        merged.push(Span::styled(
            format!(" · {} not sent", f.header.features_left_out),
            Style::new().fg(Color::Yellow),
        ));
    }
    if !app.show_features {
        merged.push(Span::styled(" · hidden (o)", LABEL));
    }
    vec![
        row(
            "features",
            vec![text(format!(
                "{} · {}",
                count_of(of_kind(feature_kind::PLANE), "wall", "walls"),
                count_of(of_kind(feature_kind::CORNER), "corner", "corners"),
            ))],
        ),
        row("", {
            let mut posts = vec![text(count_of(
                of_kind(feature_kind::POINT),
                "post",
                "posts",
            ))];
            if tentative > 0 {
                posts.push(Span::styled(
                    format!(" · {tentative} tentative"),
                    feature_style(&app.palette, false),
                ));
            }
            posts
        }),
        row("merged", merged),
    ]
}

/// Up to `n` features, most confident first: kind, position and confidence, with the glyph the
/// map uses for it (so the list doubles as the overlay's legend).
fn confident_features(app: &App, n: usize) -> Vec<Line<'static>> {
    let Some(f) = &app.features else {
        return Vec::new();
    };
    let mut known: Vec<_> = f
        .records
        .iter()
        .filter(|r| {
            [
                feature_kind::PLANE,
                feature_kind::CORNER,
                feature_kind::POINT,
            ]
            .contains(&r.kind)
        })
        .collect();
    // A NaN confidence (fusion publishes none, but shared memory is not trusted) sorts last.
    known.sort_by(|a, b| {
        let key = |c: f32| if c.is_nan() { f32::NEG_INFINITY } else { c };
        key(b.confidence).total_cmp(&key(a.confidence))
    });
    known
        .into_iter()
        .take(n)
        .map(|r| {
            let segment = [
                r.segment_ax_m,
                r.segment_ay_m,
                r.segment_bx_m,
                r.segment_by_m,
            ];
            let wall = FeatureMark::Wall(Slope::Flat);
            let (name, mark, (x, y)) = match r.kind {
                // A wall's (x, y) is the foot of the perpendicular from the origin, which may lie
                // off the part that was seen: its segment's middle is where to look on the map.
                feature_kind::PLANE if segment.iter().all(|v| v.is_finite()) => (
                    "wall",
                    wall,
                    (
                        (r.segment_ax_m + r.segment_bx_m) / 2.0,
                        (r.segment_ay_m + r.segment_by_m) / 2.0,
                    ),
                ),
                feature_kind::PLANE => ("wall", wall, (r.x_m, r.y_m)),
                feature_kind::CORNER => ("corner", FeatureMark::Corner, (r.x_m, r.y_m)),
                _ => ("post", FeatureMark::Post, (r.x_m, r.y_m)),
            };
            row(
                name,
                vec![
                    Span::styled(
                        feature_glyph(mark).to_string(),
                        feature_style(&app.palette, r.is_confirmed()),
                    ),
                    text(format!(
                        " {x:+.2}, {y:+.2} m {:>3.0}%",
                        r.confidence * 100.0
                    )),
                ],
            )
        })
        .collect()
}

/// The status panel, for an inner area of `width` × `height` cells.
fn status_lines(app: &App, now: Instant, width: u16, height: u16) -> Vec<Line<'static>> {
    let mut lines = Vec::new();
    let driver_live = app.driver_peer.liveness(now);
    let mut driver = vec![source_span(app, now)];
    if let (Liveness::Alive, Some(s)) = (driver_live, &app.driver) {
        let link = match s.link_state {
            x if x == LinkState::Connected as u32 => "connected",
            x if x == LinkState::Disconnected as u32 => "port lost",
            x if x == LinkState::Refused as u32 => "wrong head on the port",
            _ => "connecting",
        };
        driver.push(text(format!(" · {link}")));
        if s.head_resets > 0 {
            driver.push(text(format!(" · head reset ×{}", s.head_resets)));
        }
    }
    lines.push(row("driver", driver));
    lines.push(row(
        "fusion",
        vec![liveness_span(app.fusion_peer.liveness(now), "fusion")],
    ));
    lines.extend(where_to_look(app, now));
    lines.extend(fusion_health(app));

    let Sweep {
        mode,
        sweep_id,
        angle,
        direction,
        progress,
    } = Sweep::of(app);
    let mut scan = match mode {
        ScanMode::Unknown if app.driver.is_none() && app.radar.is_none() => vec![text("–")],
        _ => vec![text(mode_name(mode))],
    };
    if matches!(mode, ScanMode::Full | ScanMode::Local) {
        scan.push(text(format!(
            " · sweep {sweep_id} {}",
            direction_name(direction)
        )));
    }
    lines.push(row("scan", scan));
    let mut sweep = Vec::new();
    if let Some(f) = progress {
        sweep.push(Span::styled(
            progress_bar(f, 10),
            Style::new().fg(Color::Green),
        ));
        sweep.push(text(format!(" {:>3.0}%", f * 100.0)));
    }
    if angle.is_finite() {
        sweep.push(text(format!(" {angle:+.0}°")));
    }
    lines.push(row("sweep", sweep));

    let rate = rate_text(app, now).unwrap_or_else(|| "–".to_owned());
    lines.push(row("rate", vec![text(rate)]));
    let rejected = app.driver.map_or(0, |s| s.lines_rejected);
    let rejected_style = if rejected > 0 {
        Style::new().fg(Color::Yellow)
    } else {
        Style::new()
    };
    lines.push(row(
        "errors",
        vec![Span::styled(
            format!("{rejected} lines rejected"),
            rejected_style,
        )],
    ));
    if let Some(s) = app.driver.as_ref().filter(|s| !s.head_id().is_empty()) {
        let mut head = vec![text(s.head_id().to_owned())];
        if s.silences > 0 {
            head.push(Span::styled(
                format!(" · silent ×{}", s.silences),
                Style::new().fg(Color::Yellow),
            ));
        }
        lines.push(row("head", head));
    }
    if let Some(error) = device_error(app) {
        // A refused command (e.g. a local scan outside the limits) must reach the user.
        lines.push(row("head err", vec![error]));
    }
    for (i, r) in app.readings.iter().enumerate() {
        lines.push(row(
            if i == 0 { "last" } else { "" },
            vec![text(format_reading(r))],
        ));
    }
    if app.readings.is_empty() {
        lines.push(row("last", vec![text("–")]));
    }

    match &app.grid {
        Some(g) => {
            let h = &g.header;
            lines.push(row("model", vec![text(setting_name(MODELS, h.model))]));
            lines.push(row("rule", vec![text(setting_name(RULES, h.rule))]));
            lines.push(row("preset", vec![text(setting_name(PRESETS, h.preset))]));
            lines.push(row(
                "grid",
                vec![text(format!(
                    "{}×{} · {}",
                    h.width,
                    h.height,
                    format_length(h.resolution_m)
                ))],
            ));
            lines.push(row("fused", vec![text(readings_count(h.readings_fused))]));
            lines.push(row(
                "cells",
                vec![Span::styled(
                    format!("{} occupied", format_count(h.occupied_cells.into())),
                    Style::new().fg(Color::LightRed),
                )],
            ));
            lines.push(row(
                "",
                vec![text(format!("{} free", format_count(h.free_cells.into())))],
            ));
            lines.push(row(
                "",
                vec![text(format!(
                    "{} unknown",
                    format_count(h.unknown_cells.into())
                ))],
            ));
            if let Some((position, p)) = cursor_text(app) {
                lines.push(row("cursor", vec![text(position)]));
                lines.push(row("", vec![text(p)]));
            }
        }
        None => lines.push(row("grid", vec![text("–")])),
    }
    // Exactly the origin, heading 0, is where the fusion maps without a pose source: a fixed
    // head, whose pose line would only take a row from the features' list.
    if let Some(p) = app
        .grid
        .as_ref()
        .and_then(GridSnapshot::pose)
        .filter(|p| (p.x_m, p.y_m, p.theta_rad) != (0.0, 0.0, 0.0))
    {
        lines.push(row(
            "pose",
            vec![text(format!(
                "{:+.2}, {:+.2} m {:+4.0}°",
                p.x_m,
                p.y_m,
                degrees_180(f64::from(p.theta_rad))
            ))],
        ));
    }
    if let Some(fix) = &app.localized {
        lines.extend(fix_lines(fix));
    }
    if let Some(slam) = &app.slam {
        lines.extend(slam_lines(slam));
    }
    let ipc = app.ipc_problem.as_ref().map(|problem| {
        row(
            "ipc",
            vec![Span::styled(problem.clone(), Style::new().fg(Color::Red))],
        )
    });
    lines.extend(feature_summary(app));
    // The list takes what room is left, so the IPC problem below it is never pushed out.
    let used: usize = lines.iter().chain(&ipc).map(|l| rows_of(l, width)).sum();
    let room = usize::from(height)
        .saturating_sub(used)
        .min(LISTED_FEATURES);
    lines.extend(confident_features(app, room));
    lines.extend(ipc);
    lines
}

/// Where the scan is, from the driver's status (or the radar when the driver has not said).
struct Sweep {
    mode: ScanMode,
    sweep_id: u32,
    angle: f32,
    direction: i32,
    /// 0 at the start of the pass, 1 at its end; `None` when not known.
    progress: Option<f32>,
}

impl Sweep {
    fn of(app: &App) -> Self {
        let (sweep_id, angle, direction) = match (&app.driver, &app.radar) {
            (Some(s), _) => (s.sweep_id, s.angle_deg, s.direction),
            (None, Some(r)) => (r.sweep_id, r.current_angle_deg, r.direction),
            (None, None) => (0, f32::NAN, 0),
        };
        Self {
            mode: app.scan_mode(),
            sweep_id,
            angle,
            direction,
            progress: app
                .sweep_segment()
                .and_then(|s| sweep_progress(angle, direction, s)),
        }
    }
}

/// Readings per second while the driver is alive and a rate is known.
fn rate_text(app: &App, now: Instant) -> Option<String> {
    match (app.driver_peer.liveness(now), app.rate.per_second()) {
        (Liveness::Alive, Some(r)) => Some(format!("{r:.1} readings/s")),
        _ => None,
    }
}

/// The head's latest refusal, in red; `None` when it refused nothing. A head stopped on a
/// hardware fault says so first, and how to go on.
fn device_error(app: &App) -> Option<Span<'static>> {
    app.driver
        .as_ref()
        .filter(|s| s.device_errors > 0 || s.head_fault != 0)
        .map(|s| {
            if s.head_fault != 0 {
                Span::styled(
                    format!(
                        "STOPPED: {} · check the head, then R resets it",
                        s.last_device_error()
                    ),
                    Style::new().fg(Color::Red).add_modifier(Modifier::BOLD),
                )
            } else {
                Span::styled(
                    s.last_device_error().to_owned(),
                    Style::new().fg(Color::Red),
                )
            }
        })
}

/// The cursor's position in metres and its cell's probability ("p = 0.08 free", "never
/// observed"); `None` without a map or a cursor.
fn cursor_text(app: &App) -> Option<(String, String)> {
    let g = app.grid.as_ref()?;
    let (x, y) = app.map.cursor?;
    let (wx, wy) = g.cell_center_m(x, y);
    let p = match g.cell(x, y).and_then(decode_probability) {
        Some(p) => format!("p = {p:.2} {}", if p > 0.5 { "occupied" } else { "free" }),
        None => "never observed".to_owned(),
    };
    Some((format!("{wx:+.2}, {wy:+.2} m"), p))
}

/// The compact layout's one line: what the status panel would say first, most urgent first —
/// the producers' liveness, a refused command, an IPC problem, the scan and its progress, the
/// cursor, the rate. Whatever does not fit the terminal's width is cut at the end.
fn compact_line(app: &App, now: Instant) -> Line<'static> {
    let mut parts: Vec<Vec<Span<'static>>> = Vec::new();
    for (name, peer) in [("driver", &app.driver_peer), ("fusion", &app.fusion_peer)] {
        let liveness = peer.liveness(now);
        parts.push(match liveness {
            Liveness::Waiting => vec![liveness_span(liveness, name)],
            _ if name == "driver" && app.replay => vec![source_span(app, now)],
            _ => vec![text(format!("{name} ")), liveness_span(liveness, name)],
        });
    }
    parts.extend(device_error(app).map(|e| vec![e]));
    parts.extend(app.ipc_problem.as_ref().map(|problem| {
        vec![Span::styled(
            format!("ipc {problem}"),
            Style::new().fg(Color::Red),
        )]
    }));
    if app.driver.is_some() || app.radar.is_some() {
        let sweep = Sweep::of(app);
        let progress = sweep
            .progress
            .map_or_else(String::new, |f| format!(" {:.0}%", f * 100.0));
        parts.push(vec![text(format!("{}{progress}", mode_name(sweep.mode)))]);
    }
    parts.extend(cursor_text(app).map(|(position, p)| vec![text(format!("+ {position} {p}"))]));
    parts.extend(rate_text(app, now).map(|rate| vec![text(rate)]));
    let mut spans = vec![text(" ")];
    for (i, part) in parts.into_iter().enumerate() {
        if i > 0 {
            spans.push(Span::styled(" · ", LABEL));
        }
        spans.extend(part);
    }
    Line::from(spans)
}

/// An angle in degrees within [-180, 180).
fn degrees_180(rad: f64) -> f64 {
    (rad.to_degrees() + 180.0).rem_euclid(360.0) - 180.0
}

/// The latest sonar fix: how many observations it matched, its σ per axis, and how far the
/// odometry has drifted from it. Shared memory is not trusted: a value that is not a number (as
/// the covariance is without a fix) shows as "–".
fn fix_lines(fix: &LocalizedPose) -> Vec<Line<'static>> {
    let or_dash = |v: f64, digits: usize| {
        if v.is_finite() {
            format!("{v:.digits$}")
        } else {
            "–".to_owned()
        }
    };
    // √ of a negative variance is NaN, which shows as "–" too.
    let sigma = |variance: f32| f64::from(variance).sqrt();
    let mut lines = Vec::new();
    if fix.matched == 0 {
        lines.push(row(
            "fix",
            vec![Span::styled("no fix", Style::new().fg(Color::Yellow))],
        ));
    } else {
        lines.push(row("fix", vec![text(format!("{} matched", fix.matched))]));
        lines.push(row(
            "σ x,y,θ",
            vec![text(format!(
                "{}, {} cm, {}°",
                or_dash(100.0 * sigma(fix.cov_xx), 1),
                or_dash(100.0 * sigma(fix.cov_yy), 1),
                or_dash(sigma(fix.cov_thetatheta).to_degrees(), 1),
            ))],
        ));
    }
    let distance =
        f64::from(fix.x_m - fix.odometry_x_m).hypot(f64::from(fix.y_m - fix.odometry_y_m));
    let turn = degrees_180(f64::from(fix.theta_rad - fix.odometry_theta_rad));
    let drift = if distance.is_finite() && turn.is_finite() {
        format!("{} · {turn:+.1}°", format_length(distance as f32))
    } else {
        "–".to_owned()
    };
    lines.push(row("drift", vec![text(drift)]));
    lines
}

/// The latest estimate of `sonar-slam`: fix or why not, the pose's σ per axis (what the SLAM
/// promises about the robot's place, fix or not), and its map. Values that are not numbers show
/// as "–", as in [`fix_lines`].
fn slam_lines(c: &SlamCorrection) -> Vec<Line<'static>> {
    let sigma = |variance: f32| {
        let s = f64::from(variance).sqrt();
        s.is_finite().then_some(s)
    };
    let or_dash = |v: Option<f64>| v.map_or_else(|| "–".to_owned(), |v| format!("{v:.1}"));
    let state = match c.state {
        slam_state::FIX => Span::styled(
            format!("fix · {} matched", c.matched),
            Style::new().fg(Color::Green),
        ),
        other => {
            let why = match other {
                slam_state::NO_LANDMARKS => "no landmarks seen",
                slam_state::UNCERTAIN => "too uncertain",
                slam_state::REFUSED => "refused, odometry kept",
                _ => "unknown state",
            };
            Span::styled(format!("no fix: {why}"), Style::new().fg(Color::Yellow))
        }
    };
    vec![
        row("slam", vec![state]),
        row(
            "σ x,y,θ",
            vec![text(format!(
                "{}, {} cm, {}°",
                or_dash(sigma(c.cov_xx).map(|s| 100.0 * s)),
                or_dash(sigma(c.cov_yy).map(|s| 100.0 * s)),
                or_dash(sigma(c.cov_thetatheta).map(f64::to_degrees)),
            ))],
        ),
        row(
            "map",
            vec![text(format!(
                "{} landmarks, {} refused",
                c.landmarks, c.refused
            ))],
        ),
    ]
}

/// The keys, or the selection's or a message's line.
fn bottom_line(app: &App) -> Line<'static> {
    let key = Style::new().fg(Color::Cyan).add_modifier(Modifier::BOLD);
    if let Some(s) = app.selection {
        return Line::from(vec![
            Span::styled(
                format!(" local scan {:+.0}°..{:+.0}° ", s.from_deg, s.to_deg),
                Style::new().fg(Color::Yellow).add_modifier(Modifier::BOLD),
            ),
            Span::styled("←/→", key),
            text(" turn  "),
            Span::styled("↑/↓", key),
            text(" width  "),
            Span::styled("Enter", key),
            text(" scan  "),
            Span::styled("Esc", key),
            text(" cancel"),
        ]);
    }
    if let Some(message) = &app.message {
        return Line::from(vec![
            text(format!(" {message}  ")),
            Span::styled("?", key),
            text(" help  "),
            Span::styled("q", key),
            text(" quit"),
        ]);
    }
    let mut spans = vec![text(" ")];
    for (k, what) in [
        ("f", "full scan"),
        ("l", "local"),
        ("x", "stop"),
        ("C", "clear"),
        ("s", "save"),
        ("Tab", "view"),
        ("?", "help"),
        ("q", "quit"),
    ] {
        spans.push(Span::styled(k, key));
        spans.push(text(format!(" {what}  ")));
    }
    Line::from(spans)
}

fn render_help(area: Rect, buf: &mut Buffer) {
    let width = KEYS
        .iter()
        .map(|(k, w)| 14 + w.chars().count().max(k.chars().count()))
        .max()
        .unwrap_or(40) as u16
        + 4;
    let popup = area.centered(
        Constraint::Length(width.min(area.width)),
        Constraint::Length((KEYS.len() as u16 + 4).min(area.height)),
    );
    let key = Style::new().fg(Color::Cyan).add_modifier(Modifier::BOLD);
    let mut lines: Vec<Line> = KEYS
        .iter()
        .map(|(k, what)| Line::from(vec![Span::styled(format!("{k:<13} "), key), text(*what)]))
        .collect();
    lines.push(Line::styled("any key closes this help", LABEL));
    Clear.render(popup, buf);
    Paragraph::new(lines)
        .block(Block::bordered().title(" keys "))
        .render(popup, buf);
}

#[cfg(test)]
#[path = "ui_tests.rs"]
mod tests;
