//! The map as a PNG: one pixel per grid cell in the [`colour`](crate::colour) code, the highest y
//! on top, the map's geometry in a `Comment` text chunk so the picture can be placed in the world
//! again; optionally a legend strip below the map with a scale bar and the colour code, and the
//! walls, corners and posts drawn over the map as the viewer draws them ([`overlay`]).

use std::io::Write;

use sonar_common::ipc::{FeatureRecord, feature_kind};

use crate::canvas::Canvas;
use crate::colour::{FEATURE_RGB, TENTATIVE_FEATURE_RGB, UNKNOWN_RGB, cell_rgb};
use crate::font;
use crate::map::{Map, MapError};
use crate::overlay::{self, FeatureMark};
use crate::settings::{MODELS, RULES, setting_name};
use crate::viewport::Viewport;

/// Rows the legend adds below the map.
pub const LEGEND_HEIGHT: u32 = 24;
const MARGIN: u32 = 8;
const TEXT_SCALE: u32 = 2;
/// Top of the text and of the legend's swatches, from the top of the strip.
const TEXT_TOP: u32 = 7;
const TEXT_H: u32 = font::GLYPH_H * TEXT_SCALE;
const RAMP_WIDTH: u32 = 64;
const INK: [u8; 3] = [0, 0, 0];
const PAPER: [u8; 3] = [255, 255, 255];

/// Half the size of a corner's cross and a post's square in the picture, pixels: a mark 5 pixels
/// wide, seen on a map of a thousand cells without covering a 5 cm post's neighbourhood.
const MARK_HALF: i64 = 2;

/// What goes into the picture besides the map.
#[derive(Debug, Clone, Copy, Default)]
pub struct PngOptions<'a> {
    /// A [`LEGEND_HEIGHT`]-pixel strip below the map: a scale bar with its length, the colour ramp
    /// from p = 0 to p = 1, and the colour of unknown cells. The picture is widened if the map is
    /// narrower than the legend. Without it (`sonar-export --no-legend`), the picture is exactly
    /// one pixel per cell.
    pub legend: bool,
    /// Walls, corners and posts to draw over the map in [`FEATURE_RGB`], those heard from one
    /// place only (tentative) in [`TENTATIVE_FEATURE_RGB`] (`sonar-export --features`, the
    /// viewer's `s` while its overlay is on): a wall as a line along its segment (a tick across
    /// its normal when its extent is unknown), a corner as a cross, a post as a square around its
    /// cell.
    pub features: Option<&'a [FeatureRecord]>,
}

/// The scale bar of a legend.
#[derive(Debug, Clone, PartialEq)]
pub struct ScaleBar {
    /// Length in metres: 1, 2 or 5 times a power of ten.
    pub metres: f64,
    /// Length in pixels (= cells), rounded: off by at most half a pixel.
    pub pixels: u32,
    /// The length as text, e.g. `2 m`, `50 cm`.
    pub label: String,
}

/// The longest round length (1, 2 or 5 × 10ⁿ m) that takes at most a third of the map's width, or
/// 20 pixels on a very narrow map.
pub fn scale_bar(resolution_m: f32, map_width_px: u32) -> ScaleBar {
    let res = f64::from(resolution_m);
    let max_m = (f64::from(map_width_px) / 3.0).max(20.0) * res;
    let k = max_m.log10().floor() as i32;
    let (mantissa, exponent) = [(5.0, k), (2.0, k), (1.0, k)]
        .into_iter()
        .find(|&(m, e)| m * 10f64.powi(e) <= max_m * (1.0 + 1e-9))
        .unwrap_or((5.0, k - 1));
    let metres = mantissa * 10f64.powi(exponent);
    let (unit, unit_exp) = match exponent {
        3.. => ("km", 3),
        0.. => ("m", 0),
        -2.. => ("cm", -2),
        _ => ("mm", -3),
    };
    let number = mantissa * 10f64.powi(exponent - unit_exp);
    ScaleBar {
        metres,
        pixels: ((metres / res).round() as u32).max(1),
        label: format!("{number} {unit}"),
    }
}

/// Encodes `map` as an 8-bit RGB PNG.
pub fn write_png<W: Write>(out: W, map: &Map<'_>, options: &PngOptions) -> Result<(), MapError> {
    let hd = map.header();
    let bar = options.legend.then(|| scale_bar(hd.resolution_m, hd.width));
    let mut comment = format!(
        "sonar occupancy map {}x{}, cells of {} m, lower-left corner at ({}, {}) m, \
         model {}, rule {}, {} readings fused; top row = highest y",
        hd.width,
        hd.height,
        hd.resolution_m,
        hd.origin_x_m,
        hd.origin_y_m,
        setting_name(MODELS, hd.model),
        setting_name(RULES, hd.rule),
        hd.readings_fused
    );
    let mut canvas = match &bar {
        None => Canvas::new(hd.width as usize, hd.height as usize, PAPER),
        Some(bar) => {
            comment.push_str(&format!(
                "; below the map a {LEGEND_HEIGHT}-pixel legend: scale bar of {} ({} pixels), \
                 colour ramp p = 0 to 1, unknown",
                bar.label, bar.pixels
            ));
            let width = hd.width.max(legend_width(bar));
            Canvas::new(width as usize, (hd.height + LEGEND_HEIGHT) as usize, PAPER)
        }
    };
    // Snapshot row 0 is the lowest y; image row 0 is the top.
    for (y, row) in map.rows_top_down().enumerate() {
        for (x, &cell) in row.iter().enumerate() {
            canvas.set(x, y, cell_rgb(cell));
        }
    }
    if let Some(records) = options.features {
        draw_features(&mut canvas, map, records);
        let count = |kind| records.iter().filter(|r| r.kind == kind).count();
        comment.push_str(&format!(
            "; features drawn over the map in green (RGB {FEATURE_RGB:?}): {} walls as lines, {} \
             corners as crosses, {} posts as squares; of them {} heard from one place only \
             (tentative) in amber (RGB {TENTATIVE_FEATURE_RGB:?})",
            count(feature_kind::PLANE),
            count(feature_kind::CORNER),
            count(feature_kind::POINT),
            records.iter().filter(|r| !r.is_confirmed()).count()
        ));
    }
    if let Some(bar) = &bar {
        draw_legend(&mut canvas, hd.height, bar);
    }

    // Maps are mostly flat areas: the fast setting compresses them well, in a blink.
    canvas.write_png(out, png::Compression::Fast, Some(&comment))
}

/// The features over the map: the pixels the viewer's overlay uses at one pixel per cell, a corner
/// and a post widened to a mark a reader can find; the tentative ones (heard from one place only)
/// in their own colour and first ([`overlay::tentative_then_confirmed`]). Marks
/// reaching over the map's edge are clipped to it, never drawn on the legend.
fn draw_features(canvas: &mut Canvas, map: &Map<'_>, records: &[FeatureRecord]) {
    for (confirmed, records) in overlay::tentative_then_confirmed(records) {
        let rgb = if confirmed {
            FEATURE_RGB
        } else {
            TENTATIVE_FEATURE_RGB
        };
        draw_feature_marks(canvas, map, &records, rgb);
    }
}

fn draw_feature_marks(canvas: &mut Canvas, map: &Map<'_>, records: &[FeatureRecord], rgb: [u8; 3]) {
    let hd = map.header();
    let (w, h) = (i64::from(hd.width), i64::from(hd.height));
    let mut set = |x: i64, y: i64| {
        if (0..w).contains(&x) && (0..h).contains(&y) {
            canvas.set(x as usize, y as usize, rgb);
        }
    };
    let viewport = Viewport::one_to_one(hd.width, hd.height);
    for (px, py, mark) in overlay::feature_pixels(records, hd, &viewport) {
        let (x, y) = (i64::from(px), i64::from(py));
        match mark {
            FeatureMark::Wall(_) => set(x, y),
            FeatureMark::Corner => {
                for d in -MARK_HALF..=MARK_HALF {
                    set(x + d, y + d);
                    set(x + d, y - d);
                }
            }
            FeatureMark::Post => {
                for d in -MARK_HALF..=MARK_HALF {
                    set(x + d, y - MARK_HALF);
                    set(x + d, y + MARK_HALF);
                    set(x - MARK_HALF, y + d);
                    set(x + MARK_HALF, y + d);
                }
            }
        }
    }
}

/// Writes `text` in ink with its top-left corner at (`x`, `y`).
fn draw_text(canvas: &mut Canvas, text: &str, x: u32, y: u32) {
    font::draw(text, x, y, TEXT_SCALE, |px, py| {
        canvas.set(px as usize, py as usize, INK);
    });
}

/// [`Canvas::fill`] in the legend's `u32` coordinates.
fn fill(canvas: &mut Canvas, x: u32, y: u32, w: u32, h: u32, rgb: [u8; 3]) {
    canvas.fill(x as usize, y as usize, w as usize, h as usize, rgb);
}

/// Left edges of the legend's parts: scale label, "0", ramp, "1", unknown swatch and its label;
/// and the legend's total width.
fn legend_layout(bar: &ScaleBar) -> [u32; 7] {
    let digit = font::text_width("0", TEXT_SCALE);
    let label = MARGIN + bar.pixels + 6;
    let zero = label + font::text_width(&bar.label, TEXT_SCALE) + 16;
    let ramp = zero + digit + 4;
    let one = ramp + RAMP_WIDTH + 4;
    let swatch = one + digit + 12;
    let unknown = swatch + TEXT_H + 4;
    let end = unknown + font::text_width("unknown", TEXT_SCALE) + MARGIN;
    [label, zero, ramp, one, swatch, unknown, end]
}

fn legend_width(bar: &ScaleBar) -> u32 {
    legend_layout(bar)[6]
}

/// Draws the legend into the strip starting at row `top`.
fn draw_legend(canvas: &mut Canvas, top: u32, bar: &ScaleBar) {
    let [label, zero, ramp, one, swatch, unknown, _] = legend_layout(bar);
    let text_y = top + TEXT_TOP;
    // The bar: 3 pixels thick, with end ticks the height of the text, exactly `pixels` wide.
    fill(canvas, MARGIN, text_y + 4, bar.pixels, 3, INK);
    fill(canvas, MARGIN, text_y, 1, TEXT_H, INK);
    fill(canvas, MARGIN + bar.pixels - 1, text_y, 1, TEXT_H, INK);
    draw_text(canvas, &bar.label, label, text_y);

    draw_text(canvas, "0", zero, text_y);
    for i in 0..RAMP_WIDTH {
        let cell = (f64::from(i) / f64::from(RAMP_WIDTH - 1) * 254.0).round() as u8;
        fill(canvas, ramp + i, text_y, 1, TEXT_H, cell_rgb(cell));
    }
    draw_text(canvas, "1", one, text_y);
    fill(canvas, swatch, text_y, TEXT_H, TEXT_H, UNKNOWN_RGB);
    draw_text(canvas, "unknown", unknown, text_y);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::test_grid;
    use sonar_common::ipc::{CELL_UNKNOWN, feature_flags};

    struct Decoded {
        width: u32,
        height: u32,
        pixels: Vec<u8>,
        comment: String,
    }

    impl Decoded {
        fn px(&self, x: u32, y: u32) -> [u8; 3] {
            let i = ((y * self.width + x) * 3) as usize;
            [self.pixels[i], self.pixels[i + 1], self.pixels[i + 2]]
        }
    }

    fn decode(bytes: &[u8]) -> Decoded {
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
            .read_info()
            .unwrap();
        let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut pixels).unwrap();
        let comment = reader.info().uncompressed_latin1_text[0].text.clone();
        Decoded {
            width: info.width,
            height: info.height,
            pixels,
            comment,
        }
    }

    fn png(options: PngOptions) -> Decoded {
        let h = test_grid::header();
        let map = Map::new(&h, &test_grid::CELLS).unwrap();
        let mut bytes = Vec::new();
        write_png(&mut bytes, &map, &options).unwrap();
        decode(&bytes)
    }

    #[test]
    fn one_pixel_per_cell_with_the_highest_row_on_top() {
        let img = png(PngOptions::default());
        assert_eq!((img.width, img.height), (3, 2));
        assert_eq!(img.px(0, 1), cell_rgb(0));
        assert_eq!(img.px(1, 1), cell_rgb(CELL_UNKNOWN));
        assert_eq!(img.px(2, 1), cell_rgb(254));
        assert_eq!(img.px(1, 0), cell_rgb(203));
        assert_eq!(
            img.comment,
            "sonar occupancy map 3x2, cells of 0.05 m, lower-left corner at (-0.075, -0.05) m, \
             model smooth, rule log-odds, 42 readings fused; top row = highest y"
        );
    }

    #[test]
    fn the_legend_adds_a_scale_bar_of_the_stated_length_below_the_unchanged_map() {
        let img = png(PngOptions {
            legend: true,
            ..PngOptions::default()
        });
        let bar = scale_bar(0.05, 3);
        // A 3-cell map is narrower than the legend: 20 pixels of 5 cm make 1 m.
        assert_eq!(
            (bar.metres, bar.pixels, bar.label.as_str()),
            (1.0, 20, "1 m")
        );
        assert_eq!(img.width, legend_width(&bar));
        assert_eq!(img.height, 2 + LEGEND_HEIGHT);
        let plain = png(PngOptions::default());
        for (x, y) in [(0, 0), (1, 0), (2, 0), (0, 1), (1, 1), (2, 1)] {
            assert_eq!(img.px(x, y), plain.px(x, y));
        }
        assert_eq!(img.px(3, 0), PAPER, "right of a narrow map");
        // The bar's middle row is ink over exactly `pixels` columns from the margin.
        let row = 2 + TEXT_TOP + 5;
        let inked: Vec<u32> = (0..img.width)
            .take_while(|&x| x < legend_layout(&bar)[0])
            .filter(|&x| img.px(x, row) == INK)
            .collect();
        assert_eq!(inked, (MARGIN..MARGIN + 20).collect::<Vec<_>>());
        assert!(img.comment.ends_with(
            "below the map a 24-pixel legend: scale bar of 1 m (20 pixels), colour ramp p = 0 to 1, unknown"
        ));
        // The ramp starts free and ends occupied; the swatch is the unknown colour.
        let [_, _, ramp, one, swatch, ..] = legend_layout(&bar);
        assert_eq!(img.px(ramp, row), cell_rgb(0));
        assert_eq!(img.px(one - 5, row), cell_rgb(254));
        assert_eq!(img.px(swatch + 1, row), UNKNOWN_RGB);
    }

    /// `sonar-export --features`: the viewer's overlay pixels in the picture, a wall as a line, a
    /// corner as a cross, a post as a square around its cell; nothing else changes, and marks at
    /// the edge stay on the map.
    #[test]
    fn features_are_drawn_over_the_map_as_the_viewer_places_them() {
        use sonar_common::ipc::{CELL_UNKNOWN, GridHeader};
        let header = GridHeader {
            width: 40,
            height: 30,
            resolution_m: 0.1,
            origin_x_m: -2.0,
            origin_y_m: -1.5,
            ..GridHeader::default()
        };
        let cells = vec![CELL_UNKNOWN; 1200];
        let map = Map::new(&header, &cells).unwrap();
        let nan = f32::NAN;
        let feature = |kind, x_m, y_m| FeatureRecord {
            kind,
            x_m,
            y_m,
            angle_deg: nan,
            segment_ax_m: nan,
            segment_ay_m: nan,
            segment_bx_m: nan,
            segment_by_m: nan,
            flags: feature_flags::CONFIRMED,
            ..FeatureRecord::default()
        };
        let records = [
            // A wall along y = 1.05 m (cell row 25, picture row 4) from x = -1.45 to 0.55 m.
            FeatureRecord {
                segment_ax_m: -1.45,
                segment_ay_m: 1.05,
                segment_bx_m: 0.55,
                segment_by_m: 1.05,
                ..feature(feature_kind::PLANE, 0.0, 0.0)
            },
            // A corner at cell (30, 10), picture (30, 19); a post at cell (10, 10), picture
            // (10, 19), heard from one place only; a post on the top-right corner cell, picture
            // (39, 0).
            feature(feature_kind::CORNER, 1.05, -0.45),
            FeatureRecord {
                flags: 0,
                ..feature(feature_kind::POINT, -0.95, -0.45)
            },
            feature(feature_kind::POINT, 1.95, 1.45),
        ];
        let mut bytes = Vec::new();
        let options = PngOptions {
            legend: true,
            features: Some(&records),
        };
        write_png(&mut bytes, &map, &options).unwrap();
        let img = decode(&bytes);
        let mut plain_bytes = Vec::new();
        let plain = PngOptions {
            legend: true,
            features: None,
        };
        write_png(&mut plain_bytes, &map, &plain).unwrap();
        let plain = decode(&plain_bytes);
        assert_eq!((img.width, img.height), (plain.width, plain.height));

        let of_colour = |rgb| -> Vec<(u32, u32)> {
            (0..img.height)
                .flat_map(|y| (0..img.width).map(move |x| (x, y)))
                .filter(|&(x, y)| img.px(x, y) == rgb)
                .collect()
        };
        let mut expected: Vec<(u32, u32)> = (5..=25).map(|x| (x, 4)).collect();
        let mut tentative = Vec::new();
        for d in -2i32..=2 {
            expected.push(((30 + d) as u32, (19 + d) as u32));
            expected.push(((30 + d) as u32, (19 - d) as u32));
            for (x, y) in [(10 + d, 17), (10 + d, 21), (8, 19 + d), (12, 19 + d)] {
                tentative.push((x as u32, y as u32));
            }
            // The edge post: only the parts of its square inside the map.
            for (x, y) in [(39 + d, -2), (39 + d, 2), (37, d), (41, d)] {
                if (0..40).contains(&x) && (0..30).contains(&y) {
                    expected.push((x as u32, y as u32));
                }
            }
        }
        for marks in [&mut expected, &mut tentative] {
            marks.sort_by_key(|&(x, y)| (y, x));
            marks.dedup();
        }
        assert_eq!(of_colour(FEATURE_RGB), expected);
        assert_eq!(of_colour(TENTATIVE_FEATURE_RGB), tentative);
        expected.extend(tentative);
        // Every other pixel is the plain picture's, the legend included.
        for y in 0..img.height {
            for x in 0..img.width {
                if !expected.contains(&(x, y)) {
                    assert_eq!(img.px(x, y), plain.px(x, y), "({x}, {y})");
                }
            }
        }
        assert!(
            img.comment
                .contains("1 walls as lines, 1 corners as crosses, 2 posts as squares; of them 1 heard from one place only (tentative)"),
            "{}",
            img.comment
        );
    }

    #[test]
    fn scale_bars_are_round_lengths_up_to_a_third_of_the_map() {
        let cases = [
            (0.02, 400, 2.0, 100, "2 m"),
            (0.05, 400, 5.0, 100, "5 m"),
            (0.01, 800, 2.0, 200, "2 m"),
            (0.01, 400, 1.0, 100, "1 m"),
            (0.005, 400, 0.5, 100, "50 cm"),
            (0.001, 300, 0.1, 100, "10 cm"),
            (0.03, 400, 2.0, 67, "2 m"),
            (0.0001, 100, 0.002, 20, "2 mm"),
            (2.0, 3000, 2000.0, 1000, "2 km"),
        ];
        for (res, width, metres, pixels, label) in cases {
            let bar = scale_bar(res, width);
            assert!(
                (bar.metres - metres).abs() < 1e-9 * metres,
                "{res} {width}: {bar:?}"
            );
            assert_eq!(
                (bar.pixels, bar.label.as_str()),
                (pixels, label),
                "{res} {width}"
            );
        }
    }
}
