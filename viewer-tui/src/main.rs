//! `sonar-viewer`: terminal setup and teardown, logging, signals and the frame loop. Everything it
//! shows and every decision about keys lives in the library; see its documentation.
//!
//! One thread, asleep in one waitset on the terminal, the wake-up events of the streams (readings,
//! grid, radar, features), its next look at the producers and SIGINT/SIGTERM. Each turn takes the
//! newest snapshots (at most `--fps` times a second), draws if what it would show changed
//! (`App::needs_redraw`: a snapshot, a status, a key, a producer's liveness; a terminal resize),
//! and sleeps again. While streams move it looks at the frame rate; idle, once a second (the
//! statuses and the producers' liveness), so an idle viewer wakes about twice a second and draws
//! nothing, except once a second while a producer is gone (its "gone for N s" ticks). Keys are
//! handled as soon as they arrive and drawn at once.

use std::fs::OpenOptions;
use std::io::{IsTerminal, Read, Stdout, stdout};
use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Parser, ValueEnum};
use crossterm::event::{self, DisableMouseCapture, EnableMouseCapture, Event};
use crossterm::terminal::{
    EnterAlternateScreen, LeaveAlternateScreen, disable_raw_mode, enable_raw_mode,
};
use crossterm::{cursor, execute};
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::waitset::WaitSetRunResult;
use ratatui::Terminal;
use ratatui::backend::CrosstermBackend;
use sonar_common::ipc::{self, IpcArgs, IpcError, WatchedFd, unix_time_ns};
use sonar_common::logging::{self, LogTo};
use sonar_viewer::app::{Action, App, Drawn, View, key_help_text};
use sonar_viewer::export;
use sonar_viewer::heatmap::{ColorMode, Palette};
use sonar_viewer::source::{self, Source};
use sonar_viewer::ui::{self, DrawInfo, MapCache};
use tracing::{info, warn};

/// How long an idle viewer sleeps between looks at the producers' statuses and liveness, unless a
/// key, a resize or a snapshot's wake-up comes first.
const IDLE_PERIOD: Duration = Duration::from_secs(1);

/// Terminal viewer of the sonar pipeline: the probability map, the radar display and the state of
/// the driver and the fusion engine. Its keys send scan and fusion commands over iceoryx2.
///
/// Start it before or after the other processes, with the same --iox-* settings; it shows
/// "waiting for …" until they appear and carries on when they restart.
///
/// Examples:
///   sonar-viewer
///   sonar-viewer --view map --color 256
///   sonar-viewer --iox-prefix test_ --log-file viewer.log
#[derive(Debug, Parser)]
#[command(version, verbatim_doc_comment, after_help = key_help_text())]
struct Args {
    /// View at start: map, radar or split (both).
    #[arg(long, value_enum, default_value_t = ViewArg::Split)]
    view: ViewArg,
    /// Colours: auto, truecolor, 256, 16 (the ANSI colours) or none (shapes only). Auto: none if
    /// NO_COLOR is set (not empty) or TERM is dumb, truecolor if COLORTERM is truecolor or 24bit,
    /// 16 for TERM=linux, vt*, ansi*, *-color, *-16color, else 256.
    #[arg(long, value_enum, default_value_t = ColorArg::Auto)]
    color: ColorArg,
    /// Frames per second at most; snapshots arriving faster are skipped, never queued.
    #[arg(long, default_value_t = 25, value_parser = clap::value_parser!(u32).range(1..=60))]
    fps: u32,
    /// Directory where `s` saves the map as PNG (with its legend, as sonar-export's), created if
    /// missing [default: $XDG_DATA_HOME/sonar/maps, else ~/.local/share/sonar/maps].
    #[arg(long, value_name = "DIR")]
    save_dir: Option<PathBuf>,
    /// Log file [default: sonar-viewer.log in $XDG_STATE_HOME/sonar, else ~/.local/state/sonar,
    /// as sonar-pipeline's]; the level comes from RUST_LOG (default info, iceoryx2's at error).
    #[arg(long, value_name = "FILE")]
    log_file: Option<PathBuf>,
    #[command(flatten)]
    ipc: IpcArgs,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ViewArg {
    Map,
    Radar,
    Split,
}

impl From<ViewArg> for View {
    fn from(v: ViewArg) -> Self {
        match v {
            ViewArg::Map => View::Map,
            ViewArg::Radar => View::Radar,
            ViewArg::Split => View::Split,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ColorArg {
    Auto,
    Truecolor,
    #[value(name = "256")]
    Ansi256,
    #[value(name = "16")]
    Ansi16,
    None,
}

fn main() -> ExitCode {
    let args = Args::parse();
    let log = init_logging(args.log_file.clone());
    // The terminal is restored when `run` returns: the message lands on the user's screen.
    sonar_common::report_exit("sonar-viewer", run(args, log))
}

fn default_log_path() -> PathBuf {
    sonar_common::state_dir().join("sonar-viewer.log")
}

/// Logs to a file; on failure the viewer runs without a log and says why in its status line.
/// Either way iceoryx2's messages go through `tracing`, never over the picture.
fn init_logging(path: Option<PathBuf>) -> Result<PathBuf, String> {
    let path = path.unwrap_or_else(default_log_path);
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        let _ = std::fs::create_dir_all(dir);
    }
    match OpenOptions::new().create(true).append(true).open(&path) {
        Ok(file) => {
            logging::init(LogTo::File(file));
            Ok(path)
        }
        Err(e) => {
            logging::init(LogTo::Nowhere);
            Err(format!("not logging: {}: {e}", path.display()))
        }
    }
}

/// Sets the returned flag on SIGTERM, SIGINT, SIGHUP (the SSH session went away) and SIGQUIT.
fn quit_on_signals(node: &Node<Ipc>) -> Result<Arc<AtomicBool>> {
    // iceoryx2 installs its SIGINT/SIGTERM handlers the first time it looks for signals (also
    // inside some shared-memory operations), replacing what is there without chaining. Let it do
    // so now: the handlers registered next chain to it, so neither loses the signal.
    let _ = node.wait(Duration::ZERO);
    let quit = Arc::new(AtomicBool::new(false));
    for signal in [
        signal_hook::consts::SIGTERM,
        signal_hook::consts::SIGINT,
        signal_hook::consts::SIGHUP,
        signal_hook::consts::SIGQUIT,
    ] {
        signal_hook::flag::register(signal, Arc::clone(&quit))
            .with_context(|| format!("cannot handle signal {signal}"))?;
    }
    Ok(quit)
}

/// Whether raw mode and the alternate screen are on; makes restoring idempotent, so the panic hook
/// and the guard's `Drop` can both run without the second one disturbing the restored screen.
static TERMINAL_ACTIVE: AtomicBool = AtomicBool::new(false);

fn restore_terminal() {
    if TERMINAL_ACTIVE.swap(false, Ordering::SeqCst) {
        let _ = disable_raw_mode();
        let _ = execute!(
            stdout(),
            DisableMouseCapture,
            LeaveAlternateScreen,
            cursor::Show
        );
    }
}

/// The terminal in raw mode on the alternate screen; restored when dropped and on panic.
struct Tui {
    terminal: Terminal<CrosstermBackend<Stdout>>,
}

impl Tui {
    fn enter() -> Result<Self> {
        let default_hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |panic| {
            restore_terminal();
            default_hook(panic);
        }));
        TERMINAL_ACTIVE.store(true, Ordering::SeqCst);
        let terminal = enable_raw_mode()
            .and_then(|()| {
                execute!(
                    stdout(),
                    EnterAlternateScreen,
                    EnableMouseCapture,
                    cursor::Hide
                )
            })
            .and_then(|()| Terminal::new(CrosstermBackend::new(stdout())));
        match terminal {
            Ok(terminal) => Ok(Self { terminal }),
            Err(e) => {
                restore_terminal();
                Err(e).context("cannot set up the terminal")
            }
        }
    }
}

impl Drop for Tui {
    fn drop(&mut self) {
        restore_terminal();
    }
}

fn run(args: Args, log: Result<PathBuf, String>) -> Result<()> {
    if !stdout().is_terminal() {
        bail!("standard output is not a terminal: run sonar-viewer in a terminal (or in tmux)");
    }
    let node = args
        .ipc
        .node("sonar-viewer")
        .context("cannot join the iceoryx2 pipeline")?;
    let quit = quit_on_signals(&node)?;
    let mode = match args.color {
        ColorArg::Auto => {
            let var = |name| std::env::var(name).ok();
            ColorMode::detect(
                var("COLORTERM").as_deref(),
                var("TERM").as_deref(),
                var("NO_COLOR").as_deref(),
            )
        }
        ColorArg::Truecolor => ColorMode::TrueColor,
        ColorArg::Ansi256 => ColorMode::Indexed256,
        ColorArg::Ansi16 => ColorMode::Ansi16,
        ColorArg::None => ColorMode::Mono,
    };
    let mut app = App::new(Palette::new(mode), args.view.into());
    app.namespace = Some(args.ipc.describe());
    match &log {
        Ok(path) => info!(log = %path.display(), ?mode, "viewer starting"),
        Err(problem) => app.message = Some(problem.clone()),
    }
    // Created before the node moves into the source, dropped before it (declared after it).
    let wakeups = match source::wakeup_listeners(&node) {
        Ok(listeners) => listeners,
        Err(e) => {
            warn!("{e}: looking for snapshots at the frame rate instead of sleeping on them");
            Vec::new()
        }
    };
    let mut source = Source::new(node, Instant::now());
    let mut cache = MapCache::default();
    let mut tui = Tui::enter()?;

    // One wait covers the terminal, the producers' wake-up events, the next poll and SIGINT/SIGTERM.
    let waitset = WaitSetBuilder::new()
        .create::<Ipc>()
        .map_err(|e| IpcError::new("create waitset", e))?;
    let stdin = std::io::stdin();
    let watched_stdin = if stdin.is_terminal() {
        WatchedFd::new(&stdin)
    } else {
        None
    };
    let stdin_guard = watched_stdin
        .as_ref()
        .map(|fd| waitset.attach_notification(fd))
        .transpose()
        .map_err(|e| IpcError::new("attach the terminal", e))?;
    // A resize is a SIGWINCH, which crossterm hears only once its reader runs (the first key):
    // the signal also writes to a socket this wait watches.
    let (resizes, on_resize) = UnixStream::pair().context("cannot create a socket")?;
    resizes
        .set_nonblocking(true)
        .and_then(|()| on_resize.set_nonblocking(true))
        .context("cannot set up a socket")?;
    signal_hook::low_level::pipe::register(signal_hook::consts::SIGWINCH, on_resize)
        .context("cannot handle SIGWINCH")?;
    let watched_resizes =
        WatchedFd::new(&resizes).context("the resize socket has no descriptor")?;
    let resize_guard = waitset
        .attach_notification(&watched_resizes)
        .map_err(|e| IpcError::new("attach the resize socket", e))?;
    let _wakeup_guards = ipc::attach_all(&waitset, &wakeups)?;

    let frame = Duration::from_secs(1) / args.fps;
    // Without news the viewer looks again after this long (the statuses and liveness come once a
    // second), unless a wake-up comes first; it cannot sleep if it cannot hear either.
    let idle = if wakeups.is_empty() || stdin_guard.is_none() {
        frame
    } else {
        IDLE_PERIOD
    };
    let mut next_poll = Instant::now();
    let mut last_poll = next_poll;
    let mut drawn: Option<Drawn> = None;
    // The terminal was resized: not app state, so `needs_redraw` cannot know.
    let mut resized = false;
    while !quit.load(Ordering::Relaxed) {
        let now = Instant::now();
        if now >= next_poll {
            let news = source.poll(&mut app, now);
            last_poll = now;
            next_poll = now + if news { frame } else { idle };
        }
        if resized || app.needs_redraw(now, drawn.as_ref()) {
            let mut info = DrawInfo::default();
            let drew = tui
                .terminal
                .draw(|f| info = ui::draw(f, &app, &mut cache, now));
            // A terminal that hung up since the last wait fails the write (EIO): said as what it is.
            if drew.is_err() && stdin_guard.is_some() && hung_up_said() {
                return Ok(());
            }
            drew.context("cannot draw")?;
            app.map_px = info.map_px;
            app.map_origin = info.map_origin;
            drawn = Some(app.drawn(now));
            resized = false;
        }
        let (mut typed, mut news, mut resize) = (false, false, false);
        let woke = waitset
            .wait_and_process_once_with_timeout(
                |id| {
                    if stdin_guard.as_ref().is_some_and(|g| id.has_event_from(g)) {
                        typed = true;
                    } else if id.has_event_from(&resize_guard) {
                        resize = true;
                    } else {
                        news = true;
                    }
                    CallbackProgression::Continue
                },
                next_poll.saturating_duration_since(Instant::now()),
            )
            .map_err(|e| IpcError::new("wait", e))?;
        // SIGHUP and SIGQUIT end the wait as an interrupt and set the flag. A hang-up may come as
        // SIGHUP before the terminal reads as hung up: said as what it is.
        if woke == WaitSetRunResult::TerminationRequest || quit.load(Ordering::Relaxed) {
            if stdin_guard.is_some() && hung_up_said() {
                return Ok(());
            }
            break;
        }
        if news {
            for listener in &wakeups {
                ipc::drain_wakeups(listener)?;
            }
            // Taken at once, but not more often than the frame rate.
            next_poll = next_poll.min(last_poll + frame);
        }
        if resize {
            while (&resizes).read(&mut [0u8; 64]).is_ok_and(|n| n > 0) {}
            resized = true;
        }
        if typed && hung_up_said() {
            return Ok(());
        }
        // Only when the terminal has something (or cannot be watched): on a hung-up terminal
        // crossterm's poll never returns (see `terminal_hung_up`).
        if stdin_guard.is_some() && !typed {
            continue;
        }
        // Collects what is there (keys, resizes) without blocking; take every queued event before
        // drawing again, so held-down keys never lag.
        while event::poll(Duration::ZERO).context("cannot read the terminal")? {
            match event::read().context("cannot read the terminal")? {
                Event::Key(key) => {
                    if let Some(action) = app.on_key(key)
                        && perform(action, &mut app, &mut source, &args)
                    {
                        info!("quit");
                        return Ok(());
                    }
                }
                Event::Mouse(mouse) => app.on_mouse(mouse),
                Event::Resize(..) => resized = true,
                _ => {}
            }
        }
    }
    info!("quit on a signal");
    Ok(())
}

/// [`terminal_hung_up`], and if so says so in the log.
fn hung_up_said() -> bool {
    let gone = terminal_hung_up();
    if gone {
        warn!("the terminal went away (hang-up): quitting");
    }
    gone
}

/// Whether the terminal hung up (its tmux or SSH session ended). Asked when the waitset found it
/// readable. crossterm alone cannot be trusted with that: on a hung-up terminal its reader loops
/// on end-of-file inside `event::poll` forever, at full CPU (seen with `tmux kill-server`), and
/// the hang-up does not always signal us (the kernel sends SIGHUP to the session leader, the shell
/// that started us). On a hung-up terminal `poll` reports POLLHUP, `tcgetpgrp` fails with EIO,
/// and it no longer counts as a terminal at all.
fn terminal_hung_up() -> bool {
    use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
    use std::os::fd::AsFd;
    let stdin = std::io::stdin();
    if !stdin.is_terminal() {
        return true;
    }
    let mut fds = [PollFd::new(stdin.as_fd(), PollFlags::POLLIN)];
    let gone = PollFlags::POLLHUP | PollFlags::POLLERR | PollFlags::POLLNVAL;
    poll(&mut fds, PollTimeout::ZERO).is_ok_and(|n| n > 0)
        && fds[0].revents().is_some_and(|r| r.intersects(gone))
        || matches!(
            nix::unistd::tcgetpgrp(std::io::stdin()),
            Err(nix::errno::Errno::EIO)
        )
}

/// Carries out an action and reports the outcome in the status line; true to quit.
fn perform(action: Action, app: &mut App, source: &mut Source, args: &Args) -> bool {
    let now = Instant::now();
    let what = action.describe();
    let outcome = match action {
        Action::Quit => return true,
        Action::Scan(cmd) => delivery(source.send_scan(cmd, now), "driver"),
        Action::Fusion(cmd) => delivery(source.send_fusion(cmd, now), "fusion engine"),
        Action::SaveMap => match &app.grid {
            None => Err("no map yet".to_owned()),
            Some(grid) => export::save_png(
                &save_dir(args),
                grid,
                // The picture as on screen: with the features while the overlay (`o`) is on.
                app.features
                    .as_ref()
                    .filter(|_| app.show_features)
                    .map(|f| f.records.as_slice()),
                unix_time_ns() / 1_000_000_000,
            )
            .map(|path| format!("saved {}", path.display()))
            .map_err(|e| e.to_string()),
        },
    };
    app.message = Some(match outcome {
        Ok(done) => {
            info!("{what}: {done}");
            format!("{what}: {done}")
        }
        Err(e) => {
            warn!("{what}: {e}");
            format!("{what} failed: {e}")
        }
    });
    false
}

fn save_dir(args: &Args) -> PathBuf {
    args.save_dir.clone().unwrap_or_else(|| {
        export::default_save_dir(std::env::var_os("XDG_DATA_HOME"), std::env::var_os("HOME"))
    })
}

fn delivery(sent: Result<usize, String>, receiver: &str) -> Result<String, String> {
    match sent? {
        0 => Err(format!("no {receiver} is listening")),
        _ => Ok("sent".to_owned()),
    }
}
