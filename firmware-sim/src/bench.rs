//! The test bench: the chip in simavr, the head around it, the serial line to the pseudo-terminal,
//! on one thread, paced by the chip's cycle counter.
//!
//! Each turn runs the chip to the earliest of: the next edge the head drives (an ECHO edge, a
//! switch bounce), the next look at the serial line (every [`LINE_PERIOD_US`] of emulated time),
//! or a change of a port the head watches (the chip stops there by itself). Then it gives the
//! port changes to the head, drives the edges due, and on line turns moves bytes both ways and
//! sleeps if emulated time runs ahead of wall time × speed.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use sonar_common::speed::Speed;
use sonar_sim::{Pty, Transducer};

use crate::head::{Head, HeadStats};
use crate::headid::HeadId;
use crate::serial::LineStats;

/// Emulated time between two looks at the serial line: 100 µs, about one byte at 115200 baud.
pub const LINE_PERIOD_US: u64 = 100;

/// What the bench runs.
#[derive(Debug, Clone)]
pub struct BenchConfig {
    /// The firmware ELF.
    pub firmware: PathBuf,
    /// Written into the EEPROM before the first instruction; `None` leaves it blank (0xFF).
    pub head_id: Option<HeadId>,
    pub speed: Speed,
}

/// The signals the bench obeys, set from signal handlers.
#[derive(Debug, Default, Clone)]
pub struct Signals {
    /// Stop and return.
    pub stop: Arc<AtomicBool>,
    /// Press the reset button (cleared when done).
    pub reset: Arc<AtomicBool>,
}

/// How the run ended.
#[derive(Debug, Clone, PartialEq)]
pub enum End {
    /// Asked to stop.
    Stopped,
    /// The firmware stopped running: crashed, or asleep with interrupts off.
    Died { state: String, pc: u32 },
}

/// What the bench did.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    pub end: End,
    pub emulated: Duration,
    pub wall: Duration,
    pub head: HeadStats,
    pub line: LineStats,
    /// Resets after power-on (reset button, watchdog).
    pub resets: u32,
    /// The head id in the EEPROM at the end, if its record is valid.
    pub head_id: Option<HeadId>,
}

impl Summary {
    /// Emulated seconds per wall second.
    pub fn real_time_factor(&self) -> f64 {
        self.emulated.as_secs_f64() / self.wall.as_secs_f64().max(1e-9)
    }
}

/// Why the bench could not run.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(
        "built without simavr: apt-get install simavr libsimavr-dev libelf-dev, then cargo build again"
    )]
    NoSimavr,
    #[cfg(simavr)]
    #[error(transparent)]
    Chip(#[from] crate::avr::ChipError),
    #[error("the serial line: {0}")]
    Io(#[from] std::io::Error),
}

/// Whether this build has simavr.
pub const WITH_SIMAVR: bool = cfg!(simavr);

/// Runs `cfg.firmware` with `head` around it, its UART0 on `pty`, until `signals.stop` is set or the
/// firmware dies.
#[cfg(not(simavr))]
pub fn run<T: Transducer>(
    _cfg: &BenchConfig,
    _head: &mut Head<T>,
    _pty: &Pty,
    _signals: &Signals,
) -> Result<Summary, BenchError> {
    Err(BenchError::NoSimavr)
}

/// Runs `cfg.firmware` with `head` around it, its UART0 on `pty`, until `signals.stop` is set or the
/// firmware dies.
#[cfg(simavr)]
pub fn run<T: Transducer>(
    cfg: &BenchConfig,
    head: &mut Head<T>,
    pty: &Pty,
    signals: &Signals,
) -> Result<Summary, BenchError> {
    use std::sync::atomic::Ordering;
    use std::time::Instant;

    use tracing::{error, info, warn};

    use crate::avr::{Chip, CpuState, PortEvent};
    use crate::headid::RECORD_LEN;
    use crate::pacing::Pacer;
    use crate::pins::{CYCLES_PER_US, Port};
    use crate::serial::SerialLine;

    /// Moves what the firmware sent into the line's queue for the terminal.
    fn uart_to_line(chip: &mut Chip, line: &mut SerialLine<'_>) {
        let mut buf = [0u8; 256];
        loop {
            let n = chip.take_uart(&mut buf);
            if n == 0 {
                break;
            }
            line.send_to_host(&buf[..n]);
        }
    }

    let mut chip = Chip::load(&cfg.firmware)?;
    if let Some(id) = cfg.head_id {
        chip.eeprom_write(0, &id.record())?;
    }
    chip.watch(Port::B)?;
    chip.watch(Port::D)?;
    if head.wants_oc1b() {
        chip.watch_oc1b()?;
    }
    for (pin, high) in head.input_levels() {
        chip.drive(pin, high)?;
    }
    let mut line = SerialLine::new(pty);
    let wall0 = Instant::now();
    let mut pacer = Pacer::new(cfg.speed, wall0, chip.cycle());
    let mut next_line = chip.cycle();
    let mut resets = chip.resets();
    let power_on_resets = resets;
    let mut due = Vec::new();
    let end = loop {
        if signals.stop.load(Ordering::Relaxed) {
            break End::Stopped;
        }
        if signals.reset.swap(false, Ordering::Relaxed) {
            info!(
                emulated_s = chip.cycle() as f64 / f64::from(crate::pins::CLOCK_HZ),
                "reset button pressed (SIGUSR1)"
            );
            chip.reset();
            resets = chip.resets();
        }
        let until = head.next_edge_at().map_or(next_line, |t| t.min(next_line));
        let state = chip.run_until(until);
        if !state.is_alive() {
            let pc = chip.pc();
            error!(
                ?state,
                pc = format_args!("{pc:#06x}"),
                "the firmware stopped running"
            );
            break End::Died {
                state: match state {
                    CpuState::Done => "asleep with interrupts off".to_owned(),
                    CpuState::Crashed => "crashed".to_owned(),
                    other => format!("{other:?}"),
                },
                pc,
            };
        }
        if chip.resets() != resets {
            resets = chip.resets();
            warn!("the chip reset itself (watchdog)");
        }
        while let Some(ev) = chip.next_event() {
            match ev {
                PortEvent::Port {
                    cycle,
                    port,
                    levels,
                } => head.on_port(port, levels, cycle),
                PortEvent::Pulse {
                    cycle,
                    pin,
                    width_cycles,
                } => head.on_pulse(pin, width_cycles, cycle),
            }
        }
        let now = chip.cycle();
        due.clear();
        head.take_due(now, &mut due);
        for edge in &due {
            chip.drive(edge.pin, edge.high)?;
        }
        if now >= next_line {
            next_line = now + LINE_PERIOD_US * CYCLES_PER_US;
            uart_to_line(&mut chip, &mut line);
            line.read_host()?;
            while chip.uart_ready() {
                let Some(byte) = line.next_for_chip() else {
                    break;
                };
                chip.uart_send(byte);
            }
            let wall = Instant::now();
            if line.has_output() {
                line.flush(wall)?;
            }
            if let Some(ahead) = pacer.ahead(now, wall) {
                std::thread::sleep(ahead);
            }
        }
    };
    // What the firmware sent last, for a host still reading.
    uart_to_line(&mut chip, &mut line);
    line.flush(Instant::now())?;
    let (lost_events, lost_bytes) = chip.lost();
    if lost_events + lost_bytes > 0 {
        warn!(lost_events, lost_bytes, "the shim's queues overflowed");
    }
    let mut record = [0u8; RECORD_LEN];
    chip.eeprom_read(0, &mut record)?;
    Ok(Summary {
        end,
        emulated: Duration::from_nanos(chip.cycle() * 1000 / CYCLES_PER_US),
        wall: wall0.elapsed(),
        head: head.stats(),
        line: line.stats(),
        resets: chip.resets() - power_on_resets,
        head_id: HeadId::from_record(&record),
    })
}
