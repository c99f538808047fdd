//! Shared ground of the sonar pipeline: what crosses processes and what crosses the serial line.
//!
//! - [`protocol`]: the line protocol spoken by the microcontroller (or the simulator) and the PC,
//!   as pure encode/parse functions, plus the hobby "Arduino radar" dialect.
//! - [`sensor`]: the geometry of the rotating head and the physics of time of flight.
//! - [`ipc`]: the `#[repr(C)]` payloads exchanged over iceoryx2, their service names, and one function
//!   per service so every process opens it with the same quality of service.
//!
//! Nothing here does I/O except opening iceoryx2 services on behalf of the caller.

pub mod ipc;
pub mod protocol;
pub mod sensor;

/// Sets up `tracing` for a binary: level from `RUST_LOG` (default `info`), to standard error.
pub fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    // A second initialisation (tests) is harmless; ignore it.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}
