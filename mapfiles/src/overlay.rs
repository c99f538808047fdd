//! The walls, corners and posts of a `sonar/features` snapshot drawn over the map: which pixels of
//! a picture ([`Viewport`]) show them and how. The terminal viewer draws these pixels as glyphs,
//! the PNG ([`picture`](crate::picture)) as coloured marks, so both show the same overlay.

use sonar_common::ipc::{FeatureRecord, GridHeader, feature_kind};

use crate::viewport::Viewport;

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
    pub fn of(dx: f64, dy: f64) -> Self {
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

/// The records apart by [`FeatureRecord::is_confirmed`], in the order an overlay draws them: the
/// tentative ones (heard from one place only, `false`) first, so that a confirmed feature's mark is
/// drawn over one beside it.
pub fn tentative_then_confirmed(records: &[FeatureRecord]) -> [(bool, Vec<FeatureRecord>); 2] {
    [false, true].map(|confirmed| {
        let subset = records
            .iter()
            .filter(|r| r.is_confirmed() == confirmed)
            .copied()
            .collect();
        (confirmed, subset)
    })
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

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::viewport::MAX_PIXELS_PER_CELL;
    use proptest::prelude::*;

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
}
