//! Support for the end-to-end tests: start the real binaries as separate processes, each test in its
//! own iceoryx2 namespace (prefix + root path), and clean up after them.
//!
//! The binaries are taken from the same target directory as the test executable, so build them first
//! (`cargo build --workspace --bins`, which the README's test command does).
#![allow(clippy::unwrap_used, clippy::expect_used)] // test support: a failure here is a test failure

use std::io::{BufRead, BufReader, Read};
use std::path::PathBuf;
use std::process::{Child, ChildStdout, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use nalgebra::{Isometry2, Vector2};
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use sonar_common::ipc::{self, DriverStatus, FusionStatus, GridHeader, IpcArgs, Pose2D, Reading};

/// Generous bound for anything a test waits for; only there so a broken build fails instead of
/// hanging CI. No test asserts on how fast something happens.
pub const PATIENCE: Duration = Duration::from_secs(60);

/// A serial device the test plays: a pseudo-terminal in raw mode whose slave the driver opens.
#[derive(Debug)]
pub struct FakeSerial {
    /// The device's side: what the test writes here, the driver reads.
    pub master: std::fs::File,
    /// Held open so the master never reads EIO while the driver reopens the slave (and so a test
    /// can read the terminal settings the driver leaves).
    pub slave: std::os::fd::OwnedFd,
    /// The path to give the driver's `--port`.
    pub slave_path: String,
}

impl FakeSerial {
    pub fn open() -> Self {
        use std::os::fd::AsFd;
        let pty = nix::pty::openpty(None, None).unwrap();
        let slave_path = nix::unistd::ttyname(pty.slave.as_fd()).unwrap();
        let mut tio = nix::sys::termios::tcgetattr(pty.slave.as_fd()).unwrap();
        nix::sys::termios::cfmakeraw(&mut tio);
        nix::sys::termios::tcsetattr(pty.slave.as_fd(), nix::sys::termios::SetArg::TCSANOW, &tio)
            .unwrap();
        Self {
            master: std::fs::File::from(pty.master),
            slave: pty.slave,
            slave_path: slave_path.to_str().unwrap().to_owned(),
        }
    }
}

/// The workspace's root directory.
pub fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The Python interpreter with the packages the tests use (`SONAR_PYTHON`, else the workspace's
/// `.venv`, which `.ci/run` sets up).
pub fn python() -> PathBuf {
    let python = std::env::var_os("SONAR_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace().join(".venv/bin/python3"));
    assert!(
        python.exists(),
        "{} missing: run .ci/run once (it makes .venv and installs iceoryx2, mcap, \
         mcap-protobuf-support, websockets, rosbags and eclipse-zenoh)",
        python.display()
    );
    python
}

/// A busy thread that loads a core while it lives: a test that must hold on a loaded machine (CI's
/// is one) runs its processes beside one. Stopped and joined when dropped.
#[derive(Debug)]
pub struct CpuHog {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl CpuHog {
    /// One spinning thread: a core of CI's two taken from the test's processes, with the other
    /// tests of its binary running beside it.
    pub fn start() -> Self {
        use std::sync::atomic::{AtomicBool, Ordering};
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let threads = (0..1)
            .map(|_| {
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let mut x = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        x = std::hint::black_box(
                            x.wrapping_mul(6364136223846793005).wrapping_add(1),
                        );
                    }
                })
            })
            .collect();
        Self { stop, threads }
    }
}

impl Drop for CpuHog {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Subscribers of `sonar/readings` now.
pub fn readings_subscribers(node: &Node<Ipc>) -> usize {
    ipc::readings_service(node)
        .unwrap()
        .dynamic_config()
        .number_of_subscribers()
}

/// Waits (at most [`PATIENCE`]) until `ready`, e.g. until processes have opened their ports.
pub fn wait_until(node: &Node<Ipc>, what: &str, mut ready: impl FnMut() -> bool) {
    let deadline = Instant::now() + PATIENCE;
    while !ready() {
        assert!(Instant::now() < deadline, "gave up waiting for {what}");
        let _ = node.wait(Duration::from_millis(10));
    }
}

/// The standard output of a finished command that must have succeeded.
pub fn check_ok(what: &str, out: &std::process::Output) -> String {
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{what} failed: {:?}\n{stdout}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// Path of a workspace binary next to the running test executable.
pub fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    // target/<profile>/deps/<test-binary> → target/<profile>/<name>
    let dir = exe
        .parent()
        .and_then(|deps| deps.parent())
        .expect("target dir");
    let path = dir.join(name);
    assert!(
        path.exists(),
        "{} is missing: run `cargo build --workspace --bins` before the tests",
        path.display()
    );
    path
}

/// A running process that is stopped with SIGTERM when dropped.
#[derive(Debug)]
pub struct Proc {
    pub name: String,
    pub child: Child,
}

impl Proc {
    /// Sends SIGTERM and waits for the exit; the status tells whether shutdown was clean.
    pub fn terminate(mut self) -> ExitStatus {
        sigterm(&self.child);
        let status = wait_timeout(&mut self.child).unwrap_or_else(|| {
            let _ = self.child.kill();
            panic!("{} did not exit after SIGTERM", self.name)
        });
        std::mem::forget(self);
        status
    }

    /// Kills the process with SIGKILL, as a crash or the OOM killer would (no handler runs, nothing
    /// is cleaned up), and reaps it.
    pub fn kill9(mut self) -> ExitStatus {
        let _ = self.child.kill();
        let status = self.child.wait().expect("reap a killed child");
        std::mem::forget(self);
        status
    }

    /// Sends SIGTERM and waits for the exit; returns its status and standard error.
    pub fn terminate_with_stderr(self) -> (ExitStatus, String) {
        sigterm(&self.child);
        self.wait_exit()
    }

    /// Waits for the process to exit by itself; returns its status and standard error.
    pub fn wait_exit(mut self) -> (ExitStatus, String) {
        let status = wait_timeout(&mut self.child).unwrap_or_else(|| {
            let _ = self.child.kill();
            panic!("{} did not exit", self.name)
        });
        let mut stderr = String::new();
        if let Some(mut e) = self.child.stderr.take() {
            let _ = e.read_to_string(&mut stderr);
        }
        std::mem::forget(self);
        (status, stderr)
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        sigterm(&self.child);
        if wait_timeout(&mut self.child).is_none() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// Asks a child to shut down, as Ctrl-C or systemd would.
fn sigterm(child: &Child) {
    if let Ok(pid) = i32::try_from(child.id()) {
        let _ = kill(Pid::from_raw(pid), Signal::SIGTERM);
    }
}

fn wait_timeout(child: &mut Child) -> Option<ExitStatus> {
    let deadline = Instant::now() + PATIENCE;
    while Instant::now() < deadline {
        if let Ok(Some(status)) = child.try_wait() {
            return Some(status);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    None
}

/// Stops a driver and returns how many readings it published, from its stop line. Not counted
/// by a subscriber of the test's: on a loaded machine the readings published while the driver
/// shuts down can overflow its buffer, and a reading dropped there was still fused.
pub fn stop_driver(driver: Proc) -> u64 {
    let (status, stderr) = driver.terminate_with_stderr();
    assert!(status.success(), "driver did not exit cleanly: {stderr}");
    stderr
        .lines()
        .filter(|l| l.contains("driver stopped"))
        .find_map(|l| {
            let field = l
                .split_whitespace()
                .find_map(|w| w.strip_prefix("readings="))?;
            field.parse().ok()
        })
        .unwrap_or_else(|| panic!("no 'driver stopped readings=N' line in\n{stderr}"))
}

/// One test's private iceoryx2 namespace and the processes it started.
#[derive(Debug)]
pub struct Sandbox {
    pub prefix: String,
    pub root: PathBuf,
    /// The processes' `$XDG_STATE_HOME`: what they keep between runs (the fusion's saved map, the
    /// launcher's logs) stays in the test, never in the user's home.
    pub state: PathBuf,
    /// A network namespace its processes run in (`ip netns exec`), if any.
    pub netns: Option<String>,
}

impl Sandbox {
    pub fn new(test: &str) -> Self {
        let tag = format!("sonar_t{}_{test}_", std::process::id());
        let root = std::env::temp_dir().join(format!("{tag}root"));
        let state = std::env::temp_dir().join(format!("{tag}state"));
        for dir in [&root, &state] {
            let _ = std::fs::remove_dir_all(dir);
            std::fs::create_dir_all(dir).unwrap();
        }
        Self {
            prefix: tag,
            root,
            state,
            netns: None,
        }
    }

    /// The same, with its processes in network namespace `netns` (which the test made).
    pub fn in_netns(test: &str, netns: &str) -> Self {
        let mut sandbox = Self::new(test);
        sandbox.netns = Some(netns.to_owned());
        sandbox
    }

    pub fn ipc_args(&self) -> IpcArgs {
        IpcArgs {
            iox_config: None,
            iox_prefix: Some(self.prefix.clone()),
            iox_root: Some(self.root.clone()),
        }
    }

    /// An iceoryx2 node of the test process in this namespace.
    pub fn node(&self, name: &str) -> Node<Ipc> {
        self.ipc_args().node(name).unwrap()
    }

    /// A command for a workspace binary with this namespace in its environment and logs on stderr.
    pub fn command(&self, name: &str) -> Command {
        let mut cmd = match &self.netns {
            Some(netns) => {
                // `ip netns exec` execs the program: its pid is the program's, signals reach it.
                let mut cmd = Command::new("ip");
                cmd.args(["netns", "exec", netns]).arg(bin(name));
                cmd
            }
            None => Command::new(bin(name)),
        };
        cmd.env("SONAR_IOX_PREFIX", &self.prefix)
            .env("SONAR_IOX_ROOT", &self.root)
            .env("XDG_STATE_HOME", &self.state)
            .env(
                "RUST_LOG",
                std::env::var("RUST_LOG").unwrap_or_else(|_| "info".into()),
            )
            .stdin(Stdio::null());
        cmd
    }

    pub fn spawn(&self, name: &str, args: &[&str]) -> Proc {
        let child = self
            .command(name)
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("start {name}: {e}"));
        Proc {
            name: name.to_owned(),
            child,
        }
    }

    /// Starts the simulator and returns it with the path of its pseudo-terminal.
    pub fn spawn_sim(&self, args: &[&str]) -> (Proc, String) {
        self.spawn_head("sonar-sim", args)
    }

    /// Starts a sensor head behind a pseudo-terminal (`sonar-sim` or `sonar-firmware-sim`, which
    /// both print `PTY <path>` first) and returns it with that path.
    pub fn spawn_head(&self, name: &str, args: &[&str]) -> (Proc, String) {
        let mut head = Proc {
            name: name.into(),
            child: self
                .command(name)
                .args(args)
                .stdout(Stdio::piped())
                .stderr(Stdio::inherit())
                .spawn()
                .unwrap_or_else(|e| panic!("start {name}: {e}")),
        };
        let pty = read_pty_line(head.child.stdout.take().expect("head stdout"));
        (head, pty)
    }

    /// Runs a workspace binary in this namespace to its end; its status and output.
    pub fn run(&self, name: &str, args: &[&str]) -> std::process::Output {
        self.command(name)
            .args(args)
            .output()
            .unwrap_or_else(|e| panic!("run {name}: {e}"))
    }

    /// Files this namespace has in /dev/shm.
    pub fn shm_files(&self) -> Vec<String> {
        std::fs::read_dir("/dev/shm")
            .map(|dir| {
                dir.filter_map(|e| e.ok())
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|n| n.starts_with(&self.prefix))
                    .collect()
            })
            .unwrap_or_default()
    }

    /// Files left in /dev/shm once every process of the namespace has gone, except the 16-byte
    /// global management file that iceoryx2 keeps per prefix by design.
    pub fn stale_shm_files(&self) -> Vec<String> {
        self.shm_files()
            .into_iter()
            .filter(|f| !f.ends_with(".global_mgmt"))
            .collect()
    }
}

impl Sandbox {
    /// iceoryx2's files and node directories left under the root (in its `nodes/` and `services/`)
    /// once every process of the namespace has gone; a test may keep its own files beside them.
    pub fn stale_root_files(&self) -> Vec<PathBuf> {
        fn walk(dir: &std::path::Path, found: &mut Vec<PathBuf>) {
            for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
                let path = entry.path();
                if path.is_dir() {
                    walk(&path, found);
                }
                found.push(path);
            }
        }
        let mut found = Vec::new();
        for dir in ["nodes", "services"] {
            walk(&self.root.join(dir), &mut found);
        }
        found
    }
}

impl Drop for Sandbox {
    fn drop(&mut self) {
        for f in self.shm_files() {
            let _ = std::fs::remove_file(format!("/dev/shm/{f}"));
        }
        let _ = std::fs::remove_dir_all(&self.root);
        let _ = std::fs::remove_dir_all(&self.state);
    }
}

/// The simulator prints `PTY <path>` as its first line.
fn read_pty_line(stdout: ChildStdout) -> String {
    let mut line = String::new();
    BufReader::new(stdout)
        .read_line(&mut line)
        .expect("read simulator stdout");
    line.strip_prefix("PTY ")
        .unwrap_or_else(|| panic!("simulator printed {line:?} instead of `PTY <path>`"))
        .trim()
        .to_owned()
}

/// Polls `receive` until `done` says enough, or [`PATIENCE`] runs out (then panics).
pub fn collect_until<T>(
    node: &Node<Ipc>,
    mut receive: impl FnMut() -> Option<T>,
    mut done: impl FnMut(&[T]) -> bool,
) -> Vec<T> {
    let deadline = Instant::now() + PATIENCE;
    let mut got = Vec::new();
    loop {
        while let Some(item) = receive() {
            got.push(item);
            if done(&got) {
                return got;
            }
        }
        assert!(
            Instant::now() < deadline,
            "gave up waiting after {} items",
            got.len()
        );
        let _ = node.wait(Duration::from_millis(5));
    }
}

/// A terminal for a text program: a detached tmux session on a private server socket, so tests
/// never see each other's sessions. Killed with its server when dropped.
#[derive(Debug)]
pub struct Tmux {
    socket: PathBuf,
}

impl Tmux {
    /// Starts `name` (a workspace binary, with `args`) in a `cols` × `rows` terminal, inside a
    /// shell that prints `EXIT=<status>` when it ends and stays, so the test can see the status
    /// and what the terminal looked like afterwards.
    pub fn start(sandbox: &Sandbox, name: &str, args: &[&str], cols: u16, rows: u16) -> Self {
        let socket = sandbox.root.join("tmux.sock");
        // In the sandbox's network namespace, if it has one, as its other processes.
        let netns = sandbox
            .netns
            .as_ref()
            .map(|ns| format!("ip netns exec {ns} "))
            .unwrap_or_default();
        let mut line = format!(
            "SONAR_IOX_PREFIX={} SONAR_IOX_ROOT={} XDG_STATE_HOME={} {netns}{}",
            sandbox.prefix,
            sandbox.root.display(),
            sandbox.state.display(),
            bin(name).display()
        );
        for a in args {
            line.push(' ');
            line.push_str(a);
        }
        line.push_str("; echo EXIT=$?; sleep 600");
        let tmux = Self { socket };
        let status = tmux
            .cmd()
            .args([
                "new-session",
                "-d",
                "-x",
                &cols.to_string(),
                "-y",
                &rows.to_string(),
            ])
            .arg(line)
            .status()
            .expect("run tmux (apt-get install -y tmux)");
        assert!(status.success(), "tmux new-session failed");
        tmux
    }

    fn cmd(&self) -> Command {
        let mut cmd = Command::new("tmux");
        cmd.arg("-S").arg(&self.socket).stdin(Stdio::null());
        cmd
    }

    /// Types keys, in tmux `send-keys` notation (`f`, `Enter`, `C-c`).
    pub fn send_keys(&self, keys: &[&str]) {
        let status = self.cmd().arg("send-keys").args(keys).status().unwrap();
        assert!(status.success(), "tmux send-keys {keys:?} failed");
    }

    /// The screen as text, without colours.
    pub fn capture(&self) -> String {
        let out = self.cmd().args(["capture-pane", "-p"]).output().unwrap();
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    /// Waits until the screen satisfies `pred`; returns it. Fails with the last screen after
    /// [`PATIENCE`].
    pub fn wait_for(&self, what: &str, pred: impl Fn(&str) -> bool) -> String {
        let deadline = Instant::now() + PATIENCE;
        loop {
            let screen = self.capture();
            if pred(&screen) {
                return screen;
            }
            assert!(
                Instant::now() < deadline,
                "gave up waiting for {what}; the screen:\n{screen}"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

/// Rows of the screen holding a horizontal run of at least `len` wall glyphs, by row index: `▄`
/// for the grid's occupied cells and `─` for a wall of `sonar/features` drawn over them (see the
/// viewer's README). Only inside the map's frame: after its left border `│` and before its right
/// one, which the status panel's left border follows (`││`); the frame's top and bottom rows
/// (`┌─…`, `└─…`) are not inside.
pub fn map_wall_rows(screen: &str, len: usize) -> Vec<usize> {
    screen
        .lines()
        .enumerate()
        .filter(|(_, line)| {
            let Some(inside) = line.strip_prefix('│') else {
                return false;
            };
            let map = inside.split("││").next().unwrap_or(inside);
            let mut run = 0;
            map.chars().any(|c| {
                run = if c == '▄' || c == '─' { run + 1 } else { 0 };
                run >= len
            })
        })
        .map(|(i, _)| i)
        .collect()
}

impl Drop for Tmux {
    fn drop(&mut self) {
        let _ = self.cmd().arg("kill-server").status();
    }
}

/// The processes whose parent is `pid`, as (pid, program name), from /proc.
pub fn children_of(pid: u32) -> Vec<(u32, String)> {
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    dir.filter_map(|e| e.ok())
        .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
        .filter_map(|child| {
            // `pid (comm) state ppid …`; comm may hold spaces, so split after the last `)`.
            let stat = std::fs::read_to_string(format!("/proc/{child}/stat")).ok()?;
            let (head, tail) = stat.rsplit_once(')')?;
            let comm = head.split_once('(')?.1.to_owned();
            let ppid: u32 = tail.split_whitespace().nth(1)?.parse().ok()?;
            (ppid == pid).then_some((child, comm))
        })
        .collect()
}

/// Waits until process `pid` has a running child named `name` other than `not` (e.g. the one
/// just killed); returns its pid.
pub fn child_named(pid: u32, name: &str, not: Option<u32>) -> u32 {
    let deadline = Instant::now() + PATIENCE;
    loop {
        if let Some((child, _)) = children_of(pid)
            .into_iter()
            .find(|(c, comm)| comm == name && Some(*c) != not && is_running(*c))
        {
            return child;
        }
        assert!(
            is_running(pid),
            "process {pid}, the parent of {name}, has exited"
        );
        assert!(Instant::now() < deadline, "{name} never started");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Whether process `pid` still exists (a zombie counts as gone).
pub fn is_running(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|s| {
            s.rsplit_once(')')
                .map(|(_, t)| t.trim_start().starts_with('Z'))
        })
        .is_some_and(|zombie| !zombie)
}

/// Running processes of program `name` whose command line contains `needle` (e.g. a path unique
/// to one test), by pid.
pub fn pids_of(name: &str, needle: &str) -> Vec<u32> {
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    dir.filter_map(|e| e.ok())
        .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
        .filter(|pid| {
            std::fs::read_to_string(format!("/proc/{pid}/comm")).is_ok_and(|c| c.trim() == name)
                && std::fs::read(format!("/proc/{pid}/cmdline"))
                    .is_ok_and(|c| String::from_utf8_lossy(&c).contains(needle))
        })
        .filter(|&pid| is_running(pid))
        .collect()
}

impl Tmux {
    /// Ends the terminal as a dropped SSH connection would: the tmux server and its terminals go.
    pub fn hang_up(&self) {
        let _ = self.cmd().arg("kill-server").status();
    }

    /// Resizes the terminal to `cols` × `rows`, as a user dragging the window's corner.
    pub fn resize(&self, cols: u16, rows: u16) {
        let status = self
            .cmd()
            .args([
                "resize-window",
                "-x",
                &cols.to_string(),
                "-y",
                &rows.to_string(),
            ])
            .status()
            .expect("tmux runs");
        assert!(status.success(), "tmux resize-window failed");
    }
}

/// A temporary path as the `&str` a command line takes.
pub fn path_str(p: &std::path::Path) -> &str {
    p.to_str().expect("temp paths are UTF-8")
}

/// A subscriber to `sonar/readings`; subscribe before the driver starts to miss nothing.
/// A subscriber of `sonar/localized_pose`.
pub fn localized_pose_subscriber(node: &Node<Ipc>) -> Subscriber<Ipc, ipc::LocalizedPose, ()> {
    ipc::localized_pose_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

/// `robot/true_pose`: the simulator's truth beside its odometry.
pub fn true_pose_subscriber(node: &Node<Ipc>) -> Subscriber<Ipc, Pose2D, ()> {
    ipc::true_pose_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

pub fn slam_correction_subscriber(node: &Node<Ipc>) -> Subscriber<Ipc, ipc::SlamCorrection, ()> {
    ipc::slam_correction_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

pub fn grid_subscriber(node: &Node<Ipc>) -> Subscriber<Ipc, [u8], GridHeader> {
    ipc::grid_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

pub fn readings_subscriber(node: &Node<Ipc>) -> Subscriber<Ipc, Reading, ()> {
    ipc::readings_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

/// A subscriber to `sonar/sweep_ends`.
pub fn sweep_ends_subscriber(node: &Node<Ipc>) -> Subscriber<Ipc, ipc::SweepEnd, ()> {
    ipc::sweep_ends_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

pub fn receive_reading(sub: &Subscriber<Ipc, Reading, ()>) -> Option<Reading> {
    sub.receive().unwrap().map(|s| *s.payload())
}

/// A subscriber to `sonar/driver_status`.
pub fn driver_status_subscriber(node: &Node<Ipc>) -> Subscriber<Ipc, DriverStatus, ()> {
    ipc::driver_status_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

/// A subscriber to `sonar/fusion_status`.
/// What a test needs to stand in for the driver: the `sonar/readings` publisher and the notifier
/// of its wake-up event (send a reading, then notify, as the driver does).
pub fn driver_ports(
    node: &Node<Ipc>,
) -> (
    iceoryx2::port::publisher::Publisher<Ipc, Reading, ()>,
    iceoryx2::port::notifier::Notifier<Ipc>,
) {
    let readings = ipc::readings_service(node)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    let wake = ipc::wakeup_notifier(node, ipc::READINGS_SERVICE).unwrap();
    (readings, wake)
}

/// Sends one scan command on `sonar/commands`, as the viewer or any script does. Keep the
/// publisher until the command has had its effect: iceoryx2 drops a departed publisher's samples
/// that no subscriber has taken yet.
#[must_use = "dropping the publisher may drop the command before the driver takes it"]
pub fn send_scan_command(
    node: &Node<Ipc>,
    command: ipc::ScanCommand,
) -> iceoryx2::port::publisher::Publisher<Ipc, ipc::ScanCommand, ()> {
    let publisher = ipc::commands_service(node)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    publisher.send_copy(command).unwrap();
    publisher
}

pub fn fusion_status_subscriber(node: &Node<Ipc>) -> Subscriber<Ipc, FusionStatus, ()> {
    ipc::fusion_status_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

/// Waits for a status (the driver's or the fusion's) that satisfies `pred` and returns it.
pub fn wait_for_status<T: std::fmt::Debug + Copy + ZeroCopySend>(
    node: &Node<Ipc>,
    sub: &Subscriber<Ipc, T, ()>,
    pred: impl Fn(&T) -> bool,
) -> T {
    let got = collect_until(
        node,
        || sub.receive().unwrap().map(|s| *s.payload()),
        |got| got.last().is_some_and(&pred),
    );
    *got.last().unwrap()
}

/// The corridor scene's grid for a fusion (`--config`): 450 cells of 2 cm around its middle, so
/// both rooms and the corridor fit. Written to a file of the sandbox's test, which the caller
/// removes.
pub fn corridor_grid_config(test: &str) -> PathBuf {
    let config = std::env::temp_dir().join(format!("sonar_t{}_{test}.toml", std::process::id()));
    std::fs::write(
        &config,
        "[fusion.grid]\ncells = 450\nresolution_m = 0.02\ncentre_x_m = 3.0\ncentre_y_m = 1.5\n",
    )
    .unwrap();
    config
}

/// Whether a `sonar/grid` snapshot (`header`, `cells`) has at least 5 occupied cells (p ≥ 0.8)
/// within 6 cm of the corridor scene's back wall (y = 3.6 m) and 30 cm of `x_m`: the wall seen from
/// the room below it.
pub fn back_wall_seen_at(header: &GridHeader, cells: &[u8], x_m: f32) -> bool {
    let res = header.resolution_m;
    let mut hits = 0;
    for dy in -3..=3 {
        for dx in -15..=15 {
            let (x, y) = (x_m + dx as f32 * res, 3.6 + dy as f32 * res);
            let col = ((x - header.origin_x_m) / res) as usize;
            let row = ((y - header.origin_y_m) / res) as usize;
            if cells
                .get(row * header.width as usize + col)
                .is_some_and(|&c| c >= 203)
            {
                hits += 1;
            }
        }
    }
    hits >= 5
}

/// A private copy of a `sonar/grid` snapshot.
#[derive(Debug)]
pub struct GridSnapshot {
    pub header: GridHeader,
    pub cells: Vec<u8>,
}

impl GridSnapshot {
    /// The highest probability of the cells within `radius` cells of world point (`x`, `y`),
    /// `None` if all of them are unknown.
    pub fn max_near(&self, x: f32, y: f32, radius: i64) -> Option<f32> {
        let h = &self.header;
        let cx = ((x - h.origin_x_m) / h.resolution_m).floor() as i64;
        let cy = ((y - h.origin_y_m) / h.resolution_m).floor() as i64;
        let mut best = None;
        for j in cy - radius..=cy + radius {
            for i in cx - radius..=cx + radius {
                let inside = (0..h.width as i64).contains(&i) && (0..h.height as i64).contains(&j);
                assert!(inside, "({x}, {y}) lies outside the grid");
                let cell = self.cells[(j * h.width as i64 + i) as usize];
                if let Some(p) = ipc::decode_probability(cell) {
                    best = Some(best.map_or(p, |b: f32| b.max(p)));
                }
            }
        }
        best
    }
}

/// The simulator's true poses (`robot/true_pose`), gathered beside an estimate's messages.
#[derive(Debug)]
pub struct TruePoses(Vec<Pose2D>);

impl TruePoses {
    /// The true pose nearest `stamp_ns`, if one lies within 10 ms of it.
    pub fn at(&self, stamp_ns: u64) -> Option<Isometry2<f32>> {
        self.0
            .iter()
            .min_by_key(|t| t.stamp_ns.abs_diff(stamp_ns))
            .filter(|t| t.stamp_ns.abs_diff(stamp_ns) < 10_000_000)
            .map(|t| Isometry2::new(Vector2::new(t.x_m, t.y_m), t.theta_rad))
    }
}

/// `n` messages of `estimates`, and every true pose that arrived on `truth` meanwhile.
pub fn collect_with_truth<T>(
    node: &Node<Ipc>,
    truth: &Subscriber<Ipc, Pose2D, ()>,
    mut estimates: impl FnMut() -> Option<T>,
    n: usize,
) -> (Vec<T>, TruePoses) {
    let mut true_poses = Vec::new();
    let got = collect_until(
        node,
        || {
            while let Some(p) = truth.receive().unwrap() {
                true_poses.push(*p.payload());
            }
            estimates()
        },
        |got| got.len() >= n,
    );
    (got, TruePoses(true_poses))
}

pub mod room;

/// A subscriber to `sonar/features` (fixed-size records behind a header).
pub fn features_subscriber(
    node: &Node<Ipc>,
) -> Subscriber<Ipc, [ipc::FeatureRecord], ipc::FeaturesHeader> {
    ipc::features_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

/// Snapshots of `sonar/features` until one with at least `min_sweeps` merged satisfies
/// `expected`, or `max_sweeps` have been merged (then the test fails with what is wrong in the
/// last one). Returns that snapshot.
pub fn room_features(
    node: &Node<Ipc>,
    features: &Subscriber<Ipc, [ipc::FeatureRecord], ipc::FeaturesHeader>,
    expected: &room::Expected,
    min_sweeps: u64,
    max_sweeps: u64,
) -> (ipc::FeaturesHeader, Vec<ipc::FeatureRecord>) {
    let got = collect_until(
        node,
        || {
            features
                .receive()
                .unwrap()
                .map(|s| (*s.user_header(), s.payload().to_vec()))
        },
        |got| {
            got.last().is_some_and(|(header, records)| {
                header.sweeps >= max_sweeps
                    || (header.sweeps >= min_sweeps && expected.check(records).is_ok())
            })
        },
    );
    let (header, records) = got.last().unwrap().clone();
    if let Err(wrong) = expected.check(&records) {
        panic!("after {} sweeps: {wrong}", header.sweeps);
    }
    (header, records)
}

/// A network namespace of the test's own with only its loopback up, removed when dropped: the
/// live server and its client talk inside it, never on the machine's own interfaces.
#[derive(Debug)]
pub struct Netns(String);

impl Netns {
    pub fn new(tag: &str) -> Self {
        let name = format!("sonar-{tag}-{}", std::process::id());
        let ip = |args: &[&str]| {
            let out = Command::new("ip").args(args).output().unwrap();
            check_ok(&format!("ip {}", args.join(" ")), &out);
        };
        ip(&["netns", "add", &name]);
        let ns = Self(name);
        ip(&["-n", &ns.0, "link", "set", "lo", "up"]);
        ns
    }

    /// Its name, for `Sandbox::in_netns`.
    pub fn name(&self) -> &str {
        &self.0
    }

    /// `command`, run inside the namespace with the same arguments and environment.
    pub fn wrap(&self, command: &Command) -> Command {
        let mut wrapped = Command::new("ip");
        wrapped
            .args(["netns", "exec", &self.0])
            .arg(command.get_program())
            .args(command.get_args());
        for (key, value) in command.get_envs() {
            if let Some(value) = value {
                wrapped.env(key, value);
            }
        }
        wrapped
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        let _ = Command::new("ip").args(["netns", "del", &self.0]).status();
    }
}

/// Scans the simulated room (×100, seed 3) through a driver until at least `readings_wanted`
/// readings came, stops the driver and waits until the fusion has fused every reading sent;
/// returns the simulator (still running) and that count.
pub fn scan_room_until_fused(
    sandbox: &Sandbox,
    node: &Node<Ipc>,
    readings: &Subscriber<Ipc, Reading, ()>,
    grid: &Subscriber<Ipc, [u8], GridHeader>,
    readings_wanted: usize,
) -> (Proc, usize) {
    let (sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "100", "--seed", "3"]);
    let driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);
    let got = collect_until(
        node,
        || readings.receive().unwrap().map(|s| s.payload().seq),
        |got| got.len() >= readings_wanted,
    );
    let mut count = got.len();
    assert!(driver.terminate().success(), "driver did not exit cleanly");
    while readings.receive().unwrap().is_some() {
        count += 1;
    }
    collect_until(
        node,
        || {
            grid.receive()
                .unwrap()
                .map(|s| s.user_header().readings_fused)
        },
        |got| got.last() == Some(&(count as u64)),
    );
    (sim, count)
}

/// Starts the simulator touring the built-in corridor at ×10 (seed 1) with an odometry 3 % long
/// and 2°/m of heading drift, and a driver on it: the drifting tour the localisation, SLAM and
/// frames tests share (at 10× the stops' sweeps are taken standing still). Returns the simulator
/// and the driver.
pub fn drive_drifting_corridor(sandbox: &Sandbox) -> (Proc, Proc) {
    let (sim, pty) = sandbox.spawn_sim(&[
        "--scene",
        "corridor",
        "--speed",
        "10",
        "--seed",
        "1",
        "--odom-scale-error",
        "0.03",
        "--odom-heading-drift",
        "2",
    ]);
    let driver = sandbox.spawn("sonar-driver", &["--port", &pty]);
    (sim, driver)
}

/// The number written after `key` in `text` (a log line's `key=N`, a status line's `key N `).
pub fn number_after(text: &str, key: &str) -> Option<u64> {
    text.split(key)
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|n| n.parse().ok())
}
