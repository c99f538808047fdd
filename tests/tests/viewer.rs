//! End to end in a real terminal: simulator, driver, fusion and the viewer in tmux; the test
//! presses keys as a user would and reads the screen.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::time::{Duration, Instant};

use sonar_common::ipc::{self, Reading, ScanMode};
use sonar_e2e::{
    PATIENCE, Sandbox, Tmux, collect_until, driver_ports, map_wall_rows, path_str, pids_of,
    readings_subscribers, wait_until,
};

/// The sensor on the map: an arrow along its heading, `@` without one (see the viewer's README).
const SENSOR_GLYPHS: [char; 9] = ['→', '↗', '↑', '↖', '←', '↙', '↓', '↘', '@'];

#[test]
fn the_viewer_shows_the_room_scans_on_keys_and_quits_cleanly() {
    let sandbox = Sandbox::new("viewer");
    let node = sandbox.node("test-observer");
    let readings = ipc::readings_service(&node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    let (_sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "20"]);
    let _driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--scan", "none"]);
    let _fusion = sandbox.spawn("sonar-fusion", &[]);
    let log = sandbox.root.join("viewer.log");
    let log = log.to_str().unwrap();
    let term = Tmux::start(
        &sandbox,
        "sonar-viewer",
        &["--view", "map", "--log-file", log],
        140,
        50,
    );

    term.wait_for("driver and fusion alive", |s| {
        s.contains("driver   alive") && s.contains("fusion   alive")
    });
    assert!(
        map_wall_rows(&term.capture(), 8).is_empty(),
        "no scan, no walls"
    );

    // `f`: the driver starts full sweeps and the room's north and south walls (facing the sweep)
    // appear above and below the sensor.
    term.send_keys(&["f"]);
    // The sensor is an arrow (a fixed head's points along its 0°, →), under the cursor `+` until
    // the cursor moves; the status panel (right of `││`) has `+` signs of its own.
    let sensor_row = |screen: &str| {
        screen
            .lines()
            .map(|l| l.split("││").next().unwrap_or(l))
            .position(|map| map.contains(SENSOR_GLYPHS) || map.contains('+'))
    };
    // Waited for, not taken from the first screen with two walls: early in the sweep the walls
    // drawn so far may all lie on one side.
    let screen = term.wait_for("the room's walls above and below the sensor", |s| {
        let rows = map_wall_rows(s, 8);
        sensor_row(s).is_some_and(|sensor| {
            rows.first().is_some_and(|&top| top < sensor)
                && rows.last().is_some_and(|&bottom| sensor < bottom)
        })
    });
    assert!(screen.contains("scan     full"), "{screen}");

    // `l` then Enter: a local scan of the selected segment, which the driver carries out.
    term.send_keys(&["l"]);
    term.send_keys(&["Enter"]);
    term.wait_for("local scan in the status panel", |s| {
        s.contains("scan     local")
    });
    collect_until(
        &node,
        || readings.receive().unwrap().map(|s| *s.payload()),
        |got| got.last().is_some_and(|r| r.scan_mode() == ScanMode::Local),
    );

    // `q` quits with status 0 and gives the terminal back: the map is gone from the screen.
    term.send_keys(&["q"]);
    let after = term.wait_for("the viewer's exit", |s| s.contains("EXIT="));
    assert!(after.contains("EXIT=0"), "{after}");
    assert!(
        !after.contains('▄') && !after.contains("driver   alive"),
        "{after}"
    );
}

#[test]
fn the_viewer_exits_when_its_terminal_hangs_up() {
    let sandbox = Sandbox::new("viewerhup");
    let log = sandbox.root.join("viewer.log");
    let log = log.to_str().unwrap();
    let term = Tmux::start(&sandbox, "sonar-viewer", &["--log-file", log], 100, 30);
    term.wait_for("the viewer", |s| s.contains("waiting for"));
    assert_eq!(pids_of("sonar-viewer", log).len(), 1, "one viewer runs");

    term.hang_up();
    let deadline = Instant::now() + PATIENCE;
    while !pids_of("sonar-viewer", log).is_empty() {
        assert!(
            Instant::now() < deadline,
            "the viewer outlived its terminal"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let text = std::fs::read_to_string(log).unwrap();
    assert!(text.contains("the terminal went away"), "{text}");
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}

/// An idle viewer sleeps until something happens; a resize is something: it draws again at the
/// new size at once, before any key or snapshot.
#[test]
fn an_idle_viewer_redraws_when_its_terminal_is_resized() {
    let sandbox = Sandbox::new("viewerresize");
    let log = sandbox.root.join("viewer.log");
    let term = Tmux::start(
        &sandbox,
        "sonar-viewer",
        &["--log-file", log.to_str().unwrap()],
        100,
        30,
    );
    let widest = |s: &str| s.lines().map(|l| l.chars().count()).max().unwrap_or(0);
    let before = term.wait_for("the viewer", |s| s.contains("waiting for"));
    assert!(widest(&before) <= 100, "{before}");
    term.resize(140, 40);
    term.wait_for("the panels drawn 140 wide", |s| {
        s.lines()
            .any(|l| l.chars().count() >= 140 && l.trim_end().ends_with('┐'))
    });
}

/// Issue 28: while nothing runs the panel says where the viewer looks; readings from sonar-replay
/// that end are a finished replay, not a driver gone.
#[test]
fn the_viewer_names_its_namespace_and_says_when_a_replay_finished() {
    let sandbox = Sandbox::new("viewerreplay");
    let log = sandbox.root.join("viewer.log");
    let log = log.to_str().unwrap();
    let term = Tmux::start(&sandbox, "sonar-viewer", &["--log-file", log], 140, 50);
    let waiting = term.wait_for("the viewer waiting", |s| s.contains("waiting for driver"));
    assert!(waiting.contains("looking"), "{waiting}");
    assert!(
        waiting.contains(&format!("\"{}\"", sandbox.prefix)),
        "the prefix {} in\n{waiting}",
        sandbox.prefix
    );

    // A recording of 20 readings, the test standing in for the driver.
    let node = sandbox.node("test-driver");
    let file = sandbox.root.join("run.mcap");
    let recorder = sandbox.spawn("sonar-record", &[path_str(&file), "--no-foxglove"]);
    wait_until(
        &node,
        "the viewer's and the recorder's subscriptions",
        || readings_subscribers(&node) >= 2,
    );
    let (readings, wake) = driver_ports(&node);
    for seq in 0..20u64 {
        let reading = Reading {
            seq,
            host_stamp_ns: 1_700_000_000_000_000_000 + seq * 25_000_000,
            layout_version: ipc::LAYOUT_VERSION,
            sweep_id: 1,
            angle_deg: -147.0 + 6.0 * seq as f32,
            beam_half_angle_deg: 30.0,
            distance_m: 1.2,
            ping_count: 4,
            pings_used: 4,
            direction: 1,
            mode: 1,
            ..Default::default()
        };
        readings.send_copy(reading).unwrap();
        wake.notify().unwrap();
    }
    assert!(recorder.terminate().success(), "sonar-record failed");
    drop((readings, wake));

    // It stays 5 s after its last reading: the viewer looks at who publishes once a second.
    let replay = sandbox.spawn(
        "sonar-replay",
        &[path_str(&file), "--speed", "max", "--linger", "5"],
    );
    term.wait_for("the replay running", |s| s.contains("replay running"));
    let (status, stderr) = replay.wait_exit();
    assert!(status.success(), "sonar-replay failed: {stderr}");
    let finished = term.wait_for("the replay finished", |s| s.contains("replay finished"));
    assert!(!finished.contains("gone for"), "{finished}");
    term.send_keys(&["q"]);
    let after = term.wait_for("the viewer's exit", |s| s.contains("EXIT="));
    assert!(after.contains("EXIT=0"), "{after}");
}
