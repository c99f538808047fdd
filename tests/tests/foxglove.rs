//! End to end: the well-known channels of a recording (Foxglove's protobuf schemas and ROS 2's
//! CDR messages), decoded by independent readers (Python `mcap`, `mcap-protobuf-support`,
//! `mcap-ros2-support`, installed by `.ci/run`) and compared with the map and the readings; and
//! `sonar-replay` reading such a file as before.
#![allow(clippy::unwrap_used, clippy::expect_used)] // a panic is a failure

use sonar_e2e::{
    Sandbox, check_ok, collect_until, grid_subscriber, path_str, python, readings_subscriber,
    readings_subscribers, wait_until, workspace,
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
    let (sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "100", "--seed", "3"]);
    let driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);
    // Three sweeps and a part (50 readings a sweep).
    let got = collect_until(
        &node,
        || readings.receive().unwrap().map(|s| s.payload().seq),
        |got| got.len() >= 160,
    );
    let mut count = got.len();
    assert!(driver.terminate().success(), "driver did not exit cleanly");
    while readings.receive().unwrap().is_some() {
        count += 1;
    }
    collect_until(
        &node,
        || {
            grid.receive()
                .unwrap()
                .map(|s| s.user_header().readings_fused)
        },
        |got| got.last() == Some(&(count as u64)),
    );
    assert!(
        recorder.terminate().success(),
        "sonar-record did not exit cleanly"
    );
    let stem = sandbox.root.join("final");
    check_ok(
        "sonar-export",
        &sandbox.run(
            "sonar-export",
            &["--format", "npy,pgm", "--out", path_str(&stem)],
        ),
    );

    let out = std::process::Command::new(python())
        .arg(workspace().join("tests/python/check_wellknown_mcap.py"))
        .args([path_str(&file), path_str(&stem), "--ros2"])
        .output()
        .unwrap();
    let summary = check_ok("check_wellknown_mcap.py", &out);
    // grid 400x400 … scans N readings M …
    let field = |name: &str| -> u64 {
        let words: Vec<&str> = summary.split_whitespace().collect();
        let i = words.iter().position(|w| *w == name).unwrap();
        words[i + 1].parse().unwrap()
    };
    assert_eq!(field("readings"), count as u64, "{summary}");
    assert!(field("scans") >= 4, "three sweeps and a part: {summary}");
    assert!(field("known") > 1000, "the room is mapped: {summary}");
    assert!(field("wall_lines") >= 1, "the room's walls: {summary}");

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
    assert!(skipped >= field("scans") * 2, "{info}\n{summary}");

    assert!(fusion.terminate().success());
    assert!(sim.terminate().success());
}
