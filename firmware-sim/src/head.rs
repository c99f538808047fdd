//! The hardware around the chip, as one pure state machine: port levels the firmware drives go in
//! (with their cycle), edges to drive on its input pins come out (with theirs).

use sonar_sim::{SwitchFaults, Transducer};
use tracing::{debug, warn};

use crate::motor::{Follower, Motor, STOP_DEG, Shaft, StartOutsideStops, Travel};
use crate::pins::{ECHO, LED, Pin, Port, TRIG};
use crate::schedule::{Edge, Schedule};
use crate::srf05::{PingStats, Srf05};
use crate::switches::LimitSwitches;

/// How the head is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadConfig {
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
    /// How far the shaft turned.
    pub travel: Travel,
    pub sonar: PingStats,
}

/// Stepper, limit switches and SRF05 on the board.
#[derive(Debug)]
pub struct Head<T> {
    follower: Follower,
    shaft: Shaft,
    switches: LimitSwitches,
    sonar: Srf05<T>,
    schedule: Schedule,
    /// Port B's levels last seen (TRIG, LED).
    portb: u8,
    faults: u64,
    /// Against a stop, losing steps (logged once per episode).
    stalled: bool,
}

impl<T: Transducer> Head<T> {
    pub fn new(cfg: &HeadConfig, transducer: T) -> Result<Self, StartOutsideStops> {
        let shaft = Shaft::new(cfg.motor, cfg.start_deg)?;
        Ok(Self {
            follower: Follower::new(cfg.motor.drive()),
            switches: LimitSwitches::new(&shaft, cfg.bounce_seed, cfg.switch_faults),
            shaft,
            sonar: Srf05::new(transducer, cfg.echo_timeout_us),
            schedule: Schedule::default(),
            portb: 0,
            faults: 0,
            stalled: false,
        })
    }

    /// The levels of the pins the head drives, now: the switches and ECHO (low between pings).
    pub fn input_levels(&self) -> [(Pin, bool); 3] {
        let [min, max] = self.switches.levels();
        [min, max, (ECHO, false)]
    }

    /// The firmware changed the levels of `port` to `levels` at cycle `now`.
    pub fn on_port(&mut self, port: Port, levels: u8, now: u64) {
        match port {
            Port::B => {
                let changed = self.portb ^ levels;
                self.portb = levels;
                if TRIG.level_in(changed) {
                    let aim = self.shaft.angle_deg();
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

    fn on_driver(&mut self, portd: u8, now: u64) {
        let decoded = self.follower.on_port(portd);
        if let Some(fault) = decoded.fault {
            self.faults += 1;
            warn!(
                cycle = now,
                angle = self.shaft.angle_deg(),
                "stepper: {fault}"
            );
        }
        if decoded.steps == 0 {
            return;
        }
        let lost = self.shaft.step(decoded.steps);
        if lost > 0 && !self.stalled {
            warn!(
                angle = self.shaft.angle_deg(),
                "the shaft is against its mechanical stop (±{STOP_DEG}°): the motor stalls, steps are lost"
            );
        }
        self.stalled = lost > 0;
        self.switches.update(&self.shaft, now, &mut self.schedule);
    }

    /// The cycle of the next edge the head will drive.
    pub fn next_edge_at(&self) -> Option<u64> {
        self.schedule.next_at()
    }

    /// Removes the edges due at `now` and appends them to `out`.
    pub fn take_due(&mut self, now: u64, out: &mut Vec<Edge>) {
        self.schedule.take_due(now, out);
    }

    pub fn angle_deg(&self) -> f64 {
        self.shaft.angle_deg()
    }

    pub fn stats(&self) -> HeadStats {
        let (steps, lost_steps) = self.shaft.counts();
        HeadStats {
            steps,
            lost_steps,
            faults: self.faults,
            switch_changes: self.switches.changes(),
            travel: self.shaft.travel(),
            sonar: self.sonar.stats(),
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
    fn bad_coil_patterns_are_counted_as_faults() {
        let mut h = head(0.0);
        h.on_port(Port::D, 0b0001 << 4, 0);
        h.on_port(Port::D, 0b0100 << 4, 1);
        h.on_port(Port::D, 0b1111 << 4, 2);
        assert_eq!(h.stats().faults, 2);
        assert_eq!(h.angle_deg(), 0.0);
    }
}
