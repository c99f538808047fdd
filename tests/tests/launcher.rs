//! End to end: `sonar-pipeline` starts, supervises and stops the whole pipeline.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::os::unix::process::ExitStatusExt;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use sonar_common::ipc::{self, GridHeader};
use sonar_e2e::{PATIENCE, Sandbox, Tmux, child_named, collect_until, is_running, pids_of};

#[test]
fn the_launcher_restarts_a_dead_process_and_stops_everything_cleanly() {
    let sandbox = Sandbox::new("launcher");
    let node = sandbox.node("test-consumer");
    let grid = ipc::grid_service(&node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    let logs = sandbox.root.join("logs");
    let launcher = sandbox.spawn(
        "sonar-pipeline",
        &[
            "--no-viewer",
            "--speed",
            "100",
            "--log-dir",
            logs.to_str().unwrap(),
        ],
    );
    let pid = launcher.child.id();
    let next = |pred: &dyn Fn(&GridHeader) -> bool| {
        collect_until(
            &node,
            || grid.receive().unwrap().map(|s| *s.user_header()),
            |got| got.last().is_some_and(pred),
        );
    };
    next(&|h| h.readings_fused >= 60);
    let started: Vec<u32> = ["sonar-sim", "sonar-driver", "sonar-fusion"]
        .iter()
        .map(|name| child_named(pid, name, None))
        .collect();

    // The fusion engine crashes; the launcher starts a new one, whose map starts from scratch.
    let fusion = started[2];
    kill(Pid::from_raw(fusion as i32), Signal::SIGKILL).unwrap();
    let restarted = child_named(pid, "sonar-fusion", Some(fusion));
    assert_ne!(restarted, fusion);
    next(&|h| h.readings_fused < 60);
    next(&|h| h.readings_fused >= 60);

    // SIGTERM (systemd's stop, or Ctrl-C) stops every process and leaves no shared memory.
    let (status, stderr) = {
        kill(Pid::from_raw(pid as i32), Signal::SIGTERM).unwrap();
        launcher.wait_exit()
    };
    assert!(status.success(), "{stderr}");
    assert!(stderr.contains("process died: restarting"), "{stderr}");
    for child in started[..2].iter().chain([&restarted]) {
        assert!(!is_running(*child), "process {child} still runs");
    }
    drop((grid, node));
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
    let driver_log = std::fs::read_to_string(logs.join("sonar-driver.log")).unwrap();
    assert!(driver_log.contains("handshake done"), "{driver_log}");
    // The logs are their owner's only.
    use std::os::unix::fs::PermissionsExt;
    let mode = |p: &std::path::Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode(&logs), 0o700);
    for name in ["sonar-driver.log", "sonar-fusion.log", "sonar-sim.log"] {
        assert_eq!(mode(&logs.join(name)), 0o600, "{name}");
    }
}

#[test]
fn a_process_that_fails_at_start_stops_the_pipeline_with_its_error() {
    let sandbox = Sandbox::new("launchfail");
    let logs = sandbox.root.join("logs");
    let logs = logs.to_str().unwrap();
    let (status, stderr) = sandbox
        .spawn(
            "sonar-pipeline",
            &["--no-viewer", "--port", "/dev/ttyNOPE", "--log-dir", logs],
        )
        .wait_exit();
    assert!(!status.success());
    assert!(stderr.contains("sonar-driver failed at start"), "{stderr}");
    assert!(stderr.contains("/dev/ttyNOPE does not exist"), "{stderr}");

    let config = sandbox.root.join("bad.toml");
    std::fs::write(&config, "[serial]\nbuad = 9600\n").unwrap();
    let (status, stderr) = sandbox
        .spawn(
            "sonar-pipeline",
            &[
                "--no-viewer",
                "--config",
                config.to_str().unwrap(),
                "--log-dir",
                logs,
            ],
        )
        .wait_exit();
    assert!(!status.success());
    assert!(stderr.contains("unknown field `buad`"), "{stderr}");
}

/// A scan outside the head's limit switches stops the pipeline with the reason (the head would
/// refuse it for ever, and the pipeline ran with 0 readings); a later run's error quotes that run
/// only, once, in plain text, without iceoryx2's chatter.
#[test]
fn a_scan_outside_the_limits_stops_the_pipeline_and_errors_quote_their_own_run_once() {
    let sandbox = Sandbox::new("launchscan");
    let logs = sandbox.root.join("logs");
    let logs = logs.to_str().unwrap();
    let run = |args: &[&str]| {
        let mut all = vec!["--no-viewer", "--log-dir", logs];
        all.extend_from_slice(args);
        let (status, stderr) = sandbox.spawn("sonar-pipeline", &all).wait_exit();
        assert!(!status.success(), "{stderr}");
        assert!(!stderr.contains('\x1b'), "colour codes in {stderr:?}");
        assert!(!stderr.contains("No config file was loaded"), "{stderr}");
        assert_eq!(
            stderr.matches("sonar-pipeline: error:").count(),
            1,
            "{stderr}"
        );
        stderr
    };

    let stderr = run(&["--scan=100..200", "--speed", "10"]);
    assert!(stderr.contains("sonar-driver stopped"), "{stderr}");
    assert!(
        stderr.contains("lies outside this head's limit switches, -150..150°"),
        "{stderr}"
    );
    let driver_log = std::fs::read_to_string(sandbox.root.join("logs/sonar-driver.log")).unwrap();
    assert!(!driver_log.contains('\x1b'), "colour codes in the log file");

    let stderr = run(&["--speed", "abc"]);
    assert!(stderr.contains("is not a speed"), "{stderr}");
    // A negative speed too: the simulator takes it as a value and says what a speed is.
    let stderr = run(&["--speed", "-5"]);
    assert!(stderr.contains("\"-5\" is not a speed"), "{stderr}");
    assert!(
        !stderr.contains("limit switches"),
        "an earlier run's error: {stderr}"
    );
}

#[test]
fn the_first_command_shows_the_room_and_q_stops_every_process() {
    let sandbox = Sandbox::new("launchtui");
    let logs = sandbox.root.join("logs");
    let term = Tmux::start(
        &sandbox,
        "sonar-pipeline",
        &[
            "--speed",
            "20",
            "--view",
            "map",
            "--log-dir",
            logs.to_str().unwrap(),
        ],
        140,
        50,
    );
    term.wait_for("the pipeline in the viewer", |s| {
        s.contains("driver   alive") && s.contains("fusion   alive") && s.contains('▄')
    });
    term.send_keys(&["q"]);
    let after = term.wait_for("the pipeline's exit", |s| s.contains("EXIT="));
    assert!(after.contains("EXIT=0"), "{after}");
    assert!(after.contains("sonar-pipeline: stopped"), "{after}");
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}

#[test]
fn a_kill_9_of_the_launcher_stops_every_process_and_leaves_nothing() {
    let sandbox = Sandbox::new("launchkill");
    let node = sandbox.node("test-consumer");
    let grid = ipc::grid_service(&node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    let logs = sandbox.root.join("logs");
    let launcher = sandbox.spawn(
        "sonar-pipeline",
        &[
            "--no-viewer",
            "--speed",
            "100",
            "--log-dir",
            logs.to_str().unwrap(),
        ],
    );
    let pid = launcher.child.id();
    collect_until(
        &node,
        || grid.receive().unwrap().map(|s| *s.user_header()),
        |got| !got.is_empty(),
    );
    let children: Vec<u32> = ["sonar-sim", "sonar-driver", "sonar-fusion"]
        .iter()
        .map(|name| child_named(pid, name, None))
        .collect();

    // SIGKILL: the launcher cannot stop anything itself; the kernel tells the processes.
    kill(Pid::from_raw(pid as i32), Signal::SIGKILL).unwrap();
    let (status, _) = launcher.wait_exit();
    assert_eq!(status.signal(), Some(Signal::SIGKILL as i32));
    let deadline = Instant::now() + PATIENCE;
    while let Some(alive) = children.iter().find(|&&c| is_running(c)) {
        assert!(
            Instant::now() < deadline,
            "process {alive} outlived the launcher"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    // They stopped cleanly (SIGTERM), so they took their shared memory with them.
    drop((grid, node));
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
    let left = sandbox.stale_root_files();
    assert!(left.is_empty(), "stale iceoryx2 files: {left:?}");
}

#[test]
fn a_killed_viewer_is_restarted_in_a_restored_terminal_and_the_pipeline_goes_on() {
    let sandbox = Sandbox::new("viewkill");
    let logs = sandbox.root.join("logs");
    let logs = logs.to_str().unwrap();
    let term = Tmux::start(
        &sandbox,
        "sonar-pipeline",
        &["--speed", "20", "--view", "map", "--log-dir", logs],
        140,
        50,
    );
    let up = |s: &str| s.contains("driver   alive") && s.contains("fusion   alive");
    term.wait_for("the pipeline in the viewer", up);
    let launcher = *pids_of("sonar-pipeline", logs)
        .first()
        .expect("the launcher runs");
    let viewer = child_named(launcher, "sonar-viewer", None);
    let others: Vec<u32> = ["sonar-sim", "sonar-driver", "sonar-fusion"]
        .iter()
        .map(|name| child_named(launcher, name, None))
        .collect();

    kill(Pid::from_raw(viewer as i32), Signal::SIGKILL).unwrap();
    child_named(launcher, "sonar-viewer", Some(viewer));
    // The dead viewer's screen went with the alternate screen the launcher left: this is the new
    // viewer's.
    term.wait_for("the new viewer", up);
    for (name, pid) in ["sonar-sim", "sonar-driver", "sonar-fusion"]
        .iter()
        .zip(&others)
    {
        assert_eq!(
            child_named(launcher, name, None),
            *pid,
            "{name} was restarted"
        );
    }

    term.send_keys(&["q"]);
    let after = term.wait_for("the pipeline's exit", |s| s.contains("EXIT="));
    assert!(after.contains("sonar-pipeline: stopped"), "{after}");
    // Had the launcher not switched raw mode off before the new viewer started, that viewer would
    // have taken raw mode for the terminal's normal state and left it so: lines would not return to
    // the first column.
    assert!(after.lines().any(|l| l.starts_with("EXIT=0")), "{after}");
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}
