//! End to end over a network: a robot and a laptop in two network namespaces joined by a veth
//! pair, each with its own iceoryx2 namespace. The robot runs the simulator, driver, fusion and
//! `sonar-bridge`; the laptop runs `sonar-bridge --mode remote` and the unchanged `sonar-viewer` in
//! tmux, and the test reads both sides' shared memory (network namespaces do not separate
//! /dev/shm). Over mutual TLS (certificates from `sonar-bridge certs`) the grid must arrive byte
//! for byte, a sweep's end after its last reading, the viewer must draw the room, a key pressed in it must start a local scan on the
//! robot's driver, and the map must resume after the link was cut for 10 s. Intruders on the link
//! (plain zenoh peers played by `sonar-test-peer`: no certificate, another authority's, a valid
//! but unlisted one, a listed reader) read nothing or command nothing, and bomb frames from a
//! listed commander are counted as rejected while the robot's bridge stays up and small.
//!
//! Needs root and iproute2 (`ip`); CI has both. Without them the test says SKIPPED and passes.
#![allow(clippy::unwrap_used, clippy::expect_used)] // helpers outside #[test] fns; a panic is a failure

use std::collections::BTreeMap;
use std::process::Command;
use std::time::{Duration, Instant};

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use sonar_bridge::wire::{self, Codec, Expect};
use sonar_common::ipc::{self, GridHeader, ScanCommand, ScanCommandKind, ScanMode};
use sonar_e2e::{
    PATIENCE, Proc, Sandbox, Tmux, driver_status_subscriber, grid_subscriber, map_wall_rows,
    path_str, readings_subscriber, sweep_ends_subscriber, wait_for_status,
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

/// Makes the authority and the peers' certificates in `dir` with `sonar-bridge certs`, the command
/// docs/bridge.md gives.
fn make_certs(dir: &std::path::Path, peers: &[&str]) {
    let out = Command::new(sonar_e2e::bin("sonar-bridge"))
        .args(["certs", "--dir", path_str(dir)])
        .args(peers)
        .output()
        .unwrap();
    sonar_e2e::check_ok("sonar-bridge certs", &out);
}

/// `--ca --cert --key` of peer `name` whose files are in `dir`.
fn tls_args(dir: &std::path::Path, name: &str) -> Vec<String> {
    let file = |f: String| dir.join(f).display().to_string();
    vec![
        "--ca".into(),
        file("ca.pem".into()),
        "--cert".into(),
        file(format!("{name}.pem")),
        "--key".into(),
        file(format!("{name}.key")),
    ]
}

fn str_args(args: &[String]) -> Vec<&str> {
    args.iter().map(String::as_str).collect()
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
    let laptop_readings = readings_subscriber(&laptop_node);
    let laptop_ends = sweep_ends_subscriber(&laptop_node);

    let fusion = robot.spawn("sonar-fusion", &["--no-persist"]);
    let (sim, pty) = robot.spawn_sim(&["--scene", "room", "--speed", "20", "--seed", "3"]);
    let mut driver = robot.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);
    // Mutual TLS: the robot's certificate names the address the laptop connects to.
    let certs = robot.root.join("certs");
    make_certs(&certs, &[&format!("r1={}", robot_addr(0)), "laptop"]);
    let listen = format!("tls/{}:7447", robot_addr(0));
    let mut args = vec![
        "--robot",
        "r1",
        "--listen",
        &listen,
        "--allow-command",
        "laptop",
    ];
    let robot_tls = tls_args(&certs, "r1");
    args.extend(str_args(&robot_tls));
    let mut robot_bridge = robot.spawn("sonar-bridge", &args);
    let laptop_tls = tls_args(&certs, "laptop");
    let mut args = vec!["--mode", "remote", "--robot", "r1", "--connect", &listen];
    args.extend(str_args(&laptop_tls));
    let mut laptop_bridge = laptop.spawn("sonar-bridge", &args);

    // The map arrives on the laptop as the robot published it.
    let mut robot_grids = BTreeMap::new();
    let first =
        wait_for_identical_grid(&robot_node, &robot_grid, &laptop_grid, &mut robot_grids, 0);

    // A sweep's end comes after its last reading, both carried: a fusion on the laptop would
    // close the sweep without waiting for the next one.
    let mut seen: BTreeMap<u64, u32> = BTreeMap::new();
    let deadline = Instant::now() + PATIENCE;
    'ended: loop {
        assert!(Instant::now() < deadline, "no sweep end reached the laptop");
        while let Some(r) = laptop_readings.receive().unwrap() {
            seen.insert(r.payload().seq, r.payload().sweep_id);
        }
        while let Some(end) = laptop_ends.receive().unwrap() {
            if seen.get(&end.payload().last_seq) == Some(&end.payload().sweep_id) {
                break 'ended;
            }
        }
        let _ = laptop_node.wait(Duration::from_millis(20));
    }

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
    drop((laptop_readings, laptop_ends));
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
                "--insecure",
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
            &[
                "--mode",
                "remote",
                "--connect",
                &connect,
                "--list-robots",
                "--insecure",
            ],
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
        &[
            "--mode",
            "remote",
            "--robot",
            "beta",
            "--connect",
            &connect,
            "--insecure",
        ],
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
    for (_, [bridge, driver, sim]) in robots {
        // Plain TCP beyond localhost was asked for by name, and the robot said what that means.
        let (status, stderr) = bridge.terminate_with_stderr();
        assert!(status.success(), "{stderr}");
        assert!(
            stderr.contains("INSECURE"),
            "no warning at start:\n{stderr}"
        );
        driver.terminate();
        sim.terminate();
    }
}

/// One intruder on the link: a plain zenoh peer with the credentials it has.
struct Intruder {
    who: &'static str,
    /// `--tls CA CERT KEY`, or nothing: plain TCP to the robot's TLS port.
    tls: Vec<String>,
    /// Whether the robot lists it as a reader (it must then read, or the check could not fail).
    listed_reader: bool,
}

/// A plain zenoh peer (`sonar-test-peer`) in `side`'s network namespace.
fn peer(side: &Sandbox, endpoint: &str, tls: &[String], command: &[&str]) -> std::process::Child {
    side.command("sonar-test-peer")
        .arg(endpoint)
        .args(tls)
        .args(command)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap()
}

fn output_of(child: std::process::Child) -> String {
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "sonar-test-peer failed: {out:?}");
    String::from_utf8(out.stdout).unwrap()
}

/// `name=<number>` in a log line.
fn field(line: &str, name: &str) -> u64 {
    let at = line
        .find(&format!(" {name}="))
        .unwrap_or_else(|| panic!("no {name} in {line}"));
    line[at + name.len() + 2..]
        .split(|c: char| !c.is_ascii_digit())
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

/// Peak resident memory of a process, kB.
fn peak_rss_kb(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

/// The robot's bridge over mutual TLS lists one commander (`laptop`) and one reader (`watcher`).
/// The intruders listen on plain TCP as zenoh peers do by default: a bridge that learned their
/// addresses by gossip and connected to them would hand them everything (it did, before gossip
/// was turned off).
/// On the link: a peer without a certificate, one with another authority's, one with a valid
/// but unlisted certificate, and the listed reader. Each watches `sonar/r1/**` (the robot's keys:
/// a wider expression is refused all the more) and asks for it, and puts 40 local-scan commands
/// on the robot's command key. Then the commander's
/// machine sends bomb frames (4 kB declaring a 4 GiB LZ4 slice, 2 MB frames), and the real laptop
/// commands a local scan. The unlisted peers read nothing; the reader reads; no intruder's command
/// arrives (the robot counts only the laptop's); the bombs are counted as rejected, the bridge's
/// memory stays small, and it stops cleanly.
#[test]
fn intruders_read_and_command_nothing_and_bombs_are_counted() {
    if let Some(why) = missing_privileges() {
        eprintln!("SKIPPED the intruder test: {why}");
        return;
    }
    let net = Netns::new("i", 1);
    let robot = Sandbox::in_netns("bridge_intr_robot", net.robot(0));
    let laptop = Sandbox::in_netns("bridge_intr_laptop", &net.laptop);
    let certs = robot.root.join("certs");
    let foreign = robot.root.join("foreign");
    make_certs(
        &certs,
        &[
            &format!("r1={}", robot_addr(0)),
            "laptop",
            "watcher",
            "stranger",
        ],
    );
    make_certs(&foreign, &["eve"]);

    let (sim, pty) = robot.spawn_sim(&["--scene", "room", "--speed", "5"]);
    let driver = robot.spawn("sonar-driver", &["--port", &pty, "--scan", "none"]);
    let endpoint = format!("tls/{}:7447", robot_addr(0));
    let robot_tls = tls_args(&certs, "r1");
    let mut args = vec!["--robot", "r1", "--listen", &endpoint];
    args.extend(["--allow-read", "watcher", "--allow-command", "laptop"]);
    args.extend(str_args(&robot_tls));
    let mut robot_bridge = robot.spawn("sonar-bridge", &args);
    let robot_node = robot.node("test-robot-side");
    let robot_status = driver_status_subscriber(&robot_node);

    let laptop_node = laptop.node("test-laptop-side");
    let laptop_status = driver_status_subscriber(&laptop_node);
    let laptop_tls = tls_args(&certs, "laptop");
    let mut args = vec!["--mode", "remote", "--robot", "r1", "--connect", &endpoint];
    args.extend(str_args(&laptop_tls));
    let mut laptop_bridge = laptop.spawn("sonar-bridge", &args);
    wait_for_status(&laptop_node, &laptop_status, |_| true);

    let peer_tls = |dir: &std::path::Path, name: &str| {
        let file = |f: String| dir.join(f).display().to_string();
        vec![
            "--tls".into(),
            file("ca.pem".into()),
            file(format!("{name}.pem")),
            file(format!("{name}.key")),
        ]
    };
    let intruders = [
        Intruder {
            who: "no certificate (plain TCP)",
            tls: Vec::new(),
            listed_reader: false,
        },
        Intruder {
            who: "another authority's certificate",
            tls: peer_tls(&foreign, "eve"),
            listed_reader: false,
        },
        Intruder {
            who: "a valid certificate nobody listed",
            tls: peer_tls(&certs, "stranger"),
            listed_reader: false,
        },
        Intruder {
            who: "a listed reader",
            tls: peer_tls(&certs, "watcher"),
            listed_reader: true,
        },
    ];
    // Plain TCP to the same port: the TLS listener is all there is to talk to.
    let endpoint_of = |i: &Intruder| {
        if i.tls.is_empty() {
            format!("tcp/{}:7447", robot_addr(0))
        } else {
            endpoint.clone()
        }
    };
    let watchers: Vec<_> = intruders
        .iter()
        .map(|i| peer(&laptop, &endpoint_of(i), &i.tls, &["watch", "sonar/r1/**"]))
        .collect();
    let frames = robot.root.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let command = Expect::fixed::<ScanCommand>();
    let local_scan = ScanCommand::new(ScanCommandKind::LocalScan, -20.0, 20.0);
    let local_scan_file = frames.join("local_scan");
    let frame = wire::encode(&command.tag, wire::bytes_of(&local_scan), &[], Codec::Raw);
    std::fs::write(&local_scan_file, frame).unwrap();
    let puts: Vec<_> = intruders
        .iter()
        .map(|i| {
            let file = path_str(&local_scan_file);
            let args = ["put", "sonar/r1/commands", file, "40"];
            (i.who, peer(&laptop, &endpoint_of(i), &i.tls, &args))
        })
        .collect();
    for ((who, put), intruder) in puts.into_iter().zip(&intruders) {
        let out = output_of(put);
        assert!(out.contains("sent 40"), "{who}: {out}");
        // The listed reader is shown the robot's command subscription: its 40 commands reach the
        // robot, whose access control must refuse them (the others never get that far).
        if intruder.listed_reader {
            assert!(out.contains("\nmatched"), "{who}: {out}");
        }
    }

    // Bombs from the commander's machine: one 4 kB frame declaring a 4 GiB LZ4 slice (it aborted
    // the bridge), five times, and two 2 MB frames.
    let mut bomb = wire::encode(&command.tag, &[0; 16], &[], Codec::Raw);
    bomb[5] = Codec::Lz4 as u8;
    bomb[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
    bomb.resize(4096, 0xAB);
    let bomb_file = frames.join("bomb_4k");
    std::fs::write(&bomb_file, &bomb).unwrap();
    bomb.resize(2_000_000, 0xCD);
    bomb[12..16].copy_from_slice(&(512u32 << 20).to_le_bytes());
    let big_file = frames.join("bomb_2m");
    std::fs::write(&big_file, &bomb).unwrap();
    let commander = peer_tls(&certs, "laptop");
    for (file, count) in [(&bomb_file, "5"), (&big_file, "2")] {
        let args = ["put", "sonar/r1/commands", path_str(file), count];
        let out = output_of(peer(&laptop, &endpoint, &commander, &args));
        assert!(out.contains("\nmatched"), "the commander's peer: {out}");
    }

    // The laptop commands a local scan (again while the robot has not switched: a command sent
    // before the bridges matched their ends would go nowhere). At most one a second, so fewer
    // than 40 over PATIENCE: a single intruder's commands arriving would outnumber them.
    let laptop_commands = ipc::commands_service(&laptop_node)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    let deadline = Instant::now() + PATIENCE;
    let mut sent = 0u64;
    let mut robot_local = false;
    while !robot_local {
        assert!(Instant::now() < deadline, "the robot never scanned locally");
        laptop_commands.send_copy(local_scan).unwrap();
        sent += 1;
        let until = Instant::now() + Duration::from_secs(2);
        while Instant::now() < until && !robot_local {
            while let Some(s) = robot_status.receive().unwrap() {
                robot_local |= ScanMode::from_u8(s.payload().mode as u8) == ScanMode::Local;
            }
            let _ = robot_node.wait(Duration::from_millis(20));
        }
    }
    still_running(&mut [&mut robot_bridge, &mut laptop_bridge]);
    let peak_kb = peak_rss_kb(robot_bridge.child.id());

    for (mut watcher, intruder) in watchers.into_iter().zip(&intruders) {
        use std::io::Write as _;
        writeln!(watcher.stdin.take().unwrap()).unwrap();
        let counts = output_of(watcher);
        let samples = field(&format!(" {counts}"), "samples");
        let replies = field(&format!(" {counts}"), "replies");
        if intruder.listed_reader {
            assert!(samples > 0, "{}: read nothing ({counts})", intruder.who);
        } else {
            assert_eq!((samples, replies), (0, 0), "{}: {counts}", intruder.who);
        }
    }

    drop((laptop_commands, laptop_status, robot_status));
    assert!(laptop_bridge.terminate().success());
    let (status, stderr) = robot_bridge.terminate_with_stderr();
    assert!(status.success(), "the robot's bridge: {status}\n{stderr}");
    let counts = stderr
        .lines()
        .rfind(|l| l.contains("counts") && l.contains("channel=commands"))
        .unwrap_or_else(|| panic!("no command counts:\n{stderr}"));
    let arrived = field(counts, "messages");
    assert!(
        (1..=sent).contains(&arrived),
        "{arrived} commands arrived, the laptop sent {sent}: {counts}"
    );
    // The 4 kB bombs reach the bridge and are refused unread; the 2 MB frames are dropped by
    // zenoh (longer than a robot takes), or refused by the bridge if they arrive.
    let rejected = field(counts, "rejected");
    assert!((5..=7).contains(&rejected), "{counts}");
    // It was 563 MB after one 2 MB frame, and one 4 kB frame aborted it.
    assert!(
        peak_kb < 200 * 1024,
        "the robot's bridge peaked at {peak_kb} kB"
    );
    eprintln!("robot bridge: {counts}; peak RSS {peak_kb} kB");
    driver.terminate();
    sim.terminate();
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
                // The figures of docs/benchmarks.md were taken over plain TCP.
                "--insecure",
            ],
        );
        let laptop_bridge = laptop.spawn(
            "sonar-bridge",
            &[
                "--mode",
                "remote",
                "--robot",
                "r1",
                "--connect",
                &listen,
                "--insecure",
            ],
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
