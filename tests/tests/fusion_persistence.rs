//! End to end: the fusion's map survives `kill -9` (saved periodically, restored at start),
//! readings that never reach the fusion are counted on `sonar/fusion_status`, and a fusion offered
//! more than it can fuse keeps fusing.
#![allow(clippy::unwrap_used, clippy::expect_used)] // helpers outside #[test] fns; a panic is a failure

use std::path::Path;
use std::time::Instant;

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use sonar_common::ipc::{self, FusionStatus, GridHeader, LAYOUT_VERSION, Radar, Reading};
use sonar_e2e::{
    PATIENCE, Proc, Sandbox, collect_until, driver_ports, fusion_status_subscriber, path_str,
    wait_for_status,
};
use sonar_fusion::engine::Engine;

/// A grid snapshot as received.
struct Snapshot {
    header: GridHeader,
    cells: Vec<u8>,
}

type GridSubscriber = Subscriber<Ipc, [u8], GridHeader>;

fn grid_subscriber(node: &Node<Ipc>) -> GridSubscriber {
    ipc::grid_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

fn radar_subscriber(node: &Node<Ipc>) -> Subscriber<Ipc, Radar, ()> {
    ipc::radar_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

/// The next grid snapshot that satisfies `pred`.
fn next_snapshot(
    node: &Node<Ipc>,
    grid: &GridSubscriber,
    pred: impl Fn(&GridHeader) -> bool,
) -> Snapshot {
    let got = collect_until(
        node,
        || {
            grid.receive().unwrap().map(|s| Snapshot {
                header: *s.user_header(),
                cells: s.payload().to_vec(),
            })
        },
        |got| got.last().is_some_and(|s| pred(&s.header)),
    );
    got.into_iter().next_back().unwrap()
}

/// What a fusion restored from `state_file` would publish, decoded by the test itself.
fn map_in_file(state_file: &Path) -> (Vec<u8>, Radar) {
    let saved = sonar_fusion::persist::read(state_file)
        .unwrap()
        .expect("a state file");
    let mut engine = Engine::restore(saved.settings, usize::MAX, saved.state).unwrap();
    let mut cells = vec![0; engine.grid_len()];
    engine.encode_grid(&mut cells);
    (cells, engine.radar(0, 0))
}

fn fusion_status(node: &Node<Ipc>, sub: &Subscriber<Ipc, FusionStatus, ()>) -> FusionStatus {
    wait_for_status(node, sub, |_| true)
}

#[test]
fn the_map_survives_kill_9_of_the_fusion_and_is_restored_cell_for_cell() {
    let sandbox = Sandbox::new("persist");
    let state_file = sandbox.state.join("maps/fusion-map.bin");
    let node = sandbox.node("test-persist");
    let status = fusion_status_subscriber(&node);
    let grid = grid_subscriber(&node);
    let radar = radar_subscriber(&node);
    let (sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "100", "--seed", "5"]);
    let driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);
    let fusion_args = [
        "--state-file",
        path_str(&state_file),
        "--save-period",
        "0.2",
    ];
    let fusion = sandbox.spawn("sonar-fusion", &fusion_args);

    // A few saves of a map with readings in it, while readings keep coming.
    let before = wait_for_status(&node, &status, |s| {
        s.saves >= 3 && s.saved_readings_fused >= 30
    });
    assert_eq!(before.restored, 0, "nothing to restore at the first start");
    assert_eq!(before.save_failures, 0);
    // Killed with no chance to save or clean up: the file holds the last periodic save.
    assert!(!fusion.kill9().success());
    // No readings while the new fusion starts, so its first snapshot is the restored map.
    assert!(driver.terminate().success());
    while grid.receive().unwrap().is_some() {}
    while radar.receive().unwrap().is_some() {}
    while status.receive().unwrap().is_some() {}

    let fusion = sandbox.spawn("sonar-fusion", &fusion_args);
    let after = wait_for_status(&node, &status, |s| s.stamp_ns > before.stamp_ns);
    assert_eq!(after.restored, 1, "{after:?}");
    assert!(
        after.readings_fused >= before.saved_readings_fused,
        "restored {} readings, the save seen before the kill had {}",
        after.readings_fused,
        before.saved_readings_fused
    );
    assert_ne!(
        after.last_seq,
        FusionStatus::NO_SEQ,
        "the last seq is restored too"
    );
    let snapshot = next_snapshot(&node, &grid, |_| true);
    assert_eq!(snapshot.header.readings_fused, after.readings_fused);
    assert!(
        snapshot.header.occupied_cells > 100,
        "{:?}",
        snapshot.header
    );

    // Cell for cell the map in the file, and so is the radar.
    let (cells, expected_radar) = map_in_file(&state_file);
    assert_eq!(cells.len(), snapshot.cells.len());
    let differing = cells
        .iter()
        .zip(&snapshot.cells)
        .filter(|(a, b)| a != b)
        .count();
    assert_eq!(differing, 0, "cells differ from the saved map");
    let got_radar = collect_until(
        &node,
        || radar.receive().unwrap().map(|s| *s.payload()),
        |got| !got.is_empty(),
    )[0];
    let bits = |r: &Radar| r.distances_m.map(f32::to_bits);
    assert_eq!(bits(&got_radar), bits(&expected_radar));
    assert!(!sonar_fusion::persist::quarantine_path(&state_file).exists());

    // Stopped properly, it has nothing new to save: the file stays as it was.
    let saved = std::fs::read(&state_file).unwrap();
    assert!(fusion.terminate().success(), "fusion did not exit cleanly");
    assert_eq!(std::fs::read(&state_file).unwrap(), saved);
    while status.receive().unwrap().is_some() {}

    // Other settings: the fusion starts anyway, empty, and keeps the file aside.
    let mut other_args = fusion_args.to_vec();
    other_args.extend(["--cells", "200"]);
    let fusion = sandbox.spawn("sonar-fusion", &other_args);
    let fresh = wait_for_status(&node, &status, |s| s.stamp_ns > after.stamp_ns);
    assert_eq!((fresh.restored, fresh.readings_fused), (0, 0), "{fresh:?}");
    assert_eq!(
        std::fs::read(sonar_fusion::persist::quarantine_path(&state_file)).unwrap(),
        saved
    );
    assert!(fusion.terminate().success());

    assert!(sim.terminate().success());
    drop((grid, radar, status, node));
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}

/// A fusion killed long before its first save period is over still restores what it had fused:
/// the first save follows the first change of the map (before, a kill within 5 s of the start
/// persisted nothing; issue 24).
#[test]
fn the_first_readings_are_saved_at_once_not_a_save_period_later() {
    let sandbox = Sandbox::new("firstsave");
    let state_file = sandbox.state.join("fusion-map.bin");
    // The test is the driver.
    let node = sandbox.node("test-driver");
    let (readings, wake) = driver_ports(&node);
    let status = fusion_status_subscriber(&node);
    // An hour between saves: only the first save can put the readings in the file.
    let fusion_args = [
        "--state-file",
        path_str(&state_file),
        "--save-period",
        "3600",
    ];
    let fusion = sandbox.spawn("sonar-fusion", &fusion_args);
    let first = fusion_status(&node, &status);
    assert_eq!(first.saves, 0);
    readings.update_connections().unwrap();
    for seq in 0..3 {
        readings.send_copy(reading(seq)).unwrap();
    }
    wake.notify().unwrap();
    let saved = wait_for_status(&node, &status, |s| {
        s.saves >= 1 && s.saved_readings_fused >= 1
    });
    assert!(!fusion.kill9().success());
    while status.receive().unwrap().is_some() {}

    let fusion = sandbox.spawn("sonar-fusion", &fusion_args);
    let after = wait_for_status(&node, &status, |s| s.stamp_ns > saved.stamp_ns);
    assert_eq!(after.restored, 1, "{after:?}");
    assert!(
        after.readings_fused >= saved.saved_readings_fused,
        "{after:?}"
    );
    assert!(fusion.terminate().success());
}

fn reading(seq: u64) -> Reading {
    Reading {
        seq,
        layout_version: LAYOUT_VERSION,
        sweep_id: 1,
        angle_deg: -147.0 + 6.0 * (seq % 50) as f32,
        beam_half_angle_deg: 30.0,
        distance_m: 1.5,
        min_range_m: 0.03,
        max_range_m: 4.0,
        direction: 1,
        mode: 1,
        ..Reading::default()
    }
}

fn signal(proc: &Proc, signal: Signal) {
    kill(Pid::from_raw(proc.child.id() as i32), signal).unwrap();
}

#[test]
fn readings_lost_to_gaps_and_a_full_buffer_are_counted_and_a_driver_restart_is_not() {
    let sandbox = Sandbox::new("loss");
    // The test is the driver.
    let node = sandbox.node("test-driver");
    let (readings, wake) = driver_ports(&node);
    let status = fusion_status_subscriber(&node);
    let fusion = sandbox.spawn("sonar-fusion", &["--no-persist"]);
    // Its first status comes once its subscriber exists.
    let first = fusion_status(&node, &status);
    assert_eq!((first.readings_received, first.readings_lost), (0, 0));
    assert_eq!(first.last_seq, FusionStatus::NO_SEQ);
    readings.update_connections().unwrap();
    let publish = |r: Reading| {
        readings.send_copy(r).unwrap();
        wake.notify().unwrap();
    };

    // 3 and 4 never published: two lost.
    for seq in [0, 1, 2, 5, 6] {
        publish(reading(seq));
    }
    let s = wait_for_status(&node, &status, |s| s.readings_received == 5);
    assert_eq!((s.readings_lost, s.readings_out_of_order), (2, 0), "{s:?}");
    assert_eq!((s.last_seq, s.readings_fused), (6, 5));

    // The driver restarts and counts from 0: a restart, not a loss.
    publish(reading(0));
    publish(reading(1));
    let s = wait_for_status(&node, &status, |s| s.readings_received == 7);
    assert_eq!((s.readings_lost, s.readings_out_of_order), (2, 1), "{s:?}");

    // A reading of another layout version is received, counted, not fused.
    publish(Reading {
        layout_version: 99,
        ..reading(2)
    });
    let s = wait_for_status(&node, &status, |s| s.readings_received == 8);
    assert_eq!((s.readings_rejected, s.readings_fused), (1, 7), "{s:?}");

    // The fusion stalls (SIGSTOP) while the driver goes on: its buffer of 256 overflows and
    // iceoryx2 drops the oldest readings, which only the numbering reveals.
    signal(&fusion, Signal::SIGSTOP);
    let burst = 600;
    for seq in 3..3 + burst {
        readings.send_copy(reading(seq)).unwrap();
    }
    wake.notify().unwrap();
    signal(&fusion, Signal::SIGCONT);
    let last = 2 + burst;
    let s = wait_for_status(&node, &status, |s| s.last_seq == last);
    let received = s.readings_received - 8;
    assert!(received <= 256, "{s:?}");
    assert_eq!(
        s.readings_lost - 2,
        burst - received,
        "every reading published is received or counted lost: {s:?}"
    );

    assert!(fusion.terminate().success(), "fusion did not exit cleanly");
    drop((readings, wake, status, node));
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}

/// Readings of a local scan of the narrowest segment (two readings a sweep) offered far faster
/// than the fusion fuses them: its buffer overflows, so nearly every reading it gets starts a new
/// sweep. A sweep's end used to force a snapshot each time, whatever `--max-snapshot-rate`, and the engine
/// spent itself on them (at 1024² cells, offered 9 k readings/s, it fused 105/s). Now it keeps
/// fusing, publishes at most two snapshots per rate interval (the periodic one and one at a
/// sweep's end), counts every reading it did not get, and the last map still appears.
#[test]
fn an_overloaded_fusion_keeps_fusing_within_its_snapshot_rate_and_counts_the_loss() {
    const MAX_RATE: f64 = 5.0;
    let sandbox = Sandbox::new("overload");
    let node = sandbox.node("test-driver");
    let (readings, wake) = driver_ports(&node);
    let status = fusion_status_subscriber(&node);
    let grid = grid_subscriber(&node);
    let started = Instant::now();
    let fusion = sandbox.spawn(
        "sonar-fusion",
        &["--no-persist", "--max-snapshot-rate", &MAX_RATE.to_string()],
    );
    fusion_status(&node, &status);
    readings.update_connections().unwrap();
    let fragment = |seq: u64| Reading {
        sweep_id: u32::try_from(seq / 2).unwrap(),
        ..reading(seq)
    };
    // The first reading on its own: readings lost before the first one received are not seen.
    readings.send_copy(fragment(0)).unwrap();
    wake.notify().unwrap();
    wait_for_status(&node, &status, |s| s.readings_received == 1);

    // Bursts of sixteen buffers' worth, until the fusion has been seen losing readings and its
    // count of fused ones rising three times: it fuses on through the overload.
    let mut sent = 1;
    let mut fused_while_losing: Vec<u64> = Vec::new();
    let deadline = Instant::now() + PATIENCE;
    while fused_while_losing.len() < 4 {
        assert!(
            Instant::now() < deadline,
            "the fusion stopped fusing under overload: {fused_while_losing:?}"
        );
        for _ in 0..4096 {
            readings.send_copy(fragment(sent)).unwrap();
            sent += 1;
        }
        wake.notify().unwrap();
        while let Some(sample) = status.receive().unwrap() {
            let s = *sample.payload();
            if s.readings_lost > 0 && fused_while_losing.last() != Some(&s.readings_fused) {
                fused_while_losing.push(s.readings_fused);
            }
        }
    }

    // The newest readings stay in the buffer, so the last one sent arrives, every reading before
    // it was either received or counted lost, and the fusion fuses every reading it received
    // (those in its backlog, at most 2048, once it has caught up).
    let s = wait_for_status(&node, &status, |s| {
        s.last_seq == sent - 1 && s.readings_fused == s.readings_received
    });
    assert_eq!(s.readings_received + s.readings_lost, sent, "{s:?}");
    assert!(s.readings_lost > 0, "{s:?}");
    // An upper bound, so it holds on a machine of any speed: per interval of 1/MAX_RATE, one
    // snapshot paced by the rate and one brought forward by a sweep's end.
    let intervals = (started.elapsed().as_secs_f64() * MAX_RATE).ceil() as u64 + 1;
    assert!(
        s.snapshots_published <= 2 * intervals,
        "{} snapshots in {intervals} intervals: {s:?}",
        s.snapshots_published
    );
    // The map of the last readings is published once the pace allows.
    next_snapshot(&node, &grid, |h| h.readings_fused == s.readings_fused);

    assert!(fusion.terminate().success(), "fusion did not exit cleanly");
    drop((readings, wake, status, grid, node));
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}

/// A second fusion on the namespace of a running one is refused with what to do, not with
/// iceoryx2's bare `ExceedsMaxSupportedPublishers` (issue 28).
#[test]
fn a_second_fusion_on_a_running_namespace_says_so_and_how_to_pick_another() {
    let sandbox = Sandbox::new("second");
    let node = sandbox.node("test-second");
    let status = fusion_status_subscriber(&node);
    let fusion = sandbox.spawn("sonar-fusion", &["--no-persist"]);
    fusion_status(&node, &status);
    let second = sandbox.run("sonar-fusion", &["--no-persist"]);
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert!(!second.status.success(), "{stderr}");
    assert!(stderr.contains("ExceedsMaxSupportedPublishers"), "{stderr}");
    assert!(stderr.contains("already running"), "{stderr}");
    assert!(stderr.contains("--iox-prefix"), "{stderr}");
    assert!(fusion.terminate().success());
}

/// A state file that cannot be written stops the fusion at start with the reason and the way out,
/// instead of a warning at every save period while persistence is silently off (issue 28).
#[test]
fn an_unwritable_state_file_stops_the_start_with_what_to_do() {
    let sandbox = Sandbox::new("unwritable");
    // Under a file, not a directory: unwritable for root too.
    let blocker = sandbox.root.join("not-a-directory");
    std::fs::write(&blocker, b"x").unwrap();
    let state = blocker.join("map.bin");
    let out = sandbox.run("sonar-fusion", &["--state-file", path_str(&state)]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(stderr.contains("cannot write the state file"), "{stderr}");
    assert!(stderr.contains("--no-persist"), "{stderr}");
    // And a writable one is left without a stray temporary file.
    let fine = sandbox.state.join("ok/map.bin");
    let fusion = sandbox.spawn("sonar-fusion", &["--state-file", path_str(&fine)]);
    let node = sandbox.node("test-unwritable");
    let status = fusion_status_subscriber(&node);
    fusion_status(&node, &status);
    assert!(!sonar_fusion::persist::temporary_path(&fine).exists());
    assert!(fusion.terminate().success());
}
