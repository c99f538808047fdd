//! `sonar-sim`: the simulated sonar head on a pseudo-terminal. See the crate docs for the device's
//! behaviour and the echo model.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use anyhow::{Context, Result};
use clap::{Parser, ValueEnum};
use sonar_common::protocol::{PROTOCOL_VERSION, ProtocolVersion, parse_head_id};
use sonar_common::sensor::SensorConfig;
use sonar_sim::link::open_announced;
use sonar_sim::{
    Device, EchoModel, FaultInjector, FaultSpec, Firmware, HobbySketch, NativeDevice, Scene, Speed,
    Timing, serve,
};
use tracing::info;

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
/// or a .toml/.json file in the format of simulator/scenes/*.toml.
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
    #[arg(long, default_value = "1")]
    speed: Speed,
    /// Seed of the ranging noise; the same seed and commands give the same readings.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Which firmware to run.
    #[arg(long, value_enum, default_value_t = Dialect::Native)]
    dialect: Dialect,
    /// Air temperature in °C, which sets the speed of sound (331.3 + 0.606·T m/s).
    #[arg(long, default_value_t = 20.0, allow_hyphen_values = true)]
    air_temperature: f32,
    /// Also make a symbolic link to the pseudo-terminal at this path (removed on exit).
    #[arg(long)]
    link: Option<PathBuf>,
    /// Simulated duration of one ping, echo wait included, in ms.
    #[arg(long, default_value_t = Timing::default().ping_interval_ms)]
    ping_interval_ms: u32,
    /// Simulated duration of one 1.5° stepper step, in ms.
    #[arg(long, default_value_t = Timing::default().step_time_ms)]
    step_time_ms: u32,
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
    #[arg(long, value_name = "SPEC", verbatim_doc_comment)]
    faults: Option<FaultSpec>,
    /// Seed of the faults; the same seed and the same traffic give the same faults.
    #[arg(long, default_value_t = 1, requires = "faults")]
    fault_seed: u64,
    /// Log every line sent (intact or damaged, with the original) and every event of --faults
    /// here, as JSON lines.
    #[arg(long, value_name = "FILE", requires = "faults")]
    fault_log: Option<PathBuf>,
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
    let scene =
        Scene::resolve(&args.scene).with_context(|| format!("loading scene {:?}", args.scene))?;
    let sensor = SensorConfig {
        air_temperature_c: args.air_temperature,
        ..SensorConfig::default()
    };
    sensor.validate().context("--air-temperature")?;
    let timing = Timing {
        ping_interval_ms: args.ping_interval_ms,
        step_time_ms: args.step_time_ms,
    };
    let scene_name = scene.name.clone();
    let suggested = scene.scan;
    let model = EchoModel::new(scene, sensor, args.seed)?;
    let mut device: Box<dyn Device> = match args.dialect {
        Dialect::Native => {
            let head_id = args
                .head_id
                .clone()
                .unwrap_or_else(|| format!("{:016X}", rand::random::<u64>()));
            info!(head_id, protocol = %args.protocol, "head identity");
            Box::new(NativeDevice::new(
                Firmware::new(sensor, timing, model)?.speaking(args.protocol, &head_id),
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
    let stats = serve(&pty, device.as_mut(), args.speed, &stop, faults.as_mut())
        .context("serving the PTY")?;
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
