//! A port of a service a process can do without, opened again while it cannot be had.
//!
//! A recorder or a live server subscribes to what it finds useful (the odometry, the map, the
//! corrections) and goes on without what it cannot have: a subscriber QoS already full, say. But
//! an opening can also fail for a moment, when another process of the pipeline is creating the
//! same service at the same instant on a loaded machine; given up for good, the port would be
//! missing for the rest of the run, silently (a recording of a tour without its odometry). So a
//! port that could not be had is tried again, at most every [`RETRY_PERIOD`], for as long as the
//! process runs: the first failure is a warning, later ones are debug lines, the success an info
//! line.

use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use tracing::{debug, info, warn};

use crate::ipc::IpcError;

/// How often a port that could not be had is tried again.
pub const RETRY_PERIOD: Duration = Duration::from_secs(1);

/// An optional port: `Some` once opened, tried again while `None`.
#[derive(Debug)]
pub struct OptionalPort<P> {
    /// What it is, for the log: the service's name.
    name: &'static str,
    open: fn(&Node<Ipc>) -> Result<P, IpcError>,
    port: Option<P>,
    /// When it is tried next; never for a port not wanted.
    next_try: Option<Instant>,
}

impl<P> OptionalPort<P> {
    /// Opens the port with `open`; on failure warns once and leaves it to [`Self::retry`].
    pub fn open(
        node: &Node<Ipc>,
        name: &'static str,
        open: fn(&Node<Ipc>) -> Result<P, IpcError>,
    ) -> Self {
        let port = open(node)
            .inspect_err(|e| {
                warn!("{name} cannot be had for now (tried again every {RETRY_PERIOD:?}): {e}")
            })
            .ok();
        Self {
            name,
            open,
            port,
            next_try: Some(Instant::now() + RETRY_PERIOD),
        }
    }

    /// [`Self::open`] if `wanted`; else a port never opened nor tried (a feature turned off).
    pub fn open_if(
        wanted: bool,
        node: &Node<Ipc>,
        name: &'static str,
        open: fn(&Node<Ipc>) -> Result<P, IpcError>,
    ) -> Self {
        match wanted {
            true => Self::open(node, name, open),
            false => Self {
                name,
                open,
                port: None,
                next_try: None,
            },
        }
    }

    /// The port, if it has been had.
    pub fn get(&self) -> Option<&P> {
        self.port.as_ref()
    }

    /// Tries the opening again if the port is missing and [`RETRY_PERIOD`] has passed since the
    /// last try; true when the port was had just now.
    pub fn retry(&mut self, node: &Node<Ipc>, now: Instant) -> bool {
        if self.port.is_some() || self.next_try.is_none_or(|t| now < t) {
            return false;
        }
        self.next_try = Some(now + RETRY_PERIOD);
        match (self.open)(node) {
            Ok(port) => {
                info!("{} had after all", self.name);
                self.port = Some(port);
                true
            }
            Err(e) => {
                debug!("{} still cannot be had: {e}", self.name);
                false
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    static CALLS: AtomicUsize = AtomicUsize::new(0);

    /// Fails twice, then opens.
    fn third_time_lucky(_: &Node<Ipc>) -> Result<u32, IpcError> {
        if CALLS.fetch_add(1, Ordering::SeqCst) < 2 {
            Err(IpcError {
                context: "open".into(),
                message: "being created by another process".into(),
            })
        } else {
            Ok(7)
        }
    }

    #[test]
    fn a_port_that_fails_is_tried_again_each_period_until_it_opens() {
        let root = std::env::temp_dir().join(format!("sonar_optport_{}", std::process::id()));
        let args = crate::ipc::IpcArgs {
            iox_prefix: Some(format!("optport{}_", std::process::id())),
            iox_root: Some(root.clone()),
            ..Default::default()
        };
        let node = args.node("optional-port-test").unwrap();
        let mut port = OptionalPort::open(&node, "test/service", third_time_lucky);
        assert!(port.get().is_none());
        let start = Instant::now();
        // Not before the period is over.
        assert!(!port.retry(&node, start));
        assert_eq!(CALLS.load(Ordering::SeqCst), 1);
        // The second try fails, the third opens; then it is never tried again.
        assert!(!port.retry(&node, start + RETRY_PERIOD * 2));
        assert!(port.retry(&node, start + RETRY_PERIOD * 4));
        assert_eq!(port.get(), Some(&7));
        assert!(!port.retry(&node, start + RETRY_PERIOD * 8));
        assert_eq!(CALLS.load(Ordering::SeqCst), 3);
        drop(node);
        let _ = std::fs::remove_dir_all(root);
    }
}
