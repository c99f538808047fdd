//! The probability map as pixels: which grid cells each pixel covers (zoom and pan), how a block of
//! cells becomes one pixel (max-pool that never hides an occupied cell) and which colour a pixel gets;
//! which pixels show the walls, corners and posts drawn over the map.
//!
//! Pure functions over plain slices, so the rendering tests and the benchmark exercise exactly the
//! code the viewer runs. A "pixel" is half a terminal cell: the renderer draws two pixels per cell
//! with a half-block glyph, which makes pixels roughly square on common fonts.

use std::ops::Range;

use ratatui::style::Color;
use sonar_common::ipc::{CELL_UNKNOWN, decode_probability};
// The picture's geometry and the features overlay are the PNG's too (sonar_mapfiles), so the
// saved map and the screen show the same pixels.
pub use sonar_mapfiles::overlay::{
    FeatureMark, Slope, WALL_TICK_HALF_M, feature_pixels, tentative_then_confirmed,
};
use sonar_mapfiles::viewport::pixel_cells;
pub use sonar_mapfiles::viewport::{CellBox, MAX_PIXELS_PER_CELL, Viewport};

/// Cells with a value above this have p > 0.5, the threshold `GridHeader::occupied_cells` uses.
pub const OCCUPIED_ABOVE: u8 = 127;
/// True for an observed cell that is more likely occupied than free.
pub fn is_occupied(cell: u8) -> bool {
    cell > OCCUPIED_ABOVE && cell != CELL_UNKNOWN
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

pub use sonar_mapfiles::colour::{FEATURE_RGB, TENTATIVE_FEATURE_RGB};
/// The colour of the robot's trail: violet, another hue the colour code never uses and apart from
/// the features' green, so the path reads as neither map nor wall.
pub const TRAIL_RGB: [u8; 3] = [200, 130, 255];

/// Cell value → terminal colour, precomputed for one [`ColorMode`], and the overlays' colours.
#[derive(Debug, Clone)]
pub struct Palette {
    mode: ColorMode,
    colors: [Color; 256],
    feature: Color,
    tentative_feature: Color,
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
            tentative_feature: color(TENTATIVE_FEATURE_RGB, Color::Yellow),
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

    /// The colour of features heard from one place only (tentative).
    pub fn tentative_feature(&self) -> Color {
        self.tentative_feature
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
            // Thousandths, not proptest's float ranges, which trip their own debug assertion
            // on rare draws (fusion's `test_strategies`).
            fx in (0..1000u16).prop_map(|k| f64::from(k) / 1000.0),
            fy in (0..1000u16).prop_map(|k| f64::from(k) / 1000.0),
            zoom in -3i32..4,
            pan_x in (-300..300i16).prop_map(|k| f64::from(k) / 1000.0),
            pan_y in (-300..300i16).prop_map(|k| f64::from(k) / 1000.0),
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
        assert!(!bands.contains(&p16.tentative_feature()));
        assert_ne!(p16.tentative_feature(), p16.feature());

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
