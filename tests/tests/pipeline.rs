//! End to end: the simulator on a pseudo-terminal, the driver as a separate process, and the test as
//! an iceoryx2 consumer in its own namespace.
#![allow(clippy::unwrap_used, clippy::expect_used)] // helpers outside #[test] fns; a panic is a failure

use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::time::{Duration, Instant};

use nalgebra::{Isometry2, Vector2};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use sonar_common::ipc::{
    self, FusionCommand, FusionCommandKind, GridHeader, LinkState, Reading, ScanCommand,
    ScanCommandKind, ScanMode, feature_kind, flags,
};
use sonar_common::protocol::{
    DeviceMessage, DeviceState, Direction, ErrorCode, PROTOCOL_VERSION, WireReading, encode_device,
};
use sonar_e2e::{
    FakeSerial, GridSnapshot, PATIENCE, Sandbox, back_wall_seen_at, check_ok, collect_until,
    collect_with_truth, corridor_grid_config, drive_drifting_corridor, driver_status_subscriber,
    features_subscriber, grid_subscriber, localized_pose_subscriber, readings_subscriber,
    readings_subscribers, receive_reading, room, room_features, send_scan_command,
    sweep_ends_subscriber, true_pose_subscriber, wait_for_status, wait_until,
};

/// The test plays the microcontroller on a pseudo-terminal of its own.
struct FakeHead {
    serial: FakeSerial,
    heard: String,
}

impl FakeHead {
    fn new() -> Self {
        Self {
            serial: FakeSerial::open(),
            heard: String::new(),
        }
    }

    /// Reads what the driver sends until `text` has come `times` times in all.
    fn hear(&mut self, text: &str, times: usize) {
        let deadline = Instant::now() + PATIENCE;
        while self.heard.matches(text).count() < times {
            assert!(
                Instant::now() < deadline,
                "waited for {times}× {text:?}, heard {:?}",
                self.heard
            );
            let mut fds = [PollFd::new(self.serial.master.as_fd(), PollFlags::POLLIN)];
            if poll(&mut fds, PollTimeout::from(100u16)).unwrap() > 0 {
                let mut buf = [0u8; 256];
                let n = self.serial.master.read(&mut buf).unwrap();
                self.heard.push_str(&String::from_utf8_lossy(&buf[..n]));
            }
        }
    }

    /// The driver's first handshake answered as head `head_id`, up to its full scan.
    fn handshake(&mut self, head_id: &str) {
        self.hear("$HELLO,2*", 1);
        self.say(&hello_from(head_id));
        self.hear("$SCAN,FULL*", 1);
    }

    fn say(&mut self, msg: &DeviceMessage) {
        self.serial
            .master
            .write_all(encode_device(msg, PROTOCOL_VERSION).as_bytes())
            .unwrap();
    }
}

fn hello_from(head_id: &str) -> DeviceMessage {
    DeviceMessage::Hello {
        version: 2,
        firmware: "test-device".into(),
        head_id: head_id.into(),
        step_cdeg: 150,
        pings_per_reading: 4,
        min_cdeg: -15000,
        max_cdeg: 15000,
    }
}

fn sweeps_of(readings: &[Reading], sweep: u32) -> Vec<Reading> {
    readings
        .iter()
        .filter(|r| r.sweep_id == sweep)
        .copied()
        .collect()
}

#[test]
fn full_sweeps_of_the_room_stream_over_shared_memory() {
    let sandbox = Sandbox::new("room");
    let node = sandbox.node("test-consumer");
    // Subscribe before the driver starts, so not one reading is missed. At `--speed max` the
    // pipeline moves ~90k readings/s, which outruns any subscriber buffer while a busy CI machine
    // deschedules this test; 100× real time (~500 readings/s) leaves it half a second of slack.
    let sub = readings_subscriber(&node);
    let (sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "100", "--seed", "7"]);
    let driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);

    let readings = collect_until(
        &node,
        || receive_reading(&sub),
        |got| got.iter().any(|r| r.sweep_id == 3),
    );

    // Sequence numbers come without gaps.
    for (i, r) in readings.iter().enumerate() {
        assert_eq!(r.seq, i as u64);
        assert_eq!(r.layout_version, ipc::LAYOUT_VERSION);
        assert_eq!(r.scan_mode(), ScanMode::Full);
    }
    // Sweep 1 goes counter-clockwise from the min limit, sweep 2 back: 50 readings 6° apart each.
    for (sweep, dir) in [(1, 1i8), (2, -1i8)] {
        let s = sweeps_of(&readings, sweep);
        assert_eq!(s.len(), 50, "sweep {sweep}");
        let first = if dir > 0 { -147.0 } else { 147.0 };
        for (k, r) in s.iter().enumerate() {
            assert_eq!(r.direction, dir);
            let expected = first + f32::from(dir) * 6.0 * k as f32;
            assert!((r.angle_deg - expected).abs() < 1e-3, "{r:?}");
            assert_eq!(r.ping_count, 4);
        }
    }

    // The 2.4 m square room, sensor at its centre: walls 1.20 m away along the axes, corners 1.70 m
    // away on the diagonals, nothing nearer than a wall or farther than a corner.
    let both: Vec<Reading> = readings
        .iter()
        .filter(|r| r.sweep_id <= 2)
        .copied()
        .collect();
    let valid: Vec<&Reading> = both.iter().filter(|r| r.is_valid_range()).collect();
    assert!(valid.len() >= 80, "only {} valid readings", valid.len());
    for r in &valid {
        assert!(
            (1.16..=1.75).contains(&r.distance_m),
            "reading outside the room: {r:?}"
        );
    }
    let near = |a: f32, targets: &[f32], tol: f32| targets.iter().any(|t| (a - t).abs() <= tol);
    let axis_readings: Vec<&&Reading> = valid
        .iter()
        .filter(|r| near(r.angle_deg, &[-90.0, 0.0, 90.0], 10.0))
        .collect();
    assert!(axis_readings.len() >= 12);
    for r in axis_readings {
        assert!((r.distance_m - 1.20).abs() <= 0.03, "wall reading {r:?}");
    }
    let diagonal: Vec<&&Reading> = valid
        .iter()
        .filter(|r| near(r.angle_deg, &[-135.0, -45.0, 45.0, 135.0], 3.0))
        .collect();
    assert!(diagonal.len() >= 6);
    for r in diagonal {
        assert!((r.distance_m - 1.697).abs() <= 0.05, "corner reading {r:?}");
    }

    assert!(driver.terminate().success(), "driver did not exit cleanly");
    assert!(sim.terminate().success(), "simulator did not exit cleanly");
    drop(sub);
    drop(node);
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}

#[test]
fn a_missing_port_is_a_clear_error() {
    let sandbox = Sandbox::new("missing");
    let driver = sandbox.spawn("sonar-driver", &["--port", "/dev/ttyDOESNOTEXIST"]);
    let (status, stderr) = driver.wait_exit();
    assert!(!status.success());
    assert!(
        stderr.contains("/dev/ttyDOESNOTEXIST does not exist"),
        "{stderr}"
    );
    // A file, or a device that is not a terminal.
    let file = std::env::temp_dir().join(format!("sonar_t{}_not_a_port", std::process::id()));
    std::fs::write(&file, b"").unwrap();
    for path in [file.to_str().unwrap(), "/dev/null"] {
        let (status, stderr) = sandbox.spawn("sonar-driver", &["--port", path]).wait_exit();
        assert!(!status.success());
        assert!(stderr.contains("is not a serial port"), "{stderr}");
    }
    let _ = std::fs::remove_file(&file);
}

#[test]
fn a_busy_port_is_a_clear_error() {
    let sandbox = Sandbox::new("busy");
    let node = sandbox.node("test-consumer");
    let status = driver_status_subscriber(&node);
    let (_sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "max"]);
    let _first = sandbox.spawn("sonar-driver", &["--port", &pty, "--scan", "none"]);
    wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Connected as u32
    });

    let second = sandbox.spawn("sonar-driver", &["--port", &pty]);
    let (exit, stderr) = second.wait_exit();
    assert!(!exit.success());
    assert!(stderr.contains("cannot open serial port"), "{stderr}");
    assert!(stderr.contains("busy"), "{stderr}");
}

#[test]
fn a_scan_command_from_any_process_starts_a_local_scan() {
    let sandbox = Sandbox::new("local");
    let node = sandbox.node("test-commander");
    let sub = readings_subscriber(&node);
    let status = driver_status_subscriber(&node);
    let (_sim, pty) = sandbox.spawn_sim(&["--scene", "obstacle", "--speed", "max"]);
    let _driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--scan", "none"]);
    wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Connected as u32
    });

    let _commands = send_scan_command(
        &node,
        ScanCommand::new(ScanCommandKind::LocalScan, -30.0, 30.0),
    );

    let readings = collect_until(&node, || receive_reading(&sub), |got| got.len() >= 40);
    let centres: Vec<f32> = (0..10).map(|k| -27.0 + 6.0 * k as f32).collect();
    for r in &readings {
        assert_eq!(r.scan_mode(), ScanMode::Local);
        assert!(
            centres.iter().any(|c| (r.angle_deg - c).abs() < 1e-3),
            "reading outside the segment: {r:?}"
        );
    }
    let directions: std::collections::BTreeSet<i8> = readings.iter().map(|r| r.direction).collect();
    assert_eq!(directions.len(), 2, "a local scan goes back and forth");
    // The post 1 m ahead is seen straight ahead; the wall 2 m ahead beside it.
    let ahead = readings
        .iter()
        .find(|r| r.angle_deg.abs() < 4.0 && r.is_valid_range())
        .expect("a valid reading straight ahead");
    assert!((ahead.distance_m - 0.975).abs() < 0.05, "{ahead:?}");
    let beside = readings
        .iter()
        .find(|r| (r.angle_deg - 27.0).abs() < 1e-3 && r.is_valid_range())
        .expect("a valid reading at 27°");
    assert!((beside.distance_m - 2.0).abs() < 0.05, "{beside:?}");
}

#[test]
fn the_hobby_radar_dialect_works_unchanged() {
    let sandbox = Sandbox::new("hobby");
    let node = sandbox.node("test-consumer");
    let sub = readings_subscriber(&node);
    let (_sim, pty) =
        sandbox.spawn_sim(&["--scene", "room", "--speed", "100", "--dialect", "hobby"]);
    let _driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--dialect", "hobby"]);

    let readings = collect_until(&node, || receive_reading(&sub), |got| got.len() >= 200);
    // Past the first (possibly partial) record, angles step by one degree within the servo's
    // 15°..165°, shifted so that 90° is straight ahead.
    for pair in readings[1..].windows(2) {
        let step = pair[1].angle_deg - pair[0].angle_deg;
        assert!(step.abs() <= 1.0 + 1e-3, "{pair:?}");
    }
    for r in &readings[1..] {
        assert!((-75.0..=75.0).contains(&r.angle_deg), "{r:?}");
        assert!(r.has(flags::NO_RAW_PINGS));
        assert_eq!(r.ping_count, 1);
    }
    let straight = readings[1..]
        .iter()
        .find(|r| r.angle_deg == 0.0)
        .expect("a reading straight ahead");
    // Integer centimetres: the wall 1.20 m ahead.
    assert!((straight.distance_m - 1.20).abs() <= 0.03, "{straight:?}");
    let sweeps: std::collections::BTreeSet<u32> = readings.iter().map(|r| r.sweep_id).collect();
    assert!(sweeps.len() >= 2, "direction reversals start new sweeps");
}

/// A head with version-1 firmware (XOR checksum, no identity) still works behind `--protocol 1`;
/// the default version-2 driver does not mistake it for a version-2 head.
#[test]
fn version_1_heads_work_behind_the_option() {
    let sandbox = Sandbox::new("v1");
    let node = sandbox.node("test-consumer");
    let sub = readings_subscriber(&node);
    let (_sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "100", "--protocol", "1"]);
    let driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--protocol", "1"]);
    let readings = collect_until(&node, || receive_reading(&sub), |got| got.len() >= 10);
    assert!(readings.iter().all(|r| r.ping_count == 4), "{readings:?}");
    assert!(driver.terminate().success());
    while receive_reading(&sub).is_some() {}

    let (_sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "100", "--protocol", "1"]);
    let status = driver_status_subscriber(&node);
    let _driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--max-backoff", "0.5"]);
    // Each v2 HELLO is answered in v1 framing, which the v2 driver rejects: it never connects.
    let s = wait_for_status(&node, &status, |s| s.lines_rejected >= 2);
    assert_ne!(s.link_state, LinkState::Connected as u32);
    assert!(receive_reading(&sub).is_none());
}

/// The test plays the microcontroller on a pseudo-terminal of its own and sends the driver every
/// kind of damage a serial line does.
#[test]
fn garbage_on_the_line_is_counted_and_never_published() {
    let sandbox = Sandbox::new("garbage");
    let node = sandbox.node("test-device");
    let sub = readings_subscriber(&node);
    let status = driver_status_subscriber(&node);
    let mut head = FakeHead::new();
    let _driver = sandbox.spawn(
        "sonar-driver",
        &["--port", &head.serial.slave_path, "--scan", "none"],
    );

    // Answer the handshake.
    head.hear("$HELLO,2*", 1);
    head.say(&hello_from("TEST-HEAD"));
    wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Connected as u32
    });

    let t = 5831; // ≈ 1.00 m at 20 °C
    let good = |seq: u32, angle_cdeg: i32| {
        encode_device(
            &DeviceMessage::Reading(WireReading {
                seq,
                time_ms: 1000 + seq,
                sweep: 1,
                direction: Direction::Ccw,
                angle_cdeg,
                ping_count: 4,
                echo_us: [t, t, t, t, 0, 0, 0, 0],
            }),
            PROTOCOL_VERSION,
        )
    };
    // Two bits flipped in the same position of two digits: version 1's XOR passed these.
    let double_flip = {
        let mut line = good(93, 9900).into_bytes();
        line[7] ^= 0x04;
        line[12] ^= 0x04;
        String::from_utf8(line).unwrap()
    };
    let mut stream = Vec::new();
    stream.extend_from_slice(b"hello world\n"); // no frame
    stream.extend_from_slice(good(90, 9900).replace("RD,90", "RD,91").as_bytes()); // bad checksum
    stream.extend_from_slice(&good(92, 9900).as_bytes()[..20]); // truncated ...
    stream.push(b'\n'); // ... by a line break
    stream.extend_from_slice(&[b'x'; 500]); // overlong
    stream.push(b'\n');
    stream.extend_from_slice(b"\x00\xff\xfe$RD*\n"); // binary noise
    stream.extend_from_slice(good(0, -300).as_bytes());
    stream.extend_from_slice(b"$RD,1,2,3,+,100,1*0000\n"); // bad checksum, wrong fields
    stream.extend_from_slice(double_flip.as_bytes());
    stream.extend_from_slice(good(1, 300).as_bytes());
    head.serial.master.write_all(&stream).unwrap();

    let readings = collect_until(&node, || receive_reading(&sub), |got| got.len() >= 2);
    assert_eq!(readings[0].device_seq, 0);
    assert_eq!(readings[0].angle_deg, -3.0);
    assert_eq!(readings[1].device_seq, 1);
    assert_eq!(readings[1].angle_deg, 3.0);
    for r in &readings {
        assert!((r.distance_m - 1.0).abs() < 0.005, "{r:?}");
        assert_eq!(r.flags, 0);
    }
    let last = wait_for_status(&node, &status, |s| s.lines_rejected >= 7);
    assert_eq!(last.lines_rejected, 7);
    assert_eq!(last.lines_ok, 3); // HELLO and two readings
    // Nothing else was published.
    std::thread::sleep(Duration::from_millis(200));
    assert!(receive_reading(&sub).is_none());
}

/// A head that announces itself while connected was reset: the driver sends its scan again. A
/// different head on the same port is refused, and never commanded.
#[test]
fn a_reset_head_is_sent_its_scan_again_and_a_different_head_is_refused() {
    let sandbox = Sandbox::new("reset");
    let node = sandbox.node("test-device");
    let status = driver_status_subscriber(&node);
    let mut head = FakeHead::new();
    let _driver = sandbox.spawn(
        "sonar-driver",
        &[
            "--port",
            &head.serial.slave_path,
            "--scan",
            "full",
            "--max-backoff",
            "0.5",
        ],
    );
    head.handshake("HEAD-A");
    wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Connected as u32
    });

    head.say(&hello_from("HEAD-A"));
    head.hear("$SCAN,FULL*", 2);
    let s = wait_for_status(&node, &status, |s| s.head_resets == 1);
    assert_eq!(s.link_state, LinkState::Connected as u32);

    head.say(&hello_from("HEAD-B"));
    wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Refused as u32
    });
    // The driver tries the port again and asks who is there; it never commands the stranger.
    head.hear("$HELLO,2*", 2);
    head.say(&hello_from("HEAD-B"));
    std::thread::sleep(Duration::from_millis(500));
    head.hear("$SCAN,FULL*", 2);
    assert_eq!(head.heard.matches("$SCAN,").count(), 2, "{}", head.heard);
    // Its own head comes back on the port: accepted, scanning again.
    head.hear("$HELLO,2*", 3);
    head.say(&hello_from("HEAD-A"));
    head.hear("$SCAN,FULL*", 3);
    wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Connected as u32
    });
}

/// A sweep the head reports ended is published whole at once: the driver passes the head's
/// `SWP,END` on (`sonar/sweep_ends`) and the fusion places the sweep's last region of constant
/// depth then, not when the next sweep's first reading comes (here none comes at all).
#[test]
fn a_sweep_the_head_reports_ended_is_mapped_whole_without_waiting_for_the_next() {
    let sandbox = Sandbox::new("sweepend");
    let node = sandbox.node("test-device");
    let status = driver_status_subscriber(&node);
    let grid = grid_subscriber(&node);
    let ends = sweep_ends_subscriber(&node);
    let mut head = FakeHead::new();
    let _driver = sandbox.spawn(
        "sonar-driver",
        &["--port", &head.serial.slave_path, "--scan", "full"],
    );
    let _fusion = sandbox.spawn("sonar-fusion", &["--no-persist"]);
    head.handshake("TEST-HEAD");
    wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Connected as u32
    });
    wait_until(&node, "the fusion subscribed to the readings", || {
        readings_subscribers(&node) >= 1
    });

    // A wall 1 m ahead heard from -30° to +30°: one region of constant depth, open until
    // something ends it.
    head.say(&DeviceMessage::SweepStart {
        sweep: 7,
        direction: Direction::Ccw,
        mode: sonar_common::protocol::WireScanMode::Full,
        from_cdeg: -3000,
        to_cdeg: 3000,
    });
    let t = 5831; // ≈ 1.00 m at 20 °C
    for (seq, angle_cdeg) in (-3000..=3000).step_by(600).enumerate() {
        head.say(&DeviceMessage::Reading(WireReading {
            seq: seq as u32,
            time_ms: 1000 + 240 * seq as u32,
            sweep: 7,
            direction: Direction::Ccw,
            angle_cdeg,
            ping_count: 4,
            echo_us: [t, t + 3, t, t - 3, 0, 0, 0, 0],
        }));
    }
    let snapshot = |s: iceoryx2::sample::Sample<_, [u8], GridHeader>| GridSnapshot {
        header: *s.user_header(),
        cells: s.payload().to_vec(),
    };
    // The sweep's readings all fused, its last region still open.
    let open = collect_until(
        &node,
        || grid.receive().unwrap().map(snapshot),
        |got| got.last().is_some_and(|g| g.header.readings_fused == 11),
    );
    let open = open.last().unwrap();
    let foot_open = open.max_near(1.0, 0.0, 1).unwrap_or(0.5);

    head.say(&DeviceMessage::SweepEnd { sweep: 7 });
    let end = collect_until(
        &node,
        || ends.receive().unwrap().map(|s| *s.payload()),
        |got| !got.is_empty(),
    )[0];
    assert_eq!((end.sweep_id, end.last_seq), (7, 10), "{end:?}");
    // A snapshot of the same readings with the region placed: the wall's foot more certain.
    let whole = collect_until(
        &node,
        || grid.receive().unwrap().map(snapshot),
        |got| {
            got.last().is_some_and(|g| {
                g.header.seq > open.header.seq
                    && g.max_near(1.0, 0.0, 1).is_some_and(|p| p > foot_open)
            })
        },
    );
    let whole = whole.last().unwrap();
    assert_eq!(whole.header.readings_fused, 11, "{:?}", whole.header);
    assert!(
        whole.max_near(1.0, 0.0, 1).is_some_and(|p| p > 0.5),
        "the wall's foot is not occupied: {:?}",
        whole.header
    );
}

/// A command the head refuses (a segment outside its limits) reaches every consumer of the
/// driver's status, with the head's reason.
#[test]
fn a_refused_command_is_in_the_driver_status() {
    let sandbox = Sandbox::new("refused");
    let node = sandbox.node("test-consumer");
    let status = driver_status_subscriber(&node);
    let (_sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "100"]);
    // A scan outside the limits asked at run time, as the viewer or a script may (one given on
    // the command line stops the driver before it is sent: launcher.rs tests that).
    let _driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);
    wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Connected as u32
    });
    let _commands = send_scan_command(
        &node,
        ScanCommand::new(ScanCommandKind::LocalScan, 100.0, 200.0),
    );
    let s = wait_for_status(&node, &status, |s| s.device_errors >= 1);
    assert!(
        s.last_device_error().starts_with("RANGE: "),
        "{}",
        s.last_device_error()
    );
}

/// A head that stops talking is asked for its status; one that answers idle while it should scan
/// is sent the scan again; one that does not answer at all is handshaken again, and resumes.
#[test]
fn a_silent_head_is_probed_then_handshaken_again_and_resumes() {
    let sandbox = Sandbox::new("silence");
    let node = sandbox.node("test-device");
    let status = driver_status_subscriber(&node);
    let mut head = FakeHead::new();
    let _driver = sandbox.spawn(
        "sonar-driver",
        &[
            "--port",
            &head.serial.slave_path,
            "--scan",
            "full",
            "--silence-timeout",
            "0.5",
            "--max-backoff",
            "0.5",
        ],
    );
    head.handshake("HEAD-A");

    // Quiet: the driver asks; the head says it is idle (it lost the command): the scan again.
    head.hear("$STATUS*", 1);
    head.say(&DeviceMessage::Status {
        state: sonar_common::protocol::DeviceState::Idle,
        angle_cdeg: -15000,
        direction: Direction::Ccw,
        sweep: 0,
    });
    head.hear("$SCAN,FULL*", 2);

    // Silent even to STATUS: counted, the port opened again, the handshake repeated.
    head.hear("$STATUS*", 2);
    let s = wait_for_status(&node, &status, |s| s.silences == 1);
    assert_eq!(s.head_id(), "HEAD-A");
    head.hear("$HELLO,2*", 2);
    head.say(&hello_from("HEAD-A"));
    head.hear("$SCAN,FULL*", 3);
    let s = wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Connected as u32 && s.reconnects >= 1
    });
    assert_eq!(s.silences, 1);
}

/// Issue 24: a head that stopped on a hardware fault (`ERR,HARDWARE`, then `ST,FAULT`) gets no
/// further scan — not on the silence probe, not after it reset itself, not when a scan is asked
/// for — until a person acknowledges with the reset command: then `RESET` and the scan.
#[test]
fn a_head_stopped_on_a_hardware_fault_gets_no_scan_until_a_reset() {
    let sandbox = Sandbox::new("hw_fault");
    let node = sandbox.node("test-device");
    let status = driver_status_subscriber(&node);
    let mut head = FakeHead::new();
    let _driver = sandbox.spawn(
        "sonar-driver",
        &[
            "--port",
            &head.serial.slave_path,
            "--scan",
            "full",
            "--silence-timeout",
            "0.5",
        ],
    );
    let fault = DeviceMessage::Status {
        state: DeviceState::Fault,
        angle_cdeg: -15000,
        direction: Direction::Cw,
        sweep: 0,
    };
    head.handshake("HEAD-A");
    head.say(&DeviceMessage::Error {
        code: ErrorCode::Hardware,
        text: "MIN switch not found in 315 deg of homing (dead switch? wiring?)".into(),
    });
    // The driver asks at once whether the head stopped.
    head.hear("$STATUS*", 1);
    head.say(&fault);
    let s = wait_for_status(&node, &status, |s| s.head_fault == 1);
    assert_eq!(s.hardware_faults, 1);
    assert_eq!(
        s.last_device_error(),
        "HARDWARE: MIN switch not found in 315 deg of homing (dead switch? wiring?)"
    );
    assert_eq!(s.link_state, LinkState::Connected as u32);
    // Quiet: probed, and told again that the head is stopped.
    for k in 2..=3 {
        head.hear("$STATUS*", k);
        head.say(&fault);
    }
    // A scan asked for by a user is kept, not sent.
    let _scan = send_scan_command(&node, ScanCommand::new(ScanCommandKind::FullScan, 0.0, 0.0));
    head.hear("$STATUS*", 4);
    // The head resets itself (its latch is gone: it answers idle): still no scan, the fault is
    // not acknowledged.
    head.say(&hello_from("HEAD-A"));
    wait_for_status(&node, &status, |s| s.head_resets == 1);
    for k in 5..=6 {
        head.hear("$STATUS*", k);
        head.say(&DeviceMessage::Status {
            state: DeviceState::Idle,
            angle_cdeg: -15000,
            direction: Direction::Ccw,
            sweep: 0,
        });
    }
    head.hear("$STATUS*", 7);
    assert_eq!(
        head.heard.matches("$SCAN").count(),
        1,
        "no scan after the fault: {:?}",
        head.heard
    );
    assert!(!head.heard.contains("$RESET"), "{:?}", head.heard);
    assert_eq!(wait_for_status(&node, &status, |_| true).head_fault, 1);

    // A person checked the head and resets it (`sonar reset-head`, as the viewer's R): RESET,
    // then the scan it should run.
    let out = sandbox.run("sonar", &["reset-head"]);
    let said = check_ok("sonar reset-head", &out);
    assert!(
        said.starts_with("reset sent: the head homes again"),
        "{said}"
    );
    head.hear("$RESET*", 1);
    head.hear("$SCAN,FULL*", 2);
    let at = head.heard.find("$RESET*").unwrap();
    assert!(
        head.heard[at..].contains("$SCAN,FULL*"),
        "RESET, then the scan"
    );
    let s = wait_for_status(&node, &status, |s| s.head_fault == 0);
    assert_eq!(s.hardware_faults, 1);
}

#[test]
fn the_driver_reconnects_when_the_port_comes_back() {
    let sandbox = Sandbox::new("reconnect");
    let link = sandbox.root.join("sonar-tty");
    let link_str = link.to_str().unwrap().to_owned();
    let node = sandbox.node("test-consumer");
    let sub = readings_subscriber(&node);
    let status = driver_status_subscriber(&node);
    // The same head comes back, so it keeps its identity.
    let sim_args = [
        "--scene",
        "room",
        "--speed",
        "100",
        "--link",
        &link_str,
        "--head-id",
        "HEAD-A",
    ];
    let (sim, _) = sandbox.spawn_sim(&sim_args);
    let _driver = sandbox.spawn(
        "sonar-driver",
        &[
            "--port",
            &link_str,
            "--scan",
            "full",
            "--max-backoff",
            "0.5",
        ],
    );
    let before = collect_until(&node, || receive_reading(&sub), |got| got.len() >= 3);

    assert!(sim.terminate().success());
    wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Disconnected as u32
    });
    // Whatever the old simulator sent is in by now; only the new one can send more.
    let stale: Vec<Reading> = std::iter::from_fn(|| receive_reading(&sub)).collect();
    let last_seq = stale.last().unwrap_or(&before[before.len() - 1]).seq;
    let (_sim, _) = sandbox.spawn_sim(&sim_args);
    let after = collect_until(&node, || receive_reading(&sub), |got| got.len() >= 3);
    assert_eq!(
        after[0].seq,
        last_seq + 1,
        "the sequence goes on without a gap"
    );
    let s = wait_for_status(&node, &status, |s| s.reconnects >= 1);
    assert_eq!(s.link_state, LinkState::Connected as u32);
}

/// A consumer in another language, written from docs/ipc.md alone, reads the driver's readings.
#[test]
fn a_python_consumer_reads_the_documented_layout() {
    let workspace = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let python = std::env::var_os("SONAR_PYTHON")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| workspace.join(".venv/bin/python3"));
    assert!(
        python.exists(),
        "{} missing: python3 -m venv .venv && .venv/bin/pip install 'iceoryx2==0.10.*' (.ci/run does)",
        python.display()
    );
    let sandbox = Sandbox::new("python");
    let node = sandbox.node("test-consumer");
    let status = driver_status_subscriber(&node);
    let (_sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "20"]);
    let _driver = sandbox.spawn("sonar-driver", &["--port", &pty]);
    wait_for_status(&node, &status, |s| {
        s.link_state == LinkState::Connected as u32
    });

    let output = std::process::Command::new(python)
        .arg(workspace.join("examples/python/print_readings.py"))
        .args(["--count", "5"])
        .env("SONAR_IOX_PREFIX", &sandbox.prefix)
        .env("SONAR_IOX_ROOT", &sandbox.root)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let lines: Vec<&str> = stdout
        .lines()
        .filter(|l| l.starts_with("reading "))
        .collect();
    assert_eq!(lines.len(), 5, "{stdout}");
    // Each line parses back: the angle is one of the 6° centres and the range lies in the room.
    for line in lines {
        let fields: Vec<&str> = line.split_whitespace().collect();
        let angle: f32 = fields[5].parse().unwrap();
        assert!(
            ((angle + 147.0) / 6.0 - ((angle + 147.0) / 6.0).round()).abs() < 1e-3,
            "{line}"
        );
        if fields[7] == "m" {
            let d: f32 = fields[6].parse().unwrap();
            assert!((1.16..=1.75).contains(&d), "{line}");
        }
    }
}

#[test]
fn the_fusion_engine_maps_the_room_walls_occupied_and_the_space_in_front_free() {
    let sandbox = Sandbox::new("fusion");
    let node = sandbox.node("test-map-consumer");
    let grid = ipc::grid_service(&node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    let radar = ipc::radar_service(&node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    let (sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "100", "--seed", "11"]);
    let driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);
    let fusion = sandbox.spawn("sonar-fusion", &["--max-snapshot-rate", "20"]);

    // Two full sweeps: the snapshot published at the end of the second one holds 100 readings.
    let snapshots = collect_until(
        &node,
        || {
            grid.receive().unwrap().map(|s| GridSnapshot {
                header: *s.user_header(),
                cells: s.payload().to_vec(),
            })
        },
        |got| got.last().is_some_and(|s| s.header.readings_fused >= 100),
    );
    let map = snapshots.last().unwrap();
    let h = &map.header;
    assert_eq!(h.layout_version, ipc::LAYOUT_VERSION);
    assert_eq!((h.width, h.height, h.resolution_m), (400, 400, 0.02));
    assert_eq!(map.cells.len(), 400 * 400);
    assert_eq!(h.preset, ipc::preset_code::RECOMMENDED);
    assert!(
        snapshots
            .windows(2)
            .all(|w| w[0].header.seq < w[1].header.seq),
        "snapshots in order"
    );
    // Occupied (p > 0.5), free (p < 0.5) and never observed (byte 255): a cell whose evidence
    // cancelled to p = 0.5 exactly (a weak echo taken back, `docs/fusion.md`) is none of them.
    let counted = h.occupied_cells + h.free_cells + h.unknown_cells;
    let byte_count = |byte: u8| map.cells.iter().filter(|&&c| c == byte).count() as u32;
    assert_eq!(
        h.unknown_cells,
        byte_count(ipc::CELL_UNKNOWN),
        "unknown cells"
    );
    assert!(
        counted <= 400 * 400 && 400 * 400 - counted <= byte_count(127),
        "counts cover the grid but for cells at p = 0.5: {counted} counted"
    );

    // The 2.4 m room around the sensor: the walls 1.2 m away are occupied where the beam meets
    // them near normal incidence (a wall returns its perpendicular distance, so farther along it
    // reads as an arc), and so are the four corners, strong reflectors; the space half-way to
    // them is free. The wall behind (x = -1.2) faces the sweep's blind 60° and stays unseen.
    for (x, y) in [
        (1.2, 0.0),
        (1.2, 0.2),
        (0.0, 1.2),
        (0.0, -1.2),
        (1.2, 1.2),
        (1.2, -1.2),
        (-1.2, 1.2),
        (-1.2, -1.2),
    ] {
        let p = map.max_near(x, y, 2).unwrap_or(0.5);
        assert!(p > 0.5, "wall at ({x}, {y}) has p = {p}");
    }
    for (x, y) in [(0.6, 0.0), (0.0, 0.6), (0.0, -0.6), (0.5, 0.5)] {
        let p = map.max_near(x, y, 1).expect("observed");
        assert!(p < 0.5, "free space at ({x}, {y}) has p = {p}");
    }
    // Beyond the walls nothing was ever seen.
    assert_eq!(map.max_near(3.5, 0.0, 1), None);

    // The basic method's array: the wall straight ahead at 1.2 m.
    let latest = collect_until(
        &node,
        || radar.receive().unwrap().map(|s| *s.payload()),
        |got| !got.is_empty(),
    );
    let r = latest.last().unwrap();
    assert_eq!(r.bin_count, 60, "a full turn of the paper's 6° bins");
    let ahead = ((3.0 - r.first_bin_deg) / r.bin_width_deg).round() as usize;
    assert!((r.distances_m[ahead] - 1.2).abs() < 0.05, "{r:?}");

    assert!(fusion.terminate().success(), "fusion did not exit cleanly");
    assert!(driver.terminate().success());
    assert!(sim.terminate().success());
    drop((grid, radar, node));
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}

#[test]
fn fusion_commands_switch_the_preset_and_clear_the_map() {
    let sandbox = Sandbox::new("fusioncmd");
    let node = sandbox.node("test-commander");
    let grid = ipc::grid_service(&node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    let (_sim, pty) = sandbox.spawn_sim(&["--scene", "room", "--speed", "100"]);
    let _driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);
    let _fusion = sandbox.spawn("sonar-fusion", &[]);
    let next = |pred: &dyn Fn(&GridHeader) -> bool| {
        let got = collect_until(
            &node,
            || grid.receive().unwrap().map(|s| *s.user_header()),
            |got| got.last().is_some_and(pred),
        );
        *got.last().unwrap()
    };
    next(&|h| h.readings_fused >= 20);

    let commands = ipc::fusion_commands_service(&node)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    let wake = ipc::wakeup_service(&node, ipc::FUSION_COMMANDS_SERVICE)
        .unwrap()
        .notifier_builder()
        .create()
        .unwrap();
    let send = |cmd| {
        commands.send_copy(cmd).unwrap();
        wake.notify().unwrap();
    };
    send(FusionCommand::new(
        FusionCommandKind::SetPreset,
        ipc::preset_code::PAPER,
    ));
    let paper = next(&|h| h.preset == ipc::preset_code::PAPER);
    assert_eq!(paper.model, ipc::model_code::PAPER);
    assert_eq!(paper.rule, ipc::rule_code::BAYES);
    // The readings so far were re-fused, not dropped.
    assert!(paper.readings_fused >= 20, "{paper:?}");

    send(FusionCommand::new(FusionCommandKind::Clear, 0));
    // The map restarts: a snapshot with fewer readings than before the clear.
    let before = paper.readings_fused;
    next(&|h| h.readings_fused < before);
}

#[test]
fn bad_fusion_settings_are_clear_errors() {
    let sandbox = Sandbox::new("fusionbad");
    for (args, expected) in [
        (
            &["--resolution-m", "-0.02"][..],
            "resolution_m must be a positive",
        ),
        (
            &["--cells", "5000"][..],
            "grid.cells must be between 1 and 4096",
        ),
        (&["--model", "sonar"][..], "unknown sensor model \"sonar\""),
        (
            &["--config", "/nonexistent/sonar.toml"][..],
            "cannot read config file",
        ),
    ] {
        let (status, stderr) = sandbox.spawn("sonar-fusion", args).wait_exit();
        assert!(!status.success(), "{args:?}");
        assert!(stderr.contains(expected), "{args:?}: {stderr}");
    }
}

/// The paper's stepper head (`sonar-sim`) in the room with a post (`tests/scenes/room-post.toml`,
/// the scene every head maps: `tests/tests/heads.rs`, `tests/tests/firmware.rs`) through driver
/// and fusion: `sonar/features` carries the three walls its ±150° sweep faces, the four corners
/// and the post, where they truly are and nothing else (`sonar_e2e::room`), and a clear command
/// empties it.
#[test]
fn the_fusion_publishes_walls_and_posts_and_clears_them() {
    let sandbox = Sandbox::new("features");
    let node = sandbox.node("test-features");
    let features = features_subscriber(&node);
    let readings = readings_subscriber(&node);
    // Fast, but not so fast that a debug-build fusion falls behind and loses readings: a sweep
    // with readings missing hides its regions' ends.
    let scene = room::scene();
    let (_sim, pty) = sandbox.spawn_sim(&["--scene", &scene, "--speed", "20"]);
    let driver = sandbox.spawn("sonar-driver", &["--port", &pty]);
    let _fusion = sandbox.spawn("sonar-fusion", &["--no-persist"]);
    let receive = || {
        features
            .receive()
            .unwrap()
            .map(|s| (*s.user_header(), s.payload().to_vec()))
    };
    // The back wall's normal (180°) lies outside the ±150° sweep; its corners do not.
    let expected = room::Expected {
        step_deg: 1.5,
        walls_deg: vec![0.0, 90.0, -90.0],
        corners_deg: vec![45.0, -45.0, 135.0, -135.0],
    };
    let (header, records) = room_features(&node, &features, &expected, 3, 8);
    assert_eq!(header.layout_version, ipc::LAYOUT_VERSION);
    assert_eq!(header.feature_count as usize, records.len());
    let wall = records
        .iter()
        .find(|r| r.kind == feature_kind::PLANE && r.angle_deg.abs() < 2.0)
        .unwrap();
    assert!(
        wall.times_seen >= 2,
        "seen again, refined, not duplicated: {wall:?}"
    );

    // Stop the head, let the last readings drain, then clear: the features go with the grid.
    let commands = ipc::commands_service(&node)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    let driver_status = driver_status_subscriber(&node);
    commands
        .send_copy(ScanCommand::new(ScanCommandKind::Stop, 0.0, 0.0))
        .unwrap();
    // The driver's status says the scan stopped (it kept the last sweep's mode before).
    wait_for_status(&node, &driver_status, |s| {
        s.mode == ScanMode::Idle as u32 && s.direction == 0
    });
    let mut last_reading = Instant::now();
    while last_reading.elapsed() < Duration::from_secs(3) {
        if receive_reading(&readings).is_some() {
            last_reading = Instant::now();
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    // Held until the end: a departed publisher's samples are dropped before they are read.
    let fusion_commands = ipc::fusion_commands_service(&node)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    fusion_commands
        .send_copy(FusionCommand::new(FusionCommandKind::Clear, 0))
        .unwrap();
    collect_until(&node, receive, |got| {
        got.last()
            .is_some_and(|(h, records)| h.feature_count == 0 && records.is_empty())
    });
    // A consumer that joins while the head stands still still gets the current snapshot.
    let late = ipc::features_service(&node)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    collect_until(
        &node,
        || late.receive().unwrap().map(|s| *s.user_header()),
        |got| got.last().is_some_and(|h| h.feature_count == 0),
    );
    drop(driver);
}

/// Distance from `(x, y)` to the room tour's path: the square of side 1.2 m round the centre.
fn off_the_room_tour(x: f32, y: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    if ax <= 0.6 && ay <= 0.6 {
        0.6 - ax.max(ay)
    } else {
        (ax - 0.6).max(0.0).hypot((ay - 0.6).max(0.0))
    }
}

#[test]
fn the_simulated_robot_tours_the_room_publishing_its_odometry_and_its_true_pose() {
    let sandbox = Sandbox::new("tour");
    let node = sandbox.node("test-consumer");
    let readings = readings_subscriber(&node);
    let subscribe =
        |service: ipc::PubSub<ipc::Pose2D>| service.subscriber_builder().create().unwrap();
    let odometry = subscribe(ipc::pose_service(&node).unwrap());
    let truth = subscribe(ipc::true_pose_service(&node).unwrap());
    let started_ns = ipc::unix_time_ns();
    // Odometry 5 % long with 2°/m of drift: far from the truth within one round.
    let (sim, pty) = sandbox.spawn_sim(&[
        "--scene",
        "room-tour",
        "--speed",
        "20",
        "--seed",
        "3",
        "--odom-scale-error",
        "0.05",
        "--odom-heading-drift",
        "2",
    ]);
    let driver = sandbox.spawn("sonar-driver", &["--port", &pty, "--scan", "full"]);

    // Poses until the truth has been round the tour once (32 s simulated, 1.6 s here), the
    // odometry beside it; both keep coming while the readings do.
    let mut odometry_poses = Vec::new();
    let true_poses = collect_until(
        &node,
        || {
            while let Some(p) = odometry.receive().unwrap() {
                odometry_poses.push(*p.payload());
            }
            truth.receive().unwrap().map(|s| *s.payload())
        },
        |got| {
            let near = |cx: f32, cy: f32| got.iter().any(|p| (p.x_m - cx).hypot(p.y_m - cy) < 0.05);
            got.len() > 100
                && near(0.6, -0.6)
                && near(0.6, 0.6)
                && near(-0.6, 0.6)
                && got.iter().rev().take(20).any(|p| p.y_m < -0.55)
        },
    );
    let sweep_readings = collect_until(&node, || receive_reading(&readings), |got| got.len() >= 10);
    let now_ns = ipc::unix_time_ns();

    // The truth: on the tour, heading along it, stamped in order with the host's clock.
    for p in &true_poses {
        assert_eq!(p.layout_version, ipc::LAYOUT_VERSION);
        assert!(
            off_the_room_tour(p.x_m, p.y_m) < 1e-3,
            "off the tour: {p:?}"
        );
        assert!((started_ns..=now_ns).contains(&p.stamp_ns), "{p:?}");
    }
    for pair in true_poses.windows(2) {
        assert!(pair[1].stamp_ns > pair[0].stamp_ns, "{pair:?}");
    }
    // 20 poses per simulated second at 20×: 2.5 ms of host time apart, none lost (the buffer
    // of robot/true_pose holds 5 s of them; with 16, two busy loops cost 50-84 of 600).
    for pair in true_poses.windows(2) {
        let gap_ms = (pair[1].stamp_ns - pair[0].stamp_ns) as f64 / 1e6;
        assert!((gap_ms - 2.5).abs() < 0.01, "{gap_ms} ms between poses");
    }
    // It starts at the first waypoint heading for the second (east): the first pose received
    // is the tour's first, however late the test reads; up the east side it heads north.
    let first = true_poses[0];
    assert!(
        (first.x_m + 0.6).abs() < 1e-6 && (first.y_m + 0.6).abs() < 1e-6 && first.theta_rad == 0.0,
        "{first:?}"
    );
    let east_side: Vec<_> = true_poses
        .iter()
        .filter(|p| (p.x_m - 0.6).abs() < 1e-3 && p.y_m.abs() < 0.5)
        .collect();
    assert!(!east_side.is_empty());
    for p in east_side {
        assert!(
            (p.theta_rad - std::f32::consts::FRAC_PI_2).abs() < 1e-3,
            "{p:?}"
        );
    }

    // The odometry: the same instants, drifting away from the truth.
    assert!(!odometry_poses.is_empty());
    let mut worst = 0.0f32;
    let mut paired = 0;
    for o in &odometry_poses {
        if let Some(t) = true_poses.iter().find(|t| t.stamp_ns == o.stamp_ns) {
            paired += 1;
            worst = worst.max((o.x_m - t.x_m).hypot(o.y_m - t.y_m));
        }
    }
    assert!(
        paired > 50,
        "only {paired} odometry poses matched a true one"
    );
    assert!(worst > 0.1, "odometry stays within {worst} m of the truth");
    assert!(!sweep_readings.is_empty());

    assert!(driver.terminate().success(), "driver did not exit cleanly");
    assert!(sim.terminate().success(), "simulator did not exit cleanly");
    drop((odometry, truth, readings));
    drop(node);
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}

/// The corridor tour through simulator, driver and a localising fusion: the back wall that both
/// rooms share is mapped where the scene has it, seen from each room, and sweeps are localised
/// against the features (odometry without errors, so the map is the robot's path's own); features
/// heard from more than one stop are published as confirmed.
#[test]
fn a_touring_robot_maps_both_rooms_in_one_frame_and_is_localised() {
    let sandbox = Sandbox::new("corridor");
    let node = sandbox.node("test-consumer");
    let grid = grid_subscriber(&node);
    let localized = localized_pose_subscriber(&node);
    let features = features_subscriber(&node);
    let config = corridor_grid_config("corridor");
    let (_sim, pty) = sandbox.spawn_sim(&[
        "--scene",
        "corridor",
        "--speed",
        "40",
        "--odom-scale-error",
        "0",
        "--odom-heading-drift",
        "0",
        "--odom-noise-m",
        "0",
        "--odom-noise-deg",
        "0",
    ]);
    let _driver = sandbox.spawn("sonar-driver", &["--port", &pty]);
    let _fusion = sandbox.spawn(
        "sonar-fusion",
        &[
            "--config",
            config.to_str().unwrap(),
            "--no-persist",
            "--localize",
        ],
    );

    // The rooms' back wall, seen from each room's waypoint (x = 1.5 and x = 4.5).
    collect_until(
        &node,
        || {
            grid.receive().unwrap().map(|s| {
                let h = *s.user_header();
                (
                    h,
                    back_wall_seen_at(&h, s.payload(), 1.5)
                        && back_wall_seen_at(&h, s.payload(), 4.5),
                )
            })
        },
        |got| got.last().is_some_and(|(_, both)| *both),
    );
    let fixes = collect_until(
        &node,
        || localized.receive().unwrap().map(|s| *s.payload()),
        |got| got.iter().any(|p| p.matched >= 2),
    );
    let fix = fixes.iter().find(|p| p.matched >= 2).unwrap();
    assert_eq!(fix.layout_version, ipc::LAYOUT_VERSION);
    // Odometry without errors: the fix agrees with it.
    let off = (fix.x_m - fix.odometry_x_m).hypot(fix.y_m - fix.odometry_y_m);
    assert!(off < 0.05, "{fix:?}");
    assert!(fix.cov_xx.is_finite() && fix.cov_xx > 0.0, "{fix:?}");
    // The fix matched features the map had from an earlier stop: heard from two places now, they
    // are confirmed on `sonar/features` (a standing sensor's are all tentative: consumers.rs).
    collect_until(
        &node,
        || {
            features
                .receive()
                .unwrap()
                .map(|s| s.payload().iter().filter(|r| r.is_confirmed()).count())
        },
        |confirmed| confirmed.last().is_some_and(|&n| n >= 1),
    );
    let _ = std::fs::remove_file(&config);
}

/// The corridor tour with the evaluation's drifting odometry (3 % long, 2°/m) through simulator,
/// driver and a localising fusion: every fix lies near the truth of its instant (the simulator's
/// `robot/true_pose`, same host clock) while the odometry has drifted far from it. (Seen at
/// 7b57f0c: 11 fixes in 20 sweeps, the worst 3.6 cm and 0.7° off, the odometry 1.16 m.)
#[test]
fn a_drifting_robot_is_localised_near_the_truth() {
    let sandbox = Sandbox::new("drift");
    let node = sandbox.node("test-consumer");
    // The truth comes at 800 poses/s and is drained every few milliseconds; a lost one only
    // leaves a sweep without a truth to compare (within 10 ms of its stamp).
    let truth = true_pose_subscriber(&node);
    let localized = localized_pose_subscriber(&node);
    let config = corridor_grid_config("drift");
    // The fusion first, so that it hears the tour from its start. At 10× (not the 40× of the
    // test above) a reading's host stamp, a millisecond or two after the ping, is still within a
    // few millimetres of the robot's motion: the stops' sweeps are taken standing still.
    let _fusion = sandbox.spawn(
        "sonar-fusion",
        &[
            "--config",
            config.to_str().unwrap(),
            "--no-persist",
            "--localize",
        ],
    );
    wait_until(&node, "the fusion's readings subscriber", || {
        readings_subscribers(&node) >= 1
    });
    let (_sim, _driver) = drive_drifting_corridor(&sandbox);

    // Sweeps until the robot has been into both rooms and back to the corridor's far end (20
    // sweeps, 240 s simulated, 24 s here), the truth beside them.
    let (sweeps, true_poses) = collect_with_truth(
        &node,
        &truth,
        || localized.receive().unwrap().map(|s| *s.payload()),
        20,
    );
    let truth_at = |stamp_ns: u64| true_poses.at(stamp_ns);
    // The map's frame is the odometry's at the first reading the fusion heard (the robot may
    // have set off before): the truth is brought into it through the first sweep.
    let first = &sweeps[0];
    let map_from_world = Isometry2::new(Vector2::new(first.x_m, first.y_m), first.theta_rad)
        * truth_at(first.stamp_ns)
            .expect("the truth of the first sweep")
            .inverse();
    let mut fixes = 0;
    let mut odometry_off = 0.0f32;
    for s in &sweeps {
        let Some(t) = truth_at(s.stamp_ns).map(|t| map_from_world * t) else {
            continue;
        };
        let odometry = Vector2::new(s.odometry_x_m, s.odometry_y_m);
        odometry_off = odometry_off.max((odometry - t.translation.vector).norm());
        if s.matched == 0 {
            continue;
        }
        fixes += 1;
        let off = (Vector2::new(s.x_m, s.y_m) - t.translation.vector).norm();
        let turned = (s.theta_rad - t.rotation.angle() + std::f32::consts::PI)
            .rem_euclid(std::f32::consts::TAU)
            - std::f32::consts::PI;
        assert!(
            off < 0.1 && turned.abs() < 4f32.to_radians(),
            "fix {off} m, {} deg from the truth: {s:?} {t:?}",
            turned.to_degrees()
        );
    }
    assert!(fixes >= 8, "only {fixes} of {} sweeps fixed", sweeps.len());
    assert!(
        odometry_off > 0.3,
        "the odometry stayed within {odometry_off} m"
    );
    let _ = std::fs::remove_file(&config);
}

/// `--version` names the program the user ran, not the crate it is built from.
#[test]
fn every_program_names_itself_in_its_version() {
    let sandbox = Sandbox::new("version");
    for name in [
        "sonar-sim",
        "sonar-driver",
        "sonar-fusion",
        "sonar-viewer",
        "sonar-pipeline",
        "sonar-record",
        "sonar-replay",
        "sonar-export",
        "sonar-firmware-sim",
        "sonar-nearest-obstacle",
        "sonar-foxglove",
        "sonar-slam",
    ] {
        let out = sandbox.run(name, &["--version"]);
        assert!(out.status.success(), "{name}");
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(text.starts_with(&format!("{name} ")), "{name}: {text}");
    }
}

/// A device that has not identified itself as the head (it sends readings but never answers
/// `HELLO`) gets nothing but `HELLO`, none of its readings is published, and the driver leaves
/// its terminal settings as it found them (issue 24).
#[test]
fn a_device_that_never_identifies_itself_is_only_asked_who_it_is() {
    let sandbox = Sandbox::new("unknown_dev");
    let node = sandbox.node("test-device");
    let readings = readings_subscriber(&node);
    let mut head = FakeHead::new();
    let before = nix::sys::termios::tcgetattr(head.serial.slave.as_fd()).unwrap();
    let driver = sandbox.spawn(
        "sonar-driver",
        &["--port", &head.serial.slave_path, "--scan", "full"],
    );
    head.hear("$HELLO,2*", 1);
    for seq in 0..6u32 {
        head.say(&DeviceMessage::Reading(WireReading {
            seq,
            time_ms: 1000 + seq,
            sweep: 1,
            direction: Direction::Ccw,
            angle_cdeg: -14700 + 600 * seq as i32,
            ping_count: 4,
            echo_us: [5800, 5800, 5800, 5800, 0, 0, 0, 0],
        }));
    }
    // The driver asks again (its handshake attempts), so it has read the lines sent before.
    head.hear("$HELLO,2*", 2);
    let (status, stderr) = driver.terminate_with_stderr();
    assert!(status.success(), "{stderr}");
    assert!(
        stderr.contains("unidentified_readings=6"),
        "the readings were not read, or published: {stderr}"
    );
    assert!(receive_reading(&readings).is_none());
    // Give a STOP time to arrive, were one sent.
    std::thread::sleep(Duration::from_millis(200));
    let mut fds = [PollFd::new(head.serial.master.as_fd(), PollFlags::POLLIN)];
    if poll(&mut fds, PollTimeout::from(100u16)).unwrap() > 0 {
        let mut buf = [0u8; 256];
        let n = head.serial.master.read(&mut buf).unwrap_or(0);
        head.heard.push_str(&String::from_utf8_lossy(&buf[..n]));
    }
    let sent: Vec<&str> = head.heard.lines().collect();
    assert!(
        sent.iter().all(|l| l.starts_with("$HELLO,")),
        "more than HELLO sent to an unidentified device: {sent:?}"
    );
    let after = nix::sys::termios::tcgetattr(head.serial.slave.as_fd()).unwrap();
    assert_eq!(
        (
            after.input_flags,
            after.output_flags,
            after.control_flags,
            after.local_flags
        ),
        (
            before.input_flags,
            before.output_flags,
            before.control_flags,
            before.local_flags
        ),
        "terminal settings changed"
    );
    assert_eq!(
        nix::sys::termios::cfgetospeed(&after),
        nix::sys::termios::cfgetospeed(&before)
    );
}

/// A flood of device errors is counted in full and logged at most once a second with the number
/// left out (issue 24: every ERR line was a WARN line).
#[test]
fn device_errors_are_counted_in_full_and_logged_rate_limited() {
    let sandbox = Sandbox::new("errflood");
    let node = sandbox.node("test-device");
    let status = driver_status_subscriber(&node);
    let mut head = FakeHead::new();
    let driver = sandbox.spawn(
        "sonar-driver",
        &["--port", &head.serial.slave_path, "--scan", "full"],
    );
    head.handshake("HEAD-A");
    for k in 0..40 {
        head.say(&DeviceMessage::Error {
            code: ErrorCode::Range,
            text: format!("refused {k}"),
        });
    }
    let s = wait_for_status(&node, &status, |s| s.device_errors == 40);
    assert_eq!(s.last_device_error(), "RANGE: refused 39");
    let (exit, stderr) = driver.terminate_with_stderr();
    assert!(exit.success(), "{stderr}");
    let logged = stderr.matches("device reports an error").count();
    // One a second: 40 lines read within a few seconds even on a loaded machine.
    assert!(
        (1..=10).contains(&logged),
        "{logged} lines for 40 errors:\n{stderr}"
    );
}
