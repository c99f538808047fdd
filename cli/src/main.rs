//! `sonar`: the tools people know from `ros2` and `iox2`, for this pipeline's services.
//!
//! - `sonar services`: every iceoryx2 service of the namespace, its messaging pattern, and the
//!   processes attached to it (their node names and pids), from iceoryx2's own records.
//! - `sonar echo TOPIC`: each message of a service decoded on one line (the layouts are
//!   `sonar_common::ipc`'s, so the tool never disagrees with the pipeline about them).
//! - `sonar hz TOPIC`: messages per second, once a second.
//! - `sonar reset-head`: a person's acknowledgement of a head stopped on a hardware fault.
//! - `sonar calibrate-range`: the sensor's range offset, on a wall at a known distance
//!   ([`calibrate`]).
//!
//! It is an ordinary consumer: it subscribes like the viewer does and costs the pipeline nothing
//! but a subscriber slot. It polls every [`POLL`] (a shell tool, not part of the pipeline), and
//! stops on Ctrl-C, SIGTERM, or after `--count`.

mod calibrate;

use std::fmt::Write as _;
use std::io::Write as _;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use iceoryx2::node::NodeView;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use sonar_common::ipc::{
    self, DriverStatus, FeatureRecord, FeaturesHeader, FusionCommand, FusionCommandKind,
    FusionStatus, GridHeader, IpcArgs, IpcError, LinkState, LocalizedPose, Pose2D, Radar, Reading,
    ScanCommand, ScanCommandKind, ScanMode, SlamCorrection, SweepEnd, feature_kind, slam_state,
};

/// How often `echo` and `hz` look for new messages.
const POLL: Duration = Duration::from_millis(5);

/// The pipeline's services from a shell: which exist and who is attached, their messages
/// decoded, their rates. Takes the pipeline's --iox-* settings (or SONAR_IOX_*) like every other
/// program.
///
/// Examples:
///   sonar services
///   sonar echo readings --count 10
///   sonar hz grid
///   sonar reset-head        # a person checked a head stopped on a hardware fault
///   sonar calibrate-range --wall-distance 1.00   # the head still, facing a wall 1 m away
#[derive(Debug, Parser)]
#[command(name = "sonar", version, verbatim_doc_comment)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    #[command(flatten)]
    ipc: IpcArgs,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Every service of the namespace, its pattern, and the processes attached to it.
    Services,
    /// Prints each message of a service, decoded, one per line (standard output).
    Echo {
        topic: Topic,
        /// Stop after N messages (default: until Ctrl-C).
        #[arg(long, value_name = "N")]
        count: Option<u64>,
    },
    /// Prints the messages per second of a service, once a second (standard output).
    Hz {
        topic: Topic,
        /// Stop after N reports (default: until Ctrl-C).
        #[arg(long, value_name = "N")]
        count: Option<u64>,
    },
    /// Acknowledge a head stopped on a hardware fault, once a person has checked it (its limit
    /// switches, their wiring, that it turns freely): the driver sends RESET, the head homes
    /// again, then the driver sends its scan. As the viewer's R key.
    ResetHead,
    /// Measures the sensor's range offset (`[features] range_offset_m`, taken off every range by
    /// the features, the grid and the SLAM) on a flat wall at a known distance: keep the head
    /// still, facing the wall with nothing nearer, while it sweeps; each sweep's wall, seen
    /// whole, gives its distance as the mean of its pings, and the offset is their mean less
    /// the distance given. Prints the lines to put in the pipeline's configuration file.
    CalibrateRange(calibrate::Settings),
}

/// The services `echo` and `hz` know how to decode (a service's own name, `driver_status`, is
/// taken too).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Topic {
    /// sonar/readings: one line per reading.
    Readings,
    /// sonar/sweep_ends: each sweep the head reported ended, with its last reading's seq.
    #[value(alias = "sweep_ends")]
    SweepEnds,
    /// sonar/driver_status: the link, the scan, the counters.
    #[value(alias = "driver_status")]
    DriverStatus,
    /// sonar/grid: the snapshot headers (not the cells).
    Grid,
    /// robot/pose: the odometry.
    Pose,
    /// robot/true_pose: the simulator's true pose beside its odometry.
    #[value(alias = "true_pose")]
    TruePose,
    /// sonar/localized_pose: localisation's pose of each sweep, its σ, the odometry's.
    #[value(alias = "localized_pose")]
    LocalizedPose,
    /// sonar/fusion_status: the fusion's health counters (lost, rejected, saves, …).
    #[value(alias = "fusion_status")]
    FusionStatus,
    /// sonar/slam_correction: sonar-slam's map → odom correction after each sweep, its σ, the
    /// fix state, the pose in the map and the odometry's.
    #[value(alias = "slam_correction")]
    SlamCorrection,
    /// sonar/slam_landmarks: sonar-slam's landmarks after each sweep, in the map frame (walls
    /// by the foot of their perpendicular, points), one line each.
    #[value(alias = "slam_landmarks")]
    SlamLandmarks,
    /// sonar/radar: the basic map's snapshot (bins with a distance, nearest).
    Radar,
    /// sonar/features: each snapshot's counts, then one line per wall, corner and post.
    Features,
    /// sonar/commands: the scan commands sent to the driver (full, local, stop, …).
    Commands,
    /// sonar/fusion_commands: the commands sent to the fusion (clear, preset, model, rule).
    #[value(alias = "fusion_commands")]
    FusionCommands,
}

impl Topic {
    fn service(self) -> &'static str {
        match self {
            Topic::Readings => ipc::READINGS_SERVICE,
            Topic::SweepEnds => ipc::SWEEP_ENDS_SERVICE,
            Topic::DriverStatus => ipc::DRIVER_STATUS_SERVICE,
            Topic::Grid => ipc::GRID_SERVICE,
            Topic::Pose => ipc::POSE_SERVICE,
            Topic::TruePose => ipc::TRUE_POSE_SERVICE,
            Topic::LocalizedPose => ipc::LOCALIZED_POSE_SERVICE,
            Topic::FusionStatus => ipc::FUSION_STATUS_SERVICE,
            Topic::SlamCorrection => ipc::SLAM_CORRECTION_SERVICE,
            Topic::SlamLandmarks => ipc::SLAM_LANDMARKS_SERVICE,
            Topic::Radar => ipc::RADAR_SERVICE,
            Topic::Features => ipc::FEATURES_SERVICE,
            Topic::Commands => ipc::COMMANDS_SERVICE,
            Topic::FusionCommands => ipc::FUSION_COMMANDS_SERVICE,
        }
    }
}

fn main() -> ExitCode {
    sonar_common::init_tracing();
    sonar_common::report_exit("sonar", run(Cli::parse()))
}

fn run(cli: Cli) -> Result<()> {
    let node = cli.ipc.node("sonar-cli")?;
    match cli.command {
        Command::Services => services(&cli.ipc),
        Command::Echo { topic, count } => {
            let mut out = Lines::new(count);
            receive(&node, topic, |line| out.print(line))
        }
        Command::Hz { topic, count } => hz(&node, topic, count),
        Command::ResetHead => reset_head(&node),
        Command::CalibrateRange(settings) => calibrate::run(&node, &settings),
    }
}

/// Driver status messages to wait for after sending the reset: the driver publishes one at least
/// every second and takes a command as soon as it is woken, so by the second it has taken the
/// reset.
const RESET_STATUSES: usize = 2;

/// `reset-head`: sends the reset command and reports what the driver says after it.
fn reset_head(node: &Node<Ipc>) -> Result<()> {
    let status = ipc::driver_status_service(node)?
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new("subscribe to the driver status", e))?;
    let commands = ipc::commands_service(node)?
        .publisher_builder()
        .create()
        .map_err(|e| IpcError::new("publish on the commands service", e))?;
    // The driver sleeps on the commands' wake-up event between lines from the head.
    let wake = ipc::wakeup_notifier(node, ipc::COMMANDS_SERVICE)?;
    let delivered = commands
        .send_copy(ScanCommand::new(ScanCommandKind::Reset, 0.0, 0.0))
        .map_err(|e| IpcError::new("send the reset command", e))?;
    wake.notify()
        .map_err(|e| IpcError::new("wake the driver", e))?;
    anyhow::ensure!(
        delivered > 0,
        "no driver listens on {} (is sonar-driver running, with the same --iox-* settings?)",
        ipc::COMMANDS_SERVICE
    );
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut seen = Vec::new();
    while seen.len() < RESET_STATUSES {
        anyhow::ensure!(
            Instant::now() < deadline,
            "the driver published no status for 10 s after the reset"
        );
        while let Some(sample) = status
            .receive()
            .map_err(|e| IpcError::new("receive the driver status", e))?
        {
            seen.push(*sample.payload());
        }
        if node.wait(Duration::from_millis(50)).is_err() {
            return Ok(());
        }
    }
    let last = seen[seen.len() - 1];
    println!(
        "reset sent: the head homes again ({})",
        driver_status_line(&last)
    );
    Ok(())
}

/// `services`: one line per service, sorted by name.
fn services(args: &IpcArgs) -> Result<()> {
    let cfg = args.config()?;
    let mut rows = Vec::new();
    Ipc::list(&cfg, |service| {
        let name = service.static_details.name().to_string();
        let pattern = format!("{}", service.static_details.messaging_pattern());
        let mut attached: Vec<String> = service
            .dynamic_details
            .iter()
            .flat_map(|d| &d.nodes)
            .filter_map(|n| match n {
                iceoryx2::node::NodeState::Alive(view) => view
                    .details()
                    .as_ref()
                    .map(|d| format!("{} (pid {})", d.name(), d.process_id().value())),
                iceoryx2::node::NodeState::Dead(_) => Some("a dead process".to_owned()),
                _ => None,
            })
            .collect();
        attached.sort();
        attached.dedup();
        rows.push((name, pattern, attached));
        CallbackProgression::Continue
    })
    .map_err(|e| IpcError::new("list the services", e))?;
    rows.sort();
    let mut text = String::new();
    for (name, pattern, attached) in &rows {
        let who = if attached.is_empty() {
            "nobody attached".to_owned()
        } else {
            attached.join(", ")
        };
        let _ = writeln!(text, "{name:<24} {pattern:<16} {who}");
    }
    if rows.is_empty() {
        text.push_str("no services: is the pipeline running with these --iox-* settings?\n");
    }
    std::io::stdout()
        .write_all(text.as_bytes())
        .context("write to standard output")
}

/// Stops after `limit` lines; a closed standard output (`| head`) ends it quietly.
struct Lines {
    limit: Option<u64>,
    printed: u64,
    out: std::io::Stdout,
}

impl Lines {
    fn new(limit: Option<u64>) -> Self {
        Self {
            limit,
            printed: 0,
            out: std::io::stdout(),
        }
    }

    /// False when no more lines are wanted.
    fn print(&mut self, line: String) -> Result<bool> {
        if self.limit.is_some_and(|n| self.printed >= n) {
            return Ok(false);
        }
        match writeln!(self.out.lock(), "{line}") {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return Ok(false),
            Err(e) => return Err(e).context("write to standard output"),
        }
        self.printed += 1;
        Ok(self.limit.is_none_or(|n| self.printed < n))
    }
}

/// `hz`: counts what arrives and prints the rate once a second.
fn hz(node: &Node<Ipc>, topic: Topic, count: Option<u64>) -> Result<()> {
    let mut out = Lines::new(count);
    let mut window = (Instant::now(), 0u64);
    receive_or_tick(node, topic, |line| {
        if line.is_some() {
            window.1 += 1;
        }
        let elapsed = window.0.elapsed();
        if elapsed < Duration::from_secs(1) {
            return Ok(true);
        }
        let rate = window.1 as f64 / elapsed.as_secs_f64();
        let report = format!(
            "{}: {rate:.1} messages/s ({} in {:.2} s)",
            topic.service(),
            window.1,
            elapsed.as_secs_f64()
        );
        window = (Instant::now(), 0);
        out.print(report)
    })
}

/// `echo`: each message decoded; `each` returns false to stop.
fn receive(
    node: &Node<Ipc>,
    topic: Topic,
    mut each: impl FnMut(String) -> Result<bool>,
) -> Result<()> {
    receive_or_tick(node, topic, |line| match line {
        Some(line) => each(line),
        None => Ok(true),
    })
}

/// Subscribes to `topic` and calls `each` with every message decoded, and with `None` after each
/// poll; stops when it returns false, or on a signal.
fn receive_or_tick(
    node: &Node<Ipc>,
    topic: Topic,
    mut each: impl FnMut(Option<String>) -> Result<bool>,
) -> Result<()> {
    let service = topic.service();
    match topic {
        Topic::Readings => each_message(
            node,
            &ipc::readings_service(node)?,
            service,
            reading_line,
            each,
        ),
        Topic::SweepEnds => each_message(
            node,
            &ipc::sweep_ends_service(node)?,
            service,
            sweep_end_line,
            each,
        ),
        Topic::DriverStatus => each_message(
            node,
            &ipc::driver_status_service(node)?,
            service,
            driver_status_line,
            each,
        ),
        Topic::Pose => each_message(node, &ipc::pose_service(node)?, service, pose_line, each),
        Topic::TruePose => each_message(
            node,
            &ipc::true_pose_service(node)?,
            service,
            pose_line,
            each,
        ),
        Topic::LocalizedPose => each_message(
            node,
            &ipc::localized_pose_service(node)?,
            service,
            localized_pose_line,
            each,
        ),
        Topic::SlamCorrection => each_message(
            node,
            &ipc::slam_correction_service(node)?,
            service,
            slam_correction_line,
            each,
        ),
        Topic::FusionStatus => each_message(
            node,
            &ipc::fusion_status_service(node)?,
            service,
            fusion_status_line,
            each,
        ),
        Topic::Radar => each_message(node, &ipc::radar_service(node)?, service, radar_line, each),
        Topic::Commands => each_message(
            node,
            &ipc::commands_service(node)?,
            service,
            scan_command_line,
            each,
        ),
        Topic::FusionCommands => each_message(
            node,
            &ipc::fusion_commands_service(node)?,
            service,
            fusion_command_line,
            each,
        ),
        Topic::Features | Topic::SlamLandmarks => {
            let port = if topic == Topic::Features {
                ipc::features_service(node)?
            } else {
                ipc::slam_landmarks_service(node)?
            };
            let sub = subscribe(&port, service)?;
            poll(node, &mut each, || {
                Ok(sub
                    .receive()
                    .map_err(|e| IpcError::new(format!("receive from {service}"), e))?
                    .map(|s| features_lines(s.user_header(), s.payload())))
            })
        }
        Topic::Grid => {
            let sub = subscribe(&ipc::grid_service(node)?, service)?;
            poll(node, &mut each, || {
                Ok(sub
                    .receive()
                    .map_err(|e| IpcError::new(format!("receive from {service}"), e))?
                    .map(|s| grid_line(s.user_header(), s.payload().len())))
            })
        }
    }
}

/// [`receive_or_tick`] for a service of fixed-size messages, each decoded by `line`.
fn each_message<T: std::fmt::Debug + ZeroCopySend + 'static>(
    node: &Node<Ipc>,
    port: &ipc::PubSub<T>,
    service: &str,
    line: fn(&T) -> String,
    mut each: impl FnMut(Option<String>) -> Result<bool>,
) -> Result<()> {
    let sub = subscribe(port, service)?;
    poll(node, &mut each, || {
        Ok(sub
            .receive()
            .map_err(|e| IpcError::new(format!("receive from {service}"), e))?
            .map(|s| line(s.payload())))
    })
}

fn subscribe<P, H>(port: &PortFactory<Ipc, P, H>, service: &str) -> Result<Subscriber<Ipc, P, H>>
where
    P: std::fmt::Debug + IceoryxSend + ?Sized + 'static,
    H: std::fmt::Debug + ZeroCopySend + 'static,
{
    Ok(port
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new(format!("subscribe to {service}"), e))?)
}

/// Takes everything waiting, then sleeps [`POLL`] on the node (which also notices signals).
fn poll(
    node: &Node<Ipc>,
    each: &mut impl FnMut(Option<String>) -> Result<bool>,
    mut next: impl FnMut() -> Result<Option<String>>,
) -> Result<()> {
    loop {
        while let Some(line) = next()? {
            if !each(Some(line))? {
                return Ok(());
            }
        }
        if !each(None)? || node.wait(POLL).is_err() {
            return Ok(());
        }
    }
}

fn slam_correction_line(c: &SlamCorrection) -> String {
    let state = match c.state {
        slam_state::FIX => "fix",
        slam_state::NO_LANDMARKS => "no fix (no landmarks)",
        slam_state::UNCERTAIN => "no fix (too uncertain)",
        slam_state::REFUSED => "no fix (refused)",
        slam_state::REVISED => "revised (moved by later sweeps)",
        _ => "unknown state",
    };
    let sigma = |v: f32| v.max(0.0).sqrt();
    format!(
        "sweep {} {state} map→odom {:+.3} {:+.3} {:+.2}° σ {:.3} m {:.3} m {:.2}° pose {:+.3} {:+.3} {:+.1}° σ {:.3} m {:.3} m {:.2}° odometry {:+.3} {:+.3} {:+.1}° matched {} landmarks {} fixes {} refused {}",
        c.sweep_id,
        c.correction_x_m,
        c.correction_y_m,
        c.correction_theta_rad.to_degrees(),
        sigma(c.correction_cov_xx),
        sigma(c.correction_cov_yy),
        sigma(c.correction_cov_thetatheta).to_degrees(),
        c.x_m,
        c.y_m,
        c.theta_rad.to_degrees(),
        sigma(c.cov_xx),
        sigma(c.cov_yy),
        sigma(c.cov_thetatheta).to_degrees(),
        c.odometry_x_m,
        c.odometry_y_m,
        c.odometry_theta_rad.to_degrees(),
        c.matched,
        c.landmarks,
        c.fixes,
        c.refused,
    )
}

fn localized_pose_line(p: &LocalizedPose) -> String {
    // A prediction without a fix has a NaN covariance: say so rather than print NaN.
    let sigma = if p.matched == 0 || !p.cov_xx.is_finite() {
        "no fix".to_owned()
    } else {
        format!(
            "σ {:.3} m {:.3} m {:.2}°",
            p.cov_xx.max(0.0).sqrt(),
            p.cov_yy.max(0.0).sqrt(),
            p.cov_thetatheta.max(0.0).sqrt().to_degrees()
        )
    };
    format!(
        "stamp {} x {:+.3} y {:+.3} θ {:+.1}° {sigma} matched {} fixes {} odometry {:+.3} {:+.3} {:+.1}°",
        p.stamp_ns,
        p.x_m,
        p.y_m,
        p.theta_rad.to_degrees(),
        p.matched,
        p.fixes,
        p.odometry_x_m,
        p.odometry_y_m,
        p.odometry_theta_rad.to_degrees()
    )
}

fn fusion_status_line(s: &FusionStatus) -> String {
    format!(
        "received {} fused {} lost {} out_of_order {} rejected {} snapshots {} skipped {} saves {} save_failures {} restored {} feature_readings_skipped {}",
        s.readings_received,
        s.readings_fused,
        s.readings_lost,
        s.readings_out_of_order,
        s.readings_rejected,
        s.snapshots_published,
        s.snapshots_skipped,
        s.saves,
        s.save_failures,
        s.restored,
        s.feature_readings_skipped
    )
}

fn radar_line(r: &Radar) -> String {
    let bins = (r.bin_count as usize).min(r.distances_m.len());
    let heard: Vec<f32> = r.distances_m[..bins]
        .iter()
        .copied()
        .filter(|d| d.is_finite() && *d > 0.0)
        .collect();
    let nearest = heard
        .iter()
        .copied()
        .fold(None, |m: Option<f32>, d| Some(m.map_or(d, |m| m.min(d))));
    format!(
        "seq {} sweep {} bins {} with a distance {}{} at {:+.1}°",
        r.seq,
        r.sweep_id,
        bins,
        heard.len(),
        nearest.map_or(String::new(), |d| format!(", nearest {d:.3} m")),
        r.current_angle_deg
    )
}

/// A snapshot's counts, then one line per feature.
fn features_lines(h: &FeaturesHeader, records: &[FeatureRecord]) -> String {
    let mut out = format!(
        "seq {} sweeps {} features {} (left out {})",
        h.seq, h.sweeps, h.feature_count, h.features_left_out
    );
    for f in records {
        let kind = match f.kind {
            feature_kind::PLANE => "wall",
            feature_kind::CORNER => "corner",
            feature_kind::POINT => "post",
            _ => "unknown",
        };
        // Heard from one place only: it may be a phantom (`docs/features.md`).
        let tentative = if f.is_confirmed() { "" } else { " tentative" };
        out.push_str(&format!(
            "\n  {kind} {} at {:+.3} {:+.3} seen {}{tentative}",
            f.id, f.x_m, f.y_m, f.times_seen
        ));
    }
    out
}

fn reading_line(r: &Reading) -> String {
    let range = if r.flags & ipc::flags::NO_ECHO != 0 {
        "no echo".to_owned()
    } else {
        format!("{:.3} m", r.distance_m)
    };
    format!(
        "seq {} sweep {} angle {:+.1}° {range} tof {:.0} µs flags {:#x}",
        r.seq, r.sweep_id, r.angle_deg, r.tof_us, r.flags
    )
}

fn driver_status_line(s: &DriverStatus) -> String {
    let link = match s.link_state {
        x if x == LinkState::Connecting as u32 => "connecting",
        x if x == LinkState::Connected as u32 => "connected",
        x if x == LinkState::Disconnected as u32 => "disconnected",
        x if x == LinkState::Refused as u32 => "refused",
        _ => "unknown",
    };
    let mode = match s.mode {
        x if x == ScanMode::Full as u32 => "full",
        x if x == ScanMode::Local as u32 => "local",
        x if x == ScanMode::Idle as u32 => "stopped",
        _ => "unknown",
    };
    let mut line = format!(
        "{link} scan {mode} sweep {} angle {:+.1}° readings {} rejected {} reconnects {}",
        s.sweep_id, s.angle_deg, s.readings_published, s.lines_rejected, s.reconnects
    );
    if s.head_fault != 0 {
        line.push_str(" HEAD STOPPED on a hardware fault: check it, then `sonar reset-head`");
    }
    if s.device_errors > 0 {
        let _ = write!(
            line,
            " device errors {} (last: {})",
            s.device_errors,
            s.last_device_error()
        );
    }
    line
}

fn grid_line(h: &GridHeader, cells: usize) -> String {
    format!(
        "seq {} readings {} {}×{} of {:.3} m ({cells} cells) occupied {} free {} unknown {}",
        h.seq,
        h.readings_fused,
        h.width,
        h.height,
        h.resolution_m,
        h.occupied_cells,
        h.free_cells,
        h.unknown_cells
    )
}

fn scan_command_line(c: &ScanCommand) -> String {
    match c.kind() {
        Some(ScanCommandKind::FullScan) => "full scan".to_owned(),
        Some(ScanCommandKind::LocalScan) => {
            format!("local scan {:+.1}° .. {:+.1}°", c.from_deg, c.to_deg)
        }
        Some(ScanCommandKind::Stop) => "stop".to_owned(),
        Some(ScanCommandKind::Status) => "status".to_owned(),
        Some(ScanCommandKind::Reset) => "reset".to_owned(),
        None => format!("unknown kind {}", c.kind),
    }
}

fn fusion_command_line(c: &FusionCommand) -> String {
    let name = |names: &[(u32, &str)]| {
        names
            .iter()
            .find(|(code, _)| *code == c.value)
            .map_or_else(|| format!("code {}", c.value), |(_, n)| (*n).to_owned())
    };
    match c.kind() {
        Some(FusionCommandKind::Clear) => "clear".to_owned(),
        Some(FusionCommandKind::SetPreset) => format!(
            "preset {}",
            name(&[
                (ipc::preset_code::CUSTOM, "custom"),
                (ipc::preset_code::PAPER, "paper"),
                (ipc::preset_code::RECOMMENDED, "recommended"),
            ])
        ),
        Some(FusionCommandKind::SetModel) => format!(
            "model {}",
            name(&[
                (ipc::model_code::PAPER, "paper"),
                (ipc::model_code::LOG_ODDS, "log-odds"),
                (ipc::model_code::SMOOTH, "smooth"),
            ])
        ),
        Some(FusionCommandKind::SetRule) => format!(
            "rule {}",
            name(&[
                (ipc::rule_code::BAYES, "bayes"),
                (ipc::rule_code::LOG_ODDS, "log-odds"),
                (ipc::rule_code::DEMPSTER_SHAFER, "dempster-shafer"),
                (ipc::rule_code::HIMM, "himm"),
            ])
        ),
        None => format!("unknown kind {} value {}", c.kind, c.value),
    }
}

fn sweep_end_line(e: &SweepEnd) -> String {
    format!(
        "stamp {} sweep {} ended, its last reading seq {}",
        e.stamp_ns, e.sweep_id, e.last_seq
    )
}

fn pose_line(p: &Pose2D) -> String {
    format!(
        "stamp {} x {:+.3} m y {:+.3} m heading {:+.1}°",
        p.stamp_ns,
        p.x_m,
        p.y_m,
        p.theta_rad.to_degrees()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_feature_heard_from_one_place_only_is_marked_tentative() {
        let post = FeatureRecord {
            id: 4,
            kind: feature_kind::POINT,
            times_seen: 3,
            x_m: 0.975,
            flags: ipc::feature_flags::CONFIRMED,
            ..FeatureRecord::default()
        };
        let wall = FeatureRecord {
            id: 5,
            kind: feature_kind::PLANE,
            x_m: 2.0,
            flags: 0,
            ..post
        };
        let header = FeaturesHeader {
            seq: 2,
            sweeps: 6,
            feature_count: 2,
            ..FeaturesHeader::default()
        };
        assert_eq!(
            features_lines(&header, &[post, wall]),
            "seq 2 sweeps 6 features 2 (left out 0)\n  post 4 at +0.975 +0.000 seen 3\n  \
             wall 5 at +2.000 +0.000 seen 3 tentative"
        );
    }

    #[test]
    fn a_slam_correction_says_whether_it_is_a_fix_and_how_sure() {
        let c = SlamCorrection {
            sweep_id: 9,
            state: slam_state::FIX,
            correction_x_m: 0.1,
            correction_theta_rad: 2f32.to_radians(),
            correction_cov_xx: 0.0004,
            correction_cov_yy: 0.0009,
            correction_cov_thetatheta: 1f32.to_radians().powi(2),
            matched: 3,
            landmarks: 12,
            fixes: 5,
            ..SlamCorrection::default()
        };
        let line = slam_correction_line(&c);
        assert!(
            line.starts_with("sweep 9 fix map→odom +0.100 +0.000 +2.00° σ 0.020 m 0.030 m 1.00°"),
            "{line}"
        );
        assert!(
            line.ends_with("matched 3 landmarks 12 fixes 5 refused 0"),
            "{line}"
        );
        let uncertain = SlamCorrection {
            state: slam_state::UNCERTAIN,
            ..c
        };
        assert!(slam_correction_line(&uncertain).contains(" no fix (too uncertain) "));
    }

    #[test]
    fn lines_are_decoded_with_their_units() {
        let r = Reading {
            seq: 7,
            sweep_id: 2,
            angle_deg: -12.5,
            distance_m: 1.2341,
            tof_us: 7190.0,
            ..Reading::default()
        };
        assert_eq!(
            reading_line(&r),
            "seq 7 sweep 2 angle -12.5° 1.234 m tof 7190 µs flags 0x0"
        );
        let silent = Reading {
            flags: ipc::flags::NO_ECHO,
            ..r
        };
        assert!(reading_line(&silent).contains("no echo"));
        let mut s = DriverStatus {
            link_state: LinkState::Connected as u32,
            mode: ScanMode::Idle as u32,
            device_errors: 1,
            ..DriverStatus::default()
        };
        ipc::set_padded_text(&mut s.last_device_error, "RANGE: outside");
        let line = driver_status_line(&s);
        assert!(line.starts_with("connected scan stopped"), "{line}");
        assert!(
            line.ends_with("device errors 1 (last: RANGE: outside)"),
            "{line}"
        );
        s.head_fault = 1;
        let line = driver_status_line(&s);
        assert!(line.contains("HEAD STOPPED"), "{line}");
    }

    #[test]
    fn commands_are_decoded() {
        let local = ScanCommand::new(ScanCommandKind::LocalScan, -45.0, 30.0);
        assert_eq!(scan_command_line(&local), "local scan -45.0° .. +30.0°");
        let odd = ScanCommand { kind: 9, ..local };
        assert_eq!(scan_command_line(&odd), "unknown kind 9");
        let preset = FusionCommand::new(FusionCommandKind::SetPreset, ipc::preset_code::PAPER);
        assert_eq!(fusion_command_line(&preset), "preset paper");
        let rule = FusionCommand::new(FusionCommandKind::SetRule, 77);
        assert_eq!(fusion_command_line(&rule), "rule code 77");
        let clear = FusionCommand::new(FusionCommandKind::Clear, 0);
        assert_eq!(fusion_command_line(&clear), "clear");
    }
}
