//! The map for ROS navigation: a `map_server` map, i.e. a PGM picture plus a YAML file with the
//! resolution, the origin and the thresholds that turn grey levels back into occupancy.
//!
//! The picture is trinary, as `map_saver` writes it: occupied cells black (0), free cells white
//! (254), unknown ones grey (205). `map_server` reads a pixel `v` as occupancy `(255 − v) / 255`
//! (`negate: 0`), occupied above `occupied_thresh`, free below `free_thresh`, unknown in between;
//! grey 205 reads as 50/255 = 0.19608, just above `free_thresh` 0.196, so unknown stays unknown.
//! Our cells are classified with the same thresholds: p > 0.65 occupied, p < 0.196 free; the
//! occupied threshold can be set higher or lower ([`Thresholds::occupied_above`]), and the YAML
//! says which.
//!
//! Orientation: PGM rows run top-down, so the picture's first row is the grid's highest row; the
//! YAML `origin` is the world position of the lower-left corner of the picture, which is the
//! corner of grid cell (0, 0) (`origin_x_m`, `origin_y_m`), with yaw 0.

use std::io::Write;

use sonar_common::ipc::decode_probability;

use crate::map::{Map, MapError};

/// Cells with p above this are occupied (`occupied_thresh` in the YAML), unless told otherwise:
/// what `map_saver` writes.
pub const OCCUPIED_THRESH: f32 = 0.65;
/// Cells with p below this are free (`free_thresh` in the YAML).
pub const FREE_THRESH: f32 = 0.196;
pub const PGM_OCCUPIED: u8 = 0;
pub const PGM_FREE: u8 = 254;
pub const PGM_UNKNOWN: u8 = 205;

/// The occupancy thresholds a ROS map is written with: cells above `occupied` black, below
/// `free` white, grey between.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thresholds {
    occupied: f32,
    free: f32,
}

impl Default for Thresholds {
    fn default() -> Self {
        Self {
            occupied: OCCUPIED_THRESH,
            free: FREE_THRESH,
        }
    }
}

/// An occupied threshold the map cannot be written with.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "occupied threshold {0} out of range: it must lie from 0.5 to 0.99 (cells more likely \
     occupied than not, below certainty; 0.65 is what map_saver writes)"
)]
pub struct ThresholdOutOfRange(pub f32);

impl Thresholds {
    /// Cells counted occupied above `p` (0.5 to 0.99), free below [`FREE_THRESH`]: the grey of
    /// unknown cells (0.196) stays between them.
    pub fn occupied_above(p: f32) -> Result<Self, ThresholdOutOfRange> {
        if (0.5..=0.99).contains(&p) {
            Ok(Self {
                occupied: p,
                free: FREE_THRESH,
            })
        } else {
            Err(ThresholdOutOfRange(p))
        }
    }

    pub fn occupied(&self) -> f32 {
        self.occupied
    }

    /// The PGM grey level of a snapshot cell value.
    pub fn pgm_value(&self, cell: u8) -> u8 {
        match decode_probability(cell) {
            Some(p) if p > self.occupied => PGM_OCCUPIED,
            Some(p) if p < self.free => PGM_FREE,
            _ => PGM_UNKNOWN,
        }
    }
}

/// Writes `map` as a binary PGM (P5, maxval 255), first row = highest y, its cells classified by
/// `thresholds`.
pub fn write_pgm<W: Write>(
    mut out: W,
    map: &Map<'_>,
    thresholds: &Thresholds,
) -> Result<(), MapError> {
    let h = map.header();
    write!(
        out,
        "P5\n# CREATOR: sonar-export {} m/pix\n{} {}\n255\n",
        h.resolution_m, h.width, h.height
    )?;
    let mut line = Vec::with_capacity(map.width());
    for row in map.rows_top_down() {
        line.clear();
        line.extend(row.iter().map(|&c| thresholds.pgm_value(c)));
        out.write_all(&line)?;
    }
    out.flush()?;
    Ok(())
}

/// The `map_server` YAML for `map`, whose picture is `image` (a path relative to the YAML file's
/// directory, normally just the PGM's file name), written with `thresholds`.
pub fn map_yaml(map: &Map<'_>, image: &str, thresholds: &Thresholds) -> String {
    let h = map.header();
    format!(
        "# sonar occupancy map ({w} x {hgt} cells, {n} readings fused). Load it with\n\
         #   ros2 run nav2_map_server map_server --ros-args -p yaml_filename:=<this file>\n\
         image: {image}\n\
         mode: trinary\n\
         resolution: {res}\n\
         origin: [{ox}, {oy}, 0.0]\n\
         negate: 0\n\
         occupied_thresh: {occ}\n\
         free_thresh: {free}\n",
        w = h.width,
        hgt = h.height,
        n = h.readings_fused,
        image = yaml_string(image),
        res = yaml_float(h.resolution_m),
        ox = yaml_float(h.origin_x_m),
        oy = yaml_float(h.origin_y_m),
        occ = yaml_float(thresholds.occupied),
        free = yaml_float(thresholds.free),
    )
}

/// The shortest decimal that reads back as the same `f32`, always with a fraction part (so YAML
/// sees a float, not an integer).
fn yaml_float(v: f32) -> String {
    let s = v.to_string();
    if s.contains(['.', 'e', 'E']) || !v.is_finite() {
        s
    } else {
        format!("{s}.0")
    }
}

/// A YAML scalar for a file name: plain when that is unambiguous, else double-quoted.
fn yaml_string(s: &str) -> String {
    let plain = !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "._-/+".contains(c))
        && !s.starts_with(['-', '.']);
    if plain {
        s.to_owned()
    } else {
        let escaped: String = s
            .chars()
            .flat_map(|c| match c {
                '"' | '\\' => vec!['\\', c],
                c => vec![c],
            })
            .collect();
        format!("\"{escaped}\"")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::test_grid;
    use sonar_common::ipc::{CELL_UNKNOWN, encode_probability};

    fn pgm_value(cell: u8) -> u8 {
        Thresholds::default().pgm_value(cell)
    }

    #[test]
    fn cells_are_classified_with_the_yaml_thresholds() {
        assert_eq!(pgm_value(254), PGM_OCCUPIED);
        assert_eq!(pgm_value(encode_probability(0.66)), PGM_OCCUPIED);
        assert_eq!(pgm_value(encode_probability(0.65)), PGM_UNKNOWN);
        assert_eq!(pgm_value(127), PGM_UNKNOWN);
        assert_eq!(pgm_value(encode_probability(0.2)), PGM_UNKNOWN);
        assert_eq!(pgm_value(encode_probability(0.19)), PGM_FREE);
        assert_eq!(pgm_value(0), PGM_FREE);
        assert_eq!(pgm_value(CELL_UNKNOWN), PGM_UNKNOWN);
        // What map_server makes of our grey levels (negate 0): occ = (255 - v) / 255.
        let occ = |v: u8| (255.0 - f64::from(v)) / 255.0;
        assert!(occ(PGM_OCCUPIED) > f64::from(OCCUPIED_THRESH));
        assert!(occ(PGM_FREE) < f64::from(FREE_THRESH));
        let unknown = occ(PGM_UNKNOWN);
        assert!(unknown >= f64::from(FREE_THRESH) && unknown <= f64::from(OCCUPIED_THRESH));
    }

    #[test]
    fn pgm_bytes_are_top_row_first() {
        let h = test_grid::header();
        let map = Map::new(&h, &test_grid::CELLS).unwrap();
        let mut bytes = Vec::new();
        write_pgm(&mut bytes, &map, &Thresholds::default()).unwrap();
        let mut expected = b"P5\n# CREATOR: sonar-export 0.05 m/pix\n3 2\n255\n".to_vec();
        // Top row (y = 1): 0.5, 0.8, 0.1; bottom row (y = 0): free, unknown, occupied.
        expected.extend([205, 0, 254, 254, 205, 0]);
        assert_eq!(bytes, expected);
    }

    #[test]
    fn yaml_has_the_map_server_fields() {
        let h = test_grid::header();
        let map = Map::new(&h, &test_grid::CELLS).unwrap();
        assert_eq!(
            map_yaml(&map, "room.pgm", &Thresholds::default()),
            "# sonar occupancy map (3 x 2 cells, 42 readings fused). Load it with\n\
             #   ros2 run nav2_map_server map_server --ros-args -p yaml_filename:=<this file>\n\
             image: room.pgm\n\
             mode: trinary\n\
             resolution: 0.05\n\
             origin: [-0.075, -0.05, 0.0]\n\
             negate: 0\n\
             occupied_thresh: 0.65\n\
             free_thresh: 0.196\n"
        );
        let whole = sonar_common::ipc::GridHeader {
            origin_x_m: -4.0,
            origin_y_m: 2.0,
            ..h
        };
        let map = Map::new(&whole, &test_grid::CELLS).unwrap();
        assert!(
            map_yaml(&map, "x.pgm", &Thresholds::default()).contains("origin: [-4.0, 2.0, 0.0]\n")
        );
    }

    #[test]
    fn an_occupied_threshold_of_its_own_classifies_the_cells_and_is_written_in_the_yaml() {
        let strict = Thresholds::occupied_above(0.8).unwrap();
        assert_eq!(strict.pgm_value(encode_probability(0.7)), PGM_UNKNOWN);
        assert_eq!(strict.pgm_value(encode_probability(0.81)), PGM_OCCUPIED);
        assert_eq!(strict.pgm_value(encode_probability(0.19)), PGM_FREE);
        assert_eq!(pgm_value(encode_probability(0.7)), PGM_OCCUPIED);
        let h = test_grid::header();
        let map = Map::new(&h, &test_grid::CELLS).unwrap();
        let yaml = map_yaml(&map, "room.pgm", &strict);
        assert!(
            yaml.contains("occupied_thresh: 0.8\nfree_thresh: 0.196\n"),
            "{yaml}"
        );
        // The test grid's 0.8 cell is no longer occupied at 0.8.
        let mut bytes = Vec::new();
        write_pgm(&mut bytes, &map, &strict).unwrap();
        assert_eq!(bytes[bytes.len() - 6..], [205, 205, 254, 254, 205, 0]);
        for bad in [0.3, 0.49, 1.0, f32::NAN] {
            assert!(Thresholds::occupied_above(bad).is_err(), "{bad}");
        }
        assert!(Thresholds::occupied_above(0.5).is_ok());
    }

    #[test]
    fn odd_file_names_are_quoted() {
        assert_eq!(yaml_string("map-1.pgm"), "map-1.pgm");
        assert_eq!(yaml_string("my map: v2.pgm"), "\"my map: v2.pgm\"");
        assert_eq!(yaml_string("-x.pgm"), "\"-x.pgm\"");
        assert_eq!(yaml_string("a\"b\\.pgm"), "\"a\\\"b\\\\.pgm\"");
        assert_eq!(yaml_float(1e-7), "0.0000001");
    }
}
