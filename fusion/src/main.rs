//! `sonar-fusion`: the compute kernel of the pipeline as its own process.
//!
//! It sleeps on the readings' wake-up event, fuses every reading into both of the paper's maps
//! (see the crate docs), and publishes them as snapshots on `sonar/grid` (header + one byte per
//! cell, written straight into the loaned shared-memory sample) and `sonar/radar`, at most
//! `--max-rate` times a second (readings in between are coalesced) and always at the end of a
//! sweep. Commands on `sonar/fusion_commands` clear the maps or switch model, rule or preset.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Parser;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::waitset::WaitSetRunResult;
use sonar_common::ipc::{
    self, FusionCommand, GRID_SEGMENT_SLOTS, GridHeader, IpcArgs, IpcError, LAYOUT_VERSION, Radar,
    unix_time_ns,
};
use sonar_fusion::engine::Engine;
use sonar_fusion::{FusionConfig, ModelConfig, ModelKind, Preset, RuleConfig, RuleKind};
use tracing::{debug, info, warn};

/// How often idle publishers offer their last snapshot to subscribers that joined since.
const REFRESH_PERIOD: Duration = Duration::from_secs(1);

/// Builds the paper's two maps from `sonar/readings` and publishes them on `sonar/grid` (the
/// probability method's occupancy grid) and `sonar/radar` (the basic method's latest distance per
/// angle); takes commands on `sonar/fusion_commands`.
///
/// Settings come from the `[fusion]` table of --config, then from the flags below; --preset
/// replaces model, rule and no-echo handling, and --model/--rule/--clear-on-no-echo refine it.
///
/// Examples:
///   sonar-fusion                                  # recommended preset, 400² cells of 2 cm
///   sonar-fusion --preset paper                   # the paper exactly as written
///   sonar-fusion --rule dempster-shafer --cells 800 --resolution 0.01
#[derive(Debug, Parser)]
#[command(version, verbatim_doc_comment)]
struct Args {
    /// Pipeline configuration file (TOML); its `[fusion]` table is read, other tables ignored.
    #[arg(long, env = "SONAR_CONFIG")]
    config: Option<PathBuf>,
    /// Ready-made settings: `paper` or `recommended`.
    #[arg(long, value_parser = parse::<Preset>)]
    preset: Option<Preset>,
    /// Sensor model: `paper`, `log-odds` or `smooth` (with its default parameters).
    #[arg(long, value_parser = parse::<ModelKind>)]
    model: Option<ModelKind>,
    /// Combination rule: `bayes`, `log-odds`, `dempster-shafer` or `himm`.
    #[arg(long, value_parser = parse::<RuleKind>)]
    rule: Option<RuleKind>,
    /// Grid cells per side (the grid is square and centred on the sensor's start).
    #[arg(long)]
    cells: Option<u32>,
    /// Cell edge in metres.
    #[arg(long, allow_negative_numbers = true)]
    resolution: Option<f32>,
    /// Fuse readings without an echo as free space up to the maximum range.
    #[arg(long)]
    clear_on_no_echo: Option<bool>,
    /// Most snapshots published per second; readings in between are coalesced.
    #[arg(long, default_value_t = 10.0)]
    max_rate: f64,
    /// Readings kept to re-fuse when model, rule or preset change (0: switching clears the map).
    #[arg(long, default_value_t = 20_000)]
    history: usize,
    #[command(flatten)]
    ipc: IpcArgs,
}

fn parse<T: std::str::FromStr<Err: std::fmt::Display>>(s: &str) -> Result<T, String> {
    s.parse().map_err(|e: T::Err| e.to_string())
}

fn main() -> ExitCode {
    sonar_common::init_tracing();
    let args = Args::parse();
    sonar_common::report_exit("sonar-fusion", run(&args))
}

/// The configuration from the file, the preset and the flags, validated.
fn fusion_config(args: &Args) -> Result<FusionConfig> {
    let mut config = match &args.config {
        Some(path) => load_config(path)?,
        None => FusionConfig::default(),
    };
    if let Some(preset) = args.preset {
        let p = FusionConfig::preset(preset);
        config.model = p.model;
        config.rule = p.rule;
        config.clear_on_no_echo = p.clear_on_no_echo;
    }
    if let Some(kind) = args.model {
        config.model = ModelConfig::default_for(kind);
    }
    if let Some(kind) = args.rule {
        config.rule = RuleConfig::default_for(kind);
    }
    if let Some(cells) = args.cells {
        config.grid.cells = cells;
    }
    if let Some(resolution) = args.resolution {
        config.grid.resolution_m = resolution;
    }
    if let Some(clear) = args.clear_on_no_echo {
        config.clear_on_no_echo = clear;
    }
    config.validate().context("invalid fusion settings")?;
    Ok(config)
}

fn load_config(path: &Path) -> Result<FusionConfig> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read config file {}", path.display()))?;
    #[derive(serde::Deserialize)]
    struct File {
        #[serde(default)]
        fusion: FusionConfig,
    }
    let file: File =
        toml::from_str(&text).with_context(|| format!("invalid config file {}", path.display()))?;
    Ok(file.fusion)
}

/// Refuses a grid whose snapshots cannot fit in /dev/shm: tmpfs commits pages on first write, so
/// an oversized segment is created fine and the process dies of SIGBUS later.
fn check_shared_memory(cells: usize) -> Result<u64> {
    let slot = (std::mem::size_of::<GridHeader>() + cells + 64) as u64;
    let needed = slot * GRID_SEGMENT_SLOTS as u64;
    match nix::sys::statvfs::statvfs("/dev/shm") {
        Ok(fs) => {
            #[allow(clippy::unnecessary_cast)] // 32-bit targets have 32-bit block counts
            let available = fs.blocks_available() as u64 * fs.fragment_size() as u64;
            if needed > available {
                bail!(
                    "the grid is too large for shared memory: {GRID_SEGMENT_SLOTS} snapshots of \
                     {cells} cells need {} MiB in /dev/shm, {} MiB are free (fewer or coarser \
                     cells, or a larger /dev/shm)",
                    needed >> 20,
                    available >> 20
                );
            }
        }
        Err(e) => warn!("cannot check the free space of /dev/shm: {e}"),
    }
    Ok(needed)
}

fn run(args: &Args) -> Result<()> {
    if !(args.max_rate.is_finite() && args.max_rate > 0.0) {
        bail!("--max-rate must be a positive number of snapshots per second");
    }
    let config = fusion_config(args)?;
    let mut engine = Engine::new(config, args.history).context("invalid fusion settings")?;
    let footprint = check_shared_memory(engine.grid_len())?;
    info!(
        cells = config.grid.cells,
        resolution_m = config.grid.resolution_m,
        model = config.model.kind().name(),
        rule = config.rule.kind().name(),
        preset = config.matching_preset().map_or("custom", Preset::name),
        clear_on_no_echo = config.clear_on_no_echo,
        shm_mib = footprint as f64 / f64::from(1 << 20),
        "fusion engine ready"
    );

    let node = args.ipc.node("sonar-fusion")?;
    let ports = Ports::new(&node, engine.grid_len())?;
    let waitset = WaitSetBuilder::new()
        .create::<Ipc>()
        .map_err(|e| IpcError::new("create waitset", e))?;
    let readings_guard = waitset
        .attach_notification(&ports.readings_listener)
        .map_err(|e| IpcError::new("attach readings listener", e))?;
    let commands_guard = waitset
        .attach_notification(&ports.commands_listener)
        .map_err(|e| IpcError::new("attach commands listener", e))?;
    let min_interval = Duration::from_secs_f64(1.0 / args.max_rate);
    let tick = min_interval.clamp(Duration::from_millis(10), REFRESH_PERIOD);
    let tick_guard = waitset
        .attach_interval(tick)
        .map_err(|e| IpcError::new("attach interval", e))?;

    let mut out = Output {
        ports: &ports,
        seq: 0,
        dirty: true, // publish the empty maps at once, so a viewer knows fusion is there
        last_publish: None,
        last_refresh: Instant::now(),
        min_interval,
    };
    loop {
        let (mut readings, mut commands) = (false, false);
        let result = waitset
            .wait_and_process_once(|id| {
                readings |= id.has_event_from(&readings_guard);
                commands |= id.has_event_from(&commands_guard) || id.has_event_from(&tick_guard);
                CallbackProgression::Continue
            })
            .map_err(|e| IpcError::new("wait", e))?;
        if matches!(
            result,
            WaitSetRunResult::Interrupt | WaitSetRunResult::TerminationRequest
        ) {
            break;
        }
        if commands {
            drain_wakeups(&out.ports.commands_listener);
            out.handle_commands(&mut engine)?;
        }
        // The interval also ends up here: readings are drained whenever the process is awake, so
        // a lost wake-up can delay a reading by one tick at most.
        if readings {
            drain_wakeups(&out.ports.readings_listener);
        }
        out.take_pose(&mut engine)?;
        out.fuse_readings(&mut engine)?;
        out.publish_if_due(&engine, Instant::now())?;
    }
    info!(
        readings = engine.mapper().readings_fused(),
        snapshots = out.seq,
        "fusion stopped"
    );
    Ok(())
}

/// The process's iceoryx2 ports. Dropped before the node, leaving nothing in /dev/shm.
struct Ports {
    readings: iceoryx2::port::subscriber::Subscriber<Ipc, sonar_common::ipc::Reading, ()>,
    readings_listener: Listener,
    commands: iceoryx2::port::subscriber::Subscriber<Ipc, FusionCommand, ()>,
    commands_listener: Listener,
    pose: iceoryx2::port::subscriber::Subscriber<Ipc, sonar_common::ipc::Pose2D, ()>,
    grid: Publisher<Ipc, [u8], GridHeader>,
    grid_notifier: Notifier<Ipc>,
    radar: Publisher<Ipc, Radar, ()>,
    radar_notifier: Notifier<Ipc>,
}

type Listener = iceoryx2::port::listener::Listener<Ipc>;

/// Consumes the pending wake-ups (all of them), so the waitset sleeps again.
fn drain_wakeups(listener: &Listener) {
    if let Err(e) = listener.try_wait(|_| {}) {
        warn!("listener: {e:?}");
    }
}

impl Ports {
    fn new(node: &Node<Ipc>, grid_cells: usize) -> Result<Self> {
        Ok(Self {
            readings: ipc::readings_service(node)?
                .subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create readings subscriber", e))?,
            readings_listener: ipc::wakeup_listener(node, ipc::READINGS_SERVICE)?,
            commands: ipc::fusion_commands_service(node)?
                .subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create fusion command subscriber", e))?,
            commands_listener: ipc::wakeup_listener(node, ipc::FUSION_COMMANDS_SERVICE)?,
            pose: ipc::pose_service(node)?
                .subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create pose subscriber", e))?,
            grid: ipc::grid_service(node)?
                .publisher_builder()
                .initial_max_slice_len(grid_cells)
                .create()
                .map_err(|e| {
                    IpcError::new("create grid publisher (is another fusion running?)", e)
                })?,
            grid_notifier: ipc::wakeup_notifier(node, ipc::GRID_SERVICE)?,
            radar: ipc::radar_service(node)?
                .publisher_builder()
                .create()
                .map_err(|e| IpcError::new("create radar publisher", e))?,
            radar_notifier: ipc::wakeup_notifier(node, ipc::RADAR_SERVICE)?,
        })
    }
}

/// Publishing state: what is new since the last snapshot, and when that was.
struct Output<'a> {
    ports: &'a Ports,
    seq: u64,
    dirty: bool,
    last_publish: Option<Instant>,
    last_refresh: Instant,
    min_interval: Duration,
}

impl Output<'_> {
    fn handle_commands(&mut self, engine: &mut Engine) -> Result<()> {
        while let Some(sample) = self
            .ports
            .commands
            .receive()
            .map_err(|e| IpcError::new("receive fusion command", e))?
        {
            let command = *sample.payload();
            match engine.apply(&command) {
                Ok(()) => {
                    info!(?command, "fusion command");
                    self.dirty = true;
                    // A command's effect shows at once, whatever the rate limit.
                    self.publish(engine)?;
                }
                Err(e) => warn!(?command, "fusion command refused: {e}"),
            }
        }
        Ok(())
    }

    fn take_pose(&mut self, engine: &mut Engine) -> Result<()> {
        while let Some(sample) = self
            .ports
            .pose
            .receive()
            .map_err(|e| IpcError::new("receive pose", e))?
        {
            if !engine.set_pose(sample.payload()) {
                warn!(pose = ?sample.payload(), "pose refused: not finite");
            }
        }
        Ok(())
    }

    fn fuse_readings(&mut self, engine: &mut Engine) -> Result<()> {
        while let Some(sample) = self
            .ports
            .readings
            .receive()
            .map_err(|e| IpcError::new("receive reading", e))?
        {
            let reading = *sample.payload();
            drop(sample);
            if reading.layout_version != LAYOUT_VERSION {
                warn!(
                    version = reading.layout_version,
                    "reading of another layout version ignored"
                );
                continue;
            }
            if engine.starts_new_sweep(&reading) && self.dirty {
                // The finished sweep's maps, before the next sweep's first reading.
                self.publish(engine)?;
            }
            if !engine.fuse(&reading) {
                warn!(?reading, "reading refused by the kernels");
            }
            self.dirty = true;
        }
        Ok(())
    }

    fn publish_if_due(&mut self, engine: &Engine, now: Instant) -> Result<()> {
        let due = self
            .last_publish
            .is_none_or(|t| now.duration_since(t) >= self.min_interval);
        if self.dirty && due {
            self.publish(engine)?;
        } else if now.duration_since(self.last_refresh) >= REFRESH_PERIOD {
            // Late joiners get the history sample only on a send or an explicit update.
            self.last_refresh = now;
            for result in [
                self.ports.grid.update_connections(),
                self.ports.radar.update_connections(),
            ] {
                if let Err(e) = result {
                    warn!("update connections: {e:?}");
                }
            }
            self.notify();
        }
        Ok(())
    }

    fn publish(&mut self, engine: &Engine) -> Result<()> {
        self.seq += 1;
        let stamp = unix_time_ns();
        match self.ports.grid.loan_slice(engine.grid_len()) {
            Ok(mut sample) => {
                let counts = engine.encode_grid(sample.payload_mut());
                *sample.user_header_mut() = engine.grid_header(self.seq, stamp, counts);
                if let Err(e) = sample.send() {
                    warn!("send grid: {e:?}");
                }
            }
            // Every slot held by slow subscribers: skip this snapshot, the next one comes.
            Err(e) => warn!("loan grid sample: {e:?}"),
        }
        if let Err(e) = self.ports.radar.send_copy(engine.radar(self.seq, stamp)) {
            warn!("send radar: {e:?}");
        }
        self.notify();
        debug!(seq = self.seq, "snapshot published");
        let now = Instant::now();
        self.dirty = false;
        self.last_publish = Some(now);
        self.last_refresh = now;
        Ok(())
    }

    fn notify(&self) {
        for notifier in [&self.ports.grid_notifier, &self.ports.radar_notifier] {
            if let Err(e) = notifier.notify() {
                warn!("notify: {e:?}");
            }
        }
    }
}
