//! Shared ground of the sonar pipeline: what crosses processes and what crosses the serial line.
//!
//! - [`protocol`]: the line protocol spoken by the microcontroller (or the simulator) and the PC,
//!   as pure encode/parse functions, plus the hobby "Arduino radar" dialect.
//! - [`sensor`]: the geometry of the rotating head and the physics of time of flight.
//! - [`ipc`]: the `#[repr(C)]` payloads exchanged over iceoryx2, their service names, and one function
//!   per service so every process opens it with the same quality of service.
//! - [`namespace`]: removes what processes killed while creating iceoryx2 resources left behind.
//! - [`optional_port`]: a port a process can do without, opened again while it cannot be had.
//! - [`logging`]: one way for every program to log and to report the error it stops with.
//! - [`speed`]: simulated time against wall time; [`throttle`]: rate limits for frequent log lines.
//! - [`toml_file`]: configuration files parsed with errors placed at the value at fault.
//!
//! Nothing here does I/O except opening iceoryx2 services on behalf of the caller, and removing
//! what killed processes left in their namespace before that.

use std::path::PathBuf;

pub mod flood;
pub mod ipc;
pub mod logging;
pub mod namespace;
pub mod optional_port;
pub mod protocol;
pub mod sensor;
pub mod speed;
pub mod throttle;
pub mod toml_file;

pub use logging::report_exit;

/// Sets up `tracing` for a binary that logs to standard error; see [`logging`].
pub fn init_tracing() {
    logging::init(logging::LogTo::Stderr);
}

/// Where the pipeline keeps what outlives a process (the launcher's logs, the fusion's saved map):
/// `$XDG_STATE_HOME/sonar`, else `~/.local/state/sonar` (the XDG default), else `<tmp>/sonar`
/// for a user without a home.
pub fn state_dir() -> PathBuf {
    let non_empty = |name| std::env::var_os(name).filter(|v| !v.is_empty());
    if let Some(state) = non_empty("XDG_STATE_HOME") {
        return PathBuf::from(state).join("sonar");
    }
    match non_empty("HOME") {
        Some(home) => PathBuf::from(home).join(".local/state/sonar"),
        None => std::env::temp_dir().join("sonar"),
    }
}

/// A command-line value of seconds: a positive finite number (fractions allowed), for clap's
/// `value_parser`.
pub fn parse_positive_seconds(s: &str) -> Result<std::time::Duration, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 && x < 1e9 => Ok(std::time::Duration::from_secs_f64(x)),
        _ => Err(format!("{s:?} is not a positive number of seconds")),
    }
}
