//! `sonar-replay`: publishes a recording into the pipeline in place of the driver.
//!
//! The whole file is read and checked before anything is published, so a damaged file fails
//! with a clear message instead of half a replay. Readings go out on `sonar/readings` exactly as
//! recorded (unless `--restamp`), each followed by a notification on its wake-up event, like the
//! driver does; recorded fusion commands and poses go out on their services at their recorded
//! places in the stream. Scan commands and feature snapshots are in the file for the record but
//! are not replayed: the scan commands were addressed to the driver, which a replay stands in for,
//! and the features are what a fusion engine derives from the replayed readings.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Parser;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use sonar_common::ipc::{self, IpcArgs, IpcError, PubSub, Reading};
use sonar_recorder::format::{Message, ReadOptions, Recording, Topic, read_file};
use sonar_recorder::pace::{DEFAULT_BURST, DEFAULT_MAX_RATE, Pacer, Speed};
use tracing::{info, warn};

/// Progress lines in the log when there is no progress bar (stderr is not a terminal).
const PROGRESS_LOG_PERIOD: Duration = Duration::from_secs(5);

/// Publishes a recording made by sonar-record on `sonar/readings` (plus its fusion commands and
/// poses), in place of the driver: in real time, at a speed factor, or as fast as the consumers
/// can take it. See docs/recording.md.
///
/// Examples:
///   sonar-replay run.mcap                                   # real time
///   sonar-replay run.mcap --speed 10                        # ten times faster
///   sonar-replay run.mcap --speed max --wait-for-subscribers 1
///   sonar-replay run.mcap --info                            # what is in the file
#[derive(Debug, Parser)]
#[command(name = "sonar-replay", version, verbatim_doc_comment)]
struct Args {
    /// Recording to replay (MCAP, as sonar-record writes it).
    file: PathBuf,
    /// `1` real time (from the readings' recorded host_stamp_ns), a factor such as `10` or `0.5`,
    /// or `max`.
    #[arg(long, default_value = "1", allow_hyphen_values = true)]
    speed: Speed,
    /// Never publish more than this many messages (readings, commands, poses) per second, after a
    /// burst of 32 (0: no ceiling). Keeps a consumer's buffer of 256 from overflowing at high
    /// speeds. (`--max-rate` still works.)
    #[arg(long, value_name = "PER_SECOND", alias = "max-rate", default_value_t = DEFAULT_MAX_RATE)]
    max_message_rate: f64,
    /// Before publishing anything, wait until this many subscribers are connected to
    /// `sonar/readings`.
    #[arg(long, value_name = "N", default_value_t = 0)]
    wait_for_subscribers: usize,
    /// Replace each reading's host_stamp_ns, and each pose's stamp_ns, by the time it is
    /// published (the other bytes stay as recorded): the fusion places a reading at the pose of
    /// its stamp, so both move to the replay's clock.
    #[arg(long)]
    restamp: bool,
    /// Publish only the readings, not the recorded fusion commands and poses.
    #[arg(long)]
    readings_only: bool,
    /// Accept a file that ends early (a recorder that was killed) and replay what it holds.
    #[arg(long)]
    allow_truncated: bool,
    /// Print what the file holds and exit without publishing.
    #[arg(long)]
    info: bool,
    /// Seconds to stay after the last message before exiting. A consumer that has not fetched
    /// anything from this replay before it exits cannot fetch its messages afterwards (iceoryx2
    /// drops a departed publisher's samples unless the subscriber had connected to it).
    #[arg(long, value_name = "SECONDS", default_value_t = 1.0)]
    linger: f64,
    /// No progress bar (it is shown only when standard error is a terminal anyway).
    #[arg(long)]
    no_progress: bool,
    #[command(flatten)]
    ipc: IpcArgs,
}

fn main() -> std::process::ExitCode {
    sonar_common::init_tracing();
    sonar_common::report_exit("sonar-replay", run(Args::parse()))
}

fn run(args: Args) -> Result<()> {
    let options = ReadOptions {
        allow_truncated: args.allow_truncated,
    };
    let recording = read_file(&args.file, options)
        .with_context(|| format!("cannot replay {}", args.file.display()))?;
    if recording.truncated {
        warn!(
            messages = recording.entries.len(),
            "the file ends early; replaying the messages before the cut"
        );
    }
    if args.info {
        print_info(&args, &recording);
        return Ok(());
    }
    if recording.count(Topic::Readings) == 0 {
        anyhow::bail!(
            "{} holds no readings: nothing to replay (`sonar-replay --info {}` lists what it \
             holds; a recorder started after the driver stopped, or stopped before the first \
             sweep, records none)",
            args.file.display(),
            args.file.display()
        );
    }
    if !(args.max_message_rate.is_finite() && args.max_message_rate >= 0.0) {
        anyhow::bail!(
            "--max-message-rate must be a number ≥ 0, got {}",
            args.max_message_rate
        );
    }
    if !(args.linger.is_finite() && (0.0..1e6).contains(&args.linger)) {
        anyhow::bail!(
            "--linger must be a number of seconds ≥ 0, got {}",
            args.linger
        );
    }

    let node = args.ipc.node(ipc::REPLAY_NODE_NAME)?;
    // iceoryx2 installs its SIGINT/SIGTERM handler on the first wait: do it now, so a signal
    // from here on ends the replay cleanly.
    if node.wait(Duration::ZERO).is_err() {
        info!("signal received; nothing published");
        return Ok(());
    }
    let mut ports = Ports::open(&node, &recording, args.readings_only)?;
    if args.wait_for_subscribers > 0
        && !ports.wait_for_subscribers(&node, args.wait_for_subscribers)
    {
        info!("signal received while waiting for subscribers; nothing published");
        return Ok(());
    }

    let entries: Vec<_> = recording
        .entries
        .iter()
        .filter(|e| match e.message.topic() {
            // The sweeps' ends go with the readings: the fusion closes a sweep where the live one
            // did, the last one too (`docs/ipc.md`, `sonar/sweep_ends`).
            Topic::Readings | Topic::SweepEnds => true,
            // Addressed to the driver, or derived from the readings by the fusion or sonar-slam.
            Topic::ScanCommands
            | Topic::Features
            | Topic::LocalizedPose
            | Topic::SlamCorrection => false,
            Topic::FusionCommands | Topic::Pose => !args.readings_only,
        })
        .collect();
    let total_readings = recording.count(Topic::Readings) as u64;
    info!(
        file = %args.file.display(),
        readings = total_readings,
        others = entries.len() as u64 - total_readings,
        speed = %args.speed,
        max_message_rate = args.max_message_rate,
        "replaying"
    );
    let bar = progress_bar(total_readings, args.no_progress);
    let mut pacer = Pacer::new(args.speed, args.max_message_rate, DEFAULT_BURST);
    let start = Instant::now();
    let mut next_log = start + PROGRESS_LOG_PERIOD;
    let mut published = 0u64;
    let mut interrupted = false;
    for entry in &entries {
        let stamp = match &entry.message {
            Message::Reading(r) => r.host_stamp_ns,
            _ => entry.log_time_ns,
        };
        let due = pacer.due(stamp);
        let elapsed = start.elapsed();
        // Waiting through the node also notices Ctrl-C/SIGTERM; when there is nothing to wait for,
        // check every so often anyway.
        let wait = due.saturating_sub(elapsed);
        if (!wait.is_zero() || published.is_multiple_of(64)) && node.wait(wait).is_err() {
            interrupted = true;
            break;
        }
        ports.publish(&entry.message, args.restamp)?;
        pacer.sent(start.elapsed());
        if let Message::Reading(_) = entry.message {
            published += 1;
            bar.inc(1);
        }
        if bar.is_hidden() && Instant::now() >= next_log {
            info!(published, total = total_readings, "replaying");
            next_log += PROGRESS_LOG_PERIOD;
        }
    }
    bar.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();
    if !interrupted && node.wait(Duration::from_secs_f64(args.linger)).is_err() {
        interrupted = true;
    }
    info!(
        published,
        seconds = format_args!("{seconds:.2}"),
        rate = format_args!("{:.0}/s", published as f64 / seconds.max(1e-9)),
        subscribers = ports.subscribers(),
        "replay {}",
        if interrupted {
            "interrupted"
        } else {
            "finished"
        }
    );
    Ok(())
}

fn progress_bar(len: u64, disabled: bool) -> ProgressBar {
    if disabled || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template(
        "{elapsed_precise} [{wide_bar}] {pos}/{len} readings, eta {eta}",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar
}

/// A publisher and the notifier of its wake-up event.
type Port<T> = (Publisher<Ipc, T, ()>, Notifier<Ipc>);

struct Ports {
    readings_service: PubSub<Reading>,
    readings: Port<Reading>,
    fusion_commands: Option<Port<ipc::FusionCommand>>,
    pose: Option<Port<ipc::Pose2D>>,
    /// With the readings' wake-up event, which the fusion waits on.
    sweep_ends: Option<Port<ipc::SweepEnd>>,
}

impl Ports {
    /// Opens the readings publisher, and those of the other services only if the recording has
    /// messages for them (a replay should not occupy ports it never uses).
    fn open(node: &Node<Ipc>, recording: &Recording, readings_only: bool) -> Result<Self> {
        let readings_service = ipc::readings_service(node)?;
        let readings = port(node, &readings_service, ipc::READINGS_SERVICE)?;
        if readings_service.dynamic_config().number_of_publishers() > 1 {
            anyhow::bail!(
                "another process (a sonar-driver, or another sonar-replay) already publishes {} \
                 in this namespace, and the fusion would mix both streams into one map: stop it \
                 (a pipeline with a driver: sonar-pipeline --replay FILE replays without one), \
                 or replay into another namespace (--iox-prefix)",
                ipc::READINGS_SERVICE
            );
        }
        let wanted = |t| !readings_only && recording.count(t) > 0;
        let fusion_commands = if wanted(Topic::FusionCommands) {
            let service = ipc::fusion_commands_service(node)?;
            Some(port(node, &service, ipc::FUSION_COMMANDS_SERVICE)?)
        } else {
            None
        };
        let pose = if wanted(Topic::Pose) {
            let service = ipc::pose_service(node)?;
            Some(port(node, &service, ipc::POSE_SERVICE)?)
        } else {
            None
        };
        let sweep_ends = if recording.count(Topic::SweepEnds) > 0 {
            // On the readings' wake-up event, which the fusion waits on (as the driver does).
            let service = ipc::sweep_ends_service(node)?;
            Some(port_waking(
                node,
                &service,
                ipc::SWEEP_ENDS_SERVICE,
                ipc::READINGS_SERVICE,
            )?)
        } else {
            None
        };
        Ok(Self {
            readings_service,
            readings,
            fusion_commands,
            pose,
            sweep_ends,
        })
    }

    fn subscribers(&self) -> usize {
        self.readings_service
            .dynamic_config()
            .number_of_subscribers()
    }

    /// False if a signal came first.
    fn wait_for_subscribers(&self, node: &Node<Ipc>, n: usize) -> bool {
        let mut logged = false;
        while self.subscribers() < n {
            if !logged {
                info!(
                    want = n,
                    have = self.subscribers(),
                    "waiting for subscribers on {}",
                    ipc::READINGS_SERVICE
                );
                logged = true;
            }
            if node.wait(Duration::from_millis(10)).is_err() {
                return false;
            }
        }
        true
    }

    fn publish(&mut self, message: &Message, restamp: bool) -> Result<()> {
        match message {
            Message::Reading(r) => {
                let mut r = *r;
                if restamp {
                    r.host_stamp_ns = ipc::unix_time_ns();
                }
                send(&self.readings, r, ipc::READINGS_SERVICE)
            }
            Message::FusionCommand(c) => match &self.fusion_commands {
                Some(p) => send(p, *c, ipc::FUSION_COMMANDS_SERVICE),
                None => Ok(()),
            },
            Message::Pose(p) => match &self.pose {
                Some(port) => {
                    // The fusion places readings at the pose of their own stamp: both move to
                    // the replay's clock, or none.
                    let mut p = *p;
                    if restamp {
                        p.stamp_ns = ipc::unix_time_ns();
                    }
                    send(port, p, ipc::POSE_SERVICE)
                }
                None => Ok(()),
            },
            Message::SweepEnd(end) => match &self.sweep_ends {
                Some(port) => {
                    let mut end = *end;
                    if restamp {
                        end.stamp_ns = ipc::unix_time_ns();
                    }
                    send(port, end, ipc::SWEEP_ENDS_SERVICE)
                }
                None => Ok(()),
            },
            Message::ScanCommand(_)
            | Message::Features(_)
            | Message::LocalizedPose(_)
            | Message::SlamCorrection(_) => Ok(()),
        }
    }
}

fn port<T: std::fmt::Debug + ZeroCopySend>(
    node: &Node<Ipc>,
    service: &PubSub<T>,
    name: &str,
) -> Result<Port<T>> {
    port_waking(node, service, name, name)
}

/// A publisher on `service` (named `name`) with a notifier of the wake-up event `event`.
fn port_waking<T: std::fmt::Debug + ZeroCopySend>(
    node: &Node<Ipc>,
    service: &PubSub<T>,
    name: &str,
    event: &str,
) -> Result<Port<T>> {
    let publisher = service
        .publisher_builder()
        .create()
        .map_err(|e| IpcError::new(format!("create {name} publisher"), e))?;
    let notifier = ipc::wakeup_notifier(node, event)?;
    Ok((publisher, notifier))
}

fn send<T: std::fmt::Debug + ZeroCopySend>(port: &Port<T>, value: T, name: &str) -> Result<()> {
    let (publisher, notifier) = port;
    publisher
        .send_copy(value)
        .map_err(|e| IpcError::new(format!("send on {name}"), e))?;
    notifier
        .notify()
        .map_err(|e| IpcError::new(format!("notify {name}"), e))?;
    Ok(())
}

/// `--info`: a summary of the file on standard output.
fn print_info(args: &Args, recording: &Recording) {
    println!("file: {}", args.file.display());
    for (key, value) in &recording.metadata {
        println!("{key}: {value}");
    }
    let times = recording.entries.iter().map(|e| e.log_time_ns);
    if let (Some(first), Some(last)) = (times.clone().min(), times.max()) {
        println!("recorded: {:.3} s", last.saturating_sub(first) as f64 / 1e9);
    }
    for topic in Topic::ALL {
        let n = recording.count(topic);
        let seqs: Vec<u64> = match topic {
            Topic::Readings => recording.readings().map(|r| r.seq).collect(),
            _ => Vec::new(),
        };
        if let (Some(first), Some(last)) = (seqs.first(), seqs.last()) {
            let gaps = seqs
                .windows(2)
                .filter(|w| w[1] != w[0].wrapping_add(1))
                .count();
            println!("{topic}: {n} (seq {first}..={last}, {gaps} gaps)");
        } else {
            println!("{topic}: {n}");
        }
    }
    if recording.skipped > 0 {
        println!("other channels (skipped): {}", recording.skipped);
    }
    println!(
        "complete: {}",
        if recording.truncated {
            "no (truncated)"
        } else {
            "yes"
        }
    );
}
