//! `sonar-record`: writes the pipeline's readings, commands, poses and features to an MCAP file.
//!
//! Two threads. The main thread sleeps in an iceoryx2 WaitSet on the readings' wake-up event (and
//! the command services' wake-up events), plus a short interval for publishers that never notify
//! and for the stop conditions; each wake-up drains every subscriber completely and hands plain
//! copies of the payloads to the writer thread over an unbounded channel. The writer thread owns
//! the file. So a slow disk delays only the writer: the subscriber's 256-reading buffer is
//! emptied at every wake-up whatever the disk does, and the backlog waits in memory (104 B per
//! reading) instead of being overwritten in shared memory.
//!
//! Beside its own channels the writer thread also writes the well-known ones Foxglove (and, with
//! `--ros2`, ROS 2 tools) draw: the map from `sonar/grid`, each sweep as a laser scan, the frames
//! `map → odom → sonar` as transforms (the pose of `robot/pose` below the latest correction from
//! `sonar/localized_pose` or `sonar/slam_correction`, both also recorded in their own channels,
//! so an export of the recording draws the same frames) and the features as a scene
//! (`sonar_wellknown`; `docs/foxglove.md`).

use std::collections::BTreeMap;
use std::fmt::Debug;
use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::thread;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use clap::Parser;
use iceoryx2::port::ReceiveError;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::waitset::WaitSetRunResult;
use sonar_common::ipc::{
    self, FeatureRecord, FeaturesHeader, GridHeader, IpcArgs, IpcError, LAYOUT_VERSION, Reading,
};
use sonar_common::optional_port::{OptionalPort, snapshot_subscriber, subscriber};
use sonar_recorder::format::{FeatureSnapshot, Message, RecordingWriter, Topic};
use sonar_recorder::{Ros2Bag, WellKnownChannels};
use sonar_wellknown::Options as WellKnownOptions;
use tracing::{debug, info, warn};

/// How often the loop wakes without an event: polls subscribers whose publishers do not notify,
/// and checks `--duration`.
const POLL: Duration = Duration::from_millis(100);
/// The writer closes a chunk and flushes at least this often while data comes in, so a recorder
/// killed with SIGKILL loses at most about this much (`sonar-replay --allow-truncated`).
const FLUSH_PERIOD: Duration = Duration::from_secs(1);
/// Readings waiting for the disk before the progress log warns about it.
const BACKLOG_WARNING: u64 = 10_000;

/// Records `sonar/readings`, `sonar/commands`, `sonar/fusion_commands`, `robot/pose`,
/// `sonar/features` and the corrections of the odometry (`sonar/localized_pose`,
/// `sonar/slam_correction`) to an MCAP file (one channel each; docs/recording.md), until Ctrl-C/SIGTERM,
/// `--max-readings` or `--duration`. Beside them it writes what Foxglove draws by itself: the map
/// (`sonar/grid`) as foxglove.Grid, each sweep as foxglove.LaserScan, the frames map → odom →
/// sonar as foxglove.FrameTransform (robot/pose below the latest correction of sonar/localized_pose
/// or sonar/slam_correction), the features and each reading's beam (at most 10 a second) as
/// foxglove.SceneUpdate (docs/foxglove.md); with
/// `--ros2` also /map, /scan and /tf as ROS 2 messages, in a ROS 2 bag of their own beside the
/// file (run.mcap → run_ros2/, for `ros2 bag play run_ros2`).
///
/// Examples:
///   sonar-record run.mcap                          # until Ctrl-C
///   sonar-record run.mcap --max-readings 500       # the next 500 readings
///   sonar-record run.mcap --duration 60 --force    # one minute, replacing run.mcap
///   sonar-record run.mcap --ros2                   # also for ros2 bag play and RViz
#[derive(Debug, Parser)]
#[command(name = "sonar-record", version, verbatim_doc_comment)]
struct Args {
    /// Output file (MCAP). Not replaced if it exists, unless `--force`.
    file: PathBuf,
    /// Replace the output file if it exists.
    #[arg(long)]
    force: bool,
    /// Stop after this many readings. (`--count` still works.)
    #[arg(long, value_name = "N", alias = "count", value_parser = clap::value_parser!(u64).range(1..))]
    max_readings: Option<u64>,
    /// Stop after this many seconds.
    #[arg(long, value_name = "SECONDS", value_parser = sonar_common::parse_positive_seconds)]
    duration: Option<Duration>,
    /// Seconds between progress lines in the log.
    #[arg(long, value_name = "SECONDS", default_value = "5", value_parser = sonar_common::parse_positive_seconds)]
    progress_interval: Duration,
    /// Only the pipeline's own channels: no map, scans, transforms or scene for Foxglove.
    #[arg(long, conflicts_with = "ros2")]
    no_foxglove: bool,
    /// Also the ROS 2 messages /map (nav_msgs/msg/OccupancyGrid), /scan (sensor_msgs/msg/LaserScan)
    /// and /tf (tf2_msgs/msg/TFMessage), CDR-encoded, in a ROS 2 bag beside the file (run.mcap →
    /// run_ros2/: metadata.yaml and an MCAP file of profile ros2), for `ros2 bag play` and RViz.
    /// Not replaced if it exists, unless `--force`.
    #[arg(long)]
    ros2: bool,
    /// Seconds between the maps written for Foxglove (and ROS 2); the latest is always written
    /// at the end. A 400 × 400 map takes 800 KB as foxglove.Grid (+160 KB with --ros2).
    #[arg(long, value_name = "SECONDS", default_value = "5", value_parser = sonar_common::parse_positive_seconds)]
    grid_period: Duration,
    #[command(flatten)]
    ipc: IpcArgs,
}

fn main() -> std::process::ExitCode {
    sonar_common::init_tracing();
    sonar_common::report_exit("sonar-record", run(Args::parse()))
}

/// Counters the writer thread shares with the main thread.
#[derive(Debug, Default)]
struct Written {
    messages: AtomicU64,
}

/// What the writer thread reports at the end.
#[derive(Debug)]
struct Finished {
    counts: BTreeMap<Topic, u64>,
    /// Messages on the well-known channels (Foxglove, ROS 2).
    well_known: u64,
    bytes: u64,
}

fn run(args: Args) -> Result<()> {
    sonar_common::ipc::catch_termination_requests();
    let node = args.ipc.node("sonar-record")?;
    // The stop signal is caught from before the node (so anyone who sees our subscription may
    // stop us cleanly); one that came while the node was made is seen here.
    let signalled_early = node.wait(Duration::ZERO).is_err();
    let mut ports = Ports::open(&node, !args.no_foxglove)?;

    // The file after the ports: a failure to set those up leaves no file behind.
    let started_ns = ipc::unix_time_ns();
    let mut extra = BTreeMap::new();
    extra.insert(
        "recorder".to_owned(),
        format!("sonar-record {}", env!("CARGO_PKG_VERSION")),
    );
    extra.insert("started_unix_ns".to_owned(), started_ns.to_string());
    let writer = RecordingWriter::create(&args.file, args.force, &extra)
        .with_context(|| format!("cannot create the recording {}", args.file.display()))
        .map_err(|e| {
            if args.file.exists() && !args.force {
                e.context("the file exists: pass --force to replace it")
            } else {
                e
            }
        })?;

    let bag = args
        .ros2
        .then(|| {
            let dir = Ros2Bag::dir_beside(&args.file);
            Ros2Bag::create(&dir, args.force).with_context(|| {
                format!(
                    "cannot create the ROS 2 bag {} (pass --force to replace it)",
                    dir.display()
                )
            })
        })
        .transpose()?;
    let well_known = (!args.no_foxglove).then(|| WellKnown {
        options: WellKnownOptions {
            ros2: args.ros2,
            grid_period_ns: u64::try_from(args.grid_period.as_nanos()).unwrap_or(u64::MAX),
        },
        bag,
    });
    let written = Arc::new(Written::default());
    let (tx, rx) = mpsc::channel::<(u64, Item)>();
    let writer_thread = {
        let written = Arc::clone(&written);
        thread::Builder::new()
            .name("recording-writer".into())
            .spawn(move || write_loop(writer, well_known, rx, &written))
            .context("start the writer thread")?
    };

    info!(
        file = %args.file.display(),
        max_readings = ?args.max_readings,
        duration = ?args.duration,
        "recording"
    );
    let mut recorder = Recorder {
        tx,
        readings: 0,
        others: 0,
        lost: 0,
        last_seq: None,
        limit: args.max_readings,
        writer_gone: false,
    };
    let outcome = if signalled_early {
        info!("signal received before the recording started");
        Ok(())
    } else {
        recorder.run(&mut ports, &node, &args, &written)
    };

    // Closing the channel tells the writer to write what is queued and finish the file.
    let Recorder {
        tx, readings, lost, ..
    } = recorder;
    drop(tx);
    let finished = match writer_thread.join() {
        Ok(result) => result,
        Err(_) => Err(anyhow!("the writer thread panicked")),
    };
    // The writer's error, if any, is the cause; the loop's "writer stopped" only its echo.
    let finished = finished
        .and_then(|f| outcome.map(|()| f))
        .with_context(|| {
            format!(
                "recording {} failed after {readings} readings",
                args.file.display()
            )
        })?;
    let count = |t| finished.counts.get(&t).copied().unwrap_or(0);
    info!(
        file = %args.file.display(),
        readings = count(Topic::Readings),
        scan_commands = count(Topic::ScanCommands),
        fusion_commands = count(Topic::FusionCommands),
        poses = count(Topic::Pose),
        features = count(Topic::Features),
        localized_poses = count(Topic::LocalizedPose),
        slam_corrections = count(Topic::SlamCorrection),
        sweep_ends = count(Topic::SweepEnds),
        well_known = finished.well_known,
        lost,
        bytes = finished.bytes,
        seconds = format_args!("{:.1}", (ipc::unix_time_ns() - started_ns) as f64 / 1e9),
        "recording finished"
    );
    if lost > 0 {
        warn!(
            "{lost} readings were lost before they reached the recorder (see the warnings above)"
        );
    }
    Ok(())
}

/// The subscriptions. Readings are required; the other services are recorded when a subscriber
/// can be had (the commands' QoS allows only two subscribers, e.g. the driver and one recorder),
/// and tried again every second while it cannot (a service another process is creating at the
/// same instant may fail to open for a moment on a loaded machine).
struct Ports {
    readings: Subscriber<Ipc, Reading, ()>,
    scan_commands: OptionalPort<Subscriber<Ipc, ipc::ScanCommand, ()>>,
    fusion_commands: OptionalPort<Subscriber<Ipc, ipc::FusionCommand, ()>>,
    pose: OptionalPort<Subscriber<Ipc, ipc::Pose2D, ()>>,
    features: OptionalPort<Subscriber<Ipc, [FeatureRecord], FeaturesHeader>>,
    /// The map, for the well-known channels only (not replayed: the fusion derives it).
    grid: OptionalPort<Subscriber<Ipc, [u8], GridHeader>>,
    /// The corrections of the odometry: recorded, and the well-known channels' `map → odom` (not
    /// replayed: the fusion or sonar-slam derives them).
    localized_pose: OptionalPort<Subscriber<Ipc, ipc::LocalizedPose, ()>>,
    slam_correction: OptionalPort<Subscriber<Ipc, ipc::SlamCorrection, ()>>,
    /// Where the head said its sweeps ended (their wake-up is the readings').
    sweep_ends: OptionalPort<Subscriber<Ipc, ipc::SweepEnd, ()>>,
    /// Wake-up events: the readings' (required), then those of the other services had at start
    /// (one had later is polled).
    listeners: Vec<Listener<Ipc>>,
}

impl Ports {
    fn open(node: &Node<Ipc>, with_grid: bool) -> Result<Self> {
        let readings = ipc::readings_service(node)?
            .subscriber_builder()
            .create()
            .map_err(|e| IpcError::new("create readings subscriber", e))?;
        let mut listeners = vec![ipc::wakeup_listener(node, ipc::READINGS_SERVICE)?];
        let ports = Self {
            readings,
            scan_commands: OptionalPort::open(node, ipc::COMMANDS_SERVICE, |n| {
                subscriber(n, ipc::commands_service)
            }),
            fusion_commands: OptionalPort::open(node, ipc::FUSION_COMMANDS_SERVICE, |n| {
                subscriber(n, ipc::fusion_commands_service)
            }),
            pose: OptionalPort::open(node, ipc::POSE_SERVICE, |n| {
                subscriber(n, ipc::pose_service)
            }),
            features: OptionalPort::open(node, ipc::FEATURES_SERVICE, |n| {
                snapshot_subscriber(ipc::features_service(n))
            }),
            grid: OptionalPort::open_if(with_grid, node, ipc::GRID_SERVICE, |n| {
                snapshot_subscriber(ipc::grid_service(n))
            }),
            localized_pose: OptionalPort::open_if(
                with_grid,
                node,
                ipc::LOCALIZED_POSE_SERVICE,
                |n| subscriber(n, ipc::localized_pose_service),
            ),
            slam_correction: OptionalPort::open_if(
                with_grid,
                node,
                ipc::SLAM_CORRECTION_SERVICE,
                |n| subscriber(n, ipc::slam_correction_service),
            ),
            sweep_ends: OptionalPort::open(node, ipc::SWEEP_ENDS_SERVICE, |n| {
                subscriber(n, ipc::sweep_ends_service)
            }),
            listeners: Vec::new(),
        };
        for (present, service) in [
            (ports.scan_commands.get().is_some(), ipc::COMMANDS_SERVICE),
            (
                ports.fusion_commands.get().is_some(),
                ipc::FUSION_COMMANDS_SERVICE,
            ),
            (ports.pose.get().is_some(), ipc::POSE_SERVICE),
            (ports.features.get().is_some(), ipc::FEATURES_SERVICE),
            (ports.grid.get().is_some(), ipc::GRID_SERVICE),
            (
                ports.localized_pose.get().is_some(),
                ipc::LOCALIZED_POSE_SERVICE,
            ),
            (
                ports.slam_correction.get().is_some(),
                ipc::SLAM_CORRECTION_SERVICE,
            ),
        ] {
            if present {
                match ipc::wakeup_listener(node, service) {
                    Ok(l) => listeners.push(l),
                    Err(e) => debug!("no wake-up listener for {service} (polled instead): {e:#}"),
                }
            }
        }
        Ok(Self { listeners, ..ports })
    }

    /// Tries again, once the retry period has passed, the optional subscriptions that could not
    /// be had so far.
    fn retry_missing(&mut self, node: &Node<Ipc>) {
        let now = Instant::now();
        self.scan_commands.retry(node, now);
        self.fusion_commands.retry(node, now);
        self.pose.retry(node, now);
        self.features.retry(node, now);
        self.grid.retry(node, now);
        self.localized_pose.retry(node, now);
        self.slam_correction.retry(node, now);
        self.sweep_ends.retry(node, now);
    }
}

/// What the main thread hands the writer thread.
#[derive(Debug)]
enum Item {
    /// A message of the recording's own channels.
    Recorded(Message),
    /// A map snapshot, for the well-known channels.
    Grid(GridHeader, Vec<u8>),
}

struct Recorder {
    tx: Sender<(u64, Item)>,
    readings: u64,
    others: u64,
    lost: u64,
    last_seq: Option<u64>,
    limit: Option<u64>,
    writer_gone: bool,
}

impl Recorder {
    fn run(
        &mut self,
        ports: &mut Ports,
        node: &Node<Ipc>,
        args: &Args,
        written: &Written,
    ) -> Result<()> {
        let waitset = WaitSetBuilder::new()
            .create::<Ipc>()
            .map_err(|e| IpcError::new("create waitset", e))?;
        // The listeners apart from the ports: the waitset holds them while missing ports are
        // tried again.
        let listeners = std::mem::take(&mut ports.listeners);
        let mut _guards = Vec::new();
        for l in &listeners {
            _guards.push(
                waitset
                    .attach_notification(l)
                    .map_err(|e| IpcError::new("attach listener", e))?,
            );
        }
        let _interval = waitset
            .attach_interval(POLL)
            .map_err(|e| IpcError::new("attach interval", e))?;

        let start = Instant::now();
        let mut next_progress = start + args.progress_interval;
        let mut readings_at_progress = 0;
        loop {
            match waitset.wait_and_process_once(|_| CallbackProgression::Continue) {
                Ok(WaitSetRunResult::Interrupt | WaitSetRunResult::TerminationRequest) => {
                    info!("signal received: finishing the recording");
                    // What was delivered before the signal still belongs in the file.
                    self.drain_all(ports);
                    return Ok(());
                }
                Ok(_) => {}
                Err(e) => return Err(IpcError::new("wait for readings", e).into()),
            }
            for l in &listeners {
                let _ = l.try_wait(|_| {});
            }
            ports.retry_missing(node);
            let done = self.drain_all(ports);
            if self.writer_gone {
                bail!("the writer stopped");
            }
            if done {
                info!(readings = self.readings, "reached --max-readings");
                return Ok(());
            }
            if args.duration.is_some_and(|d| start.elapsed() >= d) {
                info!(readings = self.readings, "reached --duration");
                return Ok(());
            }
            let now = Instant::now();
            if now >= next_progress {
                let backlog = (self.readings + self.others)
                    .saturating_sub(written.messages.load(Ordering::Relaxed));
                let rate = (self.readings - readings_at_progress) as f64
                    / args.progress_interval.as_secs_f64();
                info!(
                    readings = self.readings,
                    rate = format_args!("{rate:.1}/s"),
                    commands_poses_features = self.others,
                    lost = self.lost,
                    backlog,
                    "recording"
                );
                if backlog > BACKLOG_WARNING {
                    warn!(
                        backlog,
                        "the disk is slower than the readings; they wait in memory"
                    );
                }
                readings_at_progress = self.readings;
                next_progress = now + args.progress_interval;
            }
            if node.wait(Duration::ZERO).is_err() {
                info!("signal received: finishing the recording");
                self.drain_all(ports);
                return Ok(());
            }
        }
    }

    /// Empties every subscriber (commands, poses and features first: they are usually older than
    /// the readings found in the same wake-up); true once `--max-readings` is reached.
    fn drain_all(&mut self, ports: &Ports) -> bool {
        let now = ipc::unix_time_ns();
        // The corrections before the poses: a pose's transforms carry the latest with them.
        if let Some(sub) = ports.localized_pose.get() {
            let next = || Ok::<_, ReceiveError>(sub.receive()?.map(|s| Message::LocalizedPose(*s)));
            self.drain(Topic::LocalizedPose, next, now);
        }
        if let Some(sub) = ports.slam_correction.get() {
            let next =
                || Ok::<_, ReceiveError>(sub.receive()?.map(|s| Message::SlamCorrection(*s)));
            self.drain(Topic::SlamCorrection, next, now);
        }
        if let Some(sub) = ports.scan_commands.get() {
            let next = || Ok::<_, ReceiveError>(sub.receive()?.map(|s| Message::ScanCommand(*s)));
            self.drain(Topic::ScanCommands, next, now);
        }
        if let Some(sub) = ports.fusion_commands.get() {
            let next = || Ok::<_, ReceiveError>(sub.receive()?.map(|s| Message::FusionCommand(*s)));
            self.drain(Topic::FusionCommands, next, now);
        }
        if let Some(sub) = ports.pose.get() {
            let next = || Ok::<_, ReceiveError>(sub.receive()?.map(|s| Message::Pose(*s)));
            self.drain(Topic::Pose, next, now);
        }
        if let Some(sub) = ports.features.get() {
            // History 1 and one snapshot a sweep: rarely more than one per wake-up.
            let next = || {
                Ok::<_, ReceiveError>(sub.receive()?.map(|s| {
                    Message::Features(FeatureSnapshot {
                        header: *s.user_header(),
                        records: s.payload().to_vec(),
                    })
                }))
            };
            self.drain(Topic::Features, next, now);
        }
        if let Some(sub) = ports.grid.get() {
            self.drain_grid(sub, now);
        }
        let done = self.drain_readings(&ports.readings);
        // After the readings: an end follows its sweep's last reading.
        if let Some(sub) = ports.sweep_ends.get() {
            let next = || Ok::<_, ReceiveError>(sub.receive()?.map(|s| Message::SweepEnd(*s)));
            self.drain(Topic::SweepEnds, next, ipc::unix_time_ns());
        }
        done
    }

    fn send(&mut self, log_time_ns: u64, message: Message) {
        self.send_item(log_time_ns, Item::Recorded(message));
    }

    fn send_item(&mut self, log_time_ns: u64, item: Item) {
        if self.tx.send((log_time_ns, item)).is_err() {
            self.writer_gone = true;
        }
    }

    /// Hands the newest map snapshot, if one came, to the writer (it keeps one every
    /// `--grid-period`); a snapshot of another layout or whose size disagrees with its header is
    /// left out.
    fn drain_grid(&mut self, sub: &Subscriber<Ipc, [u8], GridHeader>, now: u64) {
        let mut newest = None;
        loop {
            match sub.receive() {
                Ok(Some(sample)) => newest = Some(sample),
                Ok(None) => break,
                Err(e) => {
                    warn!("receiving {} failed: {e:?}", ipc::GRID_SERVICE);
                    break;
                }
            }
        }
        let Some(sample) = newest else { return };
        let header = *sample.user_header();
        let cells = sample.payload();
        if header.layout_version != LAYOUT_VERSION
            || (header.width as usize).checked_mul(header.height as usize) != Some(cells.len())
        {
            warn!(
                layout_version = header.layout_version,
                width = header.width,
                height = header.height,
                cells = cells.len(),
                "map snapshot left out: another layout, or its size disagrees with its header"
            );
            return;
        }
        self.send_item(now, Item::Grid(header, cells.to_vec()));
    }

    /// Takes every message `next` yields: a subscriber's `receive`, the payload copied out of
    /// shared memory.
    fn drain<E: Debug>(
        &mut self,
        topic: Topic,
        mut next: impl FnMut() -> Result<Option<Message>, E>,
        now: u64,
    ) {
        loop {
            match next() {
                Ok(Some(message)) => {
                    debug!(?message, "recorded");
                    self.others += 1;
                    self.send(now, message);
                }
                Ok(None) => return,
                Err(e) => {
                    warn!("receiving {topic} failed: {e:?}");
                    return;
                }
            }
        }
    }

    /// Takes every reading the subscriber holds; true once `--max-readings` is reached.
    fn drain_readings(&mut self, sub: &Subscriber<Ipc, Reading, ()>) -> bool {
        loop {
            if self.limit.is_some_and(|n| self.readings >= n) {
                return true;
            }
            let reading = match sub.receive() {
                Ok(Some(sample)) => *sample.payload(),
                Ok(None) => return false,
                Err(e) => {
                    warn!("receiving readings failed: {e:?}");
                    return false;
                }
            };
            match self.last_seq {
                Some(last) if reading.seq > last + 1 => {
                    let gap = reading.seq - last - 1;
                    self.lost += gap;
                    warn!(
                        gap,
                        seq = reading.seq,
                        "readings lost before the recorder got them (its buffer of 256 overflowed?)"
                    );
                }
                Some(last) if reading.seq <= last => {
                    info!(
                        seq = reading.seq,
                        "reading sequence restarted (a new driver?)"
                    );
                }
                _ => {}
            }
            self.last_seq = Some(reading.seq);
            self.readings += 1;
            self.send(ipc::unix_time_ns(), Message::Reading(reading));
        }
    }
}

/// What the well-known channels are written with: the options, and the ROS 2 bag with `--ros2`.
struct WellKnown {
    options: WellKnownOptions,
    bag: Option<Ros2Bag>,
}

fn write_loop(
    mut writer: RecordingWriter<BufWriter<File>>,
    well_known: Option<WellKnown>,
    rx: Receiver<(u64, Item)>,
    written: &Written,
) -> Result<Finished> {
    let mut well_known = well_known
        .map(|w| WellKnownChannels::declare(&mut writer, w.options, w.bag))
        .transpose()
        .context("declare the well-known channels")?;
    let mut last_flush = Instant::now();
    let mut dirty = false;
    loop {
        match rx.recv_timeout(FLUSH_PERIOD) {
            Ok((log_time, item)) => {
                match (&item, &mut well_known) {
                    (Item::Recorded(message), w) => {
                        writer.write(log_time, message)?;
                        written.messages.fetch_add(1, Ordering::Relaxed);
                        if let Some(w) = w {
                            w.message(&mut writer, log_time, message)?;
                        }
                    }
                    (Item::Grid(header, cells), Some(w)) => {
                        w.grid(&mut writer, log_time, header, cells)?
                    }
                    (Item::Grid(..), None) => {}
                }
                dirty = true;
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        if dirty && last_flush.elapsed() >= FLUSH_PERIOD {
            writer.flush()?;
            if let Some(w) = &mut well_known {
                w.flush()?;
            }
            dirty = false;
            last_flush = Instant::now();
        }
    }
    // The map kept back and the sweep in progress.
    let well_known = match well_known {
        Some(w) => w.finish(&mut writer, ipc::unix_time_ns())?,
        None => 0,
    };
    let counts = Topic::ALL
        .into_iter()
        .map(|t| (t, writer.count(t)))
        .collect();
    let file = writer
        .finish()?
        .into_inner()
        .map_err(|e| e.into_error())
        .context("write the end of the recording")?;
    file.sync_all().context("sync the recording to disk")?;
    let bytes = file.metadata().map(|m| m.len()).unwrap_or(0);
    Ok(Finished {
        counts,
        well_known,
        bytes,
    })
}
