//! End to end over a network: a robot and a laptop in two network namespaces joined by a veth
//! pair, each with its own iceoryx2 namespace. The robot runs the simulator, driver, fusion and
//! `sonar-bridge`; the laptop runs `sonar-bridge --mode remote` and the unchanged `sonar-viewer` in
//! tmux, and the test reads both sides' shared memory (network namespaces do not separate
//! /dev/shm). The grid must arrive byte for byte, the viewer must draw the room, a key pressed in
//! it must start a local scan on the robot's driver, and the map must resume after the link was
//! cut for 10 s.
//!
//! Needs root and iproute2 (`ip`); CI has both. Without them the test says SKIPPED and passes.
#![allow(clippy::unwrap_used, clippy::expect_used)] // helpers outside #[test] fns; a panic is a failure

use std::collections::BTreeMap;
use std::process::Command;
use std::time::{Duration, Instant};

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use sonar_common::ipc::{self, GridHeader, ScanMode};
use sonar_e2e::{
    PATIENCE, Proc, Sandbox, Tmux, driver_status_subscriber, grid_subscriber, map_wall_rows,
    path_str, wait_for_status,
};

const LINK_CUT: Duration = Duration::from_secs(10);

/// The robot at the end of link `i`; the laptop is `10.77.<i>.2` on that link.
fn robot_addr(i: usize) -> String {
    format!("10.77.{i}.1")
}

/// A laptop's network namespace and robots' namespaces, each robot joined to the laptop by a veth
/// pair of its own; deleted when dropped, also when the test fails half-way (deleting a namespace
/// deletes its end of a pair, and with it the other).
struct Netns {
    laptop: String,
    /// Each robot's namespace and its end of the link.
    robots: Vec<(String, String)>,
}

fn ip(args: &[&str]) {
    let status = Command::new("ip").args(args).status().unwrap();
    assert!(status.success(), "ip {} failed: {status}", args.join(" "));
}

impl Netns {
    /// `tag` (one letter) keeps the namespaces of two tests of this process apart.
    fn new(tag: &str, robots: usize) -> Self {
        let id = std::process::id();
        let mut net = Self {
            laptop: format!("sonar-laptop{tag}-{id}"),
            robots: Vec::new(),
        };
        ip(&["netns", "add", &net.laptop]);
        ip(&["-n", &net.laptop, "link", "set", "lo", "up"]);
        for i in 0..robots {
            let robot = format!("sonar-robot{tag}{i}-{id}");
            // Interface names have at most 15 bytes.
            let robot_if = format!("sr{tag}{i}{}", id % 1_000_000);
            let laptop_if = format!("sl{tag}{i}{}", id % 1_000_000);
            ip(&["netns", "add", &robot]);
            net.robots.push((robot.clone(), robot_if.clone()));
            ip(&[
                "link",
                "add",
                &robot_if,
                "netns",
                &robot,
                "type",
                "veth",
                "peer",
                "name",
                &laptop_if,
                "netns",
                &net.laptop,
            ]);
            let laptop_addr = format!("10.77.{i}.2");
            for (ns, dev, addr) in [
                (&robot, &robot_if, robot_addr(i)),
                (&net.laptop, &laptop_if, laptop_addr),
            ] {
                let cidr = format!("{addr}/24");
                ip(&["-n", ns, "addr", "add", &cidr, "dev", dev]);
                ip(&["-n", ns, "link", "set", dev, "up"]);
                ip(&["-n", ns, "link", "set", "lo", "up"]);
            }
        }
        net
    }

    fn robot(&self, i: usize) -> &str {
        &self.robots[i].0
    }

    /// Bytes the robot's end of the link sent and received so far.
    fn robot_link_bytes(&self) -> u64 {
        let out = Command::new("ip")
            .args([
                "-n",
                self.robot(0),
                "-s",
                "link",
                "show",
                "dev",
                &self.robots[0].1,
            ])
            .output()
            .unwrap();
        // `ip -s link`: a header line, then a line of numbers after "RX:" and after "TX:".
        let text = String::from_utf8(out.stdout).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        let bytes_after = |label: &str| -> u64 {
            let i = lines
                .iter()
                .position(|l| l.trim_start().starts_with(label))
                .unwrap();
            lines[i + 1]
                .split_whitespace()
                .next()
                .unwrap()
                .parse()
                .unwrap()
        };
        bytes_after("RX:") + bytes_after("TX:")
    }

    fn set_robot_link(&self, up: bool) {
        let state = if up { "up" } else { "down" };
        let (robot, dev) = &self.robots[0];
        ip(&["-n", robot, "link", "set", dev, state]);
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        let robots = self.robots.iter().map(|(ns, _)| ns);
        for ns in robots.chain([&self.laptop]) {
            let _ = Command::new("ip").args(["netns", "del", ns]).status();
        }
    }
}

/// Why the test cannot run here, if it cannot.
fn missing_privileges() -> Option<&'static str> {
    let uid = Command::new("id").arg("-u").output();
    if !uid.is_ok_and(|out| out.stdout.trim_ascii() == b"0") {
        return Some("needs root to make network namespaces");
    }
    if Command::new("ip").arg("-V").output().is_err() {
        return Some("needs iproute2 (`ip`)");
    }
    None
}

type GridSubscriber = Subscriber<Ipc, [u8], GridHeader>;

/// Every grid snapshot a subscriber holds: header and cells.
fn receive_grids(sub: &GridSubscriber, into: &mut BTreeMap<u64, (GridHeader, Vec<u8>)>) {
    while let Some(sample) = sub.receive().unwrap() {
        let header = *sample.user_header();
        into.insert(header.seq, (header, sample.payload().to_vec()));
    }
    // Keep the memory bounded: the latest snapshots are the ones compared.
    while into.len() > 64 {
        into.pop_first();
    }
}

/// Watches both sides until the laptop shows a snapshot newer than `after_seq` that is the
/// robot's snapshot of the same number byte for byte; returns its number.
fn wait_for_identical_grid(
    node: &Node<Ipc>,
    robot: &GridSubscriber,
    laptop: &GridSubscriber,
    robot_grids: &mut BTreeMap<u64, (GridHeader, Vec<u8>)>,
    after_seq: u64,
) -> u64 {
    let deadline = Instant::now() + PATIENCE;
    let mut laptop_grids = BTreeMap::new();
    loop {
        receive_grids(robot, robot_grids);
        receive_grids(laptop, &mut laptop_grids);
        for (seq, remote) in laptop_grids.range(after_seq + 1..) {
            if let Some(local) = robot_grids.get(seq) {
                assert_eq!(local.0, remote.0, "header of snapshot {seq}");
                assert!(local.1 == remote.1, "cells of snapshot {seq} differ");
                assert!(remote.1.len() == (remote.0.width * remote.0.height) as usize);
                return *seq;
            }
        }
        assert!(
            Instant::now() < deadline,
            "no laptop snapshot after {after_seq} matched the robot's (laptop has {:?})",
            laptop_grids.keys().collect::<Vec<_>>()
        );
        let _ = node.wait(Duration::from_millis(2));
    }
}

fn still_running(procs: &mut [&mut Proc]) {
    for p in procs {
        assert!(
            p.child.try_wait().unwrap().is_none(),
            "{} exited during the test",
            p.name
        );
    }
}

#[test]
fn a_laptop_watches_and_commands_the_robot_over_zenoh_through_a_cut_link() {
    if let Some(why) = missing_privileges() {
        eprintln!("SKIPPED the bridge test: {why}");
        return;
    }
    let net = Netns::new("t", 1);
    let robot = Sandbox::in_netns("bridge_robot", net.robot(0));
    let laptop = Sandbox::in_netns("bridge_laptop", &net.laptop);
    let robot_node = robot.node("test-robot-side");
    let laptop_node = laptop.node("test-laptop-side");
    let robot_grid = grid_subscriber(&robot_node);
    let laptop_grid = grid_subscriber(&laptop_node);
    let robot_status = driver_status_subscriber(&robot_node);
    let laptop_status = driver_status_subscriber(&laptop_node);

    let fusion = robot.spawn("sonar-fusion", &["--no-persist"]);
    let (sim, pty) = robot.spawn_sim(&["--scene", "room", "--speed", "20", "--seed", "3"]);
    let mut driver = robot.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);
    let listen = format!("tcp/{}:7447", robot_addr(0));
    let mut robot_bridge = robot.spawn("sonar-bridge", &["--robot", "r1", "--listen", &listen]);
    let mut laptop_bridge = laptop.spawn(
        "sonar-bridge",
        &["--mode", "remote", "--robot", "r1", "--connect", &listen],
    );

    // The map arrives on the laptop as the robot published it.
    let mut robot_grids = BTreeMap::new();
    let first =
        wait_for_identical_grid(&robot_node, &robot_grid, &laptop_grid, &mut robot_grids, 0);

    // The unchanged viewer on the laptop, in a terminal in the laptop's namespace, draws the room.
    let viewer_log = laptop.root.join("viewer.log");
    let term = Tmux::start(
        &laptop,
        "sonar-viewer",
        &["--view", "map", "--log-file", path_str(&viewer_log)],
        140,
        50,
    );
    term.wait_for("the room's walls on the laptop's viewer", |s| {
        let rows = map_wall_rows(s, 8);
        rows.len() >= 2 && rows[rows.len() - 1] - rows[0] >= 8
    });

    // `l` then Enter on the laptop's viewer: a local scan starts on the robot, and the laptop's
    // viewer shows it. Keys are pressed again while the robot has not switched (a command sent
    // before the bridges have matched their ends of the command channel would go nowhere).
    let deadline = Instant::now() + PATIENCE;
    let mut robot_local = None;
    while robot_local.is_none() {
        assert!(Instant::now() < deadline, "the robot never scanned locally");
        term.send_keys(&["l"]);
        term.send_keys(&["Enter"]);
        let until = Instant::now() + Duration::from_secs(2);
        while Instant::now() < until && robot_local.is_none() {
            while let Some(s) = robot_status.receive().unwrap() {
                if ScanMode::from_u8(s.payload().mode as u8) == ScanMode::Local {
                    robot_local = Some(*s.payload());
                }
            }
            let _ = robot_node.wait(Duration::from_millis(20));
        }
    }
    wait_for_status(&laptop_node, &laptop_status, |s| {
        ScanMode::from_u8(s.mode as u8) == ScanMode::Local
    });
    term.wait_for("the local scan on the laptop's viewer", |s| {
        s.contains("scan     local")
    });

    // The link goes down for 10 s and comes back: both bridges live on and the map resumes.
    let before_cut = wait_for_identical_grid(
        &robot_node,
        &robot_grid,
        &laptop_grid,
        &mut robot_grids,
        first,
    );
    net.set_robot_link(false);
    let cut_until = Instant::now() + LINK_CUT;
    while Instant::now() < cut_until {
        receive_grids(&robot_grid, &mut robot_grids);
        let _ = robot_node.wait(Duration::from_millis(20));
    }
    still_running(&mut [&mut robot_bridge, &mut laptop_bridge]);
    let robot_seq_at_restore = *robot_grids.keys().last().unwrap();
    assert!(
        robot_seq_at_restore > before_cut,
        "the robot's map did not go on while the link was down"
    );
    net.set_robot_link(true);
    let resumed = wait_for_identical_grid(
        &robot_node,
        &robot_grid,
        &laptop_grid,
        &mut robot_grids,
        robot_seq_at_restore,
    );
    assert!(resumed > robot_seq_at_restore);
    still_running(&mut [&mut robot_bridge, &mut laptop_bridge, &mut driver]);

    // The laptop's viewer lived through the cut and quits cleanly on `q`.
    term.send_keys(&["q"]);
    let after = term.wait_for("the viewer's exit", |s| s.contains("EXIT="));
    assert!(after.contains("EXIT=0"), "the viewer's exit:\n{after}");

    // Both bridges stop cleanly on SIGTERM and leave nothing in shared memory.
    for bridge in [laptop_bridge, robot_bridge] {
        let name = bridge.name.clone();
        let status = bridge.terminate();
        assert!(status.success(), "{name} exited with {status}");
    }
    for p in [driver, fusion, sim] {
        p.terminate();
    }
    drop((robot_grid, laptop_grid, robot_status, laptop_status));
    drop((robot_node, laptop_node));
    for side in [&robot, &laptop] {
        assert!(
            side.stale_shm_files().is_empty(),
            "stale shared memory: {:?}",
            side.stale_shm_files()
        );
    }
}

/// Two robots on two links to one laptop: the laptop lists both by name, and a remote bridge for
/// one of them brings that robot's services only.
#[test]
fn two_robots_are_told_apart() {
    if let Some(why) = missing_privileges() {
        eprintln!("SKIPPED the two-robot bridge test: {why}");
        return;
    }
    let net = Netns::new("m", 2);
    let mut robots = Vec::new();
    let mut connect = Vec::new();
    for (i, name) in ["alpha", "beta"].into_iter().enumerate() {
        let side = Sandbox::in_netns(&format!("bridge_{name}"), net.robot(i));
        let head = format!("HEAD-{name}");
        let (sim, pty) = side.spawn_sim(&["--scene", "room", "--speed", "5", "--head-id", &head]);
        let driver = side.spawn("sonar-driver", &["--port", &pty, "--scan", "none"]);
        let listen = format!("tcp/{}:7447", robot_addr(i));
        let bridge = side.spawn(
            "sonar-bridge",
            &[
                "--robot",
                name,
                "--listen",
                &listen,
                "--services",
                "driver_status",
            ],
        );
        connect.push(listen);
        robots.push((side, [bridge, driver, sim]));
    }
    let connect = connect.join(",");
    let laptop = Sandbox::in_netns("bridge_two_laptop", &net.laptop);
    let deadline = Instant::now() + PATIENCE;
    loop {
        let out = laptop.run(
            "sonar-bridge",
            &["--mode", "remote", "--connect", &connect, "--list-robots"],
        );
        assert!(out.status.success(), "--list-robots failed: {out:?}");
        if String::from_utf8_lossy(&out.stdout) == "alpha\nbeta\n" {
            break;
        }
        assert!(Instant::now() < deadline, "robots listed: {out:?}");
    }

    let laptop_node = laptop.node("test-laptop-side");
    let status = driver_status_subscriber(&laptop_node);
    let bridge = laptop.spawn(
        "sonar-bridge",
        &["--mode", "remote", "--robot", "beta", "--connect", &connect],
    );
    let mut heads = Vec::new();
    sonar_e2e::collect_until(
        &laptop_node,
        || {
            status
                .receive()
                .unwrap()
                .map(|s| s.payload().head_id().to_owned())
        },
        |got| {
            heads = got.to_vec();
            got.len() >= 3
        },
    );
    assert!(
        heads.iter().all(|h| h == "HEAD-beta"),
        "the laptop's driver status came from {heads:?}"
    );
    drop(status);
    assert!(bridge.terminate().success());
    for (_, procs) in robots {
        for p in procs {
            p.terminate();
        }
    }
}

/// CPU time (user + system) a process has used so far.
fn cpu_time(pid: u32) -> Duration {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
    // Fields after the command name (which ends with ')'): utime and stime are the 12th and 13th.
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .unwrap()
        .1
        .split_whitespace()
        .collect();
    let ticks: u64 = fields[11].parse::<u64>().unwrap() + fields[12].parse::<u64>().unwrap();
    Duration::from_secs_f64(ticks as f64 / 100.0) // USER_HZ is 100 on Linux
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// The figures of `docs/benchmarks.md` ("Bridge"): bytes on the link, grid latency robot → laptop
/// subscriber, CPU of both bridges, per condition. Not a check: run by hand with
/// `cargo test -p sonar-e2e --test bridge -- --ignored --nocapture`.
#[test]
#[ignore]
fn bridge_link_figures() {
    if let Some(why) = missing_privileges() {
        eprintln!("SKIPPED the bridge benchmark: {why}");
        return;
    }
    const WINDOW: Duration = Duration::from_secs(30);
    // (label, simulator speed, driver's scan, --grid-max-rate)
    let conditions = [
        ("idle (no readings)", "1", "none", "2"),
        ("sensor rate (speed 1)", "1", "full", "2"),
        ("replay speed 20", "20", "full", "2"),
        ("replay speed 20, grid not rate-limited", "20", "full", "0"),
    ];
    println!(
        "| condition | link bytes/s | grids | grid latency p50 / p99 ms | robot bridge CPU % | laptop bridge CPU % |"
    );
    println!("|---|---|---|---|---|---|");
    for (label, speed, scan, rate) in conditions {
        let net = Netns::new("b", 1);
        let robot = Sandbox::in_netns("bridge_bench_robot", net.robot(0));
        let laptop = Sandbox::in_netns("bridge_bench_laptop", &net.laptop);
        let laptop_node = laptop.node("bench-laptop-side");
        let laptop_grid = grid_subscriber(&laptop_node);
        let fusion = robot.spawn("sonar-fusion", &["--no-persist"]);
        let (sim, pty) = robot.spawn_sim(&["--scene", "room", "--speed", speed, "--seed", "3"]);
        let driver = robot.spawn("sonar-driver", &["--port", &pty, "--scan", scan]);
        let listen = format!("tcp/{}:7447", robot_addr(0));
        let robot_bridge = robot.spawn(
            "sonar-bridge",
            &[
                "--robot",
                "r1",
                "--listen",
                &listen,
                "--grid-max-rate",
                rate,
            ],
        );
        let laptop_bridge = laptop.spawn(
            "sonar-bridge",
            &["--mode", "remote", "--robot", "r1", "--connect", &listen],
        );
        // Settle: connections made, the first snapshots through.
        std::thread::sleep(Duration::from_secs(5));
        while laptop_grid.receive().unwrap().is_some() {}
        let bytes0 = net.robot_link_bytes();
        let cpu0 = (
            cpu_time(robot_bridge.child.id()),
            cpu_time(laptop_bridge.child.id()),
        );
        let start = Instant::now();
        let mut latencies_ms = Vec::new();
        while start.elapsed() < WINDOW {
            while let Some(sample) = laptop_grid.receive().unwrap() {
                let now = ipc::unix_time_ns();
                latencies_ms.push(now.saturating_sub(sample.user_header().stamp_ns) as f64 / 1e6);
            }
            let _ = laptop_node.wait(Duration::from_millis(1));
        }
        let secs = start.elapsed().as_secs_f64();
        let bytes = net.robot_link_bytes() - bytes0;
        let cpu_pct =
            |pid: u32, before: Duration| (cpu_time(pid) - before).as_secs_f64() / secs * 100.0;
        let robot_cpu = cpu_pct(robot_bridge.child.id(), cpu0.0);
        let laptop_cpu = cpu_pct(laptop_bridge.child.id(), cpu0.1);
        latencies_ms.sort_by(f64::total_cmp);
        let latency = if latencies_ms.is_empty() {
            "–".to_owned()
        } else {
            format!(
                "{:.1} / {:.1}",
                percentile(&latencies_ms, 0.5),
                percentile(&latencies_ms, 0.99)
            )
        };
        println!(
            "| {label} | {:.0} | {} | {latency} | {robot_cpu:.1} | {laptop_cpu:.1} |",
            bytes as f64 / secs,
            latencies_ms.len()
        );
        drop(laptop_grid);
        for p in [laptop_bridge, robot_bridge, driver, fusion, sim] {
            p.terminate();
        }
    }
}
