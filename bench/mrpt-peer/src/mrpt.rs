//! MRPT's `COccupancyGridMap2D` through the C shim (`shim/mrpt_peer.cpp`).

use std::ffi::{CStr, c_char, c_double, c_float, c_int, c_uint};
use std::ptr::NonNull;

use anyhow::{Result, bail};
use sonar_fusion::GridGeometry;

/// The shim's grid and its reusable observation.
#[repr(C)]
struct RawGrid {
    _opaque: [u8; 0],
}

unsafe extern "C" {
    fn mrpt_peer_grid_new(
        x_min: c_float,
        x_max: c_float,
        y_min: c_float,
        y_max: c_float,
        resolution: c_float,
        max_range_m: c_float,
        aperture_rad: c_float,
        err: *mut c_char,
        err_len: usize,
    ) -> *mut RawGrid;
    fn mrpt_peer_grid_free(grid: *mut RawGrid);
    fn mrpt_peer_grid_insert(
        grid: *mut RawGrid,
        x: c_double,
        y: c_double,
        yaw_rad: c_double,
        range_m: c_float,
    ) -> c_int;
    fn mrpt_peer_grid_clear(grid: *mut RawGrid);
    fn mrpt_peer_grid_size_x(grid: *const RawGrid) -> c_uint;
    fn mrpt_peer_grid_size_y(grid: *const RawGrid) -> c_uint;
    fn mrpt_peer_grid_read(
        grid: *const RawGrid,
        x0: c_float,
        y0: c_float,
        resolution: c_float,
        n: usize,
        out: *mut c_float,
    );
}

/// An MRPT occupancy grid over the same square as one of ours, fed sonar cones.
#[derive(Debug)]
pub struct MrptGrid {
    raw: NonNull<RawGrid>,
    /// MRPT 2.5 draws a range observation's cone from yaw − aperture to yaw (not centred on
    /// the yaw): every reading's yaw is offset by this, half the aperture, to centre it.
    half_aperture_rad: f64,
}

impl MrptGrid {
    /// A grid covering `geometry`'s square with its cells, for cones of `aperture_rad` (full
    /// width) reaching `max_range_m`; a reading at or beyond that range inserts nothing.
    pub fn new(geometry: &GridGeometry, max_range_m: f32, aperture_rad: f32) -> Result<Self> {
        let origin = geometry.origin();
        let side = geometry.cells_per_side() as f32 * geometry.resolution();
        let mut err = [0 as c_char; 256];
        // SAFETY: plain values and a buffer of the length given; the shim catches every C++
        // exception and returns null with the message in `err`.
        let raw = unsafe {
            mrpt_peer_grid_new(
                origin.x,
                origin.x + side,
                origin.y,
                origin.y + side,
                geometry.resolution(),
                max_range_m,
                aperture_rad,
                err.as_mut_ptr(),
                err.len(),
            )
        };
        let Some(raw) = NonNull::new(raw) else {
            // SAFETY: the shim wrote a NUL-terminated message within the buffer.
            let message = unsafe { CStr::from_ptr(err.as_ptr()) };
            bail!("MRPT grid not created: {}", message.to_string_lossy());
        };
        let grid = Self {
            raw,
            half_aperture_rad: f64::from(aperture_rad) / 2.0,
        };
        let (x, y) = grid.size();
        let n = geometry.cells_per_side();
        if (x, y) != (n, n) {
            bail!("MRPT made a {x} × {y} grid for our {n} × {n}");
        }
        Ok(grid)
    }

    /// Inserts a reading taken at (`x`, `y`) whose beam axis points at `bearing_rad` (world),
    /// `range_m` away (at or beyond the maximum range: no echo, nothing inserted). Returns
    /// whether MRPT inserted it.
    #[inline(never)]
    pub fn insert(&mut self, x: f64, y: f64, bearing_rad: f64, range_m: f32) -> Result<bool> {
        // SAFETY: `raw` is a live grid owned by `self`; the shim catches C++ exceptions.
        let inserted = unsafe {
            mrpt_peer_grid_insert(
                self.raw.as_ptr(),
                x,
                y,
                bearing_rad + self.half_aperture_rad,
                range_m,
            )
        };
        match inserted {
            1 => Ok(true),
            0 => Ok(false),
            _ => bail!("MRPT threw while inserting a range observation"),
        }
    }

    /// Every cell back to the prior, size kept.
    pub fn clear(&mut self) {
        // SAFETY: `raw` is a live grid owned by `self`.
        unsafe { mrpt_peer_grid_clear(self.raw.as_ptr()) }
    }

    /// Cells in x and y: MRPT grows its grid when a reading comes near the edge.
    pub fn size(&self) -> (usize, usize) {
        // SAFETY: `raw` is a live grid owned by `self`.
        unsafe {
            (
                mrpt_peer_grid_size_x(self.raw.as_ptr()) as usize,
                mrpt_peer_grid_size_y(self.raw.as_ptr()) as usize,
            )
        }
    }

    /// MRPT's occupancy probability at the centre of each cell of `geometry`, row-major from the
    /// lowest y (our grid's layout); 0.5 where MRPT's grid does not reach. (MRPT stores the
    /// probability of a cell being free; the shim turns it round.)
    pub fn probabilities(&self, geometry: &GridGeometry) -> Vec<f32> {
        let n = geometry.cells_per_side();
        let origin = geometry.origin();
        let mut out = vec![0.5; n * n];
        // SAFETY: `out` holds n × n floats, which is what the shim writes.
        unsafe {
            mrpt_peer_grid_read(
                self.raw.as_ptr(),
                origin.x,
                origin.y,
                geometry.resolution(),
                n,
                out.as_mut_ptr(),
            );
        }
        out
    }
}

impl Drop for MrptGrid {
    fn drop(&mut self) {
        // SAFETY: `raw` came from `mrpt_peer_grid_new` and is freed once, here.
        unsafe { mrpt_peer_grid_free(self.raw.as_ptr()) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// MRPT's cells of a 60° cone to 2 m along +x, as (bearing of the cell centre in degrees,
    /// distance, probability), for the cells MRPT changed.
    fn cone_cells(bearing_rad: f64) -> Vec<(f64, f64, f32)> {
        let geometry = GridGeometry::new(400, 0.02);
        let mut grid = MrptGrid::new(&geometry, 4.0, 60f32.to_radians()).unwrap();
        assert!(grid.insert(0.0, 0.0, bearing_rad, 2.0).unwrap());
        let n = geometry.cells_per_side();
        grid.probabilities(&geometry)
            .into_iter()
            .enumerate()
            .filter(|&(_, p)| p != 0.5)
            .map(|(i, p)| {
                let c = geometry.cell_centre(i % n, i / n);
                let (x, y) = (f64::from(c.x), f64::from(c.y));
                ((y.atan2(x) - bearing_rad).to_degrees(), x.hypot(y), p)
            })
            .collect()
    }

    #[test]
    fn the_cone_is_centred_on_the_bearing() {
        for bearing_deg in [0.0f64, 90.0, -135.0] {
            let cells = cone_cells(bearing_deg.to_radians());
            // Away from the apex, where a cell's centre can lie at any bearing.
            let bearings: Vec<f64> = cells
                .iter()
                .filter(|c| c.1 > 0.3)
                .map(|c| (c.0 + 540.0).rem_euclid(360.0) - 180.0)
                .collect();
            let lo = bearings.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = bearings.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            // ±30°, to within the cells' size.
            assert!((-33.0..=-29.0).contains(&lo), "{bearing_deg}°: from {lo}°");
            assert!((29.0..=33.0).contains(&hi), "{bearing_deg}°: to {hi}°");
            // Occupied only along the far edge, MRPT's chord between the cone's ends at 2 m
            // (2 cos 30° = 1.73 m from the sensor in its middle), free before it.
            // The chord is 2 m long: 70 (diagonal) to 100 (along an axis) steps of 2 cm cells.
            let occupied = cells.iter().filter(|c| c.2 > 0.5).count();
            assert!(
                (65..=200).contains(&occupied),
                "{bearing_deg}°: {occupied} occupied"
            );
            for &(_, r, p) in &cells {
                if p > 0.5 {
                    assert!(r > 1.55 && r < 2.1, "{bearing_deg}°: occupied at {r} m");
                } else if r < 1.5 {
                    assert!(p < 0.5);
                }
            }
        }
    }

    #[test]
    fn a_reading_at_the_maximum_range_inserts_nothing() {
        let geometry = GridGeometry::new(100, 0.05);
        let mut grid = MrptGrid::new(&geometry, 4.0, 60f32.to_radians()).unwrap();
        grid.insert(0.0, 0.0, 0.0, 4.0).unwrap();
        assert!(grid.probabilities(&geometry).iter().all(|&p| p == 0.5));
        grid.insert(0.0, 0.0, 0.0, 1.0).unwrap();
        assert!(grid.probabilities(&geometry).iter().any(|&p| p != 0.5));
        grid.clear();
        assert!(grid.probabilities(&geometry).iter().all(|&p| p == 0.5));
    }
}
