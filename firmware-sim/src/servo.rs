//! The hobby servo of the servo head (`make -C firmware HEAD=servo`, `--head servo`): an SG90 or
//! MG90S whose signal line (OC1B = PB2) carries a pulse every 20 ms. The servo turns its shaft to
//! the angle the pulse width says — 1000 µs at 0°, 2000 µs at 180° (TowerPro SG90 datasheet), the
//! head angle being the servo's − 90° — at its rated speed, 0.1 s per 60° at 4.8 V (SG90 datasheet),
//! and no farther than its own stops at 0° and 180°.
//!
//! Modelled: the width of each pulse (the board takes it from Timer1 when the pulse ends, see
//! `board.c`); pulses outside 500…2500 µs, which no hobby servo takes for a position, are ignored
//! and counted; the shaft turns at constant speed toward the last valid pulse's angle, from the
//! moment that pulse ended. Not modelled: dead band,
//! overshoot and ringing, the servo letting go when the pulses stop (it holds here), the supply.

use crate::motor::Travel;
use crate::pins::CYCLES_PER_US;

/// Pulse width at the servo's 0°, µs (SG90 datasheet).
pub const PULSE_MIN_US: f64 = 1000.0;
/// Pulse width at the servo's 180°, µs (SG90 datasheet).
pub const PULSE_MAX_US: f64 = 2000.0;
/// Rated speed: 60° in 0.1 s at 4.8 V (SG90, MG90S datasheets).
pub const DEG_PER_S: f64 = 600.0;
/// The servo's travel, in head degrees (servo 0…180° less 90°).
pub const STOP_DEG: f64 = 90.0;
/// Pulses narrower or wider than this are not positions: ignored.
const PULSE_VALID_US: std::ops::RangeInclusive<f64> = 500.0..=2500.0;

/// The servo's shaft, counting time in chip cycles.
#[derive(Debug, Clone)]
pub struct Servo {
    /// Where the shaft stood at `since`, head degrees.
    from_deg: f64,
    since: u64,
    /// Where the last valid pulse sends it, head degrees (within the stops).
    target_deg: f64,
    pulses: u64,
    bad_pulses: u64,
    travel: Travel,
}

/// Counters of the servo, for the summary.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ServoStats {
    /// Pulses taken as positions.
    pub pulses: u64,
    /// Pulses ignored (outside 500…2500 µs).
    pub bad_pulses: u64,
}

/// The head angle a pulse of `width_us` asks for, before the servo's stops.
pub fn commanded_deg(width_us: f64) -> f64 {
    (width_us - PULSE_MIN_US) / (PULSE_MAX_US - PULSE_MIN_US) * 180.0 - 90.0
}

impl Servo {
    /// The shaft at `start_deg` (head degrees, within ±90°), holding there.
    pub fn new(start_deg: f64) -> Option<Self> {
        if !start_deg.is_finite() || start_deg.abs() > STOP_DEG {
            return None;
        }
        Some(Self {
            from_deg: start_deg,
            since: 0,
            target_deg: start_deg,
            pulses: 0,
            bad_pulses: 0,
            travel: Travel {
                lowest_deg: start_deg,
                highest_deg: start_deg,
                wound_lowest_deg: start_deg,
                wound_highest_deg: start_deg,
            },
        })
    }

    /// The shaft's angle at cycle `now` (not before the last pulse), head degrees.
    pub fn angle_deg(&self, now: u64) -> f64 {
        let dt_s = now.saturating_sub(self.since) as f64 / (CYCLES_PER_US as f64 * 1e6);
        let reach = DEG_PER_S * dt_s;
        let delta = self.target_deg - self.from_deg;
        if delta.abs() <= reach {
            self.target_deg
        } else {
            self.from_deg + reach.copysign(delta)
        }
    }

    /// A pulse `width_us` wide ended at cycle `now`.
    pub fn on_pulse(&mut self, width_us: f64, now: u64) {
        if !PULSE_VALID_US.contains(&width_us) {
            self.bad_pulses += 1;
            return;
        }
        self.pulses += 1;
        let asked = commanded_deg(width_us);
        // Where the shaft is now is where the previous move left it; the rest of that move is
        // given up for the new one.
        self.from_deg = self.angle_deg(now);
        self.since = now;
        self.target_deg = asked.clamp(-STOP_DEG, STOP_DEG);
        let t = &mut self.travel;
        t.wound_lowest_deg = t.wound_lowest_deg.min(asked);
        t.wound_highest_deg = t.wound_highest_deg.max(asked);
        // It will reach the target (the speed is constant and the stops are the clamp).
        t.lowest_deg = t.lowest_deg.min(self.target_deg).min(self.from_deg);
        t.highest_deg = t.highest_deg.max(self.target_deg).max(self.from_deg);
    }

    /// How far the shaft turned (lowest/highest: where it was sent within its stops; wound: what
    /// the pulses asked for).
    pub fn travel(&self) -> Travel {
        self.travel
    }

    pub fn stats(&self) -> ServoStats {
        ServoStats {
            pulses: self.pulses,
            bad_pulses: self.bad_pulses,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1000 * CYCLES_PER_US;

    fn pulse(s: &mut Servo, at: u64, width_us: u64) {
        s.on_pulse(width_us as f64, at + width_us * CYCLES_PER_US);
    }

    #[test]
    fn the_pulse_width_sets_the_angle_and_the_shaft_turns_at_its_speed() {
        assert_eq!(commanded_deg(1000.0), -90.0);
        assert_eq!(commanded_deg(1500.0), 0.0);
        assert_eq!(commanded_deg(2000.0), 90.0);
        let mut s = Servo::new(0.0).unwrap();
        pulse(&mut s, 0, 2000);
        let end = 2 * MS;
        // 90° at 600°/s: 150 ms.
        assert_eq!(s.angle_deg(end), 0.0);
        assert!((s.angle_deg(end + 50 * MS) - 30.0).abs() < 1e-9);
        assert_eq!(s.angle_deg(end + 150 * MS), 90.0);
        assert_eq!(s.angle_deg(end + 500 * MS), 90.0);
        // A new pulse mid-way turns it back from where it is.
        let mut s = Servo::new(0.0).unwrap();
        pulse(&mut s, 0, 2000);
        pulse(&mut s, 48 * MS, 1500);
        // It reached 28.5° when the second pulse ended (49.5 ms), and has come back 0.3° since.
        let turned = s.angle_deg(50 * MS);
        assert!((turned - 28.2).abs() < 1e-9, "{turned}");
        assert!((s.angle_deg(50 * MS + 48 * MS) - 0.0).abs() < 1e-9);
    }

    #[test]
    fn the_stops_hold_and_bad_pulses_are_ignored() {
        let mut s = Servo::new(-10.0).unwrap();
        pulse(&mut s, 0, 2400); // asks for 162°: the stop at +90° holds
        assert_eq!(s.angle_deg(u64::MAX / 2), 90.0);
        pulse(&mut s, 20 * MS, 100);
        pulse(&mut s, 40 * MS, 3000);
        assert_eq!(
            s.stats(),
            ServoStats {
                pulses: 1,
                bad_pulses: 2
            }
        );
        let t = s.travel();
        assert_eq!((t.lowest_deg, t.highest_deg), (-10.0, 90.0));
        assert_eq!(t.wound_lowest_deg, -10.0);
        assert!((t.wound_highest_deg - 162.0).abs() < 1e-9, "{t:?}");
        assert!(Servo::new(91.0).is_none());
    }
}
