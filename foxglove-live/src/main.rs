//! `sonar-foxglove`: serves the pipeline live to Foxglove over Foxglove's WebSocket protocol, with
//! the subprotocols the `foxglove` crate 0.30 speaks (`foxglove.sdk.v1`, `.v1.1`) and, through a
//! thin front of this process's own (`front`), the older `foxglove.websocket.v1` that Lichtblick
//! and older Foxglove offer; with the same well-known channels a recording carries
//! (`docs/foxglove.md`): the map as `foxglove.Grid`, each sweep as `foxglove.LaserScan`, the
//! sensor's pose as `foxglove.FrameTransform`, the features and each reading's beam (at most 10 a
//! second) as `foxglove.SceneUpdate`.
//!
//! One more consumer of the pipeline's services: it polls its subscribers every 20 ms, converts
//! with `sonar_wellknown` (the recorder's conversion) and hands the bytes to the `foxglove` crate's
//! server, which runs its own tokio runtime on its own threads on 127.0.0.1 at a free port; the
//! front owns the public address and relays each client to it. Nothing async is written here.
//! Bound to 127.0.0.1 by default: the protocol has no authentication, so exposing it on a network
//! (`--host 0.0.0.0`) is a choice to make knowingly.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Parser;
use foxglove::{ChannelBuilder, PartialMetadata, RawChannel, Schema, WebSocketServer};
use sonar_common::flood::FloodGuard;
use sonar_common::ipc::IpcArgs;
use sonar_wellknown::live::Ports;
use sonar_wellknown::{Channel, Options, WellKnown};
use tracing::{debug, info};

mod front;

/// How often the subscribers are emptied. The readings' buffer holds 256, so even the simulator
/// at 100× real time (about 500 readings a second) loses none.
const POLL: Duration = Duration::from_millis(20);

/// Serves the running pipeline to Foxglove over its WebSocket protocol: the map (sonar/grid) as
/// foxglove.Grid on /foxglove/map, each sweep as foxglove.LaserScan on /foxglove/scan, the
/// sensor's pose as foxglove.FrameTransform on /foxglove/tf and the features as
/// foxglove.SceneUpdate on /foxglove/features, the latest reading's beam as foxglove.SceneUpdate on
/// /foxglove/beam. In Foxglove: Open connection → Foxglove WebSocket →
/// ws://127.0.0.1:8765 (docs/foxglove.md). Prints that address on standard output when ready.
///
/// Examples:
///   sonar-foxglove                              # ws://127.0.0.1:8765
///   sonar-foxglove --host 0.0.0.0 --port 9000   # reachable from other machines (no authentication!)
#[derive(Debug, Parser)]
#[command(name = "sonar-foxglove", version, verbatim_doc_comment)]
struct Args {
    /// Address to listen on. The default serves only this machine.
    #[arg(long, default_value = "127.0.0.1")]
    host: String,
    /// TCP port (0: any free one, printed at start).
    #[arg(long, default_value_t = 8765)]
    port: u16,
    /// Most clients served at once; more are closed at once (and counted in the log).
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u16).range(1..))]
    max_clients: u16,
    /// Seconds between maps sent (the newest snapshot each time; a client that connects gets the
    /// next one).
    #[arg(long, value_name = "SECONDS", default_value = "1", value_parser = sonar_common::parse_positive_seconds)]
    grid_period: Duration,
    #[command(flatten)]
    ipc: IpcArgs,
}

fn main() -> std::process::ExitCode {
    // A client can make the foxglove crate log a line per item of its request.
    let flood = FloodGuard::new(&["foxglove"]);
    sonar_common::flood::init_tracing(flood.clone());
    sonar_common::report_exit("sonar-foxglove", run(Args::parse(), &flood))
}

fn run(args: Args, flood: &FloodGuard) -> Result<()> {
    sonar_common::ipc::catch_termination_requests();
    let node = args.ipc.node("sonar-foxglove")?;
    // The stop signal is caught from before the node (so anyone who sees us can stop us
    // cleanly); one that came while the node was made ends the run here, before subscribing.
    if node.wait(Duration::ZERO).is_err() {
        info!("signal received before start");
        return Ok(());
    }
    let mut ports = Ports::open(&node)?;
    let mut converter = WellKnown::new(Options {
        ros2: false,
        grid_period_ns: u64::try_from(args.grid_period.as_nanos()).unwrap_or(u64::MAX),
    });
    let server = WebSocketServer::new()
        .name("sonar-foxglove")
        .bind("127.0.0.1", 0)
        .start_blocking()
        .context("cannot start the WebSocket server on 127.0.0.1")?;
    let inner = std::net::SocketAddr::from(([127, 0, 0, 1], server.port()));
    debug!(%inner, "the foxglove crate's server");
    let mut front = front::Front::bind(&args.host, args.port, inner, args.max_clients.into())
        .with_context(|| format!("cannot serve on {}:{}", args.host, args.port))?;
    let mut channels: BTreeMap<Channel, Arc<RawChannel>> = BTreeMap::new();
    for channel in converter.channels() {
        let spec = channel.spec();
        let raw = ChannelBuilder::new(spec.topic)
            .schema(Schema::new(
                spec.schema_name,
                spec.schema_encoding,
                spec.schema,
            ))
            .message_encoding(spec.message_encoding)
            .build_raw()
            .with_context(|| format!("create channel {}", spec.topic))?;
        channels.insert(channel, raw);
    }
    let url = format!("ws://{}:{}", args.host, front.port()?);
    info!(%url, "serving the pipeline to Foxglove");
    // The address on standard output, for scripts and tests that asked for any free port.
    println!("{url}");

    let mut sent = 0u64;
    let mut last_flood_report = std::time::Instant::now();
    while node.wait(POLL).is_ok() {
        front.accept_waiting();
        if last_flood_report.elapsed() >= sonar_common::flood::PERIOD {
            last_flood_report = std::time::Instant::now();
            flood.report();
        }
        ports.retry_missing(&node);
        for out in ports.drain(&mut converter) {
            if let Some(channel) = channels.get(&out.channel) {
                channel.log_with_meta(&out.data, PartialMetadata::with_log_time(out.stamp_ns));
                sent += 1;
            }
        }
    }
    flood.report();
    info!(
        messages = sent,
        connections_refused = front.refused(),
        "signal received: stopping"
    );
    server.stop().wait_blocking();
    Ok(())
}
