//! A port of a service a process can do without, opened again while it cannot be had.
//!
//! A recorder or a live server subscribes to what it finds useful (the odometry, the map, the
//! corrections) and goes on without what it cannot have. A service whose QoS has no room for
//! another port is left out for good: a port had later would take the place of a process the
//! pipeline needs (a restarted fusion's, say). But an opening can also fail for a moment, when
//! another process of the pipeline is creating the same service at the same instant on a loaded
//! machine; given up for good, the port would be missing for the rest of the run, silently (a
//! recording of a tour without its odometry). So such a port is tried again, at most every
//! [`RETRY_PERIOD`], for as long as the process runs: the first failure is a warning, later ones
//! are debug lines, the success an info line.

use std::fmt::Debug;
use std::time::{Duration, Instant};

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use tracing::{debug, info, warn};

use crate::ipc::{IpcError, PubSub};

/// How often a port that could not be had is tried again.
pub const RETRY_PERIOD: Duration = Duration::from_secs(1);

/// An optional port: `Some` once opened, tried again while `None`.
#[derive(Debug)]
pub struct OptionalPort<P> {
    /// What it is, for the log: the service's name.
    name: &'static str,
    open: fn(&Node<Ipc>) -> Result<P, IpcError>,
    port: Option<P>,
    /// When it is tried next; never for a port had, not wanted, or whose service is full.
    next_try: Option<Instant>,
}

impl<P> OptionalPort<P> {
    /// Opens the port with `open`; on a failure other than a full service, warns once and leaves
    /// it to [`Self::retry`].
    pub fn open(
        node: &Node<Ipc>,
        name: &'static str,
        open: fn(&Node<Ipc>) -> Result<P, IpcError>,
    ) -> Self {
        let (port, next_try) = match open(node) {
            Ok(port) => (Some(port), None),
            Err(e) if e.is_service_full() => {
                warn!("left out {name}: {e}");
                (None, None)
            }
            Err(e) => {
                warn!("{name} cannot be had for now (tried again every {RETRY_PERIOD:?}): {e}");
                (None, Some(Instant::now() + RETRY_PERIOD))
            }
        };
        Self {
            name,
            open,
            port,
            next_try,
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
            Err(e) if e.is_service_full() => {
                warn!("left out {}: {e}", self.name);
                self.next_try = None;
                false
            }
            Err(e) => {
                debug!("{} still cannot be had: {e}", self.name);
                false
            }
        }
    }
}

/// A subscriber of the service of single messages `open` opens: the opening an optional port of
/// one usually is (`OptionalPort::open(node, name, |n| subscriber(n, ipc::pose_service))`).
pub fn subscriber<T: Debug + ZeroCopySend>(
    node: &Node<Ipc>,
    open: fn(&Node<Ipc>) -> Result<PubSub<T>, IpcError>,
) -> Result<Subscriber<Ipc, T, ()>, IpcError> {
    open(node)?
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new("create subscriber", e))
}

/// A subscriber of a snapshot service (`sonar/features`, `sonar/grid`: a slice behind a header).
pub fn snapshot_subscriber<T, H>(
    service: Result<PortFactory<Ipc, [T], H>, IpcError>,
) -> Result<Subscriber<Ipc, [T], H>, IpcError>
where
    T: Debug + ZeroCopySend + 'static,
    H: Debug + ZeroCopySend + 'static,
{
    service?
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new("create subscriber", e))
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

    static FULL_CALLS: AtomicUsize = AtomicUsize::new(0);

    /// Always full.
    fn full(_: &Node<Ipc>) -> Result<u32, IpcError> {
        FULL_CALLS.fetch_add(1, Ordering::SeqCst);
        Err(IpcError::new(
            "create subscriber",
            "ExceedsMaxSupportedSubscribers",
        ))
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

        // A full service is left out for good: a place had later would be someone else's.
        let mut port = OptionalPort::open(&node, "test/full", full);
        assert!(!port.retry(&node, start + RETRY_PERIOD * 2));
        assert!(port.get().is_none());
        assert_eq!(FULL_CALLS.load(Ordering::SeqCst), 1);
        drop(node);
        let _ = std::fs::remove_dir_all(root);
    }
}
