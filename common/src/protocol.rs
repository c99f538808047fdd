//! The line protocol between the microcontroller and the PC (see `docs/protocol.md`).
//!
//! Every line is `$BODY*HHHH\n`: `BODY` is comma-separated printable ASCII whose first field is the
//! message tag, `HHHH` the CRC-16/CCITT-FALSE of the `BODY` bytes as four hex digits. Angles travel
//! as signed integer centidegrees so that neither side ever parses a float.
//!
//! Version 1 framed lines with `*HH`, the XOR of the body bytes (NMEA 0183). An XOR cannot see two
//! flipped bits in the same bit position of two bytes, and serial noise does exactly that: a fault
//! probe published every one of 200 such lines as a reading. Version 2 ([`ProtocolVersion::V2`])
//! replaces it with a CRC-16, which sees every error of up to three bits in a line this short, and
//! adds the head's identity to `HELLO`. Version 1 is still spoken on request; the two framings never
//! mix (a receiver of one rejects the other's checksum width).
//!
//! Everything here is pure: [`encode_command`]/[`encode_device`] build lines, [`parse_command`] and
//! [`parse_device`] read them back, and [`LineFramer`] cuts a byte stream into lines. Parsing never
//! panics and rejects any line whose check does not match before looking at its fields.

use std::fmt::Write as _;

/// A version of the line protocol: how lines are checked and what `HELLO` carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ProtocolVersion {
    /// XOR checksum `*HH`; `HELLO` without a head identity.
    V1,
    /// CRC-16/CCITT-FALSE `*HHHH`; `HELLO` with the head's identity, also sent unprompted at reset.
    V2,
}

impl ProtocolVersion {
    /// The number exchanged in `HELLO`.
    pub fn number(self) -> u32 {
        match self {
            ProtocolVersion::V1 => 1,
            ProtocolVersion::V2 => 2,
        }
    }

    pub fn from_number(n: u32) -> Option<Self> {
        match n {
            1 => Some(ProtocolVersion::V1),
            2 => Some(ProtocolVersion::V2),
            _ => None,
        }
    }

    /// Hex digits of the line check.
    fn check_digits(self) -> usize {
        match self {
            ProtocolVersion::V1 => 2,
            ProtocolVersion::V2 => 4,
        }
    }

    /// The line check of a body.
    pub fn check(self, body: &[u8]) -> u16 {
        match self {
            ProtocolVersion::V1 => u16::from(xor_checksum(body)),
            ProtocolVersion::V2 => crc16_ccitt_false(body),
        }
    }
}

impl std::str::FromStr for ProtocolVersion {
    type Err = String;

    /// `1` or `2`, as on a command line.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        s.trim()
            .parse()
            .ok()
            .and_then(Self::from_number)
            .ok_or_else(|| format!("protocol version must be 1 or 2, got {s:?}"))
    }
}

impl std::fmt::Display for ProtocolVersion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.number())
    }
}

/// The newest version, spoken unless told otherwise.
pub const PROTOCOL_VERSION: ProtocolVersion = ProtocolVersion::V2;
/// Longest head identity in `HELLO`.
pub const MAX_HEAD_ID_LEN: usize = 32;
/// Longest line either side accepts, terminator included; longer input is discarded as garbage.
pub const MAX_LINE_LEN: usize = 160;
/// Most pings one reading can carry on the wire (the paper uses four).
pub const MAX_PINGS_PER_READING: usize = 8;

/// Direction of the stepper: `Ccw` increases the angle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    Ccw,
    Cw,
}

impl Direction {
    /// +1 for counter-clockwise (angle increasing), -1 for clockwise.
    pub fn sign(self) -> i32 {
        match self {
            Direction::Ccw => 1,
            Direction::Cw => -1,
        }
    }

    pub fn reversed(self) -> Self {
        match self {
            Direction::Ccw => Direction::Cw,
            Direction::Cw => Direction::Ccw,
        }
    }

    fn wire(self) -> &'static str {
        match self {
            Direction::Ccw => "+",
            Direction::Cw => "-",
        }
    }

    fn from_wire(s: &str) -> Result<Self, ParseError> {
        match s {
            "+" => Ok(Direction::Ccw),
            "-" => Ok(Direction::Cw),
            _ => Err(ParseError::BadField("direction")),
        }
    }
}

/// Which of the paper's two modes a sweep belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum WireScanMode {
    /// Between the two limit switches (300°).
    Full,
    /// Back and forth over a segment chosen by the PC.
    Local,
}

impl WireScanMode {
    fn wire(self) -> &'static str {
        match self {
            WireScanMode::Full => "F",
            WireScanMode::Local => "L",
        }
    }

    fn from_wire(s: &str) -> Result<Self, ParseError> {
        match s {
            "F" => Ok(WireScanMode::Full),
            "L" => Ok(WireScanMode::Local),
            _ => Err(ParseError::BadField("scan mode")),
        }
    }
}

/// Which limit switch closed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Limit {
    Min,
    Max,
}

/// What the device is doing, as reported by `ST`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DeviceState {
    Idle,
    Full,
    Local,
    /// Looking for the MIN limit switch after a reset (version 2).
    Homing,
    /// Stopped on a hardware fault (a limit switch that did not close where it should, or both
    /// closed), reported just before with `ERR,HARDWARE`: the head moves again only after `RESET`.
    Fault,
}

/// Error codes a device reports with `ERR`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorCode {
    /// A line from the PC had a wrong checksum.
    Checksum,
    /// A line from the PC could not be understood.
    Syntax,
    /// An angle outside the limit switches was asked for.
    Range,
    /// The PC speaks a protocol version the device does not.
    Version,
    /// Hardware fault (stepper stalled, limit switch never reached, sensor silent).
    Hardware,
}

impl ErrorCode {
    /// The code as the line carries it, e.g. `RANGE`.
    pub fn wire(self) -> &'static str {
        match self {
            ErrorCode::Checksum => "CHECKSUM",
            ErrorCode::Syntax => "SYNTAX",
            ErrorCode::Range => "RANGE",
            ErrorCode::Version => "VERSION",
            ErrorCode::Hardware => "HARDWARE",
        }
    }

    fn from_wire(s: &str) -> Result<Self, ParseError> {
        Ok(match s {
            "CHECKSUM" => ErrorCode::Checksum,
            "SYNTAX" => ErrorCode::Syntax,
            "RANGE" => ErrorCode::Range,
            "VERSION" => ErrorCode::Version,
            "HARDWARE" => ErrorCode::Hardware,
            _ => return Err(ParseError::BadField("error code")),
        })
    }
}

/// A command from the PC to the device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum HostCommand {
    /// Handshake: the protocol version the PC speaks.
    Hello { version: u32 },
    /// Sweep between the limit switches until stopped.
    FullScan,
    /// Sweep back and forth between two angles (centidegrees, `from < to`).
    LocalScan { from_cdeg: i32, to_cdeg: i32 },
    /// Stop after the current ping and hold the position.
    Stop,
    /// Ask for one `ST` line.
    Status,
    /// Clear a hardware fault (a person has looked at the head) and home again.
    Reset,
}

/// A message from the device to the PC.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DeviceMessage {
    /// Handshake reply with the device's identity and geometry, so the PC can check both. Version 2
    /// devices also send it by themselves after a reset.
    Hello {
        version: u32,
        firmware: String,
        /// Stays the same for the life of the head (empty in version 1, which has none).
        head_id: String,
        step_cdeg: u32,
        pings_per_reading: u32,
        min_cdeg: i32,
        max_cdeg: i32,
    },
    /// A command was accepted; carries the command's tag.
    Ack { command: String },
    /// The raw echo times of the pings of one beam position group, 0 µs meaning no echo.
    Reading(WireReading),
    /// A limit switch closed; the stepper reverses.
    LimitHit(Limit),
    /// A sweep (one pass in one direction) begins.
    SweepStart {
        sweep: u32,
        direction: Direction,
        mode: WireScanMode,
        from_cdeg: i32,
        to_cdeg: i32,
    },
    /// A sweep ends.
    SweepEnd { sweep: u32 },
    /// Reply to `STATUS`.
    Status {
        state: DeviceState,
        angle_cdeg: i32,
        direction: Direction,
        sweep: u32,
    },
    /// Something went wrong on the device.
    Error { code: ErrorCode, text: String },
}

/// One `RD` line: up to [`MAX_PINGS_PER_READING`] raw echo times around a centre angle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WireReading {
    /// The device's own reading counter (wraps at `u32::MAX`).
    pub seq: u32,
    /// The device's millisecond clock when the last ping of the group ended.
    pub time_ms: u32,
    pub sweep: u32,
    pub direction: Direction,
    /// Centre of the ping angles, centidegrees.
    pub angle_cdeg: i32,
    pub ping_count: u8,
    /// Echo times in µs, in ping order; entries past `ping_count` are 0.
    pub echo_us: [u32; MAX_PINGS_PER_READING],
}

impl WireReading {
    /// The echo times actually carried.
    pub fn pings(&self) -> &[u32] {
        &self.echo_us[..usize::from(self.ping_count)]
    }
}

/// Why a line was rejected. Every variant is a counted, logged event in the driver, never a panic.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    #[error("line does not start with '$'")]
    NoStart,
    #[error("line has no '*' checksum separator")]
    NoChecksum,
    #[error("check mismatch: line says {declared:04X}, body gives {computed:04X}")]
    ChecksumMismatch { declared: u16, computed: u16 },
    #[error("line check is not {0} hex digits (another protocol version?)")]
    BadChecksumDigits(usize),
    #[error("line contains non-printable or non-ASCII bytes")]
    NotAscii,
    #[error("line longer than {MAX_LINE_LEN} bytes")]
    TooLong,
    #[error("unknown message tag {0:?}")]
    UnknownTag(String),
    #[error("wrong number of fields for {tag}: expected {expected}, got {got}")]
    FieldCount {
        tag: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("field {0} is malformed")]
    BadField(&'static str),
}

/// XOR of all bytes: the line check of version 1.
pub fn xor_checksum(body: &[u8]) -> u8 {
    body.iter().fold(0, |acc, b| acc ^ b)
}

/// CRC-16/CCITT-FALSE (polynomial 0x1021, initial 0xFFFF, no reflection, no final XOR): the line
/// check of version 2. Bitwise, as the firmware computes it: a table would cost 512 bytes of flash
/// for no gain at 115200 baud.
pub fn crc16_ccitt_false(bytes: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in bytes {
        crc ^= u16::from(b) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// Wraps a body into a complete line, `$BODY*HHHH\n` (`*HH` in version 1).
fn frame(body: &str, version: ProtocolVersion) -> String {
    let width = version.check_digits();
    format!(
        "${body}*{:0width$X}\n",
        version.check(body.as_bytes()),
        width = width
    )
}

/// Checks framing and line check, returns the body's fields.
fn unframe(line: &[u8], version: ProtocolVersion) -> Result<Vec<&str>, ParseError> {
    let line = trim_line_end(line);
    if line.len() > MAX_LINE_LEN {
        return Err(ParseError::TooLong);
    }
    let rest = line.strip_prefix(b"$").ok_or(ParseError::NoStart)?;
    let star = rest
        .iter()
        .rposition(|&b| b == b'*')
        .ok_or(ParseError::NoChecksum)?;
    let (body, tail) = (&rest[..star], &rest[star + 1..]);
    if !body.iter().all(|b| (0x20..0x7f).contains(b)) {
        return Err(ParseError::NotAscii);
    }
    let digits = version.check_digits();
    let declared = parse_hex(tail, digits).ok_or(ParseError::BadChecksumDigits(digits))?;
    let computed = version.check(body);
    if declared != computed {
        return Err(ParseError::ChecksumMismatch { declared, computed });
    }
    // Printable ASCII was checked above, so this cannot fail; map it anyway rather than unwrap.
    let body = std::str::from_utf8(body).map_err(|_| ParseError::NotAscii)?;
    Ok(body.split(',').collect())
}

fn trim_line_end(line: &[u8]) -> &[u8] {
    let mut end = line.len();
    while end > 0 && matches!(line[end - 1], b'\n' | b'\r') {
        end -= 1;
    }
    &line[..end]
}

fn parse_hex(digits: &[u8], count: usize) -> Option<u16> {
    if digits.len() != count || !digits.iter().all(u8::is_ascii_hexdigit) {
        return None;
    }
    let s = std::str::from_utf8(digits).ok()?;
    u16::from_str_radix(s, 16).ok()
}

/// A head identity given on a command line (`--head-id`), checked as [`is_valid_head_id`] does.
pub fn parse_head_id(s: &str) -> Result<String, String> {
    if is_valid_head_id(s) {
        Ok(s.to_owned())
    } else {
        Err(format!(
            "a head id is 1–{MAX_HEAD_ID_LEN} characters of 0-9 A-Z a-z - _, got {s:?}"
        ))
    }
}

/// A head identity: 1–[`MAX_HEAD_ID_LEN`] characters of `0-9 A-Z a-z - _`.
pub fn is_valid_head_id(id: &str) -> bool {
    (1..=MAX_HEAD_ID_LEN).contains(&id.len())
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
}

fn expect_fields(fields: &[&str], tag: &'static str, expected: usize) -> Result<(), ParseError> {
    if fields.len() == expected {
        Ok(())
    } else {
        Err(ParseError::FieldCount {
            tag,
            expected,
            got: fields.len(),
        })
    }
}

/// Parses a decimal integer field in its one spelling (`0`, `7`, `-15000`): no `+`, no leading
/// zeros, no `-0`, no spaces, no sign where the type has none, no overflow. With one spelling per
/// value a line that is taken reads back as itself (the fuzz target in `fuzz/` checks it): `RD,007`
/// is not a second way to write `RD,7`.
fn num<T: std::str::FromStr>(s: &str, what: &'static str) -> Result<T, ParseError> {
    let digits = s.strip_prefix('-').unwrap_or(s);
    let canonical = match digits.as_bytes() {
        [] => false,
        [b'0'] => digits.len() == s.len(),
        [b'0', ..] => false,
        d => d.iter().all(u8::is_ascii_digit),
    };
    if !canonical {
        return Err(ParseError::BadField(what));
    }
    s.parse().map_err(|_| ParseError::BadField(what))
}

/// Free text fields may not contain the separators of the frame.
fn sanitize_text(text: &str) -> String {
    text.chars()
        .map(|c| {
            if c.is_ascii_graphic() && !matches!(c, '$' | '*' | ',') || c == ' ' {
                c
            } else {
                '_'
            }
        })
        .take(80)
        .collect()
}

/// Encodes a PC command as a complete line.
pub fn encode_command(cmd: &HostCommand, version: ProtocolVersion) -> String {
    let body = match cmd {
        HostCommand::Hello { version } => format!("HELLO,{version}"),
        HostCommand::FullScan => "SCAN,FULL".to_owned(),
        HostCommand::LocalScan { from_cdeg, to_cdeg } => {
            format!("SCAN,LOCAL,{from_cdeg},{to_cdeg}")
        }
        HostCommand::Stop => "STOP".to_owned(),
        HostCommand::Status => "STATUS".to_owned(),
        HostCommand::Reset => "RESET".to_owned(),
    };
    frame(&body, version)
}

/// Parses a line sent by the PC (the device's side of the protocol).
pub fn parse_command(line: &[u8], version: ProtocolVersion) -> Result<HostCommand, ParseError> {
    let f = unframe(line, version)?;
    match f[0] {
        "HELLO" => {
            expect_fields(&f, "HELLO", 2)?;
            Ok(HostCommand::Hello {
                version: num(f[1], "version")?,
            })
        }
        "SCAN" => match f.get(1).copied() {
            Some("FULL") => {
                expect_fields(&f, "SCAN,FULL", 2)?;
                Ok(HostCommand::FullScan)
            }
            Some("LOCAL") => {
                expect_fields(&f, "SCAN,LOCAL", 4)?;
                let from_cdeg = num(f[2], "from angle")?;
                let to_cdeg = num(f[3], "to angle")?;
                if from_cdeg >= to_cdeg {
                    return Err(ParseError::BadField("local scan segment (from >= to)"));
                }
                Ok(HostCommand::LocalScan { from_cdeg, to_cdeg })
            }
            _ => Err(ParseError::BadField("scan kind")),
        },
        "STOP" => {
            expect_fields(&f, "STOP", 1)?;
            Ok(HostCommand::Stop)
        }
        "STATUS" => {
            expect_fields(&f, "STATUS", 1)?;
            Ok(HostCommand::Status)
        }
        "RESET" => {
            expect_fields(&f, "RESET", 1)?;
            Ok(HostCommand::Reset)
        }
        other => Err(ParseError::UnknownTag(sanitize_text(other))),
    }
}

/// Encodes a device message as a complete line. A version-1 `HELLO` leaves out the head identity.
pub fn encode_device(msg: &DeviceMessage, version: ProtocolVersion) -> String {
    let mut body = String::with_capacity(64);
    // Writing into a String cannot fail; the results are ignored for that reason only.
    match msg {
        DeviceMessage::Hello {
            version: announced,
            firmware,
            head_id,
            step_cdeg,
            pings_per_reading,
            min_cdeg,
            max_cdeg,
        } => {
            let _ = write!(body, "HELLO,{announced},{}", sanitize_text(firmware));
            if version >= ProtocolVersion::V2 {
                let _ = write!(body, ",{}", sanitize_text(head_id));
            }
            let _ = write!(
                body,
                ",{step_cdeg},{pings_per_reading},{min_cdeg},{max_cdeg}"
            );
        }
        DeviceMessage::Ack { command } => {
            let _ = write!(body, "ACK,{}", sanitize_text(command));
        }
        DeviceMessage::Reading(r) => {
            let _ = write!(
                body,
                "RD,{},{},{},{},{},{}",
                r.seq,
                r.time_ms,
                r.sweep,
                r.direction.wire(),
                r.angle_cdeg,
                r.ping_count
            );
            for echo in r.pings() {
                let _ = write!(body, ",{echo}");
            }
        }
        DeviceMessage::LimitHit(limit) => {
            body.push_str(match limit {
                Limit::Min => "LIM,MIN",
                Limit::Max => "LIM,MAX",
            });
        }
        DeviceMessage::SweepStart {
            sweep,
            direction,
            mode,
            from_cdeg,
            to_cdeg,
        } => {
            let _ = write!(
                body,
                "SWP,START,{sweep},{},{},{from_cdeg},{to_cdeg}",
                direction.wire(),
                mode.wire()
            );
        }
        DeviceMessage::SweepEnd { sweep } => {
            let _ = write!(body, "SWP,END,{sweep}");
        }
        DeviceMessage::Status {
            state,
            angle_cdeg,
            direction,
            sweep,
        } => {
            let state = match state {
                DeviceState::Idle => "IDLE",
                DeviceState::Full => "FULL",
                DeviceState::Local => "LOCAL",
                DeviceState::Homing => "HOMING",
                DeviceState::Fault => "FAULT",
            };
            let _ = write!(body, "ST,{state},{angle_cdeg},{},{sweep}", direction.wire());
        }
        DeviceMessage::Error { code, text } => {
            let _ = write!(body, "ERR,{},{}", code.wire(), sanitize_text(text));
        }
    }
    frame(&body, version)
}

/// Parses a line sent by the device (the PC's side of the protocol).
pub fn parse_device(line: &[u8], version: ProtocolVersion) -> Result<DeviceMessage, ParseError> {
    let f = unframe(line, version)?;
    match f[0] {
        "HELLO" => {
            // Version 2 inserts the head identity after the firmware name.
            let (head_id, geometry) = match version {
                ProtocolVersion::V1 => {
                    expect_fields(&f, "HELLO", 7)?;
                    (String::new(), &f[3..])
                }
                ProtocolVersion::V2 => {
                    expect_fields(&f, "HELLO", 8)?;
                    if !is_valid_head_id(f[3]) {
                        return Err(ParseError::BadField("head id"));
                    }
                    (f[3].to_owned(), &f[4..])
                }
            };
            Ok(DeviceMessage::Hello {
                version: num(f[1], "version")?,
                firmware: f[2].to_owned(),
                head_id,
                step_cdeg: num(geometry[0], "step angle")?,
                pings_per_reading: num(geometry[1], "pings per reading")?,
                min_cdeg: num(geometry[2], "min angle")?,
                max_cdeg: num(geometry[3], "max angle")?,
            })
        }
        "ACK" => {
            expect_fields(&f, "ACK", 2)?;
            Ok(DeviceMessage::Ack {
                command: f[1].to_owned(),
            })
        }
        "RD" => parse_reading(&f).map(DeviceMessage::Reading),
        "LIM" => {
            expect_fields(&f, "LIM", 2)?;
            match f[1] {
                "MIN" => Ok(DeviceMessage::LimitHit(Limit::Min)),
                "MAX" => Ok(DeviceMessage::LimitHit(Limit::Max)),
                _ => Err(ParseError::BadField("limit")),
            }
        }
        "SWP" => match f.get(1).copied() {
            Some("START") => {
                expect_fields(&f, "SWP,START", 7)?;
                Ok(DeviceMessage::SweepStart {
                    sweep: num(f[2], "sweep")?,
                    direction: Direction::from_wire(f[3])?,
                    mode: WireScanMode::from_wire(f[4])?,
                    from_cdeg: num(f[5], "from angle")?,
                    to_cdeg: num(f[6], "to angle")?,
                })
            }
            Some("END") => {
                expect_fields(&f, "SWP,END", 3)?;
                Ok(DeviceMessage::SweepEnd {
                    sweep: num(f[2], "sweep")?,
                })
            }
            _ => Err(ParseError::BadField("sweep event")),
        },
        "ST" => {
            expect_fields(&f, "ST", 5)?;
            let state = match f[1] {
                "IDLE" => DeviceState::Idle,
                "FULL" => DeviceState::Full,
                "LOCAL" => DeviceState::Local,
                "HOMING" => DeviceState::Homing,
                "FAULT" => DeviceState::Fault,
                _ => return Err(ParseError::BadField("state")),
            };
            Ok(DeviceMessage::Status {
                state,
                angle_cdeg: num(f[2], "angle")?,
                direction: Direction::from_wire(f[3])?,
                sweep: num(f[4], "sweep")?,
            })
        }
        "ERR" => {
            expect_fields(&f, "ERR", 3)?;
            Ok(DeviceMessage::Error {
                code: ErrorCode::from_wire(f[1])?,
                text: f[2].to_owned(),
            })
        }
        other => Err(ParseError::UnknownTag(sanitize_text(other))),
    }
}

fn parse_reading(f: &[&str]) -> Result<WireReading, ParseError> {
    const HEAD: usize = 7;
    if f.len() < HEAD {
        return Err(ParseError::FieldCount {
            tag: "RD",
            expected: HEAD,
            got: f.len(),
        });
    }
    let ping_count: u8 = num(f[6], "ping count")?;
    if ping_count == 0 || usize::from(ping_count) > MAX_PINGS_PER_READING {
        return Err(ParseError::BadField("ping count"));
    }
    expect_fields(f, "RD", HEAD + usize::from(ping_count))?;
    let mut echo_us = [0u32; MAX_PINGS_PER_READING];
    for (slot, field) in echo_us.iter_mut().zip(&f[HEAD..]) {
        *slot = num(field, "echo time")?;
    }
    Ok(WireReading {
        seq: num(f[1], "sequence")?,
        time_ms: num(f[2], "device time")?,
        sweep: num(f[3], "sweep")?,
        direction: Direction::from_wire(f[4])?,
        angle_cdeg: num(f[5], "angle")?,
        ping_count,
        echo_us,
    })
}

/// A reading of the hobby "Arduino radar" sketches: angle in degrees, distance in cm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HobbyReading {
    pub angle_deg: f32,
    /// Distance in cm; 0 means no echo (NewPing convention).
    pub distance_cm: f32,
}

/// Parses one line of the hobby radar dialect: `37,18` (also `37;18`, `37*18`), without terminator.
///
/// These sketches send no checksum, so plausibility is all we can check: both fields numeric and
/// finite, the angle within a turn, the distance not negative.
pub fn parse_hobby(line: &[u8]) -> Result<HobbyReading, ParseError> {
    let line = trim_line_end(line);
    if line.len() > MAX_LINE_LEN {
        return Err(ParseError::TooLong);
    }
    let text = std::str::from_utf8(line).map_err(|_| ParseError::NotAscii)?;
    let text = text.trim();
    let (angle, distance) = text
        .split_once([',', ';', '*'])
        .ok_or(ParseError::FieldCount {
            tag: "hobby",
            expected: 2,
            got: 1,
        })?;
    let angle_deg: f32 = angle
        .trim()
        .parse()
        .map_err(|_| ParseError::BadField("angle"))?;
    let distance_cm: f32 = distance
        .trim()
        .trim_end_matches('#')
        .parse()
        .map_err(|_| ParseError::BadField("distance"))?;
    if !angle_deg.is_finite() || !(-360.0..=360.0).contains(&angle_deg) {
        return Err(ParseError::BadField("angle"));
    }
    if !distance_cm.is_finite() || distance_cm < 0.0 {
        return Err(ParseError::BadField("distance"));
    }
    Ok(HobbyReading {
        angle_deg,
        distance_cm,
    })
}

/// Which bytes end a line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Terminators {
    /// Our protocol: `\n` (a preceding `\r` is tolerated).
    Newline,
    /// The hobby sketches: `\n`, `\r`, or `.`/`#` (HowToMechatronics ends each record with `.` and no
    /// newline, Techno-E-Solution with `#`), so decimal points are not supported in that dialect.
    Hobby,
}

/// Cuts a byte stream into lines of at most [`MAX_LINE_LEN`] bytes.
///
/// A line that grows past the limit is dropped whole (reported once as [`FramedLine::Overflow`]) and
/// framing resumes at the next terminator, so one lost newline costs one line, never the stream.
#[derive(Debug)]
pub struct LineFramer {
    buf: Vec<u8>,
    overflowed: bool,
    terminators: Terminators,
}

/// One item cut from the stream.
#[derive(Debug, PartialEq, Eq)]
pub enum FramedLine<'a> {
    Line(&'a [u8]),
    /// A line exceeded [`MAX_LINE_LEN`] and was discarded.
    Overflow,
}

impl LineFramer {
    pub fn new(terminators: Terminators) -> Self {
        Self {
            buf: Vec::with_capacity(MAX_LINE_LEN),
            overflowed: false,
            terminators,
        }
    }

    fn is_terminator(&self, b: u8) -> bool {
        match self.terminators {
            Terminators::Newline => b == b'\n',
            Terminators::Hobby => matches!(b, b'\n' | b'\r' | b'.' | b'#'),
        }
    }

    /// Feeds bytes; calls `on_line` for each complete line (without terminator) or overflow.
    pub fn push(&mut self, bytes: &[u8], mut on_line: impl FnMut(FramedLine<'_>)) {
        for &b in bytes {
            if self.is_terminator(b) {
                if self.overflowed {
                    self.overflowed = false;
                } else if !trim_line_end(&self.buf).is_empty() {
                    on_line(FramedLine::Line(trim_line_end(&self.buf)));
                }
                self.buf.clear();
            } else if self.overflowed {
                // Skip the rest of an overlong line.
            } else if self.buf.len() >= MAX_LINE_LEN {
                self.buf.clear();
                self.overflowed = true;
                on_line(FramedLine::Overflow);
            } else {
                self.buf.push(b);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn reading(pings: &[u32]) -> WireReading {
        let mut echo_us = [0; MAX_PINGS_PER_READING];
        echo_us[..pings.len()].copy_from_slice(pings);
        WireReading {
            seq: 7,
            time_ms: 123_456,
            sweep: 3,
            direction: Direction::Cw,
            angle_cdeg: -14_700,
            ping_count: pings.len() as u8,
            echo_us,
        }
    }

    const BOTH: [ProtocolVersion; 2] = [ProtocolVersion::V1, ProtocolVersion::V2];

    #[test]
    fn version_1_check_is_nmea_xor() {
        // Known NMEA sentence: $GPGLL,5057.970,N,00146.110,E,142451,A*27
        assert_eq!(xor_checksum(b"GPGLL,5057.970,N,00146.110,E,142451,A"), 0x27);
        assert_eq!(
            encode_command(&HostCommand::Stop, ProtocolVersion::V1),
            "$STOP*18\n"
        );
    }

    #[test]
    fn version_2_check_is_crc16_ccitt_false() {
        // The catalogued check value of CRC-16/CCITT-FALSE.
        assert_eq!(crc16_ccitt_false(b"123456789"), 0x29B1);
        assert_eq!(crc16_ccitt_false(b""), 0xFFFF);
        // The examples in docs/protocol.md (the firmware's host tests pin the same strings).
        let v2 = ProtocolVersion::V2;
        assert_eq!(encode_command(&HostCommand::Stop, v2), "$STOP*AF2E\n");
        assert_eq!(
            encode_command(&HostCommand::FullScan, v2),
            "$SCAN,FULL*36C7\n"
        );
        assert_eq!(
            encode_command(&HostCommand::Hello { version: 2 }, v2),
            "$HELLO,2*4975\n"
        );
        assert_eq!(encode_command(&HostCommand::Reset, v2), "$RESET*7DB2\n");
        assert_eq!(
            parse_command(b"$SCAN,FULL*36c7", v2),
            Ok(HostCommand::FullScan),
            "lower-case hex digits are accepted"
        );
    }

    #[test]
    fn versions_never_mix() {
        let v1 = encode_command(&HostCommand::FullScan, ProtocolVersion::V1);
        let v2 = encode_command(&HostCommand::FullScan, ProtocolVersion::V2);
        assert_eq!(
            parse_command(v1.as_bytes(), ProtocolVersion::V2),
            Err(ParseError::BadChecksumDigits(4))
        );
        assert_eq!(
            parse_command(v2.as_bytes(), ProtocolVersion::V1),
            Err(ParseError::BadChecksumDigits(2))
        );
    }

    #[test]
    fn every_command_round_trips() {
        for cmd in [
            HostCommand::Hello { version: 2 },
            HostCommand::FullScan,
            HostCommand::LocalScan {
                from_cdeg: -3000,
                to_cdeg: 4500,
            },
            HostCommand::Stop,
            HostCommand::Status,
            HostCommand::Reset,
        ] {
            for v in BOTH {
                let line = encode_command(&cmd, v);
                assert!(line.ends_with('\n'));
                assert_eq!(parse_command(line.as_bytes(), v), Ok(cmd.clone()));
            }
        }
    }

    #[test]
    fn hello_carries_the_head_id_in_version_2_only() {
        let hello = |head_id: &str| DeviceMessage::Hello {
            version: 2,
            firmware: "sonar-head 0.2.0".into(),
            head_id: head_id.into(),
            step_cdeg: 150,
            pings_per_reading: 4,
            min_cdeg: -15000,
            max_cdeg: 15000,
        };
        let line = encode_device(&hello("3F2A9C0417B6E5D1"), ProtocolVersion::V2);
        assert!(
            line.starts_with("$HELLO,2,sonar-head 0.2.0,3F2A9C0417B6E5D1,150,4,-15000,15000*"),
            "{line}"
        );
        let v1 = encode_device(&hello("3F2A9C0417B6E5D1"), ProtocolVersion::V1);
        assert_eq!(
            parse_device(v1.as_bytes(), ProtocolVersion::V1),
            Ok(hello("")),
            "{v1}"
        );
        for bad in ["", "has space", "a,b", &"X".repeat(MAX_HEAD_ID_LEN + 1)] {
            let body = format!("HELLO,2,fw,{bad},150,4,-15000,15000");
            assert!(
                parse_device(
                    frame(&body, ProtocolVersion::V2).as_bytes(),
                    ProtocolVersion::V2
                )
                .is_err(),
                "{body}"
            );
        }
    }

    #[test]
    fn every_device_message_round_trips() {
        for msg in [
            DeviceMessage::Hello {
                version: 2,
                firmware: "sonar-sim 0.1.0".into(),
                head_id: "sim-1_A".into(),
                step_cdeg: 150,
                pings_per_reading: 4,
                min_cdeg: -15000,
                max_cdeg: 15000,
            },
            DeviceMessage::Ack {
                command: "SCAN".into(),
            },
            DeviceMessage::Reading(reading(&[5800, 5830, 0, 5790])),
            DeviceMessage::LimitHit(Limit::Min),
            DeviceMessage::LimitHit(Limit::Max),
            DeviceMessage::SweepStart {
                sweep: 2,
                direction: Direction::Ccw,
                mode: WireScanMode::Local,
                from_cdeg: -3000,
                to_cdeg: 3000,
            },
            DeviceMessage::SweepEnd { sweep: 2 },
            DeviceMessage::Status {
                state: DeviceState::Full,
                angle_cdeg: 4425,
                direction: Direction::Cw,
                sweep: 9,
            },
            DeviceMessage::Status {
                state: DeviceState::Homing,
                angle_cdeg: 0,
                direction: Direction::Cw,
                sweep: 0,
            },
            DeviceMessage::Status {
                state: DeviceState::Fault,
                angle_cdeg: -15000,
                direction: Direction::Cw,
                sweep: 3,
            },
            DeviceMessage::Error {
                code: ErrorCode::Range,
                text: "angle outside limits".into(),
            },
        ] {
            let line = encode_device(&msg, ProtocolVersion::V2);
            assert_eq!(
                parse_device(line.as_bytes(), ProtocolVersion::V2),
                Ok(msg),
                "{line}"
            );
        }
    }

    #[test]
    fn reading_line_has_documented_shape() {
        let msg = DeviceMessage::Reading(reading(&[5800, 5830, 0, 5790]));
        let body = "RD,7,123456,3,-,-14700,4,5800,5830,0,5790";
        assert_eq!(
            encode_device(&msg, ProtocolVersion::V2),
            format!("${body}*{:04X}\n", crc16_ccitt_false(body.as_bytes()))
        );
        assert!(encode_device(&msg, ProtocolVersion::V1).starts_with(&format!("${body}*")));
    }

    #[test]
    fn rejects_bad_checksum_and_framing() {
        for v in BOTH {
            let good = encode_command(&HostCommand::FullScan, v);
            let bad = good.replace("FULL", "FULM");
            assert!(matches!(
                parse_command(bad.as_bytes(), v),
                Err(ParseError::ChecksumMismatch { .. })
            ));
            assert_eq!(
                parse_command(b"SCAN,FULL*0000", v),
                Err(ParseError::NoStart)
            );
            assert_eq!(parse_command(b"$SCAN,FULL", v), Err(ParseError::NoChecksum));
            assert_eq!(
                parse_command(b"$SCAN,FULL*G1", v),
                Err(ParseError::BadChecksumDigits(v.check_digits()))
            );
            assert_eq!(parse_device(b"$\xff*FFFF", v), Err(ParseError::NotAscii));
            assert_eq!(parse_device(&[b'$'; 400], v), Err(ParseError::TooLong));
        }
        // "+1F" parses as a number in Rust; it is not four hex digits.
        assert_eq!(
            parse_command(b"$STOP*+F2E", ProtocolVersion::V2),
            Err(ParseError::BadChecksumDigits(4))
        );
    }

    /// The failure that made version 2: two bits flipped in the same position of two bytes leave
    /// the XOR unchanged. The CRC sees every such pair in every reading line.
    #[test]
    fn same_column_double_flips_pass_xor_but_never_the_crc() {
        let msg = DeviceMessage::Reading(reading(&[18195, 18210, 18190, 18201]));
        let mut slipped_past_xor = 0;
        for v in BOTH {
            let line = encode_device(&msg, v).into_bytes();
            let star = line.iter().rposition(|&b| b == b'*').unwrap_or(0);
            for i in 1..star {
                for j in i + 1..star {
                    for bit in 0..7 {
                        let mut bad = line.clone();
                        bad[i] ^= 1 << bit;
                        bad[j] ^= 1 << bit;
                        if let Ok(DeviceMessage::Reading(r)) = parse_device(&bad, v)
                            && DeviceMessage::Reading(r) != msg
                        {
                            assert_eq!(v, ProtocolVersion::V1, "the CRC let a corrupt line pass");
                            slipped_past_xor += 1;
                        }
                    }
                }
            }
        }
        assert!(slipped_past_xor > 100, "{slipped_past_xor}");
    }

    #[test]
    fn rejects_wrong_fields_even_with_good_checksum() {
        for body in [
            "RD,1,2,3,+,100,5,1,2,3,4",
            "RD,1,2,3,+,100,0",
            "RD,1,2,3,x,100,1,5",
            "RD,1,2,3,+,100,1,-5",
            "WHAT,1",
        ] {
            for v in BOTH {
                assert!(
                    parse_device(frame(body, v).as_bytes(), v).is_err(),
                    "{body}"
                );
            }
        }
        let v2 = ProtocolVersion::V2;
        assert!(parse_command(frame("SCAN,LOCAL,300,100", v2).as_bytes(), v2).is_err());
    }

    /// Found by the fuzz target: `-07050` and `000` were taken for `-7050` and `0`, so a line
    /// could be spelt two ways (and in version 1 the XOR of `00` is 0: `$SCAN,LOCAL,000,3000*4D`
    /// carries the same check as `$SCAN,LOCAL,0,3000`).
    #[test]
    fn numbers_have_one_spelling() {
        for v in BOTH {
            for bad in [
                "007", "-07050", "-0", "00", "+7", " 7", "7 ", "", "-", "0x10", "1_0",
            ] {
                let body = format!("RD,{bad},2,3,+,100,1,5");
                assert_eq!(
                    parse_device(frame(&body, v).as_bytes(), v),
                    Err(ParseError::BadField("sequence")),
                    "{body}"
                );
                let body = format!("SCAN,LOCAL,{bad},30000");
                assert!(
                    parse_command(frame(&body, v).as_bytes(), v).is_err(),
                    "{body}"
                );
            }
            for (good, value) in [
                ("0", 0),
                ("7", 7),
                ("-15000", -15000),
                ("-2147483648", i32::MIN),
            ] {
                let body = format!("SCAN,LOCAL,{good},2147483647");
                assert_eq!(
                    parse_command(frame(&body, v).as_bytes(), v),
                    Ok(HostCommand::LocalScan {
                        from_cdeg: value,
                        to_cdeg: i32::MAX
                    }),
                    "{body}"
                );
            }
        }
        assert!(parse_command(b"$SCAN,LOCAL,000,3000*4D", ProtocolVersion::V1).is_err());
    }

    #[test]
    fn hobby_dialect_variants() {
        let expect = HobbyReading {
            angle_deg: 37.0,
            distance_cm: 18.0,
        };
        for line in ["37,18", "37;18", "37*18#", " 37 , 18 \r"] {
            assert_eq!(parse_hobby(line.as_bytes()), Ok(expect), "{line:?}");
        }
        assert!(parse_hobby(b"37").is_err());
        assert!(parse_hobby(b"37,-1").is_err());
        assert!(parse_hobby(b"abc,1").is_err());
        assert!(parse_hobby(b"37,NaN").is_err());
    }

    #[test]
    fn framer_splits_lines_and_drops_overlong_ones() {
        let mut framer = LineFramer::new(Terminators::Newline);
        let mut out = Vec::new();
        let mut collect = |l: FramedLine<'_>| {
            out.push(match l {
                FramedLine::Line(l) => String::from_utf8_lossy(l).into_owned(),
                FramedLine::Overflow => "<overflow>".into(),
            })
        };
        framer.push(b"$A*41\r\n$B", &mut collect);
        framer.push(b"*42\n", &mut collect);
        framer.push(&[b'x'; MAX_LINE_LEN + 10], &mut collect);
        framer.push(b"\n$C*43\n", &mut collect);
        assert_eq!(out, ["$A*41", "$B*42", "<overflow>", "$C*43"]);
    }

    #[test]
    fn hobby_framer_splits_on_dots() {
        let mut framer = LineFramer::new(Terminators::Hobby);
        let mut out = Vec::new();
        framer.push(b"15,20.16,21.17,22\n", |l| {
            if let FramedLine::Line(l) = l {
                out.push(parse_hobby(l).map(|r| r.angle_deg));
            }
        });
        assert_eq!(out, [Ok(15.0), Ok(16.0), Ok(17.0)]);
    }

    fn arb_reading() -> impl Strategy<Value = WireReading> {
        (
            any::<u32>(),
            any::<u32>(),
            any::<u32>(),
            any::<bool>(),
            any::<i32>(),
            prop::collection::vec(any::<u32>(), 1..=MAX_PINGS_PER_READING),
        )
            .prop_map(|(seq, time_ms, sweep, ccw, angle_cdeg, pings)| {
                let mut r = reading(&pings);
                r.seq = seq;
                r.time_ms = time_ms;
                r.sweep = sweep;
                r.direction = if ccw { Direction::Ccw } else { Direction::Cw };
                r.angle_cdeg = angle_cdeg;
                r
            })
    }

    proptest! {
        #[test]
        fn reading_round_trips(r in arb_reading()) {
            for v in BOTH {
                let line = encode_device(&DeviceMessage::Reading(r), v);
                prop_assert!(line.len() <= MAX_LINE_LEN);
                prop_assert_eq!(parse_device(line.as_bytes(), v), Ok(DeviceMessage::Reading(r)));
            }
        }

        #[test]
        fn local_scan_round_trips(a in -36000i32..36000, len in 1i32..36000) {
            let cmd = HostCommand::LocalScan { from_cdeg: a, to_cdeg: a + len };
            for v in BOTH {
                prop_assert_eq!(parse_command(encode_command(&cmd, v).as_bytes(), v), Ok(cmd.clone()));
            }
        }

        #[test]
        fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
            for v in BOTH {
                let _ = parse_device(&bytes, v);
                let _ = parse_command(&bytes, v);
            }
            let _ = parse_hobby(&bytes);
            let mut framer = LineFramer::new(Terminators::Hobby);
            framer.push(&bytes, |_| {});
        }

        /// Whatever bytes arrive, nothing is accepted unless its checksum matches its body.
        #[test]
        fn nothing_accepted_without_matching_checksum(
            bytes in prop::collection::vec(any::<u8>(), 0..200),
        ) {
            for v in BOTH {
                if parse_device(&bytes, v).is_ok() {
                    let line = trim_line_end(&bytes);
                    let star = line.iter().rposition(|&b| b == b'*').unwrap();
                    let declared = parse_hex(&line[star + 1..], v.check_digits()).unwrap();
                    prop_assert_eq!(declared, v.check(&line[1..star]));
                }
            }
        }

        /// Corrupting one byte of a valid reading line is always detected or harmless.
        #[test]
        fn single_byte_corruption_never_yields_a_different_reading(
            r in arb_reading(), pos in any::<prop::sample::Index>(), flip in 1u8..=255,
        ) {
            for v in BOTH {
                let mut line = encode_device(&DeviceMessage::Reading(r), v).into_bytes();
                let i = pos.index(line.len());
                line[i] ^= flip;
                if let Ok(DeviceMessage::Reading(parsed)) = parse_device(&line, v) {
                    prop_assert_eq!(parsed, r);
                }
            }
        }

        /// Version 2: any two flipped bits anywhere in a reading line are detected or harmless.
        #[test]
        fn any_two_bit_flips_never_yield_a_different_reading(
            r in arb_reading(),
            a in any::<prop::sample::Index>(), b in any::<prop::sample::Index>(),
            bit_a in 0u8..8, bit_b in 0u8..8,
        ) {
            let v = ProtocolVersion::V2;
            let mut line = encode_device(&DeviceMessage::Reading(r), v).into_bytes();
            let n = line.len() - 1; // keep the terminator: the framer cuts lines there
            line[a.index(n)] ^= 1 << bit_a;
            line[b.index(n)] ^= 1 << bit_b;
            if let Ok(DeviceMessage::Reading(parsed)) = parse_device(&line, v) {
                prop_assert_eq!(parsed, r);
            }
        }
    }
}
