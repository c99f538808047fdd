//! End to end: `sonar-record` on the live pipeline, `sonar-replay` of its file into a second
//! namespace, and what each does with bad input.
#![allow(clippy::unwrap_used, clippy::expect_used)] // helpers outside #[test] fns; a panic is a failure

use std::path::PathBuf;
use std::time::{Duration, Instant};

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use sonar_common::ipc::{
    self, FusionCommand, FusionCommandKind, Reading, ScanCommand, ScanCommandKind,
};
use sonar_e2e::{
    CpuHog, PATIENCE, Sandbox, check_ok, collect_until, corridor_grid_config, driver_ports,
    fusion_status_subscriber, path_str, readings_subscriber, readings_subscribers, receive_reading,
    stop_driver, wait_until,
};
use sonar_fusion::features::SWEEP_IDLE;

/// More than one subscriber buffer (256): a replay that did not pace itself at `--speed max`
/// would overwrite readings before the test's subscriber (polling every 5 ms) takes them.
const READINGS: usize = 300;

/// Every bit of a reading, floats as their bit patterns (NaN compares equal to itself here).
fn bits(r: &Reading) -> Vec<u64> {
    let mut v = vec![
        r.seq,
        r.host_stamp_ns,
        r.layout_version.into(),
        r.device_seq.into(),
        r.device_time_ms.into(),
        r.sweep_id.into(),
        r.flags.into(),
    ];
    v.extend(
        [
            r.angle_deg,
            r.beam_half_angle_deg,
            r.tof_us,
            r.distance_m,
            r.speed_of_sound_mps,
            r.min_range_m,
            r.max_range_m,
        ]
        .map(|f| u64::from(f.to_bits())),
    );
    v.extend(r.echo_us.map(u64::from));
    v.extend([r.direction as u8, r.mode, r.ping_count, r.pings_used].map(u64::from));
    v.extend(r.reserved.map(u64::from));
    v
}

#[test]
fn a_replay_publishes_exactly_what_the_live_pipeline_published() {
    let live = Sandbox::new("rec_live");
    let node = live.node("test-live");
    let sub = readings_subscriber(&node);
    let file: PathBuf = live.root.join("run.mcap");
    let count = READINGS.to_string();
    let recorder = live.spawn("sonar-record", &[path_str(&file), "--max-readings", &count]);
    // Both subscribers exist before the driver publishes its first reading.
    wait_until(&node, "the recorder's subscription", || {
        readings_subscribers(&node) >= 2
    });
    let (sim, pty) = live.spawn_sim(&["--scene", "room", "--speed", "100", "--seed", "3"]);
    let driver = live.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);

    let live_readings = collect_until(
        &node,
        || sub.receive().unwrap().map(|s| *s.payload()),
        |got| got.len() >= READINGS,
    );
    let (status, stderr) = recorder.wait_exit();
    assert!(status.success(), "sonar-record failed: {stderr}");
    assert!(stderr.contains("reached --max-readings"), "{stderr}");
    assert!(driver.terminate().success(), "driver did not exit cleanly");
    assert!(sim.terminate().success(), "simulator did not exit cleanly");

    let info = live.run("sonar-replay", &[path_str(&file), "--info"]);
    let info_out = String::from_utf8_lossy(&info.stdout);
    assert!(info.status.success(), "{info:?}");
    assert!(
        info_out.contains(&format!(
            "sonar/readings: {READINGS} (seq 0..={}, 0 gaps)",
            READINGS - 1
        )),
        "{info_out}"
    );
    assert!(info_out.contains("complete: yes"), "{info_out}");
    // No fusion engine ran: the features channel is there, empty.
    assert!(info_out.contains("\nsonar/features: 0\n"), "{info_out}");

    // A second pipeline, which never saw the live one, gets the same readings from the file.
    let replay_box = Sandbox::new("rec_replay");
    let replay_node = replay_box.node("test-replay");
    let replay_sub = readings_subscriber(&replay_node);
    let replay = replay_box.spawn(
        "sonar-replay",
        &[
            path_str(&file),
            "--speed",
            "max",
            "--wait-for-subscribers",
            "1",
        ],
    );
    let replayed = collect_until(
        &replay_node,
        || replay_sub.receive().unwrap().map(|s| *s.payload()),
        |got| got.len() >= READINGS,
    );
    let (status, stderr) = replay.wait_exit();
    assert!(status.success(), "sonar-replay failed: {stderr}");

    assert_eq!(replayed.len(), live_readings.len());
    for (k, (a, b)) in live_readings.iter().zip(&replayed).enumerate() {
        assert_eq!(a.seq, k as u64, "the live run has no gaps");
        assert_eq!(bits(a), bits(b), "reading {k} differs:\n{a:?}\n{b:?}");
    }
}

fn test_reading(seq: u64) -> Reading {
    Reading {
        seq,
        host_stamp_ns: 1_700_000_000_000_000_000 + seq * 25_000_000,
        layout_version: ipc::LAYOUT_VERSION,
        sweep_id: 1,
        angle_deg: -147.0 + 6.0 * seq as f32,
        beam_half_angle_deg: 30.0,
        distance_m: if seq.is_multiple_of(2) { 1.2 } else { f32::NAN },
        flags: if seq.is_multiple_of(2) {
            0
        } else {
            ipc::flags::NO_ECHO
        },
        ping_count: 4,
        pings_used: 4,
        direction: 1,
        mode: 1,
        ..Default::default()
    }
}

#[test]
fn the_recorder_finishes_its_file_on_sigterm_with_the_commands() {
    let sandbox = Sandbox::new("rec_term");
    let node = sandbox.node("test-driver");
    let file = sandbox.root.join("term.mcap");
    let recorder = sandbox.spawn("sonar-record", &[path_str(&file)]);
    let fusion = ipc::fusion_commands_service(&node).unwrap();
    let commands = ipc::commands_service(&node).unwrap();
    wait_until(&node, "the recorder's subscriptions", || {
        readings_subscribers(&node) >= 1
            && fusion.dynamic_config().number_of_subscribers() >= 1
            && commands.dynamic_config().number_of_subscribers() >= 1
    });

    // The test stands in for the driver and a viewer.
    let (readings, wake) = driver_ports(&node);
    let sent: Vec<Reading> = (0..20).map(test_reading).collect();
    for r in &sent[..10] {
        readings.send_copy(*r).unwrap();
        wake.notify().unwrap();
    }
    let clear = FusionCommand::new(FusionCommandKind::Clear, 0);
    let fusion_pub = fusion.publisher_builder().create().unwrap();
    fusion_pub.send_copy(clear).unwrap();
    let scan = ScanCommand::new(ScanCommandKind::LocalScan, -30.0, 30.0);
    let commands_pub = commands.publisher_builder().create().unwrap();
    commands_pub.send_copy(scan).unwrap();
    for r in &sent[10..] {
        readings.send_copy(*r).unwrap();
        wake.notify().unwrap();
    }
    // Everything above sits in the recorder's queues (delivery is synchronous); SIGTERM now.
    let status = recorder.terminate();
    assert!(status.success(), "sonar-record did not exit cleanly");
    drop((fusion_pub, commands_pub, readings, wake));

    let info = sandbox.run("sonar-replay", &[path_str(&file), "--info"]);
    let info_out = String::from_utf8_lossy(&info.stdout);
    assert!(info.status.success(), "{info:?}");
    for line in [
        "sonar/readings: 20 (seq 0..=19, 0 gaps)",
        "sonar/commands: 1",
        "sonar/fusion_commands: 1",
        "complete: yes",
    ] {
        assert!(info_out.contains(line), "{line:?} missing in\n{info_out}");
    }

    // Replayed with --restamp into another namespace: the fusion command comes along (the scan
    // command stays in the file: it was for the driver), and only host_stamp_ns changes.
    let replay_box = Sandbox::new("rec_term_replay");
    let rnode = replay_box.node("test-consumer");
    let rsub = readings_subscriber(&rnode);
    let fsub = ipc::fusion_commands_service(&rnode)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    let before = ipc::unix_time_ns();
    let replay = replay_box.spawn(
        "sonar-replay",
        &[
            path_str(&file),
            "--speed",
            "max",
            "--restamp",
            "--wait-for-subscribers",
            "1",
        ],
    );
    // Like a consumer, take whatever arrives on either service until both are complete.
    let mut fusion_commands = Vec::new();
    let got = collect_until(
        &rnode,
        || {
            if let Some(c) = fsub.receive().unwrap() {
                fusion_commands.push(*c.payload());
            }
            rsub.receive().unwrap().map(|s| *s.payload())
        },
        |got| got.len() >= sent.len(),
    );
    let (status, stderr) = replay.wait_exit();
    assert!(status.success(), "sonar-replay failed: {stderr}");
    for (a, b) in sent.iter().zip(&got) {
        assert!(b.host_stamp_ns >= before, "not restamped: {b:?}");
        let mut b = *b;
        b.host_stamp_ns = a.host_stamp_ns;
        assert_eq!(bits(a), bits(&b));
    }
    while let Some(c) = fsub.receive().unwrap() {
        fusion_commands.push(*c.payload());
    }
    assert_eq!(fusion_commands, [clear]);

    // A copy cut short, as a killed recorder might leave it: an error naming the problem, unless
    // the user asks for what is there.
    let bytes = std::fs::read(&file).unwrap();
    let cut = sandbox.root.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() - 100]).unwrap();
    let out = sandbox.run("sonar-replay", &[path_str(&cut), "--speed", "max"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("truncated"), "{stderr}");
    assert!(stderr.contains("--allow-truncated"), "{stderr}");
    let out = sandbox.run(
        "sonar-replay",
        &[path_str(&cut), "--allow-truncated", "--info"],
    );
    assert!(out.status.success(), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("complete: no (truncated)"),
        "{out:?}"
    );

    // Into a namespace where a driver still publishes readings, a replay would mix both streams
    // in the map: refused, saying what to do.
    let driver = ipc::readings_service(&node)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    let out = sandbox.run("sonar-replay", &[path_str(&file), "--speed", "max"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("already publishes sonar/readings"),
        "{stderr}"
    );
    drop(driver);
}

#[test]
fn damaged_or_foreign_files_are_clear_errors() {
    let sandbox = Sandbox::new("rec_bad");
    let noise = sandbox.root.join("noise.mcap");
    let bytes: Vec<u8> = (0..10_000u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 11) as u8)
        .collect();
    std::fs::write(&noise, &bytes).unwrap();

    let out = sandbox.run("sonar-replay", &[path_str(&noise)]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("not an MCAP file"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");

    // MCAP magic followed by noise.
    let mut fake = b"\x89MCAP0\r\n".to_vec();
    fake.extend_from_slice(&bytes);
    std::fs::write(&noise, &fake).unwrap();
    let out = sandbox.run("sonar-replay", &[path_str(&noise)]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("corrupt") || stderr.contains("truncated"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");

    let missing = sandbox.root.join("missing.mcap");
    let out = sandbox.run("sonar-replay", &[path_str(&missing)]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("missing.mcap"),
        "{out:?}"
    );

    // The recorder does not overwrite a file by accident.
    let out = sandbox.run("sonar-record", &[path_str(&noise), "--max-readings", "1"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("--force"), "{stderr}");
    assert_eq!(std::fs::read(&noise).unwrap(), fake, "the file was touched");

    // A recording without readings (its recorder stopped before a driver published any): said,
    // and a failure, by sonar-replay and by sonar-pipeline --replay, instead of a silent exit 0.
    let node = sandbox.node("test-waiter");
    let empty = sandbox.root.join("empty.mcap");
    let recorder = sandbox.spawn("sonar-record", &[path_str(&empty)]);
    wait_until(&node, "the recorder's subscription", || {
        readings_subscribers(&node) >= 1
    });
    assert!(
        recorder.terminate().success(),
        "sonar-record did not exit cleanly"
    );
    let out = sandbox.run("sonar-replay", &[path_str(&empty), "--speed", "max"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(stderr.contains("holds no readings"), "{stderr}");
    assert!(stderr.contains("--info"), "{stderr}");
    let out = sandbox.run(
        "sonar-pipeline",
        &["--replay", path_str(&empty), "--no-viewer"],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(stderr.contains("holds no readings"), "{stderr}");
}

type GridSubscriber = Subscriber<Ipc, [u8], ipc::GridHeader>;

fn grid_subscriber(node: &Node<Ipc>) -> GridSubscriber {
    ipc::grid_service(node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap()
}

/// A snapshot that follows the last one with the same readings by this long has not come: the
/// map after them is settled. The sweep those readings end is closed after the snapshot of its
/// last reading once the head's end of it comes (`sonar/sweep_ends`), so two snapshots can hold the
/// same readings, the second with the sweep's last region placed; the fusion sends the second
/// within its snapshot interval (100 ms) of the first.
const SETTLED: Duration = Duration::from_secs(3);

/// The last `sonar/grid` snapshot with exactly `readings` fused, once none has followed it for
/// [`SETTLED`]: its header and cells. Gives up after [`PATIENCE`] naming the last snapshot had and
/// the fusion's latest status (a reading lost on the way never comes: its `readings_lost`).
fn map_after(node: &Node<Ipc>, grid: &GridSubscriber, readings: u64) -> (ipc::GridHeader, Vec<u8>) {
    let status = fusion_status_subscriber(node);
    let deadline = Instant::now() + PATIENCE;
    let mut last = None;
    let mut last_status = None;
    let mut found: Option<(ipc::GridHeader, Vec<u8>, Instant)> = None;
    loop {
        while let Some(sample) = grid.receive().unwrap() {
            let header = *sample.user_header();
            if header.readings_fused == readings {
                found = Some((header, sample.payload().to_vec(), Instant::now()));
            }
            last = Some(header);
        }
        if let Some((header, cells, at)) = &found
            && at.elapsed() >= SETTLED
        {
            return (*header, cells.clone());
        }
        while let Some(sample) = status.receive().unwrap() {
            last_status = Some(*sample.payload());
        }
        assert!(
            Instant::now() < deadline,
            "no snapshot with {readings} readings fused; the last: {last:?}; the fusion's status: \
             {last_status:?}"
        );
        let _ = node.wait(Duration::from_millis(5));
    }
}

#[test]
fn replaying_a_recording_into_the_fusion_engine_gives_the_live_map() {
    let live = Sandbox::new("rec_map_live");
    let node = live.node("test-live");
    let readings = readings_subscriber(&node);
    let file: PathBuf = live.root.join("run.mcap");
    let recorder = live.spawn("sonar-record", &[path_str(&file)]);
    let fusion = live.spawn("sonar-fusion", &[]);
    wait_until(&node, "recorder and fusion subscribed", || {
        readings_subscribers(&node) >= 3
    });
    let live_grid = grid_subscriber(&node);
    let (sim, pty) = live.spawn_sim(&["--scene", "room", "--speed", "20", "--seed", "5"]);
    let driver = live.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);
    // More than two sweeps (50 readings each), then the head stops: the live map is the one of
    // every reading published, whenever the fusion publishes it.
    collect_until(&node, || receive_reading(&readings), |got| got.len() >= 101);
    let count = stop_driver(driver);
    let (live_header, live_cells) = map_after(&node, &live_grid, count);
    for p in [recorder, sim, fusion] {
        assert!(p.terminate().success());
    }
    // The fusion published the features of sweep 1 when sweep 2 began; the recorder has them.
    let info = live.run("sonar-replay", &[path_str(&file), "--info"]);
    let info_out = String::from_utf8_lossy(&info.stdout);
    assert!(info.status.success(), "{info:?}");
    assert!(
        info_out.contains(&format!(
            "sonar/readings: {count} (seq 0..={}, 0 gaps)",
            count - 1
        )),
        "{info_out}"
    );
    let features: usize = info_out
        .lines()
        .find_map(|l| l.strip_prefix("sonar/features: "))
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no sonar/features line in\n{info_out}"));
    assert!(features >= 1, "{info_out}");

    // Replayed with the one command (`sonar-pipeline --replay`: fusion on the recording, no
    // driver), which stops by itself at the end of the recording when there is no viewer.
    let replay_box = Sandbox::new("rec_map_replay");
    let replay_node = replay_box.node("test-replay");
    let replay_grid = grid_subscriber(&replay_node);
    let pipeline = replay_box.spawn(
        "sonar-pipeline",
        &["--no-viewer", "--replay", path_str(&file), "--speed", "max"],
    );
    let (header, cells) = map_after(&replay_node, &replay_grid, count);
    let (status, stderr) = pipeline.wait_exit();
    assert!(status.success(), "{stderr}");
    assert!(
        stderr.contains("finished process=\"sonar-replay\""),
        "{stderr}"
    );

    assert_same_cells(&live_cells, &cells, "");
    assert!(live_header.occupied_cells > 100, "{live_header:?}");
    assert_eq!(
        (
            header.occupied_cells,
            header.free_cells,
            header.unknown_cells
        ),
        (
            live_header.occupied_cells,
            live_header.free_cells,
            live_header.unknown_cells
        )
    );
}

/// Readings of the corridor tour, sweeps of 50: past the robot's stop in the second room.
const TOUR_READINGS: usize = 850;

/// The corridor tour recorded with its odometry on `robot/pose`, replayed at the pace it was
/// recorded at into a fresh fusion: the map of the tour again, cell for cell, on a machine whose
/// every core is kept busy (where a reading lands must not depend on the load: issue 24). A
/// debug-build fusion beside busy loops fuses the tour slower than it comes: it keeps what it has
/// not fused in its backlog (before, its buffer of 256 overflowed and 97-147 of the 850 readings
/// were lost in 5 of 6 runs, so no snapshot ever held them all).
#[test]
fn replaying_a_recorded_tour_gives_the_live_map() {
    let _hog = CpuHog::start();
    let config = corridor_grid_config("rec_tour");
    let fusion_args = ["--config", config.to_str().unwrap(), "--no-persist"];
    let live = Sandbox::new("rec_tour_live");
    let node = live.node("test-live");
    let readings = readings_subscriber(&node);
    let file: PathBuf = live.root.join("tour.mcap");
    let recorder = live.spawn("sonar-record", &[path_str(&file)]);
    let fusion = live.spawn("sonar-fusion", &fusion_args);
    wait_until(&node, "recorder and fusion subscribed", || {
        readings_subscribers(&node) >= 3
    });
    let live_grid = grid_subscriber(&node);
    // Odometry without errors: the map is where the scene has its walls.
    let (sim, count) = drive_tour(&live, &node, &readings, "5", ("0", "0"), None);
    let (live_header, live_cells) = map_after(&node, &live_grid, count);
    let (status, recorder_log) = recorder.terminate_with_stderr();
    assert!(status.success(), "{recorder_log}");
    assert!(sim.terminate().success());
    let live_log = stopped_line(fusion);
    // The fusion placed the readings at the robot's poses: the last snapshot's is in the second
    // room's half of the corridor, 3 m and more from the start.
    assert!(live_header.pose_x_m > 3.0, "{live_header:?}");
    assert!(live_header.occupied_cells > 500, "{live_header:?}");
    let info = live.run("sonar-replay", &[path_str(&file), "--info"]);
    let info_out = String::from_utf8_lossy(&info.stdout);
    assert!(info.status.success(), "{info:?}");
    let poses: usize = info_out
        .lines()
        .find_map(|l| l.strip_prefix("robot/pose: "))
        .and_then(|n| n.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no robot/pose line in\n{info_out}"));
    assert!(poses > 100, "{info_out}\nsonar-record: {recorder_log}");
    // Every reading the driver published is in the file (else the replay can never match).
    let recorded: u64 = info_out
        .lines()
        .find_map(|l| l.strip_prefix(&format!("{}: ", ipc::READINGS_SERVICE)))
        .and_then(|n| n.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no readings line in\n{info_out}"));
    assert_eq!(recorded, count, "{info_out}\nsonar-record: {recorder_log}");

    let replay_box = Sandbox::new("rec_tour_replay");
    let replay_node = replay_box.node("test-replay");
    let replay_grid = grid_subscriber(&replay_node);
    let fusion = replay_box.spawn("sonar-fusion", &fusion_args);
    wait_until(&replay_node, "fusion subscribed", || {
        readings_subscribers(&replay_node) >= 1
    });
    let replay = replay_box.spawn(
        "sonar-replay",
        &[
            path_str(&file),
            // The pace it was recorded at (the factor is of the recorded stamps' pace, so the
            // `--speed 40` this test had ran into the replay's ceiling of 1000 messages a
            // second, and a debug-build fusion beside busy loops lost readings whenever one of
            // its steps, a sweep's end, took longer than 256 of them: 0.26 s).
            "--speed",
            "1",
            "--wait-for-subscribers",
            "1",
        ],
    );
    let (header, cells) = map_after(&replay_node, &replay_grid, count);
    let _ = std::fs::remove_file(&config);
    assert!(replay.wait_exit().0.success());
    let replay_log = stopped_line(fusion);

    assert_same_cells(
        &live_cells,
        &cells,
        &format!("({header:?})\nlive: {live_log}\nreplay: {replay_log}"),
    );
}

/// The corridor tour with its drifting odometry through a localising fusion (the pipeline's
/// configuration file: the tour's grid, `[features] localize = true`), recorded; `sonar-export
/// --from-recording` given the same file fuses the recording into the live map, cell for cell
/// (issue 27: an export took no configuration, so a tour's map came out clipped and smeared).
#[test]
fn an_offline_export_with_the_pipelines_config_gives_the_live_localised_map() {
    let config = corridor_grid_config("export_tour");
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(&config, format!("{text}\n[features]\nlocalize = true\n")).unwrap();
    let sandbox = Sandbox::new("export_tour");
    let node = sandbox.node("test-export");
    let readings = readings_subscriber(&node);
    let file: PathBuf = sandbox.root.join("tour.mcap");
    let recorder = sandbox.spawn("sonar-record", &[path_str(&file)]);
    let fusion = sandbox.spawn(
        "sonar-fusion",
        &["--config", config.to_str().unwrap(), "--no-persist"],
    );
    wait_until(&node, "recorder and fusion subscribed", || {
        readings_subscribers(&node) >= 3
    });
    let grid = grid_subscriber(&node);
    // The evaluation's drifting odometry: 3 % long, 2 degrees a metre; the simulator stalled
    // for longer than the fusion's idle time in the middle of a sweep, as a loaded machine may
    // stall it: the live fusion shows the sweep merged but must go on with it as the export,
    // which never sees the stall, does.
    let (sim, count) = drive_tour(
        &sandbox,
        &node,
        &readings,
        "3",
        ("0.03", "2"),
        Some(TOUR_READINGS / 2),
    );
    let (header, _) = map_after(&node, &grid, count);
    assert!(header.occupied_cells > 500, "{header:?}");
    let live_map = export_npy(&sandbox, "live", &[]);
    for p in [recorder, sim] {
        assert!(p.terminate().success());
    }
    let live_log = stopped_line(fusion);
    let config_arg = config.to_str().unwrap();
    let offline_map = export_npy(
        &sandbox,
        "offline",
        &[
            "--from-recording",
            path_str(&file),
            "--config",
            config_arg,
            "--mcap",
        ],
    );
    assert_same_cells(&live_map, &offline_map, &format!("live: {live_log}"));
    // The localisation made a difference: the same grid without it is another map.
    std::fs::write(&config, text).unwrap();
    let unlocalised_map = export_npy(
        &sandbox,
        "unlocalised",
        &[
            "--from-recording",
            path_str(&file),
            "--config",
            config_arg,
            "--mcap",
        ],
    );
    let _ = std::fs::remove_file(&config);
    assert_eq!(unlocalised_map.len(), live_map.len());
    assert_ne!(unlocalised_map, live_map);
    // The frames say where the readings were placed: the localised export's `map → odom` takes
    // the drift out (the odometry 3 % long: centimetres by the tour's end), the other's is the
    // identity, as its readings lie at the odometry's poses.
    let localised = maps_to_odom(&sandbox.root.join("offline.mcap"));
    let (x, y, theta) = *localised.last().expect("map → odom written");
    assert!(
        x.hypot(y) > 0.01 || theta.abs() > 0.2f64.to_radians(),
        "the localised export's last map → odom is ({x}, {y}, {theta})"
    );
    let unlocalised = maps_to_odom(&sandbox.root.join("unlocalised.mcap"));
    assert!(!unlocalised.is_empty());
    assert!(
        unlocalised.iter().all(|&t| t == (0.0, 0.0, 0.0)),
        "the unlocalised export's map → odom is not the identity"
    );
}

/// Every `map → odom` of an MCAP file's `/foxglove/tf`, as (x, y, θ), in file order.
fn maps_to_odom(file: &std::path::Path) -> Vec<(f64, f64, f64)> {
    use foxglove::Decode;
    let bytes = std::fs::read(file).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(Result::unwrap)
        .filter(|m| m.channel.topic == "/foxglove/tf")
        .map(|m| foxglove::messages::FrameTransform::decode(&m.data[..]).unwrap())
        .filter(|t| t.parent_frame_id == "map" && t.child_frame_id == "odom")
        .map(|t| {
            let (p, q) = (t.translation.unwrap(), t.rotation.unwrap());
            (p.x, p.y, 2.0 * q.z.atan2(q.w))
        })
        .collect()
}

/// The corridor tour at 20× with `seed` and odometry errors `(scale, heading drift °/m)` through a
/// driver in `sandbox`, until [`TOUR_READINGS`] readings; the driver stopped, the simulator still
/// running. With `stall_after`, the simulator is stopped (SIGSTOP) for longer than the fusion's
/// [`SWEEP_IDLE`] once that many readings have come, then let go on (its readings' stamps, from
/// the head's clock, show no pause). Returns it and how many readings the driver published.
fn drive_tour(
    sandbox: &Sandbox,
    node: &Node<Ipc>,
    readings: &Subscriber<Ipc, Reading, ()>,
    seed: &str,
    (scale, drift): (&str, &str),
    stall_after: Option<usize>,
) -> (sonar_e2e::Proc, u64) {
    // 20× with poses at 5 Hz: 83 readings and 100 poses a second, so the readings' (256) and the
    // poses' (2048) subscriber buffers hold 3 s and 20 s of them for a consumer descheduled on a
    // loaded machine (at 40× and 20 Hz, 1.5 s and 2.5 s: the recorder and the fusion lost poses
    // and readings beside two busy loops, and the maps differed for that alone).
    let (sim, pty) = sandbox.spawn_sim(&[
        "--scene",
        "corridor",
        "--speed",
        "20",
        "--pose-rate",
        "5",
        "--seed",
        seed,
        "--odom-scale-error",
        scale,
        "--odom-heading-drift",
        drift,
    ]);
    // A driver that waits out the stall without asking the head for its status.
    let driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--silence-timeout", "10"]);
    let mut collected = 0;
    if let Some(stall_after) = stall_after {
        collected = collect_until(
            node,
            || receive_reading(readings),
            |got| got.len() >= stall_after,
        )
        .len();
        let pid = Pid::from_raw(sim.child.id() as i32);
        kill(pid, Signal::SIGSTOP).unwrap();
        // Well beyond the idle time, however late the fusion takes the last reading.
        std::thread::sleep(SWEEP_IDLE + Duration::from_secs(1));
        kill(pid, Signal::SIGCONT).unwrap();
    }
    collect_until(
        node,
        || receive_reading(readings),
        |got| collected + got.len() >= TOUR_READINGS,
    );
    (sim, stop_driver(driver))
}

/// Runs `sonar-export --format npy` with `args` into the sandbox as `name.npy`; the file's bytes.
fn export_npy(sandbox: &Sandbox, name: &str, args: &[&str]) -> Vec<u8> {
    let stem = sandbox.root.join(name);
    let mut all = vec!["--format", "npy", "--out", path_str(&stem)];
    all.extend_from_slice(args);
    let out = sandbox.run("sonar-export", &all);
    check_ok(&format!("{name} sonar-export"), &out);
    // How an offline export placed its readings, shown with a failure's output.
    for line in String::from_utf8_lossy(&out.stderr).lines() {
        if line.contains("recording fused") {
            eprintln!("{name}: {line}");
        }
    }
    std::fs::read(stem.with_extension("npy")).unwrap()
}

/// Stops a fusion and returns its last log line, the one with its counters (readings, and those
/// placed past the latest pose).
fn stopped_line(fusion: sonar_e2e::Proc) -> String {
    let (status, stderr) = fusion.terminate_with_stderr();
    assert!(status.success(), "{stderr}");
    let line = stderr
        .lines()
        .find(|l| l.contains("fusion stopped"))
        .unwrap_or_else(|| panic!("no stop line in\n{stderr}"))
        .to_owned();
    eprintln!("{line}");
    line
}

/// The live and the replayed map hold the same cells; `context` goes into the failure message.
fn assert_same_cells(live: &[u8], replayed: &[u8], context: &str) {
    assert_eq!(replayed.len(), live.len());
    let differing = replayed.iter().zip(live).filter(|(a, b)| a != b).count();
    assert_eq!(
        differing, 0,
        "cells differ between the live and the replayed map {context}"
    );
}

/// Recorders started before the head leave the driver and the fusion their places on the command
/// services: with two places, two early recorders made the driver exit (issue 28).
#[test]
fn recorders_started_first_never_keep_the_driver_or_the_fusion_out() {
    let sandbox = Sandbox::new("rec_early");
    let node = sandbox.node("test-early");
    let commands = ipc::commands_service(&node).unwrap();
    let fusion_commands = ipc::fusion_commands_service(&node).unwrap();
    let recorders: Vec<_> = (0..3)
        .map(|k| {
            let file = sandbox.root.join(format!("early{k}.mcap"));
            sandbox.spawn("sonar-record", &[path_str(&file)])
        })
        .collect();
    wait_until(&node, "the recorders' subscriptions", || {
        commands.dynamic_config().number_of_subscribers() >= 3
            && fusion_commands.dynamic_config().number_of_subscribers() >= 3
    });
    let readings = readings_subscriber(&node);
    let fusion = sandbox.spawn("sonar-fusion", &["--no-persist"]);
    let (sim, pty) = sandbox.spawn_sim(&["--speed", "20"]);
    let driver = sandbox.spawn("sonar-driver", &["--port", &pty]);
    // The driver runs (it subscribes to sonar/commands before it publishes a reading).
    collect_until(&node, || receive_reading(&readings), |got| got.len() >= 10);
    assert_eq!(fusion_commands.dynamic_config().number_of_subscribers(), 4);
    for p in [driver, fusion, sim].into_iter().chain(recorders) {
        assert!(p.terminate().success());
    }
}
