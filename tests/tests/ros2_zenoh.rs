//! End to end: `sonar-bridge --mode ros2` publishes `/map`, `/scan` and `/tf` under `rmw_zenoh`'s
//! keys, and a Python zenoh peer (`eclipse-zenoh`, installed by `.ci/run`) written from
//! `rmw_zenoh`'s design, not from our code, receives them, decodes them with `rosbags`' Jazzy
//! typestore and finds the final map cell for cell, the attachments and the graph's tokens
//! (`tests/python/check_ros2_zenoh.py`). All inside a network namespace of the test's own.
#![allow(clippy::unwrap_used, clippy::expect_used)] // a panic is a failure

use std::io::Read;
use std::process::{Command, Stdio};

use sonar_e2e::{
    Netns, Proc, Sandbox, check_ok, grid_subscriber, path_str, python, readings_subscriber,
    readings_subscribers, scan_room_until_fused, wait_until, workspace,
};

/// The room through simulator, driver and fusion with the bridge in ros2 mode beside them
/// (connecting, by default, to 127.0.0.1:7447, where rmw_zenoh's router would listen, and where
/// the peer listens from the start). The driver stops, the final map is exported, and the peer
/// must then receive that map (kept back by the rate limit, then repeated each second), and have
/// received scans and transforms, each as rmw_zenoh would deliver it.
#[test]
fn a_zenoh_peer_following_rmw_zenoh_s_design_receives_and_decodes_map_scan_and_tf() {
    let netns = Netns::new("ros2z");
    let sandbox = Sandbox::in_netns("ros2z", netns.name());
    let node = sandbox.node("test-counter");
    let grid = grid_subscriber(&node);
    let readings = readings_subscriber(&node);
    let stem = sandbox.root.join("final");
    let ready = sandbox.root.join("final.ready");
    let connected = sandbox.root.join("peer.connected");
    let mut peer = Command::new(python());
    peer.arg(workspace().join("tests/python/check_ros2_zenoh.py"))
        .args(["tcp/127.0.0.1:7447", path_str(&stem), path_str(&ready)])
        .args(["--connected", path_str(&connected), "--timeout", "120"]);
    // A Proc: stopped if the test fails before it ends by itself.
    let mut peer = Proc {
        name: "check_ros2_zenoh.py".into(),
        child: netns
            .wrap(&peer)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    };
    let mut peer_stdout = peer.child.stdout.take().unwrap();
    let fusion = sandbox.spawn("sonar-fusion", &["--no-persist"]);
    let bridge = sandbox.spawn("sonar-bridge", &["--mode", "ros2"]);
    wait_until(&node, "fusion's and the bridge's subscriptions", || {
        readings_subscribers(&node) >= 3
    });
    // Scans and transforms are volatile: the readings start once the bridge's session has found
    // the peer, which starts Python and retries its connection in its own time.
    wait_until(&node, "the peer to hear the bridge's node", || {
        connected.exists()
    });
    // Three sweeps and a part (50 readings a sweep).
    let (sim, _) = scan_room_until_fused(&sandbox, &node, &readings, &grid, 160);
    check_ok(
        "sonar-export",
        &sandbox.run(
            "sonar-export",
            &["--format", "npy,pgm", "--out", path_str(&stem)],
        ),
    );
    std::fs::write(&ready, "").unwrap();

    let (status, stderr) = peer.wait_exit();
    let mut summary = String::new();
    peer_stdout.read_to_string(&mut summary).unwrap();
    assert!(status.success(), "check_ros2_zenoh.py: {summary}\n{stderr}");
    // map 400x400 known N maps M scans S tfs T tokens K scan_ranges R
    let words: Vec<&str> = summary.split_whitespace().collect();
    assert_eq!(words[0], "map", "{summary}");
    assert!(words[3].parse::<u64>().unwrap() > 0, "{summary}");
    assert!(words[5].parse::<u64>().unwrap() >= 3, "{summary}");
    // The node and one publisher a topic at least.
    assert!(words[11].parse::<u64>().unwrap() >= 4, "{summary}");

    let (status, stderr) = bridge.terminate_with_stderr();
    assert!(status.success(), "{stderr}");
    assert!(stderr.contains("signal received: stopping"), "{stderr}");
    assert!(fusion.terminate().success());
    assert!(sim.terminate().success());
    drop((grid, readings, node));
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}
