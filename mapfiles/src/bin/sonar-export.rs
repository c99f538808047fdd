//! `sonar-export`: the occupancy map and the features to files, from a running pipeline or from a
//! recording.
//!
//! Live, it is one more consumer of `sonar/grid`: it sleeps on the grid's wake-up event, takes the
//! first snapshot that satisfies `--wait-readings`/`--sweeps` (without them, the current map, which
//! history 1 hands to a new subscriber; with `--sweeps`, the end-of-sweep snapshot, see [`Wanted`]),
//! writes it and exits. Asked for the features, it also takes the latest `sonar/features` snapshot
//! by then (or the next one, if none has come yet). Offline, it fuses a recording's readings with
//! the fusion engine's own code (grid and feature tracker), so map and features are the ones the
//! live engine would have built from the same readings. Both paths end in the same writers.
//!
//! With `--mcap` it also writes STEM.mcap with the channels Foxglove and ROS 2 tools draw, through
//! the recorder's own writer of them ([`WellKnownChannels`], the one `sonar-record` uses): from a
//! recording, what `sonar-record` would have written beside it (each sweep's scan, the poses, the
//! recorded features) with the maps the offline fusion builds, one at the end of each sweep; live,
//! the snapshot taken (its map, the sensor's pose, the latest features if the fusion publishes any).

use std::collections::{BTreeMap, VecDeque};
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Parser;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::waitset::WaitSetRunResult;
use sonar_common::ipc::{
    self, FusionCommandKind, GridHeader, IpcArgs, IpcError, LAYOUT_VERSION, Reading,
    SlamCorrection, SweepEnd, slam_state,
};
use sonar_fusion::engine::{Engine, SweepEndOutcome};
use sonar_fusion::history::Revised;
use sonar_fusion::poses::MAX_POSE_WAIT;
use sonar_fusion::{
    FeatureTracker, FeaturesSection, FusionConfig, FusionFile, FusionSection, Preset,
};
use sonar_mapfiles::{FeatureFormat, Format, Map, PngOptions, Thresholds, output, write_features};
use sonar_recorder::well_known::Options as WellKnownOptions;
use sonar_recorder::{
    FeatureSnapshot, Message, ReadOptions, Recording, RecordingWriter, Ros2Bag, Topic,
    WellKnownChannels,
};
use tracing::{debug, info, warn};

/// Readings the offline engine keeps for re-fusing on a recorded preset/model/rule switch; the
/// same as `sonar-fusion --history`'s default, so both build the same map.
const OFFLINE_HISTORY: usize = 20_000;
/// How long the live wait is quiet before it says that no fusion publishes a map, and how often
/// it says it again.
const NO_FUSION_HINT_AFTER: Duration = Duration::from_secs(3);
const NO_FUSION_HINT_EVERY: Duration = Duration::from_secs(10);
/// How often the live wait looks at the clock (for --timeout) and for a missed wake-up.
const TICK: Duration = Duration::from_millis(500);

/// Writes the sonar occupancy map as files: a PNG in the viewer's colours with a scale bar, a ROS
/// map_server map (PGM + YAML), the probabilities as CSV or as a NumPy .npy array; and, when asked
/// for, the walls, corners and posts of sonar/features as CSV or JSON.
///
/// Live (default): takes the map from sonar/grid of the running pipeline (same --iox-* settings as
/// sonar-fusion), writes it and exits. Without --wait-readings/--sweeps that is the current map.
/// The features are the latest sonar/features snapshot by then, or the next one (the fusion
/// publishes one per sweep).
///
/// Offline (--from-recording): fuses the readings of a sonar-record file with the fusion engine
/// (poses and fusion commands as recorded) and writes the final map and features. The readings lie
/// where the odometry (robot/pose) put them, unless --localize corrects it anew or
/// --slam-correction takes the corrections sonar-slam published while recording (sonar-record
/// keeps them), as sonar-fusion does with the same flags.
///
/// Files are named after --out without its extension: STEM.png, STEM.pgm + STEM.yaml, STEM.csv,
/// STEM.npy, STEM.features.csv, STEM.features.json, STEM.mcap; missing directories are created.
/// Their paths are printed on standard output. See docs/export.md for the conventions.
///
/// --mcap writes STEM.mcap for Foxglove (and with --ros2 for ROS 2 tools; docs/foxglove.md): from a
/// recording, the map (re-fused, at most one every --grid-period), each sweep as a laser scan, the
/// frames map → odom → sonar (map → odom the correction the readings were placed with: identity,
/// --localize's or the recorded SLAM's) and the recorded features; live, the map taken, the
/// sensor's pose and the latest features.
///
/// Examples:
///   sonar-export --format png --out room.png
///   sonar-export --format png --features --out room   # walls, corners, posts over the map
///   sonar-export --format all --out maps/room --sweeps 2
///   sonar-export --format pgm --out map --from-recording run.mcap --preset paper
///   sonar-export --format features-csv,features-json --out maps/room
///   sonar-export --mcap --ros2 --out room --from-recording old.mcap   # room.mcap for Foxglove, RViz
///   sonar-export --mcap --out tour --from-recording tour.mcap --slam-correction
///   ros2 run nav2_map_server map_server --ros-args -p yaml_filename:=map.yaml
///
/// Exit status: 0 written, 1 error, 130 interrupted (Ctrl-C/SIGTERM) before a map arrived.
#[derive(Debug, Parser)]
#[command(name = "sonar-export", version, verbatim_doc_comment)]
struct Args {
    /// Formats, comma-separated: png, pgm (with its YAML), csv, npy, or all (these four map
    /// formats); features-csv, features-json (the features, only when named). [default: all,
    /// none with --mcap]
    #[arg(long, value_delimiter = ',', value_parser = parse_formats)]
    format: Vec<Formats>,
    /// Also write STEM.mcap: the map as foxglove.Grid, the sweeps as foxglove.LaserScan, the
    /// sensor's pose as foxglove.FrameTransform, the features as foxglove.SceneUpdate.
    #[arg(long)]
    mcap: bool,
    /// With --mcap: also /map, /scan and /tf as ROS 2 messages (CDR), for `ros2 bag play`.
    #[arg(long, requires = "mcap")]
    ros2: bool,
    /// With --mcap from a recording: seconds (of the recording's time) between the maps written;
    /// the last is always written.
    #[arg(long, value_name = "SECONDS", default_value = "5", value_parser = sonar_common::parse_positive_seconds)]
    grid_period: Duration,
    /// Output path: the files' stem (an extension like .png or .features.csv is dropped), or an
    /// existing directory (files named sonar-map.* in it). Existing files are replaced, missing
    /// directories created.
    #[arg(long, default_value = "sonar-map", value_name = "PATH")]
    out: PathBuf,
    /// PNG without the legend strip (scale bar, colour ramp): exactly one pixel per cell.
    #[arg(long)]
    no_legend: bool,
    /// The ROS map's (pgm) occupied threshold, 0.5 to 0.99: cells above it are black in the PGM
    /// and the YAML's `occupied_thresh` says it. 0.65 is what map_saver writes; a higher one
    /// leaves out the weakly held cells, where most of a sonar map's wrong ones are
    /// (docs/results.md, "The grid as a ROS map reads it", by sensor).
    #[arg(long, value_name = "P", default_value = "0.65", value_parser = parse_occupied_thresh)]
    occupied_thresh: Thresholds,
    /// Draw the walls, corners and posts (sonar/features, or the offline feature tracker's) over
    /// the PNG in green, as the viewer's overlay (`o`) does: walls as lines, corners as crosses,
    /// posts as squares. A sonar map of a room is arcs, not walls (README, "What a sonar map
    /// looks like"): the overlay shows the walls found in it. Live, waits for a features snapshot.
    #[arg(long)]
    features: bool,
    /// Live: wait for a map with at least N readings fused.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 0,
        conflicts_with = "from_recording"
    )]
    wait_readings: u64,
    /// Live: wait until N sweeps have ended (the one in progress at the start counts) and write
    /// the map published at the end of the Nth, which shows once the next sweep begins.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 0,
        conflicts_with = "from_recording"
    )]
    sweeps: u32,
    /// Live: give up (exit status 1) if no suitable map arrived within this many seconds
    /// [default: wait until one comes, saying every 10 s when no fusion publishes maps].
    #[arg(long, value_name = "SECONDS", conflicts_with = "from_recording")]
    timeout: Option<f64>,
    /// Offline: fuse the readings of this recording (sonar-record's MCAP file) instead.
    #[arg(long, value_name = "FILE")]
    from_recording: Option<PathBuf>,
    /// Offline: the pipeline's configuration file; its `[fusion]` and `[features]` tables are
    /// read as `sonar-fusion` reads them (grid, model, rule, `localize`), so the export fuses the
    /// recording as the pipeline did.
    #[arg(long, value_name = "FILE", requires = "from_recording")]
    config: Option<PathBuf>,
    /// Offline: fusion settings, `paper` or `recommended` (default, as sonar-fusion); with
    /// --config, replaces the file's model and rule, as `sonar-fusion --preset` does.
    #[arg(long, value_parser = parse_preset, requires = "from_recording")]
    preset: Option<Preset>,
    /// Offline: localise each sweep against the features to correct the recorded odometry, as
    /// `sonar-fusion --localize` does (`[features] localize = true` in --config does the same).
    #[arg(long, requires = "from_recording")]
    localize: bool,
    /// Offline: place the readings with the corrections of the odometry that sonar-slam published
    /// while the recording was made (sonar/slam_correction, kept by sonar-record), earlier sweeps
    /// moved where its later estimates put them, as `sonar-fusion --slam-correction` does
    /// (`[fusion] slam_correction = true` or `[slam] enabled = true` in --config do the same).
    #[arg(long, requires = "from_recording", conflicts_with = "localize")]
    slam_correction: bool,
    /// Offline: ignore the recorded fusion commands (clear, preset/model/rule switches), so every
    /// reading is fused with --preset.
    #[arg(long, requires = "from_recording")]
    ignore_fusion_commands: bool,
    /// Offline: accept a recording that ends early (a recorder that was killed).
    #[arg(long, requires = "from_recording")]
    allow_truncated: bool,
    #[command(flatten)]
    ipc: IpcArgs,
}

/// What `--format` asks for: map formats and features formats (one item, or all of them).
#[derive(Debug, Clone, Default)]
struct Formats {
    maps: Vec<Format>,
    features: Vec<FeatureFormat>,
}

/// `--occupied-thresh`: a probability from 0.5 to 0.99.
fn parse_occupied_thresh(s: &str) -> Result<Thresholds, String> {
    let p: f32 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a number (e.g. 0.65)"))?;
    Thresholds::occupied_above(p).map_err(|e| e.to_string())
}

fn parse_formats(s: &str) -> Result<Formats, String> {
    if s.eq_ignore_ascii_case("all") {
        return Ok(Formats {
            maps: Format::ALL.to_vec(),
            features: Vec::new(),
        });
    }
    if let Ok(f) = s.parse::<Format>() {
        return Ok(Formats {
            maps: vec![f],
            features: Vec::new(),
        });
    }
    s.parse::<FeatureFormat>()
        .map(|f| Formats {
            maps: Vec::new(),
            features: vec![f],
        })
        .map_err(|_| {
            format!(
                "unknown format {s:?}: expected png, pgm, csv, npy, all, features-csv or \
                 features-json"
            )
        })
}

/// A grid snapshot: its header and cells.
type Grid = (GridHeader, Vec<u8>);

/// What is exported: the map, and the features if they were asked for.
struct Snapshot {
    grid: Grid,
    features: Option<FeatureSnapshot>,
}

fn parse_preset(s: &str) -> Result<Preset, String> {
    s.parse().map_err(|e| format!("{e}"))
}

/// How a run ended without an error.
enum Outcome {
    Written(Vec<PathBuf>),
    Interrupted,
}

fn main() -> ExitCode {
    sonar_common::init_tracing();
    let args = Args::parse();
    match run(&args) {
        Ok(Outcome::Written(paths)) => {
            for path in paths {
                println!("{}", path.display());
            }
            ExitCode::SUCCESS
        }
        Ok(Outcome::Interrupted) => {
            eprintln!("sonar-export: interrupted before a map arrived; nothing written");
            ExitCode::from(130)
        }
        Err(e) => sonar_common::report_exit("sonar-export", Err(e)),
    }
}

fn run(args: &Args) -> Result<Outcome> {
    let mut formats = Formats::default();
    let default = [parse_formats("all").map_err(anyhow::Error::msg)?];
    let asked = match (args.format.is_empty(), args.mcap) {
        (true, false) => &default[..],
        _ => &args.format[..],
    };
    for f in asked {
        formats.maps.extend(&f.maps);
        formats.features.extend(&f.features);
    }
    formats.maps.sort();
    formats.maps.dedup();
    formats.features.sort();
    formats.features.dedup();
    if let Some(t) = args.timeout
        && !(t.is_finite() && t > 0.0)
    {
        bail!("--timeout must be a positive number of seconds");
    }
    if args.features && !formats.maps.contains(&Format::Png) {
        bail!("--features draws on the PNG: add png to --format (or leave --format out for all)");
    }
    let with_features = !formats.features.is_empty() || args.features;
    let stem = output::stem(&args.out);
    if let Some(dir) = stem.parent()
        && !dir.as_os_str().is_empty()
    {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create the output directory {}", dir.display()))?;
    }
    let mut written = Vec::new();
    let mcap_path = stem.with_extension("mcap");
    let mut mcap = args
        .mcap
        .then(|| McapExport::create(&mcap_path, args))
        .transpose()?;
    let snapshot = match &args.from_recording {
        Some(file) => from_recording(file, args, with_features, mcap.as_mut())?,
        None => {
            let features = match (with_features, args.mcap) {
                (true, _) => LiveFeatures::Required,
                (false, true) => LiveFeatures::IfPublisher,
                (false, false) => LiveFeatures::No,
            };
            match live(args, features)? {
                Some(snapshot) => {
                    if let Some(mcap) = &mut mcap {
                        mcap.snapshot(&snapshot)?;
                    }
                    snapshot
                }
                None => return Ok(Outcome::Interrupted),
            }
        }
    };
    if let Some(mcap) = mcap {
        let messages = mcap.finish()?;
        info!(messages, file = %mcap_path.display(), "Foxglove channels written");
        written.push(mcap_path);
    }
    let (header, cells) = &snapshot.grid;
    if !formats.maps.is_empty() {
        let map = Map::new(header, cells).context("the map is unusable")?;
        let png = PngOptions {
            legend: !args.no_legend,
            features: snapshot
                .features
                .as_ref()
                .filter(|_| args.features)
                .map(|f| f.records.as_slice()),
        };
        written.extend(sonar_mapfiles::write_map(
            &map,
            &stem,
            &formats.maps,
            &png,
            &args.occupied_thresh,
        )?);
        info!(
            readings = header.readings_fused,
            seq = header.seq,
            "map written"
        );
    }
    if let Some(features) = snapshot
        .features
        .as_ref()
        .filter(|_| !formats.features.is_empty())
    {
        written.extend(write_features(
            &features.header,
            &features.records,
            &stem,
            &formats.features,
        )?);
        info!(
            features = features.records.len(),
            sweeps = features.header.sweeps,
            "features written"
        );
    }
    Ok(Outcome::Written(written))
}

/// Which snapshot [`Wanted::offer`] picks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Take {
    Nothing,
    /// The snapshot just offered.
    Current,
    /// The one offered before it: the map at the end of the sweep that just ended.
    Previous,
}

/// Which live snapshot to export: the first map with at least `readings` readings fused and at least
/// `sweeps` sweeps that ended while we watched (the one in progress at the start included).
///
/// The fusion engine publishes a snapshot at the end of every sweep (unless sweeps end faster than
/// its `--max-snapshot-rate`), before it fuses the first
/// reading of the next, and that snapshot still carries the old `sweep_id`: a sweep is seen to
/// have ended only with the next snapshot. If no snapshot came between the two (consecutive
/// `seq`), the earlier one is the map at the end of the sweep, without readings of the next one.
#[derive(Debug, Default)]
struct Wanted {
    readings: u64,
    sweeps: u32,
    ended: u32,
    /// Sequence number, sweep and readings of the previous snapshot.
    last: Option<(u64, u32, u64)>,
}

impl Wanted {
    fn new(readings: u64, sweeps: u32) -> Self {
        Self {
            readings,
            sweeps,
            ..Self::default()
        }
    }

    /// Takes the next snapshot's header; says whether to write it, the previous one, or neither.
    fn offer(&mut self, h: &GridHeader) -> Take {
        let previous = self.last.replace((h.seq, h.sweep_id, h.readings_fused));
        let mut sweep_ended = false;
        if let Some((_, sweep, readings)) = previous {
            if h.readings_fused < readings {
                // The map was cleared: the sweeps seen so far are gone from it.
                self.ended = 0;
            } else if h.sweep_id != sweep && readings > 0 {
                self.ended += 1;
                sweep_ended = true;
            }
        }
        if self.ended < self.sweeps {
            return Take::Nothing;
        }
        if sweep_ended
            && self.ended == self.sweeps
            && let Some((seq, _, readings)) = previous
            && seq.wrapping_add(1) == h.seq
            && readings >= self.readings
        {
            return Take::Previous;
        }
        if h.readings_fused >= self.readings {
            Take::Current
        } else {
            Take::Nothing
        }
    }
}

/// Whether a live export takes the features.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LiveFeatures {
    No,
    /// Waits for a snapshot if the fusion publishes features (it re-offers its latest every second
    /// when idle), else none: a fusion run with `--no-features` has no publisher on the service.
    IfPublisher,
    /// Waits for a snapshot.
    Required,
}

/// Waits for the wanted snapshot on `sonar/grid` (and for a `sonar/features` snapshot, as
/// `features` says) and copies it out; `None` on SIGINT/SIGTERM.
fn live(args: &Args, features: LiveFeatures) -> Result<Option<Snapshot>> {
    let mut with_features = features == LiveFeatures::Required;
    let node = args.ipc.node("sonar-export")?;
    let subscriber = ipc::grid_service(&node)?
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new("create grid subscriber", e))?;
    let mut listeners = vec![ipc::wakeup_listener(&node, ipc::GRID_SERVICE)?];
    let features = if features != LiveFeatures::No {
        let service = ipc::features_service(&node)?;
        with_features |= service.dynamic_config().number_of_publishers() > 0;
        let subscriber = service
            .subscriber_builder()
            .create()
            .map_err(|e| IpcError::new("create features subscriber", e))?;
        listeners.push(ipc::wakeup_listener(&node, ipc::FEATURES_SERVICE)?);
        Some(subscriber)
    } else {
        None
    };
    let waitset = WaitSetBuilder::new()
        .create::<Ipc>()
        .map_err(|e| IpcError::new("create waitset", e))?;
    let _wakeups = listeners
        .iter()
        .map(|l| waitset.attach_notification(l))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| IpcError::new("attach listener", e))?;
    let _tick = waitset
        .attach_interval(TICK)
        .map_err(|e| IpcError::new("attach interval", e))?;

    let mut wanted = Wanted::new(args.wait_readings, args.sweeps);
    let deadline = args
        .timeout
        .map(|t| Instant::now() + Duration::from_secs_f64(t));
    let namespace = args.ipc.describe();
    info!(
        wait_readings = args.wait_readings,
        sweeps = args.sweeps,
        with_features,
        "waiting for a map on {} ({namespace})",
        ipc::GRID_SERVICE
    );
    let grid_service = ipc::grid_service(&node)?;
    let started = Instant::now();
    let mut last_hint: Option<Instant> = None;
    let mut seen = 0u64;
    // A copy of the previous snapshot, which may turn out to be the end of the last wanted sweep.
    let mut previous: Option<Grid> = None;
    let mut map: Option<Grid> = None;
    let mut latest_features: Option<FeatureSnapshot> = None;
    loop {
        // Every wake-up (event or tick) ends in the same check of the subscribers, so a missed
        // event delays a snapshot by one tick at most.
        let result = waitset
            .wait_and_process_once(|_| CallbackProgression::Continue)
            .map_err(|e| IpcError::new("wait", e))?;
        if matches!(
            result,
            WaitSetRunResult::Interrupt | WaitSetRunResult::TerminationRequest
        ) {
            return Ok(None);
        }
        for listener in &listeners {
            if let Err(e) = listener.try_wait(|_| {}) {
                warn!("listener: {e:?}");
            }
        }
        if let Some(features) = &features {
            while let Some(sample) = features
                .receive()
                .map_err(|e| IpcError::new("receive features snapshot", e))?
            {
                let header = *sample.user_header();
                if header.layout_version != LAYOUT_VERSION {
                    warn!(
                        version = header.layout_version,
                        "features snapshot of another layout version ignored"
                    );
                    continue;
                }
                debug!(seq = header.seq, sweeps = header.sweeps, "features");
                latest_features = Some(FeatureSnapshot {
                    header,
                    records: sample.payload().to_vec(),
                });
            }
        }
        while map.is_none()
            && let Some(sample) = subscriber
                .receive()
                .map_err(|e| IpcError::new("receive grid snapshot", e))?
        {
            let header = *sample.user_header();
            if header.layout_version != LAYOUT_VERSION {
                warn!(
                    version = header.layout_version,
                    "grid snapshot of another layout version ignored"
                );
                continue;
            }
            seen += 1;
            debug!(
                seq = header.seq,
                sweep = header.sweep_id,
                readings = header.readings_fused,
                "snapshot"
            );
            match wanted.offer(&header) {
                Take::Current => map = Some((header, sample.payload().to_vec())),
                Take::Previous if previous.is_some() => map = previous.take(),
                Take::Previous | Take::Nothing if args.sweeps > 0 => {
                    previous = Some((header, sample.payload().to_vec()));
                }
                Take::Previous | Take::Nothing => {}
            }
        }
        if map.is_some() && (!with_features || latest_features.is_some()) {
            return Ok(map.map(|grid| Snapshot {
                grid,
                features: latest_features,
            }));
        }
        // Nothing publishes the map: most likely no pipeline runs on this namespace. Said after a
        // few seconds and then every so often, so a wait that will never end does not look hung.
        let now = Instant::now();
        if map.is_none()
            && grid_service.dynamic_config().number_of_publishers() == 0
            && now.duration_since(started) >= NO_FUSION_HINT_AFTER
            && last_hint.is_none_or(|t| now.duration_since(t) >= NO_FUSION_HINT_EVERY)
        {
            last_hint = Some(now);
            warn!(
                "still waiting: nothing publishes {} on {namespace}. Is sonar-fusion running, \
                 with the same --iox-prefix and --iox-root as this command (`sonar services` \
                 lists what runs there)? --timeout gives up after a while",
                ipc::GRID_SERVICE
            );
        }
        if let Some(deadline) = deadline
            && Instant::now() >= deadline
        {
            if map.is_none() {
                bail!(
                    "no suitable map within --timeout ({seen} snapshots seen on {} on \
                     {namespace}): is sonar-fusion running with the same --iox-prefix/--iox-root, \
                     and the sensor scanning?",
                    ipc::GRID_SERVICE
                );
            }
            bail!(
                "no features within --timeout: sonar-fusion publishes them on {} at the end of \
                 each sweep (is the sensor scanning? does sonar-fusion run without \
                 --no-features?)",
                ipc::FEATURES_SERVICE
            );
        }
    }
}

/// STEM.mcap being written: the well-known channels only (the recording's own stay in the
/// recording).
struct McapExport<W: Write + Seek> {
    writer: RecordingWriter<W>,
    channels: WellKnownChannels,
    /// The newest time written: the end's messages take it, so an export of a recording is
    /// stamped with the recording's times, not the export's.
    last_log_ns: Option<u64>,
}

impl McapExport<BufWriter<File>> {
    fn create(path: &Path, args: &Args) -> Result<Self> {
        let mut extra = BTreeMap::new();
        extra.insert(
            "recorder".to_owned(),
            format!("sonar-export {}", env!("CARGO_PKG_VERSION")),
        );
        if let Some(source) = &args.from_recording {
            extra.insert("source".to_owned(), source.display().to_string());
        }
        let writer = RecordingWriter::create(path, true, &extra)
            .with_context(|| format!("cannot create {}", path.display()))?;
        let bag = args
            .ros2
            .then(|| {
                let dir = Ros2Bag::dir_beside(path);
                Ros2Bag::create(&dir, true)
                    .with_context(|| format!("cannot create the ROS 2 bag {}", dir.display()))
            })
            .transpose()?;
        Self::new(
            writer,
            WellKnownOptions {
                ros2: args.ros2,
                grid_period_ns: u64::try_from(args.grid_period.as_nanos()).unwrap_or(u64::MAX),
            },
            bag,
        )
    }
}

impl<W: Write + Seek> McapExport<W> {
    fn new(
        mut writer: RecordingWriter<W>,
        options: WellKnownOptions,
        bag: Option<Ros2Bag>,
    ) -> Result<Self> {
        let channels = WellKnownChannels::declare(&mut writer, options, bag)
            .context("declare the Foxglove and ROS 2 channels")?;
        Ok(Self {
            writer,
            channels,
            last_log_ns: None,
        })
    }

    fn message(&mut self, log_time_ns: u64, message: &Message) -> Result<()> {
        self.last_log_ns = self.last_log_ns.max(Some(log_time_ns));
        Ok(self
            .channels
            .message(&mut self.writer, log_time_ns, message)?)
    }

    /// The correction the readings are placed with from `stamp_ns` on: the next `map → odom`.
    fn correction(&mut self, stamp_ns: u64, x: f64, y: f64, theta: f64) {
        self.channels.correction(stamp_ns, x, y, theta);
    }

    fn grid(&mut self, log_time_ns: u64, (header, cells): &Grid) -> Result<()> {
        self.last_log_ns = self.last_log_ns.max(Some(log_time_ns));
        Ok(self
            .channels
            .grid(&mut self.writer, log_time_ns, header, cells)?)
    }

    /// A live snapshot: its map (with the sensor's pose) and its features, stamped now.
    fn snapshot(&mut self, snapshot: &Snapshot) -> Result<()> {
        let now = ipc::unix_time_ns();
        self.grid(now, &snapshot.grid)?;
        if let Some(features) = &snapshot.features {
            self.message(now, &Message::Features(features.clone()))?;
        }
        Ok(())
    }

    /// Writes what the converter kept back and the file's end; the well-known messages written.
    fn finish(mut self) -> Result<u64> {
        let end = self.last_log_ns.unwrap_or_else(ipc::unix_time_ns);
        let messages = self.channels.finish(&mut self.writer, end)?;
        self.writer
            .finish()
            .context("write the end of the MCAP file")?;
        Ok(messages)
    }
}

fn from_recording<W: Write + Seek>(
    file: &Path,
    args: &Args,
    with_features: bool,
    mcap: Option<&mut McapExport<W>>,
) -> Result<Snapshot> {
    let recording = sonar_recorder::read_file(
        file,
        ReadOptions {
            allow_truncated: args.allow_truncated,
        },
    )
    .with_context(|| format!("cannot read the recording {}", file.display()))?;
    if recording.truncated {
        warn!("the recording ends early; fusing the messages before the cut");
    }
    let settings = FusionFile::read(args.config.as_deref())?;
    let slam_correction = settings.slam_correction();
    let FusionFile {
        fusion: FusionSection {
            engine: mut config, ..
        },
        features,
        ..
    } = settings;
    if let Some(preset) = args.preset {
        config.use_preset(preset);
    }
    let localize = args.localize || features.localize;
    if localize && !features.enabled {
        bail!("localisation needs the features: [features] enabled = false in the config file");
    }
    let corrections = recording.count(Topic::SlamCorrection);
    let placement = match (localize, args.slam_correction || slam_correction) {
        (true, true) => bail!(
            "the readings are placed by the export's own localisation (--localize, [features] \
             localize) or by the recorded SLAM corrections (--slam-correction, [fusion] \
             slam_correction, [slam] enabled), not both"
        ),
        (true, false) => Placement::Localize,
        (false, true) => {
            if corrections == 0 {
                bail!(
                    "the readings are to be placed with the recorded SLAM corrections \
                     (--slam-correction, or [fusion] slam_correction / [slam] enabled in \
                     --config), but {} holds none (was sonar-slam running, and the recording made \
                     by a sonar-record that keeps them?); --localize or a config without them \
                     fuses it at the odometry's poses",
                    file.display()
                );
            }
            Placement::SlamCorrection
        }
        (false, false) => {
            if corrections > 0 {
                info!(
                    corrections,
                    "the recording holds sonar-slam's corrections: the readings stay where the \
                     odometry put them unless --slam-correction"
                );
            }
            Placement::Odometry
        }
    };
    fuse_recording(
        &recording,
        Offline {
            config,
            features,
            placement,
            commands: !args.ignore_fusion_commands,
            with_features,
        },
        mcap,
    )
}

/// Where the offline fusion places the readings, and what the frames' `map → odom` says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Placement {
    /// At the recorded odometry's poses; `map → odom` the identity.
    Odometry,
    /// Corrected by the export's own localisation against the features (`--localize`).
    Localize,
    /// Corrected by the recorded `sonar/slam_correction` (`--slam-correction`).
    SlamCorrection,
}

/// How a recording is fused offline.
struct Offline {
    config: FusionConfig,
    /// The feature settings (the file's `[features]` table).
    features: FeaturesSection,
    /// Where the readings are placed (with `Localize`, the features are extracted).
    placement: Placement,
    /// Whether the recorded fusion commands are carried out.
    commands: bool,
    /// Whether the features are written.
    with_features: bool,
}

/// Replays `recording` into a fusion engine as `sonar-fusion` runs it: readings fused, poses
/// taken, fusion commands applied (if `commands`), in recorded order; with `with_features`, each
/// reading also goes to a feature tracker with `sonar-fusion`'s default `[features]` settings
/// (before the engine fuses it, and cleared with the map, as there). Returns the final snapshot;
/// the last sweep's features are merged at the end, as the fusion does when the readings stop.
/// With `mcap`, every message also goes to its well-known channels, with the map at the end of
/// each sweep (taken before the next sweep's first reading is fused, as the fusion publishes it)
/// and the final one.
fn fuse_recording<W: Write + Seek>(
    recording: &Recording,
    offline: Offline,
    mut mcap: Option<&mut McapExport<W>>,
) -> Result<Snapshot> {
    let Offline {
        config,
        features,
        placement,
        commands,
        with_features,
    } = offline;
    let localize = placement == Placement::Localize;
    let mut engine = Engine::new(config, OFFLINE_HISTORY).context("invalid fusion settings")?;
    // As sonar-fusion: the features' calibration of the sensor's range for the grid too.
    engine.set_range_offset(features.config.range_offset_m as f32);
    let tracker = (with_features || localize)
        .then(|| {
            if localize {
                FeatureTracker::with_localization(features.config)
            } else {
                FeatureTracker::new(features.config)
            }
        })
        .transpose()
        .context("invalid [features] settings")?;
    let mut run = Run {
        engine,
        tracker,
        localize,
        waiting: VecDeque::new(),
        fused: 0,
        refused: 0,
        stamp: 0,
        snapshots: 0,
        corrections: 0,
        revisions: 0,
        pending_end: None,
    };
    for entry in &recording.entries {
        match &entry.message {
            Message::Reading(r) if r.layout_version == LAYOUT_VERSION => {
                run.waiting.push_back((entry.log_time_ns, *r));
            }
            Message::Reading(r) => warn!(
                version = r.layout_version,
                "reading of another layout version ignored"
            ),
            Message::Pose(p) => {
                if let Err(e) = run.engine.set_pose(p) {
                    warn!(pose = ?p, "pose refused: {e}");
                }
            }
            Message::SlamCorrection(c) if placement == Placement::SlamCorrection => {
                run.slam_correction(c);
            }
            Message::SweepEnd(end) => {
                run.pending_end = Some((entry.log_time_ns, *end));
                run.close_ended_sweep(mcap.as_deref_mut())?;
            }
            Message::FusionCommand(c) if commands => {
                // The readings before a command are fused before it, as the fusion receives them.
                run.release(u64::MAX, mcap.as_deref_mut())?;
                match run.engine.apply(c) {
                    Ok(()) => {
                        if let (Some(FusionCommandKind::Clear), Some(tracker)) =
                            (c.kind(), &mut run.tracker)
                        {
                            tracker.clear();
                        }
                    }
                    Err(e) => warn!(command = ?c, "recorded fusion command refused: {e}"),
                }
            }
            // Recorded features are the live fusion's; these are computed anew from the readings.
            // The recorded corrections the readings are not placed with stay out of the frames.
            Message::FusionCommand(_)
            | Message::ScanCommand(_)
            | Message::Features(_)
            | Message::SlamCorrection(_)
            | Message::LocalizedPose(_) => {}
        }
        run.release(entry.log_time_ns, mcap.as_deref_mut())?;
        let placed_with = match &entry.message {
            Message::SlamCorrection(_) => placement == Placement::SlamCorrection,
            Message::LocalizedPose(_) => false,
            _ => true,
        };
        if let Some(mcap) = mcap.as_deref_mut().filter(|_| placed_with) {
            mcap.message(entry.log_time_ns, &entry.message)?;
        }
    }
    run.release(u64::MAX, mcap.as_deref_mut())?;
    run.finish_rebuild();
    let Run {
        mut engine,
        tracker,
        fused,
        refused,
        stamp,
        snapshots,
        corrections: run_corrections,
        revisions: run_revisions,
        ..
    } = run;
    if fused == 0 {
        warn!("the recording holds no usable reading: the map is empty");
    }
    info!(
        fused,
        refused,
        slam_corrections = run_corrections,
        revisions = run_revisions,
        extrapolated_pose = engine.extrapolated_pose_readings(),
        stale_pose = engine.stale_pose_readings(),
        early_pose = engine.early_pose_readings(),
        "recording fused"
    );
    let grid = grid_snapshot(&mut engine, snapshots + 1, stamp);
    if let Some(mcap) = mcap {
        let log_time = recording.entries.last().map_or(stamp, |e| e.log_time_ns);
        mcap.grid(log_time, &grid)?;
    }
    let features = tracker.filter(|_| with_features).map(|mut tracker| {
        tracker.finish_sweep();
        let (header, records) = tracker.snapshot(engine.grid_mut(), 1, stamp);
        FeatureSnapshot { header, records }
    });
    Ok(Snapshot { grid, features })
}

/// An offline fusion under way: the engine, the features, and the readings waiting for the pose
/// that covers their instant.
struct Run {
    engine: Engine,
    tracker: Option<FeatureTracker>,
    localize: bool,
    /// Readings with the log time they were recorded at, in recorded order.
    waiting: VecDeque<(u64, Reading)>,
    fused: u64,
    refused: u64,
    /// The stamp of the last reading fused.
    stamp: u64,
    snapshots: u64,
    /// SLAM corrections taken (`Placement::SlamCorrection`), and the rebuilds of the maps they
    /// caused.
    corrections: u64,
    revisions: u64,
    /// The latest recorded sweep end whose last reading is not fused yet (it waits for its pose).
    pending_end: Option<(u64, SweepEnd)>,
}

impl Run {
    /// Fuses the waiting readings, oldest first, that no longer wait for a pose at the recording's
    /// time `now_ns`: the fusion's pose policy (`sonar_fusion::poses`), a reading newer than the
    /// newest pose waits for the one that covers it, at most `MAX_POSE_WAIT`; the readings behind
    /// it wait with it.
    fn release<W: Write + Seek>(
        &mut self,
        now_ns: u64,
        mut mcap: Option<&mut McapExport<W>>,
    ) -> Result<()> {
        let wait = u64::try_from(MAX_POSE_WAIT.as_nanos()).unwrap_or(u64::MAX);
        while let Some(&(logged_ns, reading)) = self.waiting.front() {
            if self.engine.awaits_pose(reading.host_stamp_ns)
                && now_ns.saturating_sub(logged_ns) < wait
            {
                break;
            }
            self.waiting.pop_front();
            self.fuse(logged_ns, &reading, mcap.as_deref_mut())?;
        }
        Ok(())
    }

    /// A recorded `sonar-slam` correction, taken as `sonar-fusion --slam-correction` takes it: a
    /// new sweep's correction places the readings from now on; every message (revisions too)
    /// moves its sweep's readings where it places them, and the maps are rebuilt from them before
    /// the next reading is fused ([`Self::finish_rebuild`]: once for a burst of revisions, as a
    /// loop closure sends one per sweep it moved).
    fn slam_correction(&mut self, c: &SlamCorrection) {
        let Some(sweep) = self.engine.take_slam_correction(c) else {
            warn!(correction = ?c, "recorded SLAM correction left out: not finite");
            return;
        };
        if c.state != slam_state::REVISED {
            self.corrections += 1;
        }
        match self.engine.revise(&[sweep]) {
            Revised::Unmoved | Revised::Rebuilding(_) => {}
            Revised::Uncovered(moved) => warn!(
                moved,
                sweep = c.sweep_id,
                "a revised sweep's readings are no longer kept: they stay where they were placed"
            ),
        }
    }

    /// Closes the sweep a recorded end names once its last reading is fused, where the live
    /// fusion closed it ([`Engine::sweep_ended`]); a recording without ends closes each sweep on
    /// the next one's first reading, as the fusion does without the driver's word.
    fn close_ended_sweep<W: Write + Seek>(
        &mut self,
        mcap: Option<&mut McapExport<W>>,
    ) -> Result<()> {
        let Some((logged_ns, end)) = self.pending_end.take() else {
            return Ok(());
        };
        match self.engine.sweep_ended(&end) {
            SweepEndOutcome::Early => self.pending_end = Some((logged_ns, end)),
            SweepEndOutcome::Closed { .. } => self.sweep_closed(logged_ns, mcap)?,
            SweepEndOutcome::Stale => {}
        }
        Ok(())
    }

    /// A sweep was closed: its map into the export, as the fusion publishes it then.
    fn sweep_closed<W: Write + Seek>(
        &mut self,
        logged_ns: u64,
        mcap: Option<&mut McapExport<W>>,
    ) -> Result<()> {
        if let Some(mcap) = mcap {
            self.snapshots += 1;
            mcap.grid(
                logged_ns,
                &grid_snapshot(&mut self.engine, self.snapshots, self.stamp),
            )?;
        }
        Ok(())
    }

    /// Completes the rebuild of the maps that revisions started, in one step (offline nothing
    /// waits for it).
    fn finish_rebuild(&mut self) {
        if !self.engine.rebuilding() {
            return;
        }
        if self.engine.rebuild_step(usize::MAX) {
            self.revisions += 1;
        } else {
            warn!("the maps could not be rebuilt where sonar-slam moved the sweeps");
        }
    }

    /// One reading, in the fusion's order: a new sweep's first reading closes the last region
    /// and ends the map of the sweep before it; then the engine fuses the reading; then the
    /// features take it where the engine placed it (and localisation corrects the next).
    fn fuse<W: Write + Seek>(
        &mut self,
        logged_ns: u64,
        r: &Reading,
        mut mcap: Option<&mut McapExport<W>>,
    ) -> Result<()> {
        self.finish_rebuild();
        if self.engine.close_finished_sweep(r).is_some() {
            self.sweep_closed(logged_ns, mcap.as_deref_mut())?;
        }
        if self.engine.fuse(r) {
            self.fused += 1;
        } else {
            self.refused += 1;
        }
        if let Some(tracker) = &mut self.tracker {
            tracker.follow(r, &mut self.engine, self.localize);
            if self.localize
                && let Some(mcap) = mcap.as_deref_mut()
            {
                // The correction the next reading is placed with: the frames say the same.
                let c = tracker.correction();
                mcap.correction(
                    r.host_stamp_ns,
                    f64::from(c.translation.x),
                    f64::from(c.translation.y),
                    f64::from(c.rotation.angle()),
                );
            }
        }
        self.stamp = r.host_stamp_ns;
        self.close_ended_sweep(mcap)
    }
}

/// The engine's map as the fusion publishes it: snapshot number `seq`, stamped `stamp_ns`.
fn grid_snapshot(engine: &mut Engine, seq: u64, stamp_ns: u64) -> Grid {
    let mut cells = vec![0; engine.grid_len()];
    let counts = engine.encode_grid(&mut cells);
    (engine.grid_header(seq, stamp_ns, counts), cells)
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_common::ipc::{FusionCommand, FusionCommandKind, Reading, ScanMode, preset_code};
    use sonar_recorder::Entry;
    use std::io::Cursor;

    #[test]
    fn the_occupied_threshold_is_a_probability_from_a_half_to_0_99() {
        let args = |extra: &[&str]| {
            Args::try_parse_from(["sonar-export"].iter().chain(extra).copied())
                .map(|a| a.occupied_thresh.occupied())
        };
        assert_eq!(args(&[]).unwrap(), 0.65);
        assert_eq!(args(&["--occupied-thresh", "0.8"]).unwrap(), 0.8);
        for bad in ["1.2", "0.3", "high"] {
            let err = args(&["--occupied-thresh", bad]).unwrap_err().to_string();
            assert!(err.contains("--occupied-thresh"), "{err}");
        }
    }

    /// Offers snapshots (seq, sweep, readings) in turn; the answer to each.
    fn offers(mut w: Wanted, snapshots: &[(u64, u32, u64)]) -> Vec<Take> {
        snapshots
            .iter()
            .map(|&(seq, sweep_id, readings_fused)| {
                w.offer(&GridHeader {
                    seq,
                    sweep_id,
                    readings_fused,
                    ..GridHeader::default()
                })
            })
            .collect()
    }

    use Take::{Current, Nothing, Previous};

    #[test]
    fn without_conditions_the_first_snapshot_is_taken() {
        assert_eq!(offers(Wanted::new(0, 0), &[(9, 3, 120)]), [Current]);
        assert_eq!(
            offers(Wanted::new(100, 0), &[(9, 3, 60), (10, 3, 100)]),
            [Nothing, Current]
        );
    }

    #[test]
    fn the_map_at_the_end_of_the_last_wanted_sweep_is_taken() {
        // The empty map at the start, then one snapshot per sweep end (a fast scan).
        let at_sweep_ends = [(1, 0, 0), (2, 1, 50), (3, 2, 100), (4, 3, 150)];
        assert_eq!(
            offers(Wanted::new(0, 2), &at_sweep_ends),
            [Nothing, Nothing, Nothing, Previous]
        );
        // Snapshots within sweeps too: the one before the change is the end of the sweep.
        let within = [(1, 1, 20), (2, 1, 50), (3, 2, 55), (4, 2, 100), (5, 3, 104)];
        assert_eq!(
            offers(Wanted::new(0, 2), &within),
            [Nothing, Nothing, Nothing, Nothing, Previous]
        );
        // A snapshot was missed (seq 5): the previous one may lack the sweep's last readings.
        let gap = [(1, 1, 20), (2, 1, 50), (3, 2, 55), (4, 2, 80), (6, 3, 104)];
        assert_eq!(
            offers(Wanted::new(0, 2), &gap),
            [Nothing, Nothing, Nothing, Nothing, Current]
        );
    }

    #[test]
    fn a_cleared_map_starts_the_count_again_and_readings_are_checked_too() {
        let cleared = [(1, 4, 200), (2, 4, 10), (3, 5, 20), (4, 5, 30)];
        assert_eq!(
            offers(Wanted::new(30, 1), &cleared),
            [Nothing, Nothing, Nothing, Current]
        );
    }

    fn reading(sweep_id: u32, angle_deg: f32, distance_m: f32) -> Reading {
        Reading {
            layout_version: LAYOUT_VERSION,
            sweep_id,
            angle_deg,
            beam_half_angle_deg: 30.0,
            distance_m,
            min_range_m: 0.03,
            max_range_m: 4.0,
            direction: 1,
            mode: ScanMode::Full as u8,
            ..Reading::default()
        }
    }

    /// A wall 1.2 m ahead, one sweep of 50 readings, then a clear, then another sweep.
    fn recording() -> Recording {
        let mut entries = Vec::new();
        let mut push = |message| {
            entries.push(Entry {
                log_time_ns: entries.len() as u64,
                message,
            })
        };
        for sweep in 1..=2 {
            for k in 0..50 {
                let angle = -147.0 + 6.0 * k as f32;
                let d = 1.2 / angle.to_radians().cos().abs().max(0.3);
                push(Message::Reading(reading(sweep, angle, d.min(3.9))));
            }
            if sweep == 1 {
                push(Message::FusionCommand(FusionCommand::new(
                    FusionCommandKind::Clear,
                    0,
                )));
            }
        }
        Recording {
            entries,
            ..Recording::default()
        }
    }

    /// `fuse_recording` without an MCAP to write.
    fn fuse(rec: &Recording, config: FusionConfig, commands: bool, features: bool) -> Snapshot {
        let offline = Offline {
            config,
            features: FeaturesSection::default(),
            placement: Placement::Odometry,
            commands,
            with_features: features,
        };
        fuse_recording::<Cursor<Vec<u8>>>(rec, offline, None).unwrap()
    }

    /// The MCAP of a recording gets a map at the end of each sweep and at the end (every one,
    /// with a period of 0), each with the sensor's transform (no pose source), and a scan a sweep;
    /// one beam (the readings carry one stamp, so the others come within the beam period).
    #[test]
    fn a_recording_s_mcap_has_a_map_and_a_scan_per_sweep() {
        let options = WellKnownOptions {
            ros2: true,
            grid_period_ns: 0,
        };
        let bag_dir = std::env::temp_dir().join(format!("sonar_export_bag_{}", std::process::id()));
        let mut mcap = McapExport::new(
            RecordingWriter::new(Cursor::new(Vec::new()), &BTreeMap::new()).unwrap(),
            options,
            Some(Ros2Bag::create(&bag_dir, true).unwrap()),
        )
        .unwrap();
        let rec = recording();
        let snapshot = fuse_recording(
            &rec,
            Offline {
                config: FusionConfig::default(),
                features: FeaturesSection::default(),
                placement: Placement::Odometry,
                commands: true,
                with_features: false,
            },
            Some(&mut mcap),
        )
        .unwrap();
        assert_eq!(
            snapshot.grid.0.seq, 2,
            "one map at the sweep change, then the last"
        );
        // Two sweeps: 2 maps, 2 scans and 2 transforms (on Foxglove's channel each a pair,
        // map -> odom and odom -> sonar; on ROS 2's one message holding both), each with its
        // ROS 2 message; one beam and the scan that ends the first sweep, each after the
        // sensor's transforms on Foxglove's channel.
        assert_eq!(mcap.finish().unwrap(), 19);
        // The ROS 2 half went to the bag, stamped with the recording's times: its last message
        // (start + duration) is the recording's last, not the time of the export.
        let yaml = std::fs::read_to_string(bag_dir.join("metadata.yaml")).unwrap();
        assert!(yaml.contains("message_count: 6"), "{yaml}");
        let number_after = |key: &str| -> u64 {
            let at = yaml.find(key).unwrap() + key.len();
            yaml[at..]
                .split_whitespace()
                .next()
                .unwrap()
                .parse()
                .unwrap()
        };
        let end = number_after("nanoseconds_since_epoch:") + number_after("nanoseconds:");
        assert_eq!(end, rec.entries.last().unwrap().log_time_ns, "{yaml}");
        let _ = std::fs::remove_dir_all(&bag_dir);
    }

    /// `recording()` written to a file in a directory of its own, with `extra` messages first.
    fn recorded(name: &str, extra: &[Message]) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("sonar_export_{name}_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("run.mcap");
        let mut writer = RecordingWriter::create(&file, true, &BTreeMap::new()).unwrap();
        for (t, m) in extra
            .iter()
            .chain(recording().entries.iter().map(|e| &e.message))
            .enumerate()
        {
            writer.write(t as u64, m).unwrap();
        }
        writer.finish().unwrap();
        file
    }

    /// Asked for the recorded SLAM corrections (by the flag or by the config's keys) of a
    /// recording that has none, or for them and the export's own localisation at once, the
    /// export says so instead of writing the odometry's map.
    #[test]
    fn slam_corrections_asked_of_a_recording_without_them_are_an_error() {
        let file = recorded("no_slam", &[]);
        let config = file.with_file_name("slam.toml");
        std::fs::write(&config, "[slam]\nenabled = true\n").unwrap();
        let export = |extra: &[&str]| {
            let mut words = vec!["sonar-export", "--from-recording", file.to_str().unwrap()];
            words.extend_from_slice(extra);
            let args = Args::parse_from(words);
            from_recording::<Cursor<Vec<u8>>>(&file, &args, false, None).map(|s| s.grid.0)
        };
        for asked in [
            &["--slam-correction"][..],
            &["--config", config.to_str().unwrap()],
        ] {
            let e = format!("{:#}", export(asked).unwrap_err());
            assert!(e.contains("holds none"), "{asked:?}: {e}");
        }
        let both = export(&["--config", config.to_str().unwrap(), "--localize"]);
        assert!(format!("{:#}", both.unwrap_err()).contains("not both"));
        assert_eq!(
            export(&[]).unwrap().readings_fused,
            50,
            "the odometry's map"
        );
        let _ = std::fs::remove_dir_all(file.parent().unwrap());
    }

    /// The row of the x axis.
    fn cell_y(h: &GridHeader) -> usize {
        ((0.0 - h.origin_y_m) / h.resolution_m) as usize
    }

    /// The strongest occupancy along the x axis: its x (m).
    fn wall_x(snapshot: &Snapshot) -> f32 {
        let (h, cells) = &snapshot.grid;
        let map = Map::new(h, cells).unwrap();
        let y = cell_y(h);
        let (x, _) = (0..map.width())
            .filter_map(|x| map.probability(x, y).map(|p| (x, p)))
            .fold(
                (0, 0.0f32),
                |best, (x, p)| if p > best.1 { (x, p) } else { best },
            );
        h.origin_x_m + (x as f32 + 0.5) * h.resolution_m
    }

    /// `sonar-slam` said while recording that the odometry's frame lies 0.5 m along x in the map
    /// (the first sweep's correction revised to it later, the second sweep's given before it):
    /// with `Placement::SlamCorrection` the wall ahead is drawn there for both sweeps, at the
    /// odometry's place without it.
    #[test]
    fn recorded_slam_corrections_place_the_readings_when_asked() {
        let correction = |sweep_id, state| {
            Message::SlamCorrection(SlamCorrection {
                layout_version: LAYOUT_VERSION,
                sweep_id,
                state,
                correction_x_m: 0.5,
                ..SlamCorrection::default()
            })
        };
        let mut entries: Vec<Entry> = Vec::new();
        let mut push = |message| {
            entries.push(Entry {
                log_time_ns: entries.len() as u64,
                message,
            })
        };
        for sweep in 1..=2 {
            if sweep == 2 {
                push(correction(2, slam_state::FIX));
                push(correction(1, slam_state::REVISED));
            }
            for k in 0..50 {
                let angle = -147.0 + 6.0 * k as f32;
                let d = 1.2 / angle.to_radians().cos().abs().max(0.3);
                push(Message::Reading(reading(sweep, angle, d.min(3.9))));
            }
        }
        let rec = Recording {
            entries,
            ..Recording::default()
        };
        let fused = |placement| {
            fuse_recording::<Cursor<Vec<u8>>>(
                &rec,
                Offline {
                    config: FusionConfig::default(),
                    features: FeaturesSection::default(),
                    placement,
                    commands: true,
                    with_features: false,
                },
                None,
            )
            .unwrap()
        };
        let odometry = wall_x(&fused(Placement::Odometry));
        assert!((odometry - 1.2).abs() < 0.05, "wall at {odometry} m");
        let corrected = fused(Placement::SlamCorrection);
        assert_eq!(corrected.grid.0.readings_fused, 100);
        let at = wall_x(&corrected);
        assert!((at - 1.7).abs() < 0.05, "wall at {at} m");
        // Both sweeps moved: nothing is left at the odometry's place.
        let (h, cells) = &corrected.grid;
        let map = Map::new(h, cells).unwrap();
        let cell = |x: f32| ((x - h.origin_x_m) / h.resolution_m) as usize;
        let y = cell_y(h);
        let left = (cell(1.15)..=cell(1.25))
            .filter_map(|x| map.probability(x, y))
            .fold(0.0f32, f32::max);
        assert!(left < 0.5, "p = {left} at the odometry's wall");
    }

    #[test]
    fn a_recording_is_fused_with_its_commands_unless_told_otherwise() {
        let rec = recording();
        let snapshot = fuse(&rec, FusionConfig::default(), true, false);
        assert!(snapshot.features.is_none(), "not asked for");
        let (h, cells) = snapshot.grid;
        assert_eq!(h.readings_fused, 50, "the clear dropped the first sweep");
        assert_eq!(cells.len(), (h.width * h.height) as usize);
        assert_eq!(h.preset, preset_code::RECOMMENDED);
        let map = Map::new(&h, &cells).unwrap();
        // The wall straight ahead is more likely occupied than not after one sweep.
        let x = ((1.2 - h.origin_x_m) / h.resolution_m) as usize;
        let y = ((0.0 - h.origin_y_m) / h.resolution_m) as usize;
        let wall = (x - 2..=x + 2)
            .filter_map(|x| map.probability(x, y))
            .fold(0.0f32, f32::max);
        assert!(wall > 0.5, "{wall}");

        let all = fuse(&rec, FusionConfig::preset(Preset::Paper), false, false);
        assert_eq!(all.grid.0.readings_fused, 100);
        assert_eq!(all.grid.0.preset, preset_code::PAPER);
    }

    /// A reading whose four pings, 1.5° apart, hear a 5 cm post 1 m ahead within ±13.4°.
    fn post_reading(sweep_id: u32, centre_deg: f32) -> Reading {
        let v = 343.2_f32;
        let mut r = Reading {
            speed_of_sound_mps: v,
            ping_count: 4,
            pings_used: 4,
            ..reading(sweep_id, centre_deg, 0.979)
        };
        for j in 0..4 {
            let bearing = centre_deg + 1.5 * (j as f32 - 1.5);
            if bearing.abs() <= 13.4 {
                r.echo_us[j] = (2.0 * 0.979 / v * 1e6).round() as u32;
            }
        }
        r
    }

    /// Three sweeps of the post, a clear after the first.
    fn post_recording() -> Recording {
        let mut entries = Vec::new();
        let mut push = |message| {
            entries.push(Entry {
                log_time_ns: entries.len() as u64,
                message,
            })
        };
        for sweep in 1..=3 {
            for k in 0..50 {
                push(Message::Reading(post_reading(
                    sweep,
                    -147.0 + 6.0 * k as f32,
                )));
            }
            if sweep == 1 {
                push(Message::FusionCommand(FusionCommand::new(
                    FusionCommandKind::Clear,
                    0,
                )));
            }
        }
        Recording {
            entries,
            ..Recording::default()
        }
    }

    #[test]
    fn the_features_of_a_recording_are_tracked_like_the_fusion_does_and_cleared_with_the_map() {
        let rec = post_recording();
        let features = |commands| {
            fuse(&rec, FusionConfig::default(), commands, true)
                .features
                .expect("asked for")
        };
        // The clear forgot sweep 1; sweeps 2 and 3 (the last merged at the end) saw the post.
        let cleared = features(true);
        assert_eq!(cleared.header.feature_count, 1);
        assert_eq!(cleared.header.last_sweep_id, 3);
        let post = cleared.records[0];
        assert_eq!((post.kind, post.times_seen), (ipc::feature_kind::POINT, 2));
        assert!(
            (post.x_m - 0.975).abs() < 0.005 && post.y_m.abs() < 0.005,
            "{post:?}"
        );
        assert!(post.segment_ax_m.is_nan());
        let all = features(false);
        assert_eq!(all.records[0].times_seen, 3, "without the clear");
    }

    #[test]
    fn formats_are_map_or_feature_formats() {
        let f = parse_formats("all").unwrap();
        assert_eq!((f.maps, f.features), (Format::ALL.to_vec(), vec![]));
        let f = parse_formats("features-json").unwrap();
        assert_eq!((f.maps, f.features), (vec![], vec![FeatureFormat::Json]));
        let f = parse_formats("NPY").unwrap();
        assert_eq!((f.maps, f.features), (vec![Format::Npy], vec![]));
        let err = parse_formats("features").unwrap_err();
        assert!(err.contains("features-csv or features-json"), "{err}");
    }
}
