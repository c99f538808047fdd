//! Everything that crosses a process boundary: payload types, service names and the one place where
//! each service's quality of service is set.
//!
//! Payloads are `#[repr(C)]` plain data with explicit padding, a stable iceoryx2 type name ending in
//! the layout version, and a compile-time size check, so a consumer in another language can map them
//! from `docs/ipc.md` alone. Publishers and subscribers open services through the functions here, so
//! both sides always ask for the same QoS (iceoryx2 rejects a mismatch).

use std::path::PathBuf;

use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{event, publish_subscribe};

/// The `layout_version` every payload below carries. A type whose layout changed since says so in
/// its type name's `V` suffix instead ([`DriverStatus`] is at `V3`, [`FeatureRecord`] at `V2`): the
/// type name is what tells layouts apart, in shared memory (iceoryx2 refuses a subscriber of
/// another), over the bridge (its type tag) and in recordings (the schema's name).
pub const LAYOUT_VERSION: u32 = 1;
/// Most raw pings a reading carries.
pub const MAX_PINGS: usize = crate::protocol::MAX_PINGS_PER_READING;

/// Averaged readings, one per 6° beam position, from the driver.
pub const READINGS_SERVICE: &str = "sonar/readings";
/// The sweeps the head reported ended, from the driver, each after its last reading.
pub const SWEEP_ENDS_SERVICE: &str = "sonar/sweep_ends";
/// Scan commands to the driver (full scan, local scan, stop), from any process.
pub const COMMANDS_SERVICE: &str = "sonar/commands";
/// The driver's connection state and counters, for viewers (history 1).
pub const DRIVER_STATUS_SERVICE: &str = "sonar/driver_status";
/// Probability-grid snapshots from the fusion engine: [`GridHeader`] + one `u8` per cell.
pub const GRID_SERVICE: &str = "sonar/grid";
/// The basic method's radar array from the fusion engine.
pub const RADAR_SERVICE: &str = "sonar/radar";
/// Commands to the fusion engine (clear map, switch model/rule/preset).
pub const FUSION_COMMANDS_SERVICE: &str = "sonar/fusion_commands";
/// The robot's pose in the world, from odometry or localisation (optional; static at the origin
/// without it).
pub const POSE_SERVICE: &str = "robot/pose";
/// The robot's true pose, where a simulator knows it (`sonar-sim` with a moving robot): ground
/// truth to measure odometry and localisation against. Same type as [`POSE_SERVICE`].
pub const TRUE_POSE_SERVICE: &str = "robot/true_pose";
/// The fusion engine's counters: readings received, fused and lost, snapshots, map saves (history 1).
pub const FUSION_STATUS_SERVICE: &str = "sonar/fusion_status";
/// Walls, corners and posts found in the raw pings, once per sweep.
pub const FEATURES_SERVICE: &str = "sonar/features";
/// The robot's pose as sonar localisation corrected it, once per sweep (`sonar-fusion --localize`).
pub const LOCALIZED_POSE_SERVICE: &str = "sonar/localized_pose";
/// `sonar-slam`'s correction of the odometry, once per sweep: the `map → odom` transform with its
/// covariance and whether it is a fix.
pub const SLAM_CORRECTION_SERVICE: &str = "sonar/slam_correction";
/// `sonar-slam`'s landmarks (walls, corners, posts) in the map frame, after each sweep.
pub const SLAM_LANDMARKS_SERVICE: &str = "sonar/slam_landmarks";

/// The iceoryx2 node name of `sonar-replay`: a viewer that sees it behind `sonar/readings` knows
/// that the readings stop because a recording ended, not because a driver died.
pub const REPLAY_NODE_NAME: &str = "sonar-replay";

/// Bits of [`Reading::flags`].
pub mod flags {
    /// No ping of the group heard an echo (or too few agreed): `distance_m` is meaningless.
    pub const NO_ECHO: u32 = 1 << 0;
    /// The echo lies outside the sensor's [min, max] range and was not used as a distance.
    pub const OUT_OF_RANGE: u32 = 1 << 1;
    /// Some pings were left out of the average (no echo, or outside the dominant cluster).
    pub const PINGS_REJECTED: u32 = 1 << 2;
    /// The source sends no raw pings (hobby radar dialect): `echo_us` is synthesised from the range.
    pub const NO_RAW_PINGS: u32 = 1 << 3;
}

/// How the head is scanning.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum ScanMode {
    /// Not known (e.g. a hobby sketch that never says).
    #[default]
    Unknown = 0,
    /// The 300° sweep between the limit switches.
    Full = 1,
    /// Back and forth over a segment.
    Local = 2,
    /// Stopped.
    Idle = 3,
}

impl ScanMode {
    pub fn from_u8(v: u8) -> Self {
        match v {
            1 => ScanMode::Full,
            2 => ScanMode::Local,
            3 => ScanMode::Idle,
            _ => ScanMode::Unknown,
        }
    }
}

/// One averaged reading: the pings of one 6° group, their combined time of flight and distance.
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::ReadingV1")]
#[repr(C)]
pub struct Reading {
    /// Driver's sequence number, from 0, without gaps.
    pub seq: u64,
    /// Host wall-clock time of the reading's instant (its last ping), ns since the Unix epoch:
    /// the head's clock (`device_time_ms`) mapped onto the host's by the driver
    /// (`sonar_driver::clock`), never later than the line arrived; the arrival time for a head
    /// without a clock (the hobby dialect) and for a native head's first 8 readings.
    pub host_stamp_ns: u64,
    /// [`LAYOUT_VERSION`].
    pub layout_version: u32,
    /// The device's own reading counter.
    pub device_seq: u32,
    /// The device's millisecond clock at the last ping.
    pub device_time_ms: u32,
    /// Sweep (one pass in one direction) this reading belongs to.
    pub sweep_id: u32,
    /// [`flags`] bits.
    pub flags: u32,
    /// Beam centre: mean of the ping angles, degrees, counter-clockwise from the sensor's forward axis.
    pub angle_deg: f32,
    /// Half-width of the beam used for mapping.
    pub beam_half_angle_deg: f32,
    /// Combined time of flight of the accepted pings, µs (round trip).
    pub tof_us: f32,
    /// d = V·t/2, metres; valid only without `NO_ECHO`/`OUT_OF_RANGE`.
    pub distance_m: f32,
    /// V used for the conversion, from the configured air temperature.
    pub speed_of_sound_mps: f32,
    pub min_range_m: f32,
    pub max_range_m: f32,
    /// Raw echo times of the pings in ping order, µs, 0 = no echo; entries past `ping_count` are 0.
    pub echo_us: [u32; MAX_PINGS],
    /// +1 counter-clockwise (angle increasing), -1 clockwise, 0 unknown.
    pub direction: i8,
    /// [`ScanMode`] as `u8`.
    pub mode: u8,
    pub ping_count: u8,
    /// Pings that went into `tof_us`.
    pub pings_used: u8,
    pub reserved: [u8; 4],
}

const _: () = assert!(std::mem::size_of::<Reading>() == 104);
const _: () = assert!(std::mem::align_of::<Reading>() == 8);

impl Reading {
    pub fn has(&self, flag: u32) -> bool {
        self.flags & flag != 0
    }

    /// True when `distance_m` is a range to an obstacle.
    pub fn is_valid_range(&self) -> bool {
        !self.has(flags::NO_ECHO) && !self.has(flags::OUT_OF_RANGE)
    }

    pub fn scan_mode(&self) -> ScanMode {
        ScanMode::from_u8(self.mode)
    }
}

/// A sweep the head reported ended (`SWP,END`), on [`SWEEP_ENDS_SERVICE`]: published by the
/// driver after the sweep's last reading, so a consumer that has that reading knows the sweep is
/// whole now rather than when the next sweep's first reading comes (a quarter of a second later
/// at the head's pace). Only for a sweep with a reading published; a head that never reports its
/// sweeps' ends (the hobby dialect) sends none, so a consumer must still tell sweeps apart by
/// the readings' `sweep_id`.
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::SweepEndV1")]
#[repr(C)]
pub struct SweepEnd {
    /// Host wall-clock time the end was read, ns since the Unix epoch.
    pub stamp_ns: u64,
    /// [`Reading::seq`] of the sweep's last reading.
    pub last_seq: u64,
    /// The ended sweep's [`Reading::sweep_id`].
    pub sweep_id: u32,
    pub reserved: u32,
}

const _: () = assert!(std::mem::size_of::<SweepEnd>() == 24);

/// What a [`ScanCommand`] asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum ScanCommandKind {
    FullScan = 1,
    LocalScan = 2,
    Stop = 3,
    /// Ask the device for a status line (refreshes `sonar/driver_status`).
    Status = 4,
    /// A person has checked a head stopped on a hardware fault: the driver sends `RESET` (the head
    /// homes again) and then the scan it should run.
    Reset = 5,
}

/// A command to the driver on [`COMMANDS_SERVICE`].
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::ScanCommandV1")]
#[repr(C)]
pub struct ScanCommand {
    /// [`ScanCommandKind`] as `u32`; anything else is rejected by the driver.
    pub kind: u32,
    /// Local scan segment, degrees (ignored otherwise).
    pub from_deg: f32,
    pub to_deg: f32,
    pub layout_version: u32,
}

const _: () = assert!(std::mem::size_of::<ScanCommand>() == 16);

impl ScanCommand {
    pub fn new(kind: ScanCommandKind, from_deg: f32, to_deg: f32) -> Self {
        Self {
            kind: kind as u32,
            from_deg,
            to_deg,
            layout_version: LAYOUT_VERSION,
        }
    }

    pub fn kind(&self) -> Option<ScanCommandKind> {
        Some(match self.kind {
            1 => ScanCommandKind::FullScan,
            2 => ScanCommandKind::LocalScan,
            3 => ScanCommandKind::Stop,
            4 => ScanCommandKind::Status,
            5 => ScanCommandKind::Reset,
            _ => return None,
        })
    }
}

/// Connection state of the driver, in [`DriverStatus::link_state`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u32)]
pub enum LinkState {
    #[default]
    Connecting = 0,
    Connected = 1,
    /// The port went away; the driver retries with back-off.
    Disconnected = 2,
    /// A different head answered on the port (protocol version 2 identity check); the driver does
    /// not command it and tries the port again with back-off.
    Refused = 3,
}

/// The driver's state and counters on [`DRIVER_STATUS_SERVICE`], published on change and once a
/// second.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::DriverStatusV3")]
#[repr(C)]
pub struct DriverStatus {
    pub stamp_ns: u64,
    pub readings_published: u64,
    /// Lines that parsed.
    pub lines_ok: u64,
    /// Lines rejected: bad checksum, garbage, truncated, overlong, malformed fields.
    pub lines_rejected: u64,
    pub reconnects: u32,
    /// [`LinkState`] as `u32`.
    pub link_state: u32,
    /// [`ScanMode`] as `u32`.
    pub mode: u32,
    pub sweep_id: u32,
    /// Last reading's angle.
    pub angle_deg: f32,
    /// +1 / -1 / 0.
    pub direction: i32,
    pub layout_version: u32,
    /// Times the head announced itself while connected (it was reset) and the scan was resumed.
    pub head_resets: u32,
    /// Times the head fell silent while connected and did not answer `STATUS`: the driver then
    /// opened the port again and repeated the handshake.
    pub silences: u32,
    /// `ERR` lines from the head (a refused command, a hardware fault).
    pub device_errors: u32,
    /// The identity of the head served (protocol version 2), NUL-padded ASCII; empty before the
    /// first handshake.
    pub head_id: [u8; 32],
    /// The latest `ERR` line's code and text, e.g. `RANGE: segment outside the limits`,
    /// NUL-padded ASCII (96 bytes hold the longest code and the protocol's 80 characters of text).
    pub last_device_error: [u8; 96],
    /// 1 while the head is stopped on a hardware fault (it reported `ST,FAULT`): no scan is sent
    /// until a person acknowledges it with [`ScanCommandKind::Reset`]; 0 otherwise.
    pub head_fault: u32,
    /// Times the head stopped on a hardware fault.
    pub hardware_faults: u32,
}

const _: () = assert!(std::mem::size_of::<DriverStatus>() == 208);

impl Default for DriverStatus {
    fn default() -> Self {
        Self {
            stamp_ns: 0,
            readings_published: 0,
            lines_ok: 0,
            lines_rejected: 0,
            reconnects: 0,
            link_state: 0,
            mode: 0,
            sweep_id: 0,
            angle_deg: 0.0,
            direction: 0,
            layout_version: LAYOUT_VERSION,
            head_resets: 0,
            silences: 0,
            device_errors: 0,
            head_id: [0; 32],
            last_device_error: [0; 96],
            head_fault: 0,
            hardware_faults: 0,
        }
    }
}

impl DriverStatus {
    pub fn head_id(&self) -> &str {
        padded_text(&self.head_id)
    }

    pub fn last_device_error(&self) -> &str {
        padded_text(&self.last_device_error)
    }
}

/// Writes ASCII text into a NUL-padded field, cut to fit (non-ASCII becomes `?`).
pub fn set_padded_text(field: &mut [u8], text: &str) {
    field.fill(0);
    for (slot, c) in field.iter_mut().zip(text.chars()) {
        *slot = if c.is_ascii() && c != '\0' {
            c as u8
        } else {
            b'?'
        };
    }
}

/// The text of a NUL-padded field, up to the first NUL (or invalid UTF-8).
pub fn padded_text(field: &[u8]) -> &str {
    let end = field.iter().position(|&b| b == 0).unwrap_or(field.len());
    match std::str::from_utf8(&field[..end]) {
        Ok(text) => text,
        Err(e) => std::str::from_utf8(&field[..e.valid_up_to()]).unwrap_or_default(),
    }
}

/// Cell value of a grid snapshot for a cell no reading has touched yet.
pub const CELL_UNKNOWN: u8 = 255;
/// Observed cells carry `round(p · CELL_PROBABILITY_SCALE)`: 0 = certainly free, 254 = certainly
/// occupied, 127 = even odds. Keeping 255 out of the scale lets "never seen" stay distinct from
/// "seen, but undecided", which is what a viewer must show.
pub const CELL_PROBABILITY_SCALE: f32 = 254.0;

/// Encodes an occupancy probability as a snapshot cell value.
pub fn encode_probability(p: f32) -> u8 {
    (p.clamp(0.0, 1.0) * CELL_PROBABILITY_SCALE).round() as u8
}

/// Decodes a snapshot cell value; `None` for [`CELL_UNKNOWN`].
pub fn decode_probability(cell: u8) -> Option<f32> {
    (cell != CELL_UNKNOWN).then(|| f32::from(cell) / CELL_PROBABILITY_SCALE)
}

/// Sensor model codes in [`GridHeader::model`] and [`FusionCommand`].
pub mod model_code {
    pub const PAPER: u32 = 1;
    pub const LOG_ODDS: u32 = 2;
    pub const SMOOTH: u32 = 3;
}

/// Combination rule codes in [`GridHeader::rule`] and [`FusionCommand`].
pub mod rule_code {
    pub const BAYES: u32 = 1;
    pub const LOG_ODDS: u32 = 2;
    pub const DEMPSTER_SHAFER: u32 = 3;
    pub const HIMM: u32 = 4;
}

/// Preset codes in [`GridHeader::preset`] and [`FusionCommand`]; 0 = custom settings.
pub mod preset_code {
    pub const CUSTOM: u32 = 0;
    pub const PAPER: u32 = 1;
    pub const RECOMMENDED: u32 = 2;
}

/// The fixed part of a `sonar/grid` snapshot; the payload is `width × height` cells, row-major,
/// row 0 at the lowest y (the ROS `OccupancyGrid` convention), each cell encoded as described at
/// [`CELL_UNKNOWN`].
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::GridHeaderV1")]
#[repr(C)]
pub struct GridHeader {
    pub seq: u64,
    pub stamp_ns: u64,
    /// Readings fused since the map was last cleared.
    pub readings_fused: u64,
    pub layout_version: u32,
    pub width: u32,
    pub height: u32,
    /// Cell edge, metres.
    pub resolution_m: f32,
    /// World position of the outer corner of cell (0, 0), metres.
    pub origin_x_m: f32,
    pub origin_y_m: f32,
    /// Sensor pose in the world at the last fused reading.
    pub pose_x_m: f32,
    pub pose_y_m: f32,
    pub pose_theta_rad: f32,
    /// [`model_code`], [`rule_code`], [`preset_code`].
    pub model: u32,
    pub rule: u32,
    pub preset: u32,
    /// Sweep of the last fused reading.
    pub sweep_id: u32,
    /// Cells with p > 0.5, p < 0.5, and never observed.
    pub occupied_cells: u32,
    pub free_cells: u32,
    pub unknown_cells: u32,
}

const _: () = assert!(std::mem::size_of::<GridHeader>() == 88);

/// Most angle bins a radar snapshot carries (1° bins over a full turn).
pub const RADAR_MAX_BINS: usize = 360;

/// The basic method (paper §III.A): the latest distance per beam angle, on `sonar/radar`.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::RadarV1")]
#[repr(C)]
pub struct Radar {
    pub seq: u64,
    pub stamp_ns: u64,
    pub layout_version: u32,
    /// Bins in use, from `first_bin_deg` in steps of `bin_width_deg`.
    pub bin_count: u32,
    /// Centre angle of bin 0, degrees.
    pub first_bin_deg: f32,
    pub bin_width_deg: f32,
    pub beam_half_angle_deg: f32,
    pub max_range_m: f32,
    /// Angle of the last reading: where the sweep line is.
    pub current_angle_deg: f32,
    pub sweep_id: u32,
    /// +1 / -1 / 0.
    pub direction: i32,
    /// [`ScanMode`] as `u32`.
    pub mode: u32,
    /// Latest range per bin, metres; NaN = no reading yet, +∞ = the latest reading had no echo.
    pub distances_m: [f32; RADAR_MAX_BINS],
}

const _: () = assert!(std::mem::size_of::<Radar>() == 56 + 4 * RADAR_MAX_BINS);

impl Default for Radar {
    fn default() -> Self {
        Self {
            seq: 0,
            stamp_ns: 0,
            layout_version: LAYOUT_VERSION,
            bin_count: 0,
            first_bin_deg: 0.0,
            bin_width_deg: 0.0,
            beam_half_angle_deg: 0.0,
            max_range_m: 0.0,
            current_angle_deg: 0.0,
            sweep_id: 0,
            direction: 0,
            mode: 0,
            distances_m: [f32::NAN; RADAR_MAX_BINS],
        }
    }
}

/// What a [`FusionCommand`] asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum FusionCommandKind {
    /// Forget everything: grid back to the prior, radar empty.
    Clear = 1,
    /// `value` is a [`preset_code`].
    SetPreset = 2,
    /// `value` is a [`model_code`].
    SetModel = 3,
    /// `value` is a [`rule_code`].
    SetRule = 4,
}

/// A command to the fusion engine on [`FUSION_COMMANDS_SERVICE`].
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::FusionCommandV1")]
#[repr(C)]
pub struct FusionCommand {
    pub kind: u32,
    pub value: u32,
}

impl FusionCommand {
    pub fn new(kind: FusionCommandKind, value: u32) -> Self {
        Self {
            kind: kind as u32,
            value,
        }
    }

    pub fn kind(&self) -> Option<FusionCommandKind> {
        Some(match self.kind {
            1 => FusionCommandKind::Clear,
            2 => FusionCommandKind::SetPreset,
            3 => FusionCommandKind::SetModel,
            4 => FusionCommandKind::SetRule,
            _ => return None,
        })
    }
}

/// Pose of the sensor's rotation axis in the world on [`POSE_SERVICE`]; angle 0 of the sensor points
/// along the robot's heading `theta_rad`.
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::Pose2DV1")]
#[repr(C)]
pub struct Pose2D {
    pub stamp_ns: u64,
    pub x_m: f32,
    pub y_m: f32,
    pub theta_rad: f32,
    pub layout_version: u32,
}

const _: () = assert!(std::mem::size_of::<Pose2D>() == 24);

/// The fusion engine's counters on [`FUSION_STATUS_SERVICE`], published once a second and at
/// once when a loss, a restart of the readings' sequence or a save is counted. Counters run from
/// the process's start, except `readings_fused`, which is the map's (as in [`GridHeader`]).
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::FusionStatusV1")]
#[repr(C)]
pub struct FusionStatus {
    pub stamp_ns: u64,
    /// Readings taken from `sonar/readings`.
    pub readings_received: u64,
    /// Readings in the map since it was last cleared, those of a restored map included.
    pub readings_fused: u64,
    /// Readings the driver published that never arrived: gaps in [`Reading::seq`] (the
    /// subscriber's buffer overflowed and dropped its oldest, or the fusion was not running).
    pub readings_lost: u64,
    /// Times [`Reading::seq`] went backwards or repeated: a restarted driver counts from 0 again.
    /// Counted as a restart, never as a loss.
    pub readings_out_of_order: u64,
    /// Readings received but not fused: another layout version, or refused by the kernels.
    pub readings_rejected: u64,
    /// `seq` of the latest reading received (or of the restored map's last); [`Self::NO_SEQ`]
    /// before any.
    pub last_seq: u64,
    pub snapshots_published: u64,
    /// Snapshots not published because every shared-memory sample was held by subscribers.
    pub snapshots_skipped: u64,
    /// Maps written to the state file by this process.
    pub saves: u64,
    /// When the latest save was taken (ns since the Unix epoch); 0 before any.
    pub last_save_ns: u64,
    /// `readings_fused` of the map in the latest save.
    pub saved_readings_fused: u64,
    /// Saves that failed; the previous file is then left as it was.
    pub save_failures: u32,
    /// How long the latest save held up the readings loop (copying the map), µs.
    pub last_save_copy_us: u32,
    /// How long the latest save took to encode, write, fsync and rename off that loop, µs.
    pub last_save_write_us: u32,
    /// 1 if the map was restored from the state file at start, else 0.
    pub restored: u32,
    pub layout_version: u32,
    /// Readings the walls, corners and posts could not use, since the process started: several
    /// pings without a direction, or no angle (one range per angle — the hobby dialect, imported
    /// logs — is used as one ping on the reading's axis). They are in the grid and the radar all
    /// the same. Saturates.
    pub feature_readings_skipped: u32,
}

const _: () = assert!(std::mem::size_of::<FusionStatus>() == 120);

impl FusionStatus {
    /// [`Self::last_seq`] before any reading.
    pub const NO_SEQ: u64 = u64::MAX;
}

impl Default for FusionStatus {
    fn default() -> Self {
        Self {
            stamp_ns: 0,
            readings_received: 0,
            readings_fused: 0,
            readings_lost: 0,
            readings_out_of_order: 0,
            readings_rejected: 0,
            last_seq: Self::NO_SEQ,
            snapshots_published: 0,
            snapshots_skipped: 0,
            saves: 0,
            last_save_ns: 0,
            saved_readings_fused: 0,
            save_failures: 0,
            last_save_copy_us: 0,
            last_save_write_us: 0,
            restored: 0,
            layout_version: LAYOUT_VERSION,
            feature_readings_skipped: 0,
        }
    }
}

/// Most features one `sonar/features` snapshot carries; a map with more publishes the most
/// confident ones.
pub const MAX_FEATURES: usize = 256;

/// [`FeatureRecord::kind`] codes.
pub mod feature_kind {
    /// A post, pillar, table leg or wall edge: a small convex target.
    pub const POINT: u32 = 1;
    /// A concave corner.
    pub const CORNER: u32 = 2;
    /// A wall: a partial plane.
    pub const PLANE: u32 = 3;
}

/// [`FeatureRecord::flags`] bits.
pub mod feature_flags {
    /// Heard from two places or more: a *confirmed* feature. Without it the feature is
    /// *tentative*, heard from one place only, where a phantom (an echo off two surfaces, a
    /// corner's echo taken for a wall, a wall's edge taken for a post) cannot be told from a
    /// true feature (`docs/features.md`, "Confirmed and tentative").
    pub const CONFIRMED: u32 = 1;
}

/// The fixed part of a `sonar/features` snapshot; the payload is `feature_count`
/// [`FeatureRecord`]s. Positions are in the grid's frame (metres from the sensor's start).
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::FeaturesHeaderV1")]
#[repr(C)]
pub struct FeaturesHeader {
    pub seq: u64,
    /// When the snapshot was taken, ns since the Unix epoch.
    pub stamp_ns: u64,
    /// Sweeps merged into the feature map since the fusion process started (a clear keeps counting).
    pub sweeps: u64,
    pub layout_version: u32,
    pub feature_count: u32,
    /// `sweep_id` of the readings of the latest sweep merged.
    pub last_sweep_id: u32,
    /// Regions of constant depth found in that sweep.
    pub last_sweep_rcds: u32,
    /// Its observations that refined a feature, that became new features, and features removed
    /// after it (faded: aimed at but no longer heard).
    pub last_sweep_refined: u32,
    pub last_sweep_added: u32,
    pub last_sweep_removed: u32,
    /// Features left out because the map holds more than [`MAX_FEATURES`].
    pub features_left_out: u32,
}

const _: () = assert!(std::mem::size_of::<FeaturesHeader>() == 56);

/// One feature of a `sonar/features` snapshot. Absent values are NaN.
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::FeatureRecordV2")]
#[repr(C)]
pub struct FeatureRecord {
    /// Stable while the feature lives: a feature seen again keeps its id.
    pub id: u64,
    /// [`feature_kind`].
    pub kind: u32,
    /// Sweeps it was seen in.
    pub times_seen: u32,
    /// Point, corner: the target's position. Plane: the foot of the perpendicular from the
    /// origin. Metres.
    pub x_m: f32,
    pub y_m: f32,
    /// Covariance of (x, y), m².
    pub cov_xx: f32,
    pub cov_xy: f32,
    pub cov_yy: f32,
    /// Plane: direction of its normal from the map's origin towards the wall (the foot of the
    /// perpendicular, `x_m`, `y_m`, lies along it). Point, corner: direction of the sensor's ray
    /// at the latest sighting. Degrees counter-clockwise from +x.
    pub angle_deg: f32,
    /// Plane: σ of the normal's direction, degrees; NaN otherwise.
    pub angle_sigma_deg: f32,
    /// In (0, 1): grows each time the feature is seen, shrinks each time it is aimed at and not.
    pub confidence: f32,
    /// Plane: its extent as a segment from (ax, ay) to (bx, by); NaN for the others.
    pub segment_ax_m: f32,
    pub segment_ay_m: f32,
    pub segment_bx_m: f32,
    pub segment_by_m: f32,
    /// Sweep (counted from the last clear) it was last seen in.
    pub last_seen_sweep: u64,
    /// [`feature_flags`] bits; unknown bits are 0.
    pub flags: u32,
    /// Explicit padding to the record's alignment; 0.
    pub reserved: u32,
}

const _: () = assert!(std::mem::size_of::<FeatureRecord>() == 80);

impl FeatureRecord {
    /// [`feature_flags::CONFIRMED`]: heard from two places or more.
    pub fn is_confirmed(&self) -> bool {
        self.flags & feature_flags::CONFIRMED != 0
    }
}

/// Sonar localisation's pose of the sensor in the map after a sweep, on
/// [`LOCALIZED_POSE_SERVICE`], with its uncertainty and what it rests on.
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::LocalizedPoseV1")]
#[repr(C)]
pub struct LocalizedPose {
    /// `host_stamp_ns` of the sweep's first reading: the instant the pose is for.
    pub stamp_ns: u64,
    pub x_m: f32,
    pub y_m: f32,
    pub theta_rad: f32,
    pub layout_version: u32,
    /// Covariance of (x, y, θ): m², m·rad, rad².
    pub cov_xx: f32,
    pub cov_xy: f32,
    pub cov_xtheta: f32,
    pub cov_yy: f32,
    pub cov_ytheta: f32,
    pub cov_thetatheta: f32,
    /// Observations of the sweep matched to features of the map; 0: no fix, the pose is the
    /// odometry's with the previous correction.
    pub matched: u32,
    /// Sweeps localised since the process started.
    pub fixes: u32,
    /// The odometry pose of the same instant, from `robot/pose`: the difference is the drift.
    pub odometry_x_m: f32,
    pub odometry_y_m: f32,
    pub odometry_theta_rad: f32,
    pub reserved: u32,
}

const _: () = assert!(std::mem::size_of::<LocalizedPose>() == 72);

/// Values of [`SlamCorrection::state`]: `FIX` is a fix, every other value says why there is none.
pub mod slam_state {
    /// The sweep matched landmarks of the map and its covariance is within the limits.
    pub const FIX: u32 = 1;
    /// No fix: nothing of the map was seen; the sweep was placed by odometry.
    pub const NO_LANDMARKS: u32 = 2;
    /// No fix: landmarks were seen but the pose is still too uncertain in some direction (a
    /// featureless corridor's axis, a heading no wall fixes).
    pub const UNCERTAIN: u32 = 3;
    /// No fix: the sightings would have made the odometry implausible; they were refused and
    /// the sweep placed by odometry.
    pub const REFUSED: u32 = 4;
    /// Not a new sweep: an earlier one whose pose later sweeps moved (a loop closure above all),
    /// as estimated now; its covariances are NaN. A map built with the sweep's first correction
    /// places that sweep's readings again with this one; the latest correction, for the
    /// odometry's poses from now on, is the latest message of another state.
    pub const REVISED: u32 = 5;
}

/// `sonar-slam`'s estimate after a sweep, on [`SLAM_CORRECTION_SERVICE`]: the `map → odom`
/// transform (the pose of the odometry's frame in the map, so that a pose of `robot/pose` is
/// placed in the map as `correction ∘ odometry pose`), with its covariance, the sweep's pose in
/// the map with its own, and whether it is a fix. Sent for every sweep, fix or not: without a fix
/// the correction is the SLAM's best estimate and the covariance says how little it is worth.
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("sonar::SlamCorrectionV1")]
#[repr(C)]
pub struct SlamCorrection {
    /// `host_stamp_ns` of the sweep's first reading: the instant the pose is of.
    pub stamp_ns: u64,
    pub layout_version: u32,
    pub sweep_id: u32,
    /// [`slam_state`].
    pub state: u32,
    /// Observations of the sweep matched to landmarks or admitted as new ones.
    pub matched: u32,
    /// `map → odom`: translation (m) and rotation (rad).
    pub correction_x_m: f32,
    pub correction_y_m: f32,
    pub correction_theta_rad: f32,
    /// Covariance of the correction's (x, y, θ): m², m·rad, rad².
    pub correction_cov_xx: f32,
    pub correction_cov_xy: f32,
    pub correction_cov_xtheta: f32,
    pub correction_cov_yy: f32,
    pub correction_cov_ytheta: f32,
    pub correction_cov_thetatheta: f32,
    /// The sensor's pose in the map at `stamp_ns`.
    pub x_m: f32,
    pub y_m: f32,
    pub theta_rad: f32,
    /// Covariance of the pose's (x, y, θ): m², m·rad, rad².
    pub cov_xx: f32,
    pub cov_xy: f32,
    pub cov_xtheta: f32,
    pub cov_yy: f32,
    pub cov_ytheta: f32,
    pub cov_thetatheta: f32,
    /// The odometry's pose (`robot/pose`) at `stamp_ns`.
    pub odometry_x_m: f32,
    pub odometry_y_m: f32,
    pub odometry_theta_rad: f32,
    /// Landmarks in the map now.
    pub landmarks: u32,
    /// Sweeps published as fixes since the process started.
    pub fixes: u32,
    /// Sweeps whose sightings were refused to keep the odometry plausible, since the start.
    pub refused: u32,
}

const _: () = assert!(std::mem::size_of::<SlamCorrection>() == 120);
const _: () = assert!(std::mem::align_of::<SlamCorrection>() == 8);

impl SlamCorrection {
    /// Whether this sweep is a fix.
    pub fn is_fix(&self) -> bool {
        self.state == slam_state::FIX
    }
}

/// A failure to set up or use an iceoryx2 resource, with what was being done.
#[derive(Debug, thiserror::Error)]
#[error("{context}: {message}")]
pub struct IpcError {
    pub context: String,
    pub message: String,
}

impl IpcError {
    /// The error of `context`; iceoryx2's "too many ports" errors are explained, since the usual
    /// cause is a second pipeline started on the namespace of a running one.
    pub fn new(context: impl Into<String>, err: impl std::fmt::Debug) -> Self {
        let mut message = format!("{err:?}");
        if let Some(ports) = [
            ("ExceedsMaxSupportedPublishers", "publishers"),
            ("ExceedsMaxSupportedSubscribers", "subscribers"),
        ]
        .iter()
        .find_map(|(name, ports)| message.contains(name).then_some(ports))
        {
            message.push_str(&format!(
                ": the service already has all the {ports} it allows. Is a pipeline (or another \
                 copy of this program) already running on this iceoryx2 namespace? `sonar \
                 services` lists who is attached; stop it, or give this pipeline a namespace of \
                 its own with --iox-prefix (and --iox-root), the same for each of its processes"
            ));
        }
        Self {
            context: context.into(),
            message,
        }
    }

    /// Whether the service had no room for another port of this kind: a limit of its QoS, not a
    /// passing state (a port had later would take the place of one the pipeline needs).
    pub fn is_service_full(&self) -> bool {
        self.message.contains("ExceedsMaxSupported")
    }
}

/// How long iceoryx2 waits for another process to finish creating what both share (a service, a
/// connection between a publisher and a subscriber), unless a config file says otherwise;
/// iceoryx2's default is 1 s. A connection that times out is never tried again by iceoryx2 (not
/// until the port list changes: `port::details::receiver`), so a subscriber whose publisher is
/// descheduled for a second while creating their connection receives nothing from it for the
/// rest of the run, and the publisher's sends still succeed. (On a loaded 2-core CI machine a
/// recording of a tour came out without its odometry while the simulator had sent every pose;
/// this is the one way found to lose a whole stream like that, not reproduced here.) Waiting
/// longer costs nothing when the creator is alive; a dead creator's leftovers are removed before
/// a node starts ([`crate::namespace`]), whose own patience this matches.
pub const CREATION_PATIENCE: std::time::Duration = crate::namespace::PATIENCE;

/// Installs iceoryx2's SIGINT/SIGTERM handler now, once per process. iceoryx2 installs it only
/// the first time something asks whether a stop was requested (the first [`Node::wait`]), so
/// until then a SIGTERM kills the process outright and the node it created stays behind in the
/// namespace (the launcher's `kill -9` test caught the driver so, mid-handshake, about one run in
/// ten). Called just before creating the node by the processes that stop on a wait's termination
/// request and wait soon after (the driver, the fusion, the SLAM, the recorder, the Foxglove
/// server); not by those that handle signals themselves (the launcher, the viewer, the
/// simulator), whose handlers iceoryx2's would replace, nor where no wait follows (a stop would
/// then wait for nothing). A stop requested after it is seen by the first wait.
pub fn catch_termination_requests() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    // Nothing can have been caught before the handler existed, so this asks away nothing.
    ONCE.call_once(|| {
        iceoryx2_bb_posix::signal::SignalHandler::termination_requested();
    });
}

/// Where the iceoryx2 services live. Every process of one pipeline must get the same values.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct IpcArgs {
    /// iceoryx2 config file (TOML). Without it, iceoryx2's own lookup applies
    /// (./config/iceoryx2.toml, ~/.config/iceoryx2/iceoryx2.toml, /etc/iceoryx2/iceoryx2.toml).
    #[arg(long, env = "SONAR_IOX_CONFIG", value_name = "FILE")]
    pub iox_config: Option<PathBuf>,
    /// Prefix of the shared-memory files; pipelines with different prefixes never see each other
    /// [default: iceoryx2's, iox2_, or --iox-config's].
    #[arg(long, env = "SONAR_IOX_PREFIX", value_name = "PREFIX")]
    pub iox_prefix: Option<String>,
    /// Directory of iceoryx2's service and node records [default: iceoryx2's, /tmp/iceoryx2/, or
    /// --iox-config's].
    #[arg(long, env = "SONAR_IOX_ROOT", value_name = "DIR")]
    pub iox_root: Option<PathBuf>,
}

impl IpcArgs {
    /// The iceoryx2 configuration these arguments describe.
    pub fn config(&self) -> Result<Config, IpcError> {
        let mut cfg = match &self.iox_config {
            Some(file) => {
                let path = FilePath::new(file.as_os_str().as_encoded_bytes())
                    .map_err(|e| IpcError::new(format!("config path {}", file.display()), e))?;
                Config::from_file(&path)
                    .map_err(|e| IpcError::new(format!("read {}", file.display()), e))?
            }
            None => {
                let mut cfg = Config::global_config().clone();
                cfg.global.creation_timeout = cfg.global.creation_timeout.max(CREATION_PATIENCE);
                cfg
            }
        };
        if let Some(prefix) = &self.iox_prefix {
            cfg.global.prefix = FileName::new(prefix.as_bytes())
                .map_err(|e| IpcError::new(format!("prefix {prefix:?}"), e))?;
        }
        if let Some(root) = &self.iox_root {
            let mut bytes = root.as_os_str().as_encoded_bytes().to_vec();
            if !bytes.ends_with(b"/") {
                bytes.push(b'/');
            }
            let path = Path::new(&bytes)
                .map_err(|e| IpcError::new(format!("root path {}", root.display()), e))?;
            cfg.global.set_root_path(&path);
        }
        Ok(cfg)
    }

    /// Where this process looks for the pipeline, for messages that must say it: `iceoryx2
    /// prefix "iox2_", root /tmp/iceoryx2/`.
    pub fn describe(&self) -> String {
        match self.config() {
            Ok(cfg) => format!(
                "iceoryx2 prefix {:?}, root {}",
                String::from_utf8_lossy(cfg.global.prefix.as_bytes()),
                String::from_utf8_lossy(cfg.global.root_path().as_bytes())
            ),
            Err(e) => format!("an iceoryx2 namespace that cannot be read ({e:?})"),
        }
    }

    /// Creates this process's node. First removes what processes of the namespace killed at the
    /// wrong moment left behind, which would otherwise make creating the node or opening a service
    /// hang or fail (see [`crate::namespace`]); then iceoryx2 finds no dead node left to clean.
    pub fn node(&self, name: &str) -> Result<Node<ipc::Service>, IpcError> {
        let cfg = self.config()?;
        // An access problem explains a failure below better than iceoryx2's `InternalError`.
        let explained = |err: IpcError| match crate::namespace::access_problem(&cfg) {
            Some(why) => IpcError {
                context: format!("cannot enter the pipeline's iceoryx2 namespace as {name}"),
                message: why,
            },
            None => err,
        };
        crate::namespace::recover(&cfg).map_err(|e| {
            explained(IpcError {
                context: "recover the iceoryx2 namespace".into(),
                message: e.to_string(),
            })
        })?;
        let node_name = NodeName::new(name).map_err(|e| IpcError::new("node name", e))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(&cfg)
            .create::<ipc::Service>()
            .map_err(|e| explained(IpcError::new(format!("create iceoryx2 node {name}"), e)))?;
        crate::namespace::secure(&cfg).map_err(|e| IpcError {
            context: "make the iceoryx2 namespace owner-only".into(),
            message: e.to_string(),
        })?;
        Ok(node)
    }
}

fn service_name(name: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(name).map_err(|e| IpcError::new(format!("service name {name}"), e))
}

pub type PubSub<T> = publish_subscribe::PortFactory<ipc::Service, T, ()>;
pub type Event = event::PortFactory<ipc::Service>;

/// How a publish-subscribe service of one fixed-size payload is set up (`docs/ipc.md` has each
/// service's).
#[derive(Debug, Clone, Copy)]
struct Qos {
    publishers: usize,
    subscribers: usize,
    /// Samples a subscriber buffers; beyond it the oldest is dropped.
    buffer: usize,
    /// Samples a subscriber may hold at once; `None` keeps iceoryx2's default.
    borrowed: Option<usize>,
    /// Samples a late subscriber gets at once.
    history: usize,
}

/// Opens (or creates) the service `name` of `T` with `qos`.
fn pubsub<T>(node: &Node<ipc::Service>, name: &str, qos: Qos) -> Result<PubSub<T>, IpcError>
where
    T: std::fmt::Debug + ZeroCopySend + 'static,
{
    let builder = node
        .service_builder(&service_name(name)?)
        .publish_subscribe::<T>()
        .max_publishers(qos.publishers)
        .max_subscribers(qos.subscribers)
        .subscriber_max_buffer_size(qos.buffer)
        .history_size(qos.history);
    let builder = match qos.borrowed {
        Some(borrowed) => builder.subscriber_max_borrowed_samples(borrowed),
        None => builder,
    };
    builder
        .open_or_create()
        .map_err(|e| IpcError::new(format!("open {name}"), e))
}

/// `sonar/readings`. A subscriber buffers a few sweeps so a slow consumer (a recorder on a busy
/// machine) loses nothing; readings are 104 B, so this costs little memory.
pub fn readings_service(node: &Node<ipc::Service>) -> Result<PubSub<Reading>, IpcError> {
    pubsub(
        node,
        READINGS_SERVICE,
        Qos {
            publishers: 2,
            subscribers: 8,
            buffer: 256,
            borrowed: Some(4),
            history: 0,
        },
    )
}

/// `sonar/sweep_ends`: the driver's (and a second publisher's, as `sonar/readings` allows); a
/// few ends buffered, since only the latest matters to a consumer that fell behind.
pub fn sweep_ends_service(node: &Node<ipc::Service>) -> Result<PubSub<SweepEnd>, IpcError> {
    pubsub(
        node,
        SWEEP_ENDS_SERVICE,
        Qos {
            publishers: 2,
            subscribers: 8,
            buffer: 4,
            borrowed: None,
            history: 0,
        },
    )
}

/// `sonar/commands`: many writers (viewer, scripts), one reader that acts (the driver) and
/// readers that record (recorders, a bridge). Room for 7 of those beside the driver, so recorders
/// started first never leave the driver without a place (two did, and the driver exited).
pub fn commands_service(node: &Node<ipc::Service>) -> Result<PubSub<ScanCommand>, IpcError> {
    pubsub(
        node,
        COMMANDS_SERVICE,
        Qos {
            publishers: 8,
            subscribers: 8,
            buffer: 16,
            borrowed: None,
            history: 0,
        },
    )
}

/// `sonar/driver_status`, history 1 so a viewer that starts late sees the state at once.
pub fn driver_status_service(node: &Node<ipc::Service>) -> Result<PubSub<DriverStatus>, IpcError> {
    pubsub(
        node,
        DRIVER_STATUS_SERVICE,
        Qos {
            publishers: 1,
            subscribers: 8,
            buffer: 1,
            borrowed: None,
            history: 1,
        },
    )
}

pub type GridService = publish_subscribe::PortFactory<ipc::Service, [u8], GridHeader>;

const GRID_MAX_SUBSCRIBERS: usize = 6;
const GRID_SUBSCRIBER_BUFFER: usize = 1;
const GRID_SUBSCRIBER_BORROWED: usize = 2;
const GRID_HISTORY: usize = 1;
/// Loans a publisher may hold at once (iceoryx2's default).
const PUBLISHER_MAX_LOANS: usize = 2;
/// Snapshots the grid publisher's data segment has room for: its size in /dev/shm is this many
/// times (header + cells).
pub const GRID_SEGMENT_SLOTS: usize = GRID_MAX_SUBSCRIBERS
    * (GRID_SUBSCRIBER_BUFFER + GRID_SUBSCRIBER_BORROWED)
    + GRID_HISTORY
    + PUBLISHER_MAX_LOANS;

/// `sonar/grid`: history 1 so a late joiner gets the current map at once; a subscriber buffers one
/// snapshot (a newer one replaces it: viewers want the latest, never a backlog) and may hold two
/// while it reads the next: [`GRID_SEGMENT_SLOTS`] = 6 × (1 + 2) + 1 + 2 = 21 snapshots of shared
/// memory (sparse: only written pages are committed).
pub fn grid_service(node: &Node<ipc::Service>) -> Result<GridService, IpcError> {
    latest_snapshot_service(node, GRID_SERVICE)
}

/// A service of snapshots (a header and a slice) of which consumers want the latest, never a
/// backlog: the grid's policy, shared by `sonar/features`.
fn latest_snapshot_service<T, H>(
    node: &Node<ipc::Service>,
    name: &str,
) -> Result<publish_subscribe::PortFactory<ipc::Service, [T], H>, IpcError>
where
    T: std::fmt::Debug + ZeroCopySend + 'static,
    H: std::fmt::Debug + ZeroCopySend + 'static,
{
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<[T]>()
        .user_header::<H>()
        .max_publishers(1)
        .max_subscribers(GRID_MAX_SUBSCRIBERS)
        .subscriber_max_buffer_size(GRID_SUBSCRIBER_BUFFER)
        .subscriber_max_borrowed_samples(GRID_SUBSCRIBER_BORROWED)
        .history_size(GRID_HISTORY)
        .open_or_create()
        .map_err(|e| IpcError::new(format!("open {name}"), e))
}

/// `sonar/radar`, with the same policy as the grid.
pub fn radar_service(node: &Node<ipc::Service>) -> Result<PubSub<Radar>, IpcError> {
    pubsub(
        node,
        RADAR_SERVICE,
        Qos {
            publishers: 1,
            subscribers: 6,
            buffer: 1,
            borrowed: Some(2),
            history: 1,
        },
    )
}

/// `sonar/fusion_commands`: many writers, the fusion engine reads.
pub fn fusion_commands_service(
    node: &Node<ipc::Service>,
) -> Result<PubSub<FusionCommand>, IpcError> {
    pubsub(
        node,
        FUSION_COMMANDS_SERVICE,
        Qos {
            publishers: 8,
            subscribers: 8,
            buffer: 16,
            borrowed: None,
            history: 0,
        },
    )
}

/// `robot/pose`, history 1 so the fusion engine starts from the latest pose; a buffer of 256 like
/// the readings', so a fusion busy with a burst of readings (a replay, a fast simulation) loses
/// none of the poses that place them.
pub fn pose_service(node: &Node<ipc::Service>) -> Result<PubSub<Pose2D>, IpcError> {
    pubsub(node, POSE_SERVICE, POSE_QOS)
}

/// The policy of `robot/pose` and `robot/true_pose`.
const POSE_QOS: Qos = Qos {
    publishers: 2,
    subscribers: 8,
    // 2.5 s of a replay at ×40 (800 poses a second): a fusion stalled by a snapshot on a
    // loaded machine loses no pose, so its readings are placed as in the live run.
    buffer: 2048,
    borrowed: None,
    history: 1,
};

/// `robot/true_pose`, with the policy of [`pose_service`]: the simulator publishes the truth beside
/// its odometry, at the same instants, and a consumer descheduled on a loaded machine loses the
/// truth no sooner than the odometry (a buffer of 16, 40 ms at ×20, lost a tenth of the truth
/// beside two busy loops, and the tour's first poses when the consumer read late).
pub fn true_pose_service(node: &Node<ipc::Service>) -> Result<PubSub<Pose2D>, IpcError> {
    pubsub(node, TRUE_POSE_SERVICE, POSE_QOS)
}

/// `sonar/fusion_status`, with the policy of the driver's status: history 1 so a viewer that
/// starts late sees the counters at once.
pub fn fusion_status_service(node: &Node<ipc::Service>) -> Result<PubSub<FusionStatus>, IpcError> {
    pubsub(
        node,
        FUSION_STATUS_SERVICE,
        Qos {
            publishers: 1,
            subscribers: 8,
            buffer: 1,
            borrowed: None,
            history: 1,
        },
    )
}

pub type FeaturesService =
    publish_subscribe::PortFactory<ipc::Service, [FeatureRecord], FeaturesHeader>;

/// `sonar/features`, with the grid's policy: history 1 so a late joiner gets the current features
/// at once, a buffer of one (the latest snapshot replaces an unread one). Small: at most
/// [`MAX_FEATURES`] × 80 B a snapshot.
pub fn features_service(node: &Node<ipc::Service>) -> Result<FeaturesService, IpcError> {
    latest_snapshot_service(node, FEATURES_SERVICE)
}

/// `sonar/slam_landmarks`, with the features' policy (history 1, the latest snapshot replaces an
/// unread one) and their layout: a [`FeaturesHeader`] and one [`FeatureRecord`] per landmark, in
/// the map frame of `sonar/slam_correction` (not the grid's). What the fields mean for a landmark
/// is in `docs/ipc.md`.
pub fn slam_landmarks_service(node: &Node<ipc::Service>) -> Result<FeaturesService, IpcError> {
    latest_snapshot_service(node, SLAM_LANDMARKS_SERVICE)
}

/// `sonar/localized_pose`, with the driver status's policy: history 1 so a late joiner sees the
/// latest fix at once.
pub fn localized_pose_service(
    node: &Node<ipc::Service>,
) -> Result<PubSub<LocalizedPose>, IpcError> {
    pubsub(
        node,
        LOCALIZED_POSE_SERVICE,
        Qos {
            publishers: 1,
            subscribers: 8,
            buffer: 16,
            borrowed: None,
            history: 1,
        },
    )
}

/// `sonar/slam_correction`, with the localised pose's policy: history 1 so a fusion that starts
/// late places its readings with the latest correction at once.
pub fn slam_correction_service(
    node: &Node<ipc::Service>,
) -> Result<PubSub<SlamCorrection>, IpcError> {
    pubsub(
        node,
        SLAM_CORRECTION_SERVICE,
        Qos {
            publishers: 1,
            subscribers: 8,
            buffer: 256,
            borrowed: None,
            history: 1,
        },
    )
}

/// The event service that wakes the consumers of the publish-subscribe service of the same name.
pub fn wakeup_service(node: &Node<ipc::Service>, name: &str) -> Result<Event, IpcError> {
    node.service_builder(&service_name(name)?)
        .event()
        .open_or_create()
        .map_err(|e| IpcError::new(format!("open event service {name}"), e))
}

/// A listener on the wake-up event of service `name`: what a consumer's waitset sleeps on.
pub fn wakeup_listener(
    node: &Node<ipc::Service>,
    name: &str,
) -> Result<iceoryx2::port::listener::Listener<ipc::Service>, IpcError> {
    wakeup_service(node, name)?
        .listener_builder()
        .create()
        .map_err(|e| IpcError::new(format!("create {name} listener"), e))
}

/// A notifier on the wake-up event of service `name`, for a producer to call after publishing.
pub fn wakeup_notifier(
    node: &Node<ipc::Service>,
    name: &str,
) -> Result<iceoryx2::port::notifier::Notifier<ipc::Service>, IpcError> {
    wakeup_service(node, name)?
        .notifier_builder()
        .create()
        .map_err(|e| IpcError::new(format!("create {name} notifier"), e))
}

/// Publishes a snapshot of `records` under `header` on a slice service (`sonar/features`,
/// `sonar/slam_landmarks`) and wakes its consumers through `notifier`. The error says which step
/// failed; the caller logs it (a lost snapshot is replaced by the next).
pub fn send_snapshot<T, H>(
    publisher: &iceoryx2::port::publisher::Publisher<ipc::Service, [T], H>,
    notifier: &iceoryx2::port::notifier::Notifier<ipc::Service>,
    header: H,
    records: &[T],
) -> Result<(), String>
where
    T: Copy + std::fmt::Debug + ZeroCopySend + 'static,
    H: Default + std::fmt::Debug + ZeroCopySend + 'static,
{
    let mut sample = publisher
        .loan_slice_uninit(records.len())
        .map_err(|e| format!("loan: {e:?}"))?;
    *sample.user_header_mut() = header;
    sample
        .write_from_slice(records)
        .send()
        .map_err(|e| format!("send: {e:?}"))?;
    notifier.notify().map_err(|e| format!("notify: {e:?}"))?;
    Ok(())
}

/// Consumes every pending wake-up of `listener`, so the waitset it is attached to sleeps again.
pub fn drain_wakeups(
    listener: &iceoryx2::port::listener::Listener<ipc::Service>,
) -> Result<(), IpcError> {
    listener
        .try_wait(|_| {})
        .map(drop)
        .map_err(|e| IpcError::new("take wake-ups", e))
}

/// Attaches every listener of `listeners` to `waitset`: the guards keep them attached.
pub fn attach_all<'waitset, 'attachment>(
    waitset: &'waitset WaitSet<ipc::Service>,
    listeners: &'attachment [iceoryx2::port::listener::Listener<ipc::Service>],
) -> Result<Vec<WaitSetGuard<'waitset, 'attachment, ipc::Service>>, IpcError> {
    listeners
        .iter()
        .map(|listener| waitset.attach_notification(listener))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| IpcError::new("attach wake-up listeners", e))
}

/// Sleeps in `waitset` until one of its attachments wakes it or `due` comes (at once if past);
/// false when SIGINT or SIGTERM asks the process to stop.
pub fn sleep_until(
    waitset: &WaitSet<ipc::Service>,
    due: std::time::Instant,
) -> Result<bool, IpcError> {
    let woke = waitset
        .wait_and_process_once_with_timeout(
            |_| CallbackProgression::Continue,
            due.saturating_duration_since(std::time::Instant::now()),
        )
        .map_err(|e| IpcError::new("wait", e))?;
    Ok(woke != iceoryx2::waitset::WaitSetRunResult::TerminationRequest)
}

/// A file descriptor that a waitset sleeps on beside its listeners: the serial port a driver
/// reads, the terminal a viewer reads. One wait then covers the device, the pipeline's wake-up
/// events, the next deadline and SIGINT/SIGTERM, so an idle process sleeps instead of polling.
///
/// It does not own the descriptor: the port or terminal must outlive the attachment.
#[derive(Debug)]
pub struct WatchedFd(FileDescriptor);

impl WatchedFd {
    /// `None` when `fd` is not an open descriptor.
    pub fn new(fd: &impl std::os::fd::AsRawFd) -> Option<Self> {
        FileDescriptor::non_owning_new(fd.as_raw_fd()).map(Self)
    }
}

impl FileDescriptorBased for WatchedFd {
    fn file_descriptor(&self) -> &FileDescriptor {
        &self.0
    }
}

impl SynchronousMultiplexing for WatchedFd {}

/// Nanoseconds since the Unix epoch (0 if the clock is before it).
pub fn unix_time_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// A watched descriptor wakes the waitset when it has something to read, and not before.
    #[test]
    fn a_watched_descriptor_wakes_the_waitset_when_readable() {
        use std::io::Write;
        let (mut writer, reader) = std::os::unix::net::UnixStream::pair().unwrap();
        let watched = WatchedFd::new(&reader).unwrap();
        let waitset = WaitSetBuilder::new().create::<ipc::Service>().unwrap();
        let guard = waitset.attach_notification(&watched).unwrap();
        let woke_within = |timeout| {
            let mut woke = false;
            waitset
                .wait_and_process_once_with_timeout(
                    |id| {
                        woke |= id.has_event_from(&guard);
                        CallbackProgression::Continue
                    },
                    timeout,
                )
                .unwrap();
            woke
        };
        assert!(
            !woke_within(Duration::from_millis(10)),
            "nothing written yet"
        );
        writer.write_all(b"x").unwrap();
        assert!(woke_within(Duration::from_secs(10)));
    }

    /// Without a config file, iceoryx2 waits at least [`CREATION_PATIENCE`] for a creation by
    /// another process (its own default, 1 s, is shorter than a loaded machine's stalls).
    #[test]
    fn without_a_config_file_a_creation_is_waited_for_patiently() {
        let cfg = IpcArgs::default().config().unwrap();
        assert!(cfg.global.creation_timeout >= CREATION_PATIENCE);
        assert!(Config::default().global.creation_timeout < CREATION_PATIENCE);
    }

    /// The defaults `--help` names for --iox-prefix and --iox-root are iceoryx2's.
    #[test]
    fn the_namespace_defaults_named_in_the_help_are_iceoryx2s() {
        let cfg = Config::default();
        assert_eq!(cfg.global.prefix.as_bytes(), b"iox2_");
        assert_eq!(cfg.global.root_path().as_bytes(), b"/tmp/iceoryx2/");
    }
    use std::mem::offset_of;

    /// The offsets `docs/ipc.md` documents for other languages.
    #[test]
    fn reading_layout_matches_documentation() {
        assert_eq!(offset_of!(Reading, seq), 0);
        assert_eq!(offset_of!(Reading, host_stamp_ns), 8);
        assert_eq!(offset_of!(Reading, layout_version), 16);
        assert_eq!(offset_of!(Reading, sweep_id), 28);
        assert_eq!(offset_of!(Reading, flags), 32);
        assert_eq!(offset_of!(Reading, angle_deg), 36);
        assert_eq!(offset_of!(Reading, distance_m), 48);
        assert_eq!(offset_of!(Reading, echo_us), 64);
        assert_eq!(offset_of!(Reading, direction), 96);
        assert_eq!(offset_of!(Reading, pings_used), 99);
    }

    #[test]
    fn driver_status_layout_matches_documentation() {
        assert_eq!(offset_of!(DriverStatus, head_resets), 60);
        assert_eq!(offset_of!(DriverStatus, silences), 64);
        assert_eq!(offset_of!(DriverStatus, device_errors), 68);
        assert_eq!(offset_of!(DriverStatus, head_id), 72);
        assert_eq!(offset_of!(DriverStatus, last_device_error), 104);
        assert_eq!(offset_of!(DriverStatus, head_fault), 200);
        assert_eq!(offset_of!(DriverStatus, hardware_faults), 204);
    }

    #[test]
    fn fusion_status_layout_matches_documentation() {
        assert_eq!(offset_of!(FusionStatus, stamp_ns), 0);
        assert_eq!(offset_of!(FusionStatus, readings_received), 8);
        assert_eq!(offset_of!(FusionStatus, readings_fused), 16);
        assert_eq!(offset_of!(FusionStatus, readings_lost), 24);
        assert_eq!(offset_of!(FusionStatus, readings_out_of_order), 32);
        assert_eq!(offset_of!(FusionStatus, readings_rejected), 40);
        assert_eq!(offset_of!(FusionStatus, last_seq), 48);
        assert_eq!(offset_of!(FusionStatus, snapshots_published), 56);
        assert_eq!(offset_of!(FusionStatus, snapshots_skipped), 64);
        assert_eq!(offset_of!(FusionStatus, saves), 72);
        assert_eq!(offset_of!(FusionStatus, last_save_ns), 80);
        assert_eq!(offset_of!(FusionStatus, saved_readings_fused), 88);
        assert_eq!(offset_of!(FusionStatus, save_failures), 96);
        assert_eq!(offset_of!(FusionStatus, last_save_copy_us), 100);
        assert_eq!(offset_of!(FusionStatus, last_save_write_us), 104);
        assert_eq!(offset_of!(FusionStatus, restored), 108);
        assert_eq!(offset_of!(FusionStatus, layout_version), 112);
        assert_eq!(offset_of!(FusionStatus, feature_readings_skipped), 116);
        assert_eq!(std::mem::align_of::<FusionStatus>(), 8);
    }

    #[test]
    fn features_layout_matches_documentation() {
        assert_eq!(offset_of!(FeaturesHeader, seq), 0);
        assert_eq!(offset_of!(FeaturesHeader, stamp_ns), 8);
        assert_eq!(offset_of!(FeaturesHeader, sweeps), 16);
        assert_eq!(offset_of!(FeaturesHeader, layout_version), 24);
        assert_eq!(offset_of!(FeaturesHeader, feature_count), 28);
        assert_eq!(offset_of!(FeaturesHeader, last_sweep_id), 32);
        assert_eq!(offset_of!(FeaturesHeader, last_sweep_rcds), 36);
        assert_eq!(offset_of!(FeaturesHeader, last_sweep_refined), 40);
        assert_eq!(offset_of!(FeaturesHeader, last_sweep_added), 44);
        assert_eq!(offset_of!(FeaturesHeader, last_sweep_removed), 48);
        assert_eq!(offset_of!(FeaturesHeader, features_left_out), 52);
        assert_eq!(offset_of!(FeatureRecord, id), 0);
        assert_eq!(offset_of!(FeatureRecord, kind), 8);
        assert_eq!(offset_of!(FeatureRecord, times_seen), 12);
        assert_eq!(offset_of!(FeatureRecord, x_m), 16);
        assert_eq!(offset_of!(FeatureRecord, y_m), 20);
        assert_eq!(offset_of!(FeatureRecord, cov_xx), 24);
        assert_eq!(offset_of!(FeatureRecord, cov_xy), 28);
        assert_eq!(offset_of!(FeatureRecord, cov_yy), 32);
        assert_eq!(offset_of!(FeatureRecord, angle_deg), 36);
        assert_eq!(offset_of!(FeatureRecord, angle_sigma_deg), 40);
        assert_eq!(offset_of!(FeatureRecord, confidence), 44);
        assert_eq!(offset_of!(FeatureRecord, segment_ax_m), 48);
        assert_eq!(offset_of!(FeatureRecord, segment_by_m), 60);
        assert_eq!(offset_of!(FeatureRecord, last_seen_sweep), 64);
        assert_eq!(offset_of!(FeatureRecord, flags), 72);
        assert_eq!(offset_of!(FeatureRecord, reserved), 76);
        assert_eq!(std::mem::align_of::<FeatureRecord>(), 8);
    }

    #[test]
    fn localized_pose_layout_matches_documentation() {
        assert_eq!(offset_of!(LocalizedPose, stamp_ns), 0);
        assert_eq!(offset_of!(LocalizedPose, x_m), 8);
        assert_eq!(offset_of!(LocalizedPose, theta_rad), 16);
        assert_eq!(offset_of!(LocalizedPose, layout_version), 20);
        assert_eq!(offset_of!(LocalizedPose, cov_xx), 24);
        assert_eq!(offset_of!(LocalizedPose, cov_thetatheta), 44);
        assert_eq!(offset_of!(LocalizedPose, matched), 48);
        assert_eq!(offset_of!(LocalizedPose, fixes), 52);
        assert_eq!(offset_of!(LocalizedPose, odometry_x_m), 56);
        assert_eq!(offset_of!(LocalizedPose, odometry_theta_rad), 64);
        assert_eq!(offset_of!(LocalizedPose, reserved), 68);
    }

    #[test]
    fn slam_correction_layout_matches_documentation() {
        assert_eq!(offset_of!(SlamCorrection, stamp_ns), 0);
        assert_eq!(offset_of!(SlamCorrection, layout_version), 8);
        assert_eq!(offset_of!(SlamCorrection, sweep_id), 12);
        assert_eq!(offset_of!(SlamCorrection, state), 16);
        assert_eq!(offset_of!(SlamCorrection, matched), 20);
        assert_eq!(offset_of!(SlamCorrection, correction_x_m), 24);
        assert_eq!(offset_of!(SlamCorrection, correction_theta_rad), 32);
        assert_eq!(offset_of!(SlamCorrection, correction_cov_xx), 36);
        assert_eq!(offset_of!(SlamCorrection, correction_cov_thetatheta), 56);
        assert_eq!(offset_of!(SlamCorrection, x_m), 60);
        assert_eq!(offset_of!(SlamCorrection, theta_rad), 68);
        assert_eq!(offset_of!(SlamCorrection, cov_xx), 72);
        assert_eq!(offset_of!(SlamCorrection, cov_thetatheta), 92);
        assert_eq!(offset_of!(SlamCorrection, odometry_x_m), 96);
        assert_eq!(offset_of!(SlamCorrection, odometry_theta_rad), 104);
        assert_eq!(offset_of!(SlamCorrection, landmarks), 108);
        assert_eq!(offset_of!(SlamCorrection, fixes), 112);
        assert_eq!(offset_of!(SlamCorrection, refused), 116);
    }

    #[test]
    fn padded_text_round_trips_and_cuts_to_fit() {
        let mut field = [0xFFu8; 8];
        set_padded_text(&mut field, "HEAD-7");
        assert_eq!(padded_text(&field), "HEAD-7");
        set_padded_text(&mut field, "much too long for it");
        assert_eq!(padded_text(&field), "much too");
        set_padded_text(&mut field, "°C");
        assert_eq!(padded_text(&field), "?C");
        assert_eq!(padded_text(&[b'a', 0xFF, b'b']), "a");
    }

    #[test]
    fn cell_encoding_keeps_unknown_apart() {
        assert_eq!(encode_probability(0.0), 0);
        assert_eq!(encode_probability(0.5), 127);
        assert_eq!(encode_probability(1.0), 254);
        assert_eq!(encode_probability(7.0), 254);
        assert_eq!(decode_probability(CELL_UNKNOWN), None);
        for v in 0..=254u8 {
            assert_eq!(encode_probability(decode_probability(v).unwrap()), v);
        }
    }

    #[test]
    fn command_kinds_round_trip_and_unknown_is_rejected() {
        for kind in [
            ScanCommandKind::FullScan,
            ScanCommandKind::LocalScan,
            ScanCommandKind::Stop,
            ScanCommandKind::Status,
        ] {
            assert_eq!(ScanCommand::new(kind, 0.0, 0.0).kind(), Some(kind));
        }
        let bogus = ScanCommand {
            kind: 99,
            ..Default::default()
        };
        assert_eq!(bogus.kind(), None);
    }
}
