//! Which files a map is written to, and writing them so that no reader ever sees half a file:
//! each is written under a temporary name in the same directory and renamed into place.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::str::FromStr;

use crate::map::{Map, MapError};
use crate::picture::{PngOptions, write_png};
use crate::ros::{Thresholds, map_yaml, write_pgm};
use crate::table::{write_csv, write_npy};

/// A map file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Format {
    /// `STEM.png`: the picture in the viewer's colours.
    Png,
    /// `STEM.pgm` + `STEM.yaml`: a ROS `map_server` map.
    Pgm,
    /// `STEM.csv`: probabilities, empty for unknown.
    Csv,
    /// `STEM.npy`: probabilities as `float32`, NaN for unknown.
    Npy,
}

impl Format {
    pub const ALL: [Format; 4] = [Format::Png, Format::Pgm, Format::Csv, Format::Npy];
    const NAMES: [&'static str; 4] = ["png", "pgm", "csv", "npy"];

    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }

    /// The files this format writes for `stem` (the PGM's YAML second).
    pub fn paths(self, stem: &Path) -> Vec<PathBuf> {
        let with = |ext: &str| {
            let mut name = stem.as_os_str().to_owned();
            name.push(".");
            name.push(ext);
            PathBuf::from(name)
        };
        match self {
            Format::Pgm => vec![with("pgm"), with("yaml")],
            _ => vec![with(self.name())],
        }
    }
}

/// A format name that is not one of [`Format::ALL`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown map format {0:?}: expected png, pgm, csv, npy or all")]
pub struct UnknownFormat(pub String);

impl FromStr for Format {
    type Err = UnknownFormat;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|f| f.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| UnknownFormat(s.to_owned()))
    }
}

/// Extensions [`stem`] removes, so `--out map.png` writes `map.png`, not `map.png.png`.
const MAP_EXTENSIONS: [&str; 8] = ["png", "pgm", "yaml", "yml", "csv", "npy", "json", "mcap"];

/// The stem the files of `out` are named after: `out` without a map file extension (and without
/// the `.features` of a features file's name), or `out/sonar-map` if `out` is an existing
/// directory.
pub fn stem(out: &Path) -> PathBuf {
    if out.is_dir() {
        return out.join("sonar-map");
    }
    let has = |path: &Path, extensions: &[&str]| {
        path.extension()
            .and_then(|e| e.to_str())
            .is_some_and(|ext| extensions.iter().any(|m| m.eq_ignore_ascii_case(ext)))
    };
    let mut stem = out.to_owned();
    if has(&stem, &MAP_EXTENSIONS) {
        stem.set_extension("");
        if has(&stem, &["features"]) {
            stem.set_extension("");
        }
    }
    stem
}

/// Writes `map` in each of `formats` next to `stem` ([`Format::paths`]), the ROS map with
/// `thresholds`; returns the files written, in order. Existing files are replaced.
pub fn write_map(
    map: &Map<'_>,
    stem: &Path,
    formats: &[Format],
    png: &PngOptions,
    thresholds: &Thresholds,
) -> Result<Vec<PathBuf>, MapError> {
    let mut written = Vec::new();
    for &format in formats {
        let paths = format.paths(stem);
        match format {
            Format::Png => write_file(&paths[0], |w| write_png(w, map, png))?,
            Format::Pgm => {
                write_file(&paths[0], |w| write_pgm(w, map, thresholds))?;
                let image = paths[0]
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let yaml = map_yaml(map, &image, thresholds);
                write_file(&paths[1], |w| Ok(w.write_all(yaml.as_bytes())?))?;
            }
            Format::Csv => write_file(&paths[0], |w| write_csv(w, map))?,
            Format::Npy => write_file(&paths[0], |w| write_npy(w, map))?,
        }
        written.extend(paths);
    }
    Ok(written)
}

/// Writes `path` through a temporary file in the same directory, renamed into place once complete;
/// on failure nothing is left behind.
pub fn write_file(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> Result<(), MapError>,
) -> Result<(), MapError> {
    let file_error = |source| MapError::File {
        path: path.to_owned(),
        source,
    };
    let name = path
        .file_name()
        .ok_or_else(|| file_error(std::io::Error::other("not a file name")))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".{}.part", std::process::id()));
    let tmp = path.with_file_name(tmp_name);

    let result = File::create(&tmp).map_err(file_error).and_then(|file| {
        let mut w = BufWriter::new(file);
        write(&mut w).map_err(|e| match e {
            MapError::Io(source) => file_error(source),
            other => other,
        })?;
        w.flush().map_err(file_error)?;
        std::fs::rename(&tmp, path).map_err(file_error)
    });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::test_grid;

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("sonar-mapfiles-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn formats_parse_and_name_their_files() {
        assert_eq!("PNG".parse::<Format>(), Ok(Format::Png));
        assert_eq!(
            "jpeg".parse::<Format>(),
            Err(UnknownFormat("jpeg".to_owned()))
        );
        assert_eq!(
            Format::Pgm.paths(Path::new("out/room")),
            [
                PathBuf::from("out/room.pgm"),
                PathBuf::from("out/room.yaml")
            ]
        );
        assert_eq!(
            Format::Npy.paths(Path::new("a.b")),
            [PathBuf::from("a.b.npy")]
        );
        assert_eq!(stem(Path::new("x/map.png")), PathBuf::from("x/map"));
        assert_eq!(stem(Path::new("x/map.YAML")), PathBuf::from("x/map"));
        assert_eq!(stem(Path::new("x/map.v2")), PathBuf::from("x/map.v2"));
        assert_eq!(
            stem(Path::new("x/map.features.json")),
            PathBuf::from("x/map")
        );
        assert_eq!(
            stem(Path::new("x/map.features")),
            PathBuf::from("x/map.features")
        );
        let dir = scratch("stem");
        assert_eq!(stem(&dir), dir.join("sonar-map"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn every_format_is_written_and_nothing_else_is_left() {
        let dir = scratch("all");
        let h = test_grid::header();
        let map = Map::new(&h, &test_grid::CELLS).unwrap();
        let written = write_map(
            &map,
            &dir.join("room"),
            &Format::ALL,
            &PngOptions::default(),
            &Thresholds::default(),
        )
        .unwrap();
        let names: Vec<_> = written
            .iter()
            .map(|p| p.file_name().unwrap().to_str().unwrap())
            .collect();
        assert_eq!(
            names,
            ["room.png", "room.pgm", "room.yaml", "room.csv", "room.npy"]
        );
        let mut listed: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        listed.sort();
        assert_eq!(
            listed,
            ["room.csv", "room.npy", "room.pgm", "room.png", "room.yaml"]
        );
        let yaml = std::fs::read_to_string(dir.join("room.yaml")).unwrap();
        assert!(yaml.contains("\nimage: room.pgm\n"), "{yaml}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_failed_write_leaves_no_file() {
        let dir = scratch("fail");
        let path = dir.join("map.csv");
        let err = write_file(&path, |_| Err(std::io::Error::other("disk full").into()));
        assert!(
            matches!(&err, Err(MapError::File { path: p, .. }) if *p == path),
            "{err:?}"
        );
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
        let missing = dir.join("no/such/dir/map.csv");
        assert!(matches!(
            write_file(&missing, |_| Ok(())),
            Err(MapError::File { .. })
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
