//! `sonar-bridge`: carries the pipeline's iceoryx2 services over zenoh (see the crate docs and
//! `docs/bridge.md`).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use clap::Parser;
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use sonar_bridge::certs::{self, Peer};
use sonar_bridge::channel::{self, Channel};
use sonar_bridge::config::{BridgeSection, Mode, Overrides, Settings};
use sonar_bridge::ports::{self, Reader, WriteError, Writer};
use sonar_bridge::wake::{Wake, waking_fifo};
use sonar_bridge::wire::FrameError;
use sonar_bridge::{ros2, session};
use sonar_common::flood::FloodGuard;
use sonar_common::ipc::{self, IpcArgs, IpcError};
use sonar_common::throttle::Throttle;
use sonar_wellknown::live::Ports;
use sonar_wellknown::{Options as WellKnownOptions, Output, WellKnown};
use tracing::{debug, info, warn};
use zenoh::Wait;
use zenoh::handlers::FifoChannelHandler;
use zenoh::key_expr::KeyExpr;
use zenoh::qos::{CongestionControl, Priority};
use zenoh::query::{Query, Reply};
use zenoh::sample::{Sample, SampleKind};

/// How often the services without a wake-up event (statuses, poses, corrections) are looked at:
/// the latency the bridge adds to them. Everything else wakes the bridge when it comes.
const STATE_POLL: Duration = Duration::from_millis(100);
/// How often idle local publishers hand their latest sample to new subscribers.
const REFRESH_PERIOD: Duration = Duration::from_secs(1);
/// How often the counters are logged (when they changed).
const STATS_PERIOD: Duration = Duration::from_secs(30);
/// `--mode ros2`: the map is published again after this long without a new one.
const MAP_REPEAT_PERIOD: Duration = Duration::from_secs(1);
/// How long `--list-robots` (and a remote without `--robot`) listens for robots.
const DISCOVERY_TIME: Duration = Duration::from_secs(3);
/// How long a query for the robot's latest states may take.
const QUERY_TIMEOUT: Duration = Duration::from_secs(5);

/// Carries the sonar pipeline's services between a robot and other machines over zenoh.
///
/// On the robot (--mode robot) it publishes readings, driver status, grid (LZ4-compressed,
/// rate-limited), radar, features, poses and fusion status to the keys `sonar/<robot>/<service>`
/// and forwards commands from those keys into the robot's iceoryx2. On a laptop (--mode remote)
/// it does the mirror image into the laptop's own iceoryx2, where the unchanged sonar-viewer,
/// sonar-export, sonar-record and Python scripts then run.
///
/// With --mode ros2 it publishes the map, the sweeps and the sensor's pose as the ROS 2 topics
/// /map (nav_msgs/msg/OccupancyGrid), /scan (sensor_msgs/msg/LaserScan) and /tf
/// (tf2_msgs/msg/TFMessage) in CDR under rmw_zenoh's keys (Jazzy and later), so a ROS 2 machine
/// with RMW_IMPLEMENTATION=rmw_zenoh_cpp sees them; by default it connects to the zenoh router on
/// this machine (tcp/127.0.0.1:7447, as every rmw_zenoh node does).
///
/// Settings come from the [bridge] table of --config, overridden by the flags below.
///
/// Security: by default the robot listens on this machine only (tcp/127.0.0.1:7447). Beyond it,
/// use mutual TLS: certificates from `sonar-bridge certs`, tls/ endpoints, and on the robot the
/// names of the peers that may read (--allow-read) or also command (--allow-command). Plain TCP
/// beyond localhost is refused unless asked for by name with --insecure.
///
/// Examples (docs/bridge.md):
///   sonar-bridge certs --dir certs robot1=192.168.1.20 laptop1     # once, on a trusted machine
///   sonar-bridge --robot robot1 --listen tls/192.168.1.20:7447 --ca certs/ca.pem \
///       --cert certs/robot1.pem --key certs/robot1.key --allow-command laptop1
///   sonar-bridge --mode remote --connect tls/192.168.1.20:7447 --ca certs/ca.pem \
///       --cert certs/laptop1.pem --key certs/laptop1.key        # on the laptop, then sonar-viewer
///   sonar-bridge --robot r1                                    # this machine only, no TLS
///   sonar-bridge --mode ros2                                   # /map, /scan, /tf to rmw_zenohd here
#[derive(Debug, Parser)]
#[command(version, verbatim_doc_comment, args_conflicts_with_subcommands = true)]
struct Args {
    #[command(subcommand)]
    command: Option<Command>,
    /// Pipeline configuration file (TOML) with a [bridge] table.
    #[arg(long, env = "SONAR_CONFIG")]
    config: Option<PathBuf>,
    /// robot: this machine's services out, commands in; remote: the mirror image; ros2: /map,
    /// /scan and /tf for ROS 2's rmw_zenoh [default: robot].
    #[arg(long, env = "SONAR_BRIDGE_MODE", value_enum)]
    mode: Option<Mode>,
    /// This robot's name (robot mode), or the robot to watch (remote mode; without it, the only
    /// robot seen).
    #[arg(long, env = "SONAR_ROBOT")]
    robot: Option<String>,
    /// zenoh endpoints to listen on, comma-separated, e.g. tls/192.168.1.20:7447 [default:
    /// tcp/127.0.0.1:7447 on a robot (this machine only), none on a remote].
    #[arg(long, env = "SONAR_BRIDGE_LISTEN", value_delimiter = ',')]
    listen: Vec<String>,
    /// zenoh endpoints to connect to, comma-separated, e.g. tls/192.168.1.20:7447.
    #[arg(long, env = "SONAR_BRIDGE_CONNECT", value_delimiter = ',')]
    connect: Vec<String>,
    /// Services to carry, comma-separated: readings, sweep_ends, driver_status, grid, radar,
    /// features, fusion_status, pose, localized_pose, commands, fusion_commands [default: all].
    #[arg(long, value_delimiter = ',')]
    services: Vec<String>,
    /// Seconds between the grid snapshots sent on the link, at least (0: every one) [default: 0.5],
    /// named as sonar-record's, sonar-export's and sonar-foxglove's. The same as --grid-max-rate
    /// 1/SECONDS.
    #[arg(long, value_name = "SECONDS", value_parser = parse_period, conflicts_with = "grid_max_rate")]
    grid_period: Option<f64>,
    /// Most grid snapshots per second on the link (0: every one) [default: 2]; the file's
    /// `max_rate_hz.grid`.
    #[arg(long, value_name = "HZ")]
    grid_max_rate: Option<f64>,
    /// Print the robots whose bridges are reachable, one name a line, and exit.
    #[arg(long)]
    list_robots: bool,
    /// The certificate authority's certificate (PEM): peers must show a certificate it signed.
    #[arg(long, env = "SONAR_BRIDGE_CA", value_name = "CA.pem")]
    ca: Option<PathBuf>,
    /// This bridge's certificate (PEM), from `sonar-bridge certs`.
    #[arg(long, env = "SONAR_BRIDGE_CERT", value_name = "NAME.pem")]
    cert: Option<PathBuf>,
    /// This bridge's private key (PEM).
    #[arg(long, env = "SONAR_BRIDGE_KEY", value_name = "NAME.key")]
    key: Option<PathBuf>,
    /// Robot over TLS: certificate names of the peers that may read its channels, comma-separated.
    #[arg(long, value_delimiter = ',', value_name = "NAMES")]
    allow_read: Vec<String>,
    /// Robot over TLS: certificate names of the peers that may read and command, comma-separated.
    #[arg(long, value_delimiter = ',', value_name = "NAMES")]
    allow_command: Vec<String>,
    /// Allow plain TCP beyond localhost: no authentication, no encryption, anyone who reaches the
    /// endpoint reads every channel and commands the robot. For a trusted network or a VPN only.
    #[arg(long)]
    insecure: bool,
    /// --mode ros2: the ROS domain (as ROS_DOMAIN_ID; rmw_zenoh puts it first in every key).
    #[arg(long, env = "ROS_DOMAIN_ID", default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=232))]
    ros_domain_id: u32,
    #[command(flatten)]
    ipc: IpcArgs,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Make the certificates of mutual TLS: a private certificate authority in DIR (made on the
    /// first call, reused later) and NAME.pem + NAME.key for each peer. Give a robot the host
    /// names or addresses laptops connect to it by (NAME=HOST,HOST). Existing files are never
    /// overwritten; keys are written owner-only.
    ///
    /// Example:
    ///   sonar-bridge certs --dir certs robot1=192.168.1.20,robot1.local laptop1 laptop2
    #[command(verbatim_doc_comment)]
    Certs {
        /// Directory of ca.pem, ca.key and the peers' files.
        #[arg(long, default_value = "sonar-certs")]
        dir: PathBuf,
        /// Days the peers' certificates are valid (the authority: five times as long).
        #[arg(long, default_value_t = 730)]
        days: u32,
        /// NAME or NAME=HOST[,HOST…] per peer; NAME is what --allow-read/--allow-command list.
        #[arg(required = true, value_name = "NAME[=HOSTS]")]
        peers: Vec<Peer>,
    },
}

impl Args {
    /// `--grid-max-rate`, or `--grid-period` as a rate.
    fn grid_max_rate_hz(&self) -> Option<f64> {
        self.grid_max_rate.or(self
            .grid_period
            .map(|p| if p == 0.0 { 0.0 } else { 1.0 / p }))
    }
}

/// `--grid-period`: seconds, 0 or more.
fn parse_period(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() && (0.0..1e9).contains(&x) => Ok(x),
        _ => Err(format!("{s:?} is not a number of seconds >= 0")),
    }
}

fn main() -> ExitCode {
    // A peer can make zenoh log a line per attempt (a TLS handshake without a certificate).
    let flood = FloodGuard::new(&["zenoh"]);
    sonar_common::flood::init_tracing(flood.clone());
    let args = Args::parse();
    sonar_common::report_exit("sonar-bridge", run(args, &flood))
}

fn run(args: Args, flood: &FloodGuard) -> Result<()> {
    if let Some(Command::Certs { dir, days, peers }) = &args.command {
        return make_certs(dir, peers, *days);
    }
    let file = match &args.config {
        Some(path) => BridgeSection::load(path)?,
        None => BridgeSection::default(),
    };
    let flags = Overrides {
        mode: args.mode.or(args.list_robots.then_some(Mode::Remote)),
        robot: args.robot.clone(),
        listen: args.listen.clone(),
        connect: args.connect.clone(),
        services: args.services.clone(),
        grid_max_rate_hz: args.grid_max_rate_hz(),
        insecure: args.insecure,
        ca: args.ca.clone(),
        cert: args.cert.clone(),
        key: args.key.clone(),
        allow_read: args.allow_read.clone(),
        allow_command: args.allow_command.clone(),
    };
    let settings = Settings::resolve(&file, &flags)?;
    if !settings.insecure_endpoints.is_empty() {
        warn!(
            endpoints = ?settings.insecure_endpoints,
            "INSECURE (asked for by --insecure): plain TCP beyond localhost, without \
             authentication or encryption; anyone who reaches these endpoints reads every channel \
             and commands the robot. Use mutual TLS (docs/bridge.md, Security)"
        );
    }
    if let Some(tls) = &settings.tls {
        warn_if_others_can_read(&tls.key);
    }
    let session = open_session(&settings)?;
    if args.list_robots {
        for robot in robots_seen(&session)? {
            println!("{robot}");
        }
        return close(session);
    }
    let side = match settings.mode {
        Mode::Robot => Side::Robot,
        Mode::Remote => Side::Remote,
        Mode::Ros2 => {
            let published = publish_ros2(&session, &args, &settings, flood);
            close(session)?;
            return published;
        }
    };
    let robot = match &settings.robot {
        Some(robot) => robot.clone(),
        None => choose_robot(&session)?,
    };
    let node = args
        .ipc
        .node(&format!("sonar-bridge-{robot}"))
        .context("iceoryx2")?;
    info!(
        mode = ?settings.mode,
        robot,
        listen = ?settings.listen,
        connect = ?settings.connect,
        channels = ?settings.channels,
        tls = settings.tls.is_some(),
        allow_read = ?settings.allow_read,
        allow_command = ?settings.allow_command,
        "bridge running"
    );
    let mut bridge = Bridge::new(&session, &node, &settings, side, &robot)?;
    let ran = bridge.run(flood);
    bridge.log_stats(true);
    flood.report();
    drop(bridge);
    let closed = close(session);
    ran.and(closed)
}

/// `--mode ros2`: one ROS 2 topic's publisher, its liveliness token (which makes it visible in the
/// ROS 2 graph while held) and its count of samples, which is also its last sequence number.
struct RosPublisher {
    channel: sonar_wellknown::Channel,
    publisher: zenoh::pubsub::Publisher<'static>,
    gid: [u8; ros2::GID_LEN],
    _token: zenoh::liveliness::LivelinessToken,
    sent: i64,
}

impl RosPublisher {
    fn counts(all: &[Self]) -> Vec<(&'static str, i64)> {
        all.iter().map(|p| (p.channel.topic(), p.sent)).collect()
    }
}

/// `--mode ros2`: the pipeline's map, sweeps and pose as ROS 2's `/map`, `/scan` and `/tf`
/// (`sonar_bridge::ros2`) until SIGINT/SIGTERM.
fn publish_ros2(
    session: &zenoh::Session,
    args: &Args,
    settings: &Settings,
    flood: &FloodGuard,
) -> Result<()> {
    let domain = args.ros_domain_id;
    let node = args.ipc.node("sonar-bridge-ros2").context("iceoryx2")?;
    // iceoryx2 installs its SIGINT/SIGTERM handler on the first wait.
    if node.wait(Duration::ZERO).is_err() {
        info!("signal received before start");
        return Ok(());
    }
    let mut ports = Ports::open(&node)?;
    let grid_period = settings
        .min_interval
        .get(&Channel::Grid)
        .copied()
        .unwrap_or(Duration::ZERO);
    let mut converter = WellKnown::new(WellKnownOptions {
        ros2: true,
        grid_period_ns: u64::try_from(grid_period.as_nanos()).unwrap_or(u64::MAX),
    });
    let zid = session.zid().to_string();
    let liveliness = session.liveliness();
    let node_token = ros2::node_token(domain, &zid);
    let _node_token = liveliness
        .declare_token(node_token.clone())
        .wait()
        .map_err(zerr(format!("declare token {node_token}")))?;
    let mut publishers = Vec::new();
    for topic in &ros2::TOPICS {
        let key = topic.key(domain);
        let token_key = topic.token(domain, &zid);
        let publisher = session
            .declare_publisher(key.clone())
            // A dead link must not stall the loop: drop rather than block.
            .congestion_control(CongestionControl::Drop)
            .wait()
            .map_err(zerr(format!("declare publisher {key}")))?;
        let token = liveliness
            .declare_token(token_key.clone())
            .wait()
            .map_err(zerr(format!("declare token {token_key}")))?;
        publishers.push(RosPublisher {
            channel: topic.channel,
            publisher,
            gid: ros2::gid(&token_key),
            _token: token,
            sent: 0,
        });
    }
    info!(
        domain,
        listen = ?settings.listen,
        connect = ?settings.connect,
        tls = settings.tls.is_some(),
        keys = ?ros2::TOPICS.iter().map(|t| t.key(domain)).collect::<Vec<_>>(),
        "publishing /map, /scan and /tf for ROS 2 (rmw_zenoh)"
    );
    // The map again once a period without a new one (the one kept back by the rate limit, else
    // the last): a ROS 2 subscriber that comes late (RViz opened later) gets it within a period.
    let map_period = grid_period.max(MAP_REPEAT_PERIOD);
    let mut last_map: Option<Vec<u8>> = None;
    let mut map_at = Instant::now();
    let mut stats_at = Instant::now();
    // Readings, grid and features wake the loop; poses and corrections have no wake-up event, so
    // they are looked at every STATE_POLL (the /tf's pace).
    let waitset = WaitSetBuilder::new()
        .create::<Ipc>()
        .map_err(|e| IpcError::new("create waitset", e))?;
    let wakeups: Vec<_> = [
        ipc::READINGS_SERVICE,
        ipc::GRID_SERVICE,
        ipc::FEATURES_SERVICE,
    ]
    .into_iter()
    .filter_map(|name| {
        ipc::wakeup_listener(&node, name)
            .inspect_err(|e| warn!("{e}: looked at every {STATE_POLL:?} instead"))
            .ok()
    })
    .collect();
    let _wakeup_guards = ipc::attach_all(&waitset, &wakeups)?;
    loop {
        for listener in &wakeups {
            ipc::drain_wakeups(listener)?;
        }
        ports.retry_missing(&node);
        let mut outputs = ports.drain(&mut converter);
        if map_at.elapsed() >= map_period {
            let flushed = converter.flush_map();
            if flushed.is_empty()
                && let Some(data) = &last_map
            {
                outputs.push(Output {
                    channel: sonar_wellknown::Channel::Ros2Map,
                    stamp_ns: 0,
                    data: data.clone(),
                });
            }
            outputs.extend(flushed);
            map_at = Instant::now();
        }
        for out in outputs {
            if out.channel == sonar_wellknown::Channel::Ros2Map {
                last_map = Some(out.data.clone());
                map_at = Instant::now();
            }
            let Some(topic) = publishers.iter_mut().find(|p| p.channel == out.channel) else {
                continue;
            };
            // The sequence number counts from 1, as rmw_zenoh's.
            topic.sent += 1;
            let now_ns = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX));
            if let Err(e) = topic
                .publisher
                .put(out.data)
                .attachment(ros2::attachment(topic.sent, now_ns, &topic.gid))
                .wait()
            {
                warn!("publishing {} failed: {e}", out.channel.topic());
            }
        }
        if stats_at.elapsed() >= STATS_PERIOD {
            stats_at = Instant::now();
            flood.report();
            info!(counts = ?RosPublisher::counts(&publishers), "published");
        }
        let due = (map_at + map_period).min(Instant::now() + STATE_POLL);
        if !ipc::sleep_until(&waitset, due)? {
            break;
        }
    }
    flood.report();
    info!(
        counts = ?RosPublisher::counts(&publishers),
        "signal received: stopping"
    );
    Ok(())
}

fn close(session: zenoh::Session) -> Result<()> {
    session
        .close()
        .wait()
        .map_err(|e| anyhow!("close the zenoh session: {e}"))
}

fn open_session(settings: &Settings) -> Result<zenoh::Session> {
    let config = session::zenoh_config(settings, settings.robot.as_deref())?;
    zenoh::open(config)
        .wait()
        .map_err(|e| anyhow!("open the zenoh session (listen {:?}): {e}", settings.listen))
}

/// A private key others can read is as good as theirs: say so (as ssh would; not refused, since a
/// copy made with the default umask is 0644 until fixed).
fn warn_if_others_can_read(key: &std::path::Path) {
    use std::os::unix::fs::PermissionsExt;
    if let Ok(meta) = std::fs::metadata(key)
        && meta.permissions().mode() & 0o077 != 0
    {
        warn!(
            key = %key.display(),
            mode = format!("{:o}", meta.permissions().mode() & 0o777),
            "the private key is readable by others: chmod 600 it"
        );
    }
}

fn make_certs(dir: &std::path::Path, peers: &[Peer], days: u32) -> Result<()> {
    let made = certs::make(dir, peers, days)?;
    let ca = dir.join(certs::CA_CERT);
    if made.new_authority {
        println!(
            "made the authority: {} (copy to every machine) and {} (keep it here, nowhere else)",
            ca.display(),
            dir.join(certs::CA_KEY).display()
        );
    } else {
        println!("signed with the authority in {}", ca.display());
    }
    for (cert, key) in made.peers {
        println!(
            "{} + {} (copy both to that machine only)",
            cert.display(),
            key.display()
        );
    }
    Ok(())
}

/// The names of the robots whose bridges are seen within [`DISCOVERY_TIME`], sorted. Watches
/// the robots' tokens for that long, since the connections to the endpoints may still be forming.
fn robots_seen(session: &zenoh::Session) -> Result<Vec<String>> {
    let tokens = session
        .liveliness()
        .declare_subscriber(channel::ALL_ROBOT_TOKENS)
        .history(true)
        .wait()
        .map_err(|e| anyhow!("watch for robots: {e}"))?;
    let deadline = Instant::now() + DISCOVERY_TIME;
    let mut robots = std::collections::BTreeSet::new();
    while let Some(left) = deadline.checked_duration_since(Instant::now()) {
        let Ok(Some(sample)) = tokens.recv_timeout(left) else {
            break;
        };
        if let Some(robot) = channel::robot_of_token(sample.key_expr().as_str()) {
            match sample.kind() {
                SampleKind::Put => robots.insert(robot.to_owned()),
                SampleKind::Delete => robots.remove(robot),
            };
        }
    }
    Ok(robots.into_iter().collect())
}

fn choose_robot(session: &zenoh::Session) -> Result<String> {
    let robots = robots_seen(session)?;
    match robots.as_slice() {
        [one] => {
            info!(robot = one, "the only robot seen");
            Ok(one.clone())
        }
        [] => bail!("no robot seen within {DISCOVERY_TIME:?}: give --robot NAME"),
        many => bail!(
            "{} robots seen ({}): choose one with --robot NAME",
            many.len(),
            many.join(", ")
        ),
    }
}

/// What happened on one channel since the start.
#[derive(Debug, Default, Clone, PartialEq)]
struct Counts {
    messages: u64,
    bytes: u64,
    /// Held back by the rate limit and replaced by a newer one before it could go.
    dropped_for_rate: u64,
    /// Another layout version: refused.
    version_mismatches: u64,
    /// Damaged, oversized or inconsistent frames: refused before they were decoded further.
    rejected: u64,
    /// The local publication (or the link's) failed.
    failures: u64,
}

/// A local service whose samples go out on the link.
struct Outbound {
    channel: Channel,
    read: Reader,
    publisher: zenoh::pubsub::Publisher<'static>,
    min_interval: Option<Duration>,
    /// Its producers' wake-up event wakes the bridge; else it is looked at every STATE_POLL.
    woken: bool,
    last_sent: Option<Instant>,
    /// A message the rate limit holds back; a newer one replaces it.
    pending: Option<Vec<u8>>,
    /// The latest message sent of a state channel, for late joiners' queries.
    latest: Option<Vec<u8>>,
    counts: Counts,
}

/// A key whose messages go into a local service.
struct Inbound {
    channel: Channel,
    write: Writer,
    subscriber: zenoh::pubsub::Subscriber<FifoChannelHandler<Sample>>,
    /// The last message published locally, so a query's answer does not repeat it.
    last_written: Option<Vec<u8>>,
    counts: Counts,
    refused_log: Throttle,
}

/// Which end of a link of sonar's own frames this bridge is (`--mode robot` or `remote`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Side {
    Robot,
    Remote,
}

struct Bridge {
    side: Side,
    robot: String,
    outbound: Vec<Outbound>,
    inbound: Vec<Inbound>,
    /// Robot: answers queries for the latest states.
    queryable: Option<zenoh::query::Queryable<FifoChannelHandler<Query>>>,
    /// Remote: the robot's token (the link); robot: the remotes' tokens.
    peers: zenoh::pubsub::Subscriber<FifoChannelHandler<Sample>>,
    _token: zenoh::liveliness::LivelinessToken,
    /// Remote: outstanding queries for the robot's latest states.
    queries: Vec<FifoChannelHandler<Reply>>,
    session: zenoh::Session,
    link_up: bool,
    link_ups: u64,
    link_downs: u64,
    last_refresh: Instant,
    last_stats: Instant,
    logged: BTreeMap<Channel, Counts>,
    /// Poked by every zenoh delivery.
    wake: Wake,
    /// The wake-up events of the outbound services that have one (`run` takes them).
    wakeups: Vec<Listener<Ipc>>,
}

fn zerr(what: String) -> impl FnOnce(zenoh::Error) -> anyhow::Error {
    move |e| anyhow!("{what}: {e}")
}

impl Bridge {
    fn new(
        session: &zenoh::Session,
        node: &Node<iceoryx2::service::ipc::Service>,
        settings: &Settings,
        side: Side,
        robot: &str,
    ) -> Result<Self> {
        let wake = Wake::new().context("cannot create the wake-up socket")?;
        let mut outbound = Vec::new();
        let mut inbound = Vec::new();
        let mut wakeups = Vec::new();
        for &channel in &settings.channels {
            let key = channel.key(robot);
            // Telemetry goes out from the robot, commands from the remote.
            let goes_out = channel.is_command() == (side == Side::Remote);
            if goes_out {
                let key_expr = KeyExpr::try_from(key.clone()).map_err(zerr(key.clone()))?;
                let publisher = session
                    .declare_publisher(key_expr)
                    // A dead link must not stall the loop: drop rather than block.
                    .congestion_control(CongestionControl::Drop)
                    .priority(if channel.is_command() {
                        Priority::InteractiveHigh
                    } else {
                        Priority::Data
                    })
                    .wait()
                    .map_err(zerr(format!("declare publisher {key}")))?;
                let woken = channel.wakeup_event().is_some_and(|event| {
                    match ipc::wakeup_listener(node, event) {
                        Ok(listener) => {
                            wakeups.push(listener);
                            true
                        }
                        // E.g. a socket path beyond the system's limit under a long --iox-root.
                        Err(e) => {
                            warn!("{e}: {channel} is looked at every {STATE_POLL:?} instead");
                            false
                        }
                    }
                });
                outbound.push(Outbound {
                    channel,
                    read: ports::reader(node, channel)?,
                    publisher,
                    min_interval: settings.min_interval.get(&channel).copied(),
                    woken,
                    last_sent: None,
                    pending: None,
                    latest: None,
                    counts: Counts::default(),
                });
            } else {
                let subscriber = session
                    .declare_subscriber(key.clone())
                    .with(waking_fifo(&wake.poke()))
                    .wait()
                    .map_err(zerr(format!("declare subscriber {key}")))?;
                inbound.push(Inbound {
                    channel,
                    write: ports::writer(node, channel)?,
                    subscriber,
                    last_written: None,
                    counts: Counts::default(),
                    refused_log: Throttle::new(Duration::from_secs(10)),
                });
            }
        }
        let liveliness = session.liveliness();
        let (token_key, watched) = match side {
            Side::Robot => (channel::robot_token(robot), channel::remote_tokens(robot)),
            Side::Remote => (
                channel::remote_token(robot, &session.zid().to_string()),
                channel::robot_token(robot),
            ),
        };
        let token = liveliness
            .declare_token(token_key.clone())
            .wait()
            .map_err(zerr(format!("declare token {token_key}")))?;
        let peers = liveliness
            .declare_subscriber(watched.clone())
            .history(true)
            .with(waking_fifo(&wake.poke()))
            .wait()
            .map_err(zerr(format!("watch {watched}")))?;
        let queryable = match side {
            Side::Robot => {
                let all = format!("{}/{robot}/**", channel::KEY_ROOT);
                Some(
                    session
                        .declare_queryable(all.clone())
                        .with(waking_fifo(&wake.poke()))
                        .wait()
                        .map_err(zerr(format!("declare queryable {all}")))?,
                )
            }
            Side::Remote => None,
        };
        let now = Instant::now();
        Ok(Self {
            side,
            robot: robot.to_owned(),
            outbound,
            inbound,
            queryable,
            peers,
            _token: token,
            queries: Vec::new(),
            session: session.clone(),
            link_up: false,
            link_ups: 0,
            link_downs: 0,
            last_refresh: now,
            last_stats: now,
            logged: BTreeMap::new(),
            wake,
            wakeups,
        })
    }

    /// Until Ctrl-C or SIGTERM.
    fn run(&mut self, flood: &FloodGuard) -> Result<()> {
        let waitset = WaitSetBuilder::new()
            .create::<Ipc>()
            .map_err(|e| IpcError::new("create waitset", e))?;
        let watched = self
            .wake
            .watched()
            .context("the wake-up socket has no descriptor")?;
        let _wake_guard = waitset
            .attach_notification(&watched)
            .map_err(|e| IpcError::new("attach the wake-up socket", e))?;
        // Out of `self`, which the loop changes while the waitset holds them.
        let wakeups = std::mem::take(&mut self.wakeups);
        let _wakeup_guards = ipc::attach_all(&waitset, &wakeups)?;
        let mut last_flood_report = Instant::now();
        loop {
            // Before taking what came: what arrives meanwhile pokes again.
            self.wake.drain();
            for listener in &wakeups {
                ipc::drain_wakeups(listener)?;
            }
            let now = Instant::now();
            self.watch_peers();
            self.pump_out(now);
            self.pump_in();
            self.answer_queries();
            self.take_replies();
            if now.duration_since(self.last_refresh) >= REFRESH_PERIOD {
                self.last_refresh = now;
                for inbound in &mut self.inbound {
                    inbound.write.refresh();
                }
            }
            if now.duration_since(last_flood_report) >= sonar_common::flood::PERIOD {
                last_flood_report = now;
                flood.report();
            }
            if now.duration_since(self.last_stats) >= STATS_PERIOD {
                self.last_stats = now;
                self.log_stats(false);
            }
            let due = self
                .next_due(now)
                .min(last_flood_report + sonar_common::flood::PERIOD);
            if !ipc::sleep_until(&waitset, due)? {
                info!("stopping on a signal");
                return Ok(());
            }
        }
    }

    /// The next moment something is due without a wake-up: the refresh, the counters' log, a
    /// rate-limited message's turn, a look at the services that have no wake-up event.
    fn next_due(&self, now: Instant) -> Instant {
        let polled = self
            .outbound
            .iter()
            .any(|out| !out.woken)
            .then_some(now + STATE_POLL);
        let rate_limited = self.outbound.iter().filter_map(|out| {
            let interval = out.min_interval?;
            out.pending.as_ref()?;
            Some(out.last_sent.map_or(now, |last| last + interval))
        });
        [
            self.last_refresh + REFRESH_PERIOD,
            self.last_stats + STATS_PERIOD,
        ]
        .into_iter()
        .chain(polled)
        .chain(rate_limited)
        .min()
        .unwrap_or(now + REFRESH_PERIOD)
    }

    /// Link up and down: the robot's token seen from a remote, the remotes' tokens from a robot.
    fn watch_peers(&mut self) {
        while let Ok(Some(sample)) = self.peers.try_recv() {
            let key = sample.key_expr().as_str();
            match (self.side, sample.kind()) {
                (Side::Remote, SampleKind::Put) => {
                    self.link_up = true;
                    self.link_ups += 1;
                    info!(
                        robot = self.robot,
                        ups = self.link_ups,
                        "link up: robot reachable"
                    );
                    self.ask_latest();
                }
                (Side::Remote, SampleKind::Delete) => {
                    self.link_up = false;
                    self.link_downs += 1;
                    warn!(
                        robot = self.robot,
                        downs = self.link_downs,
                        "link down: robot unreachable; retrying"
                    );
                }
                (Side::Robot, SampleKind::Put) => {
                    self.link_ups += 1;
                    info!(remote = key, "remote bridge connected");
                }
                (Side::Robot, SampleKind::Delete) => {
                    self.link_downs += 1;
                    warn!(remote = key, "remote bridge gone (left or link down)");
                }
            }
        }
    }

    /// Local samples onto the link, within each channel's rate.
    fn pump_out(&mut self, now: Instant) {
        let link_up = self.link_up || self.side == Side::Robot;
        for out in &mut self.outbound {
            loop {
                match (out.read)() {
                    Ok(Some(frame)) => {
                        if out.pending.replace(frame).is_some() {
                            out.counts.dropped_for_rate += 1;
                        }
                        // Streams go at once, message by message.
                        if out.min_interval.is_none() {
                            out.send(now, link_up);
                        }
                    }
                    Ok(None) => break,
                    Err(e) => {
                        out.counts.failures += 1;
                        warn!(channel = %out.channel, "{e}");
                        break;
                    }
                }
            }
            let due = match (out.min_interval, out.last_sent) {
                (Some(interval), Some(last)) => now.duration_since(last) >= interval,
                _ => true,
            };
            if due {
                out.send(now, link_up);
            }
        }
    }

    /// Messages from the link into local services.
    fn pump_in(&mut self) {
        for inbound in &mut self.inbound {
            while let Ok(Some(sample)) = inbound.subscriber.try_recv() {
                inbound.take_sample(&sample);
            }
        }
    }

    /// Robot: a late joiner asks for the latest states; each is answered from memory.
    fn answer_queries(&mut self) {
        let Some(queryable) = &self.queryable else {
            return;
        };
        while let Ok(Some(query)) = queryable.try_recv() {
            for out in &self.outbound {
                let Some(latest) = &out.latest else { continue };
                let key = out.publisher.key_expr();
                if query.key_expr().intersects(key)
                    && let Err(e) = query.reply(key.clone(), latest.clone()).wait()
                {
                    debug!(channel = %out.channel, "reply to a query: {e}");
                }
            }
        }
    }

    /// Remote: asks the robot for its latest states (at start and after the link came back).
    fn ask_latest(&mut self) {
        let all = format!("{}/{}/**", channel::KEY_ROOT, self.robot);
        match self
            .session
            .get(all)
            .timeout(QUERY_TIMEOUT)
            .with(waking_fifo(&self.wake.poke()))
            .wait()
        {
            Ok(replies) => self.queries.push(replies),
            Err(e) => warn!("ask the robot for its latest states: {e}"),
        }
    }

    fn take_replies(&mut self) {
        let (inbound, robot) = (&mut self.inbound, &self.robot);
        self.queries.retain(|replies| {
            loop {
                match replies.try_recv() {
                    Ok(Some(reply)) => {
                        let Ok(sample) = reply.result() else { continue };
                        let key = sample.key_expr().as_str();
                        // The whole key: `…/localized_pose` ends with `pose` too.
                        if let Some(i) = inbound.iter_mut().find(|i| key == i.channel.key(robot)) {
                            i.take_sample(sample);
                        }
                    }
                    Ok(None) => return true,
                    Err(_) => return false,
                }
            }
        });
    }

    /// Logs every channel's counts (only those that changed since the last time, unless `all`).
    fn log_stats(&mut self, all: bool) {
        let channels = self
            .outbound
            .iter()
            .map(|o| (o.channel, &o.counts, "out"))
            .chain(self.inbound.iter().map(|i| (i.channel, &i.counts, "in")));
        for (channel, counts, direction) in channels {
            if all || self.logged.get(&channel) != Some(counts) {
                info!(
                    %channel,
                    direction,
                    messages = counts.messages,
                    bytes = counts.bytes,
                    dropped_for_rate = counts.dropped_for_rate,
                    version_mismatches = counts.version_mismatches,
                    rejected = counts.rejected,
                    failures = counts.failures,
                    "counts"
                );
                self.logged.insert(channel, counts.clone());
            }
        }
        if all {
            info!(
                link_ups = self.link_ups,
                link_downs = self.link_downs,
                "link"
            );
        }
    }
}

impl Outbound {
    /// Sends the pending message, if any.
    fn send(&mut self, now: Instant, link_up: bool) {
        let Some(frame) = self.pending.take() else {
            return;
        };
        self.last_sent = Some(now);
        self.counts.messages += 1;
        self.counts.bytes += frame.len() as u64;
        if !link_up {
            // A command while the robot is unreachable goes nowhere: say so.
            warn!(channel = %self.channel, "the robot is unreachable: message dropped");
        }
        let kept = self.channel.is_state().then(|| frame.clone());
        if let Err(e) = self.publisher.put(frame).wait() {
            self.counts.failures += 1;
            warn!(channel = %self.channel, "publish: {e}");
        }
        if kept.is_some() {
            self.latest = kept;
        }
    }
}

impl Inbound {
    /// A message from the link: refused unread if it is longer than the channel's payload can be
    /// (zenoh has already capped it at the longest of all inbound channels), else published.
    fn take_sample(&mut self, sample: &Sample) {
        let len = sample.payload().len();
        let cap = self.write.max_frame_len();
        if len > cap {
            self.refuse(&WriteError::Frame(FrameError::FrameTooLong { len, cap }));
            return;
        }
        self.take(&sample.payload().to_bytes());
    }

    /// Publishes a frame locally, unless it repeats the last one or is refused.
    fn take(&mut self, frame: &[u8]) {
        if self.channel.is_state() && self.last_written.as_deref() == Some(frame) {
            return;
        }
        match self.write.write(frame) {
            Ok(()) => {
                self.counts.messages += 1;
                self.counts.bytes += frame.len() as u64;
                if self.channel.is_state() {
                    self.last_written = Some(frame.to_vec());
                }
            }
            Err(e) => self.refuse(&e),
        }
    }

    /// Counts a message that was not published, and logs it (at most once per 10 s, with the
    /// number left out since).
    fn refuse(&mut self, e: &WriteError) {
        match e {
            WriteError::Frame(f) if f.is_version_mismatch() => self.counts.version_mismatches += 1,
            WriteError::Frame(_) => self.counts.rejected += 1,
            WriteError::Ipc(_) => self.counts.failures += 1,
        }
        if let Some(left_out) = self.refused_log.allow(Instant::now()) {
            warn!(
                channel = %self.channel,
                left_out,
                "refused a message: {e}"
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--grid-period` is named and counted as elsewhere, `--grid-max-rate` still works, and
    /// not both (issue 28).
    #[test]
    fn the_grid_pace_is_a_period_or_a_rate() {
        let rate = |flags: &[&str]| {
            Args::try_parse_from([&["sonar-bridge"], flags].concat()).map(|a| a.grid_max_rate_hz())
        };
        assert_eq!(rate(&["--grid-period", "0.25"]).ok(), Some(Some(4.0)));
        assert_eq!(rate(&["--grid-period", "0"]).ok(), Some(Some(0.0)));
        assert_eq!(rate(&["--grid-max-rate", "2"]).ok(), Some(Some(2.0)));
        assert_eq!(rate(&[]).ok(), Some(None));
        assert!(rate(&["--grid-period", "-1"]).is_err());
        assert!(rate(&["--grid-period", "1", "--grid-max-rate", "1"]).is_err());
    }
}
