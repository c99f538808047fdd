//! `sonar-sim`: the simulated sonar head on a pseudo-terminal. See the crate docs for the device's
//! behaviour and the echo model.
//!
//! With a scene that has a `[robot]`, also an iceoryx2 node publishing the odometry on `robot/pose`
//! and the truth on `robot/true_pose`. The node never waits on iceoryx2, so iceoryx2 installs no
//! signal handler of its own: SIGINT/SIGTERM stay with the flag below, the serve loop ends, and
//! the publishers and the node are dropped, which removes their shared memory.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Parser, ValueEnum};
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use sonar_common::ipc::{self, IpcArgs, Pose2D};
use sonar_common::protocol::{PROTOCOL_VERSION, ProtocolVersion, parse_head_id};
use sonar_common::sensor::SensorConfig;
use sonar_common::throttle::Throttle;
use sonar_sim::link::open_announced;
use sonar_sim::{
    Carrier, Device, EchoModel, FaultInjector, FaultSpec, Firmware, HobbySketch, NativeDevice,
    OdometryParams, Pose, PoseSample, Rover, Scene, SensorProfile, Speed, Timing, serve,
};
use tracing::{info, warn};

/// Failed publications are logged at most this often.
const PUBLISH_WARN_PERIOD: Duration = Duration::from_secs(1);
/// Highest --pose-rate: far above any wheel odometry, and it bounds the work per simulated second.
const MAX_POSE_RATE_HZ: f64 = 1000.0;

/// Simulated sonar head: an SRF05 on a stepper sweeping 300° between two limit switches, driven by
/// a microcontroller that speaks the sonar protocol (docs/protocol.md) on a pseudo-terminal.
///
/// The first line on standard output is `PTY <path>`: open that path as the serial port (any baud
/// rate works). Logs go to standard error (level from RUST_LOG). Ctrl-C or SIGTERM stops the
/// simulator cleanly.
///
/// Scenes (sensor at the origin facing +x; built-in ones after the paper's Figs. 8–11):
///   room           2.4 m square room, sensor at its centre (full scan)
///   corner         two walls meeting in a 90° corner 1.2 m ahead (local scan)
///   obstacle       a 5 cm post 1.0 m ahead of a wall at 2.0 m (local scan)
///   two-obstacles  two 5 cm posts 0.30 m apart at 1.0 m, wall at 2.0 m (local scan)
/// with a robot carrying the head (angle 0 along its heading):
///   room-tour      the room, toured round a 1.2 m square, scanning while driving
///   corridor       6 m × 1.2 m corridor, doorways into two 3 m × 3 m rooms, stop-and-scan tour
/// or a .toml/.json file in the format of simulator/scenes/*.toml.
///
/// With a robot, its odometry (with the scene's [odometry] errors, or the --odom-* flags) is
/// published on the iceoryx2 service robot/pose and its true pose on robot/true_pose, at
/// --pose-rate per simulated second, stamped with the host's clock at the pose's instant.
///
/// Examples:
///   sonar-sim --scene room --speed 20
///   sonar-sim --scene my-lab.toml --link /tmp/sonar-tty
///   sonar-sim --dialect hobby        # an "Arduino radar" sketch: `angle,cm.` at once, no commands
///   sonar-sim --speed 100 --faults bitflip=0.02,truncate=0.01,reset=60s --fault-log faults.jsonl
#[derive(Debug, Parser)]
#[command(version, verbatim_doc_comment)]
struct Args {
    /// Built-in scene name or scene file (.toml or .json).
    #[arg(long, default_value = "room")]
    scene: String,
    /// Simulated time per wall time: a factor (1 = real time, 20 = twenty times faster) or `max`
    /// (never sleep; runs as fast as the host reads).
    #[arg(long, default_value = "1", allow_hyphen_values = true)]
    speed: Speed,
    /// Seed of the ranging noise and of the odometry's; the same seed and commands give the same
    /// readings and poses.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Which firmware to run.
    #[arg(long, value_enum, default_value_t = Dialect::Native)]
    dialect: Dialect,
    #[command(flatten)]
    air: sonar_common::sensor::AirTemperatureArg,
    /// Also make a symbolic link to the pseudo-terminal at this path (removed on exit).
    #[arg(long)]
    link: Option<PathBuf>,
    /// The sensor to hear the scene through: srf05, hc-sr04 or nxt (see the simulator's
    /// `profile` module: echo physics, noise, head geometry and timing). Replaces the scene's
    /// [echo] and [noise] and its own `profile` [default: the scene's profile, else the
    /// calibration of docs/results.md without per-ping noise].
    #[arg(long)]
    profile: Option<SensorProfile>,
    /// Simulated duration of one ping, echo wait included, in ms [default: the profile's, else
    /// 50].
    #[arg(long)]
    ping_interval_ms: Option<u32>,
    /// Simulated duration of one stepper step, in ms [default: the profile's, else 10].
    #[arg(long)]
    step_time_ms: Option<u32>,
    /// Protocol version the head speaks (1: XOR checksum, no identity; 2: CRC-16 and identity).
    #[arg(long = "protocol", default_value_t = PROTOCOL_VERSION)]
    protocol: ProtocolVersion,
    /// The head's identity in its HELLO (1–32 of 0-9 A-Z a-z - _) [default: made at random, so
    /// two simulators are two heads; give the same one to a restarted simulator that plays the
    /// same head].
    #[arg(long, value_parser = parse_head_id)]
    head_id: Option<String>,
    /// Damage the lines the head sends, and reset it or keep it silent at given times, to test a
    /// driver. Comma-separated KEY=VALUE, e.g.
    ///   bitflip=0.01,double-flip=0.01,truncate=0.005,garbage=0.01,overlong=0.002,stray=0.01,reset=30s,silence=20s:4s
    /// Rates, a probability per line (0.01 or 1%; at most one fault per line, so they add up to
    /// at most 1):
    ///   garbage      a line of random bytes before the line
    ///   bitflip      one bit of one byte flipped
    ///   double-flip  the same bit flipped in two bytes (protocol 1's XOR cannot see it)
    ///   truncate     the line cut short: it runs into the next one
    ///   overlong     the line padded past 160 bytes
    ///   stray        1–8 random bytes before the line
    /// Events, on the simulated clock from the host's first bytes (nothing is damaged before
    /// them; with --dialect hobby from the start); each may be given more than once:
    ///   reset=T      the head reboots (HELLO, idle, at the MIN limit)
    ///   silence=T:D  the head sends and hears nothing for D (it runs on, as if the cable were cut)
    /// Durations: 500ms, 30s, 2min. HELLO lines are spared unless hello=damage.
    /// Broken limit switches (the head stops on them: ERR,HARDWARE, ST,FAULT, until RESET):
    ///   min-switch=K, max-switch=K   K: dead, stuck, early:DEG (1–90) or bouncing
    #[arg(long, value_name = "SPEC", verbatim_doc_comment)]
    faults: Option<FaultSpec>,
    /// Seed of the faults; the same seed and the same traffic give the same faults.
    #[arg(long, default_value_t = 1, requires = "faults")]
    fault_seed: u64,
    /// Log every line sent (intact or damaged, with the original) and every event of --faults
    /// here, as JSON lines.
    #[arg(long, value_name = "FILE", requires = "faults")]
    fault_log: Option<PathBuf>,
    /// Poses published per second of simulated time (so --speed 20 publishes 20× as many per
    /// second of wall time), when the scene has a robot.
    #[arg(long, default_value_t = 20.0, value_parser = parse_pose_rate)]
    pose_rate: f64,
    /// Odometry: fraction by which distance is misreported (0.03: 3 % long) [default: the scene's
    /// [odometry] scale_error, else 0].
    #[arg(long, allow_hyphen_values = true)]
    odom_scale_error: Option<f64>,
    /// Odometry: heading error per metre driven, degrees, counter-clockwise positive [default:
    /// the scene's, else 0].
    #[arg(long, allow_hyphen_values = true)]
    odom_heading_drift: Option<f64>,
    /// Odometry: σ of white noise on each step's distance, metres [default: the scene's, else 0].
    #[arg(long)]
    odom_noise_m: Option<f64>,
    /// Odometry: σ of white noise on each step's heading change, degrees [default: the scene's,
    /// else 0].
    #[arg(long)]
    odom_noise_deg: Option<f64>,
    #[command(flatten)]
    ipc: IpcArgs,
}

fn parse_pose_rate(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= MAX_POSE_RATE_HZ => Ok(v),
        _ => Err(format!(
            "expected poses per second in (0, {MAX_POSE_RATE_HZ}], got {s:?}"
        )),
    }
}

impl Args {
    /// The scene's odometry errors with the flags given on top.
    fn odometry(&self, scene: OdometryParams) -> Result<OdometryParams> {
        let flags = [
            self.odom_scale_error,
            self.odom_heading_drift,
            self.odom_noise_m,
            self.odom_noise_deg,
        ];
        let params = OdometryParams {
            scale_error: self.odom_scale_error.unwrap_or(scene.scale_error),
            heading_drift_deg_per_m: self
                .odom_heading_drift
                .unwrap_or(scene.heading_drift_deg_per_m),
            noise_m: self.odom_noise_m.unwrap_or(scene.noise_m),
            noise_deg: self.odom_noise_deg.unwrap_or(scene.noise_deg),
        };
        if flags.iter().any(Option::is_some) {
            params
                .validate()
                .map_err(|e| anyhow::anyhow!("--odom-*: {e}"))?;
        }
        Ok(params)
    }
}

/// The robot's poses on iceoryx2: odometry on `robot/pose`, truth on `robot/true_pose`.
struct PosePublisher {
    rover: Rover,
    odometry: Publisher<Ipc, Pose2D, ()>,
    truth: Publisher<Ipc, Pose2D, ()>,
    /// Samples of one advance, kept to reuse the allocation.
    samples: Vec<PoseSample>,
    warn: Throttle,
    published: u64,
    // Declared last: the node outlives its publishers when this is dropped.
    _node: Node<Ipc>,
}

impl PosePublisher {
    fn new(ipc_args: &IpcArgs, rover: Rover) -> Result<Self> {
        let node = ipc_args.node("sonar-sim")?;
        let odometry = ipc::pose_service(&node)?
            .publisher_builder()
            .create()
            .map_err(|e| ipc::IpcError::new("create robot/pose publisher", e))?;
        let truth = ipc::true_pose_service(&node)?
            .publisher_builder()
            .create()
            .map_err(|e| ipc::IpcError::new("create robot/true_pose publisher", e))?;
        Ok(Self {
            rover,
            odometry,
            truth,
            samples: Vec::new(),
            warn: Throttle::new(PUBLISH_WARN_PERIOD),
            published: 0,
            _node: node,
        })
    }

    fn publish(&mut self, sample: PoseSample, stamp_ns: u64) {
        let wire = |p: Pose| Pose2D {
            stamp_ns,
            x_m: p.at.x as f32,
            y_m: p.at.y as f32,
            theta_rad: p.heading_rad as f32,
            layout_version: ipc::LAYOUT_VERSION,
        };
        let sent = self
            .odometry
            .send_copy(wire(sample.odometry))
            .and_then(|_| self.truth.send_copy(wire(sample.truth)));
        match sent {
            Ok(_) => self.published += 1,
            // A consumer holding every sample costs poses, never the head's pace.
            Err(e) => {
                if let Some(suppressed) = self.warn.allow(Instant::now()) {
                    warn!(suppressed, "publishing the robot's pose: {e:?}");
                }
            }
        }
    }
}

impl Carrier for PosePublisher {
    fn advance(&mut self, now_us: u64, unix_ns: &dyn Fn(u64) -> u64) -> std::io::Result<Pose> {
        let mut samples = std::mem::take(&mut self.samples);
        let pose = self.rover.advance(now_us, |s| samples.push(s));
        for s in samples.drain(..) {
            self.publish(s, unix_ns(s.t_us));
        }
        self.samples = samples;
        Ok(pose)
    }

    fn sweep_started(&mut self) {
        self.rover.sweep_started();
    }

    fn sweep_ended(&mut self, now_us: u64) {
        self.rover.sweep_ended(now_us);
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Dialect {
    /// The sonar protocol (checksummed lines, commands, 4 pings per 6° reading).
    Native,
    /// The HowToMechatronics "Arduino radar" sketch: servo 15°–165°, 1° steps, `angle,cm.` records.
    Hobby,
}

fn main() -> ExitCode {
    let args = Args::parse();
    sonar_common::init_tracing();
    sonar_common::report_exit("sonar-sim", run(args))
}

fn run(args: Args) -> Result<()> {
    let mut scene =
        Scene::resolve(&args.scene).with_context(|| format!("loading scene {:?}", args.scene))?;
    if let Some(profile) = args.profile {
        scene.set_profile(profile);
    }
    let sensor = SensorConfig {
        air_temperature_c: args.air.air_temperature_c,
        ..scene
            .profile
            .map_or_else(SensorConfig::default, SensorProfile::sensor)
    };
    sensor.validate().context("--air-temperature-c")?;
    let profile_timing = scene
        .profile
        .map_or_else(Timing::default, SensorProfile::timing);
    let timing = Timing {
        ping_interval_ms: args
            .ping_interval_ms
            .unwrap_or(profile_timing.ping_interval_ms),
        step_time_ms: args.step_time_ms.unwrap_or(profile_timing.step_time_ms),
    };
    if let Some(profile) = scene.profile {
        info!(%profile, ?timing, "sensor profile");
    }
    let scene_name = scene.name.clone();
    let suggested = scene.scan;
    let odometry = args.odometry(scene.odometry)?;
    let rover = match &scene.robot {
        Some(robot) => {
            info!(
                waypoints = robot.waypoints.len(),
                mode = ?robot.mode,
                looped = robot.looped,
                speed_mps = robot.speed_mps,
                pose_rate = args.pose_rate,
                ?odometry,
                "the head rides a robot"
            );
            Some(Rover::new(robot, odometry, args.pose_rate, args.seed))
        }
        None if odometry != OdometryParams::default() => {
            bail!("--odom-* needs a scene with a [robot]: scene {scene_name} has a fixed head")
        }
        None => None,
    };
    let model = EchoModel::new(scene, sensor, args.seed)?;
    let mut device: Box<dyn Device> = match args.dialect {
        Dialect::Native => {
            let head_id = args
                .head_id
                .clone()
                .unwrap_or_else(|| format!("{:016X}", rand::random::<u64>()));
            info!(head_id, protocol = %args.protocol, "head identity");
            let switches = args.faults.as_ref().map(|f| f.switches).unwrap_or_default();
            Box::new(NativeDevice::new(
                Firmware::new(sensor, timing, model)?
                    .speaking(args.protocol, &head_id)
                    .with_switch_faults(switches),
            ))
        }
        Dialect::Hobby => Box::new(HobbySketch::new(model, sensor.echo_timeout_us)),
    };

    let mut faults = match &args.faults {
        Some(spec) => {
            let log = match &args.fault_log {
                Some(path) => {
                    let file = File::create(path)
                        .with_context(|| format!("creating the fault log {}", path.display()))?;
                    Some(Box::new(BufWriter::new(file)) as Box<dyn Write + Send>)
                }
                None => None,
            };
            let mut faults = FaultInjector::new(spec.clone(), args.fault_seed, log);
            if args.dialect == Dialect::Hobby {
                faults.start(0).context("writing the fault log")?;
            }
            Some(faults)
        }
        None => None,
    };

    // Before the PTY line, so that a signal sent as soon as it is read is already handled.
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .context("installing the signal handlers")?;
    }

    // Before the PTY line, so that whoever reads it finds the pose services already there.
    let mut poses = rover
        .map(|rover| PosePublisher::new(&args.ipc, rover))
        .transpose()?;

    let (pty, _link) = open_announced(args.link.as_deref())?;

    info!(
        pty = %pty.path().display(),
        scene = %scene_name,
        suggested_scan = ?suggested,
        dialect = ?args.dialect,
        speed = ?args.speed,
        seed = args.seed,
        "simulator ready"
    );
    let stats = serve(
        &pty,
        device.as_mut(),
        args.speed,
        &stop,
        faults.as_mut(),
        poses.as_mut().map(|p| p as &mut dyn Carrier),
    )
    .context("serving the PTY")?;
    if let Some(p) = &poses {
        info!(poses_published = p.published, "robot stopped");
    }
    let faults = faults.map(|f| format!("; faults: {}", f.counts()));
    info!(
        bytes_received = stats.bytes_received,
        lines_written = stats.lines_written,
        lines_dropped = stats.lines_dropped,
        "stopped: {}{}",
        device.summary(),
        faults.unwrap_or_default()
    );
    Ok(())
}
