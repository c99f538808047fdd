//! Saving the probability map as a PNG: one pixel per grid cell, in the terminal view's colours,
//! north (highest y) up, with the map's geometry in a text chunk so the picture can be placed in the
//! world again. The picture itself is `sonar_mapfiles`' (the same as `sonar-export --no-legend`);
//! this module names and places the file.

use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, ErrorKind, Write};
use std::path::{Path, PathBuf};

use sonar_mapfiles::picture::PngOptions;
use sonar_mapfiles::{Map, MapError};

use crate::app::GridSnapshot;

/// Encodes `grid` as an 8-bit RGB PNG, one pixel per cell (no legend).
pub fn write_png<W: Write>(out: W, grid: &GridSnapshot) -> Result<(), MapError> {
    let map = Map::new(&grid.header, &grid.cells)?;
    sonar_mapfiles::picture::write_png(out, &map, &PngOptions { legend: false })
}

/// `sonar-map-YYYYMMDD-HHMMSS.png`, UTC.
pub fn file_stem(unix_secs: u64) -> String {
    let (days, secs) = (unix_secs / 86_400, unix_secs % 86_400);
    let (y, m, d) = civil_from_days(days);
    format!(
        "sonar-map-{y:04}{m:02}{d:02}-{:02}{:02}{:02}",
        secs / 3600,
        secs / 60 % 60,
        secs % 60
    )
}

/// Saves `grid` into `dir` under a timestamped name that no existing file has; returns the path.
pub fn save_png(dir: &Path, grid: &GridSnapshot, unix_secs: u64) -> io::Result<PathBuf> {
    let stem = file_stem(unix_secs);
    let (path, file) = create_unique(dir, &stem)?;
    let mut out = BufWriter::new(file);
    let written = write_png(&mut out, grid)
        .map_err(io::Error::other)
        .and_then(|()| out.flush());
    if let Err(e) = written {
        // Leave no truncated picture behind.
        let _ = std::fs::remove_file(&path);
        return Err(e);
    }
    Ok(path)
}

/// Creates `<stem>.png`, or `<stem>-2.png`, … if taken (two saves within a second).
fn create_unique(dir: &Path, stem: &str) -> io::Result<(PathBuf, File)> {
    for n in 1..100 {
        let name = if n == 1 {
            format!("{stem}.png")
        } else {
            format!("{stem}-{n}.png")
        };
        let path = dir.join(name);
        match OpenOptions::new().write(true).create_new(true).open(&path) {
            Ok(file) => return Ok((path, file)),
            Err(e) if e.kind() == ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(io::Error::new(e.kind(), format!("{}: {e}", path.display()))),
        }
    }
    Err(io::Error::new(
        ErrorKind::AlreadyExists,
        format!("{}: too many maps saved this second", dir.display()),
    ))
}

/// Days since 1970-01-01 → (year, month, day), proleptic Gregorian (H. Hinnant's algorithm).
fn civil_from_days(days: u64) -> (u64, u64, u64) {
    let z = days + 719_468;
    let era = z / 146_097;
    let doe = z % 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + u64::from(m <= 2);
    (y, m, d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::heatmap::cell_rgb;
    use sonar_common::ipc::{CELL_UNKNOWN, GridHeader, LAYOUT_VERSION};

    #[test]
    fn file_names_carry_the_utc_time() {
        assert_eq!(file_stem(0), "sonar-map-19700101-000000");
        assert_eq!(file_stem(951_825_600), "sonar-map-20000229-120000");
        assert_eq!(file_stem(1_767_225_599), "sonar-map-20251231-235959");
    }

    fn grid() -> GridSnapshot {
        // 3 × 2: bottom row free, unknown, occupied; top row all free.
        GridSnapshot {
            header: GridHeader {
                layout_version: LAYOUT_VERSION,
                width: 3,
                height: 2,
                resolution_m: 0.05,
                ..GridHeader::default()
            },
            cells: vec![0, CELL_UNKNOWN, 254, 0, 0, 0],
            seen: None,
        }
    }

    #[test]
    fn png_has_one_pixel_per_cell_with_the_highest_row_on_top() {
        let mut bytes = Vec::new();
        write_png(&mut bytes, &grid()).unwrap();
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
            .read_info()
            .unwrap();
        let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut pixels).unwrap();
        assert_eq!((info.width, info.height), (3, 2));
        let px = |x: usize, y: usize| &pixels[(y * 3 + x) * 3..(y * 3 + x) * 3 + 3];
        assert_eq!(px(0, 0), cell_rgb(0));
        assert_eq!(px(1, 1), cell_rgb(CELL_UNKNOWN));
        assert_eq!(px(2, 1), cell_rgb(254));
    }

    #[test]
    fn saving_twice_in_a_second_keeps_both() {
        let dir = std::env::temp_dir().join(format!("sonar-viewer-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let a = save_png(&dir, &grid(), 0).unwrap();
        let b = save_png(&dir, &grid(), 0).unwrap();
        assert_eq!(a.file_name().unwrap(), "sonar-map-19700101-000000.png");
        assert_eq!(b.file_name().unwrap(), "sonar-map-19700101-000000-2.png");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
