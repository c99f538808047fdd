//! End to end: `kill -9` of the pipeline's processes at random moments, start-up included, never
//! leaves the iceoryx2 namespace unusable (issue 10, item 5).
//!
//! `SONAR_KILL_LOOPS` sets the number of kills (CI: 20), `SONAR_KILL_SEED` repeats a run (the seed
//! of every run is printed). The documented long run:
//!
//! ```sh
//! cargo build --workspace --bins
//! SONAR_KILL_LOOPS=1000 cargo test -p sonar-e2e --test kill_loop -- --nocapture
//! ```
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::fs::File;
use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sonar_common::ipc::{self, unix_time_ns};
use sonar_e2e::{PATIENCE, Proc, Sandbox, child_named, readings_subscriber, receive_reading};

const CHILDREN: [&str; 3] = ["sonar-sim", "sonar-driver", "sonar-fusion"];
/// Kills in CI; the documented run uses 1,000.
const DEFAULT_LOOPS: usize = 20;
/// A restarted `sonar-fusion` (debug build) creates its node and services within this long after
/// its start: a kill this soon after one lands in the middle of it.
const START_UP: Duration = Duration::from_millis(300);

fn env_number(name: &str) -> Option<u64> {
    std::env::var(name).ok().map(|v| {
        v.parse()
            .unwrap_or_else(|_| panic!("{name}={v:?} is not a number"))
    })
}

fn sigkill(pid: u32) {
    // The process may have died meanwhile (a kill during its start-up): that is fine.
    let _ = kill(Pid::from_raw(pid as i32), Signal::SIGKILL);
}

#[test]
fn kill_9_at_random_moments_never_leaves_the_namespace_unusable() {
    let loops = env_number("SONAR_KILL_LOOPS").map_or(DEFAULT_LOOPS, |n| n as usize);
    let seed = env_number("SONAR_KILL_SEED").unwrap_or_else(unix_time_ns);
    eprintln!("kill loop: {loops} kills, seed {seed} (SONAR_KILL_SEED={seed} repeats it)");
    let mut rng = ChaCha8Rng::seed_from_u64(seed);

    let sandbox = Sandbox::new("killloop");
    let node = sandbox.node("test-consumer");
    let readings = readings_subscriber(&node);
    let grid = ipc::grid_service(&node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    // Outside the root, which the sandbox removes: kept for a post-mortem when the test fails.
    let logs = std::env::temp_dir().join(format!("{}logs", sandbox.prefix));
    std::fs::create_dir_all(&logs).unwrap();
    let _diagnostics = Diagnostics { logs: &logs, seed };
    // The kills are deliberate: no crash-loop limit may end the run, and no back-off slow it.
    let config = logs.join("pipeline.toml");
    std::fs::write(
        &config,
        "[launcher]\nmax_restarts = 1000000\nrestart_delay = 0.05\n",
    )
    .unwrap();
    let launcher = Proc {
        name: "sonar-pipeline".into(),
        child: sandbox
            .command("sonar-pipeline")
            .args([
                "--no-viewer",
                "--speed",
                "100",
                "--config",
                config.to_str().unwrap(),
                "--log-dir",
                logs.to_str().unwrap(),
            ])
            .stdout(Stdio::null())
            .stderr(File::create(logs.join("sonar-pipeline.log")).unwrap())
            .spawn()
            .unwrap(),
    };
    let pid = launcher.child.id();

    // Usable: readings reach a subscriber that stayed, and the fusion publishes grids, both made
    // after `since` (ns since the epoch), i.e. by the processes running now.
    let usable = |since: u64, what: &str| {
        let deadline = Instant::now() + PATIENCE;
        let (mut fresh_readings, mut fresh_grid) = (0, false);
        while fresh_readings < 3 || !fresh_grid {
            while let Some(r) = receive_reading(&readings) {
                fresh_readings += usize::from(r.host_stamp_ns > since);
            }
            while let Some(sample) = grid.receive().unwrap() {
                fresh_grid |= sample.user_header().stamp_ns > since;
            }
            assert!(
                Instant::now() < deadline,
                "{what}: the pipeline did not come back ({fresh_readings} new readings, new grid: \
                 {fresh_grid})"
            );
            let _ = node.wait(Duration::from_millis(10));
        }
    };
    usable(0, "start");

    let mut in_start_up = 0;
    for kill_no in 1..=loops {
        let name = CHILDREN[rng.random_range(0..CHILDREN.len())];
        let victim = child_named(pid, name, None);
        // Now, a little later, or while it runs; and every other time its successor at once,
        // while it creates its node and services.
        let wait = match rng.random_range(0..3) {
            0 => Duration::ZERO,
            1 => Duration::from_millis(rng.random_range(0..100)),
            _ => Duration::from_millis(rng.random_range(0..2000)),
        };
        std::thread::sleep(wait);
        sigkill(victim);
        let mut successor = child_named(pid, name, Some(victim));
        if rng.random_bool(0.5) {
            let early = rng.random_range(Duration::ZERO..START_UP);
            std::thread::sleep(early);
            sigkill(successor);
            in_start_up += 1;
            successor = child_named(pid, name, Some(successor));
        }
        let what = format!("kill {kill_no} of {loops} ({name} {victim}, then {successor})");
        usable(unix_time_ns(), &what);
        eprintln!("{what}: usable again");
    }

    // A clean stop: nothing of the namespace is left but iceoryx2's per-prefix node counter.
    kill(Pid::from_raw(pid as i32), Signal::SIGTERM).unwrap();
    let (status, _) = launcher.wait_exit();
    assert!(status.success(), "the launcher failed ({status})");
    drop((readings, grid, node));
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
    let left = sandbox.stale_root_files();
    assert!(left.is_empty(), "stale iceoryx2 files: {left:?}");
    eprintln!(
        "kill loop: {loops} kills survived, {in_start_up} more during a restarted process's \
         start-up (seed {seed})"
    );
    std::fs::remove_dir_all(&logs).unwrap();
}

/// On a failure, says how to repeat the run and shows the end of every process's log.
struct Diagnostics<'a> {
    logs: &'a Path,
    seed: u64,
}

impl Drop for Diagnostics<'_> {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            return;
        }
        let (logs, seed) = (self.logs.display(), self.seed);
        eprintln!("kill loop failed: SONAR_KILL_SEED={seed} repeats it; the logs are in {logs}");
        for name in ["sonar-pipeline"].iter().chain(&CHILDREN) {
            let text = std::fs::read_to_string(self.logs.join(format!("{name}.log")));
            let text = text.unwrap_or_default();
            let lines: Vec<&str> = text.lines().collect();
            let tail = lines[lines.len().saturating_sub(20)..].join("\n");
            eprintln!("--- the end of {name}.log:\n{tail}");
        }
    }
}
