//! Where the cells are: the square grid centred on the world origin, and the polar coordinates of a
//! cell as seen from the sensor.
//!
//! Every kernel (the paper-style whole-grid pass, the cone stencil and the bounding-box fallback)
//! obtains a cell's range and bearing from [`SensorCell::polar`], with the same operands in the
//! same order, so the kernels agree to the last bit and their grids can be compared exactly.

use std::f32::consts::{PI, TAU};

use nalgebra::{Point2, Vector2};

/// A square grid of `cells × cells` cells of `resolution` metres, centred on the world origin (the
/// sensor's position when the robot does not move). Row-major, row 0 at the lowest y and column 0
/// at the lowest x, as in ROS `OccupancyGrid` and `sonar_common::ipc::GridHeader`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridGeometry {
    cells: usize,
    resolution: f32,
    origin: Vector2<f32>,
}

impl GridGeometry {
    /// The grid of `cells` cells per side of `resolution` metres. The caller has validated both
    /// (see [`crate::config::GridConfig`]).
    pub fn new(cells: usize, resolution: f32) -> Self {
        Self::centred_at(cells, resolution, Vector2::zeros())
    }

    /// [`Self::new`] with the grid's centre at `centre` instead of the world's origin.
    pub fn centred_at(cells: usize, resolution: f32, centre: Vector2<f32>) -> Self {
        let half = cells as f32 * resolution / 2.0;
        Self {
            cells,
            resolution,
            origin: centre - Vector2::new(half, half),
        }
    }

    /// Cells per side.
    pub fn cells_per_side(&self) -> usize {
        self.cells
    }

    /// Cells in the grid.
    pub fn len(&self) -> usize {
        self.cells * self.cells
    }

    /// Always false: a valid grid has at least one cell. Present because `len` is.
    pub fn is_empty(&self) -> bool {
        self.cells == 0
    }

    /// Cell edge, metres.
    pub fn resolution(&self) -> f32 {
        self.resolution
    }

    /// World position of the outer corner of cell (0, 0).
    pub fn origin(&self) -> Vector2<f32> {
        self.origin
    }

    /// Index of cell (`x`, `y`) in the row-major cell arrays.
    pub fn index(&self, x: usize, y: usize) -> usize {
        y * self.cells + x
    }

    /// World position of the centre of cell (`x`, `y`).
    pub fn cell_centre(&self, x: usize, y: usize) -> Point2<f32> {
        Point2::new(
            self.origin.x + (x as f32 + 0.5) * self.resolution,
            self.origin.y + (y as f32 + 0.5) * self.resolution,
        )
    }

    /// The cell containing world point `p`, if it lies on the grid.
    pub fn cell_at(&self, p: Point2<f32>) -> Option<(usize, usize)> {
        let u = (p.coords - self.origin) / self.resolution;
        let n = self.cells as f32;
        (u.x >= 0.0 && u.y >= 0.0 && u.x < n && u.y < n).then(|| (u.x as usize, u.y as usize))
    }

    /// Where a sensor at world position `p` sits relative to the cells.
    pub(crate) fn sensor_cell(&self, p: Vector2<f32>) -> SensorCell {
        // Continuous cell coordinates: cell i spans [i, i + 1). Splitting them into an integer cell
        // and a fraction is exact in f32, so a sensor that stays put (or returns to a position a
        // whole number of cells away, when that sum is exact) gets the same fraction bit for bit:
        // that is what lets one cone stencil serve every reading taken there.
        let u = (p - self.origin) / self.resolution;
        let (cx, cy) = (u.x.floor(), u.y.floor());
        SensorCell {
            cell: [cx as i64, cy as i64],
            to_centre: [0.5 - (u.x - cx), 0.5 - (u.y - cy)],
            resolution: self.resolution,
        }
    }
}

/// The sensor's position in cell units: the cell it is in (possibly off the grid) and the vector
/// from the sensor to that cell's centre, in cells.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SensorCell {
    pub cell: [i64; 2],
    pub to_centre: [f32; 2],
    resolution: f32,
}

impl SensorCell {
    /// Range (metres) and bearing (radians, counter-clockwise from the world x axis, in [−π, π]) of
    /// the centre of the cell `offset` cells away from the sensor's cell.
    #[inline(always)]
    pub fn polar(&self, offset_x: i64, offset_y: i64) -> (f32, f32) {
        let dx = offset_x as f32 + self.to_centre[0];
        let dy = offset_y as f32 + self.to_centre[1];
        ((dx * dx + dy * dy).sqrt() * self.resolution, dy.atan2(dx))
    }

    /// Cell edge, metres.
    pub fn resolution(&self) -> f32 {
        self.resolution
    }

    /// Bit pattern of the sub-cell position: equal for positions a whole number of cells apart.
    pub fn fraction_bits(&self) -> [u32; 2] {
        self.to_centre.map(f32::to_bits)
    }
}

/// `angle` wrapped into [−π, π].
pub(crate) fn wrap_angle(angle: f32) -> f32 {
    angle - TAU * (angle / TAU).round()
}

/// Signed angle of bearing `bearing` off the beam axis `axis`, both in [−π, π]; the difference is
/// brought back into [−π, π] with selects rather than a division so the kernels' loops vectorise.
#[inline(always)]
pub(crate) fn off_axis(bearing: f32, axis: f32) -> f32 {
    let d = bearing - axis;
    let d = if d > PI { d - TAU } else { d };
    if d < -PI { d + TAU } else { d }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_grid_is_centred_on_the_origin() {
        let g = GridGeometry::new(400, 0.02);
        assert_eq!(g.origin(), Vector2::new(-4.0, -4.0));
        assert_eq!(g.cell_at(Point2::new(0.001, 0.001)), Some((200, 200)));
        assert_eq!(g.cell_at(Point2::new(-0.001, -0.001)), Some((199, 199)));
        assert_eq!(g.cell_at(Point2::new(4.1, 0.0)), None);
        let c = g.cell_centre(200, 199);
        assert!((c.x - 0.01).abs() < 1e-6 && (c.y + 0.01).abs() < 1e-6);
    }

    #[test]
    fn a_grid_centred_elsewhere_is_shifted_whole() {
        let g = GridGeometry::centred_at(400, 0.02, Vector2::new(3.0, 1.5));
        assert_eq!(g.origin(), Vector2::new(-1.0, -2.5));
        assert_eq!(g.cell_at(Point2::new(3.001, 1.501)), Some((200, 200)));
        assert_eq!(g.cell_at(Point2::new(-1.01, 0.0)), None);
        assert_eq!(g.cell_at(Point2::new(6.99, 5.49)), Some((399, 399)));
    }

    #[test]
    fn polar_of_cells_around_a_sensor_on_a_corner() {
        let g = GridGeometry::new(4, 1.0);
        let s = g.sensor_cell(Vector2::zeros());
        assert_eq!(s.cell, [2, 2]);
        let (r, a) = s.polar(0, 0);
        assert!((r - 0.5f32.hypot(0.5)).abs() < 1e-6);
        assert!((a - PI / 4.0).abs() < 1e-6);
        let (_, a) = s.polar(-1, -1);
        assert!((a + 3.0 * PI / 4.0).abs() < 1e-6);
    }

    #[test]
    fn whole_cell_moves_keep_the_fraction() {
        // Binary fractions keep the arithmetic exact, so the fraction survives the move.
        let g = GridGeometry::new(64, 0.25);
        let a = g.sensor_cell(Vector2::new(0.125, -0.0625));
        let b = g.sensor_cell(Vector2::new(0.125 + 1.5, -0.0625 - 0.75));
        assert_eq!(a.fraction_bits(), b.fraction_bits());
        assert_eq!([b.cell[0] - a.cell[0], b.cell[1] - a.cell[1]], [6, -3]);
        let c = g.sensor_cell(Vector2::new(0.1, -0.0625));
        assert_ne!(a.fraction_bits(), c.fraction_bits());
    }

    #[test]
    fn off_axis_wraps_across_the_back() {
        assert!((off_axis(3.0, -3.0) - (6.0 - TAU)).abs() < 1e-6);
        assert!((off_axis(-3.0, 3.0) - (TAU - 6.0)).abs() < 1e-6);
        assert!((off_axis(0.25, -0.25) - 0.5).abs() < 1e-6);
        assert!((wrap_angle(7.0) - (7.0 - TAU)).abs() < 1e-6);
    }
}
