//! The pipeline's processes in an iceoryx2 namespace of their own, and what the kernel says they
//! cost (`/proc`).

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::waitset::{WaitSet, WaitSetRunResult};
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use sonar_common::ipc::{self as sonar_ipc, GridHeader, IpcArgs, IpcError};

/// A namespace (prefix, root, state directory) and the processes started in it; dropping it stops
/// them and removes what the namespace left in `/dev/shm`.
#[derive(Debug)]
pub struct Sandbox {
    prefix: String,
    dir: PathBuf,
    bin_dir: PathBuf,
    children: Vec<(String, Child)>,
}

impl Sandbox {
    pub fn new(tag: &str, bin_dir: &Path) -> Result<Self> {
        let prefix = format!("sonar_b{}_{tag}_", std::process::id());
        let dir = std::env::temp_dir().join(format!("{prefix}dir"));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("root"))
            .with_context(|| format!("create {}", dir.display()))?;
        Ok(Self {
            prefix,
            dir,
            bin_dir: bin_dir.to_owned(),
            children: Vec::new(),
        })
    }

    pub fn ipc_args(&self) -> IpcArgs {
        IpcArgs {
            iox_config: None,
            iox_prefix: Some(self.prefix.clone()),
            iox_root: Some(self.dir.join("root")),
        }
    }

    pub fn node(&self, name: &str) -> Result<Node<ipc::Service>> {
        Ok(self.ipc_args().node(name)?)
    }

    /// A scratch path inside the sandbox's directory.
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Starts `program` (a workspace binary beside this one, or this one for "sonar-bench") in the
    /// namespace, its log in the sandbox's directory; returns its pid.
    pub fn spawn(&mut self, program: &str, args: &[&str]) -> Result<u32> {
        self.spawn_with(program, args, |_| {})
    }

    /// The same, letting the caller set up the command further (a terminal as its stdio).
    pub fn spawn_with(
        &mut self,
        program: &str,
        args: &[&str],
        setup: impl FnOnce(&mut Command),
    ) -> Result<u32> {
        let log_path = self.log_path(program, self.children.len());
        let log =
            File::create(&log_path).with_context(|| format!("create {}", log_path.display()))?;
        let mut cmd = Command::new(self.bin_dir.join(program));
        cmd.args(args)
            .env("SONAR_IOX_PREFIX", &self.prefix)
            .env("SONAR_IOX_ROOT", self.dir.join("root"))
            .env("XDG_STATE_HOME", &self.dir)
            .env("RUST_LOG", "info")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log);
        setup(&mut cmd);
        let child = cmd
            .spawn()
            .with_context(|| format!("start {} (built with --release?)", program))?;
        let pid = child.id();
        self.children.push((program.to_owned(), child));
        Ok(pid)
    }

    /// Starts `sonar-fusion` at `cells`² × `resolution` m without saving or restoring a map
    /// (default preset, features on, `--max-rate 10`); returns its pid.
    pub fn spawn_fusion(&mut self, cells: u32, resolution: f32) -> Result<u32> {
        let (cells, resolution) = (cells.to_string(), resolution.to_string());
        self.spawn(
            "sonar-fusion",
            &[
                "--no-persist",
                "--cells",
                &cells,
                "--resolution",
                &resolution,
            ],
        )
    }

    fn log_path(&self, program: &str, index: usize) -> PathBuf {
        self.dir.join(format!("{program}.{index}.log"))
    }

    /// The pids and names of the processes still running.
    pub fn processes(&self) -> Vec<(String, u32)> {
        self.children
            .iter()
            .map(|(name, child)| (name.clone(), child.id()))
            .collect()
    }

    /// Stops process `pid` with SIGTERM (SIGKILL after 10 s) and returns its log.
    pub fn stop(&mut self, pid: u32) -> Result<String> {
        let Some(index) = self.children.iter().position(|(_, c)| c.id() == pid) else {
            bail!("no process {pid} in this sandbox");
        };
        let (program, mut child) = self.children.remove(index);
        terminate(&mut child);
        let log_path = self.log_path(&program, index);
        std::fs::read_to_string(&log_path).with_context(|| format!("read {}", log_path.display()))
    }

    /// Fails with the log of any process that has exited.
    pub fn check_running(&mut self) -> Result<()> {
        for (index, (program, child)) in self.children.iter_mut().enumerate() {
            if let Some(status) = child.try_wait()? {
                let log = std::fs::read_to_string(self.dir.join(format!("{program}.{index}.log")))
                    .unwrap_or_default();
                bail!("{program} exited ({status}):\n{log}");
            }
        }
        Ok(())
    }

    /// The namespace's files in `/dev/shm`.
    fn shm_files(&self) -> impl Iterator<Item = std::fs::DirEntry> + '_ {
        std::fs::read_dir("/dev/shm")
            .into_iter()
            .flatten()
            .flatten()
            .filter(|entry| {
                entry
                    .file_name()
                    .to_string_lossy()
                    .starts_with(&self.prefix)
            })
    }

    /// The namespace's files in `/dev/shm`: (apparent bytes, bytes of memory in use).
    pub fn shm_bytes(&self) -> (u64, u64) {
        use std::os::unix::fs::MetadataExt;
        self.shm_files()
            .filter_map(|entry| entry.metadata().ok())
            .fold((0, 0), |(apparent, used), meta| {
                (apparent + meta.len(), used + meta.blocks() * 512)
            })
    }
}

impl Drop for Sandbox {
    fn drop(&mut self) {
        // The last started first: consumers before their producers.
        while let Some((_, mut child)) = self.children.pop() {
            terminate(&mut child);
        }
        for entry in self.shm_files() {
            let _ = std::fs::remove_file(entry.path());
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// The subscriber of a `sonar/grid` consumer.
pub type GridSubscriber = Subscriber<ipc::Service, [u8], GridHeader>;

/// A subscriber of `sonar/grid` and a listener on its wake-up event: what every grid consumer has.
pub fn grid_consumer(
    node: &Node<ipc::Service>,
) -> Result<(GridSubscriber, Listener<ipc::Service>)> {
    let subscriber = sonar_ipc::grid_service(node)?
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new("create grid subscriber", e))?;
    Ok((
        subscriber,
        sonar_ipc::wakeup_listener(node, sonar_ipc::GRID_SERVICE)?,
    ))
}

/// Sleeps on `waitset` until an event arrives or `timeout` passes; false if a signal asks this
/// process to stop.
pub fn wait(waitset: &WaitSet<ipc::Service>, timeout: Duration) -> Result<bool> {
    let result = waitset
        .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, timeout)
        .map_err(|e| IpcError::new("wait", e))?;
    Ok(!matches!(
        result,
        WaitSetRunResult::Interrupt | WaitSetRunResult::TerminationRequest
    ))
}

fn terminate(child: &mut Child) {
    if let Ok(pid) = i32::try_from(child.id()) {
        let _ = kill(Pid::from_raw(pid), Signal::SIGTERM);
    }
    let deadline = Instant::now() + Duration::from_secs(10);
    while Instant::now() < deadline {
        if let Ok(Some(_)) = child.try_wait() {
            return;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let _ = child.kill();
    let _ = child.wait();
}

/// Waits until `ready` holds, checking every 10 ms, or fails after `timeout` saying `what`.
pub fn wait_until(what: &str, timeout: Duration, mut ready: impl FnMut() -> bool) -> Result<()> {
    let deadline = Instant::now() + timeout;
    while !ready() {
        if Instant::now() > deadline {
            bail!("timed out waiting for {what}");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(())
}

/// What `/proc` says a process has used so far.
#[derive(Debug, Clone, Copy, Default)]
pub struct ProcUsage {
    /// User + system CPU time, clock ticks.
    pub cpu_ticks: u64,
    /// Voluntary + involuntary context switches of all its threads: how often it was woken.
    pub switches: u64,
}

impl ProcUsage {
    pub fn of(pid: u32) -> Result<Self> {
        let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .with_context(|| format!("read /proc/{pid}/stat"))?;
        // Fields after the command name (which may hold spaces) in parentheses; utime and stime
        // are fields 14 and 15 of the line, so 12 and 13 after it.
        let after = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
        let fields: Vec<&str> = after.split_whitespace().collect();
        let field = |i: usize| -> Result<u64> {
            fields
                .get(i)
                .and_then(|f| f.parse().ok())
                .with_context(|| format!("field {i} of /proc/{pid}/stat"))
        };
        let cpu_ticks = field(11)? + field(12)?;
        let mut switches = 0;
        for task in std::fs::read_dir(format!("/proc/{pid}/task"))?.flatten() {
            let status = std::fs::read_to_string(task.path().join("status")).unwrap_or_default();
            switches += status_field(&status, "voluntary_ctxt_switches:")
                + status_field(&status, "nonvoluntary_ctxt_switches:");
        }
        Ok(Self {
            cpu_ticks,
            switches,
        })
    }
}

/// The number after `key` in a `/proc` status-like text (0 if absent).
pub fn status_field(text: &str, key: &str) -> u64 {
    text.lines()
        .find_map(|line| line.strip_prefix(key))
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0)
}

/// Clock ticks per second of `/proc/<pid>/stat`'s times.
pub fn clock_ticks_per_second() -> u64 {
    nix::unistd::sysconf(nix::unistd::SysconfVar::CLK_TCK)
        .ok()
        .flatten()
        .and_then(|t| u64::try_from(t).ok())
        .unwrap_or(100)
}

/// The load average over 1, 5 and 15 minutes, as `/proc/loadavg` has it.
pub fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "?".into())
}

/// The `q`-quantile (0..=1) of `samples` by the nearest rank.
pub fn quantile(samples: &[Duration], q: f64) -> Duration {
    let mut sorted = samples.to_vec();
    sorted.sort();
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}

/// A duration for a table: µs below 10 ms, else ms.
pub fn show(d: Duration) -> String {
    let us = d.as_secs_f64() * 1e6;
    if us < 10_000.0 {
        format!("{us:.0} µs")
    } else {
        format!("{:.1} ms", us / 1e3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_by_nearest_rank() {
        let samples: Vec<Duration> = (1..=100).rev().map(Duration::from_millis).collect();
        assert_eq!(quantile(&samples, 0.5), Duration::from_millis(50));
        assert_eq!(quantile(&samples, 0.99), Duration::from_millis(99));
        assert_eq!(quantile(&samples, 1.0), Duration::from_millis(100));
        assert_eq!(quantile(&[], 0.5), Duration::ZERO);
    }

    #[test]
    fn status_fields_are_found_by_key() {
        let text = "Name:\tx\nVmRSS:\t  1234 kB\nvoluntary_ctxt_switches:\t7\n";
        assert_eq!(status_field(text, "VmRSS:"), 1234);
        assert_eq!(status_field(text, "voluntary_ctxt_switches:"), 7);
        assert_eq!(status_field(text, "RssShmem:"), 0);
    }

    #[test]
    fn this_process_has_used_some_cpu_and_been_switched() {
        let usage = ProcUsage::of(std::process::id()).unwrap();
        assert!(usage.switches > 0);
    }
}
