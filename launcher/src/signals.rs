//! The supervisor's one wait. SIGINT, SIGTERM and SIGHUP ask the pipeline to stop; SIGCHLD says
//! a child ended. Each also writes a byte to a socket the supervisor sleeps on (signal-hook's
//! self-pipe), so it wakes when something happens instead of looking every so often: an idle
//! pipeline's launcher does not wake at all.

use std::io::{ErrorKind, Read};
use std::os::fd::AsFd;
use std::os::unix::net::UnixStream;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use signal_hook::consts::{SIGCHLD, SIGHUP, SIGINT, SIGTERM};

pub struct Signals {
    stop: Arc<AtomicBool>,
    /// The reading end of the self-pipe; the handlers hold the writing ends.
    woken: UnixStream,
}

impl Signals {
    pub fn install() -> Result<Self> {
        let (woken, wake) = UnixStream::pair().context("cannot create the signal socket")?;
        // Neither end may block: a handler drops a byte rather than wait, the drain stops when empty.
        woken
            .set_nonblocking(true)
            .and_then(|()| wake.set_nonblocking(true))
            .context("cannot set up the signal socket")?;
        let stop = Arc::new(AtomicBool::new(false));
        for signal in [SIGINT, SIGTERM, SIGHUP] {
            signal_hook::flag::register(signal, Arc::clone(&stop))
                .context("cannot install signal handlers")?;
        }
        for signal in [SIGINT, SIGTERM, SIGHUP, SIGCHLD] {
            let wake = wake.try_clone().context("cannot share the signal socket")?;
            signal_hook::low_level::pipe::register(signal, wake)
                .context("cannot install signal handlers")?;
        }
        Ok(Self { stop, woken })
    }

    /// SIGINT, SIGTERM or SIGHUP came.
    pub fn stop_requested(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    /// Sleeps until a signal comes (a stop, or a child that ended) or `timeout` passes (`None`:
    /// no limit), then forgets the signals that came: the caller looks at what they are about.
    /// True when a signal woke it.
    pub fn wait(&self, timeout: Option<Duration>) -> bool {
        let timeout = timeout.map_or(PollTimeout::NONE, |t| {
            PollTimeout::try_from(t.as_micros().div_ceil(1000)).unwrap_or(PollTimeout::MAX)
        });
        let mut fds = [PollFd::new(self.woken.as_fd(), PollFlags::POLLIN)];
        // EINTR (a signal came as we went to sleep) is a wake-up like any other: its byte is
        // read below.
        let _ = poll(&mut fds, timeout);
        let mut woken = false;
        let mut bytes = [0u8; 64];
        loop {
            match (&self.woken).read(&mut bytes) {
                Ok(0) => break,
                Ok(_) => woken = true,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(_) => break, // WouldBlock: drained
            }
        }
        woken
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A child that ends wakes the wait.
    #[test]
    fn a_child_that_ends_wakes_the_wait() {
        let signals = Signals::install().unwrap();
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let woken = signals.wait(Some(Duration::from_secs(60)));
        child.wait().unwrap(); // reaped, so no zombie is left
        assert!(woken, "SIGCHLD did not wake the wait");
        assert!(!signals.stop_requested());
    }
}
