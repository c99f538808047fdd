//! The fault suite (issue 10): the simulator damages the lines it sends at high rates, resets the
//! head mid-sweep and falls silent (`sonar-sim --faults`), and the real driver must publish every
//! reading that reached it intact, exactly once, and nothing else, count every damaged line, and
//! recover from the reset and the silence by itself.
//!
//! What reached the driver is known exactly: the simulator's fault log holds every byte it sent
//! from the driver's first command on (before that nothing is damaged, and the driver flushes the
//! port anyway), so the test cuts that byte stream into lines with the driver's framer and parses
//! them with the protocol's parser, as the driver does. Two things are modelled: the driver starts
//! a new framer when it reconnects, which it does during the silence (nothing is sent then); and
//! the last bytes before the simulator exits may be lost with its terminal, so the comparison
//! covers the lines the driver says it saw (`lines_ok + lines_rejected`), a prefix of the stream.
#![allow(clippy::unwrap_used, clippy::expect_used)] // a panic is a test failure

use std::collections::{BTreeMap, HashMap, HashSet};
use std::iter::Peekable;
use std::path::Path;
use std::str::Chars;
use std::time::{Duration, Instant};

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use sonar_common::ipc::{self, DriverStatus, LinkState, Reading};
use sonar_common::protocol::{
    DeviceMessage, FramedLine, LineFramer, ProtocolVersion, Terminators, WireReading, parse_device,
};
use sonar_driver::sweeps::SweepIds;
use sonar_e2e::{
    PATIENCE, Sandbox, driver_status_subscriber, path_str, readings_subscriber, receive_reading,
};

/// The line faults of the suite.
const LINE_FAULTS: [&str; 6] = [
    "garbage",
    "bitflip",
    "double-flip",
    "truncate",
    "overlong",
    "stray",
];

/// Every line fault at a high rate (a quarter of the lines), a reset and a silence. At `--speed
/// 100` the reset comes 1 s after the handshake and the silence lasts from 2.5 s to 5.5 s: the
/// driver (`--silence-timeout 0.5`) gives up on the head after about 1 s of it and opens the port
/// again, which flushes it, well before the head speaks again, and its handshake attempts (2 s
/// each, three) outlast the rest of the silence.
const SPEC: &str = "garbage=0.04,bitflip=0.05,double-flip=0.05,truncate=0.04,overlong=0.02,\
                    stray=0.04,reset=100s,silence=250s:300s";

#[test]
fn damaged_lines_are_counted_never_published_and_reset_and_silence_are_recovered() {
    let run = run_pipeline("faults", ProtocolVersion::V2, SPEC, 300);
    let replay = &run.replay;

    let corrupted = run.corrupted();
    assert_eq!(corrupted, 0, "corrupted readings were published");
    run.assert_accounted();
    for kind in LINE_FAULTS {
        assert!(replay.kind(kind) > 0, "no line suffered {kind}");
    }

    // The reset and the silence: counted once each, recovered without a restart.
    let status = &run.status;
    assert_eq!(replay.events.get("reset"), Some(&1));
    assert_eq!(replay.events.get("silence"), Some(&1));
    assert_eq!(status.head_resets, 1, "{status:?}");
    assert_eq!(status.silences, 1, "{status:?}");
    assert_eq!(status.reconnects, 1, "only the silence reopened the port");
    let readings_after = |mark: usize| {
        replay.framed[mark..run.lines_seen()]
            .iter()
            .filter(|l| matches!(parse(l, replay.version), Some(DeviceMessage::Reading(_))))
            .count()
    };
    let after_reset = readings_after(replay.reset_at[0]);
    let after_silence = readings_after(replay.silence_end_at[0]);
    assert!(
        after_silence >= 100,
        "{after_silence} readings after the silence"
    );
    assert!(
        after_reset > after_silence,
        "readings between reset and silence"
    );

    println!(
        "faults (protocol 2): {} lines from the head after the driver's first command, line faults {}, merged {}; \
         the driver saw {} lines: {} rejected, {} published readings (the test received {}), \
         corrupted published {corrupted}; head resets {}, silences {}, readings after the reset \
         {after_reset}, after the silence {after_silence}",
        replay.lines_sent,
        LINE_FAULTS
            .iter()
            .map(|k| format!("{k} {}", replay.kind(k)))
            .collect::<Vec<_>>()
            .join(", "),
        replay.kind("merged"),
        run.lines_seen(),
        status.lines_rejected,
        status.readings_published,
        run.readings.len(),
        status.head_resets,
        status.silences,
    );
}

/// The failure that made protocol version 2, caught again by the same checks: with version 1's
/// XOR, same-column double flips go through as readings.
#[test]
fn with_protocol_1_double_flips_are_published_as_corrupted_readings() {
    let run = run_pipeline("faults_v1", ProtocolVersion::V1, "double-flip=0.3", 600);
    run.assert_accounted();
    let corrupted = run.corrupted();
    println!(
        "faults (protocol 1): double flips {}, corrupted published {corrupted} of {} readings",
        run.replay.kind("double-flip"),
        run.readings.len()
    );
    assert!(corrupted > 0, "the XOR check caught every double flip?");
}

/// A run of simulator and driver, with what both reported.
struct Run {
    readings: Vec<Reading>,
    /// The driver's status after the simulator stopped.
    status: DriverStatus,
    replay: Replay,
}

impl Run {
    /// Lines the driver received: a prefix of what the simulator sent.
    fn lines_seen(&self) -> usize {
        usize::try_from(self.status.lines_ok + self.status.lines_rejected).unwrap()
    }

    /// Published readings that match no `RD` line the simulator meant to send.
    fn corrupted(&self) -> usize {
        self.readings
            .iter()
            .filter(|r| !self.replay.originals.contains(&published_key(r)))
            .count()
    }

    /// Every line that reached the driver is accounted for: the damaged ones rejected, the intact
    /// ones taken, and their readings published in order, each once.
    fn assert_accounted(&self) {
        let seen = self.lines_seen();
        let replay = &self.replay;
        assert!(
            seen <= replay.framed.len(),
            "the driver saw {seen} lines, the simulator sent {}",
            replay.framed.len()
        );
        let mut rejected = 0;
        let mut ok = 0;
        let mut expected = Vec::new();
        // Sweep ids are published on across the head's reset, as the driver does.
        let mut sweeps = SweepIds::default();
        // After the silence the driver opened the port again: until the head answers its `HELLO`
        // the readings are not published (they could be another head's), as after any new port.
        let mut identified = true;
        for (i, line) in replay.framed[..seen].iter().enumerate() {
            if replay.reset_at.contains(&i) {
                sweeps.head_was_reset();
            }
            if replay.silence_end_at.contains(&i) && self.status.reconnects > 0 {
                identified = false;
            }
            match parse(line, replay.version) {
                None => rejected += 1,
                Some(msg) => {
                    ok += 1;
                    match msg {
                        DeviceMessage::Hello { .. } => identified = true,
                        DeviceMessage::Reading(_) if !identified => {}
                        DeviceMessage::Reading(mut r) => {
                            r.sweep = sweeps.of(r.sweep);
                            expected.push(wire_key(&r));
                        }
                        DeviceMessage::SweepStart { sweep, .. } => {
                            sweeps.of(sweep);
                        }
                        _ => {}
                    }
                }
            }
        }
        assert_eq!(self.status.lines_rejected, rejected, "lines rejected");
        assert_eq!(self.status.lines_ok, ok, "lines taken");
        assert_eq!(
            self.status.readings_published,
            self.readings.len() as u64,
            "the test missed readings"
        );
        let published: Vec<Key> = self.readings.iter().map(published_key).collect();
        if let Some(i) =
            (0..published.len().min(expected.len())).find(|&i| published[i] != expected[i])
        {
            panic!(
                "reading {i}: published {:?}, sent intact {:?}",
                published[i], expected[i]
            );
        }
        assert_eq!(published.len(), expected.len(), "readings published");
    }
}

/// The raw side of a reading: device counter and clock, sweep (as published), direction, angle
/// (centidegrees), echo times.
type Key = (u32, u32, u32, i8, i32, Vec<u32>);

fn wire_key(r: &WireReading) -> Key {
    (
        r.seq,
        r.time_ms,
        r.sweep,
        r.direction.sign() as i8,
        r.angle_cdeg,
        r.pings().to_vec(),
    )
}

fn published_key(r: &Reading) -> Key {
    (
        r.device_seq,
        r.device_time_ms,
        r.sweep_id,
        r.direction,
        (r.angle_deg * 100.0).round() as i32,
        r.echo_us[..usize::from(r.ping_count)].to_vec(),
    )
}

/// A framed line as the driver's decoder sees it; `None` for a rejected one (an overlong line is
/// `None` already).
fn parse(line: &Option<Vec<u8>>, version: ProtocolVersion) -> Option<DeviceMessage> {
    parse_device(line.as_deref()?, version).ok()
}

/// Starts the simulator with `spec` and the driver, lets them run until `readings_after` readings
/// have been published after the driver first counted a head reset or silence (or after the
/// start, if the spec has neither), stops the simulator, and collects what both reported.
fn run_pipeline(name: &str, version: ProtocolVersion, spec: &str, readings_after: usize) -> Run {
    let sandbox = Sandbox::new(name);
    let node = sandbox.node("test-consumer");
    let readings_sub = readings_subscriber(&node);
    let status_sub = driver_status_subscriber(&node);
    let log_path = sandbox.root.join("faults.jsonl");
    let protocol = version.to_string();
    let (sim, pty) = sandbox.spawn_sim(&[
        "--scene",
        "room",
        "--speed",
        "100",
        "--seed",
        "3",
        "--protocol",
        &protocol,
        "--faults",
        spec,
        "--fault-seed",
        "11",
        "--fault-log",
        path_str(&log_path),
    ]);
    let driver = sandbox.spawn(
        "sonar-driver",
        &[
            "--port",
            &pty,
            "--protocol",
            &protocol,
            "--scan",
            "full",
            "--silence-timeout",
            "0.5",
        ],
    );

    let events_wanted = u32::from(spec.contains("reset=")) + u32::from(spec.contains("silence="));
    let mut readings = Vec::new();
    let mut status = DriverStatus::default();
    let mut mark = None;
    pump(
        &node,
        (&readings_sub, &status_sub),
        (&mut readings, &mut status),
        |s, got| {
            if mark.is_none() && s.head_resets + s.silences >= events_wanted {
                mark = Some(got.len());
            }
            mark.is_some_and(|m| got.len() >= m + readings_after)
        },
    );

    let stopped_ns = ipc::unix_time_ns();
    assert!(
        sim.terminate().success(),
        "the simulator did not exit cleanly"
    );
    // The driver reads what is left, loses the port and says so with its final counters.
    pump(
        &node,
        (&readings_sub, &status_sub),
        (&mut readings, &mut status),
        |s, _| s.link_state == LinkState::Disconnected as u32 && s.stamp_ns > stopped_ns,
    );
    while let Some(r) = receive_reading(&readings_sub) {
        readings.push(r);
    }
    assert!(
        driver.terminate().success(),
        "the driver did not exit cleanly"
    );
    for (i, r) in readings.iter().enumerate() {
        assert_eq!(r.seq, i as u64, "the test missed a reading");
    }
    Run {
        readings,
        status,
        replay: Replay::of_log(&log_path, version),
    }
}

/// Receives readings and the driver's status until `done` says enough, or [`PATIENCE`] runs out.
fn pump(
    node: &Node<Ipc>,
    (readings_sub, status_sub): (
        &Subscriber<Ipc, Reading, ()>,
        &Subscriber<Ipc, DriverStatus, ()>,
    ),
    (readings, status): (&mut Vec<Reading>, &mut DriverStatus),
    mut done: impl FnMut(&DriverStatus, &[Reading]) -> bool,
) {
    let deadline = Instant::now() + PATIENCE;
    loop {
        while let Some(r) = receive_reading(readings_sub) {
            readings.push(r);
        }
        while let Some(s) = status_sub.receive().unwrap() {
            *status = *s.payload();
        }
        if done(status, readings) {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "gave up waiting after {} readings; driver status {status:?}",
            readings.len()
        );
        let _ = node.wait(Duration::from_millis(5));
    }
}

/// The simulator's fault log, replayed into what the driver received.
struct Replay {
    version: ProtocolVersion,
    /// The lines the driver's framer cuts from the bytes sent after the host's first bytes, in
    /// order; `None` for an overlong one.
    framed: Vec<Option<Vec<u8>>>,
    /// Index into `framed` where each reset and each silence's end came.
    reset_at: Vec<usize>,
    silence_end_at: Vec<usize>,
    /// Every `RD` line the simulator meant to send, whatever became of it.
    originals: HashSet<Key>,
    /// Lines after the host's first bytes by their fate in the log (`intact`, `bitflip`, …).
    kinds: BTreeMap<String, u64>,
    /// Events by name.
    events: BTreeMap<String, u64>,
    /// Entries of lines sent (not silenced) after the host's first bytes.
    lines_sent: u64,
}

impl Replay {
    fn of_log(path: &Path, version: ProtocolVersion) -> Self {
        let text = std::fs::read_to_string(path).unwrap();
        let mut replay = Replay {
            version,
            framed: Vec::new(),
            reset_at: Vec::new(),
            silence_end_at: Vec::new(),
            originals: HashSet::new(),
            kinds: BTreeMap::new(),
            events: BTreeMap::new(),
            lines_sent: 0,
        };
        let mut framer = LineFramer::new(Terminators::Newline);
        let mut started = false;
        // The readings as published: sweep ids go on across a reset of the head.
        let mut sweeps = SweepIds::default();
        for entry in text.lines().map(parse_entry) {
            if let Some(event) = entry.get("event") {
                *replay.events.entry(event.clone()).or_default() += 1;
                match event.as_str() {
                    "start" => started = true,
                    "reset" => {
                        replay.reset_at.push(replay.framed.len());
                        sweeps.head_was_reset();
                    }
                    // The driver reconnects during the silence, with a new framer.
                    "silence" => framer = LineFramer::new(Terminators::Newline),
                    "silence-end" => replay.silence_end_at.push(replay.framed.len()),
                    _ => {}
                }
                continue;
            }
            let line = latin1(&entry["line"]);
            match parse_device(&line, version) {
                Ok(DeviceMessage::Reading(mut r)) => {
                    r.sweep = sweeps.of(r.sweep);
                    replay.originals.insert(wire_key(&r));
                }
                Ok(DeviceMessage::SweepStart { sweep, .. }) => {
                    sweeps.of(sweep);
                }
                _ => {}
            }
            let kind = &entry["kind"];
            if !started || kind == "silenced" {
                continue;
            }
            *replay.kinds.entry(kind.clone()).or_default() += 1;
            replay.lines_sent += 1;
            let mut sent = entry.get("sent").map_or(line, |s| latin1(s));
            if let Some(written) = entry.get("written") {
                sent.truncate(written.parse().unwrap());
            }
            framer.push(&sent, |item| {
                replay.framed.push(match item {
                    FramedLine::Line(l) => Some(l.to_vec()),
                    FramedLine::Overflow => None,
                })
            });
        }
        assert!(started, "the host never spoke to the simulator");
        replay
    }

    fn kind(&self, kind: &str) -> u64 {
        self.kinds.get(kind).copied().unwrap_or(0)
    }
}

/// The log's byte strings: one character per byte.
fn latin1(s: &str) -> Vec<u8> {
    s.chars()
        .map(|c| u8::try_from(u32::from(c)).expect("a Latin-1 character"))
        .collect()
}

/// One line of the fault log: a flat JSON object of strings, numbers and booleans (the latter two
/// kept as their text). The test crate has no JSON library, and this is all the log needs.
fn parse_entry(text: &str) -> HashMap<String, String> {
    let inner = text
        .trim()
        .strip_prefix('{')
        .and_then(|t| t.strip_suffix('}'))
        .unwrap_or_else(|| panic!("not a JSON object: {text}"));
    let mut chars = inner.chars().peekable();
    let mut entry = HashMap::new();
    while chars.peek().is_some() {
        let key = json_string(&mut chars);
        assert_eq!(chars.next(), Some(':'), "{text}");
        let value = if chars.peek() == Some(&'"') {
            json_string(&mut chars)
        } else {
            let mut scalar = String::new();
            while let Some(c) = chars.next_if(|&c| c != ',') {
                scalar.push(c);
            }
            scalar
        };
        chars.next_if_eq(&',');
        entry.insert(key, value);
    }
    entry
}

fn json_string(chars: &mut Peekable<Chars<'_>>) -> String {
    assert_eq!(chars.next(), Some('"'));
    let mut s = String::new();
    loop {
        match chars.next().expect("an unterminated string") {
            '"' => return s,
            '\\' => s.push(match chars.next().expect("an escape") {
                'n' => '\n',
                'r' => '\r',
                't' => '\t',
                'b' => '\u{8}',
                'f' => '\u{c}',
                'u' => {
                    let hex: String = chars.by_ref().take(4).collect();
                    char::from_u32(u32::from_str_radix(&hex, 16).unwrap()).unwrap()
                }
                c => c, // \" \\ \/
            }),
            c => s.push(c),
        }
    }
}

#[test]
fn the_log_reader_reads_json_escapes_and_latin1_bytes() {
    let entry = parse_entry(
        r#"{"sim_ms":12,"kind":"stray","line":"$RD,1*AB\n","sent":"\u0000ÿ\"\\$RD,1*AB\n","joined":true}"#,
    );
    assert_eq!(entry["sim_ms"], "12");
    assert_eq!(entry["kind"], "stray");
    assert_eq!(latin1(&entry["line"]), b"$RD,1*AB\n");
    assert_eq!(latin1(&entry["sent"]), b"\x00\xff\"\\$RD,1*AB\n");
    assert_eq!(entry["joined"], "true");
}
