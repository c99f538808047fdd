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

/// Which hobby distance means "no echo". A distance of 0 never is an echo and always means none;
/// sketches differ in what else they send when nothing came back: NewPing's `0`, many others `255`
/// (the largest byte), or a sentinel at or beyond the sensor's range (`400`, `999`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum NoEcho {
    /// Only 0 cm (NewPing's convention).
    #[default]
    Zero,
    /// This many cm exactly (e.g. 255), besides 0.
    Exactly(f32),
    /// This many cm or more, besides 0.
    AtOrBeyond(f32),
}

impl NoEcho {
    /// The same setting for distances given in a unit of `cm_per_unit` centimetres, in cm.
    pub fn in_cm(self, cm_per_unit: f32) -> Self {
        match self {
            NoEcho::Zero => NoEcho::Zero,
            NoEcho::Exactly(v) => NoEcho::Exactly(v * cm_per_unit),
            NoEcho::AtOrBeyond(v) => NoEcho::AtOrBeyond(v * cm_per_unit),
        }
    }

    /// True when a hobby distance (cm) means that nothing echoed.
    pub fn means_none(self, distance_cm: f32) -> bool {
        distance_cm <= 0.0
            || match self {
                NoEcho::Zero => false,
                NoEcho::Exactly(cm) => distance_cm == cm,
                NoEcho::AtOrBeyond(cm) => distance_cm >= cm,
            }
    }
}

impl std::str::FromStr for NoEcho {
    type Err = String;

    /// `0`, a value in cm (`255`), or a value and more (`400+` or `>=400`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim();
        let (number, beyond) = match s.strip_suffix('+').or_else(|| s.strip_prefix(">=")) {
            Some(n) => (n.trim(), true),
            None => (s, false),
        };
        let cm: f32 = number.parse().map_err(|_| {
            format!("expected 0, a distance in cm (255) or one and beyond (400+), got {s:?}")
        })?;
        if !(cm.is_finite() && cm >= 0.0) {
            return Err(format!(
                "the no-echo value must be a distance >= 0 cm, got {s:?}"
            ));
        }
        Ok(match (cm, beyond) {
            (0.0, _) => NoEcho::Zero,
            (cm, false) => NoEcho::Exactly(cm),
            (cm, true) => NoEcho::AtOrBeyond(cm),
        })
    }
}

/// The largest step between consecutive readings of a head: a jump of more than half a turn that
/// is at most this far the short way round is a continuous head's wrap; any other jump beyond it
/// is a servo flying back to its start (165° → 15°).
const MAX_WRAP_STEP_DEG: f32 = 45.0;

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
    /// The hobby distance that means no echo.
    hobby_no_echo: NoEcho,
    hobby: HobbySweep,
    /// Play of the head's gears, degrees ([`Self::backlash_deg`]).
    backlash_deg: f32,
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
            hobby_no_echo: NoEcho::default(),
            backlash_deg: 0.0,
            hobby: HobbySweep::default(),
        }
    }

    /// Takes out the play of the head's gears, `deg` degrees: the head sets its angle at the switch
    /// it starts a sweep from, and on the way out the motor turns the play before the shaft
    /// follows, so the angle it reports runs ahead of the shaft by the play in the direction it
    /// turns. Each reading is moved back by `deg` against its direction (none when the direction
    /// is unknown).
    pub fn backlash_deg(mut self, deg: f32) -> Self {
        self.backlash_deg = deg;
        self
    }

    /// Reads hobby distances that `no_echo` names as "nothing echoed" (0 cm always is).
    pub fn hobby_no_echo(mut self, no_echo: NoEcho) -> Self {
        self.hobby_no_echo = no_echo;
        self
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
                Ok(Decoded::Reading(self.hobby_reading(hobby, now_ns)))
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

    /// One angle and distance as the hobby dialect reads them (a line of the sketch, or a row of
    /// a log brought in by `sonar-import`), stamped `now_ns`: sweep and direction from the angle
    /// sequence, the no-echo value, one synthesised ping through the same policy as the head's.
    pub fn hobby_reading(&mut self, hobby: HobbyReading, now_ns: u64) -> Reading {
        let angle_deg = hobby.angle_deg + self.hobby_angle_offset_deg;
        let h = &mut self.hobby;
        if let Some(last) = h.last_angle_deg {
            let change = angle_deg - last;
            // The turn the angle took, the short way round: a continuous head that wraps
            // (357° → 0°, 180° → −177°, −357° → 0°) goes on in its direction.
            let turned = change - 360.0 * (change / 360.0).round();
            let wrapped = change.abs() > 180.0 && turned.abs() <= MAX_WRAP_STEP_DEG;
            // A servo that flies back from its end to its start (165° → 15°) and sweeps on in
            // the same direction.
            let flew_back = !wrapped && change.abs() > MAX_WRAP_STEP_DEG;
            let direction = if wrapped {
                turned.signum() as i8
            } else if flew_back {
                h.direction
            } else if change > 0.0 {
                1
            } else if change < 0.0 {
                -1
            } else {
                h.direction
            };
            // A reversal starts a new sweep, as a limit does in our protocol; so do a wrap (one
            // revolution of a continuous head is one sweep) and a fly-back.
            if wrapped || flew_back || (direction != h.direction && h.direction != 0) {
                h.sweep_id += 1;
            }
            h.direction = direction;
        }
        h.last_angle_deg = Some(angle_deg);
        h.device_seq = h.device_seq.wrapping_add(1);
        let (direction, sweep, device_seq) = (h.direction, h.sweep_id, h.device_seq);

        // A distance the sketch sends for "no echo" becomes no echo time; any other goes through
        // the same policy as a native ping (a synthesised echo time) so range limits apply alike.
        let echo = if self.hobby_no_echo.means_none(hobby.distance_cm) {
            0
        } else {
            self.sensor.echo_time_us(hobby.distance_cm / 100.0).round() as u32
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
            angle_deg: group.angle_deg - f32::from(group.direction) * self.backlash_deg,
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

    /// The angle of a native reading at 30° in a sweep turning `direction`, decoded by `d`.
    fn angle_turning(mut d: Decoder, direction: Direction) -> f32 {
        let start = DeviceMessage::SweepStart {
            sweep: 1,
            direction,
            mode: WireScanMode::Full,
            from_cdeg: -14700,
            to_cdeg: 14700,
        };
        let line = encode_device(&start, PROTOCOL_VERSION);
        d.decode(line.trim_end().as_bytes(), 0).unwrap();
        let wire = WireReading {
            seq: 1,
            time_ms: 1,
            sweep: 1,
            direction,
            angle_cdeg: 3000,
            ping_count: 4,
            echo_us: [3000, 3000, 3000, 3000, 0, 0, 0, 0],
        };
        let line = encode_device(&DeviceMessage::Reading(wire), PROTOCOL_VERSION);
        let Decoded::Reading(r) = d.decode(line.trim_end().as_bytes(), 1).unwrap() else {
            panic!("not a reading");
        };
        r.angle_deg
    }

    #[test]
    fn the_gears_play_is_taken_out_against_the_direction_of_turning() {
        // Without backlash the reported angle stands.
        assert_eq!(angle_turning(native(), Direction::Ccw), 30.0);
        // With 2° of play the motor runs 2° ahead of the shaft whichever way it turns.
        assert_eq!(
            angle_turning(native().backlash_deg(2.0), Direction::Ccw),
            28.0
        );
        assert_eq!(
            angle_turning(native().backlash_deg(2.0), Direction::Cw),
            32.0
        );
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

    /// (sweep, direction) of each hobby angle in turn.
    fn sweeps_of(angles: impl IntoIterator<Item = f32>) -> Vec<(u32, i8)> {
        let mut d = hobby(NoEcho::Zero);
        angles
            .into_iter()
            .map(|a| {
                let Decoded::Reading(r) = d.decode(format!("{a},100").as_bytes(), 0).unwrap()
                else {
                    panic!("not a reading")
                };
                (r.sweep_id, r.direction)
            })
            .collect()
    }

    #[test]
    fn one_revolution_of_a_continuous_head_is_one_sweep_however_its_angles_are_written() {
        let turns = 3;
        let per_turn = 120;
        /// Angle of reading `k` of a turn at 3°, written as such a head writes it.
        type Written = fn(usize) -> f32;
        let written: [(&str, Written); 4] = [
            ("0…360", |k| (k % 120) as f32 * 3.0),
            ("0…−360", |k| -((k % 120) as f32) * 3.0),
            ("−180…180", |k| (k % 120) as f32 * 3.0 - 180.0),
            ("from 90", |k| ((k % 120) as f32 * 3.0 + 90.0) % 360.0),
        ];
        for (how, angle) in written {
            let got = sweeps_of((0..turns * per_turn).map(angle));
            // A sweep ends where the written angle wraps: every whole one is one revolution.
            let mut sizes = std::collections::BTreeMap::<u32, usize>::new();
            for &(sweep, _) in &got {
                *sizes.entry(sweep).or_default() += 1;
            }
            let sizes: Vec<usize> = sizes.into_values().collect();
            let expected = if how == "from 90" {
                vec![90, 120, 120, 30]
            } else {
                vec![120; turns]
            };
            assert_eq!(sizes, expected, "{how}: readings per sweep");
            let sign = if how == "0…−360" { -1 } else { 1 };
            assert!(got[1..].iter().all(|&(_, d)| d == sign), "{how}");
        }
        // A servo still reverses, and one that flies back from 165° to 15° starts a sweep there.
        let servo = sweeps_of([15.0, 16.0, 17.0, 16.0, 15.0, 16.0]);
        assert_eq!(
            servo.iter().map(|g| g.0).collect::<Vec<_>>(),
            [0, 0, 0, 1, 1, 2]
        );
        let fly_back = sweeps_of([163.0, 164.0, 165.0, 15.0, 16.0, 17.0]);
        assert_eq!(fly_back, [(0, 0), (0, 1), (0, 1), (1, 1), (1, 1), (1, 1)]);
    }

    fn hobby(no_echo: NoEcho) -> Decoder {
        Decoder::new(
            Dialect::Hobby,
            SensorConfig::default(),
            PingPolicy::default(),
            0.0,
        )
        .hobby_no_echo(no_echo)
    }

    fn flags_of(d: &mut Decoder, line: &str) -> (u32, f32) {
        let Decoded::Reading(r) = d.decode(line.as_bytes(), 0).unwrap() else {
            panic!("not a reading")
        };
        (r.flags & !flags::NO_RAW_PINGS, r.distance_m)
    }

    #[test]
    fn the_no_echo_value_is_no_echo_and_never_a_range() {
        // Without the setting, 255 is an echo at 2.55 m (what such a sketch's user saw).
        let mut plain = hobby(NoEcho::Zero);
        let (f, d) = flags_of(&mut plain, "10,255");
        assert_eq!(f, 0);
        assert!((d - 2.55).abs() < 1e-3);
        assert_eq!(flags_of(&mut plain, "11,0").0, flags::NO_ECHO);

        let mut d = hobby("255".parse().unwrap());
        assert_eq!(flags_of(&mut d, "10,255"), (flags::NO_ECHO, 0.0));
        assert_eq!(flags_of(&mut d, "11,0"), (flags::NO_ECHO, 0.0));
        let (f, m) = flags_of(&mut d, "12,254");
        assert_eq!(f, 0);
        assert!((m - 2.54).abs() < 1e-3);

        for form in ["300+", ">=300", " 300 +"] {
            let mut d = hobby(form.parse().unwrap());
            assert_eq!(flags_of(&mut d, "10,300"), (flags::NO_ECHO, 0.0), "{form}");
            assert_eq!(flags_of(&mut d, "11,999"), (flags::NO_ECHO, 0.0), "{form}");
            assert_eq!(flags_of(&mut d, "12,299").0, 0, "{form}");
        }
    }

    #[test]
    fn no_echo_forms() {
        assert_eq!("0".parse(), Ok(NoEcho::Zero));
        assert_eq!("255".parse(), Ok(NoEcho::Exactly(255.0)));
        assert_eq!("400+".parse(), Ok(NoEcho::AtOrBeyond(400.0)));
        assert_eq!(">=400".parse(), Ok(NoEcho::AtOrBeyond(400.0)));
        for bad in ["", "far", "-5", "+", "nan", "inf+"] {
            assert!(bad.parse::<NoEcho>().is_err(), "{bad:?}");
        }
    }
}
