//! The probability map as pixels: which grid cells each pixel covers (zoom and pan), how a block of
//! cells becomes one pixel (max-pool that never hides an occupied cell) and which colour a pixel gets.
//!
//! Pure functions over plain slices, so the rendering tests and the benchmark exercise exactly the
//! code the viewer runs. A "pixel" is half a terminal cell: the renderer draws two pixels per cell
//! with a half-block glyph, which makes pixels roughly square on common fonts.

use std::ops::Range;

use ratatui::style::Color;
use sonar_common::ipc::CELL_UNKNOWN;

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
        let sx = f64::from(grid_w) / f64::from(width_px.max(1));
        let sy = f64::from(grid_h) / f64::from(height_px.max(1));
        sx.max(sy).max(1.0 / MAX_PIXELS_PER_CELL)
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
        let scale = Self::fit_scale(grid_w, grid_h, width_px, height_px);
        Self::centred(
            f64::from(grid_w) / 2.0,
            f64::from(grid_h) / 2.0,
            scale,
            grid_h,
            width_px,
            height_px,
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

/// How many colours the terminal shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorMode {
    /// 24-bit colour.
    TrueColor,
    /// The xterm 256-colour palette (its 6×6×6 cube and grey ramp; the 16 themeable colours are
    /// avoided because users redefine them).
    Indexed256,
}

impl ColorMode {
    /// Truecolor when `COLORTERM` says so (the de-facto convention), else 256 colours.
    pub fn detect(colorterm: Option<&str>) -> Self {
        match colorterm {
            Some(v) if v.eq_ignore_ascii_case("truecolor") || v.eq_ignore_ascii_case("24bit") => {
                ColorMode::TrueColor
            }
            _ => ColorMode::Indexed256,
        }
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

/// Cell value → terminal colour, precomputed for one [`ColorMode`].
#[derive(Debug, Clone)]
pub struct Palette {
    colors: [Color; 256],
}

impl Palette {
    pub fn new(mode: ColorMode) -> Self {
        Self {
            colors: std::array::from_fn(|v| {
                let rgb = cell_rgb(v as u8);
                match mode {
                    ColorMode::TrueColor => Color::Rgb(rgb[0], rgb[1], rgb[2]),
                    ColorMode::Indexed256 => Color::Indexed(nearest_xterm256(rgb)),
                }
            }),
        }
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

    #[test]
    fn colour_mode_detection() {
        assert_eq!(ColorMode::detect(Some("truecolor")), ColorMode::TrueColor);
        assert_eq!(ColorMode::detect(Some("24bit")), ColorMode::TrueColor);
        assert_eq!(ColorMode::detect(Some("")), ColorMode::Indexed256);
        assert_eq!(ColorMode::detect(None), ColorMode::Indexed256);
    }
}
