//! End to end: the well-known channels of a recording (Foxglove's protobuf schemas) and the ROS 2
//! bag beside it (CDR messages), decoded by independent readers (Python `mcap`,
//! `mcap-protobuf-support`, and `rosbags` for the bag, installed by `.ci/run`) and compared with
//! the map and the readings; and
//! `sonar-replay` reading such a file as before. And `sonar-foxglove` serving the same channels
//! live to a WebSocket client (Python `websockets`) inside a network namespace of the test's own.
#![allow(clippy::unwrap_used, clippy::expect_used)] // a panic is a failure

use std::path::Path;
use std::process::{Command, Stdio};

use sonar_common::ipc;
use sonar_e2e::{
    Netns, Proc, Sandbox, check_ok, collect_until, grid_subscriber, path_str, python,
    readings_subscriber, readings_subscribers, scan_room_until_fused, wait_until, workspace,
};

/// The room through simulator, driver and fusion, recorded with `--ros2`; the driver stops, the
/// fusion fuses the last reading, the recorder stops: its last map is the pipeline's final map,
/// which `sonar-export` then writes for the comparison.
#[test]
fn a_recording_s_grid_scans_and_ros2_messages_decode_to_the_map_and_the_readings() {
    let sandbox = Sandbox::new("foxrec");
    let node = sandbox.node("test-counter");
    let grid = grid_subscriber(&node);
    let readings = readings_subscriber(&node);
    let file = sandbox.root.join("run.mcap");
    let fusion = sandbox.spawn("sonar-fusion", &["--no-persist"]);
    let recorder = sandbox.spawn(
        "sonar-record",
        &[path_str(&file), "--ros2", "--grid-period", "0.5"],
    );
    wait_until(&node, "fusion's and the recorder's subscriptions", || {
        readings_subscribers(&node) >= 3
    });
    // Three sweeps and a part (50 readings a sweep).
    let (sim, count) = scan_room_until_fused(&sandbox, &node, &readings, &grid, 160);
    assert!(
        recorder.terminate().success(),
        "sonar-record did not exit cleanly"
    );
    // The final map as files, and as the live snapshot's MCAP (sonar-export --mcap).
    let stem = sandbox.root.join("final");
    let args = [
        "--format",
        "npy,pgm",
        "--mcap",
        "--ros2",
        "--out",
        path_str(&stem),
    ];
    check_ok("sonar-export", &sandbox.run("sonar-export", &args));

    let check = |mcap: &Path, stem: &Path, readings_from: Option<&Path>| {
        let mut command = Command::new(python());
        command
            .arg(workspace().join("tests/python/check_wellknown_mcap.py"))
            .args([path_str(mcap), path_str(stem), "--ros2"]);
        if let Some(recording) = readings_from {
            command.args(["--readings-from", path_str(recording)]);
        }
        let summary = check_ok("check_wellknown_mcap.py", &command.output().unwrap());
        eprintln!("{}: {summary}", mcap.display());
        // grid 400x400 … scans N readings M …
        move |name: &str| -> u64 {
            let words: Vec<&str> = summary.split_whitespace().collect();
            let i = words.iter().position(|w| *w == name).unwrap();
            words[i + 1].parse().unwrap()
        }
    };
    let field = check(&file, &stem, None);
    assert_eq!(field("readings"), count as u64);
    assert!(field("scans") >= 4, "three sweeps and a part");
    assert!(field("known") > 1000, "the room is mapped");
    assert!(field("wall_lines") >= 1, "the room's walls");
    assert!(field("beams") >= 1, "beams of the readings");

    // The live snapshot's MCAP: the same map, no readings, so no scans.
    let snapshot = check(&stem.with_extension("mcap"), &stem, None);
    assert_eq!((snapshot("known"), snapshot("scans")), (field("known"), 0));

    // The recording converted afterwards: the scans of the same readings, and the final map of
    // the offline fusion (written as files by the same run).
    let offline = sandbox.root.join("offline");
    let args = [
        "--from-recording",
        path_str(&file),
        "--mcap",
        "--ros2",
        "--grid-period",
        "0.5",
        "--format",
        "npy,pgm",
        "--out",
        path_str(&offline),
    ];
    let printed = check_ok(
        "sonar-export --from-recording",
        &sandbox.run("sonar-export", &args),
    );
    assert!(printed.contains("offline.mcap"), "{printed}");
    let converted = check(&offline.with_extension("mcap"), &offline, Some(&file));
    for name in ["readings", "scans", "beams", "known", "ros2_scans"] {
        assert_eq!(converted(name), field(name), "{name}");
    }

    // The replay reads its own channels and skips these.
    let info = check_ok(
        "sonar-replay --info",
        &sandbox.run("sonar-replay", &[path_str(&file), "--info"]),
    );
    assert!(
        info.contains(&format!("sonar/readings: {count} (seq 0..={}", count - 1)),
        "{info}"
    );
    let skipped: u64 = info
        .lines()
        .find_map(|l| l.strip_prefix("other channels (skipped): "))
        .unwrap_or_else(|| panic!("no skipped channels in {info}"))
        .parse()
        .unwrap();
    assert!(skipped >= field("scans") * 2, "{info}");

    assert!(fusion.terminate().success());
    assert!(sim.terminate().success());
}

/// `sonar-pipeline` starts sonar-foxglove from its `[foxglove]` table, which serves the running
/// room to a Foxglove WebSocket client that offers only `foxglove.websocket.v1`, and to one that
/// offers only `foxglove.sdk.v1`: the five channels with their protobuf schemas, and a map that
/// decodes to the fusion's grid.
#[test]
fn sonar_foxglove_serves_the_live_map_to_a_websocket_client() {
    let sandbox = Sandbox::new("foxlive");
    let node = sandbox.node("test-grid");
    let grid = grid_subscriber(&node);
    let config = sandbox.root.join("fox.toml");
    let table = "[simulator]\nscene = \"room\"\nspeed = \"20\"\nseed = 4\n\n\
                 [foxglove]\nenabled = true\nport = 8766\ngrid_period = 0.5\n";
    std::fs::write(&config, table).unwrap();
    let logs = sandbox.root.join("logs");

    let netns = Netns::new("fox");
    let mut pipeline = sandbox.command("sonar-pipeline");
    pipeline.args(["--no-viewer", "--config", path_str(&config)]);
    pipeline.args(["--log-dir", path_str(&logs)]);
    let pipeline = Proc {
        name: "sonar-pipeline".into(),
        child: netns
            .wrap(&pipeline)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    };
    let headers = collect_until(
        &node,
        || grid.receive().unwrap().map(|s| *s.user_header()),
        |got: &[ipc::GridHeader]| got.last().is_some_and(|h| h.readings_fused >= 50),
    );
    let expected = *headers.last().unwrap();
    // Ready once it printed its address (into its log, under the launcher).
    let url = "ws://127.0.0.1:8766";
    let log = logs.join("sonar-foxglove.log");
    wait_until(&node, "sonar-foxglove's address in its log", || {
        std::fs::read_to_string(&log).is_ok_and(|l| l.contains(url))
    });

    // First exactly the ws-protocol's subprotocol (Lichtblick, older Foxglove), then the crate's.
    let mut client = Command::new(python());
    client
        .arg(workspace().join("tests/python/check_foxglove_live.py"))
        .arg(url)
        .args(["--subprotocol", "foxglove.websocket.v1"])
        .args(["--subprotocol", "foxglove.sdk.v1"]);
    let out = netns.wrap(&client).output().unwrap();
    let lines = check_ok("check_foxglove_live.py", &out);
    let subprotocols: Vec<&str> = lines
        .lines()
        .map(|l| l.split(' ').next().unwrap())
        .collect();
    assert_eq!(
        subprotocols,
        ["foxglove.websocket.v1", "foxglove.sdk.v1"],
        "{lines}"
    );
    for line in lines.lines() {
        // <subprotocol> channels 5 grid 400x400 cell 0.0200 known N frame map
        let words: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(words[2], "5", "{line}");
        assert_eq!(
            words[4],
            format!("{}x{}", expected.width, expected.height),
            "{line}"
        );
        assert_eq!(words[6], format!("{:.4}", expected.resolution_m), "{line}");
        assert!(
            words[8].parse::<u64>().unwrap() > 0,
            "observed cells: {line}"
        );
        assert_eq!(words[10], "map", "{line}");
    }

    let (status, stderr) = pipeline.terminate_with_stderr();
    assert!(status.success(), "{stderr}");
    let foxglove_log = std::fs::read_to_string(&log).unwrap();
    assert!(
        foxglove_log.contains("signal received: stopping"),
        "{foxglove_log}"
    );
    drop((grid, node));
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}
