//! `sonar-firmware-sim`: the head's compiled firmware in simavr, with the hardware around the chip
//! simulated, on a pseudo-terminal. See the crate docs for what is modelled.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use clap::Parser;
use sonar_common::sensor::SensorConfig;
use sonar_common::speed::Speed;
use sonar_firmware_sim::bench::{self, BenchConfig, BenchError, End, Signals, WITH_SIMAVR};
use sonar_firmware_sim::head::{Head, HeadConfig, HeadKind};
use sonar_firmware_sim::headid::HeadId;
use sonar_firmware_sim::motor::Motor;
use sonar_sim::link::open_announced;
use sonar_sim::{EchoModel, Scene, SwitchFault, SwitchFaults};
use tracing::{info, warn};

/// Firmware in the loop: the sensor head's own ATmega328P firmware (the ELF, unchanged) runs in
/// simavr at 16 MHz; the stepper, the two limit switches and the SRF05 around the chip are
/// simulated from sonar-sim's scenes and echo model; UART0 is a pseudo-terminal that sonar-driver
/// opens as the head's USB serial adapter.
///
/// The first line on standard output is `PTY <path>`: open that path as the serial port. Logs go
/// to standard error (level from RUST_LOG). Ctrl-C or SIGTERM stops it cleanly; SIGUSR1 presses
/// the chip's reset button (the shaft stays where it is).
///
/// Time is the chip's cycle counter: --speed 1 keeps it to wall time, `max` runs as fast as simavr
/// can (a few times real time: Debian's simavr 1.6 emulates this firmware at 2–3× on a busy 2-core
/// machine, more on a quiet fast one).
///
/// Wiring: UART0 (PD0/PD1); SRF05 TRIG PB1, ECHO PB0 (ICP1); limit switches MIN PB2, MAX PB3
/// (closed = low; at −150° and +150°, mechanical stops at ±160°); LED PB5; ULN2003 IN1..IN4 on
/// PD4..PD7, or STEP PD4, DIR PD5, EN PD6 (low = enabled).
///
/// The servo head (--head servo, firmware built with `make -C firmware HEAD=servo`): an SG90 on
/// PB2 (OC1B, 50 Hz): a pulse of 1000–2000 µs turns it to −90…+90° at 0.1 s/60°, within its
/// stops at ±90°; no switches; firmware/build/servo/sonar-head.elf.
///
/// Motors (--motor must match the firmware build, `make -C firmware MOTOR=...`):
///   paper     7.5° motor, 1:5 gear, ULN2003 half steps: 0.75° per half step
///             firmware/build/sonar-head.elf
///   28byj48   28BYJ-48 on a ULN2003, half steps: about 0.088° per half step
///             firmware/build/28byj48-uln2003-g1/sonar-head.elf
///   nema17    1.8° NEMA 17, A4988 at 1/16 microstep (STEP/DIR): 0.1125° per step
///             firmware/build/nema17-stepdir-g1/sonar-head.elf
///
/// Scenes: as sonar-sim (room, corner, obstacle, two-obstacles, or a .toml/.json file).
///
/// Examples:
///   make -C firmware && sonar-firmware-sim --scene room
///   sonar-firmware-sim --speed max --link /tmp/sonar-tty --start-angle 40
///   sonar-firmware-sim --motor 28byj48 --firmware firmware/build/28byj48-uln2003-g1/sonar-head.elf
///   sonar-firmware-sim --switch-bounce --head-id 3F2A9C0417B6E5D1
///   sonar-firmware-sim --switch-fault min=dead --travel-report travel.json
///   make -C firmware HEAD=servo
///   sonar-firmware-sim --head servo --firmware firmware/build/servo/sonar-head.elf
///   kill -USR1 <pid>        # press the reset button
#[derive(Debug, Parser)]
#[command(version, verbatim_doc_comment)]
struct Args {
    /// The firmware ELF (ATmega328P).
    #[arg(long, default_value = "firmware/build/sonar-head.elf")]
    firmware: PathBuf,
    /// Built-in scene name or scene file (.toml or .json).
    #[arg(long, default_value = "room")]
    scene: String,
    /// Seed of the ranging noise and of the switch bounce.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Emulated time per wall time: a factor (1 = real time) or `max` (never sleep).
    #[arg(long, default_value = "1")]
    speed: Speed,
    #[command(flatten)]
    air: sonar_common::sensor::AirTemperatureArg,
    /// What turns the sensor (as the firmware was built for): the stepper between limit switches,
    /// or a hobby servo (no switches).
    #[arg(long, value_enum, default_value_t = HeadKind::Stepper)]
    head: HeadKind,
    /// The motor and its driver (as the firmware was built for; a stepper head).
    #[arg(long, value_enum, default_value_t = Motor::Paper)]
    motor: Motor,
    /// Where the shaft stands at power-on, degrees (a stepper head homes from there; a servo's
    /// lies within ±90°).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    start_angle: f64,
    /// Head id to program into the EEPROM (16 hex digits) [default: blank EEPROM, as a new chip:
    /// the firmware makes its own id at first boot].
    #[arg(long)]
    head_id: Option<HeadId>,
    /// Also make a symbolic link to the pseudo-terminal at this path (removed on exit).
    #[arg(long)]
    link: Option<PathBuf>,
    /// Limit switches bounce (1–3 open/close pairs within 2 ms of each change).
    #[arg(long)]
    switch_bounce: bool,
    /// Break a limit switch: WHICH=KIND, WHICH one of min, max, both; KIND one of
    ///   dead       never closes (broken contact, cut wire)
    ///   stuck      always closed (welded contact, short to ground; both=stuck: both closed)
    ///   early:DEG  closes DEG degrees (1–90) before its place (bent lever, moved switch)
    ///   bouncing   4–10 open/close pairs within 10 ms of every change (the worst a switch may)
    /// May be given twice (min and max).
    #[arg(long, value_name = "WHICH=KIND", value_parser = parse_switch_fault, verbatim_doc_comment)]
    switch_fault: Vec<(Which, SwitchFault)>,
    /// At exit, write how far the shaft turned to this file as JSON: the lowest and highest angles
    /// it reached, and those it was driven to (lost steps against the stops included), degrees.
    #[arg(long, value_name = "FILE")]
    travel_report: Option<PathBuf>,
}

/// Which switch a `--switch-fault` breaks.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Which {
    Min,
    Max,
    Both,
}

fn parse_switch_fault(s: &str) -> Result<(Which, SwitchFault), String> {
    let (which, kind) = s
        .split_once('=')
        .ok_or_else(|| format!("expected WHICH=KIND, e.g. min=dead, got {s:?}"))?;
    let which = match which.trim() {
        "min" => Which::Min,
        "max" => Which::Max,
        "both" => Which::Both,
        other => return Err(format!("{other:?}: expected min, max or both")),
    };
    Ok((which, kind.parse()?))
}

fn switch_faults(given: &[(Which, SwitchFault)]) -> Result<SwitchFaults> {
    let mut faults = SwitchFaults::default();
    for &(which, fault) in given {
        for (slot, hit) in [
            (&mut faults.min, which != Which::Max),
            (&mut faults.max, which != Which::Min),
        ] {
            if hit && slot.replace(fault).is_some() {
                bail!("--switch-fault: a switch is broken twice");
            }
        }
    }
    Ok(faults)
}

fn main() -> ExitCode {
    let args = Args::parse();
    sonar_common::init_tracing();
    sonar_common::report_exit("sonar-firmware-sim", run(args))
}

fn run(args: Args) -> Result<()> {
    if !WITH_SIMAVR {
        bail!(BenchError::NoSimavr);
    }
    if !args.firmware.is_file() {
        bail!(
            "no firmware at {}: build it with make -C firmware",
            args.firmware.display()
        );
    }
    let scene =
        Scene::resolve(&args.scene).with_context(|| format!("loading scene {:?}", args.scene))?;
    let sensor = SensorConfig {
        air_temperature_c: args.air.air_temperature_c,
        ..SensorConfig::default()
    };
    sensor.validate().context("--air-temperature-c")?;
    let scene_name = scene.name.clone();
    let faults = switch_faults(&args.switch_fault)?;
    if args.head == HeadKind::Servo && (faults != SwitchFaults::default() || args.switch_bounce) {
        bail!("--switch-fault and --switch-bounce: a servo head has no limit switches");
    }
    if faults != SwitchFaults::default() {
        warn!(?faults, "limit switches broken on purpose (--switch-fault)");
    }
    let model = EchoModel::new(scene, sensor, args.seed)?;
    let head_cfg = HeadConfig {
        kind: args.head,
        motor: args.motor,
        start_deg: args.start_angle,
        bounce_seed: (args.switch_bounce || faults.bouncing()).then_some(args.seed),
        switch_faults: faults,
        echo_timeout_us: sensor.echo_timeout_us,
    };
    let mut head = Head::new(&head_cfg, model).context("--start-angle")?;
    let bench_cfg = BenchConfig {
        firmware: args.firmware.clone(),
        head_id: args.head_id,
        speed: args.speed,
    };

    // Before the PTY line, so that a signal sent as soon as it is read is already handled.
    let signals = Signals::default();
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&signals.stop))
            .context("installing the signal handlers")?;
    }
    signal_hook::flag::register(signal_hook::consts::SIGUSR1, Arc::clone(&signals.reset))
        .context("installing the SIGUSR1 handler")?;

    let (pty, _link) = open_announced(args.link.as_deref())?;

    info!(
        pty = %pty.path().display(),
        firmware = %args.firmware.display(),
        scene = %scene_name,
        head = ?args.head,
        motor = ?args.motor,
        start_angle = args.start_angle,
        head_id = %args.head_id.map_or("blank EEPROM".to_owned(), |id| id.to_string()),
        speed = %args.speed,
        seed = args.seed,
        "firmware simulator ready"
    );
    let summary = bench::run(&bench_cfg, &mut head, &pty, &signals)
        .with_context(|| format!("running {}", args.firmware.display()))?;
    let s = &summary;
    info!(
        emulated_s = format_args!("{:.3}", s.emulated.as_secs_f64()),
        wall_s = format_args!("{:.3}", s.wall.as_secs_f64()),
        real_time_factor = format_args!("{:.2}", s.real_time_factor()),
        pings = s.head.sonar.pings,
        echoes = s.head.sonar.echoes,
        ignored_triggers = s.head.sonar.short_triggers + s.head.sonar.busy_triggers,
        steps = s.head.steps,
        lost_steps = s.head.lost_steps,
        servo_pulses = s.head.servo.pulses,
        bad_servo_pulses = s.head.servo.bad_pulses,
        faults = s.head.faults,
        switch_changes = s.head.switch_changes,
        resets = s.resets,
        bytes_from_host = s.line.from_host,
        bytes_to_host = s.line.to_host,
        bytes_dropped = s.line.dropped,
        head_id = %s.head_id.map_or("none".to_owned(), |id| id.to_string()),
        angle = head.angle_deg(),
        lowest_angle = s.head.travel.lowest_deg,
        highest_angle = s.head.travel.highest_deg,
        "stopped"
    );
    if let Some(path) = &args.travel_report {
        let t = s.head.travel;
        let report = serde_json::json!({
            "lowest_deg": t.lowest_deg,
            "highest_deg": t.highest_deg,
            "wound_lowest_deg": t.wound_lowest_deg,
            "wound_highest_deg": t.wound_highest_deg,
            "steps": s.head.steps,
            "lost_steps": s.head.lost_steps,
        });
        std::fs::write(path, format!("{report}\n"))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    match &s.end {
        End::Stopped => Ok(()),
        End::Died { state, pc } => bail!(
            "the firmware stopped running ({state}) at pc {pc:#06x} after {:.3} s",
            s.emulated.as_secs_f64()
        ),
    }
}
