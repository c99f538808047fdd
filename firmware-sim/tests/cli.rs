//! The binary as a user starts it: errors, the PTY line, `--link`, SIGUSR1 (reset button) and
//! SIGTERM, with the real firmware image (`make -C firmware`; `.ci/run` builds it).
#![allow(clippy::unwrap_used, clippy::expect_used)] // helpers outside #[test] fns; a panic is a failure

use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_sonar-firmware-sim");

#[test]
fn a_missing_firmware_or_simavr_is_a_clear_error() {
    let out = Command::new(BIN)
        .args(["--firmware", "/nonexistent/sonar-head.elf"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    let expected = if cfg!(simavr) {
        "no firmware at /nonexistent/sonar-head.elf: build it with make -C firmware"
    } else {
        "built without simavr: apt-get install simavr libsimavr-dev libelf-dev"
    };
    assert!(stderr.contains(expected), "{stderr}");
}

#[cfg(simavr)]
mod with_simavr {
    use std::io::{BufRead, BufReader, Read};
    use std::os::unix::fs::OpenOptionsExt;
    use std::path::PathBuf;
    use std::process::Stdio;
    use std::sync::mpsc;
    use std::time::Duration;

    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    use sonar_common::protocol::{DeviceMessage, PROTOCOL_VERSION, parse_device};

    use super::*;

    const PATIENCE: Duration = Duration::from_secs(60);

    fn firmware_elf() -> PathBuf {
        let elf =
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../firmware/build/sonar-head.elf");
        assert!(
            elf.exists(),
            "{} is missing: run `make -C firmware` first (.ci/run does)",
            elf.display()
        );
        elf
    }

    /// A servo head has no switches to break and a travel of ±90°: said before anything starts.
    #[test]
    fn a_servo_head_refuses_switch_faults_and_a_start_beyond_its_stops() {
        for (args, expected) in [
            (
                &["--switch-fault", "min=dead"][..],
                "--switch-fault and --switch-bounce: a servo head has no limit switches",
            ),
            (
                &["--start-angle", "120"][..],
                "the shaft cannot stand at 120°: the mechanical stops are at ±90°",
            ),
        ] {
            let out = Command::new(BIN)
                .args(["--head", "servo", "--firmware"])
                .arg(firmware_elf())
                .args(args)
                .output()
                .unwrap();
            assert!(!out.status.success(), "{args:?}");
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert!(stderr.contains(expected), "{args:?}: {stderr}");
        }
    }

    #[test]
    fn link_reset_button_and_sigterm() {
        let link = std::env::temp_dir().join(format!("sonar-fwsim-link-{}", std::process::id()));
        let mut child = Command::new(BIN)
            .arg("--firmware")
            .arg(firmware_elf())
            .arg("--link")
            .arg(&link)
            .args(["--speed", "max", "--head-id", "00C0FFEE0000BEEF"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut first = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut first)
            .unwrap();
        let pty = first.strip_prefix("PTY ").unwrap().trim().to_owned();
        assert_eq!(std::fs::read_link(&link).unwrap(), PathBuf::from(&pty));

        let port = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(nix::fcntl::OFlag::O_NOCTTY.bits())
            .open(&link)
            .unwrap();
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(port).split(b'\n') {
                if line.map(|l| tx.send(l)).is_err() {
                    break;
                }
            }
        });
        let hello = || loop {
            let line = rx.recv_timeout(PATIENCE).expect("a HELLO line");
            if let Ok(DeviceMessage::Hello { head_id, .. }) = parse_device(&line, PROTOCOL_VERSION)
            {
                return head_id;
            }
        };
        // Power-on: the firmware announces itself with the id programmed into its EEPROM.
        assert_eq!(hello(), "00C0FFEE0000BEEF");
        // The reset button: it reboots and announces itself again.
        let pid = Pid::from_raw(i32::try_from(child.id()).unwrap());
        kill(pid, Signal::SIGUSR1).unwrap();
        assert_eq!(hello(), "00C0FFEE0000BEEF");

        kill(pid, Signal::SIGTERM).unwrap();
        let status = child.wait().unwrap();
        assert!(status.success(), "{status}");
        let mut log = String::new();
        child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut log)
            .unwrap();
        assert!(log.contains("reset button pressed"), "{log}");
        assert!(log.contains("real_time_factor"), "{log}");
        assert!(
            std::fs::symlink_metadata(&link).is_err(),
            "the link is removed on exit"
        );
    }
}
