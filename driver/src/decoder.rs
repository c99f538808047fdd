//! From lines off the serial port to [`Reading`]s, for both dialects. Pure: no I/O, no clock.

use sonar_common::ipc::{LAYOUT_VERSION, MAX_PINGS, Reading, ScanMode, flags};
use sonar_common::protocol::{
    self, DeviceMessage, DeviceState, HobbyReading, PROTOCOL_VERSION, ParseError, ProtocolVersion,
    WireReading, WireScanMode,
};
use sonar_common::sensor::SensorConfig;

use crate::averaging::{Combined, PingPolicy, combine_pings};

/// Which serial format the device speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Dialect {
    /// Our protocol (docs/protocol.md): checksummed lines, handshake, commands, raw pings.
    Native,
    /// The hobby "Arduino radar" sketches: `angle,distance_cm` ended by `.`, `#` or a newline, no
    /// checksum, no commands, one ping per angle.
    Hobby,
}

impl Dialect {
    pub fn terminators(self) -> protocol::Terminators {
        match self {
            Dialect::Native => protocol::Terminators::Newline,
            Dialect::Hobby => protocol::Terminators::Hobby,
        }
    }
}

/// What a line meant.
#[derive(Debug, Clone, PartialEq)]
pub enum Decoded {
    Reading(Reading),
    /// Any other device message (handshake, acks, limits, sweep boundaries, status, errors).
    Message(DeviceMessage),
}

/// Turns lines into readings, keeping the little state a reading needs: its sequence number, the
/// current scan mode (from sweep starts), and for the hobby dialect the sweep and direction, which
/// those sketches never send and are inferred from the angle sequence.
#[derive(Debug)]
pub struct Decoder {
    dialect: Dialect,
    /// Version of the native protocol (the hobby dialect has none).
    version: ProtocolVersion,
    sensor: SensorConfig,
    policy: PingPolicy,
    next_seq: u64,
    mode: ScanMode,
    /// Added to hobby angles: the sketches' servo points forward at 90°.
    hobby_angle_offset_deg: f32,
    hobby: HobbySweep,
}

/// The raw side of a reading, whichever dialect it came in.
struct PingGroup {
    angle_deg: f32,
    direction: i8,
    sweep_id: u32,
    device_seq: u32,
    device_time_ms: u32,
    echo_us: [u32; MAX_PINGS],
    ping_count: u8,
}

#[derive(Debug, Default)]
struct HobbySweep {
    last_angle_deg: Option<f32>,
    direction: i8,
    sweep_id: u32,
    device_seq: u32,
}

impl Decoder {
    pub fn new(
        dialect: Dialect,
        sensor: SensorConfig,
        policy: PingPolicy,
        hobby_angle_offset_deg: f32,
    ) -> Self {
        Self {
            dialect,
            version: PROTOCOL_VERSION,
            sensor,
            policy,
            next_seq: 0,
            mode: ScanMode::Unknown,
            hobby_angle_offset_deg,
            hobby: HobbySweep::default(),
        }
    }

    /// Reads the native protocol in `version` instead of the newest.
    pub fn speaking(mut self, version: ProtocolVersion) -> Self {
        self.version = version;
        self
    }

    pub fn version(&self) -> ProtocolVersion {
        self.version
    }

    pub fn sensor(&self) -> &SensorConfig {
        &self.sensor
    }

    /// Adopts the geometry the device announced in its `HELLO` (the device is the authority on its
    /// own stepper and limit switches).
    pub fn adopt_device_geometry(&mut self, hello: &DeviceMessage) {
        if let DeviceMessage::Hello {
            step_cdeg,
            pings_per_reading,
            min_cdeg,
            max_cdeg,
            ..
        } = *hello
        {
            self.sensor.step_deg = step_cdeg as f32 / 100.0;
            self.sensor.pings_per_reading = u8::try_from(pings_per_reading).unwrap_or(u8::MAX);
            self.sensor.sweep_min_deg = min_cdeg as f32 / 100.0;
            self.sensor.sweep_max_deg = max_cdeg as f32 / 100.0;
        }
    }

    /// Number of readings published so far (the next sequence number).
    pub fn readings_decoded(&self) -> u64 {
        self.next_seq
    }

    /// Gives back the sequence number of the reading just decoded, which was not published (it
    /// came from a head not identified yet), so the published numbers stay without gaps.
    pub fn withdraw_last(&mut self) {
        self.next_seq = self.next_seq.saturating_sub(1);
    }

    /// Decodes one line (without terminator). `now_ns` stamps a reading.
    pub fn decode(&mut self, line: &[u8], now_ns: u64) -> Result<Decoded, ParseError> {
        match self.dialect {
            Dialect::Native => {
                let msg = protocol::parse_device(line, self.version)?;
                match msg {
                    DeviceMessage::Reading(wire) => {
                        Ok(Decoded::Reading(self.native(&wire, now_ns)))
                    }
                    other => {
                        self.track_mode(&other);
                        Ok(Decoded::Message(other))
                    }
                }
            }
            Dialect::Hobby => {
                let hobby = protocol::parse_hobby(line)?;
                Ok(Decoded::Reading(self.hobby(hobby, now_ns)))
            }
        }
    }

    fn track_mode(&mut self, msg: &DeviceMessage) {
        match msg {
            DeviceMessage::SweepStart { mode, .. } => {
                self.mode = match mode {
                    WireScanMode::Full => ScanMode::Full,
                    WireScanMode::Local => ScanMode::Local,
                };
            }
            DeviceMessage::Status { state, .. } => {
                self.mode = match state {
                    DeviceState::Idle | DeviceState::Homing | DeviceState::Fault => ScanMode::Idle,
                    DeviceState::Full => ScanMode::Full,
                    DeviceState::Local => ScanMode::Local,
                };
            }
            _ => {}
        }
    }

    fn native(&mut self, wire: &WireReading, now_ns: u64) -> Reading {
        let combined = combine_pings(wire.pings(), &self.sensor, &self.policy);
        let mut echo_us = [0u32; MAX_PINGS];
        echo_us[..wire.pings().len()].copy_from_slice(wire.pings());
        let group = PingGroup {
            angle_deg: wire.angle_cdeg as f32 / 100.0,
            direction: wire.direction.sign() as i8,
            sweep_id: wire.sweep,
            device_seq: wire.seq,
            device_time_ms: wire.time_ms,
            echo_us,
            ping_count: wire.ping_count,
        };
        self.reading(&group, combined, now_ns)
    }

    fn hobby(&mut self, hobby: HobbyReading, now_ns: u64) -> Reading {
        let angle_deg = hobby.angle_deg + self.hobby_angle_offset_deg;
        let h = &mut self.hobby;
        if let Some(last) = h.last_angle_deg {
            let direction = if angle_deg > last {
                1
            } else if angle_deg < last {
                -1
            } else {
                h.direction
            };
            // A reversal starts a new sweep, as a limit does in our protocol.
            if direction != h.direction && h.direction != 0 {
                h.sweep_id += 1;
            }
            h.direction = direction;
        }
        h.last_angle_deg = Some(angle_deg);
        h.device_seq = h.device_seq.wrapping_add(1);
        let (direction, sweep, device_seq) = (h.direction, h.sweep_id, h.device_seq);

        // NewPing sketches report 0 for no echo; the range goes through the same policy as a native
        // ping (a synthesised echo time) so range limits apply identically.
        let distance_m = hobby.distance_cm / 100.0;
        let echo = if distance_m > 0.0 {
            self.sensor.echo_time_us(distance_m).round() as u32
        } else {
            0
        };
        let mut echo_us = [0u32; MAX_PINGS];
        echo_us[0] = echo;
        let single = PingPolicy {
            min_agreeing_pings: 1,
            ..self.policy
        };
        let mut combined = combine_pings(&echo_us[..1], &self.sensor, &single);
        combined.flags |= flags::NO_RAW_PINGS;
        let group = PingGroup {
            angle_deg,
            direction,
            sweep_id: sweep,
            device_seq,
            device_time_ms: 0,
            echo_us,
            ping_count: 1,
        };
        self.reading(&group, combined, now_ns)
    }

    fn reading(&mut self, group: &PingGroup, combined: Combined, now_ns: u64) -> Reading {
        let seq = self.next_seq;
        self.next_seq += 1;
        Reading {
            seq,
            host_stamp_ns: now_ns,
            layout_version: LAYOUT_VERSION,
            device_seq: group.device_seq,
            device_time_ms: group.device_time_ms,
            sweep_id: group.sweep_id,
            flags: combined.flags,
            angle_deg: group.angle_deg,
            beam_half_angle_deg: self.sensor.beam_half_angle_deg,
            tof_us: combined.tof_us,
            distance_m: combined.distance_m,
            speed_of_sound_mps: self.sensor.speed_of_sound_mps(),
            min_range_m: self.sensor.min_range_m,
            max_range_m: self.sensor.max_range_m,
            echo_us: group.echo_us,
            direction: group.direction,
            mode: self.mode as u8,
            ping_count: group.ping_count,
            pings_used: combined.pings_used,
            reserved: [0; 4],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_common::protocol::{DeviceMessage, Direction, WireReading, encode_device};

    fn native() -> Decoder {
        Decoder::new(
            Dialect::Native,
            SensorConfig::default(),
            PingPolicy::default(),
            -90.0,
        )
    }

    #[test]
    fn native_reading_becomes_a_distance_with_raw_pings_kept() {
        let mut d = native();
        let start = DeviceMessage::SweepStart {
            sweep: 4,
            direction: Direction::Ccw,
            mode: WireScanMode::Full,
            from_cdeg: -14700,
            to_cdeg: 14700,
        };
        d.decode(
            encode_device(&start, PROTOCOL_VERSION)
                .trim_end()
                .as_bytes(),
            0,
        )
        .unwrap();
        let t = SensorConfig::default().echo_time_us(1.2).round() as u32;
        let wire = WireReading {
            seq: 10,
            time_ms: 99,
            sweep: 4,
            direction: Direction::Ccw,
            angle_cdeg: -14100,
            ping_count: 4,
            echo_us: [t, t, t, 0, 0, 0, 0, 0],
        };
        let line = encode_device(&DeviceMessage::Reading(wire), PROTOCOL_VERSION);
        let Decoded::Reading(r) = d.decode(line.trim_end().as_bytes(), 42).unwrap() else {
            panic!("not a reading");
        };
        assert_eq!(
            (r.seq, r.device_seq, r.sweep_id, r.direction),
            (0, 10, 4, 1)
        );
        assert_eq!(r.angle_deg, -141.0);
        assert_eq!(r.scan_mode(), ScanMode::Full);
        assert_eq!(r.echo_us[..4], [t, t, t, 0]);
        assert_eq!(r.flags, flags::PINGS_REJECTED);
        assert!((r.distance_m - 1.2).abs() < 1e-3);
        assert_eq!(r.host_stamp_ns, 42);
        assert_eq!(d.readings_decoded(), 1);
    }

    #[test]
    fn corrupt_native_line_is_an_error_and_consumes_no_sequence_number() {
        let mut d = native();
        assert!(d.decode(b"$RD,1,2,3,+,100,1,5800*0000", 0).is_err());
        assert_eq!(d.readings_decoded(), 0);
    }

    #[test]
    fn hobby_angles_are_shifted_and_reversals_start_sweeps() {
        let mut d = Decoder::new(
            Dialect::Hobby,
            SensorConfig::default(),
            PingPolicy::default(),
            -90.0,
        );
        let mut sweeps = Vec::new();
        for line in ["88,100", "89,100", "90,0", "89,100", "88,500"] {
            let Decoded::Reading(r) = d.decode(line.as_bytes(), 0).unwrap() else {
                panic!()
            };
            sweeps.push((r.angle_deg, r.sweep_id, r.direction, r.flags));
        }
        let valid = flags::NO_RAW_PINGS;
        assert_eq!(sweeps[0], (-2.0, 0, 0, valid));
        assert_eq!(sweeps[1], (-1.0, 0, 1, valid));
        assert_eq!(sweeps[2], (0.0, 0, 1, valid | flags::NO_ECHO));
        assert_eq!(sweeps[3], (-1.0, 1, -1, valid));
        assert_eq!(sweeps[4].3, valid | flags::OUT_OF_RANGE);
    }
}
