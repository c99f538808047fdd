//! End to end: `sonar-pipeline` starts, supervises and stops the whole pipeline.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use sonar_common::ipc::{self, GridHeader};
use sonar_e2e::{PATIENCE, Sandbox, Tmux, children_of, collect_until, is_running};

/// Waits until the launcher `pid` has a child running `name`; returns its pid.
fn child_named(pid: u32, name: &str, not: Option<u32>) -> u32 {
    let deadline = Instant::now() + PATIENCE;
    loop {
        if let Some((child, _)) = children_of(pid)
            .into_iter()
            .find(|(c, comm)| comm == name && Some(*c) != not && is_running(*c))
        {
            return child;
        }
        assert!(Instant::now() < deadline, "{name} never started");
        std::thread::sleep(Duration::from_millis(50));
    }
}

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
