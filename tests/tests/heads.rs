//! End to end: heads other than the paper's stepper, played by the test on a pseudo-terminal — a
//! hobby sketch whose no-echo value is 255, a continuous 360° head — through the real driver (and
//! fusion), as their owners would run them.
#![allow(clippy::unwrap_used, clippy::expect_used)] // helpers outside #[test] fns; a panic is a failure

use std::io::Write;
use std::time::Duration;

use sonar_common::ipc::{Reading, flags};
use sonar_e2e::{FakeSerial, Sandbox, collect_until, readings_subscriber, receive_reading};

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
    let _fusion = sandbox.spawn("sonar-fusion", &["--no-persist"]);
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
}
