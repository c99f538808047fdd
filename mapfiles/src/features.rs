//! The walls, corners and posts of a `sonar/features` snapshot as a table: CSV for a spreadsheet,
//! JSON for scripts. Both have one row (object) per feature with the record's fields of
//! `docs/ipc.md`, the kind by name; an absent value (NaN in the record: a post's segment, its
//! angle σ) is an empty CSV field or JSON `null`. Numbers are written as the shortest decimal that
//! reads back as the same `f32`, so nothing is lost.
//!
//! - CSV: a header line naming the columns ([`CSV_COLUMNS`]), then one line per feature, most
//!   confident first (the snapshot's order); `confirmed` says whether it was heard from two places
//!   or more (`true`) or from one only (`false`, tentative).
//! - JSON: one object with the snapshot header's fields and `features`, an array of one object per
//!   feature with the CSV's columns as keys.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use sonar_common::ipc::{FeatureRecord, FeaturesHeader, feature_kind};

use crate::map::MapError;
use crate::output::write_file;

/// A features file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FeatureFormat {
    /// `STEM.features.csv`.
    Csv,
    /// `STEM.features.json`.
    Json,
}

impl FeatureFormat {
    pub const ALL: [FeatureFormat; 2] = [FeatureFormat::Csv, FeatureFormat::Json];

    /// The name `sonar-export --format` takes.
    pub fn name(self) -> &'static str {
        match self {
            FeatureFormat::Csv => "features-csv",
            FeatureFormat::Json => "features-json",
        }
    }

    /// The file this format writes for `stem`.
    pub fn path(self, stem: &Path) -> PathBuf {
        let mut name = stem.as_os_str().to_owned();
        name.push(match self {
            FeatureFormat::Csv => ".features.csv",
            FeatureFormat::Json => ".features.json",
        });
        PathBuf::from(name)
    }
}

/// A name that is not one of [`FeatureFormat::ALL`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown features format {0:?}: expected features-csv or features-json")]
pub struct UnknownFeatureFormat(pub String);

impl FromStr for FeatureFormat {
    type Err = UnknownFeatureFormat;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|f| f.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| UnknownFeatureFormat(s.to_owned()))
    }
}

/// The name of a [`feature_kind`] code: `point`, `corner`, `plane`; `None` for a code this
/// version does not know.
pub fn kind_name(code: u32) -> Option<&'static str> {
    match code {
        feature_kind::POINT => Some("point"),
        feature_kind::CORNER => Some("corner"),
        feature_kind::PLANE => Some("plane"),
        _ => None,
    }
}

/// The columns of the CSV file and the keys of each JSON feature object, in order.
pub const CSV_COLUMNS: [&str; 17] = [
    "id",
    "kind",
    "x_m",
    "y_m",
    "cov_xx",
    "cov_xy",
    "cov_yy",
    "angle_deg",
    "angle_sigma_deg",
    "confidence",
    "times_seen",
    "last_seen_sweep",
    "segment_ax_m",
    "segment_ay_m",
    "segment_bx_m",
    "segment_by_m",
    "confirmed",
];

/// One field of a feature: text, a count, a number that may be absent (not finite), or yes/no.
enum Value {
    Text(String),
    Count(u64),
    Number(f32),
    Flag(bool),
}

/// The values of [`CSV_COLUMNS`] for one record. A kind code this version does not know is
/// written as its number.
fn values(r: &FeatureRecord) -> [Value; 17] {
    use Value::{Count, Flag, Number, Text};
    let kind = kind_name(r.kind).map_or_else(|| r.kind.to_string(), str::to_owned);
    [
        Count(r.id),
        Text(kind),
        Number(r.x_m),
        Number(r.y_m),
        Number(r.cov_xx),
        Number(r.cov_xy),
        Number(r.cov_yy),
        Number(r.angle_deg),
        Number(r.angle_sigma_deg),
        Number(r.confidence),
        Count(r.times_seen.into()),
        Count(r.last_seen_sweep),
        Number(r.segment_ax_m),
        Number(r.segment_ay_m),
        Number(r.segment_bx_m),
        Number(r.segment_by_m),
        Flag(r.is_confirmed()),
    ]
}

/// Writes the records as CSV: the column names, then one line per feature.
pub fn write_features_csv<W: Write>(mut out: W, records: &[FeatureRecord]) -> Result<(), MapError> {
    writeln!(out, "{}", CSV_COLUMNS.join(","))?;
    for r in records {
        let fields: Vec<String> = values(r)
            .into_iter()
            .map(|v| match v {
                // Kind names and numbers hold no comma or quote: no quoting needed.
                Value::Text(t) => t,
                Value::Count(n) => n.to_string(),
                Value::Number(x) if x.is_finite() => x.to_string(),
                Value::Number(_) => String::new(),
                Value::Flag(b) => b.to_string(),
            })
            .collect();
        writeln!(out, "{}", fields.join(","))?;
    }
    out.flush()?;
    Ok(())
}

/// Writes the snapshot as JSON: the header's fields and `features`, one object per line.
pub fn write_features_json<W: Write>(
    mut out: W,
    header: &FeaturesHeader,
    records: &[FeatureRecord],
) -> Result<(), MapError> {
    let h = header;
    let header_fields: [(&str, u64); 11] = [
        ("seq", h.seq),
        ("stamp_ns", h.stamp_ns),
        ("sweeps", h.sweeps),
        ("layout_version", h.layout_version.into()),
        ("feature_count", h.feature_count.into()),
        ("last_sweep_id", h.last_sweep_id.into()),
        ("last_sweep_rcds", h.last_sweep_rcds.into()),
        ("last_sweep_refined", h.last_sweep_refined.into()),
        ("last_sweep_added", h.last_sweep_added.into()),
        ("last_sweep_removed", h.last_sweep_removed.into()),
        ("features_left_out", h.features_left_out.into()),
    ];
    writeln!(out, "{{")?;
    for (key, value) in header_fields {
        writeln!(out, "  \"{key}\": {value},")?;
    }
    write!(out, "  \"features\": [")?;
    for (i, r) in records.iter().enumerate() {
        let fields: Vec<String> = CSV_COLUMNS
            .iter()
            .zip(values(r))
            .map(|(key, v)| match v {
                // Kind names and numbers hold nothing JSON would escape.
                Value::Text(t) => format!("\"{key}\": \"{t}\""),
                Value::Count(n) => format!("\"{key}\": {n}"),
                Value::Number(x) if x.is_finite() => format!("\"{key}\": {x}"),
                Value::Number(_) => format!("\"{key}\": null"),
                Value::Flag(b) => format!("\"{key}\": {b}"),
            })
            .collect();
        let sep = if i == 0 { "" } else { "," };
        write!(out, "{sep}\n    {{{}}}", fields.join(", "))?;
    }
    let close = if records.is_empty() { "]" } else { "\n  ]" };
    writeln!(out, "{close}\n}}")?;
    out.flush()?;
    Ok(())
}

/// Writes the snapshot in each of `formats` next to `stem` ([`FeatureFormat::path`]); returns the
/// files written, in order. Existing files are replaced, each through a temporary file.
pub fn write_features(
    header: &FeaturesHeader,
    records: &[FeatureRecord],
    stem: &Path,
    formats: &[FeatureFormat],
) -> Result<Vec<PathBuf>, MapError> {
    let mut written = Vec::new();
    for &format in formats {
        let path = format.path(stem);
        match format {
            FeatureFormat::Csv => write_file(&path, |w| write_features_csv(w, records))?,
            FeatureFormat::Json => write_file(&path, |w| write_features_json(w, header, records))?,
        }
        written.push(path);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use sonar_common::ipc::feature_flags;

    use super::*;

    /// A post with its absent values, and a wall with its segment.
    fn snapshot() -> (FeaturesHeader, Vec<FeatureRecord>) {
        let post = FeatureRecord {
            id: 7,
            kind: feature_kind::POINT,
            times_seen: 3,
            x_m: 0.975,
            y_m: -0.0125,
            cov_xx: 1e-4,
            cov_xy: -2.5e-6,
            cov_yy: 3e-4,
            angle_deg: -0.5,
            angle_sigma_deg: f32::NAN,
            confidence: 0.875,
            segment_ax_m: f32::NAN,
            segment_ay_m: f32::NAN,
            segment_bx_m: f32::NAN,
            segment_by_m: f32::NAN,
            last_seen_sweep: 4,
            flags: feature_flags::CONFIRMED,
            reserved: 0,
        };
        let wall = FeatureRecord {
            id: 12,
            kind: feature_kind::PLANE,
            times_seen: 2,
            x_m: 2.0,
            y_m: 0.0,
            angle_deg: 180.0,
            angle_sigma_deg: 0.75,
            confidence: 0.5,
            segment_ax_m: 2.0,
            segment_ay_m: -0.5,
            segment_bx_m: 2.0,
            segment_by_m: 0.625,
            flags: 0,
            ..post
        };
        let header = FeaturesHeader {
            seq: 5,
            stamp_ns: 1_700_000_000_123_456_789,
            sweeps: 4,
            layout_version: 1,
            feature_count: 2,
            last_sweep_id: 9,
            last_sweep_rcds: 3,
            last_sweep_refined: 2,
            last_sweep_added: 0,
            last_sweep_removed: 1,
            features_left_out: 0,
        };
        (header, vec![post, wall])
    }

    #[test]
    fn csv_has_named_columns_one_line_per_feature_and_empty_absent_values() {
        let (_, records) = snapshot();
        let mut bytes = Vec::new();
        write_features_csv(&mut bytes, &records).unwrap();
        assert_eq!(
            String::from_utf8(bytes).unwrap(),
            "id,kind,x_m,y_m,cov_xx,cov_xy,cov_yy,angle_deg,angle_sigma_deg,confidence,\
             times_seen,last_seen_sweep,segment_ax_m,segment_ay_m,segment_bx_m,segment_by_m,\
             confirmed\n\
             7,point,0.975,-0.0125,0.0001,-0.0000025,0.0003,-0.5,,0.875,3,4,,,,,true\n\
             12,plane,2,0,0.0001,-0.0000025,0.0003,180,0.75,0.5,2,4,2,-0.5,2,0.625,false\n"
        );
    }

    #[test]
    fn csv_numbers_read_back_as_the_same_f32() {
        let records: Vec<FeatureRecord> = [0.1f32, 1.0 / 3.0, -2.5e-6, 1e-30, 3.4e38]
            .into_iter()
            .map(|x_m| FeatureRecord {
                x_m,
                ..FeatureRecord::default()
            })
            .collect();
        let mut bytes = Vec::new();
        write_features_csv(&mut bytes, &records).unwrap();
        let text = String::from_utf8(bytes).unwrap();
        for (line, r) in text.lines().skip(1).zip(&records) {
            let x: f32 = line.split(',').nth(2).unwrap().parse().unwrap();
            assert_eq!(x.to_bits(), r.x_m.to_bits(), "{line}");
        }
    }

    #[test]
    fn json_has_the_header_and_one_object_per_feature_with_null_for_absent_values() {
        let (header, records) = snapshot();
        let mut bytes = Vec::new();
        write_features_json(&mut bytes, &header, &records).unwrap();
        let text = String::from_utf8(bytes).unwrap();
        assert_eq!(
            text,
            r#"{
  "seq": 5,
  "stamp_ns": 1700000000123456789,
  "sweeps": 4,
  "layout_version": 1,
  "feature_count": 2,
  "last_sweep_id": 9,
  "last_sweep_rcds": 3,
  "last_sweep_refined": 2,
  "last_sweep_added": 0,
  "last_sweep_removed": 1,
  "features_left_out": 0,
  "features": [
    {"id": 7, "kind": "point", "x_m": 0.975, "y_m": -0.0125, "cov_xx": 0.0001, "cov_xy": -0.0000025, "cov_yy": 0.0003, "angle_deg": -0.5, "angle_sigma_deg": null, "confidence": 0.875, "times_seen": 3, "last_seen_sweep": 4, "segment_ax_m": null, "segment_ay_m": null, "segment_bx_m": null, "segment_by_m": null, "confirmed": true},
    {"id": 12, "kind": "plane", "x_m": 2, "y_m": 0, "cov_xx": 0.0001, "cov_xy": -0.0000025, "cov_yy": 0.0003, "angle_deg": 180, "angle_sigma_deg": 0.75, "confidence": 0.5, "times_seen": 2, "last_seen_sweep": 4, "segment_ax_m": 2, "segment_ay_m": -0.5, "segment_bx_m": 2, "segment_by_m": 0.625, "confirmed": false}
  ]
}
"#
        );
    }

    #[test]
    fn an_empty_snapshot_and_an_unknown_kind_are_still_valid_files() {
        let (header, mut records) = snapshot();
        let mut bytes = Vec::new();
        write_features_json(&mut bytes, &header, &[]).unwrap();
        let text = String::from_utf8(bytes).unwrap();
        assert!(text.ends_with("  \"features\": []\n}\n"), "{text}");

        records[0].kind = 99;
        records[0].x_m = f32::INFINITY;
        let mut csv = Vec::new();
        write_features_csv(&mut csv, &records[..1]).unwrap();
        let csv = String::from_utf8(csv).unwrap();
        assert!(csv.lines().nth(1).unwrap().starts_with("7,99,,"), "{csv}");
        let mut json = Vec::new();
        write_features_json(&mut json, &header, &records[..1]).unwrap();
        let json = String::from_utf8(json).unwrap();
        assert!(json.contains(r#""kind": "99", "x_m": null,"#), "{json}");
    }

    #[test]
    fn formats_parse_and_name_their_files() {
        assert_eq!(
            "Features-CSV".parse::<FeatureFormat>(),
            Ok(FeatureFormat::Csv)
        );
        assert!("features".parse::<FeatureFormat>().is_err());
        assert_eq!(
            FeatureFormat::Json.path(Path::new("out/room")),
            PathBuf::from("out/room.features.json")
        );
        let dir = std::env::temp_dir().join(format!("sonar-features-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let (header, records) = snapshot();
        let written =
            write_features(&header, &records, &dir.join("room"), &FeatureFormat::ALL).unwrap();
        assert_eq!(
            written,
            [
                dir.join("room.features.csv"),
                dir.join("room.features.json")
            ]
        );
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 2);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
