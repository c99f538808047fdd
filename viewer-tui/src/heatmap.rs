//! The probability map as pixels: which grid cells each pixel covers (zoom and pan), how a block of
//! cells becomes one pixel (max-pool that never hides an occupied cell) and which colour a pixel gets;
//! which pixels show the walls, corners and posts drawn over the map.
//!
//! Pure functions over plain slices, so the rendering tests and the benchmark exercise exactly the
//! code the viewer runs. A "pixel" is half a terminal cell: the renderer draws two pixels per cell
//! with a half-block glyph, which makes pixels roughly square on common fonts.

use std::ops::Range;

use ratatui::style::Color;
use sonar_common::ipc::{
    CELL_UNKNOWN, FeatureRecord, GridHeader, decode_probability, feature_kind,
};

/// Cells with a value above this have p > 0.5, the threshold `GridHeader::occupied_cells` uses.
pub const OCCUPIED_ABOVE: u8 = 127;
/// Closest zoom: one grid cell spans at most this many pixels per axis.
pub const MAX_PIXELS_PER_CELL: f64 = 8.0;

/// True for an observed cell that is more likely occupied than free.
pub fn is_occupied(cell: u8) -> bool {
    cell > OCCUPIED_ABOVE && cell != CELL_UNKNOWN
}

/// Which grid cells each pixel of a `width_px × height_px` picture covers.
///
/// Grid coordinates are continuous: cell (x, y) spans [x, x+1) × [y, y+1), y pointing up (row 0 of
/// a snapshot is the lowest y). Pixel rows run downwards, so the viewport works in flipped rows
/// (r = height − 1 − y) internally.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Viewport {
    /// Grid column at the left edge of pixel column 0 (may be negative: margin left of the grid).
    pub left: f64,
    /// Flipped grid row at the top edge of pixel row 0.
    pub top: f64,
    /// Grid cells per pixel along each axis (below 1 when zoomed in past one cell per pixel).
    pub scale: f64,
    pub width_px: u32,
    pub height_px: u32,
}

impl Viewport {
    /// The scale at which the whole grid fits the picture.
    pub fn fit_scale(grid_w: u32, grid_h: u32, width_px: u32, height_px: u32) -> f64 {
        Self::fit(grid_w, grid_h, width_px, height_px).scale
    }

    /// The picture showing the grid point (`center_x`, `center_y`) (grid coordinates, y up) in its
    /// middle at `scale` cells per pixel.
    pub fn centred(
        center_x: f64,
        center_y: f64,
        scale: f64,
        grid_h: u32,
        width_px: u32,
        height_px: u32,
    ) -> Self {
        let flipped_center = f64::from(grid_h) - center_y;
        Self {
            left: center_x - f64::from(width_px) * scale / 2.0,
            top: flipped_center - f64::from(height_px) * scale / 2.0,
            scale,
            width_px,
            height_px,
        }
    }

    /// The whole grid, centred.
    pub fn fit(grid_w: u32, grid_h: u32, width_px: u32, height_px: u32) -> Self {
        Self::framing(&CellBox::whole(grid_w, grid_h), grid_h, width_px, height_px)
    }

    /// The smallest picture showing all of `frame` (grid coordinates), centred on it.
    pub fn framing(frame: &CellBox, grid_h: u32, width_px: u32, height_px: u32) -> Self {
        let sx = frame.width() / f64::from(width_px.max(1));
        let sy = frame.height() / f64::from(height_px.max(1));
        let scale = sx.max(sy).max(1.0 / MAX_PIXELS_PER_CELL);
        let (cx, cy) = frame.center();
        Self::centred(cx, cy, scale, grid_h, width_px, height_px)
    }

    /// The grid point (x right, y up) in the middle of the picture.
    pub fn center(&self, grid_h: u32) -> (f64, f64) {
        (
            self.left + f64::from(self.width_px) * self.scale / 2.0,
            f64::from(grid_h) - (self.top + f64::from(self.height_px) * self.scale / 2.0),
        )
    }

    /// The grid point (continuous, y up) under the middle of pixel (`px`, `py`).
    pub fn grid_point(&self, px: u32, py: u32, grid_h: u32) -> (f64, f64) {
        (
            self.left + (f64::from(px) + 0.5) * self.scale,
            f64::from(grid_h) - (self.top + (f64::from(py) + 0.5) * self.scale),
        )
    }

    /// The pixel that shows cell (`x`, `y`), if it is in the picture (zoomed in, the first of
    /// the pixels showing it).
    pub fn pixel_of(&self, x: u32, y: u32, grid_h: u32) -> Option<(u32, u32)> {
        let flipped = grid_h.checked_sub(1)?.checked_sub(y)?;
        let px = pixel_index(i64::from(x), self.left, self.scale, self.width_px)?;
        let py = pixel_index(i64::from(flipped), self.top, self.scale, self.height_px)?;
        Some((px, py))
    }
}

/// A rectangle of the grid in continuous grid coordinates (cells, y up): [x0, x1) × [y0, y1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellBox {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl CellBox {
    pub fn whole(grid_w: u32, grid_h: u32) -> Self {
        Self {
            x0: 0.0,
            y0: 0.0,
            x1: f64::from(grid_w),
            y1: f64::from(grid_h),
        }
    }

    pub fn width(&self) -> f64 {
        self.x1 - self.x0
    }

    pub fn height(&self) -> f64 {
        self.y1 - self.y0
    }

    pub fn center(&self) -> (f64, f64) {
        ((self.x0 + self.x1) / 2.0, (self.y0 + self.y1) / 2.0)
    }

    /// Grown to take in cell (`x`, `y`).
    pub fn including(self, x: u32, y: u32) -> Self {
        let (x, y) = (f64::from(x), f64::from(y));
        Self {
            x0: self.x0.min(x),
            y0: self.y0.min(y),
            x1: self.x1.max(x + 1.0),
            y1: self.y1.max(y + 1.0),
        }
    }

    /// Widened by `margin` cells on every side and to at least `min_side` cells per side (around
    /// its centre), then clipped to a `grid_w × grid_h` grid.
    pub fn padded(self, margin: f64, min_side: f64, grid_w: u32, grid_h: u32) -> Self {
        let (cx, cy) = self.center();
        let half_w = (self.width() / 2.0 + margin).max(min_side / 2.0);
        let half_h = (self.height() / 2.0 + margin).max(min_side / 2.0);
        Self {
            x0: (cx - half_w).max(0.0),
            y0: (cy - half_h).max(0.0),
            x1: (cx + half_w).min(f64::from(grid_w)),
            y1: (cy + half_h).min(f64::from(grid_h)),
        }
    }
}

/// The smallest box holding every observed cell of `cells` (`grid_w × grid_h`, row 0 at the
/// lowest y); `None` when no cell was observed (or the slice has the wrong length).
///
/// Runs once per new grid over every cell, so rows are tested in blocks: [`CELL_UNKNOWN`] is all
/// ones, so a block is unobserved exactly when the AND of its bytes is, which the compiler
/// vectorises (a search byte by byte stops it doing so).
pub fn seen_box(cells: &[u8], grid_w: usize, grid_h: usize) -> Option<CellBox> {
    const BLOCK: usize = 64;
    if grid_w == 0 || grid_w.checked_mul(grid_h) != Some(cells.len()) {
        return None;
    }
    let unobserved =
        |block: &[u8]| block.iter().fold(CELL_UNKNOWN, |all, &v| all & v) == CELL_UNKNOWN;
    let mut seen: Option<(usize, usize, usize, usize)> = None;
    for (y, row) in cells.chunks_exact(grid_w).enumerate() {
        let Some(first_block) = row.chunks(BLOCK).position(|b| !unobserved(b)) else {
            continue;
        };
        let last_block = row
            .chunks(BLOCK)
            .rposition(|b| !unobserved(b))
            .unwrap_or(first_block);
        let in_block = |block: usize, from_right: bool| {
            let start = block * BLOCK;
            let cells = &row[start..(start + BLOCK).min(row.len())];
            let observed = |&v: &u8| v != CELL_UNKNOWN;
            let offset = if from_right {
                cells.iter().rposition(observed)
            } else {
                cells.iter().position(observed)
            };
            start + offset.unwrap_or(0)
        };
        let (first, last) = (in_block(first_block, false), in_block(last_block, true));
        seen = Some(match seen {
            None => (first, y, last, y),
            Some((x0, y0, x1, _)) => (x0.min(first), y0, x1.max(last), y),
        });
    }
    seen.map(|(x0, y0, x1, y1)| CellBox {
        x0: x0 as f64,
        y0: y0 as f64,
        x1: (x1 + 1) as f64,
        y1: (y1 + 1) as f64,
    })
}

/// The cells pixel `i` covers, unclipped: [floor(start + i·s), floor(start + (i+1)·s)), at least
/// one cell. Neighbours share their bounds, so the pixels tile the grid without gaps: no cell is
/// ever skipped, whatever the scale. Zoomed in (s < 1), a pixel covers the cell under its left edge.
fn pixel_cells(i: u32, start: f64, scale: f64) -> Range<i64> {
    let a = (start + f64::from(i) * scale).floor() as i64;
    let b = ((start + f64::from(i + 1) * scale).floor() as i64).max(a + 1);
    a..b
}

/// The first of the `count` pixels whose [`pixel_cells`] contain `cell`. Estimated by inverting the
/// formula, then settled with the formula itself so that rounding can never make the two disagree.
/// Pixel 0 is the candidate when the cell's first pixels lie left of (above) the picture.
fn pixel_index(cell: i64, start: f64, scale: f64, count: u32) -> Option<u32> {
    let estimate = ((cell as f64 - start) / scale).floor() as i64;
    (estimate - 1..=estimate + 1)
        .chain([0])
        .filter_map(|i| u32::try_from(i).ok())
        .filter(|&i| i < count)
        .find(|&i| pixel_cells(i, start, scale).contains(&cell))
}

/// For each of `count` pixels from `start` at `scale` cells per pixel, the cells it covers
/// ([`pixel_cells`]) clipped to `0..limit`: empty outside the grid.
fn covered_ranges(start: f64, scale: f64, count: u32, limit: usize, out: &mut Vec<Range<usize>>) {
    out.clear();
    let limit = i64::try_from(limit).unwrap_or(i64::MAX);
    out.extend((0..count).map(|i| {
        let cells = pixel_cells(i, start, scale);
        let (lo, hi) = (cells.start.clamp(0, limit), cells.end.clamp(0, limit));
        lo as usize..hi.max(lo) as usize
    }));
}

/// The pooling rule for a block of `total` cells of which `unknown` were never observed and the
/// largest observed value is `max_plus_one − 1` (0 when none was observed):
///
/// 1. an occupied cell anywhere in the block wins, with the block's highest probability, so a
///    single wall cell stays visible however far the map is zoomed out;
/// 2. otherwise observed cells win if they are at least half the block, again with their highest
///    probability (a conservative choice: "uncertain" shows rather than "free");
/// 3. otherwise the block shows as never observed.
///
/// `None` when the block is empty (the pixel lies outside the grid).
pub fn pool_rule(max_plus_one: u8, unknown: usize, total: usize) -> Option<u8> {
    if total == 0 {
        return None;
    }
    let Some(max) = max_plus_one.checked_sub(1) else {
        return Some(CELL_UNKNOWN);
    };
    if is_occupied(max) || total - unknown >= unknown {
        Some(max)
    } else {
        Some(CELL_UNKNOWN)
    }
}

/// A downsampled (or upsampled) picture of a grid: one pooled cell value per pixel, `None` outside
/// the grid. Keeps its buffers between frames so pooling allocates nothing in the steady state.
#[derive(Debug, Default)]
pub struct Pooled {
    width: u32,
    height: u32,
    pixels: Vec<Option<u8>>,
    cols: Vec<Range<usize>>,
    rows: Vec<Range<usize>>,
    max_plus_one: Vec<u8>,
    unknown: Vec<usize>,
}

impl Pooled {
    /// The pooled value of pixel (`x`, `y`); `None` outside the grid or the picture.
    pub fn get(&self, x: u32, y: u32) -> Option<u8> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let i = y as usize * self.width as usize + x as usize;
        self.pixels.get(i).copied().flatten()
    }

    /// Pools `cells` (`grid_w × grid_h`, row 0 at the lowest y) into the viewport's pixels with
    /// [`pool_rule`]. Visits every covered cell once, row by row, so memory is read sequentially.
    /// A `cells` slice of the wrong length yields an empty picture rather than a panic.
    pub fn pool(&mut self, cells: &[u8], grid_w: usize, grid_h: usize, vp: &Viewport) {
        self.width = vp.width_px;
        self.height = vp.height_px;
        let (w, h) = (vp.width_px as usize, vp.height_px as usize);
        self.pixels.clear();
        self.pixels.resize(w * h, None);
        if grid_w.checked_mul(grid_h) != Some(cells.len()) {
            return;
        }
        covered_ranges(vp.left, vp.scale, vp.width_px, grid_w, &mut self.cols);
        covered_ranges(vp.top, vp.scale, vp.height_px, grid_h, &mut self.rows);
        for (py, rows) in self.rows.iter().enumerate() {
            if rows.is_empty() {
                continue;
            }
            self.max_plus_one.clear();
            self.max_plus_one.resize(w, 0);
            self.unknown.clear();
            self.unknown.resize(w, 0);
            for flipped in rows.clone() {
                let y = grid_h - 1 - flipped;
                let row = &cells[y * grid_w..(y + 1) * grid_w];
                for ((cols, max), unknown) in self
                    .cols
                    .iter()
                    .zip(&mut self.max_plus_one)
                    .zip(&mut self.unknown)
                {
                    // wrapping_add maps "unknown" (255) to 0 and every observed value v to v + 1,
                    // so one max finds the largest observed value; a separate count finds the
                    // unknown ones. Both are simple enough for the compiler to vectorise.
                    let (mut m, mut u) = (*max, 0usize);
                    for &v in &row[cols.clone()] {
                        m = m.max(v.wrapping_add(1));
                        u += usize::from(v == CELL_UNKNOWN);
                    }
                    *max = m;
                    *unknown += u;
                }
            }
            let out = &mut self.pixels[py * w..(py + 1) * w];
            for (((px, cols), max), unknown) in out
                .iter_mut()
                .zip(&self.cols)
                .zip(&self.max_plus_one)
                .zip(&self.unknown)
            {
                *px = pool_rule(*max, *unknown, rows.len() * cols.len());
            }
        }
    }
}

/// Half the length of the tick drawn for a wall whose extent is unknown, metres: long enough to
/// show the wall's direction, short enough not to claim an extent nobody measured.
pub const WALL_TICK_HALF_M: f64 = 0.25;

/// How a pixel of the features overlay is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FeatureMark {
    /// Part of a wall, with the direction of the wall on screen.
    Wall(Slope),
    Corner,
    /// A post (a point target).
    Post,
}

/// Direction of a line on screen, to the nearest 45°.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Slope {
    Flat,
    Steep,
    /// Up to the right.
    Rising,
    /// Down to the right.
    Falling,
}

impl Slope {
    /// The slope of the direction (`dx`, `dy`), y up; pixels are about square, so the picture's
    /// angles are the grid's.
    fn of(dx: f64, dy: f64) -> Self {
        let (ax, ay) = (dx.abs(), dy.abs());
        // tan 22.5° ≈ 0.414: beyond it the diagonal is the nearer glyph.
        if ay <= 0.414 * ax {
            Slope::Flat
        } else if ax <= 0.414 * ay {
            Slope::Steep
        } else if (dx > 0.0) == (dy > 0.0) {
            Slope::Rising
        } else {
            Slope::Falling
        }
    }
}

/// The pixels of the picture `vp` showing the features `records` of a grid with `header`'s
/// geometry, with how to draw each: every wall as a line of pixels along its segment (a short tick
/// across its normal through its foot point when the segment is unknown), then every corner and
/// post on the pixel showing the cell it lies in, so that points are drawn over lines. A pixel
/// appears once per feature that covers it. Features outside the grid or the picture, of an
/// unknown kind or with non-finite coordinates are left out; nothing here can panic or run long on
/// odd input (a line is clipped to the picture before it is walked).
pub fn feature_pixels(
    records: &[FeatureRecord],
    header: &GridHeader,
    vp: &Viewport,
) -> Vec<(u32, u32, FeatureMark)> {
    let res = f64::from(header.resolution_m);
    if !(res.is_finite() && res > 0.0) {
        return Vec::new();
    }
    // Continuous grid coordinates (cells, y up) of a point in metres. In f32 like
    // `GridSnapshot::cell_at_m`, so that a feature and the cursor agree on the cell.
    let to_grid = |x_m: f32, y_m: f32| {
        (
            f64::from((x_m - header.origin_x_m) / header.resolution_m),
            f64::from((y_m - header.origin_y_m) / header.resolution_m),
        )
    };
    let (gw, gh) = (f64::from(header.width), f64::from(header.height));
    // A point: the pixel that shows its cell, the very pixel the heatmap pools that cell into.
    let cell_pixel = |gx: f64, gy: f64| -> Option<(u32, u32)> {
        if !(gx >= 0.0 && gx < gw && gy >= 0.0 && gy < gh) {
            return None;
        }
        vp.pixel_of(gx as u32, gy as u32, header.height)
    };
    // A point of a line. Zoomed out, the pixel of its cell, so that a wall's line lies on the
    // pixels that pool the wall's cells. Zoomed in, a cell spans several pixels and `pixel_of`
    // gives only the first, which would leave gaps: the pixel under the point.
    let line_pixel = |gx: f64, gy: f64| -> Option<(u32, u32)> {
        if vp.scale >= 1.0 {
            return cell_pixel(gx, gy);
        }
        let px = ((gx - vp.left) / vp.scale).floor();
        let py = ((gh - gy - vp.top) / vp.scale).floor();
        let inside = gx < gw
            && gy < gh
            && (0.0..f64::from(vp.width_px)).contains(&px)
            && (0.0..f64::from(vp.height_px)).contains(&py);
        inside.then_some((px as u32, py as u32))
    };
    // The part of the grid the picture shows, grid coordinates.
    let (flipped_top, flipped_bottom) = (vp.top, vp.top + f64::from(vp.height_px) * vp.scale);
    let visible = (
        vp.left.max(0.0),
        (vp.left + f64::from(vp.width_px) * vp.scale).min(gw),
        (gh - flipped_bottom).max(0.0),
        (gh - flipped_top).min(gh),
    );

    let mut out = Vec::new();
    for r in records.iter().filter(|r| r.kind == feature_kind::PLANE) {
        let segment = [
            r.segment_ax_m,
            r.segment_ay_m,
            r.segment_bx_m,
            r.segment_by_m,
        ];
        let (a, b) = if segment.iter().all(|v| v.is_finite()) {
            (
                to_grid(r.segment_ax_m, r.segment_ay_m),
                to_grid(r.segment_bx_m, r.segment_by_m),
            )
        } else if r.x_m.is_finite() && r.y_m.is_finite() && r.angle_deg.is_finite() {
            // At least two pixels either side, so the tick shows its direction at any zoom.
            let half = (WALL_TICK_HALF_M / res).max(2.0 * vp.scale);
            let (s, c) = f64::from(r.angle_deg).to_radians().sin_cos();
            let (gx, gy) = to_grid(r.x_m, r.y_m);
            (
                (gx + s * half, gy - c * half),
                (gx - s * half, gy + c * half),
            )
        } else {
            continue;
        };
        let Some((a, b)) = clip(a, b, visible) else {
            continue;
        };
        let mark = FeatureMark::Wall(Slope::of(b.0 - a.0, b.1 - a.1));
        // Steps of half a pixel visit every pixel the line crosses (zoomed out, the pooling's
        // pixels are whole cells, at least half a pixel's width each); clipped to the picture,
        // that is at most about twice its diagonal.
        let length = (b.0 - a.0).hypot(b.1 - a.1);
        let steps = (2.0 * length / vp.scale).ceil().clamp(1.0, 1e6) as u32;
        let mut last = None;
        for i in 0..=steps {
            let t = f64::from(i) / f64::from(steps);
            if let Some(p) = line_pixel(a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t)
                && last != Some(p)
            {
                out.push((p.0, p.1, mark));
                last = Some(p);
            }
        }
    }
    for r in records {
        let mark = match r.kind {
            feature_kind::CORNER => FeatureMark::Corner,
            feature_kind::POINT => FeatureMark::Post,
            _ => continue,
        };
        let (gx, gy) = to_grid(r.x_m, r.y_m);
        if let Some((px, py)) = cell_pixel(gx, gy) {
            out.push((px, py, mark));
        }
    }
    out
}

/// The part of the segment `a`–`b` inside the rectangle (`x0`, `x1`, `y0`, `y1`) (Liang–Barsky);
/// `None` when none is, or when a coordinate is not finite or absurdly far.
fn clip(
    a: (f64, f64),
    b: (f64, f64),
    (x0, x1, y0, y1): (f64, f64, f64, f64),
) -> Option<((f64, f64), (f64, f64))> {
    // Beyond FAR cells the clipped ends would lose their precision to cancellation (and no
    // sonar's wall reaches that far): such a segment is refused, not drawn somewhere wrong.
    const FAR: f64 = 1e7;
    if ![a.0, a.1, b.0, b.1].iter().all(|v| v.abs() <= FAR) || x0 > x1 || y0 > y1 {
        return None;
    }
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [
        (-dx, a.0 - x0),
        (dx, x1 - a.0),
        (-dy, a.1 - y0),
        (dy, y1 - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    (t0 <= t1).then_some((
        (a.0 + t0 * dx, a.1 + t0 * dy),
        (a.0 + t1 * dx, a.1 + t1 * dy),
    ))
}

/// How many colours the terminal shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorMode {
    /// 24-bit colour.
    TrueColor,
    /// The xterm 256-colour palette (its 6×6×6 cube and grey ramp; the 16 themeable colours are
    /// avoided because users redefine them).
    Indexed256,
    /// The 16 ANSI colours: the colour code in bands ([`ansi16`]).
    Ansi16,
    /// No colour at all (`NO_COLOR`): the map's glyphs carry the probability ([`mono_glyph`]).
    Mono,
}

impl ColorMode {
    /// From the environment's conventions: `NO_COLOR` set and not empty (no-color.org) or
    /// `TERM=dumb`: none; `COLORTERM` `truecolor`/`24bit`: truecolor; a `TERM` of the Linux
    /// console, a VT or ANSI terminal or one named `*-color`, `*-8color`, `*-16color`: the 16 ANSI
    /// colours; else (`*-256color`, `xterm`, `screen`, `tmux`, unset) the 256-colour palette.
    pub fn detect(colorterm: Option<&str>, term: Option<&str>, no_color: Option<&str>) -> Self {
        let term = term.unwrap_or("").to_ascii_lowercase();
        if no_color.is_some_and(|v| !v.is_empty()) || term == "dumb" {
            return ColorMode::Mono;
        }
        if colorterm
            .is_some_and(|v| v.eq_ignore_ascii_case("truecolor") || v.eq_ignore_ascii_case("24bit"))
        {
            return ColorMode::TrueColor;
        }
        let few = ["linux", "vt", "ansi", "cons"]
            .iter()
            .any(|p| term.starts_with(p))
            || ["-color", "-8color", "-16color"]
                .iter()
                .any(|s| term.ends_with(s));
        if few && !term.contains("256") {
            ColorMode::Ansi16
        } else {
            ColorMode::Indexed256
        }
    }
}

/// The colour code in the 16 ANSI colours, by bands of probability: blue (p < 0.2), light blue,
/// grey around even odds (0.4–0.6), light red, red (p ≥ 0.8); dark grey never observed.
pub fn ansi16(cell: u8) -> Color {
    match decode_probability(cell) {
        None => Color::DarkGray,
        Some(p) if p < 0.2 => Color::Blue,
        Some(p) if p < 0.4 => Color::LightBlue,
        Some(p) if p < 0.6 => Color::Gray,
        Some(p) if p < 0.8 => Color::LightRed,
        Some(_) => Color::Red,
    }
}

/// Without colours, the glyph of a terminal cell showing two pixels: the darker the more likely
/// occupied, by the higher of their probabilities (so a wall pixel is never lost): `█` p > 0.75,
/// `▓` p > 0.5 (both occupied), `▒` p > 0.25, `░` free, a blank never observed or outside.
pub fn mono_glyph(upper: Option<u8>, lower: Option<u8>) -> char {
    let p = [upper, lower]
        .into_iter()
        .flatten()
        .filter_map(decode_probability)
        .reduce(f32::max);
    match p {
        None => ' ',
        Some(p) if p > 0.75 => '█',
        Some(p) if p > 0.5 => '▓',
        Some(p) if p > 0.25 => '▒',
        Some(_) => '░',
    }
}

// The colour code (blue free → pale even odds → red occupied, dark grey never observed) lives in
// sonar-mapfiles, so the terminal and every saved picture share it.
pub use sonar_mapfiles::colour::{UNKNOWN_RGB, cell_rgb};

/// The colour of the xterm 256-colour palette (indices 16–255) nearest to `rgb`.
pub fn nearest_xterm256(rgb: [u8; 3]) -> u8 {
    const LEVELS: [u8; 6] = [0, 95, 135, 175, 215, 255];
    let dist = |a: [u8; 3], b: [u8; 3]| -> u32 {
        a.iter()
            .zip(b)
            .map(|(&x, y)| (i32::from(x) - i32::from(y)).unsigned_abs().pow(2))
            .sum()
    };
    let nearest_level = |v: u8| -> usize {
        (0..LEVELS.len())
            .min_by_key(|&i| (i32::from(LEVELS[i]) - i32::from(v)).unsigned_abs())
            .unwrap_or(0)
    };
    let idx = rgb.map(nearest_level);
    let cube_rgb = idx.map(|i| LEVELS[i]);
    let cube = 16 + 36 * idx[0] + 6 * idx[1] + idx[2];
    // Grey ramp 232–255 is 8, 18, …, 238.
    let mean = rgb.iter().map(|&v| u32::from(v)).sum::<u32>() / 3;
    let step = (mean.saturating_sub(3) / 10).min(23) as u8;
    let grey_level = 8 + 10 * step;
    if dist(rgb, [grey_level; 3]) < dist(rgb, cube_rgb) {
        232 + step
    } else {
        cube as u8
    }
}

/// The colour of the features overlay: green, a hue the colour code (blue, pale, red, grey)
/// never uses, bright enough for dark and light cells alike.
pub const FEATURE_RGB: [u8; 3] = [60, 255, 60];
/// The colour of the robot's trail: violet, another hue the colour code never uses and apart from
/// the features' green, so the path reads as neither map nor wall.
pub const TRAIL_RGB: [u8; 3] = [200, 130, 255];

/// Cell value → terminal colour, precomputed for one [`ColorMode`], and the overlays' colours.
#[derive(Debug, Clone)]
pub struct Palette {
    mode: ColorMode,
    colors: [Color; 256],
    feature: Color,
    trail: Color,
}

impl Palette {
    pub fn new(mode: ColorMode) -> Self {
        let color = |rgb: [u8; 3], ansi: Color| match mode {
            ColorMode::TrueColor => Color::Rgb(rgb[0], rgb[1], rgb[2]),
            ColorMode::Indexed256 => Color::Indexed(nearest_xterm256(rgb)),
            ColorMode::Ansi16 => ansi,
            ColorMode::Mono => Color::Reset,
        };
        Self {
            mode,
            colors: std::array::from_fn(|v| color(cell_rgb(v as u8), ansi16(v as u8))),
            feature: color(FEATURE_RGB, Color::LightGreen),
            trail: color(TRAIL_RGB, Color::LightMagenta),
        }
    }

    pub fn mode(&self) -> ColorMode {
        self.mode
    }

    /// No colours: shapes alone must tell things apart.
    pub fn is_mono(&self) -> bool {
        self.mode == ColorMode::Mono
    }

    /// The colour of the robot's trail.
    pub fn trail(&self) -> Color {
        self.trail
    }

    /// The colour of walls, corners and posts drawn over the map.
    pub fn feature(&self) -> Color {
        self.feature
    }

    /// The colour of a pooled pixel; the terminal's own background outside the grid.
    pub fn color(&self, pixel: Option<u8>) -> Color {
        pixel.map_or(Color::Reset, |v| self.colors[usize::from(v)])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use sonar_mapfiles::colour::{EVEN_RGB, FREE_RGB, OCCUPIED_RGB};

    #[test]
    fn pool_rule_lets_occupied_win_then_the_majority() {
        // One occupied cell among 99 unknown ones.
        assert_eq!(pool_rule(201, 99, 100), Some(200));
        // Mostly free, a little unknown: free (the highest observed value).
        assert_eq!(pool_rule(31, 3, 10), Some(30));
        // Mostly unknown, some free: unknown.
        assert_eq!(pool_rule(31, 7, 10), Some(CELL_UNKNOWN));
        // A tie goes to the observed cells.
        assert_eq!(pool_rule(31, 5, 10), Some(30));
        assert_eq!(pool_rule(0, 10, 10), Some(CELL_UNKNOWN));
        assert_eq!(pool_rule(0, 0, 0), None);
    }

    fn grid_with(w: usize, h: usize, fill: u8, marks: &[(usize, usize, u8)]) -> Vec<u8> {
        let mut cells = vec![fill; w * h];
        for &(x, y, v) in marks {
            cells[y * w + x] = v;
        }
        cells
    }

    #[test]
    fn fitted_viewport_covers_the_whole_grid_once() {
        let (w, h) = (1000usize, 700usize);
        let vp = Viewport::fit(w as u32, h as u32, 80, 48);
        let mut cols = Vec::new();
        let mut rows = Vec::new();
        covered_ranges(vp.left, vp.scale, vp.width_px, w, &mut cols);
        covered_ranges(vp.top, vp.scale, vp.height_px, h, &mut rows);
        assert_eq!(cols.iter().map(Range::len).sum::<usize>(), w);
        assert_eq!(rows.iter().map(Range::len).sum::<usize>(), h);
    }

    #[test]
    fn pixel_of_finds_the_pixel_that_pools_the_cell() {
        let (w, h) = (333u32, 211u32);
        for vp in [
            Viewport::fit(w, h, 40, 24),
            Viewport::centred(100.5, 50.5, 0.25, h, 40, 24),
            Viewport::centred(10.0, 200.0, 3.0, h, 40, 24),
        ] {
            let (x, y) = (101u32, 49u32);
            let cells = grid_with(w as usize, h as usize, 0, &[(x as usize, y as usize, 254)]);
            let mut pooled = Pooled::default();
            pooled.pool(&cells, w as usize, h as usize, &vp);
            if let Some((px, py)) = vp.pixel_of(x, y, h) {
                assert_eq!(pooled.get(px, py), Some(254), "{vp:?}");
            }
        }
    }

    #[test]
    fn zoomed_in_pixels_repeat_cells_and_outside_is_none() {
        let cells = grid_with(4, 4, 0, &[(0, 3, 254)]); // top-left cell occupied
        let vp = Viewport::centred(2.0, 2.0, 0.5, 4, 12, 12); // 8×8 px of grid, 2 px margin
        let mut pooled = Pooled::default();
        pooled.pool(&cells, 4, 4, &vp);
        assert_eq!(pooled.get(0, 0), None);
        assert_eq!(pooled.get(2, 2), Some(254));
        assert_eq!(pooled.get(3, 3), Some(254));
        assert_eq!(pooled.get(4, 2), Some(0));
        assert_eq!(pooled.get(2, 4), Some(0));
        assert_eq!(pooled.get(11, 11), None);
    }

    #[test]
    fn wrong_payload_length_gives_an_empty_picture() {
        let vp = Viewport::fit(10, 10, 5, 5);
        let mut pooled = Pooled::default();
        pooled.pool(&[0; 99], 10, 10, &vp);
        assert!((0..5).all(|x| (0..5).all(|y| pooled.get(x, y).is_none())));
    }

    /// 120 × 80 cells of 5 cm, origin at (-3, -2) m: the metre (0, 0) is cell (60, 40).
    fn feature_grid() -> GridHeader {
        GridHeader {
            width: 120,
            height: 80,
            resolution_m: 0.05,
            origin_x_m: -3.0,
            origin_y_m: -2.0,
            ..GridHeader::default()
        }
    }

    fn feature(kind: u32, x_m: f32, y_m: f32) -> FeatureRecord {
        FeatureRecord {
            kind,
            x_m,
            y_m,
            angle_deg: f32::NAN,
            angle_sigma_deg: f32::NAN,
            segment_ax_m: f32::NAN,
            segment_ay_m: f32::NAN,
            segment_bx_m: f32::NAN,
            segment_by_m: f32::NAN,
            confidence: 0.5,
            ..FeatureRecord::default()
        }
    }

    fn wall(a: (f32, f32), b: (f32, f32)) -> FeatureRecord {
        FeatureRecord {
            segment_ax_m: a.0,
            segment_ay_m: a.1,
            segment_bx_m: b.0,
            segment_by_m: b.1,
            ..feature(feature_kind::PLANE, 0.0, 0.0)
        }
    }

    #[test]
    fn corners_and_posts_land_on_the_pixel_of_their_cell() {
        let g = feature_grid();
        let vp = Viewport::fit(120, 80, 60, 40); // 2 cells per pixel
        let records = [
            feature(feature_kind::CORNER, 1.025, 1.025), // cell (81, 61)
            feature(feature_kind::POINT, -0.475, 0.325), // cell (50, 46)
            feature(feature_kind::POINT, 9.0, 0.0),      // outside the grid
            feature(feature_kind::POINT, f32::NAN, 0.0),
            feature(7, 0.0, 0.0), // unknown kind
        ];
        assert_eq!(
            feature_pixels(&records, &g, &vp),
            vec![(40, 9, FeatureMark::Corner), (25, 16, FeatureMark::Post),]
        );
        assert_eq!(vp.pixel_of(81, 61, 80), Some((40, 9)));
        assert_eq!(vp.pixel_of(50, 46, 80), Some((25, 16)));
    }

    #[test]
    fn a_wall_segment_is_a_gapless_line_of_pixels_drawn_before_the_points() {
        let g = feature_grid();
        let vp = Viewport::fit(120, 80, 60, 40);
        // Along row 61 from cell 40 to cell 81: pixels 20..=40 of pixel row 9.
        let records = [
            feature(feature_kind::POINT, 0.025, 1.025),
            wall((-0.975, 1.025), (1.025, 1.025)),
        ];
        let pixels = feature_pixels(&records, &g, &vp);
        let (line, points) = pixels.split_at(pixels.len() - 1);
        assert_eq!(points, &[(30, 9, FeatureMark::Post)]);
        let xs: Vec<u32> = line.iter().map(|p| p.0).collect();
        assert_eq!(xs, (20..=40).collect::<Vec<_>>());
        assert!(
            line.iter()
                .all(|&(_, py, m)| py == 9 && m == FeatureMark::Wall(Slope::Flat))
        );
        // A diagonal wall rises one pixel per pixel.
        let diagonal = feature_pixels(&[wall((0.025, 0.025), (0.525, 0.525))], &g, &vp);
        assert_eq!(
            diagonal.first(),
            Some(&(30, 19, FeatureMark::Wall(Slope::Rising)))
        );
        assert_eq!(
            diagonal.last(),
            Some(&(35, 14, FeatureMark::Wall(Slope::Rising)))
        );
    }

    #[test]
    fn a_wall_without_extent_is_a_tick_across_its_normal() {
        let g = feature_grid();
        let vp = Viewport::fit(120, 80, 60, 40);
        // Normal along +x through cell (90, 40): a vertical tick of ±0.25 m = ±5 cells = ±2.5
        // pixels.
        let plane = FeatureRecord {
            angle_deg: 0.0,
            ..feature(feature_kind::PLANE, 1.525, 0.025)
        };
        let pixels = feature_pixels(&[plane], &g, &vp);
        let column = vp.pixel_of(90, 40, 80).map(|p| p.0);
        let rows: Vec<u32> = pixels.iter().map(|p| p.1).collect();
        assert_eq!(rows, (17..=22).rev().collect::<Vec<_>>());
        assert!(
            pixels
                .iter()
                .all(|&(px, _, m)| { Some(px) == column && m == FeatureMark::Wall(Slope::Steep) })
        );
        // Without a direction either there is nothing to draw.
        let lost = FeatureRecord {
            angle_deg: f32::NAN,
            ..plane
        };
        assert!(feature_pixels(&[lost], &g, &vp).is_empty());
    }

    #[test]
    fn walls_are_clipped_to_the_picture() {
        let g = feature_grid();
        // Zoomed in on the middle: 0.5 cells per pixel, the picture shows cells 45..75 × 32.5..47.5.
        let vp = Viewport::centred(60.0, 40.0, 0.5, 80, 60, 30);
        let long = wall((-100.0, 0.0), (100.0, 0.0));
        let pixels = feature_pixels(&[long], &g, &vp);
        let xs: Vec<u32> = pixels.iter().map(|p| p.0).collect();
        assert_eq!(
            xs,
            (0..60).collect::<Vec<_>>(),
            "every pixel, though cells span two"
        );
        assert!(pixels.iter().all(|p| p.1 == 15));
        // Entirely outside the picture, infinite or absurdly far: nothing.
        let outside = wall((-2.5, -1.9), (2.5, -1.9));
        let infinite = wall((f32::NEG_INFINITY, 0.0), (0.0, 0.0));
        let absurd = wall((-1e30, 0.0), (1e30, 0.0));
        assert!(feature_pixels(&[outside, infinite, absurd], &g, &vp).is_empty());
    }

    #[test]
    fn slopes_to_the_nearest_45_degrees() {
        assert_eq!(Slope::of(1.0, 0.1), Slope::Flat);
        assert_eq!(Slope::of(-0.1, 1.0), Slope::Steep);
        assert_eq!(Slope::of(-1.0, -0.9), Slope::Rising);
        assert_eq!(Slope::of(1.0, -1.2), Slope::Falling);
        assert_eq!(Slope::of(0.0, 0.0), Slope::Flat);
    }

    proptest! {
        /// Whatever the grid size, zoom and pan: a single occupied cell inside the picture shows.
        #[test]
        fn a_single_occupied_cell_is_never_pooled_away(
            w in 1usize..600, h in 1usize..600,
            fx in 0.0f64..1.0, fy in 0.0f64..1.0,
            zoom in -3i32..4, pan_x in -0.3f64..0.3, pan_y in -0.3f64..0.3,
            pw in 1u32..120, ph in 1u32..80,
            background in prop::sample::select(vec![0u8, 60, 127, CELL_UNKNOWN]),
        ) {
            let (x, y) = (((w as f64) * fx) as usize, ((h as f64) * fy) as usize);
            let cells = grid_with(w, h, background, &[(x, y, 200)]);
            let scale = Viewport::fit_scale(w as u32, h as u32, pw, ph) * 2f64.powi(-zoom);
            let vp = Viewport::centred(
                w as f64 * (0.5 + pan_x), h as f64 * (0.5 + pan_y),
                scale.max(1.0 / MAX_PIXELS_PER_CELL), h as u32, pw, ph,
            );
            let mut pooled = Pooled::default();
            pooled.pool(&cells, w, h, &vp);
            let occupied = (0..ph)
                .flat_map(|py| (0..pw).map(move |px| (px, py)))
                .filter(|&(px, py)| pooled.get(px, py) == Some(200))
                .count();
            match vp.pixel_of(x as u32, y as u32, h as u32) {
                Some((px, py)) => {
                    prop_assert_eq!(pooled.get(px, py), Some(200));
                    prop_assert!(occupied >= 1);
                }
                None => prop_assert_eq!(occupied, 0),
            }
        }

        /// Any coordinates (NaN, infinite, huge), any zoom: features give pixels inside the
        /// picture only, and a bounded number of them.
        #[test]
        fn feature_pixels_stay_in_the_picture(
            coords in prop::collection::vec(
                prop::sample::select(vec![f32::NAN, f32::INFINITY, -1e30, -2.0, -0.3, 0.0, 0.7, 2.9, 1e30]),
                7,
            ),
            kind in 0u32..5,
            zoom in -3i32..4, pw in 1u32..120, ph in 1u32..80,
        ) {
            let g = feature_grid();
            let scale = Viewport::fit_scale(120, 80, pw, ph) * 2f64.powi(-zoom);
            let vp = Viewport::centred(60.0, 40.0, scale.max(1.0 / MAX_PIXELS_PER_CELL), 80, pw, ph);
            let r = FeatureRecord {
                kind,
                x_m: coords[0],
                y_m: coords[1],
                angle_deg: coords[2] * 100.0,
                segment_ax_m: coords[3],
                segment_ay_m: coords[4],
                segment_bx_m: coords[5],
                segment_by_m: coords[6],
                ..FeatureRecord::default()
            };
            let pixels = feature_pixels(&[r], &g, &vp);
            prop_assert!(pixels.len() <= 4 * (pw + ph) as usize + 2, "{}", pixels.len());
            for (px, py, _) in pixels {
                prop_assert!(px < pw && py < ph);
            }
        }
    }

    #[test]
    fn colour_scale_runs_free_to_occupied_and_unknown_stands_apart() {
        assert_eq!(cell_rgb(0), FREE_RGB);
        assert_eq!(cell_rgb(127), EVEN_RGB);
        assert_eq!(cell_rgb(254), OCCUPIED_RGB);
        // From blue to red: blue minus red falls steadily with the probability.
        let blueness = |v: u8| {
            let [r, _, b] = cell_rgb(v);
            i32::from(b) - i32::from(r)
        };
        for v in 1..=254u8 {
            assert!(blueness(v) <= blueness(v - 1), "at {v}");
        }
        for mode in [ColorMode::TrueColor, ColorMode::Indexed256] {
            let palette = Palette::new(mode);
            let unknown = palette.color(Some(CELL_UNKNOWN));
            for v in 0..=254u8 {
                assert_ne!(palette.color(Some(v)), unknown, "{mode:?} {v}");
            }
            assert_eq!(palette.color(None), Color::Reset);
        }
    }

    #[test]
    fn xterm_palette_mapping() {
        assert_eq!(nearest_xterm256([0, 0, 0]), 16);
        assert_eq!(nearest_xterm256([255, 255, 255]), 231);
        assert_eq!(nearest_xterm256([255, 0, 0]), 196);
        assert_eq!(nearest_xterm256(UNKNOWN_RGB), 236);
        assert_eq!(nearest_xterm256([128, 128, 128]), 244);
        for v in 0..=255u8 {
            assert!(nearest_xterm256(cell_rgb(v)) >= 16);
        }
    }

    proptest! {
        /// The block-wise search finds exactly the box a cell-by-cell search finds.
        #[test]
        fn seen_box_is_the_box_of_the_observed_cells(
            w in 1usize..200,
            h in 1usize..6,
            marks in proptest::collection::vec((0usize..200, 0usize..6, 0u8..255), 0..6),
        ) {
            let marks: Vec<_> = marks.into_iter().filter(|&(x, y, _)| x < w && y < h).collect();
            let cells = grid_with(w, h, CELL_UNKNOWN, &marks);
            let expected = marks.iter().fold(None, |b: Option<CellBox>, &(x, y, _)| {
                let cell = CellBox {
                    x0: x as f64,
                    y0: y as f64,
                    x1: x as f64 + 1.0,
                    y1: y as f64 + 1.0,
                };
                Some(b.map_or(cell, |b| b.including(x as u32, y as u32)))
            });
            prop_assert_eq!(seen_box(&cells, w, h), expected);
        }
    }

    #[test]
    fn colour_mode_detection() {
        use ColorMode::*;
        let xterm = Some("xterm-256color");
        assert_eq!(ColorMode::detect(Some("truecolor"), xterm, None), TrueColor);
        assert_eq!(ColorMode::detect(Some("24bit"), None, None), TrueColor);
        assert_eq!(ColorMode::detect(Some(""), xterm, None), Indexed256);
        assert_eq!(ColorMode::detect(None, None, None), Indexed256);
        assert_eq!(ColorMode::detect(None, Some("screen"), None), Indexed256);
        // NO_COLOR wins over everything, unless empty (no-color.org).
        assert_eq!(ColorMode::detect(Some("truecolor"), xterm, Some("1")), Mono);
        assert_eq!(ColorMode::detect(None, xterm, Some("")), Indexed256);
        assert_eq!(ColorMode::detect(None, Some("dumb"), None), Mono);
        for few in [
            "linux",
            "vt220",
            "ansi",
            "xterm-color",
            "rxvt-16color",
            "screen-8color",
        ] {
            assert_eq!(ColorMode::detect(None, Some(few), None), Ansi16, "{few}");
        }
        assert_eq!(
            ColorMode::detect(None, Some("rxvt-unicode-256color"), None),
            Indexed256
        );
    }

    /// 16 colours: the code in bands, each band apart from its neighbours and from "never
    /// observed"; no colours: glyphs as dark as the cell is likely occupied.
    #[test]
    fn sixteen_colours_and_none_keep_the_classes_apart() {
        let p16 = Palette::new(ColorMode::Ansi16);
        let bands: Vec<Color> = [0.0, 0.3, 0.5, 0.7, 1.0]
            .iter()
            .map(|&p| p16.color(Some(sonar_common::ipc::encode_probability(p))))
            .collect();
        assert_eq!(
            bands,
            [
                Color::Blue,
                Color::LightBlue,
                Color::Gray,
                Color::LightRed,
                Color::Red
            ]
        );
        assert_eq!(p16.color(Some(CELL_UNKNOWN)), Color::DarkGray);
        assert!(!bands.contains(&p16.feature()) && !bands.contains(&p16.trail()));

        let mono = Palette::new(ColorMode::Mono);
        assert!(mono.is_mono());
        assert!((0..=255).all(|v| mono.color(Some(v)) == Color::Reset));
        let cell = |p: f32| Some(sonar_common::ipc::encode_probability(p));
        assert_eq!(mono_glyph(cell(0.1), cell(0.1)), '░');
        assert_eq!(mono_glyph(cell(0.4), None), '▒');
        assert_eq!(mono_glyph(cell(0.6), cell(0.1)), '▓');
        assert_eq!(mono_glyph(Some(CELL_UNKNOWN), cell(0.95)), '█');
        assert_eq!(mono_glyph(Some(CELL_UNKNOWN), None), ' ');
        assert_eq!(mono_glyph(None, None), ' ');
    }
}
