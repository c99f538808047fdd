//! `sonar-firmware-sim`: firmware in the loop. The sensor head's own firmware — the ATmega328P ELF
//! built from `firmware/`, unchanged — runs in [simavr](https://github.com/buserror/simavr), and
//! this crate plays the hardware around the chip: the stepper motor and its driver, the two limit
//! switches and the SRF05, from `sonar-sim`'s scenes and echo model. UART0 goes to a
//! pseudo-terminal (`sonar_sim::Pty`), so the real `sonar-driver` opens it exactly as the head's USB
//! serial adapter. It is the twin of `sonar-sim`, whose firmware is a Rust model of the protocol:
//! here the protocol, the timing and the motor control are the firmware's own.
//!
//! # Design
//!
//! Pure parts, unit-tested without simavr, all counting time in the chip's clock cycles (16 MHz):
//!
//! - [`pins`]: the wiring (the firmware's `pins.h` agrees; a test checks it).
//! - [`motor`]: the [`Motor`](motor::Motor) (`--motor`), the [`Follower`](motor::Follower) that
//!   turns port D's levels into steps the way the driver chip does (ULN2003 half steps on PD4..PD7,
//!   or STEP/DIR/EN), and the [`Shaft`](motor::Shaft), whose position is kept exactly in microsteps
//!   between the mechanical stops at ±160°.
//! - [`switches`]: MIN closed at ≤ −150°, MAX at ≥ +150°, active low, optionally bouncing.
//! - [`srf05`]: trigger ≥ 10 µs, ECHO pulse as wide as the echo time from
//!   [`EchoModel`](sonar_sim::EchoModel), 30 ms without an echo.
//! - [`servo`]: the servo head's SG90 (`--head servo`, `make -C firmware HEAD=servo`): the width of
//!   each pulse on its signal line (OC1B = PB2, 50 Hz) is an angle, 1000…2000 µs for −90…+90°,
//!   which the shaft turns to at 0.1 s per 60°, within its stops; no switches.
//! - [`head`]: the parts together as one state machine: port levels in, timed pin edges out
//!   ([`schedule`]).
//! - [`headid`]: the head id record in EEPROM (`--head-id`); [`pacing`]: emulated time against
//!   wall time (`--speed`); [`serial`]: UART bytes to and from the pseudo-terminal, never blocking.
//!
//! And the emulator: [`bench`] runs the chip to the next thing that matters (an edge the head
//! drives, a look at the serial line every 100 µs of emulated time, a change of port B or D), hands
//! the port changes to the head and drives its edges, on one thread. The chip itself is `avr`, a
//! safe wrapper over a thin C shim (`src/board.c`) on libsimavr: the crate's only unsafe code. The
//! shim queues port changes with their cycle and stops the run there, instead of calling into Rust
//! from inside an instruction.
//!
//! # What is modelled
//!
//! - The motor follows every step the firmware gives, at any rate; a jump of the ULN2003's coil
//!   phase by 4 half steps (which way?) or an invalid coil pattern is a fault (logged, counted),
//!   and so is a skip of 3 (the rotor follows the nearest way). With the coils off the rotor holds
//!   where it is (the gear's friction), and the next energised phase counts from the last one.
//! - Steps past the mechanical stops (±160°) are lost: the motor stalls there. Anywhere else no
//!   step is ever missed.
//! - Limit switches: pure contacts; `--switch-bounce` adds 1–3 seeded open/close pairs within
//!   2 ms of every change. `--switch-fault` breaks them: `dead` (never closes), `stuck` (always
//!   closed; `both=stuck` a shorted cable), `early:DEG` (closes DEG° before ±150°), `bouncing`
//!   (4–10 pairs within 10 ms, the worst sensor-facts allows). `--travel-report FILE` writes at exit
//!   how far the shaft turned, and how far it was driven (lost steps against the stops included).
//! - SRF05 (mode 1): a trigger pulse of ≥ 10 µs (shorter ones are ignored, as by the module)
//!   fires a ping on its falling edge, aimed where the shaft stands then. ECHO rises
//!   [`ECHO_DELAY_US`](srf05::ECHO_DELAY_US) = 500 µs later — **assumed**: no datasheet gives it —
//!   and falls after the echo time, or after 30 ms without an echo. Triggers while a ping is in
//!   progress are ignored. The firmware times ECHO with Timer1's input capture (ICP1 = PB0), which
//!   simavr emulates.
//! - The servo head (`--head servo`): Timer1's PWM pulses on OC1B (PB2), each pulse's width
//!   (1000…2000 µs, SG90 datasheet) an angle of −90…+90°, which the shaft turns to at 0.1 s/60°
//!   (SG90 datasheet, 4.8 V) from the end of the pulse, never beyond its stops at ±90°; pulses
//!   outside 500…2500 µs are ignored and counted. The width is taken from OCR1B and Timer1's
//!   prescaler at each compare match (simavr 1.6 starts some pulses late; `board.c` says more).
//!   No dead band, overshoot or ringing (the firmware waits for them), no switches.
//! - The UART: bytes from the host enter UART0 only while its receiver signals XON (simavr's
//!   64-byte receive queue has room); they wait on the host side meanwhile (up to 4 KiB, then in
//!   the terminal, whose writer blocks), and reach the firmware at the baud rate it set. Bytes the firmware sends go to the terminal as soon as they
//!   are written to UDR0; when nobody reads, they are dropped and counted, as in `sonar-sim`.
//! - The reset button (SIGUSR1): the chip restarts, the shaft stays where it is, the EEPROM keeps
//!   its contents, and the head's pins keep their levels. A watchdog reset is simavr's.
//!
//! # What is not
//!
//! Motor torque, speed limits, resonance and inertia (missed steps happen only at the stops);
//! electrical noise on any line; the 2-byte receive buffer of a real UART (simavr's is 64 bytes, so
//! a firmware that reads too slowly loses bytes on the hardware but not here) and baud-rate
//! mismatch between host and chip; the SRF05's motion during a ping (it aims where the shaft stood
//! at the trigger); its minimum interval between pings (the firmware's to keep); supply and
//! brown-out.
//!
//! # Without simavr
//!
//! `build.rs` looks for simavr with `pkg-config`. Without it the crate still builds (the workspace
//! is built for the robot, which needs no firmware simulator): [`bench::run`] returns
//! [`BenchError::NoSimavr`](bench::BenchError::NoSimavr), and the binary exits with that message.

#[cfg(simavr)]
pub mod avr;
pub mod bench;
pub mod head;
pub mod headid;
pub mod motor;
pub mod pacing;
pub mod pins;
#[cfg(test)]
mod protocol_oracle;
pub mod schedule;
pub mod serial;
pub mod servo;
pub mod srf05;
pub mod switches;
