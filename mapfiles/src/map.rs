//! A checked view of one grid snapshot, and why a map could not be written.

use std::path::PathBuf;

use sonar_common::ipc::{GridHeader, decode_probability};

/// Why a map could not be written.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    #[error("the grid header says {width} × {height} cells but the snapshot has {len}")]
    CellCount { width: u32, height: u32, len: usize },
    #[error("the grid is empty ({width} × {height} cells)")]
    Empty { width: u32, height: u32 },
    #[error("the grid header's {field} is {value}, which is not a usable value")]
    Geometry { field: &'static str, value: f32 },
    #[error("cannot write {}: {source}", path.display())]
    File {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error("a {width} × {height}-pixel picture is too large for PNG")]
    PictureSize { width: usize, height: usize },
    #[error("PNG encoding failed: {0}")]
    Png(#[from] png::EncodingError),
}

/// A checked view of one grid snapshot: the header's size matches the cells, the geometry is
/// finite. Borrowing, so a consumer can write straight from the shared-memory sample.
#[derive(Debug, Clone, Copy)]
pub struct Map<'a> {
    header: &'a GridHeader,
    cells: &'a [u8],
}

impl<'a> Map<'a> {
    pub fn new(header: &'a GridHeader, cells: &'a [u8]) -> Result<Self, MapError> {
        let (width, height) = (header.width, header.height);
        if width == 0 || height == 0 {
            return Err(MapError::Empty { width, height });
        }
        if (width as usize).checked_mul(height as usize) != Some(cells.len()) {
            return Err(MapError::CellCount {
                width,
                height,
                len: cells.len(),
            });
        }
        let res = header.resolution_m;
        if !(res.is_finite() && res > 0.0) {
            return Err(MapError::Geometry {
                field: "resolution_m",
                value: res,
            });
        }
        for (field, value) in [
            ("origin_x_m", header.origin_x_m),
            ("origin_y_m", header.origin_y_m),
        ] {
            if !value.is_finite() {
                return Err(MapError::Geometry { field, value });
            }
        }
        Ok(Self { header, cells })
    }

    pub fn header(&self) -> &'a GridHeader {
        self.header
    }

    /// All cells, row 0 (lowest y) first.
    pub fn cells(&self) -> &'a [u8] {
        self.cells
    }

    pub fn width(&self) -> usize {
        self.header.width as usize
    }

    pub fn height(&self) -> usize {
        self.header.height as usize
    }

    /// Row `y` of the grid (y = 0 is the lowest).
    pub fn row(&self, y: usize) -> &'a [u8] {
        &self.cells[y * self.width()..(y + 1) * self.width()]
    }

    /// The rows from the highest y down: the order of image files, whose first row is the top.
    pub fn rows_top_down(&self) -> impl Iterator<Item = &'a [u8]> + use<'a> {
        self.cells.chunks_exact(self.width()).rev()
    }

    /// Occupancy probability of cell (`x`, `y`); `None` if never observed.
    pub fn probability(&self, x: usize, y: usize) -> Option<f32> {
        decode_probability(self.row(y)[x])
    }
}

#[cfg(test)]
pub(crate) mod test_grid {
    use sonar_common::ipc::{CELL_UNKNOWN, GridHeader, LAYOUT_VERSION, model_code, rule_code};

    /// 3 × 2 cells of 5 cm, lower-left corner at (-0.075, -0.05) m:
    /// bottom row (y = 0) free, unknown, occupied; top row (y = 1) even odds, 0.8, 0.1.
    pub fn header() -> GridHeader {
        GridHeader {
            seq: 7,
            readings_fused: 42,
            layout_version: LAYOUT_VERSION,
            width: 3,
            height: 2,
            resolution_m: 0.05,
            origin_x_m: -0.075,
            origin_y_m: -0.05,
            model: model_code::SMOOTH,
            rule: rule_code::LOG_ODDS,
            ..GridHeader::default()
        }
    }

    pub const CELLS: [u8; 6] = [0, CELL_UNKNOWN, 254, 127, 203, 25];
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The offsets `docs/ipc.md` documents and the Python example maps.
    #[test]
    fn grid_header_layout_matches_the_documentation() {
        use std::mem::{align_of, offset_of, size_of};
        assert_eq!((size_of::<GridHeader>(), align_of::<GridHeader>()), (88, 8));
        let offsets = [
            offset_of!(GridHeader, seq),
            offset_of!(GridHeader, stamp_ns),
            offset_of!(GridHeader, readings_fused),
            offset_of!(GridHeader, layout_version),
            offset_of!(GridHeader, width),
            offset_of!(GridHeader, height),
            offset_of!(GridHeader, resolution_m),
            offset_of!(GridHeader, origin_x_m),
            offset_of!(GridHeader, origin_y_m),
            offset_of!(GridHeader, pose_x_m),
            offset_of!(GridHeader, pose_y_m),
            offset_of!(GridHeader, pose_theta_rad),
            offset_of!(GridHeader, model),
            offset_of!(GridHeader, rule),
            offset_of!(GridHeader, preset),
            offset_of!(GridHeader, sweep_id),
            offset_of!(GridHeader, occupied_cells),
            offset_of!(GridHeader, free_cells),
            offset_of!(GridHeader, unknown_cells),
        ];
        let documented = [
            0, 8, 16, 24, 28, 32, 36, 40, 44, 48, 52, 56, 60, 64, 68, 72, 76, 80, 84,
        ];
        assert_eq!(offsets, documented);
    }

    #[test]
    fn a_map_checks_its_header_against_the_cells() {
        let h = test_grid::header();
        let map = Map::new(&h, &test_grid::CELLS).unwrap();
        assert_eq!(map.row(1), &[127, 203, 25]);
        assert_eq!(map.rows_top_down().next(), Some(&[127u8, 203, 25][..]));
        assert_eq!(map.probability(1, 0), None);
        assert_eq!(map.probability(2, 0), Some(1.0));

        assert!(matches!(
            Map::new(&h, &test_grid::CELLS[..5]),
            Err(MapError::CellCount { len: 5, .. })
        ));
        let empty = GridHeader { width: 0, ..h };
        assert!(matches!(Map::new(&empty, &[]), Err(MapError::Empty { .. })));
        let flat = GridHeader {
            resolution_m: 0.0,
            ..h
        };
        assert!(matches!(
            Map::new(&flat, &test_grid::CELLS),
            Err(MapError::Geometry {
                field: "resolution_m",
                ..
            })
        ));
        let lost = GridHeader {
            origin_y_m: f32::NAN,
            ..h
        };
        assert!(Map::new(&lost, &test_grid::CELLS).is_err());
    }
}
