//! Saving the probability map as a PNG: one pixel per grid cell, in the terminal view's colours,
//! north (highest y) up, with the map's geometry in a text chunk so the picture can be placed in the
//! world again, and below it the legend (scale bar and colour code). The picture itself is
//! `sonar_mapfiles`', the very one `sonar-export` writes; this module names and places the file.

use std::ffi::OsString;
use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, ErrorKind, Write};
use std::path::{Path, PathBuf};

use sonar_common::ipc::FeatureRecord;
use sonar_mapfiles::picture::PngOptions;
use sonar_mapfiles::{Map, MapError};

use crate::app::GridSnapshot;

/// Encodes `grid` as an 8-bit RGB PNG, one pixel per cell, with the legend below and `features`
/// drawn over the map (the overlay as shown, `None` when hidden), as `sonar-export [--features]`
/// does.
pub fn write_png<W: Write>(
    out: W,
    grid: &GridSnapshot,
    features: Option<&[FeatureRecord]>,
) -> Result<(), MapError> {
    let map = Map::new(&grid.header, &grid.cells)?;
    let options = PngOptions {
        legend: true,
        features,
    };
    sonar_mapfiles::picture::write_png(out, &map, &options)
}

/// Where `s` saves maps unless `--save-dir` says otherwise: `$XDG_DATA_HOME/sonar/maps`, else
/// `~/.local/share/sonar/maps` (the XDG default), else `sonar/maps` in the temporary directory.
/// Given the two variables' values, so that it can be tested without touching the environment.
pub fn default_save_dir(xdg_data_home: Option<OsString>, home: Option<OsString>) -> PathBuf {
    let non_empty = |v: Option<OsString>| v.filter(|v| !v.is_empty()).map(PathBuf::from);
    let data = non_empty(xdg_data_home)
        .or_else(|| non_empty(home).map(|home| home.join(".local/share")))
        .unwrap_or_else(std::env::temp_dir);
    data.join("sonar/maps")
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

/// Saves `grid` into `dir` (created if missing) under a timestamped name that no existing file
/// has; returns the path.
pub fn save_png(
    dir: &Path,
    grid: &GridSnapshot,
    features: Option<&[FeatureRecord]>,
    unix_secs: u64,
) -> io::Result<PathBuf> {
    std::fs::create_dir_all(dir)
        .map_err(|e| io::Error::new(e.kind(), format!("{}: {e}", dir.display())))?;
    let stem = file_stem(unix_secs);
    let (path, file) = create_unique(dir, &stem)?;
    let mut out = BufWriter::new(file);
    let written = write_png(&mut out, grid, features)
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
    use sonar_mapfiles::picture::LEGEND_HEIGHT;

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
    fn png_has_one_pixel_per_cell_with_the_highest_row_on_top_and_the_legend_below() {
        let mut bytes = Vec::new();
        write_png(&mut bytes, &grid(), None).unwrap();
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
            .read_info()
            .unwrap();
        let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut pixels).unwrap();
        // As `sonar-export` writes it: widened for the legend strip below the map.
        assert_eq!(info.height, 2 + LEGEND_HEIGHT);
        assert!(info.width > 3);
        let width = info.width as usize;
        let px = |x: usize, y: usize| &pixels[(y * width + x) * 3..(y * width + x) * 3 + 3];
        assert_eq!(px(0, 0), cell_rgb(0));
        assert_eq!(px(1, 1), cell_rgb(CELL_UNKNOWN));
        assert_eq!(px(2, 1), cell_rgb(254));
    }

    #[test]
    fn saving_twice_in_a_second_keeps_both_in_a_directory_it_creates() {
        let top = std::env::temp_dir().join(format!("sonar-viewer-test-{}", std::process::id()));
        let dir = top.join("sonar/maps");
        assert!(!dir.exists());
        let a = save_png(&dir, &grid(), None, 0).unwrap();
        let b = save_png(&dir, &grid(), None, 0).unwrap();
        assert_eq!(a, dir.join("sonar-map-19700101-000000.png"));
        assert_eq!(b, dir.join("sonar-map-19700101-000000-2.png"));
        // A directory that cannot be made (a file is in the way) is an error naming it.
        let blocked = a.join("maps");
        let e = save_png(&blocked, &grid(), None, 0).unwrap_err();
        assert!(e.to_string().contains(&*blocked.to_string_lossy()), "{e}");
        std::fs::remove_dir_all(&top).unwrap();
    }

    #[test]
    fn maps_go_to_the_xdg_data_directory() {
        let os = |s: &str| Some(OsString::from(s));
        assert_eq!(
            default_save_dir(os("/data"), os("/home/u")),
            PathBuf::from("/data/sonar/maps")
        );
        assert_eq!(
            default_save_dir(os(""), os("/home/u")),
            PathBuf::from("/home/u/.local/share/sonar/maps")
        );
        assert_eq!(
            default_save_dir(None, None),
            std::env::temp_dir().join("sonar/maps")
        );
    }
}
