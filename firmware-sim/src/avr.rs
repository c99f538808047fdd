//! The emulated ATmega328P: simavr through the C shim `src/board.c`. The only unsafe code of the
//! crate is here, behind [`Chip`].

use std::ffi::{CStr, CString, c_char, c_int};
use std::marker::{PhantomData, PhantomPinned};
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};
use std::ptr::NonNull;
use std::sync::Once;

use crate::pins::{CLOCK_HZ, Pin, Port};

/// `board_t` of the shim, opaque.
#[repr(C)]
struct RawBoard {
    _opaque: [u8; 0],
    _marker: PhantomData<(*mut u8, PhantomPinned)>,
}

/// `board_event_t` of the shim.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
struct RawEvent {
    cycle: u64,
    port: c_char,
    value: u8,
    pin: u8,
    width: u32,
}

/// `BOARD_WHOLE_PORT`: a [`RawEvent`] of a whole port.
const WHOLE_PORT: u8 = 0xFF;

unsafe extern "C" {
    fn board_new(
        elf_path: *const c_char,
        frequency: u32,
        err: *mut c_char,
        err_len: usize,
    ) -> *mut RawBoard;
    fn board_free(b: *mut RawBoard);
    fn board_cycle(b: *const RawBoard) -> u64;
    fn board_pc(b: *const RawBoard) -> u32;
    fn board_resets(b: *const RawBoard) -> u32;
    fn board_run_until(b: *mut RawBoard, until: u64) -> c_int;
    fn board_watch_port(b: *mut RawBoard, port: c_char) -> c_int;
    fn board_watch_oc1b(b: *mut RawBoard) -> c_int;
    fn board_next_event(b: *mut RawBoard, out: *mut RawEvent) -> c_int;
    fn board_drive_pin(b: *mut RawBoard, port: c_char, pin: u8, level: c_int) -> c_int;
    fn board_uart_take(b: *mut RawBoard, buf: *mut u8, cap: usize) -> usize;
    fn board_uart_ready(b: *const RawBoard) -> c_int;
    fn board_uart_send(b: *mut RawBoard, byte: u8);
    fn board_reset(b: *mut RawBoard);
    fn board_eeprom_write(b: *mut RawBoard, offset: u16, data: *const u8, len: u32) -> c_int;
    fn board_eeprom_read(b: *mut RawBoard, offset: u16, data: *mut u8, len: u32) -> c_int;
    fn board_lost(b: *const RawBoard, events: *mut u64, uart_bytes: *mut u64);
    fn board_set_logger(cb: Option<unsafe extern "C" fn(level: c_int, msg: *const c_char)>);
}

/// What the core is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CpuState {
    Running,
    /// In a `sleep` instruction, until an interrupt.
    Sleeping,
    /// Asleep with interrupts off: the firmware stopped for good.
    Done,
    /// Invalid opcode, jump outside the code, stack overflow…
    Crashed,
    /// A state the run loop never asks for (limbo, stopped, debugger steps).
    Other,
}

impl CpuState {
    fn from_raw(state: c_int) -> Self {
        match state {
            0 => CpuState::Running,
            1 => CpuState::Sleeping,
            2 => CpuState::Done,
            3 => CpuState::Crashed,
            _ => CpuState::Other,
        }
    }

    /// Whether the firmware still runs.
    pub fn is_alive(self) -> bool {
        matches!(self, CpuState::Running | CpuState::Sleeping)
    }
}

/// A port's pin levels changed (an output written, a direction changed, a reset), or a PWM pulse
/// on a pin ended ([`Chip::watch_oc1b`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PortEvent {
    Port {
        cycle: u64,
        port: Port,
        levels: u8,
    },
    Pulse {
        /// When it ended.
        cycle: u64,
        pin: Pin,
        width_cycles: u32,
    },
}

/// What went wrong with the chip.
#[derive(Debug, thiserror::Error)]
pub enum ChipError {
    #[error("{0}")]
    Load(String),
    #[error("the firmware path {} contains a NUL byte", .0.display())]
    Path(PathBuf),
    #[error("simavr has no {0}")]
    NoPin(Pin),
    #[error("simavr has no port {0}")]
    NoPort(char),
    #[error("EEPROM bytes {offset}..{end} lie outside the chip's 1 KiB")]
    Eeprom { offset: u16, end: usize },
}

/// An ATmega328P at 16 MHz running a firmware ELF in simavr.
#[derive(Debug)]
pub struct Chip {
    raw: NonNull<RawBoard>,
}

/// simavr's log lines, to `tracing`.
unsafe extern "C" fn log_line(level: c_int, msg: *const c_char) {
    if msg.is_null() {
        return;
    }
    // SAFETY: the shim passes a NUL-terminated buffer that lives for the duration of the call.
    let msg = unsafe { CStr::from_ptr(msg) }.to_string_lossy();
    // simavr's levels: 1 output, 2 error, 3 warning (traces are not forwarded).
    if level <= 2 {
        tracing::error!(target: "simavr", "{msg}");
    } else {
        tracing::warn!(target: "simavr", "{msg}");
    }
}

fn c_char_of(letter: char) -> c_char {
    // Port letters are ASCII.
    letter as u8 as c_char
}

impl Chip {
    /// Makes the chip and loads `elf` into its flash (and EEPROM, if the ELF has an `.eeprom`
    /// section); the chip is at cycle 0, about to run the reset vector.
    pub fn load(elf: &Path) -> Result<Self, ChipError> {
        static LOGGER: Once = Once::new();
        // SAFETY: `log_line` has the signature the shim calls, and stays valid for the process.
        LOGGER.call_once(|| unsafe { board_set_logger(Some(log_line)) });
        let path = CString::new(elf.as_os_str().as_bytes())
            .map_err(|_| ChipError::Path(elf.to_owned()))?;
        let mut err = [0 as c_char; 512];
        // SAFETY: `path` is NUL-terminated and `err` writable for its length; both outlive the call.
        let raw = unsafe { board_new(path.as_ptr(), CLOCK_HZ, err.as_mut_ptr(), err.len()) };
        match NonNull::new(raw) {
            Some(raw) => Ok(Self { raw }),
            None => {
                // SAFETY: the shim wrote a NUL-terminated message into `err` (vsnprintf), or left
                // it zeroed, which is an empty string.
                let msg = unsafe { CStr::from_ptr(err.as_ptr()) };
                Err(ChipError::Load(msg.to_string_lossy().into_owned()))
            }
        }
    }

    /// The cycle counter: emulated time at 16 MHz.
    pub fn cycle(&self) -> u64 {
        // SAFETY: `raw` is a live board for the lifetime of `self`.
        unsafe { board_cycle(self.raw.as_ptr()) }
    }

    /// The program counter (byte address).
    pub fn pc(&self) -> u32 {
        // SAFETY: as in `cycle`.
        unsafe { board_pc(self.raw.as_ptr()) }
    }

    /// Resets so far, of any cause (power-on, reset button, watchdog).
    pub fn resets(&self) -> u32 {
        // SAFETY: as in `cycle`.
        unsafe { board_resets(self.raw.as_ptr()) }
    }

    /// Runs until cycle `until`, until a watched port changes (see [`Chip::next_event`]), or
    /// until the core stops; returns its state.
    pub fn run_until(&mut self, until: u64) -> CpuState {
        // SAFETY: `raw` is live and only this thread uses it (`&mut self`).
        CpuState::from_raw(unsafe { board_run_until(self.raw.as_ptr(), until) })
    }

    /// Reports every change of `port`'s levels as a [`PortEvent`].
    pub fn watch(&mut self, port: Port) -> Result<(), ChipError> {
        // SAFETY: as in `run_until`.
        match unsafe { board_watch_port(self.raw.as_ptr(), c_char_of(port.letter())) } {
            0 => Ok(()),
            _ => Err(ChipError::NoPort(port.letter())),
        }
    }

    /// Reports every pulse Timer1's fast PWM makes on OC1B (PB2, the servo's signal) as a
    /// [`PortEvent::Pulse`] when it ends, while PB2 is an output: no port event shows them. The
    /// width is OCR1B + 1 timer ticks, as the datasheet defines it (the shim says why).
    pub fn watch_oc1b(&mut self) -> Result<(), ChipError> {
        // SAFETY: as in `run_until`.
        match unsafe { board_watch_oc1b(self.raw.as_ptr()) } {
            0 => Ok(()),
            _ => Err(ChipError::NoPin(crate::pins::SERVO)),
        }
    }

    /// The oldest change of a watched port or pin not yet taken.
    pub fn next_event(&mut self) -> Option<PortEvent> {
        let mut ev = RawEvent::default();
        // SAFETY: `ev` is a valid `board_event_t` to write; `raw` as in `run_until`.
        if unsafe { board_next_event(self.raw.as_ptr(), &mut ev) } == 0 {
            return None;
        }
        let port = Port::from_letter(char::from(ev.port as u8))?;
        Some(if ev.pin == WHOLE_PORT {
            PortEvent::Port {
                cycle: ev.cycle,
                port,
                levels: ev.value,
            }
        } else {
            PortEvent::Pulse {
                cycle: ev.cycle,
                pin: Pin::new(port, ev.pin),
                width_cycles: ev.width,
            }
        })
    }

    /// Drives input pin `pin` from outside: `high` or low, until driven again (also across
    /// resets).
    pub fn drive(&mut self, pin: Pin, high: bool) -> Result<(), ChipError> {
        let letter = c_char_of(pin.port.letter());
        // SAFETY: as in `run_until`.
        match unsafe { board_drive_pin(self.raw.as_ptr(), letter, pin.bit, c_int::from(high)) } {
            0 => Ok(()),
            _ => Err(ChipError::NoPin(pin)),
        }
    }

    /// Moves bytes the firmware sent on UART0 into `buf`; returns how many.
    pub fn take_uart(&mut self, buf: &mut [u8]) -> usize {
        // SAFETY: `buf` is writable for `buf.len()` bytes; `raw` as in `run_until`.
        unsafe { board_uart_take(self.raw.as_ptr(), buf.as_mut_ptr(), buf.len()) }
    }

    /// Whether UART0's receiver takes a byte now (enabled, room in its buffer: XON).
    pub fn uart_ready(&self) -> bool {
        // SAFETY: as in `cycle`.
        unsafe { board_uart_ready(self.raw.as_ptr()) != 0 }
    }

    /// A byte arrives on UART0's RX line.
    pub fn uart_send(&mut self, byte: u8) {
        // SAFETY: as in `run_until`.
        unsafe { board_uart_send(self.raw.as_ptr(), byte) }
    }

    /// Presses the reset button: the core and its peripherals restart; pins driven from outside
    /// keep their levels, the EEPROM its contents.
    pub fn reset(&mut self) {
        // SAFETY: as in `run_until`.
        unsafe { board_reset(self.raw.as_ptr()) }
    }

    fn eeprom_range(offset: u16, len: usize) -> Result<u32, ChipError> {
        u32::try_from(len)
            .ok()
            .filter(|&n| n > 0 && usize::from(offset) + len <= 1024)
            .ok_or(ChipError::Eeprom {
                offset,
                end: usize::from(offset) + len,
            })
    }

    /// Writes `data` into the EEPROM at `offset`, as a programmer would.
    pub fn eeprom_write(&mut self, offset: u16, data: &[u8]) -> Result<(), ChipError> {
        let len = Self::eeprom_range(offset, data.len())?;
        // SAFETY: `data` is readable for `len` bytes; `raw` as in `run_until`.
        match unsafe { board_eeprom_write(self.raw.as_ptr(), offset, data.as_ptr(), len) } {
            0 => Ok(()),
            _ => Err(ChipError::Eeprom {
                offset,
                end: usize::from(offset) + data.len(),
            }),
        }
    }

    /// Reads the EEPROM at `offset` into `data`.
    pub fn eeprom_read(&mut self, offset: u16, data: &mut [u8]) -> Result<(), ChipError> {
        let len = Self::eeprom_range(offset, data.len())?;
        // SAFETY: `data` is writable for `len` bytes; `raw` as in `run_until`.
        match unsafe { board_eeprom_read(self.raw.as_ptr(), offset, data.as_mut_ptr(), len) } {
            0 => Ok(()),
            _ => Err(ChipError::Eeprom {
                offset,
                end: usize::from(offset) + data.len(),
            }),
        }
    }

    /// Port events and UART bytes lost to the shim's full queues (0 unless the loop stalls).
    pub fn lost(&self) -> (u64, u64) {
        let (mut events, mut bytes) = (0, 0);
        // SAFETY: both outputs are valid `u64`s to write; `raw` as in `cycle`.
        unsafe { board_lost(self.raw.as_ptr(), &mut events, &mut bytes) };
        (events, bytes)
    }
}

impl Drop for Chip {
    fn drop(&mut self) {
        // SAFETY: `raw` came from `board_new` and is freed once, here.
        unsafe { board_free(self.raw.as_ptr()) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_or_foreign_file_is_an_error_that_names_it() {
        let missing = Path::new("/nonexistent/sonar-head.elf");
        let err = Chip::load(missing).unwrap_err().to_string();
        assert!(err.contains("/nonexistent/sonar-head.elf"), "{err}");

        let not_elf = std::env::temp_dir().join(format!("not-an-elf-{}", std::process::id()));
        std::fs::write(&not_elf, b"#!/bin/sh\necho hello\n").unwrap();
        let err = Chip::load(&not_elf).unwrap_err().to_string();
        std::fs::remove_file(&not_elf).unwrap();
        assert!(err.contains("not-an-elf"), "{err}");

        assert!(matches!(
            Chip::load(Path::new("a\0b")),
            Err(ChipError::Path(_))
        ));
    }

    #[test]
    fn eeprom_ranges_outside_the_chip_are_refused() {
        assert_eq!(Chip::eeprom_range(0, 10).unwrap(), 10);
        assert_eq!(Chip::eeprom_range(1014, 10).unwrap(), 10);
        assert!(Chip::eeprom_range(1015, 10).is_err());
        assert!(Chip::eeprom_range(0, 0).is_err());
    }
}
