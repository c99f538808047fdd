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

/// Records what the serve loop tells the robot, and stops the loop after `until_us` simulated.
struct Recorder {
    rover: sonar_sim::Rover,
    samples: Vec<sonar_sim::PoseSample>,
    sweeps_ended: Vec<u64>,
    until_us: u64,
    stop: Arc<AtomicBool>,
}

impl sonar_sim::Carrier for Recorder {
    fn advance(
        &mut self,
        now_us: u64,
        unix_ns: &dyn Fn(u64) -> u64,
    ) -> std::io::Result<sonar_sim::Pose> {
        let samples = &mut self.samples;
        let pose = self.rover.advance(now_us, |s| samples.push(s));
        assert!(unix_ns(now_us) > 0);
        if now_us >= self.until_us {
            self.stop.store(true, Ordering::Relaxed);
        }
        Ok(pose)
    }

    fn sweep_started(&mut self) {
        self.rover.sweep_started();
    }

    fn sweep_ended(&mut self, now_us: u64) {
        self.sweeps_ended.push(now_us);
        self.rover.sweep_ended(now_us);
    }
}

#[test]
fn a_stop_and_scan_robot_waits_for_each_sweep_of_the_served_head() {
    let pty = Pty::open().unwrap();
    let path = pty.path().to_owned();
    let sensor = SensorConfig::default();
    let scene = Scene::builtin("corridor").unwrap();
    let robot = scene.robot.clone().unwrap();
    let rover = sonar_sim::Rover::new(&robot, scene.odometry, 20.0, 1);
    let model = EchoModel::new(scene, sensor, 1).unwrap();
    let firmware = Firmware::new(sensor, Timing::default(), model).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let mut recorder = Recorder {
        rover,
        samples: Vec::new(),
        sweeps_ended: Vec::new(),
        until_us: 60_000_000,
        stop: Arc::clone(&stop),
    };
    let server = std::thread::spawn({
        let stop = Arc::clone(&stop);
        move || {
            let stats = serve(
                &pty,
                &mut NativeDevice::new(firmware),
                Speed::Max,
                &stop,
                None,
                Some(&mut recorder),
            );
            (stats, recorder)
        }
    });
    let mut port = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(nix::fcntl::OFlag::O_NOCTTY.bits())
        .open(&path)
        .unwrap();
    // Drain what the head says, so the loop never waits for room in the terminal.
    let reader = port.try_clone().unwrap();
    std::thread::spawn(move || std::io::copy(&mut BufReader::new(reader), &mut std::io::sink()));
    port.write_all(encode_command(&HostCommand::FullScan, PROTOCOL_VERSION).as_bytes())
        .unwrap();
    let (stats, recorder) = server.join().unwrap();
    stats.unwrap();

    // It stands at the start through the first whole sweep, then drives 1 m east to the second
    // waypoint (5 s), arriving during the second sweep; that one was begun on the move, so it
    // stands there through the third.
    let start = robot.waypoints[0];
    let second = robot.waypoints[1];
    let ends = &recorder.sweeps_ended;
    assert!(ends.len() >= 3, "{ends:?}");
    let arrived = ends[0] + 5_000_000;
    assert!(ends[1] > arrived, "{ends:?}");
    let stands = |at: sonar_sim::Vec2, from_us: u64, to_us: u64| {
        for s in recorder.samples.iter() {
            if (from_us..=to_us).contains(&s.t_us) {
                assert!((s.truth.at - at).norm() < 1e-9, "{s:?}");
            }
        }
    };
    stands(start, 0, ends[0]);
    stands(second, arrived + 50_000, ends[2]);
    let moves_after = |t_us: u64| {
        recorder
            .samples
            .iter()
            .find(|s| s.t_us > t_us)
            .is_some_and(|s| s.truth != recorder.samples[0].truth)
    };
    assert!(moves_after(ends[0]));
    let after_third = recorder
        .samples
        .iter()
        .find(|s| s.t_us > ends[2] + 50_000)
        .expect("samples after the third sweep");
    // Turning towards the first room (north) at the second waypoint.
    assert!((after_third.truth.at - second).norm() < 1e-9);
    assert!(after_third.truth.heading_rad > 0.0, "{after_third:?}");
}
