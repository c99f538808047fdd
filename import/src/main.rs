//! `sonar-import`: a CSV/TSV log of angle and range (with or without time and poses) into a sonar
//! recording. The file is written under a temporary name beside the output and renamed at the end,
//! so a malformed row or a failure leaves nothing half-written.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::Parser;
use sonar_common::sensor::SensorConfig;
use sonar_driver::decoder::NoEcho;
use sonar_import::{AngleUnit, Column, ImportError, LogFormat, RangeUnit, TimeUnit, Turn, import};
use sonar_recorder::RecordingWriter;
use tracing::info;

/// Rows between two progress lines of a long log.
const PROGRESS_ROWS: u64 = 100_000;

/// Brings a log you already have — a CSV or TSV with one reading per row: the beam's angle and the
/// range, optionally a time and the robot's pose — into a sonar recording (MCAP, docs/recording.md)
/// that sonar-replay, sonar-export, sonar-pipeline --replay and the viewer use like any other.
///
/// Each row becomes the reading the driver publishes for the same angle and range from a hobby
/// sketch (--dialect hobby): a reversal of the angle, or the wrap of a head that turns a full
/// circle, starts a new sweep; the no-echo value and ranges outside the sensor's are never
/// obstacles. Lines starting with # are comments; a first line of names is a header (its columns
/// angle, range, time, x, y, theta are used, others left out). A malformed row stops the import
/// with its line number, and nothing is written.
///
/// Examples:
///   # scan.csv:   angle,range        (degrees counter-clockwise from ahead, cm)
///   #             0,120
///   #             3,255               (255 = no echo)
///   sonar-import scan.csv scan.mcap --no-echo 255
///   sonar-export --from-recording scan.mcap --out scan          # scan.png, .pgm/.yaml, .csv, .npy
///   sonar-pipeline --replay scan.mcap                           # the map in the viewer
///
///   # a servo log in mm, bearings clockwise with 90 ahead, tab-separated, time in ms, robot poses
///   sonar-import run.tsv run.mcap --columns time,angle,range,x,y,theta --range-unit mm \
///       --angle-direction cw --angle-zero 90 --time-unit ms
#[derive(Debug, Parser)]
#[command(name = "sonar-import", version, verbatim_doc_comment)]
struct Args {
    /// The log: CSV or TSV text.
    input: PathBuf,
    /// The recording to write (.mcap).
    output: PathBuf,
    /// Replace the output if it exists.
    #[arg(long)]
    overwrite: bool,
    /// The columns in order, comma-separated: angle, range (both required), time, x, y, theta
    /// (the robot's pose: metres, and its heading in --angle-unit), `-` for one to leave out
    /// [default: from the header line, else angle,range].
    #[arg(long, value_delimiter = ',')]
    columns: Option<Vec<Column>>,
    /// Field separator: `,`, `;`, `|`, `tab` [default: tab for .tsv files, else `,`].
    #[arg(long, value_parser = parse_delimiter)]
    delimiter: Option<u8>,
    /// Unit of the ranges.
    #[arg(long, value_enum, default_value_t = RangeUnit::Cm)]
    range_unit: RangeUnit,
    /// Unit of the angles (the beam's and the pose's heading).
    #[arg(long, value_enum, default_value_t = AngleUnit::Deg)]
    angle_unit: AngleUnit,
    /// Which way the log's angles grow, seen from above: ccw (ours) or cw (compass bearings).
    #[arg(long, value_enum, default_value_t = Turn::Ccw)]
    angle_direction: Turn,
    /// The log's angle (in --angle-unit) that points straight ahead (e.g. 90 for a servo sketch).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    angle_zero: f32,
    /// The range (in --range-unit) that means no echo: `0` (always), a value such as `255`, or a
    /// value and beyond such as `400+`.
    #[arg(long, default_value = "0", value_name = "RANGE")]
    no_echo: NoEcho,
    /// Unit of the time column.
    #[arg(long, value_enum, default_value_t = TimeUnit::S)]
    time_unit: TimeUnit,
    /// Seconds between rows of a log without a time column.
    #[arg(long, default_value = "0.1", value_parser = sonar_common::parse_positive_seconds)]
    period: Duration,
    /// Beam half-angle stamped on the readings, degrees (the paper's ±30°; an HC-SR04's ≈ 15°).
    #[arg(long, default_value_t = 30.0)]
    beam_half_angle: f32,
    /// The sensor's farthest range, metres: farther ranges are out of range, never obstacles.
    #[arg(long, default_value_t = 4.0)]
    max_range: f32,
}

fn parse_delimiter(s: &str) -> Result<u8, String> {
    match s {
        "tab" | "\\t" | "\t" => Ok(b'\t'),
        "," | ";" | "|" => Ok(s.as_bytes()[0]),
        _ => Err(format!("expected `,`, `;`, `|` or `tab`, got {s:?}")),
    }
}

fn main() -> std::process::ExitCode {
    sonar_common::init_tracing();
    sonar_common::report_exit("sonar-import", run(Args::parse()))
}

fn run(args: Args) -> Result<()> {
    let sensor = SensorConfig {
        beam_half_angle_deg: args.beam_half_angle,
        max_range_m: args.max_range,
        ..SensorConfig::default()
    };
    sensor.validate().context("invalid sensor settings")?;
    if args.output.exists() && !args.overwrite {
        bail!("{} exists (--overwrite replaces it)", args.output.display());
    }
    let is_tsv = args
        .input
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("tsv"));
    let format = LogFormat {
        columns: args.columns.clone(),
        delimiter: args.delimiter.unwrap_or(if is_tsv { b'\t' } else { b',' }),
        range_unit: args.range_unit,
        angle_unit: args.angle_unit,
        turn: args.angle_direction,
        angle_zero: args.angle_zero,
        time_unit: args.time_unit,
        period_ns: u64::try_from(args.period.as_nanos()).unwrap_or(u64::MAX),
        no_echo: args.no_echo,
    };
    let input =
        File::open(&args.input).with_context(|| format!("cannot open {}", args.input.display()))?;
    let temp = TempFile::beside(&args.output)?;
    let mut metadata = BTreeMap::new();
    metadata.insert("imported_from".to_owned(), args.input.display().to_string());
    let mut writer = RecordingWriter::create(&temp.path, true, &metadata)
        .with_context(|| format!("cannot write {}", temp.path.display()))?;
    let mut rows = 0u64;
    let summary = import(BufReader::new(input), &format, sensor, |timed| {
        writer.write(timed.stamp_ns, &timed.message)?;
        rows += 1;
        if rows.is_multiple_of(PROGRESS_ROWS) {
            info!(messages = rows, "importing");
        }
        Ok::<(), ImportError>(())
    })
    .with_context(|| format!("{} not imported", args.input.display()))?;
    writer
        .finish()
        .with_context(|| format!("cannot write {}", temp.path.display()))?;
    temp.rename_to(&args.output, args.overwrite)?;
    info!(
        readings = summary.readings,
        no_echo = summary.no_echo,
        out_of_range = summary.out_of_range,
        sweeps = summary.sweeps,
        poses = summary.poses,
        header = summary.header,
        "imported {} into {}",
        args.input.display(),
        args.output.display()
    );
    println!("{}", args.output.display());
    Ok(())
}

/// The recording under a temporary name beside its destination (so the rename stays on one file
/// system), removed unless renamed.
struct TempFile {
    path: PathBuf,
    renamed: bool,
}

impl TempFile {
    fn beside(output: &Path) -> Result<Self> {
        let name = output
            .file_name()
            .with_context(|| format!("{} names no file", output.display()))?;
        let mut temp_name = std::ffi::OsString::from(".");
        temp_name.push(name);
        temp_name.push(format!(".{}.tmp", std::process::id()));
        Ok(Self {
            path: output.with_file_name(temp_name),
            renamed: false,
        })
    }

    fn rename_to(mut self, output: &Path, overwrite: bool) -> Result<()> {
        if !overwrite && output.exists() {
            bail!(
                "{} appeared while importing (--overwrite replaces it)",
                output.display()
            );
        }
        std::fs::rename(&self.path, output)
            .with_context(|| format!("cannot rename the import to {}", output.display()))?;
        self.renamed = true;
        Ok(())
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if !self.renamed {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}
