//! A reading's line written on the serial line → the snapshot that contains it visible to a
//! subscriber, through the real `sonar-driver` and `sonar-fusion`.
//!
//! This program plays the sensor head on a pseudo-terminal (protocol version 2: it answers the
//! driver's `HELLO` and `SCAN`, then writes `RD` lines of sweeps of 50 readings), subscribes to
//! `sonar/readings` and `sonar/grid` as any consumer does (a waitset on their wake-up events), and
//! times each `RD` line from just before it is written to the master side until a grid snapshot
//! whose `readings_fused` counts it has been received (its header read). Readings are spaced a
//! little more than the fusion's snapshot interval (`--max-rate 10`, the default) apart, with a
//! random jitter, so each one gets its own snapshot rather than waiting for the pace: the head's own
//! rate is about 4 readings a second.

use std::fs::File;
use std::io::{ErrorKind, Read, Write};
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use iceoryx2::prelude::*;
use sonar_common::ipc::{self as sonar_ipc, IpcError};
use sonar_common::protocol::{
    DeviceMessage, Direction, HostCommand, ProtocolVersion, WireReading, WireScanMode,
    encode_device, parse_command,
};
use sonar_sim::serve::Pty;

use crate::sandbox::{Sandbox, grid_consumer, load_average, quantile, show, wait};

/// Readings per sweep, as the head sends them: centres −147° … 147° in 6° steps.
const SWEEP_READINGS: u32 = 50;
/// Echo time of a range, µs (343 m/s, there and back).
fn echo_us(range_m: f64) -> u32 {
    (range_m * 2.0 / 343.0 * 1e6).round() as u32
}

/// The sensor head's side of the line: replies to the driver and the `RD` lines of the sweeps.
struct Head {
    master: File,
    pending: Vec<u8>,
    readings: u32,
    scanning: bool,
}

impl Head {
    fn new(master: File) -> Self {
        Self {
            master,
            pending: Vec::new(),
            readings: 0,
            scanning: false,
        }
    }

    fn send(&mut self, msg: &DeviceMessage) -> Result<()> {
        self.master
            .write_all(encode_device(msg, ProtocolVersion::V2).as_bytes())
            .context("write to the pseudo-terminal")
    }

    /// Answers every complete command the driver has written.
    fn serve(&mut self) -> Result<()> {
        let mut buf = [0u8; 512];
        loop {
            match self.master.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => self.pending.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.raw_os_error() == Some(nix::libc::EIO) => break, // no host yet
                Err(e) => return Err(e).context("read the pseudo-terminal"),
            }
        }
        while let Some(end) = self.pending.iter().position(|&b| b == b'\n') {
            let line: Vec<u8> = self.pending.drain(..=end).collect();
            let line = line.trim_ascii_end();
            let Ok(command) = parse_command(line, ProtocolVersion::V2) else {
                continue;
            };
            match command {
                HostCommand::Hello { .. } => self.send(&DeviceMessage::Hello {
                    version: 2,
                    firmware: "sonar-bench".into(),
                    head_id: "BENCH-1".into(),
                    step_cdeg: 150,
                    pings_per_reading: 4,
                    min_cdeg: -15000,
                    max_cdeg: 15000,
                })?,
                HostCommand::FullScan | HostCommand::LocalScan { .. } => {
                    self.send(&DeviceMessage::Ack {
                        command: "SCAN".into(),
                    })?;
                    self.scanning = true;
                    self.start_sweep()?;
                }
                HostCommand::Stop => {
                    self.send(&DeviceMessage::Ack {
                        command: "STOP".into(),
                    })?;
                    self.scanning = false;
                }
                // The bench head never faults; a reset stops it, as the firmware's homing does.
                HostCommand::Reset => {
                    self.send(&DeviceMessage::Ack {
                        command: "RESET".into(),
                    })?;
                    self.scanning = false;
                }
                HostCommand::Status => self.send(&DeviceMessage::Status {
                    state: if self.scanning {
                        sonar_common::protocol::DeviceState::Full
                    } else {
                        sonar_common::protocol::DeviceState::Idle
                    },
                    angle_cdeg: 0,
                    direction: Direction::Ccw,
                    sweep: self.sweep(),
                })?,
            }
        }
        Ok(())
    }

    fn sweep(&self) -> u32 {
        self.readings / SWEEP_READINGS
    }

    fn direction(&self) -> Direction {
        if self.sweep().is_multiple_of(2) {
            Direction::Ccw
        } else {
            Direction::Cw
        }
    }

    fn start_sweep(&mut self) -> Result<()> {
        let (from_cdeg, to_cdeg) = match self.direction() {
            Direction::Ccw => (-14700, 14700),
            Direction::Cw => (14700, -14700),
        };
        self.send(&DeviceMessage::SweepStart {
            sweep: self.sweep(),
            direction: self.direction(),
            mode: WireScanMode::Full,
            from_cdeg,
            to_cdeg,
        })
    }

    /// Writes the next `RD` line (and the sweep's end and the next start after its last).
    fn write_reading(&mut self, elapsed_ms: u32) -> Result<()> {
        let index = (self.readings % SWEEP_READINGS) as i32;
        let angle_cdeg = match self.direction() {
            Direction::Ccw => -14700 + 600 * index,
            Direction::Cw => 14700 - 600 * index,
        };
        // A room: walls 1.5–3.5 m away, different at each bearing.
        let range = 1.5 + f64::from((angle_cdeg + 15000) % 2000) / 1000.0;
        let echo = echo_us(range);
        self.send(&DeviceMessage::Reading(WireReading {
            seq: self.readings,
            time_ms: elapsed_ms,
            sweep: self.sweep(),
            direction: self.direction(),
            angle_cdeg,
            ping_count: 4,
            echo_us: [echo, echo + 3, echo, echo + 6, 0, 0, 0, 0],
        }))?;
        self.readings += 1;
        if self.readings.is_multiple_of(SWEEP_READINGS) {
            self.send(&DeviceMessage::SweepEnd {
                sweep: self.sweep() - 1,
            })?;
            self.start_sweep()?;
        }
        Ok(())
    }
}

/// A small deterministic generator for the jitter (xorshift).
fn jitter_ms(state: &mut u64, max: u64) -> u64 {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    *state % (max + 1)
}

/// Measures `readings` readings at `cells`² × `resolution` and prints one table row.
pub fn run(bin_dir: &Path, cells: u32, resolution: f32, readings: usize) -> Result<()> {
    let load_before = load_average();
    let mut sandbox = Sandbox::new("lat", bin_dir)?;
    sandbox.spawn_fusion(cells, resolution)?;
    // The serial line: a raw pseudo-terminal, as `sonar-sim` serves the driver.
    let pty = Pty::open().context("open a pseudo-terminal")?;
    let port = pty.path().to_string_lossy().into_owned();
    sandbox.spawn("sonar-driver", &["--port", &port])?;
    let mut head = Head::new(pty.master().try_clone()?);

    let node = sandbox.node("bench-latency")?;
    let (grid, grid_listener) = grid_consumer(&node)?;
    let readings_sub = sonar_ipc::readings_service(&node)?
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new("create readings subscriber", e))?;
    let readings_listener = sonar_ipc::wakeup_listener(&node, sonar_ipc::READINGS_SERVICE)?;
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| IpcError::new("create waitset", e))?;
    let _g = waitset
        .attach_notification(&grid_listener)
        .map_err(|e| IpcError::new("attach", e))?;
    let _r = waitset
        .attach_notification(&readings_listener)
        .map_err(|e| IpcError::new("attach", e))?;

    // The handshake: until the driver has commanded the scan.
    let deadline = Instant::now() + Duration::from_secs(30);
    while !head.scanning {
        sandbox.check_running()?;
        head.serve()?;
        if Instant::now() > deadline {
            bail!("the driver never commanded a scan");
        }
        std::thread::sleep(Duration::from_millis(5));
    }

    let start = Instant::now();
    let mut fused_seen = 0u64;
    let mut readings_seen = 0u64;
    let (mut to_reading, mut to_snapshot) = (Vec::new(), Vec::new());
    let mut rng = 0x9e37_79b9_7f4a_7c15u64 ^ u64::from(cells);
    let warmup = 10;
    let mut slowest = Vec::new();
    for i in 0..warmup + readings {
        std::thread::sleep(Duration::from_millis(110 + jitter_ms(&mut rng, 40)));
        head.serve()?;
        sandbox.check_running()?;
        let written = Instant::now();
        let elapsed_ms = u32::try_from(start.elapsed().as_millis()).unwrap_or(u32::MAX);
        head.write_reading(elapsed_ms)?;
        let (mut reading_at, mut snapshot_at) = (None, None);
        let deadline = written + Duration::from_secs(5);
        while snapshot_at.is_none() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                bail!("reading {i} never reached a snapshot within 5 s");
            }
            if !wait(&waitset, left)? {
                bail!("interrupted");
            }
            let _ = grid_listener.try_wait(|_| {});
            let _ = readings_listener.try_wait(|_| {});
            while let Some(sample) = readings_sub
                .receive()
                .map_err(|e| IpcError::new("receive reading", e))?
            {
                readings_seen += 1;
                drop(sample);
                if readings_seen == i as u64 + 1 && reading_at.is_none() {
                    reading_at = Some(written.elapsed());
                }
            }
            while let Some(sample) = grid
                .receive()
                .map_err(|e| IpcError::new("receive grid", e))?
            {
                fused_seen = fused_seen.max(sample.user_header().readings_fused);
            }
            if fused_seen > i as u64 {
                snapshot_at = Some(written.elapsed());
            }
        }
        if i >= warmup {
            if let Some(t) = snapshot_at {
                slowest.push((t, i));
            }
            to_snapshot.extend(snapshot_at);
            to_reading.extend(reading_at);
        }
    }
    let load_after = load_average();
    println!(
        "| {cells}² × {} cm | {} | {} / {} | {} | {} / {} | {} | {load_before} → {load_after} |",
        (resolution * 100.0).round(),
        to_snapshot.len(),
        show(quantile(&to_snapshot, 0.5)),
        show(quantile(&to_snapshot, 0.99)),
        show(quantile(&to_snapshot, 1.0)),
        show(quantile(&to_reading, 0.5)),
        show(quantile(&to_reading, 0.99)),
        show(quantile(&to_reading, 1.0)),
    );
    // Which readings made the tail, by their place in the sweep: a sweep's last reading carries
    // the sweep's end (its regions placed, its features), the first the next sweep's start.
    slowest.sort_by(|a, b| b.cmp(a));
    let tail: Vec<String> = slowest
        .iter()
        .take(5)
        .map(|(t, i)| {
            format!(
                "{} (reading {} of its sweep)",
                show(*t),
                *i as u32 % SWEEP_READINGS + 1
            )
        })
        .collect();
    eprintln!("{cells}² slowest to a snapshot: {}", tail.join(", "));
    Ok(())
}

/// The table's header.
pub fn print_header() {
    println!(
        "| grid | readings | line → snapshot visible p50 / p99 | max | line → reading visible p50 / p99 | max | load average before → after |"
    );
    println!("|---|--:|--:|--:|--:|--:|---|");
}
