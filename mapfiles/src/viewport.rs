//! Which grid cells each pixel of a picture of the map shows (zoom and pan), in continuous grid
//! coordinates: shared by the terminal viewer, which zooms and pans, and the PNG writer
//! ([`picture`](crate::picture)), whose picture is the whole grid at one pixel per cell, so that the
//! features overlay ([`overlay`](crate::overlay)) lands on the same pixels in both.

use std::ops::Range;

/// Closest zoom: one grid cell spans at most this many pixels per axis.
pub const MAX_PIXELS_PER_CELL: f64 = 8.0;

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

    /// The whole grid at one pixel per cell, as the PNG draws it.
    pub fn one_to_one(grid_w: u32, grid_h: u32) -> Self {
        Self {
            left: 0.0,
            top: 0.0,
            scale: 1.0,
            width_px: grid_w,
            height_px: grid_h,
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
/// The cells pixel `i` covers, unclipped: [floor(start + i·s), floor(start + (i+1)·s)), at least
/// one cell. Neighbours share their bounds, so the pixels tile the grid without gaps: no cell is
/// ever skipped, whatever the scale. Zoomed in (s < 1), a pixel covers the cell under its left edge.
pub fn pixel_cells(i: u32, start: f64, scale: f64) -> Range<i64> {
    let a = (start + f64::from(i) * scale).floor() as i64;
    let b = ((start + f64::from(i + 1) * scale).floor() as i64).max(a + 1);
    a..b
}

/// The first of the `count` pixels whose [`pixel_cells`] contain `cell`. Estimated by inverting the
/// formula, then settled with the formula itself so that rounding can never make the two disagree.
/// Pixel 0 is the candidate when the cell's first pixels lie left of (above) the picture.
pub fn pixel_index(cell: i64, start: f64, scale: f64, count: u32) -> Option<u32> {
    let estimate = ((cell as f64 - start) / scale).floor() as i64;
    (estimate - 1..=estimate + 1)
        .chain([0])
        .filter_map(|i| u32::try_from(i).ok())
        .filter(|&i| i < count)
        .find(|&i| pixel_cells(i, start, scale).contains(&cell))
}
