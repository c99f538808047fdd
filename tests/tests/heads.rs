//! End to end: heads other than the paper's stepper — a hobby sketch whose no-echo value is 255
//! and a continuous 360° head, played by the test on a pseudo-terminal, and the simulator's hobby
//! "Arduino radar" sketch — through the real driver (and fusion), as their owners would run them.
#![allow(clippy::unwrap_used, clippy::expect_used)] // helpers outside #[test] fns; a panic is a failure

use std::io::Write;
use std::time::Duration;

use sonar_common::ipc::{LinkState, Reading, flags};
use sonar_e2e::{
    FakeSerial, GridSnapshot, Sandbox, check_ok, collect_until, driver_status_subscriber,
    features_subscriber, fusion_status_subscriber, grid_subscriber, path_str, readings_subscriber,
    receive_reading, room, room_features, wait_for_status,
};

/// A hobby sketch on a fake serial port: writes its records, one block at a time.
struct HobbyHead {
    serial: FakeSerial,
}

impl HobbyHead {
    fn new() -> Self {
        Self {
            serial: FakeSerial::open(),
        }
    }

    /// `angle,distance.` records, as the HowToMechatronics sketch writes them (no newline).
    fn send(&mut self, records: &[(i32, u32)]) {
        let text: String = records.iter().map(|(a, d)| format!("{a},{d}.")).collect();
        self.serial.master.write_all(text.as_bytes()).unwrap();
    }
}

/// Readings of a hobby head that repeats `records` until `done` (the driver drops what the port
/// held before it opened it, so the test cannot tell when its first block is read).
fn readings_while_repeating(
    sandbox: &Sandbox,
    head: &mut HobbyHead,
    records: &[(i32, u32)],
    done: impl Fn(&[Reading]) -> bool,
) -> Vec<Reading> {
    let node = sandbox.node("test-consumer");
    let sub = readings_subscriber(&node);
    let mut next_block = std::time::Instant::now();
    collect_until(
        &node,
        || {
            if std::time::Instant::now() >= next_block {
                head.send(records);
                next_block += Duration::from_millis(200);
            }
            receive_reading(&sub)
        },
        |got| done(got),
    )
}

#[test]
fn a_hobby_sketchs_255_is_no_echo_with_the_setting() {
    let sandbox = Sandbox::new("hobby255");
    let mut head = HobbyHead::new();
    let _driver = sandbox.spawn(
        "sonar-driver",
        &[
            "--port",
            &head.serial.slave_path,
            "--dialect",
            "hobby",
            "--no-echo",
            "255",
        ],
    );
    // The servo's 90° is straight ahead (the default offset of −90°).
    let records = [(88, 120), (89, 255), (90, 254), (91, 0)];
    let readings = readings_while_repeating(&sandbox, &mut head, &records, |got| got.len() >= 12);
    let at = |deg: f32| {
        readings
            .iter()
            .filter(move |r| r.angle_deg == deg)
            .collect::<Vec<_>>()
    };
    for r in at(-1.0) {
        assert!(r.has(flags::NO_ECHO), "255 is no echo: {r:?}");
        assert!(!r.is_valid_range(), "{r:?}");
    }
    for r in at(1.0) {
        assert!(r.has(flags::NO_ECHO), "0 is no echo: {r:?}");
    }
    for (deg, m) in [(-2.0, 1.20), (0.0, 2.54)] {
        let got = at(deg);
        assert!(!got.is_empty(), "readings at {deg}°: {readings:?}");
        for r in got {
            assert!(r.is_valid_range(), "{r:?}");
            assert!((r.distance_m - m).abs() < 2e-3, "{r:?}");
        }
    }
}

/// A motor that turns a full circle, pinging every 3°, writing its angles 0…357 (no offset): the
/// real driver and fusion keep every reading of a revolution in the radar, each in a bin of its
/// own, and count one sweep per revolution.
#[test]
fn a_continuous_head_at_3_degrees_keeps_every_reading_in_the_radar() {
    let sandbox = Sandbox::new("turn360");
    let mut head = HobbyHead::new();
    let node = sandbox.node("test-radar");
    let radar = sonar_common::ipc::radar_service(&node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    let _driver = sandbox.spawn(
        "sonar-driver",
        &[
            "--port",
            &head.serial.slave_path,
            "--dialect",
            "hobby",
            "--hobby-angle-offset",
            "0",
        ],
    );
    let fusion = sandbox.spawn("sonar-fusion", &["--no-persist"]);
    let fusion_status = fusion_status_subscriber(&node);
    // Each bearing its own distance, so a reading in the wrong bin shows.
    let distance_cm = |k: i32| 60 + 2 * k as u32;
    let revolution: Vec<(i32, u32)> = (0..120).map(|k| (3 * k, distance_cm(k))).collect();
    let readings = readings_while_repeating(&sandbox, &mut head, &revolution, |got| {
        got.iter()
            .map(|r| r.sweep_id)
            .collect::<std::collections::BTreeSet<_>>()
            .len()
            >= 4
    });

    // Whole revolutions (not the first, which may have begun mid-turn): one sweep each.
    let first = readings[0].sweep_id;
    let last = readings.last().unwrap().sweep_id;
    for sweep in first + 1..last {
        let of: Vec<&Reading> = readings.iter().filter(|r| r.sweep_id == sweep).collect();
        assert_eq!(of.len(), 120, "sweep {sweep} is one revolution");
        assert!(of.iter().all(|r| r.direction == 1), "{of:?}");
    }

    let latest = collect_until(
        &node,
        || radar.receive().unwrap().map(|s| *s.payload()),
        |got| {
            got.last().is_some_and(|r| {
                r.bin_count == 120 && r.distances_m[..120].iter().all(|d| d.is_finite())
            })
        },
    );
    let r = latest.last().unwrap();
    assert_eq!(r.bin_width_deg, 3.0, "{r:?}");
    for k in 0..120 {
        let bin = ((3.0 * k as f32 - r.first_bin_deg) / 3.0)
            .round()
            .rem_euclid(120.0) as usize;
        let want = distance_cm(k) as f32 / 100.0;
        assert!(
            (r.distances_m[bin] - want).abs() < 2e-3,
            "{}° in bin {bin}: {} m, sent {want} m",
            3 * k,
            r.distances_m[bin]
        );
    }

    // One range per angle is one ping on its axis for the features: no reading is skipped.
    let status = wait_for_status(&node, &fusion_status, |s| s.readings_fused >= 240);
    assert_eq!(status.feature_readings_skipped, 0, "{status:?}");
    let (exit, stderr) = fusion.terminate_with_stderr();
    assert!(exit.success(), "{stderr}");
    assert!(
        !stderr.contains("give no walls, corners or posts"),
        "{stderr}"
    );
}

/// The hobby "Arduino radar" sketch (`sonar-sim --dialect hobby`: a servo 15° → 165° and back,
/// one whole-centimetre range per degree, no raw pings) in the room with a post that every head
/// maps (`sonar_e2e::room`), through the real driver and fusion: a grid, and on `sonar/features`
/// the wall ahead, the two corners ahead and the post, where they truly are and nothing else.
/// The side walls' normals (±90°) lie outside its ±75°.
#[test]
fn a_hobby_sketch_maps_the_rooms_walls_corners_and_post() {
    let sandbox = Sandbox::new("hobby_room");
    let node = sandbox.node("test-hobby-room");
    let features = features_subscriber(&node);
    let grid = grid_subscriber(&node);
    let scene = room::scene();
    let (_sim, pty) = sandbox.spawn_sim(&["--scene", &scene, "--speed", "5", "--dialect", "hobby"]);
    let _driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--dialect", "hobby"]);
    let _fusion = sandbox.spawn("sonar-fusion", &["--no-persist"]);
    let expected = room::Expected {
        step_deg: 1.0,
        walls_deg: vec![0.0],
        corners_deg: vec![45.0, -45.0],
    };
    room_features(&node, &features, &expected, 2, 6);
    let map = latest_grid(&node, &grid);
    // The wall ahead beside the post (which hides it within ±16°) and the corners ahead, within
    // 6 cm.
    for (x, y) in [(1.2, -0.35), (1.2, 0.35), (1.2, 1.2), (1.2, -1.2)] {
        let p = map.max_near(x, y, 3).unwrap_or(0.5);
        assert!(p > 0.5, "wall at ({x}, {y}) has p = {p}");
    }
    let p = map.max_near(0.5, 0.3, 1).expect("observed");
    assert!(p < 0.5, "free space ahead has p = {p}");
}

/// The latest grid snapshot once 200 readings are fused.
fn latest_grid(
    node: &iceoryx2::prelude::Node<iceoryx2::service::ipc::Service>,
    grid: &iceoryx2::port::subscriber::Subscriber<
        iceoryx2::service::ipc::Service,
        [u8],
        sonar_common::ipc::GridHeader,
    >,
) -> GridSnapshot {
    let snapshots = collect_until(
        node,
        || {
            grid.receive().unwrap().map(|s| GridSnapshot {
                header: *s.user_header(),
                cells: s.payload().to_vec(),
            })
        },
        |got| got.last().is_some_and(|s| s.header.readings_fused >= 200),
    );
    snapshots.into_iter().last().unwrap()
}

/// Three revolutions of a continuous head at 3° in the room with a post every head maps
/// (`sonar_e2e::room`), as a hobby sensor reports them: the first echo of the simulator's echo
/// model in whole cm, 255 for no echo now and then: (angle, range) rows.
fn room_log() -> Vec<(i32, u32)> {
    let scene = sonar_sim::Scene::load(&room::scene_path()).unwrap();
    let model =
        sonar_sim::EchoModel::new(scene, sonar_common::sensor::SensorConfig::default(), 1).unwrap();
    (0..360)
        .map(|k| {
            let deg = 3 * (k % 120);
            let cm = model
                .first_echo(f64::from(deg))
                .map_or(255, |e| (e.range_m * 100.0).round() as u32);
            (deg, if k % 17 == 5 { 255 } else { cm })
        })
        .collect()
}

/// The map `sonar-export` writes as NumPy bytes (`--out` stem in `dir`, then any arguments).
fn export_npy(sandbox: &Sandbox, dir: &std::path::Path, stem: &str, args: &[&str]) -> Vec<u8> {
    let out = dir.join(stem);
    let mut all = vec!["--format", "npy", "--out", path_str(&out)];
    all.extend_from_slice(args);
    check_ok("sonar-export", &sandbox.run("sonar-export", &all));
    std::fs::read(dir.join(format!("{stem}.npy"))).unwrap()
}

/// Cells of a `.npy` map (NumPy 1.0, `<f4`) above and below p = 0.5 (unknown ones are NaN).
fn occupied_and_free(npy: &[u8]) -> (usize, usize) {
    let header = usize::from(u16::from_le_bytes([npy[8], npy[9]]));
    let p = npy[10 + header..]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    p.fold((0, 0), |(o, f), p| {
        (o + usize::from(p > 0.5), f + usize::from(p < 0.5))
    })
}

/// A CSV log brought in by `sonar-import` gives, exported or replayed, the very map (cell for cell)
/// that the same readings give live through the driver (a continuous 360° head writing them) and
/// fusion; live, that head's revolutions give the room's walls, corners and post. The replay at
/// `--speed max` (1 000 messages a second) outruns a debug-build fusion beside busy loops: it
/// keeps what it has not fused in its backlog (before, its buffer of 256 was all it had: 1 of 6
/// runs beside five busy loops never fused all 360 replayed readings and the export gave up; 0 of
/// 15 after).
#[test]
fn an_imported_log_maps_as_the_same_readings_fed_live() {
    let sandbox = Sandbox::new("import");
    let dir = std::env::temp_dir().join(format!("sonar_import_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log = room_log();
    let csv: String = std::iter::once("angle,range\n".to_owned())
        .chain(log.iter().map(|(a, d)| format!("{a},{d}\n")))
        .collect();
    let csv_path = dir.join("room.csv");
    std::fs::write(&csv_path, csv).unwrap();
    let mcap = dir.join("room.mcap");
    check_ok(
        "sonar-import",
        &sandbox.run(
            "sonar-import",
            &[path_str(&csv_path), path_str(&mcap), "--no-echo", "255"],
        ),
    );
    let imported = export_npy(
        &sandbox,
        &dir,
        "imported",
        &["--from-recording", path_str(&mcap)],
    );

    // Live: a head writes the same rows to the driver, the fusion maps them.
    let node = sandbox.node("test-live");
    let status = driver_status_subscriber(&node);
    let mut head = HobbyHead::new();
    let driver = sandbox.spawn(
        "sonar-driver",
        &[
            "--port",
            &head.serial.slave_path,
            "--dialect",
            "hobby",
            "--hobby-angle-offset",
            "0",
            "--no-echo",
            "255",
        ],
    );
    let fusion = sandbox.spawn("sonar-fusion", &["--no-persist"]);
    let features = features_subscriber(&node);
    wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Connected as u32
    });
    sonar_e2e::wait_until(&node, "the fusion to subscribe", || {
        sonar_e2e::readings_subscribers(&node) >= 1
    });
    // A few rows at a time, so no subscriber's buffer overflows.
    for rows in log.chunks(20) {
        head.send(rows);
        std::thread::sleep(Duration::from_millis(20));
    }
    let wait = log.len().to_string();
    let live = export_npy(
        &sandbox,
        &dir,
        "live",
        &["--wait-readings", &wait, "--timeout", "60"],
    );
    // The continuous head's revolutions give every wall, every corner and the post (the third
    // revolution is merged when the head has gone quiet for 2 s).
    let expected = room::Expected {
        step_deg: 3.0,
        walls_deg: vec![0.0, 90.0, 180.0, -90.0],
        corners_deg: vec![45.0, 135.0, -135.0, -45.0],
    };
    room_features(&node, &features, &expected, 2, 3);
    assert!(fusion.terminate().success());
    assert!(driver.terminate().success());
    let (occupied, free) = occupied_and_free(&imported);
    assert!(
        occupied > 100 && free > 1000,
        "walls and open floor: {occupied} / {free}"
    );
    assert_eq!(imported.len(), live.len());
    let differ = imported.iter().zip(&live).filter(|(a, b)| a != b).count();
    assert_eq!(differ, 0, "bytes of the map that differ from the live one");

    // Replayed into a pipeline like any recording: the same map again.
    let replay_box = Sandbox::new("import_replay");
    let fusion = replay_box.spawn("sonar-fusion", &["--no-persist"]);
    check_ok(
        "sonar-replay",
        &replay_box.run(
            "sonar-replay",
            &[
                path_str(&mcap),
                "--speed",
                "max",
                "--wait-for-subscribers",
                "1",
                "--no-progress",
            ],
        ),
    );
    let replayed = export_npy(
        &replay_box,
        &dir,
        "replayed",
        &["--wait-readings", &wait, "--timeout", "60"],
    );
    assert!(fusion.terminate().success());
    assert_eq!(replayed, live, "the replayed map");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A malformed row stops the import with its line number, and nothing is left behind.
#[test]
fn a_malformed_log_is_refused_with_its_line_and_writes_nothing() {
    let sandbox = Sandbox::new("import_bad");
    let dir = std::env::temp_dir().join(format!("sonar_import_bad_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv_path = dir.join("bad.csv");
    std::fs::write(&csv_path, "# my log\n0,100\n3,1O0\n6,100\n").unwrap();
    let mcap = dir.join("bad.mcap");
    let out = sandbox.run("sonar-import", &[path_str(&csv_path), path_str(&mcap)]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("line 3") && stderr.contains("\"1O0\" is not a number"),
        "{stderr}"
    );
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(
        left,
        [std::ffi::OsString::from("bad.csv")],
        "nothing written"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
