//! The recording file: MCAP with one channel per recorded service, each message the payload's
//! little-endian bytes. `docs/recording.md` is the specification; this module is its reference
//! implementation.
//!
//! Why these choices:
//! - MCAP is what Foxglove, `mcap` (CLI) and the ROS tools open, and the `mcap` crate is Foxglove's
//!   own. The file is chunked (CRC per chunk), indexed, and ends with a summary.
//! - The payloads are `#[repr(C)]` plain data without padding, little-endian, so their bytes are
//!   also exactly the ROS 1 serialisation of a `.msg` definition with the same fields in the same
//!   order (ROS 1 packs fields without padding, little-endian, fixed arrays without a length). So
//!   each channel declares message encoding `ros1` with a `ros1msg` schema, so ROS 1 decoders (such
//!   as Foxglove's) show every field by name, while our replay copies the bytes back unchanged
//!   (exact `f32` bits).
//! - The file-level version is a `sonar_recording` metadata record written before any message;
//!   the type version is in each schema name (`sonar/ReadingV1`), as in `docs/ipc.md`.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

use mcap::records::{MessageHeader, Metadata, Record};
use mcap::{McapError, WriteOptions};
use sonar_common::ipc::{
    self, FeatureRecord, FeaturesHeader, FusionCommand, LAYOUT_VERSION, LocalizedPose, MAX_PINGS,
    Pose2D, Reading, ScanCommand, SlamCorrection, SweepEnd,
};

/// Version of the recording format this crate writes and the newest it reads.
pub const FORMAT_VERSION: u32 = 1;
/// Name of the metadata record that marks a file as a sonar recording and carries its version.
pub const METADATA_NAME: &str = "sonar_recording";
/// Value of the `format` key in that record.
pub const FORMAT_NAME: &str = "sonar-recording";
/// MCAP message encoding of every channel.
pub const MESSAGE_ENCODING: &str = "ros1";
/// MCAP schema encoding of every schema.
pub const SCHEMA_ENCODING: &str = "ros1msg";

const _: () = assert!(MAX_PINGS == 8, "READING_SCHEMA says uint32[8] echo_us");

/// `sonar::ReadingV1` as a ROS 1 message definition (the bytes are identical, see the module docs).
pub const READING_SCHEMA: &str = "\
# sonar::ReadingV1 (docs/ipc.md): 104 bytes, little-endian, no padding
uint64 seq
uint64 host_stamp_ns
uint32 layout_version
uint32 device_seq
uint32 device_time_ms
uint32 sweep_id
uint32 flags
float32 angle_deg
float32 beam_half_angle_deg
float32 tof_us
float32 distance_m
float32 speed_of_sound_mps
float32 min_range_m
float32 max_range_m
uint32[8] echo_us
int8 direction
uint8 mode
uint8 ping_count
uint8 pings_used
uint8[4] reserved
";

/// `sonar::ScanCommandV1`.
pub const SCAN_COMMAND_SCHEMA: &str = "\
# sonar::ScanCommandV1 (docs/ipc.md): 16 bytes, little-endian
uint32 kind
float32 from_deg
float32 to_deg
uint32 layout_version
";

/// `sonar::FusionCommandV1`.
pub const FUSION_COMMAND_SCHEMA: &str = "\
# sonar::FusionCommandV1 (common/src/ipc.rs): 8 bytes, little-endian
uint32 kind
uint32 value
";

/// `sonar::Pose2DV1`.
pub const POSE_SCHEMA: &str = "\
# sonar::Pose2DV1 (common/src/ipc.rs): 24 bytes, little-endian
uint64 stamp_ns
float32 x_m
float32 y_m
float32 theta_rad
uint32 layout_version
";

/// `sonar::LocalizedPoseV1`: the fusion's localised pose of a sweep (`--localize`).
pub const LOCALIZED_POSE_SCHEMA: &str = "\
# sonar::LocalizedPoseV1 (common/src/ipc.rs): 72 bytes, little-endian
uint64 stamp_ns
float32 x_m
float32 y_m
float32 theta_rad
uint32 layout_version
float32 cov_xx
float32 cov_xy
float32 cov_xtheta
float32 cov_yy
float32 cov_ytheta
float32 cov_thetatheta
uint32 matched
uint32 fixes
float32 odometry_x_m
float32 odometry_y_m
float32 odometry_theta_rad
uint32 reserved
";

/// `sonar::SweepEndV1`: a sweep the head reported ended, after its last reading.
pub const SWEEP_END_SCHEMA: &str = "\
# sonar::SweepEndV1 (docs/ipc.md): 24 bytes, little-endian
uint64 stamp_ns
uint64 last_seq
uint32 sweep_id
uint32 reserved
";

/// `sonar::SlamCorrectionV1`: `sonar-slam`'s correction of the odometry (`map → odom`) at a sweep.
pub const SLAM_CORRECTION_SCHEMA: &str = "\
# sonar::SlamCorrectionV1 (common/src/ipc.rs): 120 bytes, little-endian
uint64 stamp_ns
uint32 layout_version
uint32 sweep_id
uint32 state
uint32 matched
float32 correction_x_m
float32 correction_y_m
float32 correction_theta_rad
float32 correction_cov_xx
float32 correction_cov_xy
float32 correction_cov_xtheta
float32 correction_cov_yy
float32 correction_cov_ytheta
float32 correction_cov_thetatheta
float32 x_m
float32 y_m
float32 theta_rad
float32 cov_xx
float32 cov_xy
float32 cov_xtheta
float32 cov_yy
float32 cov_ytheta
float32 cov_thetatheta
float32 odometry_x_m
float32 odometry_y_m
float32 odometry_theta_rad
uint32 landmarks
uint32 fixes
uint32 refused
";

/// `sonar::FeaturesHeaderV1` followed by its `sonar::FeatureRecordV2`s. ROS 1 writes a
/// variable-length array as a `uint32` count and the elements, so the message is the 56-byte
/// header, the number of records, then 80 bytes a record; the record type follows the separator
/// line, as `ros1msg` carries dependent types. Recordings made before the records had their flags
/// name the schema [`FEATURES_V1_SCHEMA_NAME`] (72 bytes a record, without `flags` and
/// `reserved`); they are read with `flags` 0.
pub const FEATURES_SCHEMA: &str = "\
# sonar::FeaturesHeaderV1 + [sonar::FeatureRecordV2] (docs/ipc.md): 56 + 4 + 80 bytes a record
uint64 seq
uint64 stamp_ns
uint64 sweeps
uint32 layout_version
uint32 feature_count
uint32 last_sweep_id
uint32 last_sweep_rcds
uint32 last_sweep_refined
uint32 last_sweep_added
uint32 last_sweep_removed
uint32 features_left_out
sonar/FeatureRecordV2[] features
================================================================================
MSG: sonar/FeatureRecordV2
uint64 id
uint32 kind
uint32 times_seen
float32 x_m
float32 y_m
float32 cov_xx
float32 cov_xy
float32 cov_yy
float32 angle_deg
float32 angle_sigma_deg
float32 confidence
float32 segment_ax_m
float32 segment_ay_m
float32 segment_bx_m
float32 segment_by_m
uint64 last_seen_sweep
uint32 flags
uint32 reserved
";

/// The features' schema name in recordings made before the records had their flags.
pub const FEATURES_V1_SCHEMA_NAME: &str = "sonar/FeaturesV1";
/// Bytes of a record in those recordings: [`FeatureRecord`] without `flags` and `reserved`.
const FEATURE_RECORD_V1_SIZE: usize = 72;

/// Bytes of a features message before its records: the header and the records' count.
pub const FEATURES_PREFIX_SIZE: usize = size_of::<FeaturesHeader>() + 4;

/// A recorded service: one MCAP channel each.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Topic {
    /// `sonar/readings`, [`Reading`].
    Readings,
    /// `sonar/commands`, [`ScanCommand`].
    ScanCommands,
    /// `sonar/fusion_commands`, [`FusionCommand`].
    FusionCommands,
    /// `robot/pose`, [`Pose2D`].
    Pose,
    /// `sonar/features`, [`FeatureSnapshot`]: recorded, never replayed (the fusion derives the
    /// features from the readings).
    Features,
    /// `sonar/localized_pose`, [`LocalizedPose`]: recorded, never replayed (the fusion's
    /// `--localize` derives it); what an export draws `map → odom` with.
    LocalizedPose,
    /// `sonar/slam_correction`, [`SlamCorrection`]: recorded, never replayed (`sonar-slam`
    /// derives it); what an export draws `map → odom` with, and places the readings with when
    /// asked to (`sonar-export --slam-correction`).
    SlamCorrection,
    /// `sonar/sweep_ends`, [`SweepEnd`]: where the head said its sweeps ended, so that an
    /// export closes each sweep where the live fusion did (recordings without it close a sweep
    /// on the next one's first reading, as the fusion does without the driver's word).
    SweepEnds,
}

impl Topic {
    pub const ALL: [Topic; 8] = [
        Topic::Readings,
        Topic::ScanCommands,
        Topic::FusionCommands,
        Topic::Pose,
        Topic::Features,
        Topic::LocalizedPose,
        Topic::SlamCorrection,
        Topic::SweepEnds,
    ];

    /// The iceoryx2 service name, which is also the MCAP topic.
    pub fn service(self) -> &'static str {
        match self {
            Topic::Readings => ipc::READINGS_SERVICE,
            Topic::ScanCommands => ipc::COMMANDS_SERVICE,
            Topic::FusionCommands => ipc::FUSION_COMMANDS_SERVICE,
            Topic::Pose => ipc::POSE_SERVICE,
            Topic::Features => ipc::FEATURES_SERVICE,
            Topic::LocalizedPose => ipc::LOCALIZED_POSE_SERVICE,
            Topic::SlamCorrection => ipc::SLAM_CORRECTION_SERVICE,
            Topic::SweepEnds => ipc::SWEEP_ENDS_SERVICE,
        }
    }

    /// The MCAP schema name: a ROS package resource name, as `ros1msg` requires.
    pub fn schema_name(self) -> &'static str {
        match self {
            Topic::Readings => "sonar/ReadingV1",
            Topic::ScanCommands => "sonar/ScanCommandV1",
            Topic::FusionCommands => "sonar/FusionCommandV1",
            Topic::Pose => "sonar/Pose2DV1",
            Topic::Features => "sonar/FeaturesV2",
            Topic::LocalizedPose => "sonar/LocalizedPoseV1",
            Topic::SlamCorrection => "sonar/SlamCorrectionV1",
            Topic::SweepEnds => "sonar/SweepEndV1",
        }
    }

    /// The `ros1msg` schema text.
    pub fn schema(self) -> &'static str {
        match self {
            Topic::Readings => READING_SCHEMA,
            Topic::ScanCommands => SCAN_COMMAND_SCHEMA,
            Topic::FusionCommands => FUSION_COMMAND_SCHEMA,
            Topic::Pose => POSE_SCHEMA,
            Topic::Features => FEATURES_SCHEMA,
            Topic::LocalizedPose => LOCALIZED_POSE_SCHEMA,
            Topic::SlamCorrection => SLAM_CORRECTION_SCHEMA,
            Topic::SweepEnds => SWEEP_END_SCHEMA,
        }
    }

    /// Size of every message on this channel, bytes; `None` for [`Topic::Features`], whose size
    /// depends on its number of records ([`FEATURES_PREFIX_SIZE`] + 80 bytes a record).
    pub fn message_size(self) -> Option<usize> {
        match self {
            Topic::Readings => Some(size_of::<Reading>()),
            Topic::ScanCommands => Some(size_of::<ScanCommand>()),
            Topic::FusionCommands => Some(size_of::<FusionCommand>()),
            Topic::Pose => Some(size_of::<Pose2D>()),
            Topic::Features => None,
            Topic::LocalizedPose => Some(size_of::<LocalizedPose>()),
            Topic::SlamCorrection => Some(size_of::<SlamCorrection>()),
            Topic::SweepEnds => Some(size_of::<SweepEnd>()),
        }
    }

    /// The size a message on this channel must have, judged from its first bytes (a features
    /// message names its number of records after the header, each `record_size` bytes).
    fn expected_size(self, bytes: &[u8], record_size: usize) -> usize {
        if let Some(size) = self.message_size() {
            return size;
        }
        let count = bytes
            .get(FEATURES_PREFIX_SIZE - 4..FEATURES_PREFIX_SIZE)
            .and_then(|b| <[u8; 4]>::try_from(b).ok())
            .map_or(0, u32::from_le_bytes);
        usize::try_from(count)
            .ok()
            .and_then(|n| n.checked_mul(record_size))
            .and_then(|n| n.checked_add(FEATURES_PREFIX_SIZE))
            .unwrap_or(usize::MAX)
    }

    fn from_service(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.service() == name)
    }

    fn index(self) -> usize {
        self as usize
    }
}

impl std::fmt::Display for Topic {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.service())
    }
}

/// How a recorded channel's messages are laid out: as this program writes them, or as an older
/// one wrote the features (see [`FEATURES_V1_SCHEMA_NAME`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Layout {
    Current,
    FeaturesV1,
}

impl Layout {
    fn feature_record_size(self) -> usize {
        match self {
            Layout::Current => size_of::<FeatureRecord>(),
            Layout::FeaturesV1 => FEATURE_RECORD_V1_SIZE,
        }
    }
}

/// One `sonar/features` snapshot: the header and a copy of its records.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FeatureSnapshot {
    pub header: FeaturesHeader,
    pub records: Vec<FeatureRecord>,
}

/// One recorded payload.
#[derive(Debug, Clone, PartialEq)]
pub enum Message {
    Reading(Reading),
    ScanCommand(ScanCommand),
    FusionCommand(FusionCommand),
    Pose(Pose2D),
    Features(FeatureSnapshot),
    LocalizedPose(LocalizedPose),
    SlamCorrection(SlamCorrection),
    SweepEnd(SweepEnd),
}

impl Message {
    pub fn topic(&self) -> Topic {
        match self {
            Message::Reading(_) => Topic::Readings,
            Message::ScanCommand(_) => Topic::ScanCommands,
            Message::FusionCommand(_) => Topic::FusionCommands,
            Message::Pose(_) => Topic::Pose,
            Message::Features(_) => Topic::Features,
            Message::LocalizedPose(_) => Topic::LocalizedPose,
            Message::SlamCorrection(_) => Topic::SlamCorrection,
            Message::SweepEnd(_) => Topic::SweepEnds,
        }
    }

    /// The message's bytes in the file: the payload's fields in declaration order, little-endian
    /// (a features message: the header, the number of records as `u32`, the records).
    pub fn encode(&self) -> Vec<u8> {
        let size = match self {
            Message::Features(f) => {
                FEATURES_PREFIX_SIZE + f.records.len() * size_of::<FeatureRecord>()
            }
            _ => self.topic().message_size().unwrap_or_default(),
        };
        let mut e = Encoder(Vec::with_capacity(size));
        match self {
            Message::Reading(r) => encode_reading(&mut e, r),
            Message::ScanCommand(c) => {
                e.u32(c.kind);
                e.f32(c.from_deg);
                e.f32(c.to_deg);
                e.u32(c.layout_version);
            }
            Message::FusionCommand(c) => {
                e.u32(c.kind);
                e.u32(c.value);
            }
            Message::Pose(p) => {
                e.u64(p.stamp_ns);
                e.f32(p.x_m);
                e.f32(p.y_m);
                e.f32(p.theta_rad);
                e.u32(p.layout_version);
            }
            Message::Features(f) => encode_features(&mut e, f),
            Message::LocalizedPose(p) => encode_localized_pose(&mut e, p),
            Message::SlamCorrection(c) => encode_slam_correction(&mut e, c),
            Message::SweepEnd(end) => {
                e.u64(end.stamp_ns);
                e.u64(end.last_seq);
                e.u32(end.sweep_id);
                e.u32(end.reserved);
            }
        }
        e.0
    }

    /// The inverse of [`encode`](Self::encode); the length must be the topic's message size (for
    /// features: that of the number of records the message names).
    pub fn decode(topic: Topic, bytes: &[u8]) -> Result<Self, FormatError> {
        Self::decode_layout(topic, bytes, Layout::Current)
    }

    fn decode_layout(topic: Topic, bytes: &[u8], layout: Layout) -> Result<Self, FormatError> {
        let record_size = layout.feature_record_size();
        let expected = topic.expected_size(bytes, record_size);
        if bytes.len() != expected {
            return Err(FormatError::BadMessage {
                topic,
                len: bytes.len(),
                expected,
            });
        }
        let mut d = Decoder(bytes);
        Ok(match topic {
            Topic::Readings => Message::Reading(decode_reading(&mut d)),
            Topic::ScanCommands => Message::ScanCommand(ScanCommand {
                kind: d.u32(),
                from_deg: d.f32(),
                to_deg: d.f32(),
                layout_version: d.u32(),
            }),
            Topic::FusionCommands => Message::FusionCommand(FusionCommand {
                kind: d.u32(),
                value: d.u32(),
            }),
            Topic::Pose => Message::Pose(Pose2D {
                stamp_ns: d.u64(),
                x_m: d.f32(),
                y_m: d.f32(),
                theta_rad: d.f32(),
                layout_version: d.u32(),
            }),
            Topic::Features => Message::Features(decode_features(&mut d, layout)),
            Topic::LocalizedPose => Message::LocalizedPose(decode_localized_pose(&mut d)),
            Topic::SlamCorrection => Message::SlamCorrection(decode_slam_correction(&mut d)),
            Topic::SweepEnds => Message::SweepEnd(SweepEnd {
                stamp_ns: d.u64(),
                last_seq: d.u64(),
                sweep_id: d.u32(),
                reserved: d.u32(),
            }),
        })
    }

    /// The payload's own time stamp, if it has one (readings: `host_stamp_ns`, poses, features
    /// and corrections: `stamp_ns`).
    pub fn stamp_ns(&self) -> Option<u64> {
        match self {
            Message::Reading(r) => Some(r.host_stamp_ns),
            Message::Pose(p) => Some(p.stamp_ns),
            Message::Features(f) => Some(f.header.stamp_ns),
            Message::LocalizedPose(p) => Some(p.stamp_ns),
            Message::SlamCorrection(c) => Some(c.stamp_ns),
            Message::SweepEnd(end) => Some(end.stamp_ns),
            Message::ScanCommand(_) | Message::FusionCommand(_) => None,
        }
    }
}

fn encode_localized_pose(e: &mut Encoder, p: &LocalizedPose) {
    e.u64(p.stamp_ns);
    for v in [p.x_m, p.y_m, p.theta_rad] {
        e.f32(v);
    }
    e.u32(p.layout_version);
    for v in [p.cov_xx, p.cov_xy, p.cov_xtheta, p.cov_yy, p.cov_ytheta] {
        e.f32(v);
    }
    e.f32(p.cov_thetatheta);
    e.u32(p.matched);
    e.u32(p.fixes);
    for v in [p.odometry_x_m, p.odometry_y_m, p.odometry_theta_rad] {
        e.f32(v);
    }
    e.u32(p.reserved);
}

/// Only called with exactly `size_of::<LocalizedPose>()` bytes.
fn decode_localized_pose(d: &mut Decoder) -> LocalizedPose {
    LocalizedPose {
        stamp_ns: d.u64(),
        x_m: d.f32(),
        y_m: d.f32(),
        theta_rad: d.f32(),
        layout_version: d.u32(),
        cov_xx: d.f32(),
        cov_xy: d.f32(),
        cov_xtheta: d.f32(),
        cov_yy: d.f32(),
        cov_ytheta: d.f32(),
        cov_thetatheta: d.f32(),
        matched: d.u32(),
        fixes: d.u32(),
        odometry_x_m: d.f32(),
        odometry_y_m: d.f32(),
        odometry_theta_rad: d.f32(),
        reserved: d.u32(),
    }
}

fn encode_slam_correction(e: &mut Encoder, c: &SlamCorrection) {
    e.u64(c.stamp_ns);
    for v in [c.layout_version, c.sweep_id, c.state, c.matched] {
        e.u32(v);
    }
    for v in [
        c.correction_x_m,
        c.correction_y_m,
        c.correction_theta_rad,
        c.correction_cov_xx,
        c.correction_cov_xy,
        c.correction_cov_xtheta,
        c.correction_cov_yy,
        c.correction_cov_ytheta,
        c.correction_cov_thetatheta,
        c.x_m,
        c.y_m,
        c.theta_rad,
        c.cov_xx,
        c.cov_xy,
        c.cov_xtheta,
        c.cov_yy,
        c.cov_ytheta,
        c.cov_thetatheta,
        c.odometry_x_m,
        c.odometry_y_m,
        c.odometry_theta_rad,
    ] {
        e.f32(v);
    }
    for v in [c.landmarks, c.fixes, c.refused] {
        e.u32(v);
    }
}

/// Only called with exactly `size_of::<SlamCorrection>()` bytes.
fn decode_slam_correction(d: &mut Decoder) -> SlamCorrection {
    SlamCorrection {
        stamp_ns: d.u64(),
        layout_version: d.u32(),
        sweep_id: d.u32(),
        state: d.u32(),
        matched: d.u32(),
        correction_x_m: d.f32(),
        correction_y_m: d.f32(),
        correction_theta_rad: d.f32(),
        correction_cov_xx: d.f32(),
        correction_cov_xy: d.f32(),
        correction_cov_xtheta: d.f32(),
        correction_cov_yy: d.f32(),
        correction_cov_ytheta: d.f32(),
        correction_cov_thetatheta: d.f32(),
        x_m: d.f32(),
        y_m: d.f32(),
        theta_rad: d.f32(),
        cov_xx: d.f32(),
        cov_xy: d.f32(),
        cov_xtheta: d.f32(),
        cov_yy: d.f32(),
        cov_ytheta: d.f32(),
        cov_thetatheta: d.f32(),
        odometry_x_m: d.f32(),
        odometry_y_m: d.f32(),
        odometry_theta_rad: d.f32(),
        landmarks: d.u32(),
        fixes: d.u32(),
        refused: d.u32(),
    }
}

fn encode_reading(e: &mut Encoder, r: &Reading) {
    e.u64(r.seq);
    e.u64(r.host_stamp_ns);
    e.u32(r.layout_version);
    e.u32(r.device_seq);
    e.u32(r.device_time_ms);
    e.u32(r.sweep_id);
    e.u32(r.flags);
    e.f32(r.angle_deg);
    e.f32(r.beam_half_angle_deg);
    e.f32(r.tof_us);
    e.f32(r.distance_m);
    e.f32(r.speed_of_sound_mps);
    e.f32(r.min_range_m);
    e.f32(r.max_range_m);
    for v in r.echo_us {
        e.u32(v);
    }
    e.0.extend_from_slice(&r.direction.to_le_bytes());
    e.0.extend_from_slice(&[r.mode, r.ping_count, r.pings_used]);
    e.0.extend_from_slice(&r.reserved);
}

/// Only called with exactly `size_of::<Reading>()` bytes.
fn decode_reading(d: &mut Decoder) -> Reading {
    Reading {
        seq: d.u64(),
        host_stamp_ns: d.u64(),
        layout_version: d.u32(),
        device_seq: d.u32(),
        device_time_ms: d.u32(),
        sweep_id: d.u32(),
        flags: d.u32(),
        angle_deg: d.f32(),
        beam_half_angle_deg: d.f32(),
        tof_us: d.f32(),
        distance_m: d.f32(),
        speed_of_sound_mps: d.f32(),
        min_range_m: d.f32(),
        max_range_m: d.f32(),
        echo_us: std::array::from_fn(|_| d.u32()),
        direction: i8::from_le_bytes(d.take()),
        mode: d.u8(),
        ping_count: d.u8(),
        pings_used: d.u8(),
        reserved: d.take(),
    }
}

fn encode_features(e: &mut Encoder, f: &FeatureSnapshot) {
    let h = &f.header;
    e.u64(h.seq);
    e.u64(h.stamp_ns);
    e.u64(h.sweeps);
    for v in [
        h.layout_version,
        h.feature_count,
        h.last_sweep_id,
        h.last_sweep_rcds,
        h.last_sweep_refined,
        h.last_sweep_added,
        h.last_sweep_removed,
        h.features_left_out,
    ] {
        e.u32(v);
    }
    // At most `MAX_FEATURES` records come from shared memory; a longer vector cannot be written
    // as a ROS 1 array anyway, and is cut rather than written with a wrong count.
    let count = u32::try_from(f.records.len()).unwrap_or(u32::MAX);
    e.u32(count);
    for r in f.records.iter().take(count as usize) {
        e.u64(r.id);
        e.u32(r.kind);
        e.u32(r.times_seen);
        for v in [
            r.x_m,
            r.y_m,
            r.cov_xx,
            r.cov_xy,
            r.cov_yy,
            r.angle_deg,
            r.angle_sigma_deg,
            r.confidence,
            r.segment_ax_m,
            r.segment_ay_m,
            r.segment_bx_m,
            r.segment_by_m,
        ] {
            e.f32(v);
        }
        e.u64(r.last_seen_sweep);
        e.u32(r.flags);
        e.u32(r.reserved);
    }
}

/// Only called with a buffer whose length matches the count it names.
fn decode_features(d: &mut Decoder, layout: Layout) -> FeatureSnapshot {
    let record_size = layout.feature_record_size();
    let header = FeaturesHeader {
        seq: d.u64(),
        stamp_ns: d.u64(),
        sweeps: d.u64(),
        layout_version: d.u32(),
        feature_count: d.u32(),
        last_sweep_id: d.u32(),
        last_sweep_rcds: d.u32(),
        last_sweep_refined: d.u32(),
        last_sweep_added: d.u32(),
        last_sweep_removed: d.u32(),
        features_left_out: d.u32(),
    };
    let count = d.u32() as usize;
    let records = (0..count)
        .map_while(|_| {
            (d.0.len() >= record_size).then(|| FeatureRecord {
                id: d.u64(),
                kind: d.u32(),
                times_seen: d.u32(),
                x_m: d.f32(),
                y_m: d.f32(),
                cov_xx: d.f32(),
                cov_xy: d.f32(),
                cov_yy: d.f32(),
                angle_deg: d.f32(),
                angle_sigma_deg: d.f32(),
                confidence: d.f32(),
                segment_ax_m: d.f32(),
                segment_ay_m: d.f32(),
                segment_bx_m: d.f32(),
                segment_by_m: d.f32(),
                last_seen_sweep: d.u64(),
                flags: match layout {
                    Layout::Current => d.u32(),
                    Layout::FeaturesV1 => 0,
                },
                reserved: match layout {
                    Layout::Current => d.u32(),
                    Layout::FeaturesV1 => 0,
                },
            })
        })
        .collect();
    FeatureSnapshot { header, records }
}

struct Encoder(Vec<u8>);

impl Encoder {
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }
}

/// Reads fields from a buffer whose length was checked against the message size beforehand;
/// should it be short anyway, the missing bytes read as zero (never a panic).
struct Decoder<'a>(&'a [u8]);

impl Decoder<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        let n = N.min(self.0.len());
        let (head, tail) = self.0.split_at(n);
        out[..n].copy_from_slice(head);
        self.0 = tail;
        out
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn u8(&mut self) -> u8 {
        u8::from_le_bytes(self.take())
    }
    fn f32(&mut self) -> f32 {
        f32::from_bits(self.u32())
    }
}

/// What can go wrong writing or reading a recording.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("the file is empty")]
    Empty,
    #[error("not an MCAP file (it does not start with the MCAP magic bytes)")]
    NotMcap,
    #[error(
        "the file is truncated: it ends in the middle of a record after {messages} complete \
         messages (was the recorder killed?); `--allow-truncated` replays what is there"
    )]
    Truncated { messages: u64 },
    #[error("the file is corrupt after {messages} complete messages: {what}")]
    Corrupt { messages: u64, what: String },
    #[error(
        "the file has {0}-compressed chunks; this program reads uncompressed recordings as \
         sonar-record writes them (rewrite it without compression first)"
    )]
    Compressed(String),
    #[error(
        "an MCAP file, but not a sonar recording: no `{METADATA_NAME}` metadata record before \
         the first message"
    )]
    NotARecording,
    #[error(
        "recording format version {found:?}, but this program reads versions 1 to \
         {FORMAT_VERSION}: use a newer sonar-replay"
    )]
    UnsupportedVersion { found: String },
    #[error(
        "channel {topic} has schema {found:?} ({encoding}), but this program reads {expected:?} \
         (ros1msg)"
    )]
    UnsupportedSchema {
        topic: Topic,
        found: String,
        encoding: String,
        expected: &'static str,
    },
    #[error("a message on {topic} has {len} bytes instead of {expected}")]
    BadMessage {
        topic: Topic,
        len: usize,
        expected: usize,
    },
    #[error("a message refers to channel {0}, which the file never declared")]
    UndeclaredChannel(u16),
    #[error("an extra channel cannot take {0:?}, one of the recording's own topics")]
    ReservedTopic(String),
    #[error("writing the recording failed: {0}")]
    Write(#[source] McapError),
}

/// Writes a recording. Call [`finish`](Self::finish) at the end: without it the file lacks its
/// summary and footer (it still reads with `--allow-truncated`, up to the last [`flush`](Self::flush)).
pub struct RecordingWriter<W: Write + Seek> {
    mcap: mcap::Writer<W>,
    channels: [u16; Topic::ALL.len()],
    sequences: [u32; Topic::ALL.len()],
    counts: [u64; Topic::ALL.len()],
}

impl<W: Write + Seek> std::fmt::Debug for RecordingWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecordingWriter")
            .field("counts", &self.counts)
            .finish_non_exhaustive()
    }
}

/// Target size of a chunk before it is closed; [`RecordingWriter::flush`] closes one earlier.
const CHUNK_SIZE: u64 = 256 * 1024;

impl RecordingWriter<BufWriter<File>> {
    /// Creates `path` (refusing to replace an existing file unless `overwrite`).
    pub fn create(
        path: &Path,
        overwrite: bool,
        extra: &BTreeMap<String, String>,
    ) -> Result<Self, FormatError> {
        let mut options = OpenOptions::new();
        options.write(true);
        if overwrite {
            options.create(true).truncate(true);
        } else {
            options.create_new(true);
        }
        let file = options.open(path).map_err(|source| FormatError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::new(BufWriter::new(file), extra)
    }
}

impl<W: Write + Seek> RecordingWriter<W> {
    /// Starts a recording: header, the `sonar_recording` metadata (with `extra` entries), and one
    /// schema and channel per [`Topic`], so every channel is listed even if it stays empty.
    pub fn new(sink: W, extra: &BTreeMap<String, String>) -> Result<Self, FormatError> {
        let options = WriteOptions::new()
            .compression(None)
            .chunk_size(Some(CHUNK_SIZE))
            // Build each chunk in memory and write it whole: a killed recorder then leaves complete
            // chunks followed at most by a cut one (a clear truncation), never a chunk whose header
            // still waits to be patched.
            .disable_seeking(true)
            .library(format!(
                "sonar-recorder {} (mcap {})",
                env!("CARGO_PKG_VERSION"),
                mcap::VERSION
            ));
        let mut mcap = options.create(sink).map_err(FormatError::Write)?;
        let mut metadata = extra.clone();
        metadata.insert("format".into(), FORMAT_NAME.into());
        metadata.insert("format_version".into(), FORMAT_VERSION.to_string());
        metadata.insert("layout_version".into(), LAYOUT_VERSION.to_string());
        mcap.write_metadata(&Metadata {
            name: METADATA_NAME.into(),
            metadata,
        })
        .map_err(FormatError::Write)?;
        let mut channels = [0u16; Topic::ALL.len()];
        for topic in Topic::ALL {
            let schema = mcap
                .add_schema(
                    topic.schema_name(),
                    SCHEMA_ENCODING,
                    topic.schema().as_bytes(),
                )
                .map_err(FormatError::Write)?;
            channels[topic.index()] = mcap
                .add_channel(schema, topic.service(), MESSAGE_ENCODING, &BTreeMap::new())
                .map_err(FormatError::Write)?;
        }
        Ok(Self {
            mcap,
            channels,
            sequences: [0; Topic::ALL.len()],
            counts: [0; Topic::ALL.len()],
        })
    }

    /// Appends a message. `log_time_ns` is when the recorder received it (ns since the Unix epoch);
    /// the MCAP publish time is the payload's own stamp where it has one, else the same.
    pub fn write(&mut self, log_time_ns: u64, message: &Message) -> Result<(), FormatError> {
        let topic = message.topic();
        let i = topic.index();
        let header = MessageHeader {
            channel_id: self.channels[i],
            sequence: self.sequences[i],
            log_time: log_time_ns,
            publish_time: message.stamp_ns().unwrap_or(log_time_ns),
        };
        self.mcap
            .write_to_known_channel(&header, &message.encode())
            .map_err(FormatError::Write)?;
        self.sequences[i] = self.sequences[i].wrapping_add(1);
        self.counts[i] += 1;
        Ok(())
    }

    /// Closes the current chunk and hands everything to the sink (and flushes it), so a crash
    /// after this loses nothing written before it.
    pub fn flush(&mut self) -> Result<(), FormatError> {
        self.mcap.flush().map_err(FormatError::Write)
    }

    /// Declares a channel beside the recording's own (Foxglove's or ROS 2's well-known schemas):
    /// readers of recordings skip it like any channel they do not know.
    pub fn add_channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema_encoding: &str,
        schema: &[u8],
        message_encoding: &str,
    ) -> Result<ExtraChannel, FormatError> {
        if Topic::from_service(topic).is_some() {
            return Err(FormatError::ReservedTopic(topic.to_owned()));
        }
        let schema = self
            .mcap
            .add_schema(schema_name, schema_encoding, schema)
            .map_err(FormatError::Write)?;
        let id = self
            .mcap
            .add_channel(schema, topic, message_encoding, &BTreeMap::new())
            .map_err(FormatError::Write)?;
        Ok(ExtraChannel { id, sequence: 0 })
    }

    /// Appends a message on a channel of [`add_channel`](Self::add_channel).
    pub fn write_extra(
        &mut self,
        channel: &mut ExtraChannel,
        log_time_ns: u64,
        publish_time_ns: u64,
        data: &[u8],
    ) -> Result<(), FormatError> {
        write_numbered(
            &mut self.mcap,
            channel.id,
            &mut channel.sequence,
            log_time_ns,
            publish_time_ns,
            data,
        )
    }

    /// Messages written per topic.
    pub fn count(&self, topic: Topic) -> u64 {
        self.counts[topic.index()]
    }

    /// Writes the summary and footer and returns the sink (flushed).
    pub fn finish(mut self) -> Result<W, FormatError> {
        self.mcap.finish().map_err(FormatError::Write)?;
        let mut sink = self.mcap.into_inner();
        sink.flush()
            .map_err(|e| FormatError::Write(McapError::Io(e)))?;
        Ok(sink)
    }
}

/// Writes `data` on an MCAP writer's channel `channel_id` as message number `sequence` of it,
/// then counts the number on.
pub(crate) fn write_numbered<W: Write + Seek>(
    mcap: &mut mcap::Writer<W>,
    channel_id: u16,
    sequence: &mut u32,
    log_time_ns: u64,
    publish_time_ns: u64,
    data: &[u8],
) -> Result<(), FormatError> {
    let header = MessageHeader {
        channel_id,
        sequence: *sequence,
        log_time: log_time_ns,
        publish_time: publish_time_ns,
    };
    mcap.write_to_known_channel(&header, data)
        .map_err(FormatError::Write)?;
    *sequence = sequence.wrapping_add(1);
    Ok(())
}

/// A channel of a recording outside its own topics, from [`RecordingWriter::add_channel`].
#[derive(Debug)]
pub struct ExtraChannel {
    id: u16,
    sequence: u32,
}

/// One message read back.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    /// When the recorder received it, ns since the Unix epoch.
    pub log_time_ns: u64,
    pub message: Message,
}

/// A whole recording, read into memory.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// The `sonar_recording` metadata record.
    pub metadata: BTreeMap<String, String>,
    /// Messages in file order (the order the recorder received them).
    pub entries: Vec<Entry>,
    /// The file ended early and was read with [`ReadOptions::allow_truncated`].
    pub truncated: bool,
    /// Messages on channels this program does not know (skipped).
    pub skipped: u64,
}

impl Recording {
    pub fn count(&self, topic: Topic) -> usize {
        self.entries
            .iter()
            .filter(|e| e.message.topic() == topic)
            .count()
    }

    pub fn readings(&self) -> impl Iterator<Item = &Reading> {
        self.entries.iter().filter_map(|e| match &e.message {
            Message::Reading(r) => Some(r),
            _ => None,
        })
    }
}

#[derive(Debug, Clone, Copy, Default)]
pub struct ReadOptions {
    /// Accept a file that ends early (a recorder that was killed) and return the complete
    /// messages before the end, with [`Recording::truncated`] set.
    pub allow_truncated: bool,
}

/// Reads a recording file; see [`read`].
pub fn read_file(path: &Path, options: ReadOptions) -> Result<Recording, FormatError> {
    let bytes = std::fs::read(path).map_err(|source| FormatError::Io {
        path: path.to_owned(),
        source,
    })?;
    read(&bytes, options)
}

/// Parses a recording: checks the MCAP structure (magic, record framing, chunk and data-section
/// CRCs), the `sonar_recording` version and the schemas of the known channels, and decodes every
/// message. Messages on unknown channels are counted and skipped.
///
/// The record framing is walked here rather than by the `mcap` crate's readers: those (0.26)
/// panic on some damaged uncompressed chunks (an inner record longer than its chunk underflows a
/// counter), and a damaged file must be an error. The crate still parses each record's body.
pub fn read(bytes: &[u8], options: ReadOptions) -> Result<Recording, FormatError> {
    if bytes.is_empty() {
        return Err(FormatError::Empty);
    }
    if !bytes.starts_with(mcap::MAGIC) {
        if mcap::MAGIC.starts_with(bytes) {
            return Err(FormatError::Truncated { messages: 0 });
        }
        return Err(FormatError::NotMcap);
    }
    let mut reader = Reader {
        options,
        recording: Recording::default(),
        version_seen: false,
        schemas: BTreeMap::new(),
        channels: BTreeMap::new(),
    };
    let mut pos = mcap::MAGIC.len();
    let mut data_end_seen = false;
    loop {
        let Some((op, body, next)) = frame(bytes, pos) else {
            // No footer yet: the bytes stop in the middle of the file.
            reader.truncated()?;
            break;
        };
        match op {
            op::FOOTER => {
                let tail = &bytes[next..];
                if tail == mcap::MAGIC {
                    break;
                }
                if tail.len() < mcap::MAGIC.len() && mcap::MAGIC.starts_with(tail) {
                    reader.truncated()?;
                    break;
                }
                return Err(reader.corrupt("no MCAP magic bytes after the footer"));
            }
            op::DATA_END => {
                let end = parse(&reader, op, body)?;
                if let Record::DataEnd(end) = end
                    && end.data_section_crc != 0
                    && end.data_section_crc != crc32fast::hash(&bytes[..pos])
                {
                    return Err(reader.corrupt("data section CRC mismatch"));
                }
                data_end_seen = true;
            }
            // The summary section repeats what the data section said; only the footer matters.
            _ if data_end_seen => {}
            op::CHUNK => {
                let Record::Chunk { header, data } = parse(&reader, op, body)? else {
                    return Err(reader.corrupt("chunk record did not parse as a chunk"));
                };
                if !header.compression.is_empty() {
                    return Err(FormatError::Compressed(header.compression));
                }
                if data.len() as u64 != header.uncompressed_size {
                    return Err(reader.corrupt("chunk size mismatch"));
                }
                if header.uncompressed_crc != 0 && header.uncompressed_crc != crc32fast::hash(&data)
                {
                    return Err(reader.corrupt("chunk CRC mismatch"));
                }
                let mut inner = 0;
                while inner < data.len() {
                    let Some((op, body, next)) = frame(&data, inner) else {
                        return Err(reader.corrupt("a chunk ends in the middle of a record"));
                    };
                    if op == op::CHUNK {
                        return Err(reader.corrupt("a chunk inside a chunk"));
                    }
                    reader.record(op, body)?;
                    inner = next;
                }
            }
            _ => reader.record(op, body)?,
        }
        pos = next;
    }
    if !reader.version_seen {
        return Err(FormatError::NotARecording);
    }
    Ok(reader.recording)
}

/// Opcodes of the MCAP records this reader looks at.
mod op {
    pub use mcap::records::op::{CHANNEL, CHUNK, DATA_END, FOOTER, MESSAGE, METADATA, SCHEMA};
}

/// The record at `pos`: opcode, body and the position after it; `None` if the bytes end first.
fn frame(bytes: &[u8], pos: usize) -> Option<(u8, &[u8], usize)> {
    let rest = bytes.get(pos..)?;
    let (&op, rest) = rest.split_first()?;
    let (len, rest) = rest.split_first_chunk::<8>()?;
    let len = usize::try_from(u64::from_le_bytes(*len)).ok()?;
    let body = rest.get(..len)?;
    Some((op, body, pos + 9 + len))
}

fn parse<'a>(reader: &Reader, op: u8, body: &'a [u8]) -> Result<Record<'a>, FormatError> {
    mcap::read::parse_record(op, body).map_err(|e| reader.corrupt(e.to_string()))
}

struct Reader {
    options: ReadOptions,
    recording: Recording,
    version_seen: bool,
    /// schema id → (name, encoding)
    schemas: BTreeMap<u16, (String, String)>,
    /// channel id → `Some(topic, its layout)` for ours, `None` for channels we skip
    channels: BTreeMap<u16, Option<(Topic, Layout)>>,
}

impl Reader {
    fn messages(&self) -> u64 {
        self.recording.entries.len() as u64 + self.recording.skipped
    }

    fn corrupt(&self, what: impl Into<String>) -> FormatError {
        FormatError::Corrupt {
            messages: self.messages(),
            what: what.into(),
        }
    }

    fn truncated(&mut self) -> Result<(), FormatError> {
        if self.options.allow_truncated {
            self.recording.truncated = true;
            Ok(())
        } else {
            Err(FormatError::Truncated {
                messages: self.messages(),
            })
        }
    }

    /// A data-section record outside a chunk, or one inside a chunk.
    fn record(&mut self, op: u8, body: &[u8]) -> Result<(), FormatError> {
        if !matches!(op, op::METADATA | op::SCHEMA | op::CHANNEL | op::MESSAGE) {
            return Ok(()); // header, indexes, attachments, …: nothing we need
        }
        match parse(self, op, body)? {
            Record::Metadata(m) if m.name == METADATA_NAME => {
                let version = m
                    .metadata
                    .get("format_version")
                    .cloned()
                    .unwrap_or_default();
                match version.parse::<u32>() {
                    Ok(v) if (1..=FORMAT_VERSION).contains(&v) => {}
                    _ => return Err(FormatError::UnsupportedVersion { found: version }),
                }
                self.version_seen = true;
                self.recording.metadata = m.metadata;
            }
            Record::Schema { header, .. } => {
                self.schemas
                    .insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(c) => {
                let topic = match Topic::from_service(&c.topic) {
                    None => None,
                    Some(topic) => {
                        let (name, encoding) =
                            self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                        let layout = if name == topic.schema_name() {
                            Some(Layout::Current)
                        } else if topic == Topic::Features && name == FEATURES_V1_SCHEMA_NAME {
                            Some(Layout::FeaturesV1)
                        } else {
                            None
                        };
                        let Some(layout) = layout.filter(|_| {
                            encoding == SCHEMA_ENCODING && c.message_encoding == MESSAGE_ENCODING
                        }) else {
                            return Err(FormatError::UnsupportedSchema {
                                topic,
                                found: name,
                                encoding: format!("{encoding}/{}", c.message_encoding),
                                expected: topic.schema_name(),
                            });
                        };
                        Some((topic, layout))
                    }
                };
                self.channels.insert(c.id, topic);
            }
            Record::Message { header, data } => {
                if !self.version_seen {
                    return Err(FormatError::NotARecording);
                }
                match self.channels.get(&header.channel_id) {
                    None => return Err(FormatError::UndeclaredChannel(header.channel_id)),
                    Some(None) => self.recording.skipped += 1,
                    Some(Some((topic, layout))) => {
                        let message = Message::decode_layout(*topic, &data, *layout)?;
                        self.recording.entries.push(Entry {
                            log_time_ns: header.log_time,
                            message,
                        });
                    }
                }
            }
            _ => {}
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
