#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::cell::RefCell;
use std::io::{Cursor, Seek, SeekFrom, Write};
use std::mem::offset_of;
use std::rc::Rc;

use proptest::prelude::*;
use sonar_common::ipc::{FusionCommandKind, ScanCommandKind};

use super::*;

fn reading(seq: u64) -> Reading {
    Reading {
        seq,
        host_stamp_ns: 1_700_000_000_000_000_000 + seq * 20_000_000,
        layout_version: LAYOUT_VERSION,
        device_seq: 7 + seq as u32,
        device_time_ms: 1000 + 20 * seq as u32,
        sweep_id: 3,
        flags: ipc::flags::PINGS_REJECTED,
        angle_deg: -147.0 + 6.0 * seq as f32,
        beam_half_angle_deg: 30.0,
        tof_us: 6990.5,
        distance_m: f32::from_bits(0x3f99_999a), // 1.2000000476…
        speed_of_sound_mps: 343.2,
        min_range_m: 0.03,
        max_range_m: 4.0,
        echo_us: [6990, 6991, 0, 6989, 0, 0, 0, 0],
        direction: -1,
        mode: 1,
        ping_count: 4,
        pings_used: 3,
        reserved: [0; 4],
    }
}

fn sample_messages() -> Vec<(u64, Message)> {
    let t = 1_700_000_000_000_000_000u64;
    vec![
        (
            t,
            Message::Pose(Pose2D {
                stamp_ns: t - 5,
                x_m: 0.5,
                y_m: -0.25,
                theta_rad: 0.1,
                layout_version: LAYOUT_VERSION,
            }),
        ),
        (t + 1, Message::Reading(reading(0))),
        (
            t + 2,
            Message::ScanCommand(ScanCommand::new(ScanCommandKind::LocalScan, -30.0, 30.0)),
        ),
        (t + 3, Message::Reading(reading(1))),
        (
            t + 4,
            Message::FusionCommand(FusionCommand::new(FusionCommandKind::Clear, 0)),
        ),
        (t + 5, Message::Reading(reading(2))),
        (t + 6, Message::Features(features(2))),
        (
            t + 7,
            Message::LocalizedPose(LocalizedPose {
                stamp_ns: t - 4,
                x_m: 0.52,
                y_m: -0.2,
                theta_rad: 0.09,
                layout_version: LAYOUT_VERSION,
                cov_xx: 1e-4,
                cov_xy: -2e-6,
                cov_thetatheta: 3e-4,
                matched: 4,
                fixes: 2,
                odometry_x_m: 0.5,
                odometry_y_m: -0.25,
                odometry_theta_rad: 0.1,
                ..LocalizedPose::default()
            }),
        ),
        (
            t + 8,
            Message::SlamCorrection(SlamCorrection {
                stamp_ns: t - 3,
                layout_version: LAYOUT_VERSION,
                sweep_id: 7,
                state: ipc::slam_state::FIX,
                matched: 3,
                correction_x_m: 0.02,
                correction_y_m: 0.05,
                correction_theta_rad: -0.01,
                correction_cov_thetatheta: 1e-4,
                x_m: 0.52,
                cov_yy: 4e-4,
                odometry_theta_rad: 0.1,
                landmarks: 11,
                fixes: 5,
                refused: 1,
                ..SlamCorrection::default()
            }),
        ),
        (
            t + 9,
            Message::SweepEnd(SweepEnd {
                stamp_ns: t + 9,
                last_seq: 2,
                sweep_id: 7,
                reserved: 0,
            }),
        ),
    ]
}

/// A features snapshot of `n` records: posts, except every third a wall with its segment.
fn features(n: usize) -> FeatureSnapshot {
    let records = (0..n)
        .map(|k| {
            let wall = k % 3 == 2;
            let nan_unless_wall = |v: f32| if wall { v } else { f32::NAN };
            FeatureRecord {
                id: 40 + k as u64,
                kind: if wall {
                    ipc::feature_kind::PLANE
                } else {
                    ipc::feature_kind::POINT
                },
                times_seen: 3 + k as u32,
                x_m: 0.975 + k as f32,
                y_m: -0.01,
                cov_xx: 1e-4,
                cov_xy: -2e-6,
                cov_yy: 3e-4,
                angle_deg: 179.5,
                angle_sigma_deg: nan_unless_wall(0.8),
                confidence: 0.9,
                segment_ax_m: nan_unless_wall(2.0),
                segment_ay_m: nan_unless_wall(-0.5),
                segment_bx_m: nan_unless_wall(2.0),
                segment_by_m: nan_unless_wall(0.5),
                last_seen_sweep: 6,
                flags: if k % 2 == 0 {
                    ipc::feature_flags::CONFIRMED
                } else {
                    0
                },
                reserved: 0,
            }
        })
        .collect::<Vec<_>>();
    FeatureSnapshot {
        header: FeaturesHeader {
            seq: 4,
            stamp_ns: 1_700_000_000_000_000_123,
            sweeps: 6,
            layout_version: LAYOUT_VERSION,
            feature_count: records.len() as u32,
            last_sweep_id: 9,
            last_sweep_rcds: 5,
            last_sweep_refined: 2,
            last_sweep_added: 1,
            last_sweep_removed: 0,
            features_left_out: 0,
        },
        records,
    }
}

/// A `Write + Seek` sink whose bytes stay readable while a writer owns it.
#[derive(Clone, Default)]
struct Shared(Rc<RefCell<Cursor<Vec<u8>>>>);

impl Shared {
    fn bytes(&self) -> Vec<u8> {
        self.0.borrow().get_ref().clone()
    }
}

impl Write for Shared {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.borrow_mut().write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Seek for Shared {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.0.borrow_mut().seek(pos)
    }
}

fn recording_bytes(messages: &[(u64, Message)]) -> Vec<u8> {
    let mut extra = BTreeMap::new();
    extra.insert("source".to_owned(), "unit test".to_owned());
    let mut w = RecordingWriter::new(Cursor::new(Vec::new()), &extra).unwrap();
    for (t, m) in messages {
        w.write(*t, m).unwrap();
    }
    w.finish().unwrap().into_inner()
}

fn same_bits(a: &Message, b: &Message) -> bool {
    a.topic() == b.topic() && a.encode() == b.encode()
}

// ---- the schema texts describe the bytes ------------------------------------------------------

/// (name, byte offset, byte size) of each field of a ros1msg text with only primitive fields.
fn schema_layout(text: &str) -> Vec<(String, usize, usize)> {
    let mut offset = 0;
    let mut fields = Vec::new();
    for line in text.lines() {
        let line = line.split('#').next().unwrap().trim();
        if line.is_empty() {
            continue;
        }
        let (ty, name) = line.split_once(' ').unwrap();
        let (base, count) = match ty.split_once('[') {
            Some((base, n)) => (base, n.trim_end_matches(']').parse::<usize>().unwrap()),
            None => (ty, 1),
        };
        let size = match base {
            "uint64" | "int64" | "float64" => 8,
            "uint32" | "int32" | "float32" => 4,
            "uint8" | "int8" => 1,
            other => panic!("unexpected type {other}"),
        } * count;
        fields.push((name.trim().to_owned(), offset, size));
        offset += size;
    }
    fields
}

/// The fields of schema text `$text` are those of `$ty`, at the same offsets, without padding.
macro_rules! assert_layout {
    ($text:expr, $ty:ty, [$($field:ident),* $(,)?]) => {{
        let what = stringify!($ty);
        let layout = schema_layout($text);
        let rust: Vec<(String, usize)> =
            vec![$((stringify!($field).to_owned(), offset_of!($ty, $field))),*];
        assert_eq!(layout.len(), rust.len(), "{what}: field count");
        for ((name, off, _), (rname, roff)) in layout.iter().zip(&rust) {
            assert_eq!((name, off), (rname, roff), "{what}");
        }
        let (_, last_off, last_size) = layout.last().unwrap();
        assert_eq!(last_off + last_size, size_of::<$ty>(), "{what}: no tail padding");
    }};
}

#[test]
fn schemas_match_the_rust_layouts_field_by_field() {
    assert_layout!(
        Topic::Readings.schema(),
        Reading,
        [
            seq,
            host_stamp_ns,
            layout_version,
            device_seq,
            device_time_ms,
            sweep_id,
            flags,
            angle_deg,
            beam_half_angle_deg,
            tof_us,
            distance_m,
            speed_of_sound_mps,
            min_range_m,
            max_range_m,
            echo_us,
            direction,
            mode,
            ping_count,
            pings_used,
            reserved,
        ]
    );
    assert_layout!(
        Topic::ScanCommands.schema(),
        ScanCommand,
        [kind, from_deg, to_deg, layout_version]
    );
    assert_layout!(Topic::FusionCommands.schema(), FusionCommand, [kind, value]);
    assert_layout!(
        Topic::Pose.schema(),
        Pose2D,
        [stamp_ns, x_m, y_m, theta_rad, layout_version]
    );
    assert_layout!(
        Topic::LocalizedPose.schema(),
        LocalizedPose,
        [
            stamp_ns,
            x_m,
            y_m,
            theta_rad,
            layout_version,
            cov_xx,
            cov_xy,
            cov_xtheta,
            cov_yy,
            cov_ytheta,
            cov_thetatheta,
            matched,
            fixes,
            odometry_x_m,
            odometry_y_m,
            odometry_theta_rad,
            reserved,
        ]
    );
    assert_layout!(
        Topic::SlamCorrection.schema(),
        SlamCorrection,
        [
            stamp_ns,
            layout_version,
            sweep_id,
            state,
            matched,
            correction_x_m,
            correction_y_m,
            correction_theta_rad,
            correction_cov_xx,
            correction_cov_xy,
            correction_cov_xtheta,
            correction_cov_yy,
            correction_cov_ytheta,
            correction_cov_thetatheta,
            x_m,
            y_m,
            theta_rad,
            cov_xx,
            cov_xy,
            cov_xtheta,
            cov_yy,
            cov_ytheta,
            cov_thetatheta,
            odometry_x_m,
            odometry_y_m,
            odometry_theta_rad,
            landmarks,
            fixes,
            refused,
        ]
    );
    assert_layout!(
        Topic::SweepEnds.schema(),
        SweepEnd,
        [stamp_ns, last_seq, sweep_id, reserved]
    );
    let sizes = [
        (Topic::Readings, size_of::<Reading>()),
        (Topic::ScanCommands, size_of::<ScanCommand>()),
        (Topic::FusionCommands, size_of::<FusionCommand>()),
        (Topic::Pose, size_of::<Pose2D>()),
        (Topic::LocalizedPose, size_of::<LocalizedPose>()),
        (Topic::SlamCorrection, size_of::<SlamCorrection>()),
        (Topic::SweepEnds, size_of::<SweepEnd>()),
    ];
    for (topic, size) in sizes {
        assert_eq!(topic.message_size(), Some(size), "{topic}");
    }

    // Features: the header's fields, the array of records (a ROS 1 uint32 count), then the
    // record type after the separator line.
    let (header, rest) = Topic::Features
        .schema()
        .split_once("sonar/FeatureRecordV2[] features\n")
        .unwrap();
    let (separator, record) = rest.split_once("MSG: sonar/FeatureRecordV2\n").unwrap();
    assert_eq!(separator, format!("{}\n", "=".repeat(80)));
    assert_layout!(
        header,
        FeaturesHeader,
        [
            seq,
            stamp_ns,
            sweeps,
            layout_version,
            feature_count,
            last_sweep_id,
            last_sweep_rcds,
            last_sweep_refined,
            last_sweep_added,
            last_sweep_removed,
            features_left_out,
        ]
    );
    assert_layout!(
        record,
        FeatureRecord,
        [
            id,
            kind,
            times_seen,
            x_m,
            y_m,
            cov_xx,
            cov_xy,
            cov_yy,
            angle_deg,
            angle_sigma_deg,
            confidence,
            segment_ax_m,
            segment_ay_m,
            segment_bx_m,
            segment_by_m,
            last_seen_sweep,
            flags,
            reserved,
        ]
    );
    assert_eq!(Topic::Features.message_size(), None);
    assert_eq!(FEATURES_PREFIX_SIZE, 56 + 4);
}

/// On a little-endian machine the encoding is the payload's memory image, the bytes that travel
/// in shared memory (the layouts have no padding, checked above).
#[cfg(target_endian = "little")]
#[test]
fn encoding_is_the_shared_memory_image() {
    fn image<T>(v: &T) -> Vec<u8> {
        // SAFETY: T is one of the padding-free #[repr(C)] payloads (every byte initialised).
        unsafe { std::slice::from_raw_parts((v as *const T).cast::<u8>(), size_of::<T>()) }.to_vec()
    }
    for (_, m) in sample_messages() {
        let expected = match &m {
            Message::Reading(r) => image(r),
            Message::ScanCommand(c) => image(c),
            Message::FusionCommand(c) => image(c),
            Message::Pose(p) => image(p),
            Message::LocalizedPose(p) => image(p),
            Message::SlamCorrection(c) => image(c),
            Message::SweepEnd(e) => image(e),
            Message::Features(f) => {
                let mut bytes = image(&f.header);
                bytes.extend_from_slice(&(f.records.len() as u32).to_le_bytes());
                for r in &f.records {
                    bytes.extend(image(r));
                }
                bytes
            }
        };
        assert_eq!(m.encode(), expected, "{}", m.topic());
    }
}

#[test]
fn a_message_of_the_wrong_size_is_an_error() {
    let bytes = Message::Reading(reading(1)).encode();
    for len in [0, 1, 103, 105] {
        let mut b = bytes.clone();
        b.resize(len, 0);
        assert!(matches!(
            Message::decode(Topic::Readings, &b),
            Err(FormatError::BadMessage { len: l, expected: 104, .. }) if l == len
        ));
    }
}

#[test]
fn a_features_message_must_hold_the_records_it_counts() {
    let bytes = Message::Features(features(2)).encode();
    assert_eq!(bytes.len(), 60 + 2 * 80);
    for len in [0, 59, 60, 60 + 80, 60 + 2 * 80 - 1] {
        assert!(
            matches!(
                Message::decode(Topic::Features, &bytes[..len]),
                Err(FormatError::BadMessage { .. })
            ),
            "{len} bytes"
        );
    }
    let mut three = bytes.clone();
    three[56..60].copy_from_slice(&3u32.to_le_bytes());
    assert!(matches!(
        Message::decode(Topic::Features, &three),
        Err(FormatError::BadMessage {
            len: 220,
            expected: 300,
            ..
        })
    ));
    // A count no file could hold is an error, not an allocation.
    let mut huge = bytes.clone();
    huge[56..60].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(
        Message::decode(Topic::Features, &huge),
        Err(FormatError::BadMessage { len: 220, .. })
    ));
    let empty = Message::Features(features(0));
    assert_eq!(
        Message::decode(Topic::Features, &empty.encode()).unwrap(),
        empty
    );
}

proptest! {
    /// Any bytes of the right size decode and encode back to themselves: every bit of every field
    /// (NaN payloads, negative zero, reserved bytes) survives.
    #[test]
    fn every_bit_round_trips(
        bytes in proptest::collection::vec(any::<u8>(), 120),
        topic in proptest::sample::select(
            Topic::ALL.into_iter().filter(|t| t.message_size().is_some()).collect::<Vec<_>>(),
        ),
    ) {
        let bytes = &bytes[..topic.message_size().unwrap()];
        let m = Message::decode(topic, bytes).unwrap();
        prop_assert_eq!(m.encode(), bytes.to_vec());
    }

    /// The same for features messages of any number of records.
    #[test]
    fn every_bit_of_features_round_trips(
        mut bytes in proptest::collection::vec(any::<u8>(), 60 + 3 * 80),
        count in 0usize..=3,
    ) {
        bytes[56..60].copy_from_slice(&(count as u32).to_le_bytes());
        let bytes = &bytes[..60 + count * 80];
        let m = Message::decode(Topic::Features, bytes).unwrap();
        prop_assert_eq!(m.encode(), bytes.to_vec());
    }
}

// ---- whole files ------------------------------------------------------------------------------

#[test]
fn a_recording_reads_back_exactly() {
    let messages = sample_messages();
    let bytes = recording_bytes(&messages);
    let rec = read(&bytes, ReadOptions::default()).unwrap();
    assert!(!rec.truncated);
    assert_eq!(rec.skipped, 0);
    assert_eq!(
        rec.metadata.get("format_version").map(String::as_str),
        Some("1")
    );
    assert_eq!(
        rec.metadata.get("source").map(String::as_str),
        Some("unit test")
    );
    assert_eq!(rec.entries.len(), messages.len());
    for (entry, (t, m)) in rec.entries.iter().zip(&messages) {
        assert_eq!(entry.log_time_ns, *t);
        assert!(same_bits(&entry.message, m), "{entry:?} vs {m:?}");
    }
    assert_eq!(rec.count(Topic::Readings), 3);
    assert_eq!(rec.readings().map(|r| r.seq).collect::<Vec<_>>(), [0, 1, 2]);
}

#[test]
fn extra_channels_are_written_beside_ours_and_skipped_on_reading() {
    let messages = sample_messages();
    let mut w = RecordingWriter::new(Cursor::new(Vec::new()), &BTreeMap::new()).unwrap();
    let mut grid = w
        .add_channel(
            "/foxglove/map",
            "foxglove.Grid",
            "protobuf",
            b"descriptor",
            "protobuf",
        )
        .unwrap();
    assert!(matches!(
        w.add_channel("sonar/readings", "x", "protobuf", b"", "protobuf"),
        Err(FormatError::ReservedTopic(_))
    ));
    for (i, (t, m)) in messages.iter().enumerate() {
        w.write(*t, m).unwrap();
        if i % 2 == 0 {
            w.write_extra(&mut grid, *t, *t, &[1, 2, 3]).unwrap();
        }
    }
    let bytes = w.finish().unwrap().into_inner();
    let rec = read(&bytes, ReadOptions::default()).unwrap();
    assert_eq!(rec.skipped, messages.len().div_ceil(2) as u64);
    assert_eq!(rec.entries.len(), messages.len());
    for (entry, (_, m)) in rec.entries.iter().zip(&messages) {
        assert!(same_bits(&entry.message, m), "{entry:?} vs {m:?}");
    }
}

#[test]
fn an_empty_recording_is_valid() {
    let rec = read(&recording_bytes(&[]), ReadOptions::default()).unwrap();
    assert!(rec.entries.is_empty());
}

#[test]
fn nan_and_odd_floats_keep_their_bits() {
    let mut r = reading(5);
    r.distance_m = f32::from_bits(0x7fc0_1234); // a NaN with a payload
    r.tof_us = -0.0;
    r.angle_deg = f32::INFINITY;
    let bytes = recording_bytes(&[(1, Message::Reading(r))]);
    let rec = read(&bytes, ReadOptions::default()).unwrap();
    let Message::Reading(back) = rec.entries[0].message.clone() else {
        panic!("not a reading")
    };
    assert_eq!(back.distance_m.to_bits(), 0x7fc0_1234);
    assert_eq!(back.tof_us.to_bits(), (-0.0f32).to_bits());
    assert_eq!(back.angle_deg, f32::INFINITY);
}

#[test]
fn a_file_cut_anywhere_is_a_clear_error_and_salvageable() {
    let messages = sample_messages();
    let bytes = recording_bytes(&messages);
    for len in 0..bytes.len() {
        let cut = &bytes[..len];
        match read(cut, ReadOptions::default()) {
            Err(FormatError::Empty) => assert_eq!(len, 0),
            Err(FormatError::Truncated { .. }) => {}
            other => panic!("cut at {len} of {}: {other:?}", bytes.len()),
        }
        let salvage = ReadOptions {
            allow_truncated: true,
        };
        if let Ok(rec) = read(cut, salvage) {
            // Whatever comes back is a prefix of what was written.
            assert!(rec.entries.len() <= messages.len());
            for (e, (_, m)) in rec.entries.iter().zip(&messages) {
                assert!(same_bits(&e.message, m));
            }
        }
    }
}

#[test]
fn a_killed_recorder_leaves_everything_up_to_its_last_flush() {
    let sink = Shared::default();
    let mut w = RecordingWriter::new(sink.clone(), &BTreeMap::new()).unwrap();
    let messages = sample_messages();
    for (t, m) in &messages[..4] {
        w.write(*t, m).unwrap();
    }
    w.flush().unwrap();
    for (t, m) in &messages[4..] {
        w.write(*t, m).unwrap();
    }
    // The process dies here: the file holds what reached the sink.
    let bytes = sink.bytes();
    std::mem::forget(w);

    let strict = read(&bytes, ReadOptions::default());
    assert!(
        matches!(strict, Err(FormatError::Truncated { messages: 4 })),
        "{strict:?}"
    );
    let rec = read(
        &bytes,
        ReadOptions {
            allow_truncated: true,
        },
    )
    .unwrap();
    assert!(rec.truncated);
    assert_eq!(rec.entries.len(), 4);
    for (e, (_, m)) in rec.entries.iter().zip(&messages) {
        assert!(same_bits(&e.message, m));
    }
}

#[test]
fn damage_inside_a_chunk_is_caught_by_its_crc() {
    let messages = sample_messages();
    let bytes = recording_bytes(&messages);
    let payload = Message::Reading(reading(1)).encode();
    let at = bytes
        .windows(payload.len())
        .position(|w| w == payload)
        .expect("the reading's bytes are in the file");
    for offset in [0, 40, 103] {
        let mut damaged = bytes.clone();
        damaged[at + offset] ^= 0x10;
        let err = read(
            &damaged,
            ReadOptions {
                allow_truncated: true,
            },
        )
        .unwrap_err();
        assert!(
            matches!(&err, FormatError::Corrupt { what, .. } if what.contains("CRC")),
            "{err}"
        );
    }
}

#[test]
fn damage_outside_the_chunks_is_caught_by_the_data_section_crc() {
    let mut bytes = recording_bytes(&sample_messages());
    let at = bytes
        .windows(9)
        .position(|w| w == b"unit test")
        .expect("the metadata is in the file");
    bytes[at] = b'U';
    let err = read(&bytes, ReadOptions::default()).unwrap_err();
    assert!(
        matches!(&err, FormatError::Corrupt { what, .. } if what.contains("data section CRC")),
        "{err}"
    );
}

#[test]
fn random_bytes_are_not_an_mcap_file() {
    let bytes: Vec<u8> = (0..4096u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    assert!(matches!(
        read(&bytes, ReadOptions::default()),
        Err(FormatError::NotMcap)
    ));
    assert!(matches!(
        read(&[], ReadOptions::default()),
        Err(FormatError::Empty)
    ));
}

fn plain_mcap(metadata: Option<(&str, &str)>, schema_name: &str) -> Vec<u8> {
    let mut w = mcap::Writer::new(Cursor::new(Vec::new())).unwrap();
    if let Some((key, value)) = metadata {
        w.write_metadata(&Metadata {
            name: METADATA_NAME.into(),
            metadata: [(key.to_owned(), value.to_owned())].into(),
        })
        .unwrap();
    }
    let schema = w
        .add_schema(schema_name, SCHEMA_ENCODING, READING_SCHEMA.as_bytes())
        .unwrap();
    let channel = w
        .add_channel(
            schema,
            ipc::READINGS_SERVICE,
            MESSAGE_ENCODING,
            &BTreeMap::new(),
        )
        .unwrap();
    let other_schema = w
        .add_schema("std_msgs/String", "ros1msg", b"string data")
        .unwrap();
    let other = w
        .add_channel(other_schema, "/chatter", MESSAGE_ENCODING, &BTreeMap::new())
        .unwrap();
    for (ch, data) in [
        (channel, Message::Reading(reading(0)).encode()),
        (other, vec![0; 4]),
    ] {
        w.write_to_known_channel(
            &MessageHeader {
                channel_id: ch,
                sequence: 0,
                log_time: 1,
                publish_time: 1,
            },
            &data,
        )
        .unwrap();
    }
    w.finish().unwrap();
    w.into_inner().into_inner()
}

#[test]
fn versions_and_schemas_are_checked() {
    let ok = plain_mcap(Some(("format_version", "1")), "sonar/ReadingV1");
    let rec = read(&ok, ReadOptions::default()).unwrap();
    assert_eq!(
        (rec.entries.len(), rec.skipped),
        (1, 1),
        "unknown channels are skipped"
    );
    // Like a recording made before `sonar/features` was recorded: the channel is simply absent.
    assert_eq!(rec.count(Topic::Features), 0);

    let newer = plain_mcap(Some(("format_version", "2")), "sonar/ReadingV1");
    let err = read(&newer, ReadOptions::default()).unwrap_err();
    assert!(matches!(&err, FormatError::UnsupportedVersion { found } if found == "2"));
    assert!(
        err.to_string().contains("use a newer sonar-replay"),
        "{err}"
    );

    let garbled = plain_mcap(Some(("format_version", "one")), "sonar/ReadingV1");
    assert!(matches!(
        read(&garbled, ReadOptions::default()),
        Err(FormatError::UnsupportedVersion { .. })
    ));

    let foreign = plain_mcap(None, "sonar/ReadingV1");
    assert!(matches!(
        read(&foreign, ReadOptions::default()),
        Err(FormatError::NotARecording)
    ));

    let v2 = plain_mcap(Some(("format_version", "1")), "sonar/ReadingV2");
    let err = read(&v2, ReadOptions::default()).unwrap_err();
    assert!(
        matches!(&err, FormatError::UnsupportedSchema { found, .. } if found == "sonar/ReadingV2")
    );
}

/// A recording of one `sonar/features` channel with the given schema name and messages.
fn features_mcap(schema_name: &str, messages: &[&[u8]]) -> Vec<u8> {
    let mut w = mcap::Writer::new(Cursor::new(Vec::new())).unwrap();
    w.write_metadata(&Metadata {
        name: METADATA_NAME.into(),
        metadata: [("format_version".to_owned(), "1".to_owned())].into(),
    })
    .unwrap();
    let schema = w.add_schema(schema_name, SCHEMA_ENCODING, b"").unwrap();
    let channel = w
        .add_channel(
            schema,
            ipc::FEATURES_SERVICE,
            MESSAGE_ENCODING,
            &BTreeMap::new(),
        )
        .unwrap();
    for data in messages {
        w.write_to_known_channel(
            &MessageHeader {
                channel_id: channel,
                sequence: 0,
                log_time: 1,
                publish_time: 1,
            },
            data,
        )
        .unwrap();
    }
    w.finish().unwrap();
    w.into_inner().into_inner()
}

/// A recording made before the feature records had their flags (schema `sonar/FeaturesV1`,
/// 72 bytes a record) still reads, every field as written and the flags 0; a message of the
/// current layout on such a channel is refused.
#[test]
fn features_recorded_before_their_flags_still_read() {
    let snapshot = features(3);
    let current = Message::Features(snapshot.clone()).encode();
    // The older layout: the same bytes without each record's trailing flags and padding.
    let mut older = current[..FEATURES_PREFIX_SIZE].to_vec();
    for record in current[FEATURES_PREFIX_SIZE..].chunks(size_of::<FeatureRecord>()) {
        older.extend_from_slice(&record[..FEATURE_RECORD_V1_SIZE]);
    }

    let rec = read(
        &features_mcap(FEATURES_V1_SCHEMA_NAME, &[&older]),
        ReadOptions::default(),
    )
    .unwrap();
    let [
        Entry {
            message: Message::Features(read_back),
            ..
        },
    ] = rec.entries.as_slice()
    else {
        panic!("one features message expected: {:?}", rec.entries);
    };
    let mut expected = snapshot;
    for r in &mut expected.records {
        r.flags = 0;
    }
    // Bit for bit: the records hold NaNs, which `==` never equals.
    assert_eq!(
        Message::Features(read_back.clone()).encode(),
        Message::Features(expected).encode()
    );

    assert!(matches!(
        read(
            &features_mcap(FEATURES_V1_SCHEMA_NAME, &[&current]),
            ReadOptions::default()
        ),
        Err(FormatError::BadMessage {
            topic: Topic::Features,
            ..
        })
    ));
    assert!(matches!(
        read(
            &features_mcap("sonar/FeaturesV0", &[&older]),
            ReadOptions::default()
        ),
        Err(FormatError::UnsupportedSchema { .. })
    ));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Garbage is an error, never a panic, whether or not it starts like an MCAP file.
    #[test]
    fn random_bytes_never_panic(tail in proptest::collection::vec(any::<u8>(), 0..2048), magic in any::<bool>()) {
        let mut bytes = if magic { mcap::MAGIC.to_vec() } else { Vec::new() };
        bytes.extend_from_slice(&tail);
        prop_assert!(read(&bytes, ReadOptions::default()).is_err());
        let _ = read(&bytes, ReadOptions { allow_truncated: true });
    }

    /// Damage anywhere in a real recording is reported (or, in bytes no reader checks, such as
    /// the summary's statistics, tolerated), never a panic; damage inside a chunk is caught by its
    /// CRC.
    #[test]
    fn flipped_bytes_never_panic(flips in proptest::collection::vec((any::<prop::sample::Index>(), 1u8..=255), 1..8)) {
        let mut bytes = recording_bytes(&sample_messages());
        for (at, xor) in &flips {
            let i = at.index(bytes.len());
            bytes[i] ^= xor;
        }
        let _ = read(&bytes, ReadOptions::default());
        let _ = read(&bytes, ReadOptions { allow_truncated: true });
    }
}
