//! The device behind a pseudo-terminal: the only part of the crate that does I/O.
//!
//! [`serve`] runs one loop on one thread: perform the device's next action (a motor step or a ping)
//! on the simulated clock, wait until that moment in wall time (simulated time / speed factor) while
//! gathering what the host sends, write what the action produced, then obey the commands received
//! meanwhile — as the PIC's main loop would, after the current step or ping. Waiting is done in
//! `poll` on the master, so input, pacing and the stop flag (set by a signal handler) share one
//! wait.
//!
//! With a robot ([`Carrier`]), the robot is moved to the device's clock before each action, so the
//! action's pings are taken from the pose of their instant, and it hears when sweeps begin and end
//! (a stop-and-scan robot waits for them). Its poses are stamped with the host time at which their
//! simulated instant happens, the clock the driver stamps readings with.
//!
//! With `--faults`, every line goes through a [`FaultInjector`] on its way out (and the host's bytes
//! past it on their way in), which damages lines, resets the device and keeps it silent at the times
//! it is told.
//!
//! Writes never block the loop for long: when the terminal's buffer is full (nobody reads the
//! slave), a line waits up to [`WRITE_PATIENCE`] for room and is then dropped and counted, as bytes
//! sent by a UART with no listener are lost. At `--speed max` that wait is the back-pressure that
//! keeps a slow reader from losing lines.

use std::fs::File;
use std::io::{self, ErrorKind, Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nix::errno::Errno;
use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::openpty;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use sonar_common::ipc::unix_time_ns;
use sonar_common::protocol::{DeviceMessage, FramedLine, LineFramer, Terminators, encode_device};
use tracing::{debug, info, warn};

use crate::faults::FaultInjector;
use crate::firmware::{Firmware, Transducer};
use crate::geometry::Pose;
use crate::hobby::HobbySketch;

/// How long a line may wait for room in the terminal's buffer before it is dropped.
pub const WRITE_PATIENCE: Duration = Duration::from_millis(200);
/// Longest wait of an idle device with a robot or faults: the robot moves and the faults come on
/// the device's clock, which only the loop advances. (The stop flag needs no poll: its signal
/// ends the wait.)
const IDLE_POLL: Duration = Duration::from_millis(100);
/// Longest wait of an idle device with nothing else to do: it answers the host as soon as a
/// command comes, so this only bounds how stale its clock may get.
const IDLE_WAIT: Duration = Duration::from_secs(1);
/// Falling further behind wall time than this (a stalled reader) restarts the pacing rather than
/// rushing to catch up.
const MAX_LAG: Duration = Duration::from_secs(1);

/// A pseudo-terminal whose slave plays the serial port.
#[derive(Debug)]
pub struct Pty {
    master: File,
    /// Held open so that the master never reads EIO while no host has the slave open (between a
    /// driver's close and reopen).
    _slave: OwnedFd,
    path: PathBuf,
}

impl Pty {
    /// Opens a pseudo-terminal with its slave in raw mode (no echo, no line editing, 8-bit clean,
    /// like a serial port) and its master non-blocking.
    pub fn open() -> io::Result<Self> {
        let pty = openpty(None, None)?;
        let mut tio = tcgetattr(&pty.slave)?;
        cfmakeraw(&mut tio);
        tcsetattr(&pty.slave, SetArg::TCSANOW, &tio)?;
        let path = nix::unistd::ttyname(&pty.slave)?;
        let flags = OFlag::from_bits_truncate(fcntl(&pty.master, FcntlArg::F_GETFL)?);
        fcntl(&pty.master, FcntlArg::F_SETFL(flags | OFlag::O_NONBLOCK))?;
        Ok(Self {
            master: File::from(pty.master),
            _slave: pty.slave,
            path,
        })
    }

    /// Path of the slave, e.g. `/dev/pts/3`: the "serial port" to give the driver.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The master side (non-blocking): what the device reads the host's bytes from and writes its
    /// own to. For devices served by another loop, such as the firmware-in-the-loop simulator.
    pub fn master(&self) -> &File {
        &self.master
    }
}

/// How fast simulated time runs against wall time (`Max`: as fast as the host reads).
pub use sonar_common::speed::Speed;

/// Something that talks over the line: the native firmware or the hobby sketch.
pub trait Device {
    /// What it prints when powered on (complete lines).
    fn power_on(&mut self, out: &mut Vec<String>);
    /// Bytes from the host; appends the replies (complete lines).
    fn receive(&mut self, bytes: &[u8], out: &mut Vec<String>);
    /// Performs the next timed action and appends what it prints; false when idle.
    fn act(&mut self, out: &mut Vec<String>) -> bool;
    /// Reboots (power cycle, reset button, watchdog); appends what it prints when it comes up.
    fn reset(&mut self, out: &mut Vec<String>);
    /// Simulated time, µs.
    fn now_us(&self) -> u64;
    /// Lets simulated time pass while idle.
    fn idle_until(&mut self, t_us: u64);
    /// What it did, for the log.
    fn summary(&self) -> String;
    /// Places the sensor for the actions that follow: the robot carrying the head moved.
    fn set_pose(&mut self, pose: Pose);
    /// Sweeps begun and ended so far.
    fn sweeps(&self) -> SweepCounts;
}

/// Sweeps a device has begun and ended since it was made (across resets).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SweepCounts {
    pub started: u64,
    pub ended: u64,
}

/// What moves on the simulated clock besides the head: the robot carrying it.
pub trait Carrier {
    /// Moves to simulated time `now_us` and returns the sensor's pose there. `unix_ns` gives the
    /// host's Unix-epoch time of a simulated instant up to `now_us`, to stamp what is published.
    fn advance(&mut self, now_us: u64, unix_ns: &dyn Fn(u64) -> u64) -> io::Result<Pose>;
    /// The head began a sweep.
    fn sweep_started(&mut self);
    /// The head ended a sweep at simulated time `now_us`.
    fn sweep_ended(&mut self, now_us: u64);
}

/// Our firmware behind its UART: cuts the byte stream into lines, encodes the messages.
#[derive(Debug)]
pub struct NativeDevice<T> {
    firmware: Firmware<T>,
    framer: LineFramer,
    msgs: Vec<DeviceMessage>,
    sweeps: SweepCounts,
}

impl<T: Transducer> NativeDevice<T> {
    pub fn new(firmware: Firmware<T>) -> Self {
        Self {
            firmware,
            framer: LineFramer::new(Terminators::Newline),
            msgs: Vec::new(),
            sweeps: SweepCounts::default(),
        }
    }

    fn flush(&mut self, out: &mut Vec<String>) {
        let version = self.firmware.version();
        for m in &self.msgs {
            match m {
                DeviceMessage::SweepStart { .. } => self.sweeps.started += 1,
                DeviceMessage::SweepEnd { .. } => self.sweeps.ended += 1,
                _ => {}
            }
        }
        out.extend(self.msgs.drain(..).map(|m| encode_device(&m, version)));
    }
}

impl<T: Transducer> Device for NativeDevice<T> {
    fn power_on(&mut self, out: &mut Vec<String>) {
        self.firmware.power_on(&mut self.msgs);
        self.flush(out);
    }

    fn receive(&mut self, bytes: &[u8], out: &mut Vec<String>) {
        let Self {
            firmware,
            framer,
            msgs,
            ..
        } = self;
        framer.push(bytes, |line| match line {
            FramedLine::Line(l) => {
                debug!(line = %String::from_utf8_lossy(l), "host line");
                firmware.handle_line(l, msgs);
            }
            FramedLine::Overflow => firmware.handle_overflow(msgs),
        });
        self.flush(out);
    }

    fn act(&mut self, out: &mut Vec<String>) -> bool {
        let busy = self.firmware.act(&mut self.msgs);
        self.flush(out);
        busy
    }

    fn reset(&mut self, out: &mut Vec<String>) {
        // A half-received command is lost with the UART's buffer.
        self.framer = LineFramer::new(Terminators::Newline);
        self.firmware.reset(&mut self.msgs);
        self.flush(out);
    }

    fn now_us(&self) -> u64 {
        self.firmware.now_us()
    }

    fn idle_until(&mut self, t_us: u64) {
        self.firmware.idle_until(t_us);
    }

    fn summary(&self) -> String {
        let (commands, rejected) = self.firmware.command_counts();
        format!(
            "{commands} commands, {rejected} lines rejected, {} readings",
            self.firmware.readings()
        )
    }

    fn set_pose(&mut self, pose: Pose) {
        self.firmware.transducer_mut().set_pose(pose);
    }

    fn sweeps(&self) -> SweepCounts {
        self.sweeps
    }
}

impl<T: Transducer> Device for HobbySketch<T> {
    fn power_on(&mut self, _out: &mut Vec<String>) {}

    fn receive(&mut self, bytes: &[u8], _out: &mut Vec<String>) {
        debug!(bytes = bytes.len(), "the hobby sketch reads no input");
    }

    fn act(&mut self, out: &mut Vec<String>) -> bool {
        out.push(self.step());
        true
    }

    fn reset(&mut self, _out: &mut Vec<String>) {
        HobbySketch::reset(self);
    }

    fn now_us(&self) -> u64 {
        HobbySketch::now_us(self)
    }

    fn idle_until(&mut self, _t_us: u64) {}

    fn summary(&self) -> String {
        format!("{} records", self.records())
    }

    fn set_pose(&mut self, pose: Pose) {
        self.transducer_mut().set_pose(pose);
    }

    fn sweeps(&self) -> SweepCounts {
        // The sketch always sweeps: the next pass begins as one ends.
        SweepCounts {
            started: self.passes() + 1,
            ended: self.passes(),
        }
    }
}

/// Counters of the line.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServeStats {
    pub bytes_received: u64,
    pub lines_written: u64,
    pub lines_dropped: u64,
}

/// Maps simulated time to wall time.
#[derive(Debug)]
struct Pacer {
    speed: Speed,
    wall0: Instant,
    /// `wall0` on the host's Unix-epoch clock, ns.
    unix0_ns: u64,
    sim0_us: u64,
}

impl Pacer {
    /// When simulated time `sim_us` happens in wall time.
    fn wall_at(&mut self, sim_us: u64) -> Instant {
        let now = Instant::now();
        let Speed::Factor(f) = self.speed else {
            return now;
        };
        let due = self.wall0
            + Duration::from_secs_f64(sim_us.saturating_sub(self.sim0_us) as f64 / 1e6 / f);
        if now > due + MAX_LAG {
            self.wall0 = now;
            self.unix0_ns = unix_time_ns();
            self.sim0_us = sim_us;
            now
        } else {
            due
        }
    }

    /// The host's Unix-epoch time, ns, at which simulated time `sim_us` happens (now, at `max`).
    fn unix_ns_at(&self, sim_us: u64) -> u64 {
        let Speed::Factor(f) = self.speed else {
            return unix_time_ns();
        };
        let sim_ns = (i128::from(sim_us) - i128::from(self.sim0_us)) * 1000;
        let stamp = i128::from(self.unix0_ns) + (sim_ns as f64 / f) as i128;
        u64::try_from(stamp.max(0)).unwrap_or(u64::MAX)
    }

    /// Simulated time now, for an idle device whose clock stands at `current_us`.
    fn sim_now(&self, current_us: u64) -> u64 {
        match self.speed {
            Speed::Max => current_us,
            Speed::Factor(f) => {
                let elapsed = self.wall0.elapsed().as_secs_f64() * f * 1e6;
                current_us.max(self.sim0_us + elapsed as u64)
            }
        }
    }
}

/// The master side of the terminal with its counters.
struct Line<'a> {
    master: &'a File,
    stats: ServeStats,
    /// Lines are being dropped (nobody reads); logged once per episode.
    dropping: bool,
}

fn poll_timeout(wait: Duration) -> PollTimeout {
    let ms = wait.as_micros().div_ceil(1000);
    PollTimeout::from(u16::try_from(ms).unwrap_or(u16::MAX))
}

impl Line<'_> {
    /// Waits up to `wait` for input and appends all there is; true if anything came.
    fn read_into(&mut self, buf: &mut Vec<u8>, wait: Duration) -> io::Result<bool> {
        let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLIN)];
        match poll(&mut fds, poll_timeout(wait)) {
            Ok(0) | Err(Errno::EINTR) => return Ok(false),
            Ok(_) => {}
            Err(e) => return Err(e.into()),
        }
        let before = buf.len();
        let mut chunk = [0u8; 1024];
        loop {
            match (&*self.master).read(&mut chunk) {
                Ok(0) => break,
                Ok(n) => buf.extend_from_slice(&chunk[..n]),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        self.stats.bytes_received += (buf.len() - before) as u64;
        Ok(buf.len() > before)
    }

    /// Writes the bytes of one line, or drops the rest after [`WRITE_PATIENCE`] without room;
    /// returns how many were written.
    fn write_line(&mut self, line: &[u8]) -> io::Result<usize> {
        let deadline = Instant::now() + WRITE_PATIENCE;
        let mut rest = line;
        while !rest.is_empty() {
            match (&*self.master).write(rest) {
                Ok(n) => rest = &rest[n..],
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    let wait = deadline.saturating_duration_since(Instant::now());
                    if wait.is_zero() {
                        self.stats.lines_dropped += 1;
                        if !self.dropping {
                            warn!("nobody reads the port: dropping lines");
                            self.dropping = true;
                        }
                        return Ok(line.len() - rest.len());
                    }
                    let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLOUT)];
                    match poll(&mut fds, poll_timeout(wait)) {
                        Ok(_) | Err(Errno::EINTR) => {}
                        Err(e) => return Err(e.into()),
                    }
                }
                Err(e) => return Err(e),
            }
        }
        if self.dropping {
            info!(dropped = self.stats.lines_dropped, "the port is read again");
            self.dropping = false;
        }
        self.stats.lines_written += 1;
        Ok(line.len())
    }

    /// Writes what the device printed at simulated time `now_us`, through the faults if any.
    fn send(
        &mut self,
        lines: &[String],
        faults: Option<&mut FaultInjector>,
        now_us: u64,
    ) -> io::Result<()> {
        match faults {
            None => lines
                .iter()
                .try_for_each(|l| self.write_line(l.as_bytes()).map(drop)),
            Some(faults) => lines.iter().try_for_each(|l| {
                faults.send(l.as_bytes(), now_us, |bytes| self.write_line(bytes))
            }),
        }
    }
}

/// Tells `carrier` the sweeps the device began and ended since `seen`: ends first, as a device
/// ends a sweep before it begins the next. [`serve`] calls it after every action and every
/// command; a host that drives a device without a terminal (the evaluation) does the same.
pub fn report_sweeps<'c>(
    device: &dyn Device,
    carrier: Option<&mut (dyn Carrier + 'c)>,
    seen: &mut SweepCounts,
) {
    let now = device.sweeps();
    if let Some(c) = carrier {
        if now.ended > seen.ended {
            c.sweep_ended(device.now_us());
        }
        if now.started > seen.started {
            c.sweep_started();
        }
    }
    *seen = now;
}

/// One action of `device` riding `carrier`, as [`serve`] performs each: the carrier moved to the
/// device's clock and the sensor placed at its pose (so the action's pings are taken from there),
/// the action (its lines appended to `out`), then the sweeps it began and ended reported to the
/// carrier. `unix_ns` stamps the carrier's poses ([`Carrier::advance`]). `false` when idle.
pub fn act_carried<'c>(
    device: &mut dyn Device,
    mut carrier: Option<&mut (dyn Carrier + 'c)>,
    unix_ns: &dyn Fn(u64) -> u64,
    seen: &mut SweepCounts,
    out: &mut Vec<String>,
) -> io::Result<bool> {
    if let Some(c) = carrier.as_deref_mut() {
        let pose = c.advance(device.now_us(), unix_ns)?;
        device.set_pose(pose);
    }
    let busy = device.act(out);
    report_sweeps(device, carrier, seen);
    Ok(busy)
}

/// Serves `device` on `pty` until `stop` is set, its lines damaged, and the device reset and
/// silenced, as `faults` say; the head rides on `carrier` if given.
pub fn serve(
    pty: &Pty,
    device: &mut dyn Device,
    speed: Speed,
    stop: &AtomicBool,
    mut faults: Option<&mut FaultInjector>,
    mut carrier: Option<&mut dyn Carrier>,
) -> io::Result<ServeStats> {
    let mut line = Line {
        master: &pty.master,
        stats: ServeStats::default(),
        dropping: false,
    };
    let mut pacer = Pacer {
        speed,
        wall0: Instant::now(),
        unix0_ns: unix_time_ns(),
        sim0_us: device.now_us(),
    };
    let mut out = Vec::new();
    device.power_on(&mut out);
    line.send(&out, faults.as_deref_mut(), device.now_us())?;
    let mut input = Vec::new();
    let mut sweeps = device.sweeps();
    while !stop.load(Ordering::Relaxed) {
        if let Some(f) = faults.as_deref_mut()
            && f.advance(device.now_us())?
        {
            out.clear();
            device.reset(&mut out);
            line.send(&out, Some(f), device.now_us())?;
        }
        out.clear();
        let busy = act_carried(
            device,
            carrier.as_deref_mut(),
            &|t| pacer.unix_ns_at(t),
            &mut sweeps,
            &mut out,
        )?;
        let due = if busy {
            pacer.wall_at(device.now_us())
        } else if carrier.is_some() || faults.is_some() {
            Instant::now() + IDLE_POLL
        } else {
            Instant::now() + IDLE_WAIT
        };
        // Until the action is over in wall time, gather what the host sends; an idle device
        // answers at once.
        input.clear();
        loop {
            let got = line.read_into(&mut input, due.saturating_duration_since(Instant::now()))?;
            if stop.load(Ordering::Relaxed) || Instant::now() >= due || (got && !busy) {
                break;
            }
        }
        line.send(&out, faults.as_deref_mut(), device.now_us())?;
        if !busy {
            device.idle_until(pacer.sim_now(device.now_us()));
        }
        let heard = match faults.as_deref_mut() {
            _ if input.is_empty() => false,
            Some(f) => f.hears(&input, device.now_us())?,
            None => true,
        };
        if heard {
            out.clear();
            device.receive(&input, &mut out);
            report_sweeps(device, carrier.as_deref_mut(), &mut sweeps);
            line.send(&out, faults.as_deref_mut(), device.now_us())?;
        }
    }
    if let Some(f) = faults {
        f.flush()?;
    }
    Ok(line.stats)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pacing_maps_simulated_to_wall_time() {
        // Anchored in the future, so no lag can have built up whatever the scheduler does.
        let wall0 = Instant::now() + Duration::from_secs(3600);
        let mut pacer = Pacer {
            speed: Speed::Factor(10.0),
            wall0,
            unix0_ns: 1_000_000_000,
            sim0_us: 1_000_000,
        };
        assert_eq!(pacer.wall_at(1_500_000) - wall0, Duration::from_millis(50));
        assert_eq!(pacer.sim_now(0), 1_000_000);
        // Stamps: 0.5 s of simulated time is 50 ms of host time at 10×.
        assert_eq!(pacer.unix_ns_at(1_000_000), 1_000_000_000);
        assert_eq!(pacer.unix_ns_at(1_500_000), 1_050_000_000);
        assert_eq!(pacer.unix_ns_at(500_000), 950_000_000);
        assert_eq!(pacer.sim_now(2_000_000), 2_000_000);
        assert_eq!(
            poll_timeout(Duration::from_micros(1)),
            PollTimeout::from(1u16)
        );
    }
}
