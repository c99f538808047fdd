//! The microcontroller as a pure state machine: commands in, device messages out, on a simulated
//! clock. No I/O and no wall time, so every behaviour is a deterministic unit test.
//!
//! The head's position is kept in half steps from the MIN limit switch: the pings of a reading sit
//! half a step in from the edges of its 6° (see [`SensorConfig::reading_centres_deg`]), so ping
//! positions are odd half steps and the two limits even ones. Time advances only through
//! [`Firmware::act`] (one step of the motor or one ping per call) and [`Firmware::idle_until`].

use sonar_common::protocol::{
    DeviceMessage, DeviceState, Direction, ErrorCode, HostCommand, Limit, MAX_PINGS_PER_READING,
    PROTOCOL_VERSION, ParseError, ProtocolVersion, WireReading, WireScanMode, parse_command,
};
use sonar_common::sensor::{SensorConfig, SensorConfigError};

use crate::faults::{SwitchFault, SwitchFaults};
use crate::geometry::Pose;

/// A switch closing more than this many half steps (1.5°) before its limit, or still open this far
/// past it, is a hardware fault (the firmware's `HEAD_SWITCH_TOLERANCE_UNITS`).
const SWITCH_TOLERANCE_H: i32 = 2;
/// Homing gives up after this much travel without the MIN switch: one sweep + 15° (the firmware's
/// `HOMING_MAX_DEG`).
const HOMING_MAX_DEG: u32 = 315;

/// The firmware's name in the `HELLO` reply.
pub const FIRMWARE_ID: &str = concat!("sonar-sim ", env!("CARGO_PKG_VERSION"));
/// The head identity of a [`Firmware`] not given one with [`Firmware::speaking`].
pub const DEFAULT_HEAD_ID: &str = "sonar-sim";

/// The ranging sensor as the firmware sees it.
pub trait Transducer {
    /// Fires one ping with the head at `aim_deg`; returns the echo time in µs, 0 for no echo.
    fn ping(&mut self, aim_deg: f64) -> u32;

    /// The robot carrying the head moved: later pings are taken from `pose`. A transducer with no
    /// world around it (a test probe, a bench) has nothing to move.
    fn set_pose(&mut self, _pose: Pose) {}
}

/// How long the hardware takes, in simulated time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    /// One ping, echo wait included: HC-SR04/SRF05 datasheets ask for ≥ 50 ms between pings so the
    /// previous burst has died out.
    pub ping_interval_ms: u32,
    /// One 1.5° step of the geared stepper.
    pub step_time_ms: u32,
}

impl Default for Timing {
    fn default() -> Self {
        Self {
            ping_interval_ms: 50,
            step_time_ms: 10,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scan {
    Full,
    /// Reading indices (into the reading centres) of the segment's ends.
    Local {
        first: usize,
        last: usize,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Activity {
    Idle,
    /// Driving without pings to where the next sweep of `scan` starts (a half-step position);
    /// `ending` is a sweep still open, closed on arrival (after the limit switch).
    Travel {
        scan: Scan,
        target: i32,
        ending: Option<u32>,
    },
    /// In sweep `sweep`; next comes ping `ping` of the `k`-th reading in sweep order.
    Sweep {
        scan: Scan,
        sweep: u32,
        k: usize,
        ping: usize,
    },
    /// Stopped on a hardware fault: nothing moves until `RESET`; a scan is answered with the
    /// fault's `ERR,HARDWARE` line again.
    Fault,
}

/// The emulated PIC: stepper, limit switches and ranging, driven by host commands.
#[derive(Debug)]
pub struct Firmware<T> {
    cfg: SensorConfig,
    timing: Timing,
    transducer: T,
    centres_cdeg: Vec<i32>,
    /// Position of the MAX limit switch, half steps from MIN.
    max_h: i32,
    now_us: u64,
    pos_h: i32,
    dir: Direction,
    activity: Activity,
    /// Id of the latest sweep started (0 before the first).
    last_sweep: u32,
    seq: u32,
    /// Simulated time of the latest (re)boot: the device's ms clock in `RD` lines counts from it.
    boot_us: u64,
    /// Readings sent since the simulator started, across resets.
    readings_sent: u64,
    echoes: [u32; MAX_PINGS_PER_READING],
    /// What is left of the ping interval after the last echo came in: the head waits it out
    /// before its next action, so that the burst dies away.
    holdoff_us: u64,
    commands: u64,
    rejected_lines: u64,
    version: ProtocolVersion,
    head_id: String,
    switches: SwitchFaults,
    /// What the head stopped on, while [`Activity::Fault`].
    fault_text: String,
}

impl<T: Transducer> Firmware<T> {
    /// Powers on: homed to the MIN limit, whose switch has already reversed the motor (so the
    /// direction is counter-clockwise), idle, clock at 0.
    pub fn new(
        cfg: SensorConfig,
        timing: Timing,
        transducer: T,
    ) -> Result<Self, SensorConfigError> {
        cfg.validate()?;
        let max_h = ((cfg.sweep_max_deg - cfg.sweep_min_deg) / cfg.step_deg * 2.0).round() as i32;
        Ok(Self {
            centres_cdeg: cfg
                .reading_centres_deg()
                .iter()
                .map(|&c| cdeg(c.into()))
                .collect(),
            cfg,
            timing,
            transducer,
            max_h,
            now_us: 0,
            pos_h: 0,
            dir: Direction::Ccw,
            activity: Activity::Idle,
            last_sweep: 0,
            seq: 0,
            boot_us: 0,
            holdoff_us: 0,
            readings_sent: 0,
            echoes: [0; MAX_PINGS_PER_READING],
            commands: 0,
            rejected_lines: 0,
            version: PROTOCOL_VERSION,
            head_id: DEFAULT_HEAD_ID.to_owned(),
            switches: SwitchFaults::default(),
            fault_text: String::new(),
        })
    }

    /// Breaks the limit switches as `faults` say (`--faults min-switch=…`). The model homes at
    /// once: [`Firmware::power_on`] reports what the firmware's homing would find. Positions are
    /// the head's own count from the MIN switch, so a MIN switch closing early moves where the
    /// MAX switch is met, as on the hardware. A bouncing switch is debounced, as by the firmware.
    pub fn with_switch_faults(mut self, faults: SwitchFaults) -> Self {
        self.switches = faults;
        self
    }

    /// The protocol version this head speaks (only that one) and the identity it announces.
    pub fn speaking(mut self, version: ProtocolVersion, head_id: &str) -> Self {
        self.version = version;
        self.head_id = head_id.to_owned();
        self
    }

    pub fn version(&self) -> ProtocolVersion {
        self.version
    }

    /// What the head prints at power-on: a version-2 head announces itself with its `HELLO`, so a
    /// driver that is already connected learns that the head was reset.
    pub fn power_on(&mut self, out: &mut Vec<DeviceMessage>) {
        if self.version >= ProtocolVersion::V2 {
            out.push(self.hello());
        }
        self.home(out, false);
    }

    /// Homes at once to the MIN switch (saying `LIM,MIN` if `announce`), or stops on the fault
    /// the firmware's homing would meet with these switches.
    fn home(&mut self, out: &mut Vec<DeviceMessage>, announce: bool) {
        self.pos_h = 0;
        self.dir = Direction::Ccw;
        self.activity = Activity::Idle;
        match self.switches.min {
            Some(SwitchFault::Dead) => {
                self.dir = Direction::Cw;
                return self.fault(
                    out,
                    format!(
                        "MIN switch not found in {HOMING_MAX_DEG} deg of homing (dead switch? wiring?)"
                    ),
                );
            }
            Some(SwitchFault::Stuck) => {
                return self.fault(
                    out,
                    "MIN switch stuck closed (still closed 30 deg off it)".into(),
                );
            }
            _ => {}
        }
        if self.closed_at(0).1 {
            self.dir = Direction::Cw;
            return self.fault(out, BOTH_CLOSED.into());
        }
        if announce {
            out.push(DeviceMessage::LimitHit(Limit::Min));
        }
    }

    /// Whether (MIN, MAX) are closed with the head at `pos_h` (half steps from where homing found
    /// the MIN switch).
    fn closed_at(&self, pos_h: i32) -> (bool, bool) {
        let half_step_deg = f64::from(self.cfg.step_deg) / 2.0;
        let early_h = |fault: Option<SwitchFault>| match fault {
            Some(SwitchFault::Early { deg }) => (f64::from(deg) / half_step_deg).floor() as i32,
            _ => 0,
        };
        let level = |fault: Option<SwitchFault>, at_place: bool| match fault {
            Some(SwitchFault::Dead) => false,
            Some(SwitchFault::Stuck) => true,
            _ => at_place,
        };
        // Homing put the MIN switch at 0; a MIN switch closing early moved that 0 towards MAX.
        let max_at = self.max_h - early_h(self.switches.min) - early_h(self.switches.max);
        (
            level(self.switches.min, pos_h <= 0),
            level(self.switches.max, pos_h >= max_at),
        )
    }

    /// Stops on a hardware fault: `ERR,HARDWARE`, the open sweep ended, `ST,FAULT`.
    fn fault(&mut self, out: &mut Vec<DeviceMessage>, text: String) {
        let open = match self.activity {
            Activity::Sweep { sweep, .. } => Some(sweep),
            Activity::Travel { ending, .. } => ending,
            Activity::Idle | Activity::Fault => None,
        };
        self.activity = Activity::Fault;
        self.fault_text = text.clone();
        out.push(DeviceMessage::Error {
            code: ErrorCode::Hardware,
            text,
        });
        if let Some(sweep) = open {
            out.push(DeviceMessage::SweepEnd { sweep });
        }
        out.push(self.status());
    }

    fn status(&self) -> DeviceMessage {
        let (state, sweep) = match self.activity {
            Activity::Idle => (DeviceState::Idle, self.last_sweep),
            Activity::Fault => (DeviceState::Fault, self.last_sweep),
            Activity::Travel { scan, .. } => (scan.state(), self.last_sweep),
            Activity::Sweep { scan, sweep, .. } => (scan.state(), sweep),
        };
        let (min, max) = self.limits_cdeg();
        DeviceMessage::Status {
            state,
            // As the firmware: from the position reached, within the limits.
            angle_cdeg: cdeg(self.angle_deg()).clamp(min, max),
            direction: self.dir,
            sweep,
        }
    }

    /// Reboots the head, as a power cycle, its reset button or its watchdog would: what it keeps in
    /// RAM starts over (idle, no sweep open, sweep ids and the reading counter from 0, the ms clock of
    /// `RD` lines from 0), and it prints what it prints at power-on (a version-2 head its `HELLO`).
    ///
    /// The model homes instantly, as at power-on: it stands at the MIN limit at once, with no
    /// `HOMING` state and no `LIM,MIN`, where the firmware reports `ST,HOMING` while it turns to find
    /// the switch. The simulated clock runs on (it paces the simulation), and so do the simulator's
    /// counters ([`Firmware::readings`], [`Firmware::command_counts`]).
    pub fn reset(&mut self, out: &mut Vec<DeviceMessage>) {
        self.activity = Activity::Idle;
        self.last_sweep = 0;
        self.seq = 0;
        self.echoes = [0; MAX_PINGS_PER_READING];
        self.holdoff_us = 0;
        self.boot_us = self.now_us;
        self.power_on(out);
    }

    fn hello(&self) -> DeviceMessage {
        let (min_cdeg, max_cdeg) = self.limits_cdeg();
        DeviceMessage::Hello {
            version: self.version.number(),
            firmware: FIRMWARE_ID.into(),
            head_id: self.head_id.clone(),
            step_cdeg: cdeg(self.cfg.step_deg.into()).unsigned_abs(),
            pings_per_reading: u32::from(self.cfg.pings_per_reading),
            min_cdeg,
            max_cdeg,
        }
    }

    /// Simulated time, µs since power-on.
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// Whether [`Firmware::act`] has something to do.
    pub fn is_busy(&self) -> bool {
        !matches!(self.activity, Activity::Idle | Activity::Fault)
    }

    /// Lets simulated time pass while idle (a busy device's clock follows its actions).
    pub fn idle_until(&mut self, t_us: u64) {
        if !self.is_busy() {
            self.now_us = self.now_us.max(t_us);
        }
    }

    /// Head angle, degrees.
    pub fn angle_deg(&self) -> f64 {
        f64::from(self.cfg.sweep_min_deg)
            + f64::from(self.pos_h) * f64::from(self.cfg.step_deg) / 2.0
    }

    /// Readings sent since the simulator started (resets included).
    pub fn readings(&self) -> u64 {
        self.readings_sent
    }

    /// Commands obeyed and lines rejected so far.
    pub fn command_counts(&self) -> (u64, u64) {
        (self.commands, self.rejected_lines)
    }

    pub fn transducer(&self) -> &T {
        &self.transducer
    }

    pub fn transducer_mut(&mut self) -> &mut T {
        &mut self.transducer
    }

    /// One line from the host, terminator optional.
    pub fn handle_line(&mut self, line: &[u8], out: &mut Vec<DeviceMessage>) {
        match parse_command(line, self.version) {
            Ok(cmd) => self.handle_command(cmd, out),
            Err(e) => {
                self.rejected_lines += 1;
                let code = match e {
                    ParseError::ChecksumMismatch { .. } => ErrorCode::Checksum,
                    _ => ErrorCode::Syntax,
                };
                out.push(DeviceMessage::Error {
                    code,
                    text: e.to_string(),
                });
            }
        }
    }

    /// A line too long for the receive buffer was thrown away.
    pub fn handle_overflow(&mut self, out: &mut Vec<DeviceMessage>) {
        self.rejected_lines += 1;
        out.push(DeviceMessage::Error {
            code: ErrorCode::Syntax,
            text: "line too long".into(),
        });
    }

    pub fn handle_command(&mut self, cmd: HostCommand, out: &mut Vec<DeviceMessage>) {
        self.commands += 1;
        let ack = |command: &str| DeviceMessage::Ack {
            command: command.into(),
        };
        match cmd {
            HostCommand::Hello { version } if version == self.version.number() => {
                out.push(self.hello())
            }
            HostCommand::Hello { version } => out.push(DeviceMessage::Error {
                code: ErrorCode::Version,
                text: format!(
                    "host speaks version {version}; device speaks {}",
                    self.version.number()
                ),
            }),
            HostCommand::FullScan | HostCommand::LocalScan { .. }
                if self.activity == Activity::Fault =>
            {
                // The fault again, and no motion.
                out.push(DeviceMessage::Error {
                    code: ErrorCode::Hardware,
                    text: self.fault_text.clone(),
                });
            }
            HostCommand::FullScan => {
                out.push(ack("SCAN"));
                self.close_sweep(out);
                let at_limit = self.pos_h == 0 || self.pos_h == self.max_h;
                let target = match (at_limit, self.dir) {
                    (true, _) => self.pos_h,
                    (false, Direction::Ccw) => self.max_h,
                    (false, Direction::Cw) => 0,
                };
                self.activity = Activity::Travel {
                    scan: Scan::Full,
                    target,
                    ending: None,
                };
            }
            HostCommand::LocalScan { from_cdeg, to_cdeg } => {
                let (min, max) = self.limits_cdeg();
                let inside = |c: &i32| (from_cdeg..=to_cdeg).contains(c);
                let first = self.centres_cdeg.iter().position(inside);
                let last = self.centres_cdeg.iter().rposition(inside);
                let (Some(first), Some(last)) = (first, last) else {
                    out.push(DeviceMessage::Error {
                        code: ErrorCode::Range,
                        text: format!("no reading centre in {from_cdeg}..{to_cdeg}"),
                    });
                    return;
                };
                if from_cdeg < min || to_cdeg > max {
                    out.push(DeviceMessage::Error {
                        code: ErrorCode::Range,
                        text: format!("segment outside the limits {min}..{max}"),
                    });
                    return;
                }
                out.push(ack("SCAN"));
                self.close_sweep(out);
                let scan = Scan::Local { first, last };
                let (lo, hi) = self.segment_ends_h(scan);
                let target = if (self.pos_h - lo).abs() <= (self.pos_h - hi).abs() {
                    lo
                } else {
                    hi
                };
                self.activity = Activity::Travel {
                    scan,
                    target,
                    ending: None,
                };
            }
            HostCommand::Stop => {
                out.push(ack("STOP"));
                // A fault stays until RESET.
                if self.activity != Activity::Fault {
                    self.close_sweep(out);
                    self.activity = Activity::Idle;
                }
            }
            HostCommand::Status => out.push(self.status()),
            HostCommand::Reset => {
                // A person has looked at the head: clear the fault and home again.
                out.push(ack("RESET"));
                self.close_sweep(out);
                self.home(out, true);
            }
        }
    }

    /// Does the next step of the motor or the next ping and advances the clock by its duration;
    /// returns false when idle. Messages carry the time at the end of the action.
    pub fn act(&mut self, out: &mut Vec<DeviceMessage>) -> bool {
        match self.activity {
            Activity::Idle | Activity::Fault => {
                self.holdoff_us = 0;
                return false;
            }
            _ if self.holdoff_us > 0 => {
                self.now_us += std::mem::take(&mut self.holdoff_us);
                return true;
            }
            Activity::Travel {
                scan,
                target,
                ending,
            } => {
                if self.pos_h != target {
                    self.step_toward(target, out);
                } else {
                    if let Some(sweep) = ending {
                        out.push(DeviceMessage::SweepEnd { sweep });
                    }
                    self.start_sweep(scan, out);
                }
            }
            Activity::Sweep {
                scan,
                sweep,
                k,
                ping,
            } => {
                let (lo, hi) = self.bounds(scan);
                let reading = match self.dir {
                    Direction::Ccw => lo + k,
                    Direction::Cw => hi - k,
                };
                let target = self.ping_h(reading, ping);
                if self.pos_h != target {
                    self.step_toward(target, out);
                    return true;
                }
                let echo_us = self.transducer.ping(self.angle_deg());
                self.echoes[ping] = echo_us;
                // The echo is in when the echo line falls (its time of flight, or the sensor's
                // time-out without one): then the firmware sends a reading whose last ping this
                // was, stamped with its clock. The rest of the ping interval is waited out after.
                let interval_us = u64::from(self.timing.ping_interval_ms) * 1000;
                let line_us = if echo_us == 0 {
                    self.cfg.echo_timeout_us
                } else {
                    echo_us
                };
                let heard_us = u64::from(line_us).min(interval_us);
                self.now_us += heard_us;
                self.holdoff_us = interval_us - heard_us;
                let pings = usize::from(self.cfg.pings_per_reading);
                if ping + 1 < pings {
                    self.activity = Activity::Sweep {
                        scan,
                        sweep,
                        k,
                        ping: ping + 1,
                    };
                    return true;
                }
                out.push(DeviceMessage::Reading(WireReading {
                    seq: self.seq,
                    time_ms: ((self.now_us - self.boot_us) / 1000) as u32,
                    sweep,
                    direction: self.dir,
                    angle_cdeg: self.centres_cdeg[reading],
                    ping_count: self.cfg.pings_per_reading,
                    echo_us: self.echoes,
                }));
                self.seq = self.seq.wrapping_add(1);
                self.readings_sent += 1;
                if k < hi - lo {
                    self.activity = Activity::Sweep {
                        scan,
                        sweep,
                        k: k + 1,
                        ping: 0,
                    };
                } else if scan == Scan::Full {
                    // Run on to the limit switch, which ends the sweep.
                    self.activity = Activity::Travel {
                        scan,
                        target: if self.dir == Direction::Ccw {
                            self.max_h
                        } else {
                            0
                        },
                        ending: Some(sweep),
                    };
                } else {
                    out.push(DeviceMessage::SweepEnd { sweep });
                    self.start_sweep(scan, out);
                }
            }
        }
        true
    }

    /// Moves at most one step toward `target`, half a step at a time as the firmware's microsteps,
    /// watching the switch ahead: a switch at its place reverses the motor, one closing early or
    /// still open past its limit, or both closed, stops the head ([`Firmware::fault`]).
    fn step_toward(&mut self, target: i32, out: &mut Vec<DeviceMessage>) {
        let delta = (target - self.pos_h).clamp(-2, 2);
        self.dir = if delta > 0 {
            Direction::Ccw
        } else {
            Direction::Cw
        };
        for _ in 0..delta.unsigned_abs() {
            if self.half_step(out) {
                return;
            }
        }
        let limit = match self.dir {
            Direction::Ccw => self.max_h,
            Direction::Cw => 0,
        };
        if self.pos_h == limit {
            // At the limit and its switch is open: creep on by the tolerance to meet it.
            for _ in 0..SWITCH_TOLERANCE_H {
                if self.half_step(out) {
                    return;
                }
            }
            let text = format!(
                "{} switch open at {} cdeg past its limit (dead switch? missed steps?)",
                self.switch_name(),
                cdeg(self.angle_deg())
            );
            self.fault(out, text);
        }
    }

    fn switch_name(&self) -> &'static str {
        match self.dir {
            Direction::Ccw => "MAX",
            Direction::Cw => "MIN",
        }
    }

    /// One half step in `self.dir`, then the switches; true if they acted.
    fn half_step(&mut self, out: &mut Vec<DeviceMessage>) -> bool {
        self.pos_h += self.dir.sign();
        self.now_us += u64::from(self.timing.step_time_ms) * 500;
        let (min, max) = self.closed_at(self.pos_h);
        if min && max {
            self.fault(out, BOTH_CLOSED.into());
            return true;
        }
        let (ahead, limit, off) = match self.dir {
            Direction::Ccw => (max, self.max_h, self.max_h - self.pos_h),
            Direction::Cw => (min, 0, self.pos_h),
        };
        if !ahead {
            return false;
        }
        if off > SWITCH_TOLERANCE_H {
            // Far from where the step count puts it: the switch or the count is wrong, and
            // nothing tells which. Stop rather than trust either.
            let text = format!(
                "{} switch closed at {} cdeg: {} cdeg early (switch moved? missed steps?)",
                self.switch_name(),
                cdeg(self.angle_deg()),
                cdeg(f64::from(off) * f64::from(self.cfg.step_deg) / 2.0)
            );
            self.fault(out, text);
            return true;
        }
        self.pos_h = limit;
        out.push(DeviceMessage::LimitHit(match self.dir {
            Direction::Ccw => Limit::Max,
            Direction::Cw => Limit::Min,
        }));
        self.dir = self.dir.reversed();
        if let Activity::Sweep { scan, sweep, .. } = self.activity {
            // The switch ends the sweep (the reading under way is dropped).
            out.push(DeviceMessage::SweepEnd { sweep });
            self.start_sweep(scan, out);
        }
        true
    }

    /// Begins a sweep from where the head stands (a limit, or an end of the local segment).
    fn start_sweep(&mut self, scan: Scan, out: &mut Vec<DeviceMessage>) {
        let (lo, hi) = self.bounds(scan);
        self.dir = match scan {
            Scan::Full if self.pos_h == 0 => Direction::Ccw,
            Scan::Full => Direction::Cw,
            Scan::Local { .. } if self.pos_h <= self.segment_ends_h(scan).0 => Direction::Ccw,
            Scan::Local { .. } => Direction::Cw,
        };
        self.last_sweep += 1;
        let (from, to) = match self.dir {
            Direction::Ccw => (lo, hi),
            Direction::Cw => (hi, lo),
        };
        out.push(DeviceMessage::SweepStart {
            sweep: self.last_sweep,
            direction: self.dir,
            mode: match scan {
                Scan::Full => WireScanMode::Full,
                Scan::Local { .. } => WireScanMode::Local,
            },
            from_cdeg: self.centres_cdeg[from],
            to_cdeg: self.centres_cdeg[to],
        });
        self.activity = Activity::Sweep {
            scan,
            sweep: self.last_sweep,
            k: 0,
            ping: 0,
        };
    }

    /// Reports the end of a sweep still under way (a new command interrupts it).
    fn close_sweep(&mut self, out: &mut Vec<DeviceMessage>) {
        if let Activity::Sweep { sweep, .. }
        | Activity::Travel {
            ending: Some(sweep),
            ..
        } = self.activity
        {
            out.push(DeviceMessage::SweepEnd { sweep });
        }
    }

    fn bounds(&self, scan: Scan) -> (usize, usize) {
        match scan {
            Scan::Full => (0, self.centres_cdeg.len() - 1),
            Scan::Local { first, last } => (first, last),
        }
    }

    /// Half-step position of ping `j` (in the order of motion) of reading `i`.
    fn ping_h(&self, i: usize, j: usize) -> i32 {
        let p = i32::from(self.cfg.pings_per_reading);
        let centre = p * (2 * i as i32 + 1);
        centre + self.dir.sign() * (2 * j as i32 - (p - 1))
    }

    /// Outermost ping positions of a scan's readings.
    fn segment_ends_h(&self, scan: Scan) -> (i32, i32) {
        let (lo, hi) = self.bounds(scan);
        let p = i32::from(self.cfg.pings_per_reading);
        (
            p * (2 * lo as i32 + 1) - (p - 1),
            p * (2 * hi as i32 + 1) + (p - 1),
        )
    }

    fn limits_cdeg(&self) -> (i32, i32) {
        (
            cdeg(self.cfg.sweep_min_deg.into()),
            cdeg(self.cfg.sweep_max_deg.into()),
        )
    }
}

impl Scan {
    fn state(self) -> DeviceState {
        match self {
            Scan::Full => DeviceState::Full,
            Scan::Local { .. } => DeviceState::Local,
        }
    }
}

/// The fault of both switches closed at once.
const BOTH_CLOSED: &str = "both limit switches closed (one stuck? wiring shorted?)";

/// Degrees to the wire's centidegrees.
fn cdeg(deg: f64) -> i32 {
    (deg * 100.0).round() as i32
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_common::protocol::encode_command;

    /// Records where it was aimed; always hears something 1 m away.
    #[derive(Debug, Default)]
    struct Probe {
        aims: Vec<f64>,
    }

    impl Transducer for Probe {
        fn ping(&mut self, aim_deg: f64) -> u32 {
            self.aims.push(aim_deg);
            5823
        }
    }

    fn firmware() -> Firmware<Probe> {
        Firmware::new(SensorConfig::default(), Timing::default(), Probe::default()).unwrap()
    }

    fn command(fw: &mut Firmware<Probe>, cmd: HostCommand) -> Vec<DeviceMessage> {
        let mut out = Vec::new();
        fw.handle_line(encode_command(&cmd, PROTOCOL_VERSION).as_bytes(), &mut out);
        out
    }

    /// Acts until `n` messages came out (or panics if the device idles or runs away).
    fn run(fw: &mut Firmware<Probe>, n: usize) -> Vec<DeviceMessage> {
        let mut out = Vec::new();
        for _ in 0..100_000 {
            if out.len() >= n {
                return out;
            }
            assert!(fw.act(&mut out), "idle after {out:?}");
        }
        panic!("no {n} messages");
    }

    fn readings(msgs: &[DeviceMessage]) -> Vec<WireReading> {
        msgs.iter()
            .filter_map(|m| match m {
                DeviceMessage::Reading(r) => Some(*r),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn handshake_reports_identity_and_geometry_or_refuses_the_version() {
        let mut fw = firmware().speaking(ProtocolVersion::V2, "HEAD-7");
        let hello = DeviceMessage::Hello {
            version: 2,
            firmware: FIRMWARE_ID.into(),
            head_id: "HEAD-7".into(),
            step_cdeg: 150,
            pings_per_reading: 4,
            min_cdeg: -15000,
            max_cdeg: 15000,
        };
        assert_eq!(
            command(&mut fw, HostCommand::Hello { version: 2 }),
            std::slice::from_ref(&hello)
        );
        let mut boot = Vec::new();
        fw.power_on(&mut boot);
        assert_eq!(
            boot,
            [hello],
            "a version-2 head announces itself at power-on"
        );
        let reply = command(&mut fw, HostCommand::Hello { version: 1 });
        assert!(matches!(
            &reply[..],
            [DeviceMessage::Error {
                code: ErrorCode::Version,
                ..
            }]
        ));
        assert!(!fw.is_busy());
    }

    #[test]
    fn a_version_1_head_speaks_only_version_1() {
        let mut fw = firmware().speaking(ProtocolVersion::V1, "ignored");
        let mut boot = Vec::new();
        fw.power_on(&mut boot);
        assert!(boot.is_empty(), "version 1 has no unprompted HELLO");
        let mut out = Vec::new();
        let hello = HostCommand::Hello { version: 1 };
        fw.handle_line(
            encode_command(&hello, ProtocolVersion::V1).as_bytes(),
            &mut out,
        );
        assert!(
            matches!(&out[..], [DeviceMessage::Hello { version: 1, .. }]),
            "{out:?}"
        );
        out.clear();
        fw.handle_line(
            encode_command(&hello, ProtocolVersion::V2).as_bytes(),
            &mut out,
        );
        assert!(matches!(
            &out[..],
            [DeviceMessage::Error {
                code: ErrorCode::Syntax,
                ..
            }]
        ));
    }

    #[test]
    fn power_on_status_is_idle_at_the_min_limit() {
        let mut fw = firmware();
        assert_eq!(
            command(&mut fw, HostCommand::Status),
            [DeviceMessage::Status {
                state: DeviceState::Idle,
                angle_cdeg: -15000,
                direction: Direction::Ccw,
                sweep: 0,
            }]
        );
        assert!(!fw.act(&mut Vec::new()));
    }

    #[test]
    fn full_sweeps_run_between_the_limits() {
        let mut fw = firmware();
        assert_eq!(
            command(&mut fw, HostCommand::FullScan),
            [DeviceMessage::Ack {
                command: "SCAN".into()
            }]
        );
        let msgs = run(&mut fw, 2 * 54);
        let start = |sweep, direction, from_cdeg, to_cdeg| DeviceMessage::SweepStart {
            sweep,
            direction,
            mode: WireScanMode::Full,
            from_cdeg,
            to_cdeg,
        };
        assert_eq!(msgs[0], start(1, Direction::Ccw, -14700, 14700));
        assert_eq!(msgs[51], DeviceMessage::LimitHit(Limit::Max));
        assert_eq!(msgs[52], DeviceMessage::SweepEnd { sweep: 1 });
        assert_eq!(msgs[53], start(2, Direction::Cw, 14700, -14700));
        assert_eq!(msgs[104], DeviceMessage::LimitHit(Limit::Min));
        assert_eq!(msgs[105], DeviceMessage::SweepEnd { sweep: 2 });
        assert_eq!(msgs[106], start(3, Direction::Ccw, -14700, 14700));

        for (sweep, rds, first, step) in [
            (1, readings(&msgs[1..51]), -14700, 600),
            (2, readings(&msgs[54..104]), 14700, -600),
        ] {
            assert_eq!(rds.len(), 50);
            for (k, r) in rds.iter().enumerate() {
                assert_eq!(r.sweep, sweep);
                assert_eq!(r.angle_cdeg, first + step * k as i32);
                assert_eq!(r.pings(), [5823; 4]);
                assert_eq!(
                    r.direction,
                    if step > 0 {
                        Direction::Ccw
                    } else {
                        Direction::Cw
                    }
                );
            }
        }
        let all = readings(&msgs);
        assert!(all.iter().enumerate().all(|(i, r)| r.seq == i as u32));
        // Half a step off the switch, then 3 steps and 4 pings, the reading sent as its last
        // echo (1 m: 5.8 ms) is in: 5 + 30 + 3 × 50 + 5.8 ms; then 4 steps and 4 pings per reading.
        assert_eq!(all[0].time_ms, 190);
        assert!(
            all[..50]
                .windows(2)
                .all(|w| w[1].time_ms - w[0].time_ms == 240)
        );

        // Pings 1.5° apart around each centre, in the order of motion.
        let aims = &fw.transducer().aims;
        assert_eq!(aims[..4], [-149.25, -147.75, -146.25, -144.75]);
        assert_eq!(aims[200..204], [149.25, 147.75, 146.25, 144.75]);
    }

    #[test]
    fn a_reset_mid_sweep_starts_over_as_at_power_on() {
        let mut fw = firmware().speaking(ProtocolVersion::V2, "HEAD-7");
        command(&mut fw, HostCommand::FullScan);
        run(&mut fw, 3);
        let mut power_on = Vec::new();
        fw.power_on(&mut power_on);
        let mut out = Vec::new();
        fw.reset(&mut out);
        assert_eq!(out, power_on, "the HELLO, unprompted");
        assert!(!fw.act(&mut Vec::new()), "idle");
        assert_eq!(
            command(&mut fw, HostCommand::Status),
            [DeviceMessage::Status {
                state: DeviceState::Idle,
                angle_cdeg: -15000,
                direction: Direction::Ccw,
                sweep: 0,
            }],
            "homed at once, at the MIN limit"
        );
        command(&mut fw, HostCommand::FullScan);
        let msgs = run(&mut fw, 2);
        assert!(matches!(
            msgs[0],
            DeviceMessage::SweepStart { sweep: 1, .. }
        ));
        let DeviceMessage::Reading(r) = msgs[1] else {
            panic!("{msgs:?}")
        };
        // Counter and ms clock from 0 again, as the first reading after power-on.
        assert_eq!(
            (r.seq, r.sweep, r.angle_cdeg, r.time_ms),
            (0, 1, -14700, 190)
        );
        assert_eq!(fw.readings(), 3, "the simulator's count goes on");

        let mut v1 = firmware().speaking(ProtocolVersion::V1, "ignored");
        let mut out = Vec::new();
        v1.reset(&mut out);
        assert!(out.is_empty(), "a version-1 head resets silently");
    }

    #[test]
    fn full_scan_from_between_the_limits_first_drives_on_to_the_limit_ahead() {
        let mut fw = firmware();
        command(
            &mut fw,
            HostCommand::LocalScan {
                from_cdeg: -3000,
                to_cdeg: 3000,
            },
        );
        run(&mut fw, 3); // SWP,START and two readings, going CCW
        command(&mut fw, HostCommand::Stop);
        let pings_before = fw.transducer().aims.len();
        let reply = command(&mut fw, HostCommand::FullScan);
        assert_eq!(
            reply,
            [DeviceMessage::Ack {
                command: "SCAN".into()
            }]
        );
        let msgs = run(&mut fw, 2);
        assert_eq!(msgs[0], DeviceMessage::LimitHit(Limit::Max));
        assert_eq!(
            fw.transducer().aims.len(),
            pings_before,
            "no pings on the way"
        );
        assert!(matches!(
            msgs[1],
            DeviceMessage::SweepStart {
                sweep: 2,
                direction: Direction::Cw,
                mode: WireScanMode::Full,
                from_cdeg: 14700,
                ..
            }
        ));
    }

    #[test]
    fn local_scan_sweeps_back_and_forth_over_the_segment() {
        let mut fw = firmware();
        let reply = command(
            &mut fw,
            HostCommand::LocalScan {
                from_cdeg: -3000,
                to_cdeg: 3000,
            },
        );
        assert_eq!(
            reply,
            [DeviceMessage::Ack {
                command: "SCAN".into()
            }]
        );
        let msgs = run(&mut fw, 3 * 12);
        assert!(!msgs.iter().any(|m| matches!(m, DeviceMessage::LimitHit(_))));
        let expect_start = |sweep, direction, from_cdeg, to_cdeg| DeviceMessage::SweepStart {
            sweep,
            direction,
            mode: WireScanMode::Local,
            from_cdeg,
            to_cdeg,
        };
        assert_eq!(msgs[0], expect_start(1, Direction::Ccw, -2700, 2700));
        assert_eq!(msgs[11], DeviceMessage::SweepEnd { sweep: 1 });
        assert_eq!(msgs[12], expect_start(2, Direction::Cw, 2700, -2700));
        assert_eq!(msgs[23], DeviceMessage::SweepEnd { sweep: 2 });
        assert_eq!(msgs[24], expect_start(3, Direction::Ccw, -2700, 2700));
        let angles: Vec<i32> = readings(&msgs[..24]).iter().map(|r| r.angle_cdeg).collect();
        let up: Vec<i32> = (0..10).map(|k| -2700 + 600 * k).collect();
        let down: Vec<i32> = up.iter().rev().copied().collect();
        assert_eq!(angles, [up, down].concat());
        // No pings on the way from the MIN limit; the segment starts 2.25° below its first centre.
        let aims = &fw.transducer().aims;
        assert_eq!(aims[0], -29.25);
        assert_eq!(aims[39], 29.25);
        assert_eq!(aims[40], 29.25);
    }

    #[test]
    fn local_scan_outside_the_limits_or_between_centres_is_refused() {
        let mut fw = firmware();
        for (from_cdeg, to_cdeg) in [(-16000, 0), (0, 15001), (100, 200), (14800, 15000)] {
            let reply = command(&mut fw, HostCommand::LocalScan { from_cdeg, to_cdeg });
            assert!(
                matches!(
                    &reply[..],
                    [DeviceMessage::Error {
                        code: ErrorCode::Range,
                        ..
                    }]
                ),
                "{from_cdeg}..{to_cdeg}: {reply:?}"
            );
        }
        assert!(!fw.is_busy());
        // A segment holding one centre is fine.
        let reply = command(
            &mut fw,
            HostCommand::LocalScan {
                from_cdeg: 200,
                to_cdeg: 400,
            },
        );
        assert_eq!(reply.len(), 1);
        let rds = readings(&run(&mut fw, 8));
        assert!(rds.iter().all(|r| r.angle_cdeg == 300));
    }

    #[test]
    fn stop_ends_the_sweep_and_holds_the_position() {
        let mut fw = firmware();
        command(&mut fw, HostCommand::FullScan);
        run(&mut fw, 3);
        let status = command(&mut fw, HostCommand::Status);
        assert!(matches!(
            status[..],
            [DeviceMessage::Status {
                state: DeviceState::Full,
                direction: Direction::Ccw,
                sweep: 1,
                ..
            }]
        ));
        // Half-way through the third reading.
        let mut out = Vec::new();
        for _ in 0..4 {
            fw.act(&mut out);
        }
        assert!(out.is_empty());
        assert_eq!(
            command(&mut fw, HostCommand::Stop),
            [
                DeviceMessage::Ack {
                    command: "STOP".into()
                },
                DeviceMessage::SweepEnd { sweep: 1 }
            ]
        );
        assert!(!fw.act(&mut out));
        let angle = *fw.transducer().aims.last().unwrap();
        assert_eq!(
            command(&mut fw, HostCommand::Status),
            [DeviceMessage::Status {
                state: DeviceState::Idle,
                angle_cdeg: (angle * 100.0).round() as i32,
                direction: Direction::Ccw,
                sweep: 1,
            }]
        );
        // Idle time passes only when told; a second STOP is acknowledged and changes nothing.
        let t = fw.now_us();
        fw.idle_until(t + 5_000_000);
        assert_eq!(fw.now_us(), t + 5_000_000);
        assert_eq!(command(&mut fw, HostCommand::Stop).len(), 1);
    }

    #[test]
    fn bad_lines_are_answered_with_errors() {
        let mut fw = firmware();
        let bad_checksum =
            encode_command(&HostCommand::FullScan, PROTOCOL_VERSION).replace("FULL", "FULM");
        let framed = |body: &str| {
            format!(
                "${body}*{:04X}",
                sonar_common::protocol::crc16_ccitt_false(body.as_bytes())
            )
        };
        let mut out = Vec::new();
        for line in [
            bad_checksum,
            "hello".into(),
            framed("FOO"),
            framed("SCAN,LOCAL,300,100"),
        ] {
            fw.handle_line(line.as_bytes(), &mut out);
        }
        let codes: Vec<ErrorCode> = out
            .iter()
            .map(|m| match m {
                DeviceMessage::Error { code, .. } => *code,
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(
            codes,
            [
                ErrorCode::Checksum,
                ErrorCode::Syntax,
                ErrorCode::Syntax,
                ErrorCode::Syntax
            ]
        );
        out.clear();
        fw.handle_overflow(&mut out);
        assert!(matches!(
            out[..],
            [DeviceMessage::Error {
                code: ErrorCode::Syntax,
                ..
            }]
        ));
        assert_eq!(fw.command_counts(), (0, 5));
        assert!(!fw.is_busy());
    }

    fn broken(
        min: Option<SwitchFault>,
        max: Option<SwitchFault>,
    ) -> (Firmware<Probe>, Vec<DeviceMessage>) {
        let mut fw = firmware()
            .speaking(ProtocolVersion::V2, "HEAD-7")
            .with_switch_faults(SwitchFaults { min, max });
        let mut out = Vec::new();
        fw.power_on(&mut out);
        out.remove(0); // the HELLO
        (fw, out)
    }

    fn hardware(text: &str) -> DeviceMessage {
        DeviceMessage::Error {
            code: ErrorCode::Hardware,
            text: text.into(),
        }
    }

    fn fault_status(angle_cdeg: i32, direction: Direction, sweep: u32) -> DeviceMessage {
        DeviceMessage::Status {
            state: DeviceState::Fault,
            angle_cdeg,
            direction,
            sweep,
        }
    }

    /// Stopped on a fault: scans refused, STOP changes nothing, nothing moves, RESET homes.
    fn assert_stopped(fw: &mut Firmware<Probe>) {
        let pings = fw.transducer().aims.len();
        let again = hardware(&fw.fault_text);
        assert!(!fw.fault_text.is_empty());
        for cmd in [
            HostCommand::FullScan,
            HostCommand::LocalScan {
                from_cdeg: -3000,
                to_cdeg: 3000,
            },
        ] {
            assert_eq!(
                command(fw, cmd),
                std::slice::from_ref(&again),
                "the fault again"
            );
        }
        assert_eq!(
            command(fw, HostCommand::Stop),
            [DeviceMessage::Ack {
                command: "STOP".into()
            }]
        );
        assert!(matches!(
            command(fw, HostCommand::Status)[..],
            [DeviceMessage::Status {
                state: DeviceState::Fault,
                ..
            }]
        ));
        assert!(!fw.act(&mut Vec::new()) && !fw.is_busy());
        assert_eq!(fw.transducer().aims.len(), pings);
    }

    #[test]
    fn homing_faults_are_those_the_firmware_meets() {
        let (mut fw, out) = broken(Some(SwitchFault::Dead), None);
        assert_eq!(
            out,
            [
                hardware("MIN switch not found in 315 deg of homing (dead switch? wiring?)"),
                fault_status(-15000, Direction::Cw, 0)
            ]
        );
        assert_stopped(&mut fw);
        let (mut fw, out) = broken(Some(SwitchFault::Stuck), None);
        assert_eq!(
            out[0],
            hardware("MIN switch stuck closed (still closed 30 deg off it)")
        );
        assert_stopped(&mut fw);
        for (min, max) in [
            (None, Some(SwitchFault::Stuck)),
            (Some(SwitchFault::Stuck), Some(SwitchFault::Stuck)),
        ] {
            let (mut fw, out) = broken(min, max);
            let both = out.iter().any(|m| *m == hardware(BOTH_CLOSED));
            // A stuck MIN switch is found leaving it, before MAX is reached.
            assert_eq!(both, min.is_none(), "{out:?}");
            assert_stopped(&mut fw);
        }
        let (_, out) = broken(Some(SwitchFault::Bouncing), Some(SwitchFault::Bouncing));
        assert!(out.is_empty(), "a bouncing switch is debounced: {out:?}");
    }

    #[test]
    fn a_dead_max_switch_stops_the_head_one_and_a_half_degrees_past_its_limit() {
        let (mut fw, _) = broken(None, Some(SwitchFault::Dead));
        command(&mut fw, HostCommand::FullScan);
        let mut out = Vec::new();
        while fw.act(&mut out) {}
        assert_eq!(readings(&out).len(), 50);
        assert_eq!(
            out[out.len() - 3..],
            [
                hardware(
                    "MAX switch open at 15150 cdeg past its limit (dead switch? missed steps?)"
                ),
                DeviceMessage::SweepEnd { sweep: 1 },
                fault_status(15000, Direction::Ccw, 1),
            ]
        );
        assert_eq!(fw.angle_deg(), 151.5, "never further");
        assert_stopped(&mut fw);
        // RESET: acknowledged, homed (the model at once), then a scan runs again from sweep 2.
        assert_eq!(
            command(&mut fw, HostCommand::Reset),
            [
                DeviceMessage::Ack {
                    command: "RESET".into()
                },
                DeviceMessage::LimitHit(Limit::Min)
            ]
        );
        command(&mut fw, HostCommand::FullScan);
        assert!(matches!(
            run(&mut fw, 1)[0],
            DeviceMessage::SweepStart { sweep: 2, .. }
        ));
    }

    #[test]
    fn a_switch_closing_early_stops_the_head_without_correcting() {
        // MAX 5° early: met at +145.5° (half-step grid), 450 cdeg early.
        let (mut fw, _) = broken(None, Some(SwitchFault::Early { deg: 5 }));
        command(&mut fw, HostCommand::FullScan);
        let mut out = Vec::new();
        while fw.act(&mut out) {}
        let n = out.len();
        assert_eq!(
            out[n - 3..],
            [
                hardware(
                    "MAX switch closed at 14550 cdeg: 450 cdeg early (switch moved? missed steps?)"
                ),
                DeviceMessage::SweepEnd { sweep: 1 },
                fault_status(14550, Direction::Ccw, 1),
            ]
        );
        assert!(!out.iter().any(|m| matches!(m, DeviceMessage::LimitHit(_))));
        // The last whole reading is +141°: the one at +147° was cut by the switch.
        assert_eq!(readings(&out).last().map(|r| r.angle_cdeg), Some(14100));
        assert_stopped(&mut fw);

        // A MIN switch 5° early puts home 5° towards MAX: MAX is met as early, as on the hardware.
        let (mut fw, out) = broken(Some(SwitchFault::Early { deg: 5 }), None);
        assert!(out.is_empty());
        command(&mut fw, HostCommand::FullScan);
        let mut out = Vec::new();
        while fw.act(&mut out) {}
        assert!(out.contains(&hardware(
            "MAX switch closed at 14550 cdeg: 450 cdeg early (switch moved? missed steps?)"
        )));
    }

    #[test]
    fn a_switch_within_a_step_of_its_place_is_the_limit() {
        // 1° early: met half a step before +150°, within the 1.5° tolerance.
        let (mut fw, _) = broken(None, Some(SwitchFault::Early { deg: 1 }));
        command(&mut fw, HostCommand::FullScan);
        let msgs = run(&mut fw, 60);
        assert!(
            !msgs
                .iter()
                .any(|m| matches!(m, DeviceMessage::Error { .. }))
        );
        let lim = msgs
            .iter()
            .position(|m| *m == DeviceMessage::LimitHit(Limit::Max))
            .unwrap();
        // The last reading's pings end at +149.25°: the switch at +149.25° ends the sweep there.
        assert_eq!(msgs[lim + 1], DeviceMessage::SweepEnd { sweep: 1 });
        assert!(matches!(
            msgs[lim + 2],
            DeviceMessage::SweepStart {
                sweep: 2,
                direction: Direction::Cw,
                ..
            }
        ));
    }

    #[test]
    fn reset_mid_sweep_ends_it_and_sweep_ids_go_on() {
        let mut fw = firmware();
        command(&mut fw, HostCommand::FullScan);
        run(&mut fw, 10);
        assert_eq!(
            command(&mut fw, HostCommand::Reset),
            [
                DeviceMessage::Ack {
                    command: "RESET".into()
                },
                DeviceMessage::SweepEnd { sweep: 1 },
                DeviceMessage::LimitHit(Limit::Min)
            ]
        );
        assert!(!fw.is_busy());
        command(&mut fw, HostCommand::FullScan);
        assert!(matches!(
            run(&mut fw, 1)[0],
            DeviceMessage::SweepStart { sweep: 2, .. }
        ));
    }
}
