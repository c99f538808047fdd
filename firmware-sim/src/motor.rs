//! The stepper: which motor, how its driver's inputs turn into steps, and where the shaft stands.
//!
//! [`Follower`] reads successive port D levels the way the driver chip does and says how many
//! (micro)steps the rotor takes; [`Shaft`] applies them between the mechanical stops and keeps the
//! output shaft's position exactly, in microsteps (a 28BYJ-48's gear ratio is not a whole number).

use std::cmp::Ordering;

use crate::pins::{COIL, DIR, ENABLE, STEP};

/// Mechanical stops, ± degrees: the shaft cannot turn past them; steps beyond are lost.
pub const STOP_DEG: i64 = 160;

/// How the motor is driven.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Drive {
    /// Unipolar motor on a ULN2003, four coils IN1..IN4 on PD4..PD7, half-stepped.
    Uln2003,
    /// Bipolar motor on an A4988/DRV8825: STEP, DIR, EN on PD4, PD5, PD6.
    StepDir,
}

/// The motor and gear on the head (`--motor`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Motor {
    /// The paper's 7.5° motor through a 1:5 gear on a ULN2003, half-stepped: 0.75° per half step
    /// (480 per turn).
    Paper,
    /// 28BYJ-48 (5.625°/64 through its 63.68:1 gear) on a ULN2003, half-stepped:
    /// 1650688/405 ≈ 4075.8 half steps per turn, ≈ 0.088° each.
    #[value(name = "28byj48")]
    Byj48,
    /// 1.8° NEMA 17 on an A4988/DRV8825 at 1/16 microstep: 3200 per turn, 0.1125° each.
    Nema17,
}

impl Motor {
    /// Microsteps per turn of the output shaft, as the fraction (numerator, denominator).
    pub fn microsteps_per_turn(self) -> (i64, i64) {
        match self {
            Motor::Paper => (480, 1),
            Motor::Byj48 => (1_650_688, 405),
            Motor::Nema17 => (3200, 1),
        }
    }

    pub fn drive(self) -> Drive {
        match self {
            Motor::Paper | Motor::Byj48 => Drive::Uln2003,
            Motor::Nema17 => Drive::StepDir,
        }
    }
}

/// Why the follower could not make sense of the driver's inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// The coils jumped by half a turn of the field (four half steps): the rotor could go either
    /// way, so it is taken to stay.
    Ambiguous { from: u8, to: u8 },
    /// The coils skipped two phases: the rotor follows to the nearest rest position, three half
    /// steps away, but no half-step sequence does that.
    Skipped { from: u8, to: u8 },
    /// Coils energised in a pattern that is no half-step phase (opposite coils, three or four on).
    Pattern { coils: u8 },
}

impl std::fmt::Display for Fault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Fault::Ambiguous { from, to } => {
                write!(f, "coil phase jumped {from} → {to}: ambiguous, no step")
            }
            Fault::Skipped { from, to } => {
                write!(f, "coil phase jumped {from} → {to}: two phases skipped")
            }
            Fault::Pattern { coils } => {
                write!(f, "coils IN4..IN1 = {coils:04b} is no half-step phase")
            }
        }
    }
}

/// What one change of the driver's inputs did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Decoded {
    /// Microsteps the rotor takes, + counter-clockwise (angle increasing).
    pub steps: i32,
    pub fault: Option<Fault>,
}

/// The half-step phase of coils IN4..IN1 (bits 3..0), `None` for no coil energised.
/// Phases 0..7: {IN1}, {IN1,IN2}, {IN2}, {IN2,IN3}, {IN3}, {IN3,IN4}, {IN4}, {IN4,IN1}.
fn phase_of(coils: u8) -> Result<Option<u8>, Fault> {
    match coils {
        0b0000 => Ok(None),
        0b0001 => Ok(Some(0)),
        0b0011 => Ok(Some(1)),
        0b0010 => Ok(Some(2)),
        0b0110 => Ok(Some(3)),
        0b0100 => Ok(Some(4)),
        0b1100 => Ok(Some(5)),
        0b1000 => Ok(Some(6)),
        0b1001 => Ok(Some(7)),
        _ => Err(Fault::Pattern { coils }),
    }
}

/// Reads the driver's inputs from port D and turns their changes into rotor steps.
#[derive(Debug, Clone)]
pub struct Follower {
    drive: Drive,
    /// ULN2003: the last energised phase; the rotor rests there while the coils are off (detent
    /// and gear hold it), so the next energised phase is counted from it. `None` before the first.
    phase: Option<u8>,
    /// STEP/DIR: the level of STEP last seen.
    step_high: bool,
}

impl Follower {
    pub fn new(drive: Drive) -> Self {
        Self {
            drive,
            phase: None,
            step_high: false,
        }
    }

    /// Port D's levels changed to `portd`.
    pub fn on_port(&mut self, portd: u8) -> Decoded {
        match self.drive {
            Drive::Uln2003 => self.on_coils(portd),
            Drive::StepDir => self.on_step_dir(portd),
        }
    }

    fn on_coils(&mut self, portd: u8) -> Decoded {
        let coils = COIL.iter().enumerate().fold(0u8, |acc, (i, pin)| {
            acc | u8::from(pin.level_in(portd)) << i
        });
        let phase = match phase_of(coils) {
            Ok(Some(p)) => p,
            // Off: hold lost, the rotor stays.
            Ok(None) => return Decoded::default(),
            Err(fault) => {
                return Decoded {
                    steps: 0,
                    fault: Some(fault),
                };
            }
        };
        // At the first energisation the rotor is taken to rest in that phase already.
        let from = self.phase.replace(phase).unwrap_or(phase);
        match (phase + 8 - from) % 8 {
            0 => Decoded::default(),
            d @ 1..=2 => Decoded {
                steps: i32::from(d),
                fault: None,
            },
            3 => Decoded {
                steps: 3,
                fault: Some(Fault::Skipped { from, to: phase }),
            },
            4 => Decoded {
                steps: 0,
                fault: Some(Fault::Ambiguous { from, to: phase }),
            },
            5 => Decoded {
                steps: -3,
                fault: Some(Fault::Skipped { from, to: phase }),
            },
            d => Decoded {
                steps: i32::from(d) - 8,
                fault: None,
            },
        }
    }

    fn on_step_dir(&mut self, portd: u8) -> Decoded {
        let step = STEP.level_in(portd);
        let rising = step && !self.step_high;
        self.step_high = step;
        let enabled = !ENABLE.level_in(portd);
        let steps = match (rising && enabled, DIR.level_in(portd)) {
            (false, _) => 0,
            (true, true) => 1,
            (true, false) => -1,
        };
        Decoded { steps, fault: None }
    }
}

/// The output shaft between its mechanical stops, in microsteps from 0°.
#[derive(Debug, Clone)]
pub struct Shaft {
    motor: Motor,
    position: i64,
    /// Microsteps taken.
    moved: u64,
    /// Microsteps lost against a stop.
    lost: u64,
    /// The lowest and highest positions the shaft reached.
    reached: (i64, i64),
    /// Where the shaft would be without the stops (every microstep commanded, lost ones too), and
    /// the lowest and highest of that: how far a head without stops would have wound its cable.
    wound: i64,
    wound_reached: (i64, i64),
}

/// How far the shaft turned, degrees: the extremes it reached, and those it was driven to (the
/// mechanical stops aside).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Travel {
    pub lowest_deg: f64,
    pub highest_deg: f64,
    pub wound_lowest_deg: f64,
    pub wound_highest_deg: f64,
}

/// Where to start the shaft is not a place it can be.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("the shaft cannot stand at {0}°: the mechanical stops are at ±{1}°")]
pub struct StartOutsideStops(pub f64, pub f64);

impl Shaft {
    /// The shaft at `start_deg` (rounded to the nearest microstep).
    pub fn new(motor: Motor, start_deg: f64) -> Result<Self, StartOutsideStops> {
        let (num, den) = motor.microsteps_per_turn();
        if !start_deg.is_finite() || start_deg.abs() > STOP_DEG as f64 {
            return Err(StartOutsideStops(start_deg, STOP_DEG as f64));
        }
        let position = (start_deg * num as f64 / (360.0 * den as f64)).round() as i64;
        Ok(Self {
            motor,
            position,
            moved: 0,
            lost: 0,
            reached: (position, position),
            wound: position,
            wound_reached: (position, position),
        })
    }

    /// The shaft's angle, degrees, counter-clockwise positive.
    pub fn angle_deg(&self) -> f64 {
        self.deg_of(self.position)
    }

    fn deg_of(&self, microsteps: i64) -> f64 {
        let (num, den) = self.motor.microsteps_per_turn();
        microsteps as f64 * 360.0 * den as f64 / num as f64
    }

    /// How far the shaft turned since power-on.
    pub fn travel(&self) -> Travel {
        Travel {
            lowest_deg: self.deg_of(self.reached.0),
            highest_deg: self.deg_of(self.reached.1),
            wound_lowest_deg: self.deg_of(self.wound_reached.0),
            wound_highest_deg: self.deg_of(self.wound_reached.1),
        }
    }

    /// How the shaft's angle compares with `deg`, exactly.
    pub fn cmp_deg(&self, deg: i64) -> Ordering {
        let (num, den) = self.motor.microsteps_per_turn();
        (i128::from(self.position) * 360 * i128::from(den))
            .cmp(&(i128::from(deg) * i128::from(num)))
    }

    /// Takes `steps` microsteps (+ counter-clockwise); those that would pass a stop are lost.
    /// Returns how many were lost.
    pub fn step(&mut self, steps: i32) -> u32 {
        let mut lost = 0;
        for _ in 0..steps.unsigned_abs() {
            self.wound += i64::from(steps.signum());
            self.wound_reached = (
                self.wound_reached.0.min(self.wound),
                self.wound_reached.1.max(self.wound),
            );
            self.position += i64::from(steps.signum());
            if self.cmp_deg(STOP_DEG).is_gt() || self.cmp_deg(-STOP_DEG).is_lt() {
                self.position -= i64::from(steps.signum());
                lost += 1;
            } else {
                self.moved += 1;
                self.reached = (
                    self.reached.0.min(self.position),
                    self.reached.1.max(self.position),
                );
            }
        }
        self.lost += u64::from(lost);
        lost
    }

    /// Microsteps taken and lost against the stops.
    pub fn counts(&self) -> (u64, u64) {
        (self.moved, self.lost)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Port D with coils IN4..IN1 = `coils`.
    fn coils(c: u8) -> u8 {
        c << 4
    }

    const SEQUENCE: [u8; 8] = [
        0b0001, 0b0011, 0b0010, 0b0110, 0b0100, 0b1100, 0b1000, 0b1001,
    ];

    #[test]
    fn half_step_sequence_forward_is_counter_clockwise_and_backward_clockwise() {
        let mut f = Follower::new(Drive::Uln2003);
        assert_eq!(f.on_port(coils(SEQUENCE[0])).steps, 0, "first energisation");
        let forward: i32 = (1..=16)
            .map(|k| f.on_port(coils(SEQUENCE[k % 8])).steps)
            .sum();
        assert_eq!(forward, 16);
        let backward: i32 = (0..16)
            .rev()
            .map(|k| f.on_port(coils(SEQUENCE[k % 8])).steps)
            .sum();
        assert_eq!(backward, -16);
    }

    #[test]
    fn full_steps_count_two_half_steps_and_other_pins_do_not_matter() {
        let mut f = Follower::new(Drive::Uln2003);
        f.on_port(coils(0b0011) | 0x0F);
        assert_eq!(
            f.on_port(coils(0b0110) | 0x03),
            Decoded {
                steps: 2,
                fault: None
            }
        );
        assert_eq!(
            f.on_port(coils(0b0011)),
            Decoded {
                steps: -2,
                fault: None
            }
        );
        // Wrapping around phase 7 → 0 → 1.
        f.on_port(coils(0b1001));
        assert_eq!(f.on_port(coils(0b0011)).steps, 2);
    }

    #[test]
    fn coils_off_hold_the_phase_and_the_next_one_counts_from_it() {
        let mut f = Follower::new(Drive::Uln2003);
        f.on_port(coils(0b0010));
        assert_eq!(f.on_port(0).steps, 0);
        assert_eq!(f.on_port(coils(0b0110)).steps, 1);
        assert_eq!(f.on_port(0).steps, 0);
        assert_eq!(f.on_port(coils(0b0110)).steps, 0);
    }

    #[test]
    fn jumps_of_four_are_ambiguous_and_bad_patterns_are_faults() {
        let mut f = Follower::new(Drive::Uln2003);
        f.on_port(coils(0b0001));
        assert_eq!(
            f.on_port(coils(0b0100)),
            Decoded {
                steps: 0,
                fault: Some(Fault::Ambiguous { from: 0, to: 4 })
            }
        );
        assert_eq!(
            f.on_port(coils(0b1001)),
            Decoded {
                steps: 3,
                fault: Some(Fault::Skipped { from: 4, to: 7 })
            }
        );
        assert_eq!(
            f.on_port(coils(0b0101)).fault,
            Some(Fault::Pattern { coils: 0b0101 })
        );
        // The bad pattern moved nothing; the next phase counts from phase 7.
        assert_eq!(f.on_port(coils(0b0001)).steps, 1);
    }

    #[test]
    fn step_dir_counts_rising_edges_while_enabled() {
        let (step, dir, en) = (1 << 4, 1 << 5, 1 << 6);
        let mut f = Follower::new(Drive::StepDir);
        assert_eq!(f.on_port(dir | step).steps, 1, "rising edge, DIR high: CCW");
        assert_eq!(f.on_port(dir | step).steps, 0, "no edge");
        assert_eq!(f.on_port(dir).steps, 0, "falling edge");
        assert_eq!(f.on_port(step).steps, -1, "DIR low: CW");
        f.on_port(0);
        assert_eq!(f.on_port(en | step).steps, 0, "disabled");
        f.on_port(0);
        assert_eq!(f.on_port(step).steps, -1);
    }

    #[test]
    fn motors_give_the_documented_step_angles() {
        let deg_per_step = |m: Motor| {
            let mut s = Shaft::new(m, 0.0).unwrap();
            s.step(1);
            s.angle_deg()
        };
        assert!((deg_per_step(Motor::Paper) - 0.75).abs() < 1e-12);
        assert!((deg_per_step(Motor::Nema17) - 0.1125).abs() < 1e-12);
        assert!((deg_per_step(Motor::Byj48) - 360.0 / 4075.7728).abs() < 1e-9);
        assert_eq!(Motor::Nema17.drive(), Drive::StepDir);
        assert_eq!(Motor::Byj48.drive(), Drive::Uln2003);
    }

    #[test]
    fn the_shaft_starts_at_the_nearest_microstep_and_compares_exactly() {
        let s = Shaft::new(Motor::Paper, -150.0).unwrap();
        assert_eq!(s.cmp_deg(-150), Ordering::Equal);
        assert_eq!(s.angle_deg(), -150.0);
        let s = Shaft::new(Motor::Byj48, 150.0).unwrap();
        assert!((s.angle_deg() - 150.0).abs() < 0.05);
        assert!(Shaft::new(Motor::Paper, 161.0).is_err());
        assert!(Shaft::new(Motor::Paper, f64::NAN).is_err());
    }

    #[test]
    fn steps_past_the_stops_are_lost() {
        let mut s = Shaft::new(Motor::Paper, 159.0).unwrap();
        assert_eq!(s.step(3), 2, "159.0 → 159.75 → 160.5 would pass the stop");
        assert_eq!(s.angle_deg(), 159.75);
        assert_eq!(s.step(-2), 0);
        assert_eq!(s.counts(), (3, 2));
        // −160° is no half step of this motor: it starts at the nearest, −159.75°.
        let mut s = Shaft::new(Motor::Paper, -160.0).unwrap();
        assert_eq!(s.angle_deg(), -159.75);
        assert_eq!(s.step(-1), 1);
        assert_eq!(s.angle_deg(), -159.75);
    }
}
