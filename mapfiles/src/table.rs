//! The probabilities as numbers, for analysis in a spreadsheet, NumPy or anything else.
//!
//! Both files keep the grid's own orientation: row 0 is the grid's row 0, the lowest y (unlike
//! the pictures, whose first row is the top). Cell (x, y) covers the world square from
//! (origin_x + x·res, origin_y + y·res) to one resolution further in each axis.
//!
//! - CSV: `height` lines of `width` comma-separated fields, p with 4 decimals (enough to recover
//!   the byte: `round(p · 254)`), an empty field for a cell never observed. No header line.
//! - NPY: NumPy format 1.0, `float32` little-endian (`<f4`), C order, shape `(height, width)`,
//!   p = byte / 254 exactly as `decode_probability`, NaN for never observed. Load with
//!   `numpy.load(path)`.

use std::io::Write;

use sonar_common::ipc::decode_probability;

use crate::map::{Map, MapError};

/// Writes the probabilities as CSV, row 0 (lowest y) first.
pub fn write_csv<W: Write>(mut out: W, map: &Map<'_>) -> Result<(), MapError> {
    let mut line = String::with_capacity(map.width() * 7);
    for y in 0..map.height() {
        line.clear();
        for (x, &cell) in map.row(y).iter().enumerate() {
            if x > 0 {
                line.push(',');
            }
            if let Some(p) = decode_probability(cell) {
                line.push_str(&format!("{p:.4}"));
            }
        }
        line.push('\n');
        out.write_all(line.as_bytes())?;
    }
    out.flush()?;
    Ok(())
}

/// The NPY header (magic, version 1.0, header length, dictionary padded to a multiple of 64 bytes
/// in total, ending in a newline) of a `height × width` `float32` array.
pub fn npy_header(height: usize, width: usize) -> Vec<u8> {
    let dict =
        format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({height}, {width}), }}");
    // magic (6) + version (2) + length (2) + dictionary + padding + '\n'
    let unpadded = 10 + dict.len() + 1;
    let padding = unpadded.next_multiple_of(64) - unpadded;
    let len = dict.len() + padding + 1;
    let mut out = Vec::with_capacity(10 + len);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    // Below 64 KiB for any shape of two numbers.
    out.extend_from_slice(&(len as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out.extend(std::iter::repeat_n(b' ', padding));
    out.push(b'\n');
    out
}

/// Writes the probabilities as a NumPy array, row 0 (lowest y) first.
pub fn write_npy<W: Write>(mut out: W, map: &Map<'_>) -> Result<(), MapError> {
    out.write_all(&npy_header(map.height(), map.width()))?;
    let mut row = Vec::with_capacity(map.width() * 4);
    for y in 0..map.height() {
        row.clear();
        for &cell in map.row(y) {
            let p = decode_probability(cell).unwrap_or(f32::NAN);
            row.extend_from_slice(&p.to_le_bytes());
        }
        out.write_all(&row)?;
    }
    out.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::test_grid;

    #[test]
    fn csv_rows_run_from_the_lowest_y_and_unknown_is_empty() {
        let h = test_grid::header();
        let map = Map::new(&h, &test_grid::CELLS).unwrap();
        let mut bytes = Vec::new();
        write_csv(&mut bytes, &map).unwrap();
        assert_eq!(
            String::from_utf8(bytes).unwrap(),
            "0.0000,,1.0000\n0.5000,0.7992,0.0984\n"
        );
    }

    #[test]
    fn csv_values_recover_every_byte() {
        for v in 0..=254u8 {
            let p = decode_probability(v).unwrap();
            let text = format!("{p:.4}");
            let back: f32 = text.parse().unwrap();
            assert_eq!((back * 254.0).round() as u8, v);
        }
    }

    #[test]
    fn npy_header_is_numpy_format_1_0_aligned_to_64_bytes() {
        let header = npy_header(2, 3);
        let mut expected = b"\x93NUMPY\x01\x00\x76\x00".to_vec();
        expected.extend_from_slice(b"{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }");
        expected.extend_from_slice(&[b' '; 58]);
        expected.push(b'\n');
        assert_eq!(header, expected);
        assert_eq!(header.len(), 128);
        assert_eq!(npy_header(400, 400).len() % 64, 0);
    }

    #[test]
    fn npy_data_is_float32_row_major_with_nan_for_unknown() {
        let h = test_grid::header();
        let map = Map::new(&h, &test_grid::CELLS).unwrap();
        let mut bytes = Vec::new();
        write_npy(&mut bytes, &map).unwrap();
        let data: Vec<f32> = bytes[128..]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        assert_eq!(data.len(), 6);
        assert_eq!(data[0], 0.0);
        assert!(data[1].is_nan());
        assert_eq!(data[2], 1.0);
        assert_eq!(data[3], 127.0 / 254.0);
        assert_eq!(data[4], 203.0 / 254.0);
    }
}
