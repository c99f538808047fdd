//! Side-by-side pictures as in the paper's Figs. 8–11: basic | probability | actual setup, one row
//! per method variant, written as PNG.
//!
//! Every panel shows the same window of the grid, one cell as `scale` × `scale` pixels, +x to the
//! right and +y up, the sensor marked with a green cross. Colours:
//! - probability: the paper's Fig. 7 idea of a colour code, blue (certainly free) through pale
//!   (even odds) to red (certainly occupied), the same scale as the terminal viewer; never-observed
//!   cells dark grey, which no probability takes;
//! - basic: the arcs in the occupied red on the same dark grey (the display says nothing else);
//! - actual setup: surfaces black on white, with light grey lines every metre.
//!
//! Under the probability column a colour bar runs from p = 0 (left) to p = 1, after a swatch of
//! the unknown grey.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use anyhow::{Context, Result};
use sonar_fusion::GridGeometry;
use sonar_sim::{Scene, Vec2};

pub use sonar_mapfiles::canvas::Canvas;
use sonar_mapfiles::colour::OCCUPIED_RGB;
pub use sonar_mapfiles::colour::{UNKNOWN_RGB, probability_rgb};

use crate::metrics::MapView;

const BACKGROUND_RGB: [u8; 3] = [255, 255, 255];
const SURFACE_RGB: [u8; 3] = [0, 0, 0];
const METRE_RGB: [u8; 3] = [215, 215, 215];
const SENSOR_RGB: [u8; 3] = [0, 190, 0];
/// Between panels and around the picture.
const GAP_PX: usize = 6;
const BAR_PX: usize = 12;

/// The colour of a cell of the basic raster.
pub fn basic_rgb(v: Option<f32>) -> [u8; 3] {
    if v.is_some_and(|p| p > 0.5) {
        OCCUPIED_RGB
    } else {
        UNKNOWN_RGB
    }
}

/// The window of the grid a picture shows, in cells: columns `x0..x1`, rows `y0..y1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    pub x0: usize,
    pub x1: usize,
    pub y0: usize,
    pub y1: usize,
}

impl Window {
    /// The cells covering the scene's surfaces and the sensor, with `margin_m` around them,
    /// clipped to the grid.
    pub fn around(scene: &Scene, geometry: &GridGeometry, margin_m: f64) -> Self {
        let mut points = vec![Vec2::default()];
        for w in scene.walls() {
            points.extend([w.a, w.b]);
        }
        for p in scene.posts() {
            points.push(p.centre);
        }
        let lo = |f: fn(&Vec2) -> f64| points.iter().map(f).fold(f64::INFINITY, f64::min);
        let hi = |f: fn(&Vec2) -> f64| points.iter().map(f).fold(f64::NEG_INFINITY, f64::max);
        let res = f64::from(geometry.resolution());
        let origin = geometry.origin();
        let n = geometry.cells_per_side() as f64;
        let cell = |v: f64, o: f32| ((v - f64::from(o)) / res).round().clamp(0.0, n) as usize;
        Self {
            x0: cell(lo(|p| p.x) - margin_m, origin.x),
            x1: cell(hi(|p| p.x) + margin_m, origin.x),
            y0: cell(lo(|p| p.y) - margin_m, origin.y),
            y1: cell(hi(|p| p.y) + margin_m, origin.y),
        }
    }

    fn width(&self) -> usize {
        self.x1 - self.x0
    }

    fn height(&self) -> usize {
        self.y1 - self.y0
    }
}

/// Writes a picture as an 8-bit RGB PNG.
pub fn write_png(picture: &Canvas, path: &Path) -> Result<()> {
    let file = File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut out = BufWriter::new(file);
    picture
        .write_png(&mut out, png::Compression::High, None)
        .with_context(|| format!("writing {}", path.display()))?;
    out.flush()
        .with_context(|| format!("finishing {}", path.display()))
}

/// Draws cells of the window through `colour`, `scale` pixels per cell, highest row on top.
pub fn cells_panel(
    window: Window,
    scale: usize,
    mut colour: impl FnMut(usize, usize) -> [u8; 3],
) -> Canvas {
    let mut c = Canvas::new(window.width() * scale, window.height() * scale, [0; 3]);
    for row in 0..window.height() {
        let y = window.y1 - 1 - row;
        for col in 0..window.width() {
            let rgb = colour(window.x0 + col, y);
            c.fill(col * scale, row * scale, scale, scale, rgb);
        }
    }
    c
}

/// Pixel of world point `p` in a panel of `window`, if inside.
fn pixel_of(
    geometry: &GridGeometry,
    window: Window,
    scale: usize,
    p: Vec2,
) -> Option<(usize, usize)> {
    let res = f64::from(geometry.resolution());
    let o = geometry.origin();
    let fx = ((p.x - f64::from(o.x)) / res - window.x0 as f64) * scale as f64;
    let fy = (window.y1 as f64 - (p.y - f64::from(o.y)) / res) * scale as f64;
    let (w, h) = (
        (window.width() * scale) as f64,
        (window.height() * scale) as f64,
    );
    (fx >= 0.0 && fy >= 0.0 && fx < w && fy < h).then_some((fx as usize, fy as usize))
}

fn mark_sensor(c: &mut Canvas, geometry: &GridGeometry, window: Window, scale: usize) {
    mark_sensor_at(c, geometry, window, scale, Vec2::default());
}

/// Marks a sensor standing at `at` (world frame) with a green cross.
pub fn mark_sensor_at(
    c: &mut Canvas,
    geometry: &GridGeometry,
    window: Window,
    scale: usize,
    at: Vec2,
) {
    if let Some((x, y)) = pixel_of(geometry, window, scale, at) {
        let arm = 1 + scale;
        for d in 0..=2 * arm {
            c.set((x + d).saturating_sub(arm), y, SENSOR_RGB);
            c.set(x, (y + d).saturating_sub(arm), SENSOR_RGB);
        }
    }
}

/// A map panel.
pub fn map_panel(
    map: &MapView,
    window: Window,
    scale: usize,
    colour: fn(Option<f32>) -> [u8; 3],
) -> Canvas {
    let mut c = cells_panel(window, scale, |x, y| colour(map.value(x, y)));
    mark_sensor(&mut c, map.geometry(), window, scale);
    c
}

/// The actual setup: the cells within half a cell of a true surface (or inside a post), with
/// lines every metre.
pub fn truth_panel(scene: &Scene, geometry: &GridGeometry, window: Window, scale: usize) -> Canvas {
    let res = f64::from(geometry.resolution());
    let near_metre = |v: f64| (v - v.round()).abs() < res / 2.0;
    let mut c = cells_panel(window, scale, |x, y| {
        let p = geometry.cell_centre(x, y);
        let p = Vec2::new(f64::from(p.x), f64::from(p.y));
        // Half a cell, and a hair more so that a wall on a cell boundary marks both neighbours.
        if scene.distance_to_surface(p) <= res / 2.0 + 1e-6 {
            SURFACE_RGB
        } else if near_metre(p.x) || near_metre(p.y) {
            METRE_RGB
        } else {
            BACKGROUND_RGB
        }
    });
    mark_sensor(&mut c, geometry, window, scale);
    c
}

/// Lays panels out in a grid (`rows` of equally sized panels) with gaps, and a colour bar under
/// the column `bar_column`.
pub fn compose(rows: &[Vec<Canvas>], bar_column: Option<usize>) -> Canvas {
    let (pw, ph) = rows
        .first()
        .and_then(|r| r.first())
        .map_or((0, 0), |c| (c.width(), c.height()));
    let cols = rows.iter().map(Vec::len).max().unwrap_or(0);
    let bar = if bar_column.is_some() {
        BAR_PX + GAP_PX
    } else {
        0
    };
    let width = GAP_PX + cols * (pw + GAP_PX);
    let height = GAP_PX + rows.len() * (ph + GAP_PX) + bar;
    let mut out = Canvas::new(width, height, BACKGROUND_RGB);
    for (r, row) in rows.iter().enumerate() {
        for (k, panel) in row.iter().enumerate() {
            out.blit(
                panel,
                GAP_PX + k * (pw + GAP_PX),
                GAP_PX + r * (ph + GAP_PX),
            );
        }
    }
    if let Some(col) = bar_column {
        let x0 = GAP_PX + col * (pw + GAP_PX);
        let y0 = GAP_PX + rows.len() * (ph + GAP_PX);
        let swatch = BAR_PX * 2;
        out.fill(x0, y0, swatch, BAR_PX, UNKNOWN_RGB);
        let span = pw.saturating_sub(swatch + GAP_PX).max(1);
        for i in 0..span {
            let p = i as f32 / (span - 1).max(1) as f32;
            out.fill(
                x0 + swatch + GAP_PX + i,
                y0,
                1,
                BAR_PX,
                probability_rgb(Some(p)),
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::MapKind;
    use sonar_mapfiles::colour::FREE_RGB;

    #[test]
    fn the_basic_raster_shows_occupied_cells_only() {
        for (v, expected) in [
            (Some(1.0), OCCUPIED_RGB),
            (Some(0.5), UNKNOWN_RGB),
            (None, UNKNOWN_RGB),
        ] {
            assert_eq!(basic_rgb(v), expected, "{v:?}");
        }
    }

    #[test]
    fn panels_put_the_highest_row_on_top_and_mark_the_sensor() {
        let g = GridGeometry::new(10, 0.5); // ±2.5 m
        let mut cells = vec![None; g.len()];
        cells[g.index(9, 9)] = Some(1.0); // top right
        cells[g.index(0, 0)] = Some(0.0); // bottom left
        let map = MapView::new(g, MapKind::Probability, cells);
        let window = Window {
            x0: 0,
            x1: 10,
            y0: 0,
            y1: 10,
        };
        let c = map_panel(&map, window, 3, probability_rgb);
        assert_eq!((c.width(), c.height()), (30, 30));
        assert_eq!(c.pixel(29, 0), OCCUPIED_RGB);
        assert_eq!(c.pixel(0, 29), FREE_RGB);
        assert_eq!(c.pixel(5, 5), UNKNOWN_RGB);
        // The origin is the corner of cells 4 and 5: pixel 15.
        assert_eq!(c.pixel(15, 15), SENSOR_RGB);
    }

    #[test]
    fn the_window_covers_the_scene_and_the_truth_draws_its_surfaces() {
        let scene = Scene::builtin("obstacle").unwrap();
        let g = GridGeometry::new(400, 0.02);
        let w = Window::around(&scene, &g, 0.2);
        // x from −0.2 to 2.2 m, y ±1.7 m.
        assert_eq!((w.x0, w.x1, w.y0, w.y1), (190, 310, 115, 285));
        let c = truth_panel(&scene, &g, w, 1);
        // The post at (1, 0): cell (250, 200) → column 60, row 285 − 1 − 200 = 84.
        assert_eq!(c.pixel(60, 84), SURFACE_RGB);
        // The wall at x = 2: cells 299 and 300 have centres 1 cm off it.
        assert_eq!(c.pixel(109, 10), SURFACE_RGB);
        assert_eq!(c.pixel(80, 10), BACKGROUND_RGB);
    }

    #[test]
    fn composed_pictures_are_valid_pngs() {
        let panel = Canvas::new(4, 3, OCCUPIED_RGB);
        let pic = compose(&[vec![panel.clone(), panel.clone()], vec![panel]], Some(1));
        assert_eq!(pic.width(), GAP_PX + 2 * (4 + GAP_PX));
        assert_eq!(pic.height(), GAP_PX + 2 * (3 + GAP_PX) + BAR_PX + GAP_PX);
        assert_eq!(pic.pixel(GAP_PX, GAP_PX), OCCUPIED_RGB);
        assert_eq!(
            pic.pixel(GAP_PX + 4 + GAP_PX, GAP_PX + 3 + GAP_PX),
            BACKGROUND_RGB
        );
        let dir = std::env::temp_dir().join(format!("sonar-eval-png-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.png");
        write_png(&pic, &path).unwrap();
        let decoder = png::Decoder::new(std::io::BufReader::new(File::open(&path).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(
            (info.width as usize, info.height as usize),
            (pic.width(), pic.height())
        );
        assert_eq!(&buf[..info.buffer_size()], pic.rgb());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
