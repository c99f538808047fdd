//! One way for every program to log and to report the error it stops with.
//!
//! - The level comes from `RUST_LOG` (default `info`); iceoryx2's own messages are forwarded into
//!   `tracing` under the target `iceoryx2` and shown from `error` up unless `RUST_LOG` names
//!   that target (`RUST_LOG=info,iceoryx2=warn`): its warning that no config file was loaded is normal
//!   for us (the pipeline configures iceoryx2 in code) and only noise on a user's terminal.
//! - Colour only when the log goes to a terminal: a log file holds plain text.
//! - A fatal error is printed once, as `<program>: error: <causes>` on standard error; it is also
//!   logged only when the log goes to a file (standard error is then the user's terminal, and the
//!   file would otherwise lack the reason the program stopped).

use std::fmt;
use std::fs::File;
use std::io::IsTerminal;
use std::process::ExitCode;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use iceoryx2_log::{Log, LogLevel};

/// Where a program's log goes.
#[derive(Debug)]
pub enum LogTo {
    /// Standard error, coloured if it is a terminal.
    Stderr,
    /// A file (the viewer draws on the terminal; the launcher's children write to theirs).
    File(File),
    /// No log at all (a viewer that cannot open its file), but iceoryx2 still kept off the
    /// terminal.
    Nowhere,
}

static LOG_IN_FILE: AtomicBool = AtomicBool::new(false);

/// Sets up `tracing` and forwards iceoryx2's log into it. Call first in `main`, before anything of
/// iceoryx2 runs (its logger can be set only once). A second call (tests) changes nothing.
pub fn init(to: LogTo) {
    iceoryx2_log::set_logger(&ICEORYX_TO_TRACING);
    iceoryx2_log::set_log_level_from_env_or(LogLevel::Warn);
    let filter = tracing_subscriber::EnvFilter::new(filter_directives(
        std::env::var("RUST_LOG").ok().as_deref(),
    ));
    let builder = tracing_subscriber::fmt().with_env_filter(filter);
    let installed = match to {
        LogTo::Stderr => builder
            .with_ansi(std::io::stderr().is_terminal())
            .with_writer(std::io::stderr)
            .try_init()
            .is_ok(),
        LogTo::File(file) => {
            let installed = builder
                .with_ansi(false)
                .with_writer(Mutex::new(file))
                .try_init()
                .is_ok();
            if installed {
                LOG_IN_FILE.store(true, Ordering::Relaxed);
            }
            installed
        }
        LogTo::Nowhere => true,
    };
    if !installed {
        tracing::debug!("tracing was already set up");
    }
}

/// `RUST_LOG`'s directives (default `info`), with iceoryx2 at `error` unless they name it (also for
/// `flood::init_tracing`, which installs its own subscriber after `init(LogTo::Nowhere)`).
pub(crate) fn filter_directives(rust_log: Option<&str>) -> String {
    let given = rust_log.map(str::trim).filter(|s| !s.is_empty());
    match given {
        Some(d) if d.contains("iceoryx2") => d.to_owned(),
        Some(d) => format!("{d},iceoryx2=error"),
        None => "info,iceoryx2=error".to_owned(),
    }
}

/// Forwards iceoryx2's log messages to `tracing` under the target `iceoryx2`. Its default logger
/// writes to standard error unconditionally: over the viewer's picture, and past `RUST_LOG`.
struct IceoryxToTracing;

impl Log for IceoryxToTracing {
    fn log(&self, level: LogLevel, origin: fmt::Arguments, message: fmt::Arguments) {
        match level {
            LogLevel::Trace => tracing::trace!(target: "iceoryx2", %origin, "{message}"),
            LogLevel::Debug => tracing::debug!(target: "iceoryx2", %origin, "{message}"),
            LogLevel::Info => tracing::info!(target: "iceoryx2", %origin, "{message}"),
            LogLevel::Warn => tracing::warn!(target: "iceoryx2", %origin, "{message}"),
            LogLevel::Error | LogLevel::Fatal => {
                tracing::error!(target: "iceoryx2", %origin, "{message}")
            }
        }
    }
}

static ICEORYX_TO_TRACING: IceoryxToTracing = IceoryxToTracing;

/// The exit status of a program stopped by settings it cannot work with (sysexits.h's
/// `EX_CONFIG`): the launcher stops the pipeline with the reason instead of restarting it, at
/// whatever moment it comes (a scan outside the limits the head reports after its handshake).
pub const EXIT_MISCONFIGURED: u8 = 78;

/// An error the user has to fix in the settings; anywhere in an error's chain it makes
/// [`report_exit`] exit with [`EXIT_MISCONFIGURED`].
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct Misconfigured(pub String);

/// The end of a binary's `main`: [`ExitCode::SUCCESS`] for `Ok`; for an error, prints
/// `<program>: error: <the chain of causes>` on one line of standard error and returns
/// [`ExitCode::FAILURE`], or [`EXIT_MISCONFIGURED`] for a [`Misconfigured`] one.
pub fn report_exit(program: &str, result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let message = error_chain(&e);
            if LOG_IN_FILE.load(Ordering::Relaxed) {
                tracing::error!("{program} stops: {message}");
            }
            eprintln!("{program}: error: {message}");
            if e.chain().any(|c| c.is::<Misconfigured>()) {
                ExitCode::from(EXIT_MISCONFIGURED)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}

/// The error and its causes on one line, `outer: inner: innermost`, leaving out a cause whose text
/// the message already carries: many errors (the standard library's, iceoryx2's, ours built with
/// `{source}` in their text) repeat their cause's text in their own.
pub fn error_chain(error: &anyhow::Error) -> String {
    let mut message = String::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if message.contains(text.as_str()) {
            continue;
        }
        if !message.is_empty() {
            message.push_str(": ");
        }
        message.push_str(&text);
    }
    message
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_exit_maps_ok_to_success_and_errors_to_failure() {
        assert_eq!(report_exit("test", Ok(())), ExitCode::SUCCESS);
        let err = anyhow::anyhow!("inner cause").context("outer");
        assert_eq!(report_exit("test", Err(err)), ExitCode::FAILURE);
        let err = anyhow::Error::new(Misconfigured("scan outside the limits".into())).context("x");
        assert_eq!(
            report_exit("test", Err(err)),
            ExitCode::from(EXIT_MISCONFIGURED)
        );
    }

    #[test]
    fn iceoryx2_speaks_up_from_error_unless_rust_log_names_it() {
        assert_eq!(filter_directives(None), "info,iceoryx2=error");
        assert_eq!(filter_directives(Some("debug")), "debug,iceoryx2=error");
        assert_eq!(
            filter_directives(Some("info,iceoryx2=warn")),
            "info,iceoryx2=warn"
        );
    }

    #[test]
    fn the_chain_names_each_cause_once() {
        let err = anyhow::anyhow!("inner cause")
            .context("middle")
            .context("outer");
        assert_eq!(error_chain(&err), "outer: middle: inner cause");

        // A cause whose text the outer message already repeats is left out.
        #[derive(Debug, thiserror::Error)]
        #[error("grid.resolution_m must be positive, got -0.02")]
        struct Invalid;
        #[derive(Debug, thiserror::Error)]
        #[error("invalid settings in a.toml: {0}")]
        struct Wrapper(#[source] Invalid);
        let err = anyhow::Error::new(Wrapper(Invalid)).context("cannot start");
        assert_eq!(
            error_chain(&err),
            "cannot start: invalid settings in a.toml: grid.resolution_m must be positive, got -0.02"
        );

        let io = std::io::Error::from_raw_os_error(17);
        let err = anyhow::Error::new(io).context("cannot create /x (File exists (os error 17))");
        assert_eq!(
            error_chain(&err),
            "cannot create /x (File exists (os error 17))"
        );
    }
}
