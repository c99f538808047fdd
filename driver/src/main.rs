//! `sonar-driver`: owns the serial port of the sonar head and publishes its readings over iceoryx2.
//!
//! Single-threaded by design: the loop reads the port with a short timeout, so one thread can also
//! poll the command service and notice Ctrl-C/SIGTERM (through the iceoryx2 node's signal handler)
//! without locks or channels. At 5 readings/s (real hardware) or tens of thousands (simulator at
//! `--speed max`) that loop is never the bottleneck.

use std::io::{ErrorKind, Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Parser;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::waitset::WaitSetRunResult;
use serialport::{DataBits, Parity, SerialPort, StopBits, TTYPort};
use sonar_common::ipc::{
    self, DriverStatus, IpcArgs, LinkState, Reading, ScanCommand, ScanCommandKind, ScanMode,
    SweepEnd,
};
use sonar_common::logging::Misconfigured;
use sonar_common::protocol::{
    DeviceMessage, DeviceState, ErrorCode, FramedLine, HostCommand, LineFramer, PROTOCOL_VERSION,
    ProtocolVersion, WireScanMode, encode_command, parse_head_id,
};
use sonar_common::sensor::SensorConfig;
use sonar_common::throttle::Throttle;
use sonar_driver::averaging::PingPolicy;
use sonar_driver::clock::DeviceClock;
use sonar_driver::decoder::{Decoded, Decoder, Dialect, NoEcho};
use sonar_driver::sweeps::SweepIds;
use tracing::{debug, info, warn};

/// How long one read of the port may block during the handshake: bounds the latency of shutdown
/// there. Once connected, the driver sleeps on the port, the commands' wake-up event and its next
/// deadline together, and reads only when the port has something (without the wake-up event, it
/// looks for commands this often).
const READ_TIMEOUT: Duration = Duration::from_millis(50);
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(2);
const HANDSHAKE_ATTEMPTS: u32 = 3;
/// After the `HELLO` reply, lines are read this long before the scan is commanded, so that a head
/// that announced itself at power-on just as we asked (two `HELLO`s) is not taken for reset twice.
const HANDSHAKE_SETTLE: Duration = Duration::from_millis(200);
const STATUS_PERIOD: Duration = Duration::from_secs(1);
const MIN_BACKOFF: Duration = Duration::from_millis(250);
/// Rejected lines are logged at most this often (each is counted in the status).
const REJECT_LOG_PERIOD: Duration = Duration::from_secs(1);

/// Reads a sonar head (or its simulator) over a serial port and publishes each averaged 6° reading
/// on the iceoryx2 service `sonar/readings`; takes scan commands on `sonar/commands`.
///
/// The head is identified by its HELLO (protocol version 2): the driver serves the first head it
/// meets (or the one --head-id names) and refuses a different one that later answers on the same
/// path. A head that announces itself while connected was reset: the scan is sent again.
///
/// Examples:
///   sonar-driver --port /dev/serial/by-id/usb-Arduino_Uno_85736323-if00   # stable across replugs
///   sonar-driver --port /dev/pts/5                          # the `PTY <path>` that sonar-sim prints
///   sonar-driver --port /dev/ttyACM0 --print               # check a freshly flashed head
///   sonar-driver --port /dev/ttyUSB0 --protocol 1          # a head with version-1 firmware
///   sonar-driver --port /dev/ttyACM0 --dialect hobby       # an "Arduino radar" sketch at 9600 baud
///   sonar-driver --port /dev/ttyUSB0 --dialect hobby --no-echo 255   # its sketch sends 255 for no echo
#[derive(Debug, Parser)]
#[command(version, verbatim_doc_comment)]
struct Args {
    /// Serial device: a USB adapter (/dev/ttyUSB0) or the simulator's pseudo-terminal.
    #[arg(long, env = "SONAR_PORT")]
    port: PathBuf,
    /// Baud rate [default: 115200 for native, 9600 for hobby].
    #[arg(long)]
    baud: Option<u32>,
    /// Parity bit of each character on the line (the head's firmware and the simulator: none).
    #[arg(long, value_enum, default_value_t = ParityArg::None)]
    parity: ParityArg,
    /// Data bits per character, 5 to 8 (8 for the head: the protocol is ASCII over 8N1).
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u8).range(5..=8))]
    data_bits: u8,
    /// Stop bits per character, 1 or 2.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    stop_bits: u8,
    /// Serial format the device speaks.
    #[arg(long, value_enum, default_value_t = Dialect::Native)]
    dialect: Dialect,
    /// Version of the native protocol: 2 (CRC-16 per line, head identity) or 1 (XOR checksum, no
    /// identity: older firmware).
    #[arg(long = "protocol", default_value_t = PROTOCOL_VERSION)]
    protocol: ProtocolVersion,
    /// Serve only the head with this identity (as its HELLO reports it) [default: the first head
    /// that answers].
    #[arg(long, value_parser = parse_head_id, conflicts_with = "any_head")]
    head_id: Option<String>,
    /// Accept whichever head answers, also a different one after a reconnect.
    #[arg(long)]
    any_head: bool,
    /// Scan to start after the handshake: `full`, `none`, or a local segment `FROM..TO` in degrees
    /// (e.g. `-30..30`). Restarted after a reconnect.
    #[arg(long, default_value = "full", value_parser = parse_scan, allow_hyphen_values = true)]
    scan: ScanRequest,
    #[command(flatten)]
    air: sonar_common::sensor::AirTemperatureArg,
    /// Beam half-angle stamped on readings, degrees (the paper's ±30°). Named as the file's
    /// `[sensor]` key; `--beam-half-angle` still works.
    #[arg(
        long,
        value_name = "DEGREES",
        alias = "beam-half-angle",
        default_value_t = 30.0
    )]
    beam_half_angle_deg: f32,
    /// Hobby dialect: added to the sketch's servo angle so that 0° is the sensor's forward axis.
    #[arg(long, default_value_t = -90.0, allow_hyphen_values = true)]
    hobby_angle_offset: f32,
    /// Hobby dialect: the distance the sketch sends when nothing echoed, published as NO_ECHO
    /// (never as an obstacle): `0` (NewPing), a value in cm such as `255`, or a value and beyond
    /// such as `400+`. 0 cm always means no echo.
    #[arg(long, default_value = "0", value_name = "CM")]
    no_echo: NoEcho,
    /// Play of the head's gears, degrees (a 28BYJ-48's gearbox: 1–3°): the head reports its
    /// angle ahead of the shaft by the play in the direction it turns, so each reading is moved
    /// back by it. Measure it as half the angle between where an edge (a door jamb) shows in a
    /// counter-clockwise and in a clockwise sweep (`--print`; firmware/README.md).
    #[arg(long, default_value_t = 0.0, value_name = "DEG", value_parser = parse_backlash)]
    backlash_deg: f32,
    /// Also print each reading on standard output, one line each.
    #[arg(long)]
    print: bool,
    /// Longest wait between reconnection attempts, seconds.
    #[arg(long, default_value_t = 5.0)]
    max_backoff: f64,
    /// Seconds without a line from the head before the driver asks it for STATUS; as long again
    /// without an answer and the head counts as hung or gone: the port is opened again and the
    /// handshake repeated, then the scan resumed. A head that answers but is idle while it
    /// should scan is sent its scan again.
    #[arg(long, default_value_t = 3.0, value_parser = parse_seconds)]
    silence_timeout: f64,
    #[command(flatten)]
    ipc: IpcArgs,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ParityArg {
    None,
    Odd,
    Even,
}

/// The scan the driver keeps the head doing.
#[derive(Debug, Clone, Copy, PartialEq)]
enum ScanRequest {
    None,
    Full,
    Local { from_deg: f32, to_deg: f32 },
}

fn parse_scan(s: &str) -> Result<ScanRequest, String> {
    match s {
        "none" => Ok(ScanRequest::None),
        "full" => Ok(ScanRequest::Full),
        _ => {
            let (a, b) = s
                .split_once("..")
                .ok_or_else(|| format!("expected full, none or FROM..TO degrees, got {s:?}"))?;
            let from_deg: f32 = a.trim().parse().map_err(|_| format!("bad angle {a:?}"))?;
            let to_deg: f32 = b.trim().parse().map_err(|_| format!("bad angle {b:?}"))?;
            local_segment(from_deg, to_deg)
        }
    }
}

fn parse_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 3600.0 => Ok(v),
        _ => Err(format!("expected seconds between 0 and 3600, got {s:?}")),
    }
}

fn local_segment(from_deg: f32, to_deg: f32) -> Result<ScanRequest, String> {
    if !(from_deg.is_finite() && to_deg.is_finite() && from_deg < to_deg) {
        return Err(format!(
            "local scan needs FROM < TO, got {from_deg}..{to_deg}"
        ));
    }
    if from_deg < -360.0 || to_deg > 360.0 {
        return Err("local scan angles must lie within ±360°".into());
    }
    Ok(ScanRequest::Local { from_deg, to_deg })
}

impl ScanRequest {
    fn host_command(self) -> Option<HostCommand> {
        match self {
            ScanRequest::None => None,
            ScanRequest::Full => Some(HostCommand::FullScan),
            ScanRequest::Local { from_deg, to_deg } => Some(HostCommand::LocalScan {
                from_cdeg: (from_deg * 100.0).round() as i32,
                to_cdeg: (to_deg * 100.0).round() as i32,
            }),
        }
    }

    /// Why this scan cannot run on a head whose `HELLO` reports its limit switches; `None` when
    /// it can, or when the head reports no limits (version 1).
    fn outside_limits(self, hello: &DeviceMessage) -> Option<String> {
        let (
            Some(HostCommand::LocalScan { from_cdeg, to_cdeg }),
            DeviceMessage::Hello {
                min_cdeg, max_cdeg, ..
            },
        ) = (self.host_command(), hello)
        else {
            return None;
        };
        let limits_known = min_cdeg < max_cdeg;
        (limits_known && (from_cdeg < *min_cdeg || to_cdeg > *max_cdeg)).then(|| {
            format!(
                "the local scan {}..{}° lies outside this head's limit switches, {}..{}°: \
                 give --scan=FROM..TO within them (or --scan=full)",
                from_cdeg as f32 / 100.0,
                to_cdeg as f32 / 100.0,
                *min_cdeg as f32 / 100.0,
                *max_cdeg as f32 / 100.0
            )
        })
    }
}

/// A gear play of 0 to 10 degrees.
fn parse_backlash(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if (0.0..=10.0).contains(&v) => Ok(v),
        _ => Err(format!("{s:?} is not a play of 0 to 10 degrees")),
    }
}

fn main() -> std::process::ExitCode {
    sonar_common::init_tracing();
    sonar_common::report_exit("sonar-driver", run(Args::parse()))
}

/// Why a session on an open port ended.
enum SessionEnd {
    Shutdown,
    PortLost(anyhow::Error),
    /// A different head answered; it is left alone and the port tried again later.
    WrongHead(String),
}

fn run(args: Args) -> Result<()> {
    let sensor = SensorConfig {
        air_temperature_c: args.air.air_temperature_c,
        beam_half_angle_deg: args.beam_half_angle_deg,
        ..SensorConfig::default()
    };
    sensor.validate().context("invalid sensor settings")?;
    // A port that is missing or busy at start is a mistake to report, not to wait out. It is
    // opened first so that a second driver on a busy port says so, rather than failing on the
    // readings service that the first driver already publishes.
    let mut port = open_port(&args)?;
    sonar_common::ipc::catch_termination_requests();
    let node = args.ipc.node("sonar-driver")?;
    let mut link = Link::new(&node, &args, sensor)?;
    let mut backoff = MIN_BACKOFF;
    loop {
        match link.session(&mut port.tty, &node)? {
            SessionEnd::Shutdown => break,
            end @ (SessionEnd::PortLost(_) | SessionEnd::WrongHead(_)) => {
                if let SessionEnd::WrongHead(why) = end {
                    tracing::error!("refusing the head on {}: {why}", args.port.display());
                    link.set_state(LinkState::Refused)?;
                    // The right head may come back on this path; until then wait as after a loss.
                    backoff = Duration::from_secs_f64(args.max_backoff);
                } else if let SessionEnd::PortLost(e) = end {
                    warn!("lost {}: {e:#}", args.port.display());
                    link.set_state(LinkState::Disconnected)?;
                }
                drop(port);
                port = loop {
                    if node.wait(backoff).is_err() {
                        info!("shutting down while disconnected");
                        return Ok(());
                    }
                    match open_port(&args) {
                        Ok(p) => break p,
                        Err(e) => {
                            warn!("reconnect in {backoff:?}: {e:#}");
                            backoff = (backoff * 2).min(Duration::from_secs_f64(args.max_backoff));
                        }
                    }
                };
                link.status.reconnects += 1;
                backoff = MIN_BACKOFF;
            }
        }
    }
    if link.identified && args.dialect == Dialect::Native {
        // Leave the motor idle when nobody is listening any more; a device that never said it
        // is our head is not told anything.
        let _ = port
            .tty
            .write_all(encode_command(&HostCommand::Stop, args.protocol).as_bytes());
    }
    link.set_state(LinkState::Disconnected)?;
    info!(
        readings = link.status.readings_published,
        rejected = link.status.lines_rejected,
        unidentified_readings = link.unidentified_readings,
        discarded_bytes = link.discarded_bytes,
        "driver stopped"
    );
    Ok(())
}

/// What is wrong with a path that is no serial port.
const NOT_A_PORT: &str = "is not a serial port (not a terminal device): give the adapter's \
                          device, e.g. /dev/ttyUSB0, /dev/ttyACM0 or its /dev/serial/by-id/… name";

/// The terminal settings a port had before the driver opened it, put back when dropped: the
/// driver leaves a device it gives up on (or stops serving) as it found it.
struct SavedTerminal {
    file: std::fs::File,
    settings: nix::sys::termios::Termios,
}

impl SavedTerminal {
    /// Reads the settings of `path` through a descriptor of its own, opened without making it
    /// the controlling terminal and without waiting for a carrier.
    fn take(path: &str) -> Option<Self> {
        use std::os::unix::fs::OpenOptionsExt;
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(nix::libc::O_NOCTTY | nix::libc::O_NONBLOCK)
            .open(path)
            .ok()?;
        let settings = nix::sys::termios::tcgetattr(&file).ok()?;
        Some(Self { file, settings })
    }
}

impl Drop for SavedTerminal {
    fn drop(&mut self) {
        if let Err(e) = nix::sys::termios::tcsetattr(
            &self.file,
            nix::sys::termios::SetArg::TCSANOW,
            &self.settings,
        ) {
            debug!("terminal settings not restored: {e}");
        }
    }
}

/// The serial port, and what to restore when it is closed.
struct OpenPort {
    tty: TTYPort,
    _saved: Option<SavedTerminal>,
}

fn open_port(args: &Args) -> Result<OpenPort> {
    let path = args.port.to_string_lossy().into_owned();
    if !Path::new(&path).exists() {
        bail!(
            "serial port {path} does not exist (is the device plugged in, or the simulator running?)"
        );
    }
    // Not opened to find out: opening a USB adapter resets the microcontroller behind it.
    let is_device = std::fs::metadata(&path)
        .map(|m| std::os::unix::fs::FileTypeExt::is_char_device(&m.file_type()))
        .unwrap_or(true); // unreadable: the open below says why
    if !is_device {
        bail!("{path} {NOT_A_PORT}");
    }
    let baud = args.baud.unwrap_or(match args.dialect {
        Dialect::Native => 115_200,
        Dialect::Hobby => 9_600,
    });
    let saved = SavedTerminal::take(&path);
    let port = serialport::new(&path, baud)
        .data_bits(match args.data_bits {
            5 => DataBits::Five,
            6 => DataBits::Six,
            7 => DataBits::Seven,
            _ => DataBits::Eight,
        })
        .parity(match args.parity {
            ParityArg::None => Parity::None,
            ParityArg::Odd => Parity::Odd,
            ParityArg::Even => Parity::Even,
        })
        .stop_bits(if args.stop_bits == 2 {
            StopBits::Two
        } else {
            StopBits::One
        })
        .timeout(READ_TIMEOUT)
        .open_native()
        .map_err(|e| {
            // A character device that is no terminal (/dev/null): ENOTTY, whose text is the
            // only trace serialport keeps of it.
            if e.description.contains("typewriter") || e.description.contains("ioctl") {
                return anyhow::anyhow!("{path} {NOT_A_PORT}");
            }
            let hint = match e.kind() {
                serialport::ErrorKind::NoDevice => " (busy: another program has it open?)",
                serialport::ErrorKind::Io(ErrorKind::PermissionDenied) => {
                    " (permission denied: add yourself to the dialout group)"
                }
                _ => "",
            };
            anyhow::anyhow!("cannot open serial port {path}: {e}{hint}")
        })?;
    info!(port = %path, baud, dialect = ?args.dialect, "serial port open");
    Ok(OpenPort {
        tty: port,
        _saved: saved,
    })
}

/// The driver's side of the pipeline: decoder, iceoryx2 ports and counters.
struct Link {
    decoder: Decoder,
    dialect: Dialect,
    print: bool,
    scan: ScanRequest,
    publisher: Publisher<Ipc, Reading, ()>,
    /// The sweeps the head reports ended (`sonar/sweep_ends`).
    sweep_ends: Publisher<Ipc, SweepEnd, ()>,
    /// The latest reading published: its `seq` and `sweep_id`, what a sweep's end names.
    last_published: Option<(u64, u32)>,
    notifier: Notifier<Ipc>,
    commands: Subscriber<Ipc, ScanCommand, ()>,
    status_publisher: Publisher<Ipc, DriverStatus, ()>,
    status: DriverStatus,
    /// The latest `HELLO` not yet acted on: the handshake's reply, or a reset head's announcement.
    hello: Option<DeviceMessage>,
    version_rejected: bool,
    version: ProtocolVersion,
    /// The head this driver serves; `None` until the first handshake (or with `--any-head`).
    head_id: Option<String>,
    any_head: bool,
    silence_timeout: Duration,
    /// When the last line that parsed came in.
    last_line: Instant,
    /// When a `STATUS` was sent because the head was quiet, until any line answers.
    probe_sent: Option<Instant>,
    /// The state in the latest `ST` line, until acted on.
    head_state: Option<DeviceState>,
    reject_log: Throttle,
    device_error_log: Throttle,
    /// The latest `ERR,HARDWARE` text: what the head stopped on, when it reports `ST,FAULT`.
    last_hardware_error: String,
    /// The head stopped on a hardware fault (`ST,FAULT`): no scan is sent to it until a person
    /// acknowledges with the `reset` command, also after the head was reset or reconnected.
    head_fault: bool,
    /// An `ERR,HARDWARE` came: ask the head at once whether it stopped (`ST,FAULT`).
    status_wanted: bool,
    /// Sweep ids as published, continued across resets of the head.
    sweeps: SweepIds,
    /// Stamps a native head's readings at their instant, from its clock (restarted with it).
    clock: DeviceClock,
    /// The device on the port answered the handshake as the head served: until then its
    /// readings are not published (they may be another head's) and nothing but `HELLO` is sent.
    identified: bool,
    /// Readings dropped because the device had not identified itself yet.
    unidentified_readings: u64,
    /// Bytes the port held when a session began, dropped unread.
    discarded_bytes: u64,
}

impl Link {
    fn new(node: &Node<Ipc>, args: &Args, sensor: SensorConfig) -> Result<Self> {
        let readings = ipc::readings_service(node)?;
        let publisher = readings
            .publisher_builder()
            .create()
            .map_err(|e| ipc::IpcError::new("create readings publisher", e))?;
        let sweep_ends = ipc::sweep_ends_service(node)?
            .publisher_builder()
            .create()
            .map_err(|e| ipc::IpcError::new("create sweep ends publisher", e))?;
        let notifier = ipc::wakeup_notifier(node, ipc::READINGS_SERVICE)?;
        let commands = ipc::commands_service(node)?
            .subscriber_builder()
            .create()
            .map_err(|e| ipc::IpcError::new("create command subscriber", e))?;
        let status_publisher = ipc::driver_status_service(node)?
            .publisher_builder()
            .create()
            .map_err(|e| ipc::IpcError::new("create status publisher", e))?;
        Ok(Self {
            decoder: Decoder::new(
                args.dialect,
                sensor,
                PingPolicy::default(),
                args.hobby_angle_offset,
            )
            .hobby_no_echo(args.no_echo)
            .backlash_deg(args.backlash_deg)
            .speaking(args.protocol),
            dialect: args.dialect,
            print: args.print,
            scan: args.scan,
            publisher,
            sweep_ends,
            last_published: None,
            notifier,
            commands,
            status_publisher,
            status: DriverStatus {
                layout_version: ipc::LAYOUT_VERSION,
                ..Default::default()
            },
            hello: None,
            version_rejected: false,
            version: args.protocol,
            head_id: args.head_id.clone(),
            any_head: args.any_head,
            silence_timeout: Duration::from_secs_f64(args.silence_timeout),
            last_line: Instant::now(),
            probe_sent: None,
            head_state: None,
            reject_log: Throttle::new(REJECT_LOG_PERIOD),
            device_error_log: Throttle::new(REJECT_LOG_PERIOD),
            last_hardware_error: String::new(),
            head_fault: false,
            status_wanted: false,
            sweeps: SweepIds::default(),
            clock: DeviceClock::default(),
            // The hobby dialect has no identity to wait for.
            identified: args.dialect != Dialect::Native,
            unidentified_readings: 0,
            discarded_bytes: 0,
        })
    }

    /// When the silence watchdog must look again (native heads only): a quiet head is asked for
    /// `STATUS` after the silence timeout, and given as long again to answer.
    fn silence_deadline(&self) -> Option<Instant> {
        (self.dialect == Dialect::Native)
            .then(|| self.probe_sent.unwrap_or(self.last_line) + self.silence_timeout)
    }

    /// The silence watchdog, once per loop while connected: a quiet head is asked for `STATUS`;
    /// `Err` when it did not answer that either.
    fn watch_silence(&mut self, port: &mut TTYPort) -> Result<Result<(), String>> {
        let now = Instant::now();
        match self.probe_sent {
            None if now.duration_since(self.last_line) >= self.silence_timeout => {
                debug!("the head is quiet: asking for its status");
                send(port, &HostCommand::Status, self.version)?;
                self.probe_sent = Some(now);
            }
            Some(sent) if now.duration_since(sent) >= self.silence_timeout => {
                self.status.silences += 1;
                return Ok(Err(format!(
                    "the head fell silent: no line for {:.1} s and no answer to STATUS \
                     (silences so far: {})",
                    now.duration_since(self.last_line).as_secs_f64(),
                    self.status.silences
                )));
            }
            _ => {}
        }
        Ok(Ok(()))
    }

    /// Takes a `HELLO`: the first head met becomes the one served; a different one is refused.
    fn accept_head(&mut self, hello: &DeviceMessage) -> Result<(), String> {
        let DeviceMessage::Hello {
            head_id, firmware, ..
        } = hello
        else {
            return Ok(());
        };
        if self.version < ProtocolVersion::V2 || self.any_head {
            return Ok(());
        }
        match &self.head_id {
            Some(served) if served != head_id => Err(format!(
                "it is head {head_id} ({firmware}), this driver serves head {served} \
                 (--head-id names the head to serve, --any-head accepts any)"
            )),
            Some(_) => {
                ipc::set_padded_text(&mut self.status.head_id, head_id);
                Ok(())
            }
            None => {
                info!(head_id, firmware, "serving this head from now on");
                self.head_id = Some(head_id.clone());
                ipc::set_padded_text(&mut self.status.head_id, head_id);
                Ok(())
            }
        }
    }

    /// Sends the scan the head should be doing, if any, unless the head stopped on a fault.
    fn command_scan(&mut self, port: &mut TTYPort) -> Result<()> {
        match self.scan.host_command() {
            Some(_) if self.head_fault => {
                debug!("not sending the scan: the head stopped on a hardware fault");
                Ok(())
            }
            Some(cmd) => send(port, &cmd, self.version),
            None => Ok(()),
        }
    }

    /// The head reported `ST,FAULT`: it stopped on a hardware fault and moves only after `RESET`.
    /// Said once, with what to check; no scan is sent until a person acknowledges.
    fn head_stopped_on_fault(&mut self) -> Result<()> {
        if self.head_fault {
            return Ok(());
        }
        self.head_fault = true;
        self.status.head_fault = 1;
        self.status.hardware_faults += 1;
        let what = if self.last_hardware_error.is_empty() {
            "(no ERR,HARDWARE line seen)"
        } else {
            &self.last_hardware_error
        };
        tracing::error!(
            "the head stopped on a hardware fault: {what}. Check its limit switches (both levers \
             move freely and open and close when pressed), their wiring and connector, and that the \
             head turns freely without slipping; then acknowledge with a reset (the viewer's R, or \
             `sonar reset-head`), which homes the head again. No scan is sent to it until then."
        );
        self.publish_status()
    }

    /// A person acknowledged the fault: `RESET` (the head homes again), then the scan.
    fn acknowledge_fault(&mut self, port: &mut TTYPort) -> Result<()> {
        info!(
            was_stopped = self.head_fault,
            "reset acknowledged: the head homes again"
        );
        send(port, &HostCommand::Reset, self.version)?;
        self.head_fault = false;
        self.status.head_fault = 0;
        self.publish_status()?;
        self.command_scan(port)
    }

    fn set_state(&mut self, state: LinkState) -> Result<()> {
        self.status.link_state = state as u32;
        self.publish_status()
    }

    fn publish_status(&mut self) -> Result<()> {
        self.status.stamp_ns = ipc::unix_time_ns();
        self.status.readings_published = self.decoder.readings_decoded();
        let sample = self
            .status_publisher
            .loan_uninit()
            .map_err(|e| ipc::IpcError::new("loan status sample", e))?;
        sample
            .write_payload(self.status)
            .send()
            .map_err(|e| ipc::IpcError::new("send status", e))?;
        Ok(())
    }

    /// Runs one connection: handshake, scan request, then lines until the port fails or we stop.
    fn session(&mut self, port: &mut TTYPort, node: &Node<Ipc>) -> Result<SessionEnd> {
        self.set_state(LinkState::Connecting)?;
        // Whoever is on the port now has to identify itself again, with its own clock.
        self.identified = self.dialect != Dialect::Native;
        self.clock.restart();
        // Bytes queued before we opened belong to nobody (or a previous driver, or a session that
        // failed): dropped, but counted and said.
        let queued = port.bytes_to_read().unwrap_or(0);
        let _ = port.clear(serialport::ClearBuffer::All);
        if queued > 0 {
            self.discarded_bytes += u64::from(queued);
            info!(
                bytes = queued,
                "dropped what the port held before the handshake (lines of an earlier session)"
            );
        }
        let mut framer = LineFramer::new(self.dialect.terminators());
        let mut buf = [0u8; 4096];

        if self.dialect == Dialect::Native {
            self.hello = None;
            let mut attempt = 0;
            while self.hello.is_none() {
                if attempt == HANDSHAKE_ATTEMPTS {
                    return Ok(SessionEnd::PortLost(anyhow::anyhow!(
                        "no HELLO reply in {HANDSHAKE_ATTEMPTS} attempts (wrong --baud or --dialect?)"
                    )));
                }
                attempt += 1;
                let hello = HostCommand::Hello {
                    version: self.version.number(),
                };
                if let Err(e) = send(port, &hello, self.version) {
                    return Ok(SessionEnd::PortLost(e));
                }
                let deadline = Instant::now() + HANDSHAKE_TIMEOUT;
                while self.hello.is_none() && Instant::now() < deadline {
                    if node.wait(Duration::ZERO).is_err() {
                        return Ok(SessionEnd::Shutdown);
                    }
                    if let Err(e) = self.read_some(port, &mut framer, &mut buf)? {
                        return Ok(SessionEnd::PortLost(e));
                    }
                    if self.version_rejected {
                        bail!(
                            "the device does not speak protocol version {} (try --protocol 1 for \
                             older firmware)",
                            self.version
                        );
                    }
                }
            }
            // Identified by its answer: its readings from here on are published (also those that
            // come while the handshake settles below).
            if let Some(hello) = self.hello.clone() {
                if let Err(why) = self.accept_head(&hello) {
                    return Ok(SessionEnd::WrongHead(why));
                }
                self.identified = true;
            }
            // A head that announced itself at power-on as we asked answers twice; both are this
            // handshake.
            let settle = Instant::now() + HANDSHAKE_SETTLE;
            while Instant::now() < settle {
                if let Err(e) = self.read_some(port, &mut framer, &mut buf)? {
                    return Ok(SessionEnd::PortLost(e));
                }
            }
            if let Some(hello) = self.hello.take() {
                if let Err(why) = self.accept_head(&hello) {
                    return Ok(SessionEnd::WrongHead(why));
                }
                self.identified = true;
                info!(?hello, "handshake done");
                if self.unidentified_readings > 0 {
                    info!(
                        dropped = self.unidentified_readings,
                        "readings sent before the head identified itself were not published"
                    );
                }
                self.decoder.adopt_device_geometry(&hello);
                if let Some(why) = self.scan.outside_limits(&hello) {
                    // The scan of the command line: the head would refuse it for ever. (One asked
                    // for later, from the viewer, is refused by the head, which the viewer shows.)
                    if self.status.reconnects == 0 && self.status.head_resets == 0 {
                        return Err(Misconfigured(why).into());
                    }
                    warn!("{why}");
                }
            }
            if let Err(e) = self.command_scan(port) {
                return Ok(SessionEnd::PortLost(e));
            }
        }
        self.last_line = Instant::now();
        self.probe_sent = None;
        self.head_state = None;
        self.set_state(LinkState::Connected)?;

        let waitset = WaitSetBuilder::new()
            .create::<Ipc>()
            .map_err(|e| ipc::IpcError::new("create waitset", e))?;
        let serial = ipc::WatchedFd::new(port).context("the serial port has no open descriptor")?;
        let serial_guard = waitset
            .attach_notification(&serial)
            .map_err(|e| ipc::IpcError::new("attach the serial port", e))?;
        // Wakes the loop when a command is published. Without it (e.g. a socket path beyond the
        // system's limit under a long --iox-root) commands are looked for every READ_TIMEOUT.
        let commands_listener = ipc::wakeup_listener(node, ipc::COMMANDS_SERVICE)
            .inspect_err(|e| warn!("{e}: looking for commands every {READ_TIMEOUT:?} instead"))
            .ok();
        let _commands_guard = commands_listener
            .as_ref()
            .map(|listener| waitset.attach_notification(listener))
            .transpose()
            .map_err(|e| ipc::IpcError::new("attach commands listener", e))?;
        let mut next_status = Instant::now() + STATUS_PERIOD;
        loop {
            // Asleep until the head sends, a command comes, the status or the silence watchdog
            // is due, or a signal: an idle driver wakes about once a second.
            let mut due = self
                .silence_deadline()
                .map_or(next_status, |d| d.min(next_status));
            if commands_listener.is_none() {
                due = due.min(Instant::now() + READ_TIMEOUT);
            }
            let mut readable = false;
            let woke = waitset
                .wait_and_process_once_with_timeout(
                    |id| {
                        readable |= id.has_event_from(&serial_guard);
                        CallbackProgression::Continue
                    },
                    due.saturating_duration_since(Instant::now()),
                )
                .map_err(|e| ipc::IpcError::new("wait", e))?;
            if woke == WaitSetRunResult::TerminationRequest {
                return Ok(SessionEnd::Shutdown);
            }
            if let Some(listener) = &commands_listener {
                ipc::drain_wakeups(listener)?;
            }
            if let Err(e) = self.forward_commands(port) {
                return Ok(SessionEnd::PortLost(e));
            }
            if readable && let Err(e) = self.read_some(port, &mut framer, &mut buf)? {
                return Ok(SessionEnd::PortLost(e));
            }
            if let Some(hello) = self.hello.take() {
                // Unprompted: the head was reset (power, watchdog, its reset button) and is idle.
                if let Err(why) = self.accept_head(&hello) {
                    self.identified = false;
                    return Ok(SessionEnd::WrongHead(why));
                }
                self.status.head_resets += 1;
                self.sweeps.head_was_reset();
                if self.head_fault {
                    warn!(
                        resets = self.status.head_resets,
                        "the head announced itself: it was reset; its hardware fault is not \
                         acknowledged, so no scan is sent (acknowledge with a reset)"
                    );
                } else {
                    warn!(
                        resets = self.status.head_resets,
                        "the head announced itself: it was reset; sending the scan again"
                    );
                }
                self.decoder.adopt_device_geometry(&hello);
                if let Err(e) = self.command_scan(port) {
                    return Ok(SessionEnd::PortLost(e));
                }
                self.publish_status()?;
            }
            if self.dialect == Dialect::Native {
                match self.watch_silence(port) {
                    Err(e) => return Ok(SessionEnd::PortLost(e)),
                    Ok(Err(why)) => return Ok(SessionEnd::PortLost(anyhow::anyhow!(why))),
                    Ok(Ok(())) => {}
                }
            }
            if std::mem::take(&mut self.status_wanted)
                && let Err(e) = send(port, &HostCommand::Status, self.version)
            {
                return Ok(SessionEnd::PortLost(e));
            }
            if let Err(e) = self.resume_idle_head(port) {
                return Ok(SessionEnd::PortLost(e));
            }
            if Instant::now() >= next_status {
                self.publish_status()?;
                next_status = Instant::now() + STATUS_PERIOD;
            }
        }
    }

    /// Reads what the port has (waiting at most [`READ_TIMEOUT`]) and handles every complete line.
    /// The outer error is fatal (shared memory), the inner one a lost port.
    fn read_some(
        &mut self,
        port: &mut TTYPort,
        framer: &mut LineFramer,
        buf: &mut [u8],
    ) -> Result<Result<(), anyhow::Error>> {
        let n = match port.read(buf) {
            Ok(0) => return Ok(Err(anyhow::anyhow!("end of file on the serial port"))),
            Ok(n) => n,
            Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::Interrupted) => {
                return Ok(Ok(()));
            }
            Err(e) => return Ok(Err(anyhow::Error::new(e).context("read failed"))),
        };
        let mut fatal = Ok(());
        framer.push(&buf[..n], |item| {
            if fatal.is_ok() {
                fatal = self.handle(item);
            }
        });
        fatal.map(Ok)
    }

    fn handle(&mut self, item: FramedLine<'_>) -> Result<()> {
        let line = match item {
            FramedLine::Line(line) => line,
            FramedLine::Overflow => {
                self.status.lines_rejected += 1;
                if let Some(left_out) = self.reject_log.allow(Instant::now()) {
                    warn!(
                        rejected = self.status.lines_rejected,
                        left_out, "discarded an overlong line (garbage on the serial line?)"
                    );
                }
                return Ok(());
            }
        };
        let decoded = self.decoder.decode(line, ipc::unix_time_ns());
        if decoded.is_ok() {
            self.status.lines_ok += 1;
            self.last_line = Instant::now();
            self.probe_sent = None;
        }
        match decoded {
            Err(e) => {
                self.status.lines_rejected += 1;
                // Counted always; logged at most once a second (a noisy line makes thousands).
                if let Some(left_out) = self.reject_log.allow(Instant::now()) {
                    warn!(
                        line = %String::from_utf8_lossy(line),
                        rejected = self.status.lines_rejected,
                        left_out,
                        "rejected line: {e}"
                    );
                }
            }
            Ok(Decoded::Reading(_)) if !self.identified => {
                // Before the handshake names the head, a reading may be another head's.
                self.decoder.withdraw_last();
                self.unidentified_readings += 1;
            }
            Ok(Decoded::Reading(mut reading)) => {
                reading.sweep_id = self.sweeps.of(reading.sweep_id);
                // The hobby sketches send no clock: their readings keep the arrival time.
                if self.dialect == Dialect::Native {
                    reading.host_stamp_ns = self
                        .clock
                        .stamp(reading.device_time_ms, reading.host_stamp_ns);
                }
                self.publish(&reading)?
            }
            Ok(Decoded::Message(msg)) => self.on_message(msg)?,
        }
        Ok(())
    }

    fn on_message(&mut self, msg: DeviceMessage) -> Result<()> {
        match &msg {
            DeviceMessage::Hello { .. } => {
                // Identified from this line on, not from the end of the read that brought it:
                // the readings after it in the same read are this head's too, whatever the
                // serial line's timing put into one read (a test once saw one withheld).
                if !self.identified && self.accept_head(&msg).is_ok() {
                    self.identified = true;
                }
                // A head says HELLO when it (re)starts: its clock starts again.
                self.clock.restart();
                self.hello = Some(msg);
            }
            DeviceMessage::Error { code, text } => {
                if *code == ErrorCode::Version {
                    self.version_rejected = true;
                }
                if *code == ErrorCode::Hardware {
                    self.last_hardware_error = text.clone();
                    self.status_wanted = true;
                }
                self.status.device_errors += 1;
                // Counted and kept in the status always; logged at most once a second (a head
                // answering every probe with its fault makes one a probe).
                if let Some(left_out) = self.device_error_log.allow(Instant::now()) {
                    warn!(
                        ?code,
                        text,
                        errors = self.status.device_errors,
                        left_out,
                        "device reports an error"
                    );
                }
                ipc::set_padded_text(
                    &mut self.status.last_device_error,
                    &format!("{}: {text}", code.wire()),
                );
                self.publish_status()?;
            }
            DeviceMessage::Status { state, .. } => {
                self.head_state = Some(*state);
                debug!(?msg, "status");
                if matches!(state, DeviceState::Idle | DeviceState::Fault) {
                    self.scan_stopped()?;
                }
                if *state == DeviceState::Fault {
                    self.head_stopped_on_fault()?;
                }
            }
            DeviceMessage::SweepStart {
                sweep,
                direction,
                mode,
                ..
            } => {
                self.status.sweep_id = self.sweeps.of(*sweep);
                self.status.direction = direction.sign();
                self.status.mode = match mode {
                    WireScanMode::Full => ScanMode::Full,
                    WireScanMode::Local => ScanMode::Local,
                } as u32;
                debug!(?msg, "sweep start");
            }
            DeviceMessage::SweepEnd { sweep } => {
                debug!(?msg, "sweep end");
                self.publish_sweep_end(*sweep)?;
            }
            other => debug!(msg = ?other, "device message"),
        }
        Ok(())
    }

    /// A head that reports itself idle while it should scan lost our command (or was stopped by
    /// something else): it is sent the scan again.
    fn resume_idle_head(&mut self, port: &mut TTYPort) -> Result<()> {
        if self.head_state.take() == Some(DeviceState::Idle) && self.scan.host_command().is_some() {
            info!(scan = ?self.scan, "the head is idle but should scan: sending the scan again");
            self.command_scan(port)?;
        }
        Ok(())
    }

    /// Tells the consumers that device sweep `device` ended, if its last reading was the latest
    /// published: they need not wait for the next sweep's first reading to see it whole. On
    /// the readings' wake-up event, which the fusion waits on.
    fn publish_sweep_end(&mut self, device: u32) -> Result<()> {
        let Some((last_seq, sweep_id)) = self.last_published else {
            return Ok(());
        };
        if self.sweeps.ended(device) != Some(sweep_id) {
            return Ok(());
        }
        self.sweep_ends
            .send_copy(SweepEnd {
                stamp_ns: ipc::unix_time_ns(),
                last_seq,
                sweep_id,
                reserved: 0,
            })
            .map_err(|e| ipc::IpcError::new("send sweep end", e))?;
        self.notifier
            .notify()
            .map_err(|e| ipc::IpcError::new("notify readings", e))?;
        Ok(())
    }

    fn publish(&mut self, reading: &Reading) -> Result<()> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| ipc::IpcError::new("loan reading sample", e))?;
        sample
            .write_payload(*reading)
            .send()
            .map_err(|e| ipc::IpcError::new("send reading", e))?;
        self.notifier
            .notify()
            .map_err(|e| ipc::IpcError::new("notify readings", e))?;
        self.last_published = Some((reading.seq, reading.sweep_id));
        self.status.angle_deg = reading.angle_deg;
        self.status.direction = i32::from(reading.direction);
        self.status.sweep_id = reading.sweep_id;
        debug!(
            seq = reading.seq,
            angle = reading.angle_deg,
            distance = reading.distance_m,
            flags = reading.flags,
            "reading"
        );
        if self.print {
            println!("{}", format_reading(reading));
        }
        Ok(())
    }

    /// Forwards commands from `sonar/commands` to the device.
    fn forward_commands(&mut self, port: &mut TTYPort) -> Result<()> {
        loop {
            let sample = match self.commands.receive() {
                Ok(Some(sample)) => sample,
                Ok(None) => return Ok(()),
                Err(e) => {
                    warn!("receiving commands failed: {e:?}");
                    return Ok(());
                }
            };
            let cmd = *sample.payload();
            let request = match cmd.kind() {
                Some(ScanCommandKind::FullScan) => Some(ScanRequest::Full),
                Some(ScanCommandKind::LocalScan) => match local_segment(cmd.from_deg, cmd.to_deg) {
                    Ok(r) => Some(r),
                    Err(e) => {
                        warn!("rejected local scan command: {e}");
                        continue;
                    }
                },
                Some(ScanCommandKind::Stop) => Some(ScanRequest::None),
                Some(ScanCommandKind::Status) => None,
                Some(ScanCommandKind::Reset) => {
                    if self.dialect == Dialect::Native {
                        self.acknowledge_fault(port)?;
                    }
                    continue;
                }
                None => {
                    warn!(kind = cmd.kind, "rejected unknown command");
                    continue;
                }
            };
            if self.dialect == Dialect::Hobby {
                warn!(?cmd, "the hobby dialect takes no commands; ignored");
                continue;
            }
            info!(?cmd, "command");
            let host = match request {
                Some(request) => {
                    self.scan = request;
                    request.host_command().unwrap_or(HostCommand::Stop)
                }
                None => HostCommand::Status,
            };
            if self.head_fault && host != HostCommand::Stop && host != HostCommand::Status {
                warn!(
                    "not sending the scan: the head stopped on a hardware fault ({}); it runs once \
                     the fault is acknowledged with a reset",
                    self.last_hardware_error
                );
                continue;
            }
            send(port, &host, self.version)?;
            if host == HostCommand::Stop {
                self.scan_stopped()?;
            }
        }
    }

    /// The head stands still: the status says so at once, not the last sweep's mode for ever.
    fn scan_stopped(&mut self) -> Result<()> {
        if self.status.mode != ScanMode::Idle as u32 {
            self.status.mode = ScanMode::Idle as u32;
            self.status.direction = 0;
            self.publish_status()?;
        }
        Ok(())
    }
}

fn send(port: &mut TTYPort, cmd: &HostCommand, version: ProtocolVersion) -> Result<()> {
    port.write_all(encode_command(cmd, version).as_bytes())
        .and_then(|()| port.flush())
        .with_context(|| format!("write {cmd:?}"))
}

fn format_reading(r: &Reading) -> String {
    let range = if r.is_valid_range() {
        format!("{:.3} m", r.distance_m)
    } else if r.has(ipc::flags::OUT_OF_RANGE) {
        "out of range".to_owned()
    } else {
        "no echo".to_owned()
    };
    format!(
        "#{:<6} sweep {:<4} {} {:>7.2}°  {:>12}  pings {}/{}  raw µs {:?}",
        r.seq,
        r.sweep_id,
        if r.direction >= 0 { '+' } else { '-' },
        r.angle_deg,
        range,
        r.pings_used,
        r.ping_count,
        &r.echo_us[..usize::from(r.ping_count)]
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scan_argument_forms() {
        assert_eq!(parse_scan("full"), Ok(ScanRequest::Full));
        assert_eq!(parse_scan("none"), Ok(ScanRequest::None));
        assert_eq!(
            parse_scan("-30..45.5"),
            Ok(ScanRequest::Local {
                from_deg: -30.0,
                to_deg: 45.5
            })
        );
        assert!(parse_scan("30..-30").is_err());
        assert!(parse_scan("left").is_err());
        assert_eq!(
            parse_scan("-30..30").map(ScanRequest::host_command),
            Ok(Some(HostCommand::LocalScan {
                from_cdeg: -3000,
                to_cdeg: 3000
            }))
        );
    }

    /// Named as the `[sensor]` key; the old name still works (issue 28).
    #[test]
    fn the_beam_half_angle_flag_is_named_as_its_key() {
        for flag in ["--beam-half-angle-deg", "--beam-half-angle"] {
            let args = Args::try_parse_from(["sonar-driver", "--port", "/dev/null", flag, "15"])
                .unwrap_or_else(|e| panic!("{flag}: {e}"));
            assert_eq!(args.beam_half_angle_deg, 15.0);
        }
        let defaults = Args::try_parse_from(["sonar-driver", "--port", "/dev/null"]);
        assert_eq!(defaults.map(|a| a.beam_half_angle_deg).ok(), Some(30.0));
    }
}
