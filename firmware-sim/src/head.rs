//! The hardware around the chip, as one pure state machine: port levels the firmware drives go in
//! (with their cycle), edges to drive on its input pins come out (with theirs).

use sonar_sim::{SwitchFaults, Transducer};
use tracing::{debug, warn};

use crate::motor::{Follower, Motor, STOP_DEG, Shaft, StartOutsideStops, Travel};
use crate::pins::{CYCLES_PER_US, ECHO, LED, Pin, Port, SERVO, TRIG};
use crate::schedule::{Edge, Schedule};
use crate::servo::{Servo, ServoStats};
use crate::srf05::{PingStats, Srf05};
use crate::switches::LimitSwitches;

/// What turns the sensor: the paper's stepper between two limit switches, or a hobby servo
/// (`make -C firmware HEAD=servo`) with no switches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum HeadKind {
    #[default]
    Stepper,
    Servo,
}

/// How the head is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadConfig {
    pub kind: HeadKind,
    /// The stepper (a servo head has none).
    pub motor: Motor,
    /// Where the shaft stands at power-on, degrees.
    pub start_deg: f64,
    /// `Some(seed)`: the limit switches bounce, seeded.
    pub bounce_seed: Option<u64>,
    /// Broken limit switches (`--switch-fault`).
    pub switch_faults: SwitchFaults,
    /// ECHO pulse without an echo, µs (SRF05: 30 ms).
    pub echo_timeout_us: u32,
}

/// Counters of the head, for the summary.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct HeadStats {
    /// Microsteps the shaft followed.
    pub steps: u64,
    /// Microsteps lost against the mechanical stops.
    pub lost_steps: u64,
    /// Driver inputs the follower could not make sense of.
    pub faults: u64,
    /// Limit switch changes.
    pub switch_changes: u64,
    /// The servo's pulses (a servo head).
    pub servo: ServoStats,
    /// How far the shaft turned.
    pub travel: Travel,
    pub sonar: PingStats,
}

/// What turns the shaft.
#[derive(Debug)]
#[expect(
    clippy::large_enum_variant,
    reason = "one head per process, never moved in a loop"
)]
enum Drive {
    Stepper {
        follower: Follower,
        shaft: Shaft,
        switches: LimitSwitches,
        /// Against a stop, losing steps (logged once per episode).
        stalled: bool,
    },
    Servo(Servo),
}

/// Stepper and limit switches, or servo, and the SRF05 on the board.
#[derive(Debug)]
pub struct Head<T> {
    drive: Drive,
    sonar: Srf05<T>,
    schedule: Schedule,
    /// Port B's levels last seen (TRIG, LED).
    portb: u8,
    faults: u64,
    /// The latest cycle the head was told of.
    now: u64,
}

impl<T: Transducer> Head<T> {
    pub fn new(cfg: &HeadConfig, transducer: T) -> Result<Self, StartOutsideStops> {
        let drive = match cfg.kind {
            HeadKind::Stepper => {
                let shaft = Shaft::new(cfg.motor, cfg.start_deg)?;
                Drive::Stepper {
                    follower: Follower::new(cfg.motor.drive()),
                    switches: LimitSwitches::new(&shaft, cfg.bounce_seed, cfg.switch_faults),
                    shaft,
                    stalled: false,
                }
            }
            HeadKind::Servo => Drive::Servo(
                Servo::new(cfg.start_deg)
                    .ok_or(StartOutsideStops(cfg.start_deg, crate::servo::STOP_DEG))?,
            ),
        };
        Ok(Self {
            drive,
            sonar: Srf05::new(transducer, cfg.echo_timeout_us),
            schedule: Schedule::default(),
            portb: 0,
            faults: 0,
            now: 0,
        })
    }

    /// The levels of the pins the head drives, now: the switches (a stepper head) and ECHO (low
    /// between pings).
    pub fn input_levels(&self) -> Vec<(Pin, bool)> {
        let mut levels = match &self.drive {
            Drive::Stepper { switches, .. } => switches.levels().to_vec(),
            Drive::Servo(_) => Vec::new(),
        };
        levels.push((ECHO, false));
        levels
    }

    /// Whether the head listens to the PWM pulses on OC1B (a servo head).
    pub fn wants_oc1b(&self) -> bool {
        matches!(self.drive, Drive::Servo(_))
    }

    /// The firmware changed the levels of `port` to `levels` at cycle `now`.
    pub fn on_port(&mut self, port: Port, levels: u8, now: u64) {
        self.now = self.now.max(now);
        match port {
            Port::B => {
                let changed = self.portb ^ levels;
                self.portb = levels;
                if TRIG.level_in(changed) {
                    let aim = self.angle_at(now);
                    self.sonar
                        .on_trig(TRIG.level_in(levels), now, aim, &mut self.schedule);
                }
                if LED.level_in(changed) {
                    debug!(on = LED.level_in(levels), cycle = now, "LED");
                }
            }
            Port::D => self.on_driver(levels, now),
            Port::C => {}
        }
    }

    /// A PWM pulse `width_cycles` wide on `pin` ended at cycle `now`.
    pub fn on_pulse(&mut self, pin: Pin, width_cycles: u32, now: u64) {
        self.now = self.now.max(now);
        if let (Drive::Servo(servo), true) = (&mut self.drive, pin == SERVO) {
            servo.on_pulse(f64::from(width_cycles) / CYCLES_PER_US as f64, now);
        }
    }

    fn on_driver(&mut self, portd: u8, now: u64) {
        let Drive::Stepper {
            follower,
            shaft,
            switches,
            stalled,
        } = &mut self.drive
        else {
            return; // nothing on port D turns a servo
        };
        let decoded = follower.on_port(portd);
        if let Some(fault) = decoded.fault {
            self.faults += 1;
            warn!(cycle = now, angle = shaft.angle_deg(), "stepper: {fault}");
        }
        if decoded.steps == 0 {
            return;
        }
        let lost = shaft.step(decoded.steps);
        if lost > 0 && !*stalled {
            warn!(
                angle = shaft.angle_deg(),
                "the shaft is against its mechanical stop (±{STOP_DEG}°): the motor stalls, steps are lost"
            );
        }
        *stalled = lost > 0;
        switches.update(shaft, now, &mut self.schedule);
    }

    /// The cycle of the next edge the head will drive.
    pub fn next_edge_at(&self) -> Option<u64> {
        self.schedule.next_at()
    }

    /// Removes the edges due at `now` and appends them to `out`.
    pub fn take_due(&mut self, now: u64, out: &mut Vec<Edge>) {
        self.now = self.now.max(now);
        self.schedule.take_due(now, out);
    }

    fn angle_at(&self, now: u64) -> f64 {
        match &self.drive {
            Drive::Stepper { shaft, .. } => shaft.angle_deg(),
            Drive::Servo(servo) => servo.angle_deg(now),
        }
    }

    /// The shaft's angle, degrees, at the latest cycle the head was told of.
    pub fn angle_deg(&self) -> f64 {
        self.angle_at(self.now)
    }

    pub fn stats(&self) -> HeadStats {
        let sonar = self.sonar.stats();
        match &self.drive {
            Drive::Stepper {
                shaft, switches, ..
            } => {
                let (steps, lost_steps) = shaft.counts();
                HeadStats {
                    steps,
                    lost_steps,
                    faults: self.faults,
                    switch_changes: switches.changes(),
                    servo: ServoStats::default(),
                    travel: shaft.travel(),
                    sonar,
                }
            }
            Drive::Servo(servo) => HeadStats {
                servo: servo.stats(),
                travel: servo.travel(),
                sonar,
                ..HeadStats::default()
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pins::{CYCLES_PER_US, SWITCH_MAX, SWITCH_MIN};
    use crate::srf05::ECHO_DELAY_US;

    /// Echo time = 7000 µs + aim in degrees.
    #[derive(Debug)]
    struct Room;

    impl Transducer for Room {
        fn ping(&mut self, aim_deg: f64) -> u32 {
            (7000.0 + aim_deg).round() as u32
        }
    }

    const HALF_STEPS: [u8; 8] = [
        0b0001, 0b0011, 0b0010, 0b0110, 0b0100, 0b1100, 0b1000, 0b1001,
    ];

    fn head(start_deg: f64) -> Head<Room> {
        let cfg = HeadConfig {
            kind: HeadKind::Stepper,
            motor: Motor::Paper,
            start_deg,
            bounce_seed: None,
            switch_faults: SwitchFaults::default(),
            echo_timeout_us: 30_000,
        };
        Head::new(&cfg, Room).unwrap()
    }

    /// Half steps clockwise from phase 0, one per ms from `t0`; returns the edges driven.
    fn step_cw(h: &mut Head<Room>, n: usize, t0: u64) -> Vec<Edge> {
        let mut out = Vec::new();
        for k in 0..=n {
            let t = t0 + k as u64 * 1000 * CYCLES_PER_US;
            h.on_port(Port::D, HALF_STEPS[(8 - k % 8) % 8] << 4, t);
            h.take_due(t, &mut out);
        }
        out
    }

    #[test]
    fn homing_clockwise_closes_min_at_minus_150() {
        let mut h = head(-141.0);
        assert_eq!(
            h.input_levels(),
            [(SWITCH_MIN, true), (SWITCH_MAX, true), (ECHO, false)]
        );
        // 9° = 12 half steps of 0.75°.
        let edges = step_cw(&mut h, 14, 0);
        assert_eq!(edges.len(), 1, "{edges:?}");
        assert_eq!(edges[0].pin, SWITCH_MIN);
        assert!(!edges[0].high, "closed = low");
        assert_eq!(edges[0].at, 12 * 1000 * CYCLES_PER_US);
        assert_eq!(h.angle_deg(), -151.5);
        assert_eq!(h.stats().steps, 14);
    }

    #[test]
    fn the_stop_stalls_the_motor_and_counts_lost_steps() {
        let mut h = head(-159.0);
        step_cw(&mut h, 4, 0);
        assert_eq!(h.angle_deg(), -159.75);
        let s = h.stats();
        assert_eq!((s.steps, s.lost_steps), (1, 3));
        // The shaft stopped at −159.75°; driven on, it would have wound to −162°.
        let t = s.travel;
        assert_eq!((t.lowest_deg, t.highest_deg), (-159.75, -159.0));
        assert_eq!((t.wound_lowest_deg, t.wound_highest_deg), (-162.0, -159.0));
    }

    #[test]
    fn a_trigger_pings_where_the_shaft_stands() {
        let mut h = head(30.0);
        let t0 = 1_000_000;
        h.on_port(Port::B, 0b10, t0);
        h.on_port(Port::B, 0b00, t0 + 10 * CYCLES_PER_US);
        let rise = t0 + (10 + ECHO_DELAY_US) * CYCLES_PER_US;
        assert_eq!(h.next_edge_at(), Some(rise));
        let mut out = Vec::new();
        h.take_due(rise, &mut out);
        assert_eq!(out.len(), 1);
        h.take_due(u64::MAX, &mut out);
        assert_eq!(out[1].at - out[0].at, 7030 * CYCLES_PER_US);
        assert_eq!(h.stats().sonar.pings, 1);
    }

    #[test]
    fn a_servo_head_pings_where_its_pulses_have_turned_the_shaft() {
        let cfg = HeadConfig {
            kind: HeadKind::Servo,
            motor: Motor::Paper,
            start_deg: 0.0,
            bounce_seed: None,
            switch_faults: SwitchFaults::default(),
            echo_timeout_us: 30_000,
        };
        let mut h = Head::new(&cfg, Room).unwrap();
        assert_eq!(h.input_levels(), [(ECHO, false)], "no switches");
        assert!(h.wants_oc1b());
        // 1250 µs: −45°, 75 ms away at 600°/s.
        let end = 1250 * CYCLES_PER_US;
        h.on_pulse(SERVO, 1250 * CYCLES_PER_US as u32, end);
        let t0 = end + 100_000 * CYCLES_PER_US;
        h.on_port(Port::B, 0b10, t0);
        h.on_port(Port::B, 0b00, t0 + 10 * CYCLES_PER_US);
        let mut out = Vec::new();
        h.take_due(u64::MAX, &mut out);
        assert_eq!(out[1].at - out[0].at, 6955 * CYCLES_PER_US, "aimed at −45°");
        assert_eq!(h.stats().servo.pulses, 1);
        assert!(
            Head::new(
                &HeadConfig {
                    start_deg: 120.0,
                    ..cfg
                },
                Room
            )
            .is_err()
        );
    }

    #[test]
    fn bad_coil_patterns_are_counted_as_faults() {
        let mut h = head(0.0);
        h.on_port(Port::D, 0b0001 << 4, 0);
        h.on_port(Port::D, 0b0100 << 4, 1);
        h.on_port(Port::D, 0b1111 << 4, 2);
        assert_eq!(h.stats().faults, 2);
        assert_eq!(h.angle_deg(), 0.0);
    }
}
