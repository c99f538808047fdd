//! The viewer's side of iceoryx2: subscribers to the snapshots and the driver's state, publishers of
//! commands, and the liveness of the processes behind them.
//!
//! Called from the main loop's thread (iceoryx2 ports are not `Send`) when a wake-up came or a
//! look is due, at most once per frame. Each port is opened on first use through the functions of
//! `sonar_common::ipc`, so the QoS always matches; a port that cannot be opened (a producer with
//! another layout version, shared memory trouble) is retried once a second while everything else
//! keeps working. Opening never waits for a producer: `open_or_create` creates a missing service
//! and the producer joins it later, and a live subscriber is reconnected by iceoryx2 to a
//! restarted publisher, so start order and restarts need no code here.
//!
//! Per frame, each subscriber is drained keeping only its newest sample, whose contents are copied
//! into the [`App`] before the sample is released: no shared memory is held across frames, and with
//! the grid's one-slot buffer the fusion engine never waits for the viewer.

use std::fmt::Debug;
use std::time::{Duration, Instant};

use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::node::NodeView;
use iceoryx2::port::ReceiveError;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::dynamic_config::publish_subscribe::PublisherDetails;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::service::port_factory::PortFactory;
use sonar_common::ipc::{
    self, DriverStatus, FeatureRecord, FeaturesHeader, FusionCommand, FusionStatus, GridHeader,
    IpcError, LocalizedPose, PubSub, Radar, Reading, ScanCommand, SlamCorrection,
};
use tracing::{info, warn};

use crate::app::App;

/// How often a port that failed to open is tried again.
const RETRY: Duration = Duration::from_secs(1);
/// How often the publishers' processes are checked for life (a file-lock test per node).
const LIVENESS_PERIOD: Duration = Duration::from_secs(1);
/// Readings taken per frame at most; the rest wait in the subscriber's buffer (or are dropped by
/// iceoryx2 when it overflows, which costs the driver nothing).
const MAX_READINGS_PER_POLL: usize = 256;
/// SLAM estimates taken per frame at most: `sonar/slam_correction`'s buffer.
const SLAM_PER_POLL: usize = 256;

/// A port that is opened on first use and again after a failure, at most once per [`RETRY`].
struct Lazy<T> {
    what: &'static str,
    port: Option<T>,
    retry_at: Option<Instant>,
    error: Option<String>,
}

impl<T> Lazy<T> {
    fn new(what: &'static str) -> Self {
        Self {
            what,
            port: None,
            retry_at: None,
            error: None,
        }
    }

    fn get(&mut self, now: Instant, open: impl FnOnce() -> Result<T, IpcError>) -> Option<&mut T> {
        if self.port.is_none() && self.retry_at.is_none_or(|t| now >= t) {
            match open() {
                Ok(port) => {
                    info!("{} ready", self.what);
                    self.port = Some(port);
                    self.error = None;
                }
                Err(e) => self.fail(now, e.to_string()),
            }
        }
        self.port.as_mut()
    }

    /// Drops the port (if any) and schedules a new attempt; logs each distinct failure once.
    fn fail(&mut self, now: Instant, error: String) {
        if self.error.as_ref() != Some(&error) {
            warn!("{}: {error} (retrying every {RETRY:?})", self.what);
        }
        self.port = None;
        self.error = Some(error);
        self.retry_at = Some(now + RETRY);
    }
}

type Sub<T> = (PubSub<T>, Subscriber<Ipc, T, ()>);
type GridSub = (ipc::GridService, Subscriber<Ipc, [u8], GridHeader>);
type FeaturesSub = (
    ipc::FeaturesService,
    Subscriber<Ipc, [FeatureRecord], FeaturesHeader>,
);
type CommandPort<T> = (Publisher<Ipc, T, ()>, Notifier<Ipc>);

/// All iceoryx2 resources of the viewer.
pub struct Source {
    grid: Lazy<GridSub>,
    radar: Lazy<Sub<Radar>>,
    features: Lazy<FeaturesSub>,
    localized: Lazy<Sub<LocalizedPose>>,
    slam: Lazy<Sub<SlamCorrection>>,
    status: Lazy<Sub<DriverStatus>>,
    fusion_status: Lazy<Sub<FusionStatus>>,
    readings: Lazy<Sub<Reading>>,
    commands: Lazy<CommandPort<ScanCommand>>,
    fusion_commands: Lazy<CommandPort<FusionCommand>>,
    next_liveness_check: Instant,
    // Declared last: dropped after the ports created from it.
    node: Node<Ipc>,
}

impl Debug for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Source")
            .field("node", self.node.name())
            .field("problem", &self.problem())
            .finish_non_exhaustive()
    }
}

impl Source {
    pub fn new(node: Node<Ipc>, now: Instant) -> Self {
        Self {
            grid: Lazy::new(ipc::GRID_SERVICE),
            radar: Lazy::new(ipc::RADAR_SERVICE),
            features: Lazy::new(ipc::FEATURES_SERVICE),
            localized: Lazy::new(ipc::LOCALIZED_POSE_SERVICE),
            slam: Lazy::new(ipc::SLAM_CORRECTION_SERVICE),
            status: Lazy::new(ipc::DRIVER_STATUS_SERVICE),
            fusion_status: Lazy::new(ipc::FUSION_STATUS_SERVICE),
            readings: Lazy::new(ipc::READINGS_SERVICE),
            commands: Lazy::new(ipc::COMMANDS_SERVICE),
            fusion_commands: Lazy::new(ipc::FUSION_COMMANDS_SERVICE),
            next_liveness_check: now,
            node,
        }
    }

    /// The first reason a port is not open, for the status panel.
    pub fn problem(&self) -> Option<String> {
        [
            &self.grid.error,
            &self.radar.error,
            &self.features.error,
            &self.localized.error,
            &self.slam.error,
            &self.status.error,
            &self.fusion_status.error,
            &self.readings.error,
            &self.commands.error,
            &self.fusion_commands.error,
        ]
        .into_iter()
        .flatten()
        .next()
        .cloned()
    }

    /// Takes the newest of everything into `app`. True when a stream moved (a snapshot, a
    /// reading, a pose): more is likely to follow at once. Statuses do not count: they come once
    /// a second whatever happens.
    pub fn poll(&mut self, app: &mut App, now: Instant) -> bool {
        let node = &self.node;
        let mut moved = false;

        if let Some((_, sub)) = self.grid.get(now, || {
            let service = ipc::grid_service(node)?;
            let sub = service
                .subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create grid subscriber", e))?;
            Ok((service, sub))
        }) {
            match newest(|| sub.receive()) {
                Ok(Some(sample)) => {
                    moved = true;
                    if let Err(e) = app.on_grid(sample.user_header(), sample.payload(), now) {
                        reject(app, "grid", &e);
                    }
                }
                Ok(None) => {}
                Err(e) => self.grid.fail(now, format!("receive: {e:?}")),
            }
        }

        if let Some((_, sub)) = self.radar.get(now, || subscribe(node, ipc::radar_service)) {
            match newest(|| sub.receive()) {
                Ok(Some(sample)) => {
                    moved = true;
                    if let Err(e) = app.on_radar(sample.payload(), now) {
                        reject(app, "radar", &e);
                    }
                }
                Ok(None) => {}
                Err(e) => self.radar.fail(now, format!("receive: {e:?}")),
            }
        }

        if let Some((_, sub)) = self.features.get(now, || {
            let service = ipc::features_service(node)?;
            let sub = service
                .subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create features subscriber", e))?;
            Ok((service, sub))
        }) {
            match newest(|| sub.receive()) {
                Ok(Some(sample)) => {
                    moved = true;
                    if let Err(e) = app.on_features(sample.user_header(), sample.payload(), now) {
                        reject(app, "features", &e);
                    }
                }
                Ok(None) => {}
                Err(e) => self.features.fail(now, format!("receive: {e:?}")),
            }
        }

        if let Some((_, sub)) = self
            .localized
            .get(now, || subscribe(node, ipc::localized_pose_service))
        {
            match newest(|| sub.receive()) {
                Ok(Some(sample)) => {
                    moved = true;
                    if let Err(e) = app.on_localized_pose(sample.payload(), now) {
                        reject(app, "localized pose", &e);
                    }
                }
                Ok(None) => {}
                Err(e) => self.localized.fail(now, format!("receive: {e:?}")),
            }
        }

        if let Some((_, sub)) = self
            .slam
            .get(now, || subscribe(node, ipc::slam_correction_service))
        {
            // Every sample: the newest may revise an earlier sweep, and the state is the latest
            // new sweep's. At most a buffer's worth a frame.
            let taken = each(
                SLAM_PER_POLL,
                || sub.receive(),
                |sample| {
                    moved = true;
                    if let Err(e) = app.on_slam_correction(sample.payload()) {
                        reject(app, "SLAM correction", &e);
                    }
                },
            );
            if let Err(e) = taken {
                self.slam.fail(now, format!("receive: {e:?}"));
            }
        }

        if let Some((_, sub)) = self
            .status
            .get(now, || subscribe(node, ipc::driver_status_service))
        {
            match newest(|| sub.receive()) {
                Ok(Some(sample)) => {
                    if let Err(e) = app.on_driver_status(sample.payload(), now) {
                        reject(app, "driver status", &e);
                    }
                }
                Ok(None) => {}
                Err(e) => self.status.fail(now, format!("receive: {e:?}")),
            }
        }

        if let Some((_, sub)) = self
            .fusion_status
            .get(now, || subscribe(node, ipc::fusion_status_service))
        {
            match newest(|| sub.receive()) {
                Ok(Some(sample)) => {
                    if let Err(e) = app.on_fusion_status(sample.payload(), now) {
                        reject(app, "fusion status", &e);
                    }
                }
                Ok(None) => {}
                Err(e) => self.fusion_status.fail(now, format!("receive: {e:?}")),
            }
        }

        if let Some((_, sub)) = self
            .readings
            .get(now, || subscribe(node, ipc::readings_service))
        {
            let taken = each(
                MAX_READINGS_PER_POLL,
                || sub.receive(),
                |sample| {
                    moved = true;
                    app.on_reading(sample.payload(), now);
                },
            );
            if let Err(e) = taken {
                self.readings.fail(now, format!("receive: {e:?}"));
            }
        }

        if now >= self.next_liveness_check {
            self.next_liveness_check = now + LIVENESS_PERIOD;
            let driver = self.live_publishers(|f| {
                if let Some((s, _)) = &self.status.port {
                    s.dynamic_config().list_publishers(f);
                }
            });
            // Whoever publishes the readings: a driver, or a replay standing in for one.
            let reading_publishers = self.live_publishers(|f| {
                if let Some((s, _)) = &self.readings.port {
                    s.dynamic_config().list_publishers(f);
                }
            });
            let fusion = self.live_publishers(|f| {
                if let Some((s, _)) = &self.grid.port {
                    s.dynamic_config().list_publishers(&mut *f);
                }
                if let Some((s, _)) = &self.radar.port {
                    s.dynamic_config().list_publishers(&mut *f);
                }
                if let Some((s, _)) = &self.features.port {
                    s.dynamic_config().list_publishers(&mut *f);
                }
                if let Some((s, _)) = &self.fusion_status.port {
                    s.dynamic_config().list_publishers(f);
                }
            });
            let replay = (!reading_publishers.is_empty()).then(|| {
                reading_publishers
                    .iter()
                    .any(|name| name.as_deref() == Some(ipc::REPLAY_NODE_NAME))
            });
            app.on_publishers(
                !driver.is_empty() || !reading_publishers.is_empty(),
                !fusion.is_empty(),
                replay,
                now,
            );
        }
        app.ipc_problem = self.problem();
        moved
    }

    /// The node names of the live processes behind the publishers that `list` reports (`None`
    /// for a node whose name cannot be read). A publisher of a process that was killed stays
    /// registered until someone cleans up, so presence alone is not enough; a node we may not
    /// inspect counts as alive.
    fn live_publishers(
        &self,
        list: impl FnOnce(&mut dyn FnMut(&PublisherDetails) -> CallbackProgression),
    ) -> Vec<Option<String>> {
        let mut nodes: Vec<UniqueNodeId> = Vec::new();
        list(&mut |details| {
            nodes.push(details.node_id);
            CallbackProgression::Continue
        });
        nodes
            .into_iter()
            .filter_map(|id| match Node::<Ipc>::state_of(self.node.config(), id) {
                Ok(Some(NodeState::Alive(view))) => Some(
                    view.details()
                        .as_ref()
                        .map(|d| d.name().as_str().to_owned()),
                ),
                Ok(Some(NodeState::Inaccessible(_))) => Some(None),
                _ => None,
            })
            .collect()
    }

    /// Publishes a command to the driver; the number of drivers that received it.
    pub fn send_scan(&mut self, cmd: ScanCommand, now: Instant) -> Result<usize, String> {
        let node = &self.node;
        send(
            &mut self.commands,
            now,
            || command_port(node, ipc::commands_service, ipc::COMMANDS_SERVICE),
            cmd,
        )
    }

    /// Publishes a command to the fusion engine; the number of engines that received it.
    pub fn send_fusion(&mut self, cmd: FusionCommand, now: Instant) -> Result<usize, String> {
        let node = &self.node;
        send(
            &mut self.fusion_commands,
            now,
            || {
                command_port(
                    node,
                    ipc::fusion_commands_service,
                    ipc::FUSION_COMMANDS_SERVICE,
                )
            },
            cmd,
        )
    }
}

/// Listeners on the wake-up events of the services whose producers notify (readings, grid, radar,
/// features): what the viewer sleeps on between frames.
pub fn wakeup_listeners(node: &Node<Ipc>) -> Result<Vec<Listener<Ipc>>, IpcError> {
    [
        ipc::READINGS_SERVICE,
        ipc::GRID_SERVICE,
        ipc::RADAR_SERVICE,
        ipc::FEATURES_SERVICE,
    ]
    .into_iter()
    .map(|name| ipc::wakeup_listener(node, name))
    .collect()
}

/// Drains a subscriber and returns its newest sample; older ones are released on the way.
fn newest<S>(
    mut receive: impl FnMut() -> Result<Option<S>, ReceiveError>,
) -> Result<Option<S>, ReceiveError> {
    let mut latest = None;
    while let Some(sample) = receive()? {
        latest = Some(sample);
    }
    Ok(latest)
}

/// Hands each sample of a subscriber to `take`, at most `max` of them (the rest wait for the next
/// frame). On an error the samples before it have been taken.
fn each<S>(
    max: usize,
    mut receive: impl FnMut() -> Result<Option<S>, ReceiveError>,
    mut take: impl FnMut(S),
) -> Result<(), ReceiveError> {
    for _ in 0..max {
        let Some(sample) = receive()? else { break };
        take(sample);
    }
    Ok(())
}

fn reject(app: &mut App, what: &str, error: &str) {
    let message = format!("ignored a {what} snapshot: {error}");
    if app.message.as_ref() != Some(&message) {
        warn!("{message}");
        app.message = Some(message);
    }
}

fn subscribe<T: Debug + ZeroCopySend>(
    node: &Node<Ipc>,
    open: fn(&Node<Ipc>) -> Result<PubSub<T>, IpcError>,
) -> Result<Sub<T>, IpcError> {
    let service = open(node)?;
    let sub = service
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new("create subscriber", e))?;
    Ok((service, sub))
}

/// A publisher plus a notifier on the service's wake-up event, so a consumer that sleeps on the
/// event reacts at once (one that polls just finds the sample).
fn command_port<T: Debug + ZeroCopySend>(
    node: &Node<Ipc>,
    open: fn(&Node<Ipc>) -> Result<PubSub<T>, IpcError>,
    name: &str,
) -> Result<CommandPort<T>, IpcError> {
    let publisher = open(node)?
        .publisher_builder()
        .create()
        .map_err(|e| IpcError::new(format!("create {name} publisher"), e))?;
    let notifier = ipc::wakeup_notifier(node, name)?;
    Ok((publisher, notifier))
}

fn send<T: Debug + ZeroCopySend>(
    port: &mut Lazy<CommandPort<T>>,
    now: Instant,
    open: impl FnOnce() -> Result<CommandPort<T>, IpcError>,
    cmd: T,
) -> Result<usize, String> {
    let what = port.what;
    let Some((publisher, notifier)) = port.get(now, open) else {
        return Err(port
            .error
            .clone()
            .unwrap_or_else(|| format!("{what} is not open")));
    };
    let receivers = publisher
        .send_copy(cmd)
        .map_err(|e| format!("send on {what}: {e:?}"))?;
    if let Err(e) = notifier.notify() {
        warn!("notify {what}: {e:?}");
    }
    Ok(receivers)
}
