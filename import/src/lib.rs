//! Logs people already have — a CSV or TSV of angle and range per row, with or without a time and
//! the robot's pose — as the messages of a sonar recording, so `sonar-replay`, `sonar-export` and
//! the viewer take them like any other recording. Pure: rows in, messages out; `sonar-import` does
//! the files.
//!
//! Each row becomes the reading the driver publishes for the same angle and range from a hobby
//! sketch (the same code: [`Decoder::hobby_reading`]): sweeps from the angle sequence (a reversal
//! or a continuous head's wrap starts one), the log's no-echo value as `NO_ECHO`, ranges outside
//! the sensor's as `OUT_OF_RANGE`, one ping (`NO_RAW_PINGS`). So an imported log gives the map the
//! same readings give live.

use std::io::BufRead;

use sonar_common::ipc::{LAYOUT_VERSION, Pose2D, Reading, flags};
use sonar_common::protocol::HobbyReading;
use sonar_common::sensor::SensorConfig;
use sonar_driver::averaging::PingPolicy;
use sonar_driver::decoder::{Decoder, Dialect, NoEcho};

/// What a column of the log holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Column {
    /// The beam's angle (required).
    Angle,
    /// The measured range (required).
    Range,
    /// When the reading was taken.
    Time,
    /// The robot's position, metres, and heading (in the angle unit): all three or none.
    X,
    Y,
    Theta,
    /// A column to leave out.
    Skip,
}

impl std::str::FromStr for Column {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(match s.trim().to_ascii_lowercase().as_str() {
            "angle" => Column::Angle,
            "range" => Column::Range,
            "time" => Column::Time,
            "x" => Column::X,
            "y" => Column::Y,
            "theta" => Column::Theta,
            "-" | "skip" => Column::Skip,
            other => {
                return Err(format!(
                    "unknown column {other:?}: expected angle, range, time, x, y, theta or - (skip)"
                ));
            }
        })
    }
}

/// A unit of the log's ranges.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RangeUnit {
    Mm,
    Cm,
    M,
    In,
}

impl RangeUnit {
    fn cm(self) -> f32 {
        match self {
            RangeUnit::Mm => 0.1,
            RangeUnit::Cm => 1.0,
            RangeUnit::M => 100.0,
            RangeUnit::In => 2.54,
        }
    }
}

/// A unit of the log's angles (the beam's and the robot's heading).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum AngleUnit {
    Deg,
    Rad,
}

/// Which way the log's angles grow.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Turn {
    /// Counter-clockwise seen from above (ours, and the mathematical convention).
    Ccw,
    /// Clockwise (compass bearings, many servo sketches mounted upside down).
    Cw,
}

/// A unit of the log's time column.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum TimeUnit {
    S,
    Ms,
    Us,
    Ns,
}

impl TimeUnit {
    fn ns(self) -> f64 {
        match self {
            TimeUnit::S => 1e9,
            TimeUnit::Ms => 1e6,
            TimeUnit::Us => 1e3,
            TimeUnit::Ns => 1.0,
        }
    }
}

/// How to read a log.
#[derive(Debug, Clone)]
pub struct LogFormat {
    /// The columns in order; `None`: from the file's header line, else `angle,range`.
    pub columns: Option<Vec<Column>>,
    pub delimiter: u8,
    pub range_unit: RangeUnit,
    pub angle_unit: AngleUnit,
    pub turn: Turn,
    /// The log's angle (in its unit) that points along the sensor's forward axis.
    pub angle_zero: f32,
    pub time_unit: TimeUnit,
    /// Time between rows of a log without a time column, ns.
    pub period_ns: u64,
    /// The log's range (in its unit) that means "no echo"; 0 always does.
    pub no_echo: NoEcho,
}

impl Default for LogFormat {
    fn default() -> Self {
        Self {
            columns: None,
            delimiter: b',',
            range_unit: RangeUnit::Cm,
            angle_unit: AngleUnit::Deg,
            turn: Turn::Ccw,
            angle_zero: 0.0,
            time_unit: TimeUnit::S,
            period_ns: 100_000_000,
            no_echo: NoEcho::Zero,
        }
    }
}

/// A log that cannot be imported; a row's error names its line in the file (from 1).
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    #[error("line {line}: {what}")]
    Row { line: u64, what: String },
    #[error("{0}")]
    Columns(String),
    #[error("the log holds no readings")]
    Empty,
    #[error("reading the log: {0}")]
    Read(#[from] std::io::Error),
    #[error("writing the recording: {0}")]
    Write(#[from] sonar_recorder::FormatError),
}

/// One message of the recording and when it happened, ns.
#[derive(Debug, Clone, PartialEq)]
pub struct Timed {
    pub stamp_ns: u64,
    pub message: sonar_recorder::Message,
}

/// What an import brought in.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Summary {
    pub readings: u64,
    pub no_echo: u64,
    pub out_of_range: u64,
    pub poses: u64,
    pub sweeps: u64,
    /// A header line was read (and not taken as a reading).
    pub header: bool,
}

/// Reads `input` as the log `format` describes and hands each message, in order, to `sink`.
/// Any malformed row stops the import with its line number.
///
/// Lines are split here rather than by the `csv` crate, whose record positions miscount lines
/// after comments, blank lines and CRLF endings (csv 1.4), and a row's error must name its line.
/// A log of numbers needs no quoting; quotes around a field are taken off.
pub fn import<R: BufRead>(
    input: R,
    format: &LogFormat,
    sensor: SensorConfig,
    mut sink: impl FnMut(Timed) -> Result<(), ImportError>,
) -> Result<Summary, ImportError> {
    let mut decoder = Decoder::new(Dialect::Hobby, sensor, PingPolicy::default(), 0.0)
        .hobby_no_echo(format.no_echo.in_cm(format.range_unit.cm()));
    let mut columns = format.columns.clone();
    let mut summary = Summary::default();
    let mut last_stamp: Option<u64> = None;
    let mut last_sweep = None;
    let delimiter = char::from(format.delimiter);
    for (line, text) in (1u64..).zip(input.lines()) {
        let text = text?;
        let text = text.trim();
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        let record: Vec<&str> = text
            .split(delimiter)
            .map(|f| f.trim().trim_matches('"').trim())
            .collect();
        if summary.readings == 0 && !summary.header && is_header(&record) {
            summary.header = true;
            if columns.is_none() {
                columns = Some(columns_from_header(&record, line)?);
            }
            continue;
        }
        let columns = columns.get_or_insert_with(|| vec![Column::Angle, Column::Range]);
        let layout = Layout::of(columns)?;
        let row = layout
            .row(&record, format)
            .map_err(|what| ImportError::Row { line, what })?;
        let stamp_ns = match row.time_ns {
            Some(t) => t,
            None => summary.readings * format.period_ns,
        };
        if let Some(last) = last_stamp.filter(|&last| stamp_ns < last) {
            return Err(ImportError::Row {
                line,
                what: format!(
                    "the time goes back ({} ns after {} ns): rows must be in time order",
                    stamp_ns, last
                ),
            });
        }
        last_stamp = Some(stamp_ns);
        if let Some((x_m, y_m, theta_rad)) = row.pose {
            sink(Timed {
                stamp_ns,
                message: sonar_recorder::Message::Pose(Pose2D {
                    stamp_ns,
                    x_m,
                    y_m,
                    theta_rad,
                    layout_version: LAYOUT_VERSION,
                }),
            })?;
            summary.poses += 1;
        }
        let reading = decoder.hobby_reading(row.reading, stamp_ns);
        count(&mut summary, &reading, &mut last_sweep);
        sink(Timed {
            stamp_ns,
            message: sonar_recorder::Message::Reading(reading),
        })?;
    }
    if summary.readings == 0 {
        return Err(ImportError::Empty);
    }
    Ok(summary)
}

fn count(summary: &mut Summary, reading: &Reading, last_sweep: &mut Option<u32>) {
    summary.readings += 1;
    summary.no_echo += u64::from(reading.has(flags::NO_ECHO));
    summary.out_of_range += u64::from(reading.has(flags::OUT_OF_RANGE));
    if *last_sweep != Some(reading.sweep_id) {
        summary.sweeps += 1;
        *last_sweep = Some(reading.sweep_id);
    }
}

/// A first line whose fields are not all numbers is a header.
fn is_header(record: &[&str]) -> bool {
    record.iter().any(|f| f.parse::<f64>().is_err())
}

fn columns_from_header(record: &[&str], line: u64) -> Result<Vec<Column>, ImportError> {
    // Names this program does not know are columns to leave out (a log's extra fields).
    let columns: Vec<Column> = record
        .iter()
        .map(|name| name.parse().unwrap_or(Column::Skip))
        .collect();
    if !columns.contains(&Column::Angle) || !columns.contains(&Column::Range) {
        return Err(ImportError::Columns(format!(
            "line {line}: the header {record:?} names no `angle` and `range` columns: name them \
             so, or give --columns (e.g. --columns time,angle,range)"
        )));
    }
    Ok(columns)
}

/// Where each value is in a row.
struct Layout {
    width: usize,
    angle: usize,
    range: usize,
    time: Option<usize>,
    pose: Option<[usize; 3]>,
}

/// One row's values, in our units.
struct Row {
    reading: HobbyReading,
    time_ns: Option<u64>,
    pose: Option<(f32, f32, f32)>,
}

impl Layout {
    fn of(columns: &[Column]) -> Result<Self, ImportError> {
        let find = |c: Column| {
            let mut at = columns.iter().enumerate().filter(|(_, k)| **k == c);
            match (at.next(), at.next()) {
                (_, Some(_)) => Err(ImportError::Columns(format!(
                    "the column {c:?} is named twice"
                ))),
                (found, None) => Ok(found.map(|(i, _)| i)),
            }
        };
        let required = |c: Column| {
            find(c)?.ok_or_else(|| {
                ImportError::Columns(format!("the columns need {c:?} (given: {columns:?})"))
            })
        };
        let pose = match (find(Column::X)?, find(Column::Y)?, find(Column::Theta)?) {
            (Some(x), Some(y), Some(t)) => Some([x, y, t]),
            (None, None, None) => None,
            _ => {
                return Err(ImportError::Columns(
                    "a pose needs all of x, y and theta".into(),
                ));
            }
        };
        Ok(Self {
            width: columns.len(),
            angle: required(Column::Angle)?,
            range: required(Column::Range)?,
            time: find(Column::Time)?,
            pose,
        })
    }

    fn row(&self, record: &[&str], format: &LogFormat) -> Result<Row, String> {
        if record.len() != self.width {
            return Err(format!(
                "{} fields where the columns are {}",
                record.len(),
                self.width
            ));
        }
        let number = |i: usize, name: &str| -> Result<f64, String> {
            let text = record[i];
            text.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("the {name} {text:?} is not a number"))
        };
        let degrees = |v: f64| match format.angle_unit {
            AngleUnit::Deg => v,
            AngleUnit::Rad => v.to_degrees(),
        };
        let sign = match format.turn {
            Turn::Ccw => 1.0,
            Turn::Cw => -1.0,
        };
        let angle_deg =
            sign * (degrees(number(self.angle, "angle")?) - degrees(f64::from(format.angle_zero)));
        if angle_deg.abs() > 720.0 {
            return Err(format!(
                "the angle {angle_deg}° is more than two turns: wrong --angle-unit?"
            ));
        }
        let range = number(self.range, "range")?;
        if range < 0.0 {
            return Err(format!("the range {range} is negative"));
        }
        let time_ns = match self.time {
            Some(i) => {
                let t = number(i, "time")? * format.time_unit.ns();
                if !(0.0..1.8e19).contains(&t) {
                    return Err(format!("the time {} is negative or too large", &record[i]));
                }
                Some(t as u64)
            }
            None => None,
        };
        let pose = match self.pose {
            Some([x, y, t]) => Some((
                number(x, "x")? as f32,
                number(y, "y")? as f32,
                degrees(number(t, "theta")?).to_radians() as f32,
            )),
            None => None,
        };
        Ok(Row {
            reading: HobbyReading {
                angle_deg: angle_deg as f32,
                distance_cm: (range * f64::from(format.range_unit.cm())) as f32,
            },
            time_ns,
            pose,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_recorder::Message;

    fn run(text: &str, format: &LogFormat) -> Result<(Summary, Vec<Timed>), ImportError> {
        let mut out = Vec::new();
        let summary = import(text.as_bytes(), format, SensorConfig::default(), |m| {
            out.push(m);
            Ok(())
        })?;
        Ok((summary, out))
    }

    fn readings(out: &[Timed]) -> Vec<Reading> {
        out.iter()
            .filter_map(|t| match t.message {
                Message::Reading(r) => Some(r),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn rows_become_the_readings_the_driver_publishes_for_a_hobby_head() {
        let log = "0,100\n3,255\n6,0\n";
        let format = LogFormat {
            no_echo: "255".parse().unwrap(),
            ..LogFormat::default()
        };
        let (summary, out) = run(log, &format).unwrap();
        let mut live = Decoder::new(
            Dialect::Hobby,
            SensorConfig::default(),
            PingPolicy::default(),
            0.0,
        )
        .hobby_no_echo(format.no_echo);
        let expected: Vec<Reading> = ["0,100", "3,255", "6,0"]
            .iter()
            .enumerate()
            .map(|(i, line)| {
                match live
                    .decode(line.as_bytes(), i as u64 * format.period_ns)
                    .unwrap()
                {
                    sonar_driver::decoder::Decoded::Reading(r) => r,
                    other => panic!("{other:?}"),
                }
            })
            .collect();
        assert_eq!(readings(&out), expected);
        assert_eq!(
            (summary.readings, summary.no_echo, summary.poses),
            (3, 2, 0)
        );
    }

    #[test]
    fn a_header_names_the_columns_and_units_direction_and_zero_apply() {
        let log = "# a robot's log\ntime,x,y,theta,angle,range,quality\n\
                   0.5,1.0,2.0,90,90,1.5,7\n0.75,1.0,2.0,90,93,1.6,7\n";
        let format = LogFormat {
            range_unit: RangeUnit::M,
            turn: Turn::Cw,
            angle_zero: 90.0,
            ..LogFormat::default()
        };
        let (summary, out) = run(log, &format).unwrap();
        assert!(summary.header);
        assert_eq!((summary.readings, summary.poses), (2, 2));
        let Message::Pose(p) = out[0].message else {
            panic!("{out:?}")
        };
        assert_eq!((p.stamp_ns, p.x_m, p.y_m), (500_000_000, 1.0, 2.0));
        assert!((p.theta_rad - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        let r = readings(&out);
        assert_eq!((r[0].angle_deg, r[1].angle_deg), (0.0, -3.0));
        assert!((r[1].distance_m - 1.6).abs() < 1e-3, "{:?}", r[1]);
        assert_eq!(r[1].host_stamp_ns, 750_000_000);
    }

    #[test]
    fn a_malformed_row_is_an_error_naming_its_line() {
        let cases = [
            ("0,100\n3,1o0\n", 2, "not a number"),
            ("# log\r\n0,100\r\n\r\n3\r\n", 4, "1 fields"),
            ("0,100\n3,-4\n", 2, "negative"),
            ("a,b\n0,1\n", 1, "angle"),
        ];
        for (log, line, what) in cases {
            let err = run(log, &LogFormat::default()).unwrap_err().to_string();
            assert!(
                err.contains(&format!("line {line}")) && err.contains(what),
                "{log:?}: {err}"
            );
        }
        let timed = LogFormat {
            columns: Some(vec![Column::Time, Column::Angle, Column::Range]),
            ..LogFormat::default()
        };
        let err = run("1,0,100\n0.5,3,100\n", &timed).unwrap_err().to_string();
        assert!(err.starts_with("line 2: the time goes back"), "{err}");
        assert!(matches!(
            run("# nothing\n", &LogFormat::default()),
            Err(ImportError::Empty)
        ));
    }

    #[test]
    fn tabs_radians_and_millimetres() {
        let format = LogFormat {
            delimiter: b'\t',
            angle_unit: AngleUnit::Rad,
            range_unit: RangeUnit::Mm,
            ..LogFormat::default()
        };
        let (_, out) = run("0.5\t1200\n", &format).unwrap();
        let r = readings(&out)[0];
        assert!((r.angle_deg - 28.6479).abs() < 1e-3, "{r:?}");
        assert!((r.distance_m - 1.2).abs() < 1e-3, "{r:?}");
    }
}
