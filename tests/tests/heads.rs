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
