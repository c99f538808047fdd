//! `sonar-fusion`: the compute kernel of the pipeline as its own process.
//!
//! It sleeps on the readings' wake-up event, fuses every reading into both of the paper's maps
//! (see the crate docs), and publishes them as snapshots on `sonar/grid` (header + one byte per
//! cell, written straight into the loaned shared-memory sample) and `sonar/radar`, at most
//! `--max-snapshot-rate` times a second (readings in between are coalesced), and at the end of a sweep
//! unless sweeps end faster than that (see [`Pace`]). Commands on `sonar/fusion_commands` clear
//! the maps or switch model, rule or preset.
//!
//! Two things keep what it does from being lost unnoticed:
//!
//! - **The map is saved** (`sonar_fusion::persist`): at its first change, then every
//!   `--save-period` while it changes, and at SIGINT/SIGTERM, to `--state-file`, and restored at start if it was saved with the same
//!   settings. The readings loop only copies the state; a saver thread encodes, writes and fsyncs
//!   it, so a save holds fusion up for a memory copy, not for the disk.
//! - **Losses are counted** (`sonar_fusion::status`): gaps in the readings' sequence numbers (a
//!   subscriber buffer that overflowed), restarts of the numbering, rejected readings and skipped
//!   snapshots, with the saves, on `sonar/fusion_status`, once a second and at once on news.

use std::collections::{HashMap, VecDeque};
use std::mem::MaybeUninit;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Parser;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::waitset::WaitSetRunResult;
use sonar_common::ipc::{
    self, FeatureRecord, FeaturesHeader, FusionCommand, FusionCommandKind, FusionStatus,
    GRID_SEGMENT_SLOTS, GridHeader, IpcArgs, IpcError, LAYOUT_VERSION, LocalizedPose, MAX_FEATURES,
    Radar, Reading, SlamCorrection, SweepEnd, slam_state, unix_time_ns,
};
use sonar_common::throttle::Throttle;
use sonar_fusion::SavedMap;
use sonar_fusion::engine::{Engine, SweepEndOutcome};
use sonar_fusion::features::SWEEP_IDLE;
use sonar_fusion::history::Revised;
use sonar_fusion::persist::{self, Restore, SaveReport, Saver};
use sonar_fusion::poses::MAX_POSE_WAIT;
use sonar_fusion::status::{Ledger, SeqStep};
use sonar_fusion::{
    EncodedVersion, FeatureTracker, FeaturesSection, FusionConfig, FusionFile, FusionSection,
    ModelConfig, ModelKind, PersistConfig, Preset, RuleConfig, RuleKind, SweepOutcome,
};
use tracing::{debug, info, warn};

/// How often idle publishers offer their last snapshot to subscribers that joined since.
const REFRESH_PERIOD: Duration = Duration::from_secs(1);
/// How often `sonar/fusion_status` is published when nothing happens.
const STATUS_PERIOD: Duration = Duration::from_secs(1);
/// Least time between two log lines about one kind of lost or rejected reading.
const LOG_PERIOD: Duration = Duration::from_secs(1);
/// Readings fused per turn of the loop at most: one subscriber buffer's worth. Under overload the
/// buffer never empties, and commands, status, saves and held-back snapshots must still get turns.
const READINGS_PER_TURN: usize = 256;
/// Readings taken out of the subscriber's buffer and not yet fused, at most: a fusion that falls
/// behind for a while (a sweep merged or a snapshot copied on a loaded machine, a fast replay)
/// keeps them here, 104 B each, instead of letting iceoryx2 overwrite them in its buffer of 256.
/// Beyond this the buffer is left to overflow, and its losses are counted as before: a fusion
/// overloaded for good lags its readings by no more than this and the buffer (2 s of a replay at
/// 1 000 a second), not by all it was ever sent.
const MAX_BACKLOG: usize = 2048;
/// How often robot/pose is looked at while a reading waits for its pose (poses bring no wake-up).
const POSE_POLL: Duration = Duration::from_millis(1);

/// Builds the paper's two maps from `sonar/readings` and publishes them on `sonar/grid` (the
/// probability method's occupancy grid) and `sonar/radar` (the basic method's latest distance per
/// angle); takes commands on `sonar/fusion_commands`.
///
/// Settings come from the `[fusion]` (and `[features]`) tables of --config, then from the flags
/// below; --preset replaces model, rule and no-echo handling, and --model/--rule/--clear-on-no-echo
/// refine it.
///
/// The map is saved to --state-file as soon as it first changes, then every --save-period seconds
/// while it changes, and when the process is stopped (SIGINT, SIGTERM); at start it is restored
/// if it was saved with exactly the same settings (grid, model, rule and all their parameters).
/// Otherwise the fusion starts empty, says why, and keeps the refused file as <state-file>.bad
/// (.bad.1, … when that exists; start with that file and its settings to get that map back; a map saved after a model, rule or preset switch carries the
/// switched settings). A crash, power cut or kill -9 loses at most the readings of the last save
/// period (and of a save still being written), never the previous save.
///
/// Readings that never arrive (gaps in their sequence numbers: the subscriber buffer overflowed)
/// are counted and published with the saves on sonar/fusion_status.
///
/// After each sweep, the walls, corners and posts found in its raw pings are merged into a
/// feature map and published on sonar/features (docs/features.md); the `[features]` table of
/// --config sets them up, --no-features turns them off. A clear command clears them too.
///
/// Readings are placed at the robot's pose from robot/pose, interpolated at each reading's
/// stamp. With --localize, each sweep is also matched against the features to find how far that
/// odometry has drifted; the corrected pose goes out on sonar/localized_pose and the readings
/// that follow are placed with the correction. With --slam-correction the correction comes from
/// sonar-slam instead (sonar/slam_correction, its latest map → odom transform, fix or not); the
/// two exclude each other.
///
/// Examples:
///   sonar-fusion                                  # recommended preset, 400² cells of 2 cm
///   sonar-fusion --preset paper                   # the paper exactly as written
///   sonar-fusion --rule dempster-shafer --cells 800 --resolution-m 0.01
///   sonar-fusion --state-file /var/lib/sonar/map.bin --save-period 2
#[derive(Debug, Parser)]
#[command(version, verbatim_doc_comment)]
struct Args {
    /// Pipeline configuration file (TOML); its `[fusion]` and `[features]` tables are read, the
    /// others ignored.
    #[arg(long, env = "SONAR_CONFIG")]
    config: Option<PathBuf>,
    /// Ready-made settings: `paper` or `recommended` [default: recommended, or the file's].
    #[arg(long, value_parser = parse::<Preset>)]
    preset: Option<Preset>,
    /// Sensor model: `paper`, `log-odds` or `smooth` (with its default parameters) [default: the
    /// preset's: smooth for recommended, paper for paper].
    #[arg(long, value_parser = parse::<ModelKind>)]
    model: Option<ModelKind>,
    /// Combination rule: `bayes`, `log-odds`, `dempster-shafer` or `himm` [default: the preset's:
    /// log-odds for recommended, bayes for paper].
    #[arg(long, value_parser = parse::<RuleKind>)]
    rule: Option<RuleKind>,
    /// Grid cells per side (the grid is square and centred on the sensor's start) [default: 400,
    /// or the file's `[fusion.grid] cells`].
    #[arg(long)]
    cells: Option<u32>,
    /// Cell edge in metres [default: 0.02, or the file's `[fusion.grid] resolution_m`]. Named as
    /// the file's key; `--resolution` still works.
    #[arg(
        long,
        value_name = "METRES",
        alias = "resolution",
        allow_negative_numbers = true
    )]
    resolution_m: Option<f32>,
    /// Fuse readings without an echo as free space up to the maximum range: true or false
    /// [default: false (both presets), or the file's `[fusion] clear_on_no_echo`].
    #[arg(long, value_name = "BOOL")]
    clear_on_no_echo: Option<bool>,
    /// Most grid and radar snapshots published per second; readings in between are coalesced
    /// into the next. (`--max-rate` still works.)
    #[arg(
        long,
        value_name = "PER_SECOND",
        alias = "max-rate",
        default_value_t = 10.0
    )]
    max_snapshot_rate: f64,
    /// Readings kept to re-fuse when model, rule or preset change (0: switching clears the map).
    #[arg(long, default_value_t = 20_000)]
    history: usize,
    /// Where the map is saved and restored from [default: $XDG_STATE_HOME/sonar/fusion-map.bin,
    /// else ~/.local/state/sonar/fusion-map.bin; fusion-map-<prefix>.bin for another
    /// iceoryx2 prefix].
    #[arg(long, value_name = "PATH")]
    state_file: Option<PathBuf>,
    /// Seconds between two saves of a map that changed: at most this much is lost to a crash
    /// [default: 5].
    #[arg(long, value_name = "SECONDS")]
    save_period: Option<f64>,
    /// Neither restore nor save the map.
    #[arg(long)]
    no_persist: bool,
    /// Do not extract walls, corners and posts (no `sonar/features`).
    #[arg(long, conflicts_with = "localize")]
    no_features: bool,
    /// Correct the odometry of robot/pose by matching each sweep's features against the map
    /// (publishes sonar/localized_pose); `[features] localize = true` does the same.
    #[arg(long)]
    localize: bool,
    /// Place readings with sonar-slam's correction of the odometry (sonar/slam_correction, the
    /// latest map → odom transform) instead of localising here; `[fusion] slam_correction = true`
    /// or `[slam] enabled = true` (the pipeline runs sonar-slam) does the same. Excludes
    /// --localize.
    #[arg(long, conflicts_with = "localize")]
    slam_correction: bool,
    #[command(flatten)]
    ipc: IpcArgs,
}

fn parse<T: std::str::FromStr<Err: std::fmt::Display>>(s: &str) -> Result<T, String> {
    s.parse().map_err(|e: T::Err| e.to_string())
}

fn main() -> ExitCode {
    sonar_common::init_tracing();
    let args = Args::parse();
    sonar_common::report_exit("sonar-fusion", run(&args))
}

/// The configuration from the file, the preset and the flags, validated; and the file's
/// persistence and feature settings.
fn fusion_config(args: &Args) -> Result<(FusionConfig, PersistConfig, FeaturesSection, bool)> {
    let file = FusionFile::read(args.config.as_deref())?;
    let slam_correction = file.slam_correction();
    let FusionFile {
        fusion:
            FusionSection {
                engine: mut config,
                persistence,
                ..
            },
        features,
        ..
    } = file;
    if let Some(preset) = args.preset {
        config.use_preset(preset);
    }
    if let Some(kind) = args.model {
        config.model = ModelConfig::default_for(kind);
    }
    if let Some(kind) = args.rule {
        config.rule = RuleConfig::default_for(kind);
    }
    if let Some(cells) = args.cells {
        config.grid.cells = cells;
    }
    if let Some(resolution) = args.resolution_m {
        config.grid.resolution_m = resolution;
    }
    if let Some(clear) = args.clear_on_no_echo {
        config.clear_on_no_echo = clear;
    }
    config.validate().context("invalid fusion settings")?;
    Ok((
        config,
        persistence,
        features,
        slam_correction || args.slam_correction,
    ))
}

/// Where and how often to save, from the file's `[fusion]` keys and the flags; `None` with
/// --no-persist (or `persist = false`).
fn persistence(args: &Args, mut p: PersistConfig) -> Result<Option<(PathBuf, Duration)>> {
    p.persist &= !args.no_persist;
    if let Some(path) = &args.state_file {
        p.state_file = Some(path.clone());
    }
    if let Some(seconds) = args.save_period {
        p.save_period = seconds;
    }
    let period = p.period().context("invalid --save-period")?;
    if !p.persist {
        return Ok(None);
    }
    let path = match p.state_file {
        Some(path) => path,
        None => {
            // One file per iceoryx2 prefix: two pipelines on a machine keep two maps.
            let prefix = args.ipc.config()?.global.prefix.to_string();
            let default = Config::default().global.prefix.to_string();
            persist::default_state_file((prefix != default).then_some(prefix.as_str()))
        }
    };
    Ok(Some((path, period)))
}

/// The engine, with the saved map if there is one that fits; says what became of the file.
fn open_engine(config: FusionConfig, history: usize, path: &Path) -> Result<(Engine, bool)> {
    let (engine, outcome) =
        persist::restore(path, config, history).context("invalid fusion settings")?;
    let file = path.display();
    let restored = matches!(outcome, Restore::Restored);
    match outcome {
        Restore::Restored => info!(
            readings = engine.mapper().readings_fused(),
            last_seq = engine.last_seq(),
            "map restored from {file}"
        ),
        Restore::NoFile => info!("no saved map at {file}: starting with an empty map"),
        Restore::Refused { reason, kept_as } => {
            let kept = match kept_as {
                Ok(bad) => format!("the file is kept as {}", bad.display()),
                Err(e) => format!("it could not be moved aside ({e}) and will be overwritten"),
            };
            warn!("saved map {file} not restored: {reason}; starting with an empty map ({kept})");
        }
    }
    Ok((engine, restored))
}

/// Refuses a grid whose snapshots cannot fit in /dev/shm: tmpfs commits pages on first write, so
/// an oversized segment is created fine and the process dies of SIGBUS later.
fn check_shared_memory(cells: usize) -> Result<u64> {
    let slot = (std::mem::size_of::<GridHeader>() + cells + 64) as u64;
    let needed = slot * GRID_SEGMENT_SLOTS as u64;
    match nix::sys::statvfs::statvfs("/dev/shm") {
        Ok(fs) => {
            #[allow(clippy::unnecessary_cast)] // 32-bit targets have 32-bit block counts
            let available = fs.blocks_available() as u64 * fs.fragment_size() as u64;
            if needed > available {
                bail!(
                    "the grid is too large for shared memory: {GRID_SEGMENT_SLOTS} snapshots of \
                     {cells} cells need {} MiB in /dev/shm, {} MiB are free (fewer or coarser \
                     cells, or a larger /dev/shm)",
                    needed >> 20,
                    available >> 20
                );
            }
        }
        Err(e) => warn!("cannot check the free space of /dev/shm: {e}"),
    }
    Ok(needed)
}

fn run(args: &Args) -> Result<()> {
    if !(args.max_snapshot_rate.is_finite() && args.max_snapshot_rate > 0.0) {
        bail!("--max-snapshot-rate must be a positive number of snapshots per second");
    }
    let (config, persist_config, features, slam_correction) = fusion_config(args)?;
    let localize = args.localize || features.localize;
    if localize && slam_correction {
        bail!(
            "the correction comes either from the fusion's own localisation (--localize, \
             [features] localize) or from sonar-slam (--slam-correction, [fusion] \
             slam_correction), not both"
        );
    }
    let extract = features.enabled && !args.no_features;
    if localize && !extract {
        bail!("localisation needs the features: they are turned off");
    }
    let tracker = extract
        .then(|| {
            if localize {
                FeatureTracker::with_localization(features.config)
            } else {
                FeatureTracker::new(features.config)
            }
        })
        .transpose()
        .context("invalid [features] settings")?;
    let persistence = persistence(args, persist_config)?;
    let (mut engine, restored) = match &persistence {
        Some((path, _)) => open_engine(config, args.history, path)?,
        None => (
            Engine::new(config, args.history).context("invalid fusion settings")?,
            false,
        ),
    };
    // One calibration for both maps: the features take it off their pings.
    engine.set_range_offset(features.config.range_offset_m as f32);
    let footprint = check_shared_memory(engine.grid_len())?;
    info!(
        cells = config.grid.cells,
        // As given: an f32 recorded as f64 would print 0.019999999552965164.
        resolution_m = %config.grid.resolution_m,
        model = config.model.kind().name(),
        rule = config.rule.kind().name(),
        preset = config.matching_preset().map_or("custom", Preset::name),
        clear_on_no_echo = config.clear_on_no_echo,
        range_offset_m = features.config.range_offset_m,
        shm_mib = format_args!("{:.1}", footprint as f64 / f64::from(1 << 20)),
        state_file = persistence.as_ref().map(|(p, _)| p.display().to_string()),
        features = tracker.is_some(),
        localize,
        slam_correction,
        "fusion engine ready"
    );
    if features.config.range_offset_m == 0.0 {
        info!(
            "the sensor's range offset is not calibrated ([features] range_offset_m = 0): \
             `sonar calibrate-range --wall-distance M` measures it on a wall M metres away"
        );
    }
    if let Some((path, _)) = &persistence {
        persist::check_writable(path).with_context(|| {
            format!(
                "cannot write the state file {}: give --state-file a place this user can write \
                 (or state_file in [fusion]), or --no-persist to run without saving \
                 the map",
                path.display()
            )
        })?;
    }
    let mut saving = persistence
        .map(|(path, period)| Saving::new(path, period, &engine))
        .transpose()?;

    sonar_common::ipc::catch_termination_requests();
    let node = args.ipc.node("sonar-fusion")?;
    let ports = Ports::new(&node, engine.grid_len(), slam_correction)?;
    let min_interval = Duration::from_secs_f64(1.0 / args.max_snapshot_rate);
    let mut features = tracker
        .map(|tracker| Features::new(&node, tracker, localize, min_interval))
        .transpose()?;
    let waitset = WaitSetBuilder::new()
        .create::<Ipc>()
        .map_err(|e| IpcError::new("create waitset", e))?;
    let readings_guard = waitset
        .attach_notification(&ports.readings_listener)
        .map_err(|e| IpcError::new("attach readings listener", e))?;
    let commands_guard = waitset
        .attach_notification(&ports.commands_listener)
        .map_err(|e| IpcError::new("attach commands listener", e))?;
    // Readings and commands wake the loop, and a held-back snapshot sets its own timeout below:
    // the tick is only for what comes without a wake-up (poses, corrections, the status, saves),
    // so an idle fusion wakes once a second.
    let tick_guard = waitset
        .attach_interval(REFRESH_PERIOD)
        .map_err(|e| IpcError::new("attach interval", e))?;

    let mut out = Output {
        ports: &ports,
        seq: 0,
        dirty: true, // publish the empty maps at once, so a viewer knows fusion is there
        pace: Pace::new(min_interval),
        sweep_end_pace: Pace::new(min_interval),
        pending_end: None,
        last_refresh: Instant::now(),
        ledger: Ledger::new(restored, engine.last_seq()),
        status_published: None,
        lost_log: Throttle::new(LOG_PERIOD),
        restart_log: Throttle::new(LOG_PERIOD),
        rejected_log: Throttle::new(LOG_PERIOD),
        pose_log: Throttle::new(LOG_PERIOD),
        backlog: VecDeque::new(),
        last_arrival: Instant::now(),
        backlog_peak: 0,
        waiting: None,
        corrections: 0,
        revisions: RevisionCount::default(),
        grid_samples: SampleVersions::default(),
    };
    // Readings were left in the buffer at the end of the last turn.
    let mut more = false;
    loop {
        let (mut readings, mut commands) = (false, false);
        // No sleep while readings wait; else until something arrives, the tick, or the moment a
        // held-back snapshot may go out (so it goes out then, not up to a tick later).
        let now = Instant::now();
        let timeout = if more || engine.rebuilding() {
            Duration::ZERO
        } else if out.waiting.is_some() {
            POSE_POLL
        } else {
            [
                out.held_back(now),
                features.as_ref().and_then(|f| f.held_back(now)),
            ]
            .into_iter()
            .flatten()
            .min()
            .unwrap_or(Duration::MAX)
        };
        let result = waitset
            .wait_and_process_once_with_timeout(
                |id| {
                    readings |= id.has_event_from(&readings_guard);
                    commands |=
                        id.has_event_from(&commands_guard) || id.has_event_from(&tick_guard);
                    CallbackProgression::Continue
                },
                timeout,
            )
            .map_err(|e| IpcError::new("wait", e))?;
        match result {
            WaitSetRunResult::TerminationRequest => break,
            // A stop and continue (SIGSTOP/SIGCONT, Ctrl-Z and `fg`, a debugger) also ends the
            // wait, and must not end the process. A SIGINT or SIGTERM that ended it is seen by
            // the next wait, which checks for one before anything else runs.
            WaitSetRunResult::Interrupt => continue,
            _ => {}
        }
        if commands {
            drain_wakeups(&out.ports.commands_listener);
            out.handle_commands(&mut engine, features.as_mut())?;
        }
        // The interval also ends up here: readings are drained whenever the process is awake, so
        // a lost wake-up can delay a reading by one tick at most.
        if readings {
            drain_wakeups(&out.ports.readings_listener);
        }
        out.take_pose(&mut engine)?;
        more = out.fuse_readings(&mut engine, features.as_mut(), PoseWait::Bounded)?;
        out.rebuild_step(&mut engine);
        let now = Instant::now();
        if let Some(features) = &mut features {
            if let Some(quiet_since) = out.quiet_since() {
                features.show_idle_sweep(&mut engine, quiet_since, now);
            }
            features.publish_if_due(&mut engine, now);
            features.refresh(now);
            out.ledger
                .feature_readings_skipped(features.tracker.readings_skipped());
        }
        out.publish_if_due(&mut engine, now)?;
        // After the latest reading's own snapshot, which need not wait for the sweep's end.
        out.close_ended_sweep(&mut engine)?;
        if let Some(saving) = &mut saving {
            saving.tick(&engine, &mut out.ledger, now);
        }
        out.publish_status(&engine, now);
    }
    // Stopping: the readings already delivered are fused and the map they make is published
    // (pace or not), so a replay's last readings reach the saved map and its subscribers.
    while out.fuse_readings(&mut engine, features.as_mut(), PoseWait::None)? {}
    // A sweep whose end came with those readings is closed, as an export of the recording does.
    out.close_ended_sweep(&mut engine)?;
    while engine.rebuilding() {
        out.rebuild_step(&mut engine);
    }
    if out.dirty {
        out.publish(&mut engine)?;
    }
    if let Some(saving) = saving {
        saving.finish(&engine, &mut out.ledger);
    }
    if let Some(drift) = features.as_ref().and_then(|f| f.tracker.drift()) {
        // What to calibrate the robot's odometry with (and a check on localisation).
        info!(
            fixes = features.as_ref().map_or(0, |f| f.tracker.fixes()),
            scale_error_percent = drift.scale * 100.0,
            heading_drift_deg_per_m = drift.drift_deg_per_m,
            turn_error_percent = drift.turn * 100.0,
            "the odometry's drift as localisation learnt it"
        );
    }
    let status = out.ledger.status(engine.mapper().readings_fused(), 0);
    info!(
        readings = status.readings_fused,
        extrapolated_pose = engine.extrapolated_pose_readings(),
        stale_pose = engine.stale_pose_readings(),
        early_pose = engine.early_pose_readings(),
        pose_gaps = engine.pose_gaps().gaps,
        poses_missing = engine.pose_gaps().missing,
        received = status.readings_received,
        lost = status.readings_lost,
        snapshots = out.seq,
        saves = status.saves,
        slam_corrections = out.corrections,
        slam_revisions = out.revisions.applied,
        slam_revisions_unapplied = out.revisions.uncovered,
        backlog_peak = out.backlog_peak,
        "fusion stopped"
    );
    Ok(())
}

/// The periodic save: when one is due, the state is copied on the readings loop and written by
/// the [`Saver`] thread.
struct Saving {
    saver: Saver,
    period: Duration,
    next: Instant,
    /// Engine revision of the newest map written (or restored, or the empty start).
    saved_revision: u64,
    /// Revision of the map being written.
    pending_revision: Option<u64>,
    /// The previous save's copy, handed back by the saver: the next one is captured into it.
    spare: Option<SavedMap>,
}

impl Saving {
    fn new(path: PathBuf, period: Duration, engine: &Engine) -> Result<Self> {
        Ok(Self {
            saver: Saver::spawn(path).context("cannot start the map saver thread")?,
            period,
            // The first save is due as soon as the map changes: a kill before the first period
            // is over would otherwise lose every reading since the start.
            next: Instant::now(),
            saved_revision: engine.revision(),
            pending_revision: None,
            // The copy is allocated now, at start, and reused by every save: a fresh copy of a
            // large grid costs its page faults on top of the copying (at 2048² Dempster–Shafer
            // cells, 44 ms against 9 ms, a snapshot being 11 ms).
            spare: Some(engine.capture()),
        })
    }

    fn tick(&mut self, engine: &Engine, ledger: &mut Ledger, now: Instant) {
        for report in self.saver.finished() {
            self.finished(&report, ledger);
            self.spare = Some(report.spare);
        }
        if now < self.next || !self.saver.idle() || engine.revision() == self.saved_revision {
            return;
        }
        self.next = now + self.period;
        let copy_start = Instant::now();
        let mut map = self.spare.take().unwrap_or_default();
        engine.capture_into(&mut map);
        ledger.save_taken(copy_start.elapsed());
        self.pending_revision = Some(engine.revision());
        if let Err(e) = self.saver.save(map) {
            warn!("cannot save the map: {e}");
        }
    }

    fn finished(&mut self, report: &SaveReport, ledger: &mut Ledger) {
        ledger.save_finished(report);
        let file = self.saver.path().display();
        match &report.result {
            Ok(()) => {
                if let Some(revision) = self.pending_revision.take() {
                    self.saved_revision = revision;
                }
                debug!(
                    readings = report.readings_fused,
                    write_ms = report.write_time.as_secs_f64() * 1e3,
                    "map saved to {file}"
                );
            }
            // The previous file is intact; the map stays unsaved, so the next period tries again.
            Err(e) => warn!("cannot save the map to {file}: {e}; the previous save is kept"),
        }
    }

    /// The last save, at shutdown, if the map changed since the newest one.
    fn finish(mut self, engine: &Engine, ledger: &mut Ledger) {
        let last = (engine.revision() != self.saved_revision).then(|| {
            let mut map = self.spare.take().unwrap_or_default();
            engine.capture_into(&mut map);
            map
        });
        let reports = self.saver.finish(last);
        for report in &reports {
            self.finished(report, ledger);
        }
        if reports.iter().any(|r| r.result.is_ok()) {
            info!(
                readings = engine.mapper().readings_fused(),
                "map saved to {}",
                self.saver.path().display()
            );
        }
    }
}

/// The feature map and its publisher on `sonar/features`: a snapshot after every sweep merged
/// (at most one per [`Pace`], as the grid's sweep ends) and after a clear.
///
/// The pace matters when sweeps fragment (an overflowing buffer, see [`Pace`]): each fragment is
/// merged as a sweep, and a snapshot brings the grid's kept state up to date (the encoding and
/// the walls' support cells of every cell fused since the last flush) and grows every wall.
struct Features {
    tracker: FeatureTracker,
    /// While the readings have stopped: the tracker with its pending sweep merged, published in
    /// its place until the next reading ([`Self::show_idle_sweep`]).
    shown: Option<FeatureTracker>,
    publisher: Publisher<Ipc, [FeatureRecord], FeaturesHeader>,
    notifier: Notifier<Ipc>,
    /// With --localize: where the corrected poses go.
    localized: Option<Publisher<Ipc, LocalizedPose, ()>>,
    seq: u64,
    /// A sweep was merged since the last snapshot.
    dirty: bool,
    pace: Pace,
    last_refresh: Instant,
    /// The readings the features cannot use were named in the log.
    said_skipped: bool,
}

impl Features {
    fn new(
        node: &Node<Ipc>,
        tracker: FeatureTracker,
        localize: bool,
        min_interval: Duration,
    ) -> Result<Self> {
        let localized = localize
            .then(|| {
                ipc::localized_pose_service(node)?
                    .publisher_builder()
                    .create()
                    .map_err(|e| IpcError::new("create localized pose publisher", e))
            })
            .transpose()?;
        Ok(Self {
            tracker,
            shown: None,
            localized,
            publisher: ipc::features_service(node)?
                .publisher_builder()
                .initial_max_slice_len(MAX_FEATURES)
                .create()
                .map_err(|e| IpcError::new("create features publisher", e))?,
            notifier: ipc::wakeup_notifier(node, ipc::FEATURES_SERVICE)?,
            seq: 0,
            dirty: false,
            pace: Pace::new(min_interval),
            last_refresh: Instant::now(),
            said_skipped: false,
        })
    }

    /// Adds a reading; publishes when it ended a sweep.
    fn push(&mut self, reading: &sonar_common::ipc::Reading, engine: &mut Engine) {
        self.shown = None;
        let finished = self
            .tracker
            .follow(reading, engine, self.localized.is_some());
        if let Some(outcome) = finished {
            self.sweep_done(&outcome, engine);
        }
    }

    /// Shows the pending sweep merged once its readings stopped coming [`SWEEP_IDLE`] ago
    /// (`quiet_since`): the head stopped, and its last sweep is published (and, localising, its
    /// pose) without waiting for another reading. The sweep itself stays open and the engine's
    /// correction unchanged: if the head only stalled, its next readings join the sweep as they
    /// would have without the stall, and the map is what an offline fusion of the recording
    /// makes, whatever the delivery's timing.
    fn show_idle_sweep(&mut self, engine: &mut Engine, quiet_since: Instant, now: Instant) {
        if self.shown.is_some() || now.duration_since(quiet_since) < SWEEP_IDLE {
            return;
        }
        let Some((shown, outcome)) = self.tracker.with_pending_merged() else {
            return;
        };
        debug!(
            ?outcome,
            "the readings stopped: the pending sweep shown merged"
        );
        self.send_localized(&outcome, &shown);
        self.shown = Some(shown);
        self.dirty = true;
        self.publish_if_due(engine, now);
    }

    /// Offers the latest snapshots to subscribers that joined since, once per [`REFRESH_PERIOD`]:
    /// they would otherwise wait for the next sweep, for ever while the head is stopped.
    fn refresh(&mut self, now: Instant) {
        if now.duration_since(self.last_refresh) < REFRESH_PERIOD {
            return;
        }
        self.last_refresh = now;
        let localized = self.localized.as_ref().map(|p| p.update_connections());
        for result in [Some(self.publisher.update_connections()), localized]
            .into_iter()
            .flatten()
        {
            if let Err(e) = result {
                warn!("update connections: {e:?}");
            }
        }
        if let Err(e) = self.notifier.notify() {
            warn!("notify features: {e:?}");
        }
    }

    /// After a sweep: the new correction to the engine, the corrected pose out, and the features
    /// when the pace allows (else by [`Self::publish_if_due`]).
    fn sweep_done(&mut self, outcome: &SweepOutcome, engine: &mut Engine) {
        debug!(
            ?outcome,
            features = self.tracker.len(),
            drift = ?self.tracker.drift(),
            "sweep merged into the features"
        );
        if outcome.skipped > 0 && !self.said_skipped {
            // Once: such a head sends nothing else, and a line per sweep says nothing new.
            self.said_skipped = true;
            warn!(
                sweep = outcome.sweep_id,
                skipped = outcome.skipped,
                of = outcome.readings,
                "readings whose pings cannot be placed (several pings but no direction of motion, \
                 or no angle) give no walls, corners or posts; they are in the grid and the radar. \
                 Counted in sonar/fusion_status feature_readings_skipped (`sonar echo fusion-status`)"
            );
        }
        if self.localized.is_some() {
            engine.set_correction(self.tracker.correction());
            self.send_localized(outcome, &self.tracker);
        }
        self.dirty = true;
        self.publish_if_due(engine, Instant::now());
    }

    /// With --localize: the pose of `outcome`'s sweep as `tracker` has it, on its service.
    fn send_localized(&self, outcome: &SweepOutcome, tracker: &FeatureTracker) {
        if let Some(publisher) = &self.localized
            && let Err(e) = publisher.send_copy(localized_pose(outcome, tracker.fixes()))
        {
            warn!("send localized pose: {e:?}");
        }
    }

    fn publish_if_due(&mut self, engine: &mut Engine, now: Instant) {
        if self.dirty && self.pace.allows(now) {
            self.publish(engine);
        }
    }

    /// How long until a merged sweep held back by the pace may be published.
    fn held_back(&self, now: Instant) -> Option<Duration> {
        self.dirty.then(|| self.pace.wait(now))
    }

    fn clear(&mut self, engine: &mut Engine) {
        self.tracker.clear();
        self.shown = None;
        self.publish(engine);
    }

    fn publish(&mut self, engine: &mut Engine) {
        self.dirty = false;
        self.pace.sent(Instant::now());
        self.seq += 1;
        let (header, records) = self.shown.as_ref().unwrap_or(&self.tracker).snapshot(
            engine.grid_mut(),
            self.seq,
            unix_time_ns(),
        );
        if let Err(e) = ipc::send_snapshot(&self.publisher, &self.notifier, header, &records) {
            warn!("features snapshot not published: {e}");
        }
    }
}

/// The record of a sweep's pose: the fix if there is one, else the prediction (`matched` 0, the
/// covariance NaN), with the odometry's pose of the same instant.
fn localized_pose(outcome: &SweepOutcome, fixes: u32) -> LocalizedPose {
    let (pose, covariance, matched) = match &outcome.fix {
        Some(fix) => (fix.pose, fix.covariance, fix.matched),
        None => (
            outcome.predicted,
            nalgebra::Matrix3::from_element(f64::NAN),
            0,
        ),
    };
    let odometry = outcome.odometry;
    let c = |i, j| covariance[(i, j)] as f32;
    LocalizedPose {
        stamp_ns: outcome.stamp_ns,
        x_m: pose.translation.x as f32,
        y_m: pose.translation.y as f32,
        theta_rad: pose.rotation.angle() as f32,
        layout_version: LAYOUT_VERSION,
        cov_xx: c(0, 0),
        cov_xy: c(0, 1),
        cov_xtheta: c(0, 2),
        cov_yy: c(1, 1),
        cov_ytheta: c(1, 2),
        cov_thetatheta: c(2, 2),
        matched: u32::try_from(matched).unwrap_or(u32::MAX),
        fixes,
        odometry_x_m: odometry.translation.x as f32,
        odometry_y_m: odometry.translation.y as f32,
        odometry_theta_rad: odometry.rotation.angle() as f32,
        reserved: 0,
    }
}

/// The process's iceoryx2 ports. Dropped before the node, leaving nothing in /dev/shm.
struct Ports {
    readings: iceoryx2::port::subscriber::Subscriber<Ipc, sonar_common::ipc::Reading, ()>,
    readings_listener: Listener,
    /// The driver's word that a sweep ended; it wakes the readings' listener.
    sweep_ends: iceoryx2::port::subscriber::Subscriber<Ipc, SweepEnd, ()>,
    commands: iceoryx2::port::subscriber::Subscriber<Ipc, FusionCommand, ()>,
    commands_listener: Listener,
    pose: iceoryx2::port::subscriber::Subscriber<Ipc, sonar_common::ipc::Pose2D, ()>,
    /// With --slam-correction: sonar-slam's corrections.
    slam_correction: Option<iceoryx2::port::subscriber::Subscriber<Ipc, SlamCorrection, ()>>,
    grid: Publisher<Ipc, [u8], GridHeader>,
    grid_notifier: Notifier<Ipc>,
    radar: Publisher<Ipc, Radar, ()>,
    radar_notifier: Notifier<Ipc>,
    status: Publisher<Ipc, FusionStatus, ()>,
}

type Listener = iceoryx2::port::listener::Listener<Ipc>;

/// Consumes the pending wake-ups (all of them), so the waitset sleeps again.
fn drain_wakeups(listener: &Listener) {
    if let Err(e) = ipc::drain_wakeups(listener) {
        warn!("{e}");
    }
}

impl Ports {
    fn new(node: &Node<Ipc>, grid_cells: usize, slam_correction: bool) -> Result<Self> {
        Ok(Self {
            slam_correction: slam_correction
                .then(|| {
                    ipc::slam_correction_service(node)?
                        .subscriber_builder()
                        .create()
                        .map_err(|e| IpcError::new("create SLAM correction subscriber", e))
                })
                .transpose()?,
            readings: ipc::readings_service(node)?
                .subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create readings subscriber", e))?,
            readings_listener: ipc::wakeup_listener(node, ipc::READINGS_SERVICE)?,
            sweep_ends: ipc::sweep_ends_service(node)?
                .subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create sweep ends subscriber", e))?,
            commands: ipc::fusion_commands_service(node)?
                .subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create fusion command subscriber", e))?,
            commands_listener: ipc::wakeup_listener(node, ipc::FUSION_COMMANDS_SERVICE)?,
            pose: ipc::pose_service(node)?
                .subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create pose subscriber", e))?,
            grid: ipc::grid_service(node)?
                .publisher_builder()
                .initial_max_slice_len(grid_cells)
                .create()
                .map_err(|e| {
                    IpcError::new("create grid publisher (is another fusion running?)", e)
                })?,
            grid_notifier: ipc::wakeup_notifier(node, ipc::GRID_SERVICE)?,
            radar: ipc::radar_service(node)?
                .publisher_builder()
                .create()
                .map_err(|e| IpcError::new("create radar publisher", e))?,
            radar_notifier: ipc::wakeup_notifier(node, ipc::RADAR_SERVICE)?,
            status: ipc::fusion_status_service(node)?
                .publisher_builder()
                .create()
                .map_err(|e| IpcError::new("create fusion status publisher", e))?,
        })
    }
}

/// At most one snapshot of a kind per `min_interval` (1 / `--max-snapshot-rate`).
///
/// The grid keeps two: one for the snapshots of readings (and commands), which coalesces the
/// readings in between, and one for the snapshots at the end of a sweep. A sweep's end publishes the finished sweep's map
/// before the next sweep's first reading is fused (`sonar-export --sweeps` and the viewer show
/// each sweep's own map), unless the last sweep-end snapshot was less than an interval ago; a
/// map held back that way goes out when the first pace allows, at most one interval later.
/// Uncapped, sweep ends cost the engine everything once it fell behind: its buffer overflows,
/// consecutive readings belong to different sweeps, and each forced a snapshot (at 1024² cells,
/// offered 9 k readings/s, it fused 105/s). Capped, a fragmenting stream costs at most two
/// snapshots per interval, and sweeps that end less often than `--max-snapshot-rate` keep every one.
#[derive(Debug, Clone, Copy)]
struct Pace {
    min_interval: Duration,
    last: Option<Instant>,
}

impl Pace {
    fn new(min_interval: Duration) -> Self {
        Self {
            min_interval,
            last: None,
        }
    }

    fn allows(&self, now: Instant) -> bool {
        self.wait(now).is_zero()
    }

    /// How long until the next one is allowed.
    fn wait(&self, now: Instant) -> Duration {
        self.last.map_or(Duration::ZERO, |t| {
            (t + self.min_interval).saturating_duration_since(now)
        })
    }

    fn sent(&mut self, now: Instant) {
        self.last = Some(now);
    }
}

/// Whether a reading newer than the newest pose waits for its pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PoseWait {
    /// Up to [`MAX_POSE_WAIT`]: while running.
    Bounded,
    /// Not at all: when stopping, everything delivered is fused with the poses there are.
    None,
}

/// Publishing state: what is new since the last snapshot, and when that was; the counters and
/// their rate-limited log lines.
struct Output<'a> {
    ports: &'a Ports,
    seq: u64,
    dirty: bool,
    /// Every grid snapshot.
    pace: Pace,
    /// Snapshots brought forward by a sweep's end.
    sweep_end_pace: Pace,
    /// The latest sweep end the driver reported whose last reading is not fused yet.
    pending_end: Option<SweepEnd>,
    last_refresh: Instant,
    ledger: Ledger,
    /// The latest status published, and when.
    status_published: Option<(FusionStatus, Instant)>,
    lost_log: Throttle,
    restart_log: Throttle,
    rejected_log: Throttle,
    pose_log: Throttle,
    /// Readings received and not yet fused, oldest first ([`MAX_BACKLOG`]).
    backlog: VecDeque<Reading>,
    /// When the latest reading was taken from the subscriber: the quiet after it is measured from
    /// its arrival, as a recorder logs it, not from when it was fused (it may have waited for its
    /// pose, or behind others).
    last_arrival: Instant,
    /// The most readings the backlog held: how far the fusion fell behind.
    backlog_peak: usize,
    /// A reading waiting for the pose that covers its instant, and since when it is the next to
    /// fuse ([`sonar_fusion::poses::MAX_POSE_WAIT`]); the readings after it wait behind it.
    waiting: Option<(Reading, Instant)>,
    /// sonar-slam's corrections applied (--slam-correction).
    corrections: u64,
    /// The maps rebuilt after sonar-slam moved sweeps already fused.
    revisions: RevisionCount,
    /// What the grid publisher's samples held when last written.
    grid_samples: SampleVersions,
}

/// The version of the grid's bytes each of the grid publisher's samples was last written with,
/// by the address of its payload. iceoryx2 hands a publisher back its own samples' slots as they
/// were sent (it neither clears nor writes them, and subscribers map them read-only), so a
/// reused sample needs only the cells that changed since its version
/// ([`Engine::copy_grid_changes_into`]): at the head's pace a snapshot per reading copies what
/// the reading changed, not the whole grid.
#[derive(Debug, Default)]
struct SampleVersions(HashMap<usize, EncodedVersion>);

impl SampleVersions {
    /// The slots of the grid's data segment, with room to spare; beyond that the map is
    /// forgotten (it cannot happen with a static segment, and costs a whole copy each if it did).
    const MAX: usize = 4 * GRID_SEGMENT_SLOTS;

    fn held(&self, payload: *const MaybeUninit<u8>) -> Option<EncodedVersion> {
        self.0.get(&(payload as usize)).copied()
    }

    fn written(&mut self, payload: *const MaybeUninit<u8>, version: EncodedVersion) {
        if self.0.len() >= Self::MAX && !self.0.contains_key(&(payload as usize)) {
            self.0.clear();
        }
        self.0.insert(payload as usize, version);
    }
}

/// Revisions of sweeps already fused (`sonar-slam` moving them), counted for the log.
#[derive(Debug, Default)]
struct RevisionCount {
    /// Rebuilds of the maps finished.
    applied: u64,
    /// Revisions the maps could not follow (they hold more than the kept readings).
    uncovered: u64,
    /// When the rebuild under way started.
    started: Option<Instant>,
}

impl Output<'_> {
    fn handle_commands(
        &mut self,
        engine: &mut Engine,
        mut features: Option<&mut Features>,
    ) -> Result<()> {
        while let Some(sample) = self
            .ports
            .commands
            .receive()
            .map_err(|e| IpcError::new("receive fusion command", e))?
        {
            let command = *sample.payload();
            match engine.apply(&command) {
                Ok(()) => {
                    info!(?command, "fusion command");
                    if let (Some(FusionCommandKind::Clear), Some(features)) =
                        (command.kind(), features.as_deref_mut())
                    {
                        features.clear(engine);
                    }
                    self.dirty = true;
                    // A command's effect shows at once, whatever the rate limit.
                    self.publish(engine)?;
                    self.pace.sent(Instant::now());
                }
                Err(e) => warn!(?command, "fusion command refused: {e}"),
            }
        }
        Ok(())
    }

    fn take_pose(&mut self, engine: &mut Engine) -> Result<()> {
        self.take_slam_correction(engine)?;
        while let Some(sample) = self
            .ports
            .pose
            .receive()
            .map_err(|e| IpcError::new("receive pose", e))?
        {
            if let Err(e) = engine.set_pose(sample.payload())
                && let Some(left_out) = self.pose_log.allow(Instant::now())
            {
                warn!(pose = ?sample.payload(), left_out, "pose refused: {e}");
            }
        }
        Ok(())
    }

    /// With --slam-correction: the latest of sonar-slam's corrections places the readings from
    /// now on (fix or not: without a fix it is still the SLAM's best estimate of map → odom).
    fn take_slam_correction(&mut self, engine: &mut Engine) -> Result<()> {
        let Some(subscriber) = &self.ports.slam_correction else {
            return Ok(());
        };
        let mut revised = Vec::new();
        while let Some(sample) = subscriber
            .receive()
            .map_err(|e| IpcError::new("receive SLAM correction", e))?
        {
            let c = *sample.payload();
            // Every message places its sweep's readings, fused with the correction known when
            // they came; a revision is an earlier sweep moved, the others set the correction
            // for the readings from now on.
            let Some(sweep) = engine.take_slam_correction(&c) else {
                warn!(correction = ?c, "SLAM correction refused: not finite");
                continue;
            };
            revised.push(sweep);
            if c.state == slam_state::REVISED {
                continue;
            }
            if self.corrections == 0 {
                info!(
                    sweep = c.sweep_id,
                    fix = c.is_fix(),
                    "first correction from sonar-slam"
                );
            }
            self.corrections += 1;
        }
        if revised.is_empty() {
            return Ok(());
        }
        match engine.revise(&revised) {
            Revised::Unmoved => {}
            Revised::Rebuilding(moved) => {
                debug!(
                    moved,
                    sweeps = revised.len(),
                    "sweeps revised: rebuilding the maps"
                );
                self.revisions.started.get_or_insert_with(Instant::now);
            }
            Revised::Uncovered(moved) => {
                if self.revisions.uncovered == 0 {
                    warn!(
                        moved,
                        "sonar-slam moved sweeps already fused, but the maps hold more readings \
                         than are kept (--history): they stay where they were placed; a larger \
                         --history lets the maps follow the SLAM"
                    );
                }
                self.revisions.uncovered += 1;
            }
        }
        Ok(())
    }

    /// Carries a rebuild of the maps on by one turn's worth of readings.
    fn rebuild_step(&mut self, engine: &mut Engine) {
        if engine.rebuild_step(READINGS_PER_TURN) {
            self.revisions.applied += 1;
            let took = self.revisions.started.take().map(|t| t.elapsed());
            debug!(?took, "maps rebuilt where sonar-slam now places the sweeps");
            self.dirty = true;
        }
    }

    /// Fuses up to [`READINGS_PER_TURN`] readings; true when it stopped there (more may wait),
    /// false when no reading is left or one waits for its pose (`out.waiting`). Before each, it
    /// takes every reading the subscriber's buffer holds into the backlog, so that only a single
    /// step longer than 256 readings' worth (not a long run of slow ones) can overflow it.
    fn fuse_readings(
        &mut self,
        engine: &mut Engine,
        mut features: Option<&mut Features>,
        pose_wait: PoseWait,
    ) -> Result<bool> {
        for _ in 0..READINGS_PER_TURN {
            self.take_readings()?;
            // The wait for a pose is timed from when the reading is next, not from when it was
            // taken: a reading that waited in the backlog waits for its pose as long as any.
            let (reading, received) = match self.waiting.take() {
                Some(waiting) => waiting,
                None => match self.backlog.pop_front() {
                    Some(reading) => (reading, Instant::now()),
                    None => return Ok(false),
                },
            };
            // Poses are taken before each reading, not once a turn: a turn of 256 readings takes
            // long enough in a debug build (or on a loaded machine) for a fast pose stream (a
            // replay at ×40 sends 800 a second) to overflow robot/pose's buffer of 256, and the
            // lost poses placed readings by interpolating across the gap.
            self.take_pose(engine)?;
            // The pose policy of `sonar_fusion::poses`: a reading newer than the newest pose
            // waits for the pose that covers it, for a bounded time.
            if pose_wait == PoseWait::Bounded
                && engine.awaits_pose(reading.host_stamp_ns)
                && received.elapsed() < MAX_POSE_WAIT
            {
                self.waiting = Some((reading, received));
                return Ok(false);
            }
            if let Some(changed) = engine.close_finished_sweep(&reading) {
                self.sweep_closed(engine, changed)?;
            }
            let stale_before = engine.stale_pose_readings();
            if !engine.fuse(&reading) {
                self.ledger.rejected();
                if let Some(left_out) = self.rejected_log.allow(Instant::now()) {
                    warn!(?reading, left_out, "reading refused by the kernels");
                }
            }
            if engine.stale_pose_readings() > stale_before
                && let Some(left_out) = self.pose_log.allow(Instant::now())
            {
                warn!(
                    total = engine.stale_pose_readings(),
                    left_out,
                    "reading placed at a pose more than 0.5 s older than itself: robot/pose \
                     stopped or lags"
                );
            }
            // After fusing: the features place the sweep where the fusion placed its reading.
            if let Some(features) = features.as_deref_mut() {
                features.push(&reading, engine);
            }
            self.dirty = true;
        }
        Ok(true)
    }

    /// A sweep was closed ([`Engine::close_finished_sweep`], [`Engine::sweep_ended`]): its maps
    /// published before the next sweep's first reading is fused. Counted by their own pace only:
    /// the next reading's snapshot need not wait an interval behind them (with the region model,
    /// whose sweep ends place the last region, the first reading of every sweep waited 100 ms:
    /// p99 line → snapshot 102 ms in `sonar-bench latency`).
    fn sweep_closed(&mut self, engine: &mut Engine, changed: bool) -> Result<()> {
        self.dirty |= changed;
        let now = Instant::now();
        if self.dirty && self.sweep_end_pace.allows(now) {
            self.sweep_end_pace.sent(now);
            self.publish(engine)?;
        }
        Ok(())
    }

    /// Closes the sweep the driver reported ended ([`SweepEnd`]) once its last reading is fused,
    /// in the quiet before the next sweep, rather than on the next sweep's first reading, whose
    /// snapshot then waited for the sweep's walls drawn on to their corners, refutations and
    /// withdrawals and for the sweep's own snapshot (at 400² × 2 cm 0.65–0.82 ms of its
    /// 1.2–1.4 ms, at 2048² × 1 cm 1.6–1.9 ms of 2.2–2.4 ms; `sonar-bench latency`).
    fn close_ended_sweep(&mut self, engine: &mut Engine) -> Result<()> {
        while let Some(sample) = self
            .ports
            .sweep_ends
            .receive()
            .map_err(|e| IpcError::new("receive sweep end", e))?
        {
            self.pending_end = Some(*sample.payload());
        }
        let Some(end) = self.pending_end.take() else {
            return Ok(());
        };
        match engine.sweep_ended(&end) {
            SweepEndOutcome::Early => self.pending_end = Some(end),
            SweepEndOutcome::Closed { changed } => self.sweep_closed(engine, changed)?,
            SweepEndOutcome::Stale => {}
        }
        Ok(())
    }

    /// When the readings went quiet: the arrival of the latest, if every reading received has been
    /// fused (none in the backlog or waiting for its pose).
    fn quiet_since(&self) -> Option<Instant> {
        (self.backlog.is_empty() && self.waiting.is_none()).then_some(self.last_arrival)
    }

    /// Moves what the subscriber's buffer holds into the backlog, up to [`MAX_BACKLOG`].
    fn take_readings(&mut self) -> Result<()> {
        while self.backlog.len() < MAX_BACKLOG {
            match self.receive_reading()? {
                Some(reading) => {
                    self.last_arrival = Instant::now();
                    self.backlog.push_back(reading);
                }
                None => break,
            }
        }
        self.backlog_peak = self.backlog_peak.max(self.backlog.len());
        Ok(())
    }

    /// The next reading of the buffer that can be fused (of this layout version), counted.
    fn receive_reading(&mut self) -> Result<Option<Reading>> {
        while let Some(sample) = self
            .ports
            .readings
            .receive()
            .map_err(|e| IpcError::new("receive reading", e))?
        {
            let reading = *sample.payload();
            drop(sample);
            self.count_seq(reading.seq);
            if reading.layout_version == LAYOUT_VERSION {
                return Ok(Some(reading));
            }
            self.ledger.rejected();
            if let Some(left_out) = self.rejected_log.allow(Instant::now()) {
                warn!(
                    version = reading.layout_version,
                    left_out, "reading of another layout version ignored"
                );
            }
        }
        Ok(None)
    }

    /// Counts a received reading's number: a gap is readings lost (iceoryx2 overwrote the oldest
    /// in a full buffer), a step back a restarted driver. Logged at most once per [`LOG_PERIOD`]
    /// each, with the events left out since.
    fn count_seq(&mut self, seq: u64) {
        match self.ledger.received(seq) {
            SeqStep::Gap(lost) => {
                if let Some(left_out) = self.lost_log.allow(Instant::now()) {
                    let total = self.ledger.readings_lost();
                    warn!(
                        lost,
                        total,
                        seq,
                        gaps_left_out = left_out,
                        "readings lost before this one: the fusion fell behind the driver and \
                         its subscriber buffer overflowed, or it was not running"
                    );
                }
            }
            SeqStep::Backwards => {
                if let Some(left_out) = self.restart_log.allow(Instant::now()) {
                    info!(
                        seq,
                        left_out, "the readings' numbering went back: a restarted driver"
                    );
                }
            }
            SeqStep::First | SeqStep::Next => {}
        }
    }

    /// Publishes the counters once per [`STATUS_PERIOD`], and at once when there is news.
    fn publish_status(&mut self, engine: &Engine, now: Instant) {
        let due = match &self.status_published {
            None => true,
            Some((last, at)) => {
                self.ledger.news_since(last) || now.duration_since(*at) >= STATUS_PERIOD
            }
        };
        if !due {
            return;
        }
        let status = self
            .ledger
            .status(engine.mapper().readings_fused(), unix_time_ns());
        if let Err(e) = self.ports.status.send_copy(status) {
            warn!("send fusion status: {e:?}");
        }
        self.status_published = Some((status, now));
    }

    /// How long until a map held back by the pace may be published.
    fn held_back(&self, now: Instant) -> Option<Duration> {
        self.dirty.then(|| self.pace.wait(now))
    }

    fn publish_if_due(&mut self, engine: &mut Engine, now: Instant) -> Result<()> {
        if self.dirty && self.pace.allows(now) {
            self.publish(engine)?;
            self.pace.sent(Instant::now());
        } else if now.duration_since(self.last_refresh) >= REFRESH_PERIOD {
            // Late joiners get the history sample only on a send or an explicit update.
            self.last_refresh = now;
            for result in [
                self.ports.grid.update_connections(),
                self.ports.radar.update_connections(),
            ] {
                if let Err(e) = result {
                    warn!("update connections: {e:?}");
                }
            }
            self.notify();
        }
        Ok(())
    }

    fn publish(&mut self, engine: &mut Engine) -> Result<()> {
        self.seq += 1;
        // The engine keeps the cells encoded as it fuses: a snapshot is a copy into a sample that
        // need not be zeroed first, and into a sample written before, a copy of what changed since
        // ([`SampleVersions`]). Stamped once the sample is complete, just before it goes.
        let mut whole_copy = false;
        let mut sent = false;
        let stamp = match self.ports.grid.loan_slice_uninit(engine.grid_len()) {
            Ok(sample) => {
                let payload = sample.payload().as_ptr();
                let held = self.grid_samples.held(payload);
                whole_copy = held.is_none();
                let (mut sample, counts, version) = match held {
                    Some(held) => {
                        // SAFETY: every byte of this slot was written (a whole copy, then
                        // changes) before it was sent as a sample of version `held`; nothing
                        // writes to it since (see `SampleVersions`), and any byte is a valid u8.
                        let mut sample = unsafe { sample.assume_init() };
                        let (counts, version) =
                            engine.copy_grid_changes_into(sample.payload_mut(), Some(held));
                        (sample, counts, version)
                    }
                    None => {
                        let (cells, counts) = engine.encoded_grid();
                        let sample = sample.write_from_slice(cells);
                        (sample, counts, engine.encoded_grid_version())
                    }
                };
                self.grid_samples.written(payload, version);
                let stamp = unix_time_ns();
                *sample.user_header_mut() = engine.grid_header(self.seq, stamp, counts);
                match sample.send() {
                    Ok(_) => {
                        sent = true;
                        self.ledger.snapshot_published();
                    }
                    Err(e) => {
                        self.ledger.snapshot_skipped();
                        warn!("send grid: {e:?}");
                    }
                }
                stamp
            }
            // Every slot held by slow subscribers: skip this snapshot; the map stays dirty, so
            // it is tried again after the pace's period even if no reading comes after it.
            Err(e) => {
                self.ledger.snapshot_skipped();
                warn!("loan grid sample: {e:?}");
                unix_time_ns()
            }
        };
        if let Err(e) = self.ports.radar.send_copy(engine.radar(self.seq, stamp)) {
            warn!("send radar: {e:?}");
        }
        self.notify();
        debug!(seq = self.seq, whole_copy, sent, "snapshot published");
        // A snapshot that did not go leaves the map dirty: the last readings' map must still be
        // published when no reading follows them.
        self.dirty = !sent;
        self.last_refresh = Instant::now();
        Ok(())
    }

    fn notify(&self) {
        for notifier in [&self.ports.grid_notifier, &self.ports.radar_notifier] {
            if let Err(e) = notifier.notify() {
                warn!("notify: {e:?}");
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn flags_are_named_as_the_files_keys_and_the_old_names_still_work() {
        Args::command().debug_assert();
        for (rate, resolution) in [
            ("--max-snapshot-rate", "--resolution-m"),
            ("--max-rate", "--resolution"),
        ] {
            let args = Args::try_parse_from(["sonar-fusion", rate, "4", resolution, "0.05"])
                .unwrap_or_else(|e| panic!("{rate} {resolution}: {e}"));
            assert_eq!(args.max_snapshot_rate, 4.0);
            assert_eq!(args.resolution_m, Some(0.05));
        }
    }
}
