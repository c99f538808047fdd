//! The body of the fuzz target `lines`, a plain function so that the stable test
//! `driver/tests/fuzz_lines.rs` runs it too (it includes this file), on a fixed corpus, where CI
//! cannot install a nightly toolchain. It panics on any broken promise:
//!
//! - the framer cuts the same lines whether the bytes come at once or one at a time, none longer
//!   than [`MAX_LINE_LEN`] and none with a terminator in it;
//! - nothing panics: the device and command parsers of both protocol versions, the hobby parser,
//!   the driver's [`Decoder`] in both dialects (also after adopting the geometry of any `HELLO`);
//! - a line taken as a reading (or a command) re-encodes to the same line, but for the case of the
//!   check digits: one meaning, one spelling;
//! - the decoder takes exactly the lines the parser takes, and a reading carries the line's raw
//!   fields unchanged, with a plausible range.
//!
//! Each line is tried as it came and once more with a matching check (`$` + its body + `*` +
//! check): a random check almost never matches, and the field parsers behind it would otherwise go
//! unexplored.

use sonar_common::ipc::{Reading, flags};
use sonar_common::protocol::{
    DeviceMessage, FramedLine, LineFramer, MAX_LINE_LEN, ProtocolVersion, Terminators, WireReading,
    encode_command, encode_device, parse_command, parse_device, parse_hobby,
};
use sonar_common::sensor::SensorConfig;
use sonar_driver::averaging::PingPolicy;
use sonar_driver::decoder::{Decoded, Decoder, Dialect};

const VERSIONS: [ProtocolVersion; 2] = [ProtocolVersion::V1, ProtocolVersion::V2];
/// The driver's default: the hobby sketches' servo points forward at 90°.
const HOBBY_OFFSET_DEG: f32 = -90.0;

/// Arbitrary bytes as they might come off a serial line; see the crate docs.
pub fn lines(data: &[u8]) {
    let mut decoders = VERSIONS.map(|v| decoder(Dialect::Native).speaking(v));
    let native = frame(data, Terminators::Newline);
    for line in native.iter().flatten().map(Vec::as_slice).chain([data]) {
        for (&version, decoder) in VERSIONS.iter().zip(&mut decoders) {
            native_line(line, version, decoder);
            native_line(&with_check(line, version), version, decoder);
        }
    }
    let mut hobby = decoder(Dialect::Hobby);
    let records = frame(data, Terminators::Hobby);
    for record in records.iter().flatten().map(Vec::as_slice).chain([data]) {
        hobby_record(record, &mut hobby);
    }
}

fn decoder(dialect: Dialect) -> Decoder {
    Decoder::new(
        dialect,
        SensorConfig::default(),
        PingPolicy::default(),
        HOBBY_OFFSET_DEG,
    )
}

/// The framer's lines (`None` for an overlong one), checked against a byte-at-a-time framing.
fn frame(data: &[u8], terminators: Terminators) -> Vec<Option<Vec<u8>>> {
    let cut = |chunks: &mut dyn Iterator<Item = &[u8]>| {
        let mut framer = LineFramer::new(terminators);
        let mut out = Vec::new();
        for chunk in chunks {
            framer.push(chunk, |item| {
                out.push(match item {
                    FramedLine::Line(l) => Some(l.to_vec()),
                    FramedLine::Overflow => None,
                })
            });
        }
        out
    };
    let at_once = cut(&mut std::iter::once(data));
    assert_eq!(
        at_once,
        cut(&mut data.chunks(1)),
        "framing depends on how the bytes arrive"
    );
    let ends_line = |b: &u8| match terminators {
        Terminators::Newline => *b == b'\n',
        Terminators::Hobby => matches!(b, b'\n' | b'\r' | b'.' | b'#'),
    };
    for line in at_once.iter().flatten() {
        assert!(!line.is_empty() && line.len() <= MAX_LINE_LEN, "{line:?}");
        assert!(!line.iter().any(ends_line), "a terminator in {line:?}");
        assert!(!matches!(line.last(), Some(b'\r' | b'\n')), "{line:?}");
    }
    at_once
}

/// `$` + the line's body (without a `$` before or a check after it) + `*` + its check.
fn with_check(line: &[u8], version: ProtocolVersion) -> Vec<u8> {
    let body = line.strip_prefix(b"$").unwrap_or(line);
    let body = match body.iter().rposition(|&b| b == b'*') {
        Some(star) => &body[..star],
        None => body,
    };
    let check = match version {
        ProtocolVersion::V1 => format!("{:02X}", version.check(body)),
        ProtocolVersion::V2 => format!("{:04X}", version.check(body)),
    };
    [b"$", body, b"*", check.as_bytes()].concat()
}

fn native_line(line: &[u8], version: ProtocolVersion, decoder: &mut Decoder) {
    let parsed = parse_device(line, version);
    if let Ok(DeviceMessage::Reading(r)) = &parsed {
        assert_same_line(&encode_device(&DeviceMessage::Reading(*r), version), line);
    }
    if let Ok(cmd) = parse_command(line, version) {
        assert_same_line(&encode_command(&cmd, version), line);
    }
    let before = decoder.readings_decoded();
    match (parsed, decoder.decode(line, 7)) {
        (Ok(DeviceMessage::Reading(wire)), Ok(Decoded::Reading(r))) => {
            assert_eq!(r.seq, before, "sequence numbers without gaps");
            assert_carries(&r, &wire, decoder.sensor());
        }
        (Ok(msg), Ok(Decoded::Message(decoded))) => {
            assert_eq!(msg, decoded);
            // As the driver does with a HELLO: whatever geometry it announces.
            decoder.adopt_device_geometry(&decoded);
        }
        (Err(parse), Err(decode)) => assert_eq!(parse, decode),
        (parsed, decoded) => panic!(
            "parser and decoder disagree on {:?}: {parsed:?} / {decoded:?}",
            String::from_utf8_lossy(line)
        ),
    }
    if !matches!(decoder.readings_decoded() - before, 0 | 1) {
        panic!("one line, more than one reading");
    }
}

/// `line` is what `encoded` encodes, but for the case of the check digits and the terminator.
fn assert_same_line(encoded: &str, line: &[u8]) {
    let want = encoded.trim_end_matches('\n').as_bytes();
    let mut got = line;
    while let [rest @ .., b'\r' | b'\n'] = got {
        got = rest;
    }
    let Some(star) = want.iter().rposition(|&b| b == b'*') else {
        panic!("an encoded line without a check: {encoded:?}");
    };
    let same = got.len() == want.len()
        && got[..=star] == want[..=star]
        && got[star + 1..].eq_ignore_ascii_case(&want[star + 1..]);
    assert!(
        same,
        "{:?} was taken, but reads back as {encoded:?}",
        String::from_utf8_lossy(line)
    );
}

/// A decoded reading carries the wire's raw fields unchanged, and a plausible range.
fn assert_carries(r: &Reading, wire: &WireReading, sensor: &SensorConfig) {
    let n = usize::from(wire.ping_count);
    assert_eq!(
        (r.device_seq, r.device_time_ms, r.sweep_id, r.ping_count),
        (wire.seq, wire.time_ms, wire.sweep, wire.ping_count)
    );
    assert_eq!(i32::from(r.direction), wire.direction.sign());
    assert_eq!(
        r.angle_deg.to_bits(),
        (wire.angle_cdeg as f32 / 100.0).to_bits()
    );
    assert_eq!(&r.echo_us[..n], wire.pings());
    assert!(r.echo_us[n..].iter().all(|&e| e == 0));
    assert_eq!(r.flags & flags::NO_RAW_PINGS, 0);
    assert!(r.pings_used <= r.ping_count, "{r:?}");
    if r.is_valid_range() {
        // The mean of ranges within the limits, but for the rounding of an f32 mean.
        let (lo, hi) = (sensor.min_range_m * 0.9999, sensor.max_range_m * 1.0001);
        assert!(
            (lo..=hi).contains(&r.distance_m) && r.pings_used > 0,
            "{r:?}"
        );
    }
}

fn hobby_record(record: &[u8], decoder: &mut Decoder) {
    match (parse_hobby(record), decoder.decode(record, 7)) {
        (Ok(hobby), Ok(Decoded::Reading(r))) => {
            assert_eq!(r.angle_deg, hobby.angle_deg + HOBBY_OFFSET_DEG);
            assert_eq!(r.ping_count, 1);
            assert_ne!(r.flags & flags::NO_RAW_PINGS, 0);
            assert!(r.pings_used <= 1 && r.distance_m.is_finite(), "{r:?}");
        }
        (Err(parse), Err(decode)) => assert_eq!(parse, decode),
        (parsed, decoded) => panic!(
            "hobby parser and decoder disagree on {:?}: {parsed:?} / {decoded:?}",
            String::from_utf8_lossy(record)
        ),
    }
}
