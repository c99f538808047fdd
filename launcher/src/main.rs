//! `sonar-pipeline`: the whole pipeline with one command.
//!
//! Starts the simulator (or uses a real serial port), the driver, the fusion engine and the
//! terminal viewer as separate OS processes sharing one configuration and one iceoryx2 namespace,
//! restarts a process that dies, and stops them all when the viewer quits (`q`), on Ctrl-C or on
//! SIGTERM. The viewer owns the terminal; the other processes log to files in the log directory.
//! The processes die with the launcher, even with a `kill -9` of it (Linux's parent-death signal).

mod config;
mod signals;
mod terminal;

use std::collections::VecDeque;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt, PermissionsExt};
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Parser;
use nix::errno::Errno;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use sonar_common::ipc::IpcArgs;
use sonar_common::logging::{self, LogTo};
use tracing::{info, warn};

use crate::config::{FoxgloveSection, PipelineFile, push_opt};
use crate::signals::Signals;
use crate::terminal::Terminal;

/// A process that exits with an error this soon after its first start has a configuration
/// problem, not a crash: restarting cannot help, so the pipeline stops and shows its log.
const STARTUP_GRACE: Duration = Duration::from_secs(2);
/// The window in which `max_restarts` restarts of one process mean a crash loop.
const RESTART_WINDOW: Duration = Duration::from_secs(60);
const DEFAULT_MAX_RESTARTS: u32 = 5;
/// How long the simulator may take to open its pseudo-terminal.
const SIMULATOR_READY_TIMEOUT: Duration = Duration::from_secs(10);
/// How long the processes get to exit after SIGTERM before they are killed.
const SHUTDOWN_TIMEOUT: Duration = Duration::from_secs(10);

/// Runs the sonar pipeline: simulator (or a real sensor head on --port), driver, fusion engine
/// and terminal viewer, as separate processes over iceoryx2 shared memory.
///
/// Settings come from --config (see examples/sonar.toml), overridden by the flags below and
/// their environment variables. Quit with `q` in the viewer, Ctrl-C, or SIGTERM: every process
/// stops and nothing is left in shared memory. A process that dies is restarted.
///
/// Examples:
///   sonar-pipeline                                   # the simulated room, in real time
///   sonar-pipeline --scene obstacle --scan=-45..45 --speed 10
///   sonar-pipeline --port /dev/ttyUSB0               # a real sensor head
///   sonar-pipeline --replay run.mcap --speed 5       # a recording (sonar-record's), no head
///   sonar-pipeline --config /etc/sonar.toml --no-viewer   # at boot, e.g. from systemd
///   sonar-pipeline --foxglove --no-viewer            # live in Foxglove at ws://127.0.0.1:8765
#[derive(Debug, Parser)]
#[command(version, verbatim_doc_comment)]
struct Args {
    /// Pipeline configuration file (TOML).
    #[arg(long, env = "SONAR_CONFIG")]
    config: Option<PathBuf>,
    /// Serial device of a real sensor head; without it, the simulator runs.
    #[arg(long, env = "SONAR_PORT", conflicts_with = "replay")]
    port: Option<PathBuf>,
    /// Baud rate of --port [default: [serial] baud of --config, else the driver's: 115200 for
    /// the native protocol, 9600 for hobby].
    #[arg(long, env = "SONAR_BAUD", conflicts_with = "replay")]
    baud: Option<u32>,
    /// Serial format of the head: native or hobby (an "Arduino radar" sketch) [default: [serial]
    /// dialect of --config, else native]. The simulator speaks it too.
    #[arg(long, env = "SONAR_DIALECT", value_parser = ["native", "hobby"], conflicts_with = "replay")]
    dialect: Option<String>,
    /// Replay a recording made by sonar-record instead of running a head: the fusion and the
    /// viewer show it, --speed sets the pace. Without the viewer the pipeline stops at its end.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["scene", "seed", "scan"])]
    replay: Option<PathBuf>,
    /// With --replay: accept a recording that ends early (its recorder was killed) and replay
    /// what it holds.
    #[arg(long, requires = "replay")]
    allow_truncated: bool,
    /// Simulator scene: room, corner, obstacle, two-obstacles, corridor, room-tour, or a scene
    /// file [default: [simulator] scene of --config, else room].
    #[arg(long, env = "SONAR_SCENE")]
    scene: Option<String>,
    /// Simulator's (or the replay's) speed: a factor (1 = real time) or `max` [default:
    /// [simulator] speed of --config, else 1].
    #[arg(long, env = "SONAR_SPEED", allow_hyphen_values = true)]
    speed: Option<String>,
    /// Simulator noise seed [default: [simulator] seed of --config, else 1].
    #[arg(long)]
    seed: Option<u64>,
    /// Scan after the handshake: full, none, or FROM..TO degrees (write --scan=-30..30)
    /// [default: [serial] scan of --config, else full].
    #[arg(long, env = "SONAR_SCAN", allow_hyphen_values = true)]
    scan: Option<String>,
    /// Fusion preset: paper or recommended, replacing the [fusion] model and rule [default: those
    /// of --config, else recommended].
    #[arg(long, env = "SONAR_PRESET", value_parser = ["paper", "recommended"])]
    preset: Option<String>,
    /// Run without the terminal viewer (at boot, or to attach viewers separately).
    #[arg(long)]
    no_viewer: bool,
    /// Viewer's first view: map, radar or split [default: [viewer] view of --config, else split].
    #[arg(long, value_parser = ["map", "radar", "split"])]
    view: Option<String>,
    /// Also start sonar-foxglove: the pipeline live in Foxglove (docs/foxglove.md) [default:
    /// [foxglove] enabled of --config, else off].
    #[arg(long)]
    foxglove: bool,
    /// Address sonar-foxglove listens on (0.0.0.0: every interface; the protocol has no
    /// authentication) [default: [foxglove] host of --config, else 127.0.0.1].
    #[arg(long, value_name = "HOST")]
    foxglove_host: Option<String>,
    /// Port sonar-foxglove listens on [default: [foxglove] port of --config, else 8765].
    #[arg(long, value_name = "PORT")]
    foxglove_port: Option<u16>,
    /// Directory for the processes' logs [default: $XDG_STATE_HOME/sonar, else ~/.local/state/sonar].
    #[arg(long, env = "SONAR_LOG_DIR")]
    log_dir: Option<PathBuf>,
    /// Directory of the pipeline's programs [default: the one this program is in].
    #[arg(long)]
    bin_dir: Option<PathBuf>,
    #[command(flatten)]
    ipc: IpcArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    // `run` chooses the exit code itself (the viewer's); only its errors are reported here.
    run(args).unwrap_or_else(|e| sonar_common::report_exit("sonar-pipeline", Err(e)))
}

/// One process of the pipeline: how to start it, and its current incarnation.
struct Process {
    name: &'static str,
    args: Vec<String>,
    /// The viewer: owns the terminal, and its exit ends the pipeline.
    foreground: bool,
    /// A replay: runs once to its end and is not restarted; a failure stops the pipeline (a
    /// second run would feed the map every reading again).
    until_done: bool,
    child: Option<Child>,
    started: Instant,
    /// Whether the current incarnation is a restart (then an early error is no configuration's).
    restarted: bool,
    /// Length of its log file when the current incarnation started.
    log_start: u64,
    restarts: VecDeque<Instant>,
    restart_at: Option<Instant>,
}

/// Everything the pipeline's processes share.
struct Pipeline {
    bin_dir: PathBuf,
    log_dir: PathBuf,
    env: Vec<(&'static str, String)>,
    /// The simulator's stable link to its pseudo-terminal, if the simulator runs.
    sim_link: Option<PathBuf>,
    max_restarts: u32,
    /// Before the first restart of a process; doubled for each further one within a minute.
    restart_delay: Duration,
    processes: Vec<Process>,
    /// The terminal as it was before the viewer took it over.
    terminal: Terminal,
}

fn run(args: Args) -> Result<ExitCode> {
    let file = match &args.config {
        Some(path) => PipelineFile::load(path)?,
        None => PipelineFile::default(),
    };
    let log_dir = args
        .log_dir
        .clone()
        .or(file.launcher.log_dir.clone())
        .unwrap_or_else(sonar_common::state_dir);
    // Owner-only, like the logs in it: they name the robot's surroundings and commands.
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(&log_dir)
        .with_context(|| format!("cannot create log directory {}", log_dir.display()))?;
    let with_viewer = file.viewer.enabled && !args.no_viewer;
    init_logging(&log_dir, with_viewer)?;

    let mut pipeline = Pipeline::plan(&args, &file, log_dir, with_viewer)?;
    let signals = Signals::install()?;

    let outcome = pipeline
        .start_all(&signals)
        .and_then(|()| pipeline.supervise(&signals));
    pipeline.stop_all();
    pipeline.clean_shared_memory(&args.ipc, &file);
    if let Some(link) = &pipeline.sim_link {
        let _ = std::fs::remove_file(link);
    }
    let logs = pipeline.log_dir.display();
    match outcome {
        Ok(()) => {
            info!("pipeline stopped");
            if with_viewer {
                eprintln!("sonar-pipeline: stopped; logs in {logs}");
            }
            Ok(ExitCode::SUCCESS)
        }
        Err(e) => Err(e.context(format!("the pipeline stopped (logs in {logs})"))),
    }
}

/// The launcher's own log: stderr, or a file while the viewer owns the terminal.
fn init_logging(log_dir: &Path, to_file: bool) -> Result<()> {
    let to = if to_file {
        LogTo::File(append(&log_dir.join("sonar-pipeline.log"))?)
    } else {
        LogTo::Stderr
    };
    logging::init(to);
    Ok(())
}

/// A log file opened for appending, its owner's only (0600, also when an older one was wider).
fn append(path: &Path) -> Result<File> {
    let file = File::options()
        .create(true)
        .append(true)
        .mode(0o600)
        .open(path)
        .with_context(|| format!("cannot open log file {}", path.display()))?;
    file.set_permissions(std::fs::Permissions::from_mode(0o600))
        .with_context(|| format!("cannot make log file {} owner-only", path.display()))?;
    Ok(file)
}

impl Pipeline {
    /// The processes and their command lines, from the file and the flags.
    fn plan(args: &Args, file: &PipelineFile, log_dir: PathBuf, with_viewer: bool) -> Result<Self> {
        let bin_dir = match &args.bin_dir {
            Some(dir) => dir.clone(),
            None => std::env::current_exe()
                .context("cannot locate this program")?
                .parent()
                .map(Path::to_owned)
                .context("this program has no directory")?,
        };
        let mut env = Vec::new();
        let iox = &file.iceoryx2;
        let prefix = args.ipc.iox_prefix.clone().or(iox.prefix.clone());
        let root = args.ipc.iox_root.clone().or(iox.root.clone());
        let iox_config = args.ipc.iox_config.clone().or(iox.config.clone());
        if let Some(p) = prefix {
            env.push(("SONAR_IOX_PREFIX", p));
        }
        if let Some(r) = root {
            env.push(("SONAR_IOX_ROOT", r.display().to_string()));
        }
        if let Some(c) = iox_config {
            env.push(("SONAR_IOX_CONFIG", c.display().to_string()));
        }

        let mut processes = Vec::new();
        let sim_link = if let Some(recording) = &args.replay {
            if !recording.is_file() {
                bail!("cannot replay {}: no such file", recording.display());
            }
            // Nothing is published before the fusion listens, so the map gets every reading.
            let mut replay = vec![
                recording.display().to_string(),
                "--wait-for-subscribers".to_owned(),
                "1".to_owned(),
                "--no-progress".to_owned(),
            ];
            push_opt(&mut replay, "--speed", args.speed.clone());
            if args.allow_truncated {
                replay.push("--allow-truncated".to_owned());
            }
            processes.push(Process::new("sonar-replay", replay, false).until_done());
            None
        } else {
            let port = args.port.clone().or(file.serial.port.clone());
            let dialect = args.dialect.clone().or(file.serial.dialect.clone());
            let sim_link = match &port {
                Some(_) => None,
                None => {
                    let link = std::env::temp_dir()
                        .join(format!("sonar-pipeline-{}.pty", std::process::id()));
                    // One head identity for the pipeline's life: a restarted simulator plays the same
                    // head, which the driver accepts; another pipeline's simulator is another head.
                    let mut sim = vec![
                        "--link".to_owned(),
                        link.display().to_string(),
                        "--head-id".to_owned(),
                        format!("sim-{}", std::process::id()),
                    ];
                    push_opt(
                        &mut sim,
                        "--scene",
                        args.scene.clone().or(file.simulator.scene.clone()),
                    );
                    push_opt(
                        &mut sim,
                        "--speed",
                        args.speed.clone().or(file.simulator.speed.clone()),
                    );
                    push_opt(&mut sim, "--seed", args.seed.or(file.simulator.seed));
                    push_opt(&mut sim, "--dialect", dialect.clone());
                    push_opt(
                        &mut sim,
                        "--air-temperature-c",
                        file.sensor.air_temperature_c,
                    );
                    processes.push(Process::new("sonar-sim", sim, false));
                    Some(link)
                }
            };
            let port = port.or(sim_link.clone()).context("no serial port")?;
            let mut driver = vec!["--port".to_owned(), port.display().to_string()];
            push_opt(&mut driver, "--baud", args.baud.or(file.serial.baud));
            push_opt(&mut driver, "--dialect", dialect);
            push_opt(&mut driver, "--no-echo", file.serial.no_echo.clone());
            push_opt(&mut driver, "--backlash-deg", file.serial.backlash_deg);
            if let Some(scan) = args.scan.clone().or(file.serial.scan.clone()) {
                // `=` keeps a segment such as -30..30 from reading as a flag.
                driver.push(format!("--scan={scan}"));
            }
            push_opt(
                &mut driver,
                "--air-temperature-c",
                file.sensor.air_temperature_c,
            );
            push_opt(
                &mut driver,
                "--beam-half-angle-deg",
                file.sensor.beam_half_angle_deg,
            );
            processes.push(Process::new("sonar-driver", driver, false));
            sim_link
        };

        let mut fusion = Vec::new();
        push_opt(
            &mut fusion,
            "--config",
            args.config.as_ref().map(|p| p.display()),
        );
        push_opt(&mut fusion, "--preset", args.preset.clone());
        if file.slam.enabled {
            // sonar-slam takes its [slam] table from the same file; the fusion places its
            // readings with its correction.
            let config = args
                .config
                .as_ref()
                .context("[slam] enabled needs the file given with --config")?;
            let slam = vec!["--config".to_owned(), config.display().to_string()];
            processes.push(Process::new("sonar-slam", slam, false));
            fusion.push("--slam-correction".to_owned());
        }
        processes.push(Process::new("sonar-fusion", fusion, false));

        if file.bridge_enabled().map_err(anyhow::Error::msg)? {
            // The bridge takes its [bridge] table from the same file.
            let config = args
                .config
                .as_ref()
                .context("[bridge] enabled needs the file given with --config")?;
            let bridge = vec!["--config".to_owned(), config.display().to_string()];
            processes.push(Process::new("sonar-bridge", bridge, false));
        }

        if let Some(foxglove) = foxglove_args(args, &file.foxglove)? {
            processes.push(Process::new("sonar-foxglove", foxglove, false));
        }

        if with_viewer {
            let mut viewer = vec![
                "--log-file".to_owned(),
                log_dir.join("sonar-viewer.log").display().to_string(),
            ];
            push_opt(
                &mut viewer,
                "--view",
                args.view.clone().or(file.viewer.view.clone()),
            );
            push_opt(&mut viewer, "--color", file.viewer.color.clone());
            processes.push(Process::new("sonar-viewer", viewer, true));
        }
        for p in &processes {
            let path = bin_dir.join(p.name);
            if !path.exists() {
                bail!(
                    "{} is missing (build with `cargo build --release --workspace --bins`, or \
                     point --bin-dir at the programs)",
                    path.display()
                );
            }
        }
        Ok(Self {
            bin_dir,
            log_dir,
            env,
            sim_link,
            max_restarts: file.launcher.max_restarts.unwrap_or(DEFAULT_MAX_RESTARTS),
            restart_delay: file.launcher.restart_delay().map_err(anyhow::Error::msg)?,
            processes,
            terminal: Terminal::capture(),
        })
    }

    fn start_all(&mut self, signals: &Signals) -> Result<()> {
        for i in 0..self.processes.len() {
            if signals.stop_requested() {
                return Ok(());
            }
            self.start(i)?;
        }
        Ok(())
    }

    /// Starts process `i`; the simulator counts as started once its pseudo-terminal exists, so
    /// the driver finds the port.
    fn start(&mut self, i: usize) -> Result<()> {
        let p = &self.processes[i];
        let mut cmd = Command::new(self.bin_dir.join(p.name));
        cmd.args(&p.args)
            .envs(self.env.iter().map(|(k, v)| (*k, v)));
        let log_path = self.log_path(p.name);
        // Logs are appended across runs: an error message quotes this incarnation's part only.
        let log_start = std::fs::metadata(&log_path).map_or(0, |m| m.len());
        if !p.foreground {
            let log = append(&log_path)?;
            let log2 = log.try_clone().context("cannot share a log file")?;
            cmd.stdin(Stdio::null()).stdout(log).stderr(log2);
        }
        let launcher = std::process::id();
        // SAFETY: the closure runs in the child between fork and exec, where only
        // async-signal-safe calls are allowed: it makes two system calls and allocates nothing.
        unsafe {
            cmd.pre_exec(move || {
                // SIGTERM (a clean stop) when the launcher dies, also of SIGKILL, which it cannot
                // handle. The signal follows the thread that forks: the launcher's main thread.
                nix::sys::prctl::set_pdeathsig(Signal::SIGTERM)?;
                // The launcher may have died before the prctl; then no signal ever comes.
                if std::os::unix::process::parent_id() != launcher {
                    return Err(Errno::ESRCH.into());
                }
                Ok(())
            });
        }
        if p.name == "sonar-sim"
            && let Some(link) = &self.sim_link
        {
            // A stale link from a previous incarnation must not look like readiness.
            let _ = std::fs::remove_file(link);
        }
        let child = cmd
            .spawn()
            .with_context(|| format!("cannot start {}", p.name))?;
        info!(process = p.name, pid = child.id(), args = ?p.args, "started");
        let p = &mut self.processes[i];
        p.child = Some(child);
        p.log_start = log_start;
        p.started = Instant::now();
        p.restart_at = None;
        if p.name == "sonar-sim"
            && let Some(link) = self.sim_link.clone()
        {
            self.wait_for_simulator(i, &link)?;
        }
        Ok(())
    }

    fn wait_for_simulator(&mut self, i: usize, link: &Path) -> Result<()> {
        let deadline = Instant::now() + SIMULATOR_READY_TIMEOUT;
        while !link.exists() {
            if let Some(child) = self.processes[i].child.as_mut()
                && let Ok(Some(status)) = child.try_wait()
            {
                if status.signal().is_some() {
                    // Killed, not failed: `supervise` restarts it like any process that dies.
                    return Ok(());
                }
                bail!(
                    "sonar-sim exited at start ({status}):\n{}",
                    self.log_tail("sonar-sim")
                );
            }
            if Instant::now() > deadline {
                bail!(
                    "sonar-sim did not open its pseudo-terminal within {SIMULATOR_READY_TIMEOUT:?}"
                );
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(())
    }

    /// Watches the processes until the viewer quits, a signal arrives, or a process cannot be
    /// kept running.
    fn supervise(&mut self, signals: &Signals) -> Result<()> {
        let with_viewer = self.processes.iter().any(|p| p.foreground);
        loop {
            if signals.stop_requested() {
                info!("signal received: stopping");
                return Ok(());
            }
            let now = Instant::now();
            for i in 0..self.processes.len() {
                let p = &mut self.processes[i];
                let exited = match p.child.as_mut().map(Child::try_wait) {
                    Some(Ok(Some(status))) => status,
                    Some(Ok(None)) | None => {
                        if p.restart_at.is_some_and(|t| t <= now) {
                            self.start(i)?;
                        }
                        continue;
                    }
                    Some(Err(e)) => bail!("cannot watch {}: {e}", p.name),
                };
                p.child = None;
                let (name, until_done) = (p.name, p.until_done);
                if p.foreground {
                    self.viewer_ended(exited);
                    // An exit of its own is the user's `q`, or an error to report. Killed by a
                    // signal (a crash, the OOM killer, kill -9), it is restarted like the others.
                    if exited.signal().is_none() {
                        info!(%exited, "viewer quit: stopping");
                        return if exited.success() {
                            Ok(())
                        } else {
                            Err(anyhow::anyhow!("sonar-viewer failed ({exited})"))
                        };
                    }
                }
                if signals.stop_requested() {
                    return Ok(()); // it stopped for the same signal we got
                }
                if until_done {
                    if !exited.success() {
                        bail!(
                            "{name} failed ({exited}); its log:\n{}",
                            self.log_tail(name)
                        );
                    }
                    info!(process = name, "finished");
                    if !with_viewer {
                        return Ok(()); // nothing more will come, and nobody watches
                    }
                    continue;
                }
                self.schedule_restart(i, exited, now)?;
            }
            // Until a child ends, a signal comes, or a restart is due.
            let next_restart = self.processes.iter().filter_map(|p| p.restart_at).min();
            signals.wait(next_restart.map(|t| t.saturating_duration_since(Instant::now())));
        }
    }

    /// A viewer killed by a signal could not restore the terminal (raw mode, alternate screen,
    /// hidden cursor): done here, before a new viewer or an error is shown on it. One that exited
    /// restored it itself, and restoring again would move the cursor back over what followed.
    fn viewer_ended(&self, status: ExitStatus) {
        if status.signal().is_some() {
            self.terminal.restore();
        }
    }

    fn schedule_restart(&mut self, i: usize, exited: ExitStatus, now: Instant) -> Result<()> {
        let name = self.processes[i].name;
        let ran = now.duration_since(self.processes[i].started);
        // An error exit (not a signal) right after the first start is a configuration problem.
        // After a restart it is more likely the aftermath of the death (a peer killed while it
        // was creating something, a device that went away): another death, under the back-off
        // and the crash-loop limit like any.
        if exited.code() == Some(i32::from(logging::EXIT_MISCONFIGURED)) {
            bail!(
                "{name} stopped: its settings cannot work; its log:\n{}",
                self.log_tail(name)
            );
        }
        if ran < STARTUP_GRACE
            && exited.code().is_some_and(|c| c != 0)
            && !self.processes[i].restarted
        {
            bail!(
                "{name} failed at start ({exited}); its log:\n{}",
                self.log_tail(name)
            );
        }
        let p = &mut self.processes[i];
        while p
            .restarts
            .front()
            .is_some_and(|&t| now.duration_since(t) > RESTART_WINDOW)
        {
            p.restarts.pop_front();
        }
        if p.restarts.len() >= self.max_restarts as usize {
            bail!(
                "{name} died {} times within {RESTART_WINDOW:?}: giving up; its log:\n{}",
                p.restarts.len() + 1,
                self.log_tail(name)
            );
        }
        p.restarts.push_back(now);
        let delay = self.restart_delay * (1 << (p.restarts.len() - 1).min(4));
        warn!(process = name, %exited, ?delay, "process died: restarting");
        p.restart_at = Some(now + delay);
        p.restarted = true;
        Ok(())
    }

    fn log_path(&self, name: &str) -> PathBuf {
        self.log_dir.join(format!("{name}.log"))
    }

    /// The last lines its current incarnation wrote to a process's log, for an error message.
    fn log_tail(&self, name: &str) -> String {
        let start = self
            .processes
            .iter()
            .find(|p| p.name == name)
            .map_or(0, |p| p.log_start);
        let text = read_from(&self.log_path(name), start);
        let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
        lines[lines.len().saturating_sub(10)..].join("\n")
    }

    /// SIGTERM to every process, the viewer first; SIGKILL to any still running after
    /// [`SHUTDOWN_TIMEOUT`].
    fn stop_all(&mut self) {
        for p in self.processes.iter().rev() {
            if let Some(child) = &p.child
                && let Ok(pid) = i32::try_from(child.id())
            {
                let _ = kill(Pid::from_raw(pid), Signal::SIGTERM);
            }
        }
        let deadline = Instant::now() + SHUTDOWN_TIMEOUT;
        let mut viewer = None;
        for p in self.processes.iter_mut().rev() {
            let Some(child) = p.child.as_mut() else {
                continue;
            };
            let status = loop {
                match child.try_wait() {
                    Ok(Some(status)) => {
                        info!(process = p.name, %status, "stopped");
                        break Some(status);
                    }
                    Ok(None) if Instant::now() < deadline => {
                        std::thread::sleep(Duration::from_millis(20));
                    }
                    _ => {
                        warn!(process = p.name, "did not stop in time: killed");
                        let _ = child.kill();
                        break child.wait().ok();
                    }
                }
            };
            if p.foreground {
                viewer = status;
            }
            p.child = None;
        }
        if let Some(status) = viewer {
            self.viewer_ended(status);
        }
    }

    /// Removes what processes that were killed or crashed left in shared memory: creating a node
    /// first recovers the namespace (`sonar_common::namespace`: dead nodes, half-created and
    /// half-removed services), and the node is removed again on drop.
    fn clean_shared_memory(&self, ipc: &IpcArgs, file: &PipelineFile) {
        let args = IpcArgs {
            iox_config: ipc.iox_config.clone().or(file.iceoryx2.config.clone()),
            iox_prefix: ipc.iox_prefix.clone().or(file.iceoryx2.prefix.clone()),
            iox_root: ipc.iox_root.clone().or(file.iceoryx2.root.clone()),
        };
        match args.node("sonar-pipeline") {
            Ok(node) => drop(node),
            Err(e) => warn!("cannot clean up shared memory: {e}"),
        }
    }
}

/// A file's text from byte `start` on; empty if it cannot be read.
fn read_from(path: &Path, start: u64) -> String {
    let mut text = Vec::new();
    if let Ok(mut file) = File::open(path)
        && file.seek(SeekFrom::Start(start)).is_ok()
    {
        let _ = file.read_to_end(&mut text);
    }
    String::from_utf8_lossy(&text).into_owned()
}

impl Process {
    fn until_done(self) -> Self {
        Self {
            until_done: true,
            ..self
        }
    }

    fn new(name: &'static str, args: Vec<String>, foreground: bool) -> Self {
        Self {
            name,
            args,
            foreground,
            until_done: false,
            child: None,
            started: Instant::now(),
            restarted: false,
            log_start: 0,
            restarts: VecDeque::new(),
            restart_at: None,
        }
    }
}

/// sonar-foxglove's arguments, if it is to run: the flags over the `[foxglove]` table, only the
/// settings given (its defaults live in it).
fn foxglove_args(args: &Args, table: &FoxgloveSection) -> Result<Option<Vec<String>>> {
    if !(args.foxglove || table.enabled) {
        if args.foxglove_host.is_some() || args.foxglove_port.is_some() {
            bail!(
                "--foxglove-host/--foxglove-port set where sonar-foxglove listens: start it with \
                 --foxglove or [foxglove] enabled = true"
            );
        }
        return Ok(None);
    }
    let mut foxglove = Vec::new();
    push_opt(
        &mut foxglove,
        "--host",
        args.foxglove_host.clone().or(table.host.clone()),
    );
    push_opt(&mut foxglove, "--port", args.foxglove_port.or(table.port));
    push_opt(&mut foxglove, "--grid-period", table.grid_period);
    Ok(Some(foxglove))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The example systemd unit starts the launcher with flags it has.
    #[test]
    fn the_systemd_unit_uses_existing_flags() {
        let unit = include_str!("../../examples/systemd/sonar-pipeline.service");
        let exec = unit
            .lines()
            .find_map(|l| l.strip_prefix("ExecStart="))
            .expect("an ExecStart line");
        let args = Args::try_parse_from(exec.split_whitespace()).unwrap();
        assert!(args.no_viewer);
        assert_eq!(args.config, Some(PathBuf::from("/etc/sonar/sonar.toml")));
    }

    #[test]
    fn foxglove_runs_when_the_flag_or_the_table_says_so_with_the_flags_over_the_table() {
        let parse =
            |args: &[&str]| Args::try_parse_from([&["sonar-pipeline"], args].concat()).unwrap();
        let off = FoxgloveSection::default();
        assert_eq!(foxglove_args(&parse(&[]), &off).unwrap(), None);
        assert_eq!(
            foxglove_args(&parse(&["--foxglove"]), &off).unwrap(),
            Some(vec![]),
            "its own defaults"
        );
        let table = FoxgloveSection {
            enabled: true,
            host: Some("0.0.0.0".into()),
            port: Some(9000),
            grid_period: Some(0.5),
        };
        assert_eq!(
            foxglove_args(&parse(&["--foxglove-port", "9100"]), &table).unwrap(),
            Some(
                [
                    "--host",
                    "0.0.0.0",
                    "--port",
                    "9100",
                    "--grid-period",
                    "0.5"
                ]
                .map(String::from)
                .to_vec()
            )
        );
        // An address for a server that is not started is a mistake, not silently ignored.
        let err = foxglove_args(&parse(&["--foxglove-port", "9100"]), &off).unwrap_err();
        assert!(err.to_string().contains("--foxglove"), "{err}");
    }

    #[test]
    fn the_serial_tables_no_echo_value_and_backlash_reach_the_driver() {
        let file: PipelineFile = toml::from_str(
            "[serial]\nport = \"/dev/ttyUSB0\"\ndialect = \"hobby\"\nno_echo = \"255\"\nbacklash_deg = 1.5\n",
        )
        .unwrap();
        // The plan checks that its programs exist; empty stand-ins do.
        let bin_dir = std::env::temp_dir().join(format!("sonar_plan_{}", std::process::id()));
        std::fs::create_dir_all(&bin_dir).unwrap();
        for name in ["sonar-driver", "sonar-fusion"] {
            std::fs::write(bin_dir.join(name), "").unwrap();
        }
        let dir = bin_dir.to_str().unwrap();
        let args = Args::try_parse_from(["sonar-pipeline", "--bin-dir", dir]).unwrap();
        let plan = Pipeline::plan(&args, &file, std::env::temp_dir(), false).unwrap();
        std::fs::remove_dir_all(&bin_dir).unwrap();
        let driver = plan
            .processes
            .iter()
            .find(|p| p.name == "sonar-driver")
            .unwrap();
        let at = driver.args.iter().position(|a| a == "--no-echo").unwrap();
        assert_eq!(driver.args[at + 1], "255", "{:?}", driver.args);
        let at = driver
            .args
            .iter()
            .position(|a| a == "--backlash-deg")
            .unwrap();
        assert_eq!(driver.args[at + 1], "1.5", "{:?}", driver.args);
    }

    #[test]
    fn the_slam_table_starts_sonar_slam_and_the_fusion_takes_its_correction() {
        let bin_dir = std::env::temp_dir().join(format!("sonar_plan_slam_{}", std::process::id()));
        std::fs::create_dir_all(&bin_dir).unwrap();
        for name in ["sonar-sim", "sonar-driver", "sonar-slam", "sonar-fusion"] {
            std::fs::write(bin_dir.join(name), "").unwrap();
        }
        let dir = bin_dir.to_str().unwrap();
        let plan = |file: &str| {
            let file: PipelineFile = toml::from_str(file).unwrap();
            let args =
                Args::try_parse_from(["sonar-pipeline", "--bin-dir", dir, "--config", "p.toml"])
                    .unwrap();
            Pipeline::plan(&args, &file, std::env::temp_dir(), false).unwrap()
        };
        let args_of = |plan: &Pipeline, name: &str| {
            plan.processes
                .iter()
                .find(|p| p.name == name)
                .map(|p| p.args.clone())
        };
        let on = plan("[slam]\nenabled = true\n");
        let off = plan("");
        std::fs::remove_dir_all(&bin_dir).unwrap();
        assert_eq!(
            args_of(&on, "sonar-slam"),
            Some(vec!["--config".to_owned(), "p.toml".to_owned()])
        );
        assert!(
            args_of(&on, "sonar-fusion")
                .unwrap()
                .contains(&"--slam-correction".to_owned())
        );
        assert_eq!(args_of(&off, "sonar-slam"), None);
        assert!(
            !args_of(&off, "sonar-fusion")
                .unwrap()
                .contains(&"--slam-correction".to_owned())
        );
    }

    #[test]
    fn flags_are_checked_before_anything_starts() {
        let parse = |args: &[&str]| Args::try_parse_from([&["sonar-pipeline"], args].concat());
        // A negative speed reaches the simulator, which says what a speed is, instead of clap's
        // "unexpected argument '-1'"; a segment starting below zero is a value too.
        assert_eq!(
            parse(&["--speed", "-1"]).unwrap().speed.as_deref(),
            Some("-1")
        );
        assert_eq!(
            parse(&["--scan", "-30..30"]).unwrap().scan.as_deref(),
            Some("-30..30")
        );
        // Checked even when the viewer does not run.
        let err = parse(&["--no-viewer", "--view", "bogus"]).unwrap_err();
        assert!(
            err.to_string()
                .contains("[possible values: map, radar, split]"),
            "{err}"
        );
        assert!(parse(&["--preset", "papper"]).is_err());
        // A replay has no head to scan or simulate.
        let err = parse(&["--replay", "run.mcap", "--scene", "room"]).unwrap_err();
        assert!(err.to_string().contains("cannot be used with"), "{err}");
        assert!(parse(&["--replay", "run.mcap", "--port", "/dev/ttyUSB0"]).is_err());
        // A truncated recording's error names --allow-truncated: the pipeline takes it for its
        // replay, and only with one.
        assert!(
            parse(&["--replay", "run.mcap", "--allow-truncated"])
                .unwrap()
                .allow_truncated
        );
        assert!(parse(&["--allow-truncated"]).is_err());
    }
}
