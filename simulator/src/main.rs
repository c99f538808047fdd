//! `sonar-sim`: the simulated sonar head on a pseudo-terminal. See the crate docs for the device's
//! behaviour and the echo model.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use anyhow::{Context, Result};
use clap::{Parser, ValueEnum};
use sonar_common::protocol::{
    MAX_HEAD_ID_LEN, PROTOCOL_VERSION, ProtocolVersion, is_valid_head_id,
};
use sonar_common::sensor::SensorConfig;
use sonar_sim::{
    Device, EchoModel, Firmware, HobbySketch, NativeDevice, Pty, Scene, Speed, Symlink, Timing,
    serve,
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
}

fn parse_head_id(s: &str) -> Result<String, String> {
    if is_valid_head_id(s) {
        Ok(s.to_owned())
    } else {
        Err(format!(
            "a head id is 1–{MAX_HEAD_ID_LEN} characters of 0-9 A-Z a-z - _, got {s:?}"
        ))
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

    // Before the PTY line, so that a signal sent as soon as it is read is already handled.
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .context("installing the signal handlers")?;
    }

    let pty = Pty::open().context("opening a pseudo-terminal")?;
    // The link exists before anyone learns the path from standard output.
    let _link = args
        .link
        .as_deref()
        .map(|link| Symlink::create(link, pty.path()))
        .transpose()?;
    let mut stdout = std::io::stdout().lock();
    writeln!(stdout, "PTY {}", pty.path().display())
        .and_then(|()| stdout.flush())
        .context("writing the PTY line to standard output")?;
    drop(stdout);

    info!(
        pty = %pty.path().display(),
        scene = %scene_name,
        suggested_scan = ?suggested,
        dialect = ?args.dialect,
        speed = ?args.speed,
        seed = args.seed,
        "simulator ready"
    );
    let stats = serve(&pty, device.as_mut(), args.speed, &stop).context("serving the PTY")?;
    info!(
        bytes_received = stats.bytes_received,
        lines_written = stats.lines_written,
        lines_dropped = stats.lines_dropped,
        "stopped: {}",
        device.summary()
    );
    Ok(())
}
