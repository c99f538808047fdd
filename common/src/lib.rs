//! Shared ground of the sonar pipeline: what crosses processes and what crosses the serial line.
//!
//! - [`protocol`]: the line protocol spoken by the microcontroller (or the simulator) and the PC,
//!   as pure encode/parse functions, plus the hobby "Arduino radar" dialect.
//! - [`sensor`]: the geometry of the rotating head and the physics of time of flight.
//! - [`ipc`]: the `#[repr(C)]` payloads exchanged over iceoryx2, their service names, and one function
//!   per service so every process opens it with the same quality of service.
//! - [`namespace`]: removes what processes killed while creating iceoryx2 resources left behind.
//! - [`speed`]: simulated time against wall time; [`throttle`]: rate limits for frequent log lines.
//!
//! Nothing here does I/O except opening iceoryx2 services on behalf of the caller, and removing
//! what killed processes left in their namespace before that.

use std::path::PathBuf;
use std::process::ExitCode;

pub mod ipc;
pub mod namespace;
pub mod protocol;
pub mod sensor;
pub mod speed;
pub mod throttle;

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

/// The end of a binary's `main`: [`ExitCode::SUCCESS`] for `Ok`; for an error, logs it and
/// prints `<program>: error: <the chain of causes>` on one line of standard error (the user's
/// message, also when the log goes elsewhere), and returns [`ExitCode::FAILURE`].
pub fn report_exit(program: &str, result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{e:#}");
            // One line with the chain of causes, not a backtrace: these are user errors.
            eprintln!("{program}: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_exit_maps_ok_to_success_and_errors_to_failure() {
        assert_eq!(report_exit("test", Ok(())), ExitCode::SUCCESS);
        let err = anyhow::anyhow!("inner cause").context("outer");
        assert_eq!(report_exit("test", Err(err)), ExitCode::FAILURE);
    }
}
