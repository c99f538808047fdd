//! The simulator on a real pseudo-terminal, through the library API: a host opens the slave path as
//! a plain file, as a serial port, and talks the protocol.

use std::io::{BufRead, BufReader, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use sonar_common::protocol::{
    DeviceMessage, HostCommand, PROTOCOL_VERSION, encode_command, parse_device,
};
use sonar_common::sensor::SensorConfig;
use sonar_sim::{EchoModel, Firmware, NativeDevice, Pty, Scene, Speed, Timing, serve};

/// Only so that a silent device fails the test instead of hanging it.
const PATIENCE: Duration = Duration::from_secs(60);

#[test]
fn a_host_on_the_slave_gets_the_handshake_and_readings() {
    let pty = Pty::open().unwrap();
    let path = pty.path().to_owned();
    let sensor = SensorConfig::default();
    let model = EchoModel::new(Scene::builtin("room").unwrap(), sensor, 1).unwrap();
    let firmware = Firmware::new(sensor, Timing::default(), model).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let server = std::thread::spawn({
        let stop = Arc::clone(&stop);
        move || {
            serve(
                &pty,
                &mut NativeDevice::new(firmware),
                Speed::Max,
                &stop,
                None,
            )
        }
    });

    let mut port = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(nix::fcntl::OFlag::O_NOCTTY.bits())
        .open(&path)
        .unwrap();
    let (tx, rx) = mpsc::channel();
    let reader = BufReader::new(port.try_clone().unwrap());
    std::thread::spawn(move || {
        for line in reader.split(b'\n') {
            if line.map(|l| tx.send(l)).is_err() {
                break;
            }
        }
    });
    let commands = [HostCommand::Hello { version: 2 }, HostCommand::FullScan]
        .map(|c| encode_command(&c, PROTOCOL_VERSION));
    for cmd in &commands {
        port.write_all(cmd.as_bytes()).unwrap();
    }

    let next = || {
        parse_device(
            &rx.recv_timeout(PATIENCE).expect("device went silent"),
            PROTOCOL_VERSION,
        )
    };
    // The head announces itself at power-on, then answers the handshake.
    for _ in 0..2 {
        assert!(matches!(
            next(),
            Ok(DeviceMessage::Hello {
                version: 2,
                step_cdeg: 150,
                pings_per_reading: 4,
                ..
            })
        ));
    }
    assert_eq!(
        next(),
        Ok(DeviceMessage::Ack {
            command: "SCAN".into()
        })
    );
    assert!(matches!(
        next(),
        Ok(DeviceMessage::SweepStart { sweep: 1, .. })
    ));
    let speed = sensor.speed_of_sound_mps();
    for k in 0..50 {
        let Ok(DeviceMessage::Reading(r)) = next() else {
            panic!("reading {k} missing");
        };
        assert_eq!((r.seq, r.sweep), (k, 1));
        assert_eq!(r.angle_cdeg, -14700 + 600 * k as i32);
        // Inside the 2.4 m room every echo is between a wall (1.2 m) and a corner (1.7 m), bar the
        // rare transient.
        let heard = r.pings().iter().filter(|&&us| us > 0);
        let in_room = heard
            .map(|&us| speed * us as f32 * 1e-6 / 2.0)
            .filter(|d| (1.19..1.71).contains(d))
            .count();
        assert!(in_room >= 3, "{r:?}");
    }
    assert_eq!(
        next(),
        Ok(DeviceMessage::LimitHit(sonar_common::protocol::Limit::Max))
    );

    stop.store(true, Ordering::Relaxed);
    let stats = server.join().unwrap().unwrap();
    assert!(stats.lines_written >= 54);
    assert_eq!(
        stats.bytes_received as usize,
        commands.iter().map(String::len).sum::<usize>()
    );
}
