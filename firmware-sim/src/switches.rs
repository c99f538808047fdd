//! The two limit switches: closed (pin low; the firmware has its pull-ups on) while the shaft is at
//! or past ±150°, optionally bouncing for a couple of milliseconds at each change.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::motor::Shaft;
use crate::pins::{CYCLES_PER_US, Pin, SWITCH_MAX, SWITCH_MIN};
use crate::schedule::Schedule;

/// Angle at and below which the MIN switch is closed.
pub const MIN_DEG: i64 = -150;
/// Angle at and above which the MAX switch is closed.
pub const MAX_DEG: i64 = 150;
/// A bouncing contact settles within this (sensor-facts: mechanical switches bounce 1–10 ms;
/// 2 ms is a good microswitch).
pub const BOUNCE_US: u64 = 2000;
/// At most this many extra open/close pairs before the contact settles.
pub const MAX_BOUNCES: u32 = 3;

/// Both switches as the shaft closes and opens them.
#[derive(Debug, Clone)]
pub struct LimitSwitches {
    min_closed: bool,
    max_closed: bool,
    /// `Some` with `--switch-bounce`: the seeded contact bounce.
    bounce: Option<ChaCha8Rng>,
    changes: u64,
}

impl LimitSwitches {
    /// The switches for a shaft standing at `shaft` at power-on; `bounce_seed` makes them bounce.
    pub fn new(shaft: &Shaft, bounce_seed: Option<u64>) -> Self {
        Self {
            min_closed: shaft.cmp_deg(MIN_DEG).is_le(),
            max_closed: shaft.cmp_deg(MAX_DEG).is_ge(),
            bounce: bounce_seed.map(ChaCha8Rng::seed_from_u64),
            changes: 0,
        }
    }

    /// The pin levels now: (MIN pin high, MAX pin high) — high is open.
    pub fn levels(&self) -> [(Pin, bool); 2] {
        [
            (SWITCH_MIN, !self.min_closed),
            (SWITCH_MAX, !self.max_closed),
        ]
    }

    /// The shaft moved at `now`: schedules the pin changes of a switch it closed or opened.
    pub fn update(&mut self, shaft: &Shaft, now: u64, schedule: &mut Schedule) {
        let min = shaft.cmp_deg(MIN_DEG).is_le();
        let max = shaft.cmp_deg(MAX_DEG).is_ge();
        if min != self.min_closed {
            self.min_closed = min;
            self.change(SWITCH_MIN, min, now, schedule);
        }
        if max != self.max_closed {
            self.max_closed = max;
            self.change(SWITCH_MAX, max, now, schedule);
        }
    }

    fn change(&mut self, pin: Pin, closed: bool, now: u64, schedule: &mut Schedule) {
        self.changes += 1;
        // A bounce still going on is overtaken by the new change.
        schedule.cancel(pin);
        let settled = !closed;
        let Some(rng) = self.bounce.as_mut() else {
            schedule.push(now, pin, settled);
            return;
        };
        // Make, then bounces: open/close pairs at random moments within BOUNCE_US, ending settled.
        let pairs = rng.random_range(1..=MAX_BOUNCES) as usize;
        let mut times: Vec<u64> = (0..2 * pairs)
            .map(|_| now + rng.random_range(1..=BOUNCE_US * CYCLES_PER_US))
            .collect();
        times.sort_unstable();
        schedule.push(now, pin, settled);
        for (k, at) in times.into_iter().enumerate() {
            schedule.push(at, pin, if k % 2 == 0 { !settled } else { settled });
        }
    }

    /// How often a switch closed or opened.
    pub fn changes(&self) -> u64 {
        self.changes
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motor::Motor;
    use crate::schedule::Edge;

    fn drain(s: &mut Schedule) -> Vec<Edge> {
        let mut out = Vec::new();
        s.take_due(u64::MAX, &mut out);
        out
    }

    #[test]
    fn min_closes_at_minus_150_and_opens_past_it() {
        let mut shaft = Shaft::new(Motor::Paper, -149.25).unwrap();
        let mut sw = LimitSwitches::new(&shaft, None);
        assert_eq!(sw.levels(), [(SWITCH_MIN, true), (SWITCH_MAX, true)]);
        let mut sched = Schedule::default();
        shaft.step(-1);
        sw.update(&shaft, 100, &mut sched);
        assert_eq!(
            drain(&mut sched),
            [Edge {
                at: 100,
                pin: SWITCH_MIN,
                high: false
            }]
        );
        shaft.step(-1);
        sw.update(&shaft, 200, &mut sched);
        assert!(drain(&mut sched).is_empty(), "still closed past −150°");
        shaft.step(2);
        sw.update(&shaft, 300, &mut sched);
        assert!(drain(&mut sched)[0].high, "open again at −149.25°");
        assert_eq!(sw.changes(), 2);
    }

    #[test]
    fn max_closes_at_plus_150_and_a_shaft_starting_there_is_closed() {
        let shaft = Shaft::new(Motor::Nema17, 151.0).unwrap();
        let sw = LimitSwitches::new(&shaft, None);
        assert_eq!(sw.levels(), [(SWITCH_MIN, true), (SWITCH_MAX, false)]);
    }

    #[test]
    fn bounces_toggle_within_two_ms_and_settle_to_the_new_level() {
        for seed in 0..20 {
            let mut shaft = Shaft::new(Motor::Paper, 149.25).unwrap();
            let mut sw = LimitSwitches::new(&shaft, Some(seed));
            let mut sched = Schedule::default();
            shaft.step(1);
            sw.update(&shaft, 1000, &mut sched);
            let edges = drain(&mut sched);
            assert!(edges.len() >= 3 && edges.len() % 2 == 1, "{edges:?}");
            assert_eq!(edges[0].at, 1000, "the contact makes at once");
            for (k, e) in edges.iter().enumerate() {
                assert_eq!(e.pin, SWITCH_MAX);
                assert_eq!(e.high, k % 2 == 1, "alternating, starting closed (low)");
                assert!(e.at <= 1000 + BOUNCE_US * CYCLES_PER_US);
            }
            assert!(edges.windows(2).all(|w| w[0].at <= w[1].at));
        }
    }

    #[test]
    fn a_change_during_a_bounce_replaces_it() {
        let mut shaft = Shaft::new(Motor::Paper, 149.25).unwrap();
        let mut sw = LimitSwitches::new(&shaft, Some(7));
        let mut sched = Schedule::default();
        shaft.step(1);
        sw.update(&shaft, 0, &mut sched);
        shaft.step(-1);
        sw.update(&shaft, 16, &mut sched);
        let edges = drain(&mut sched);
        assert_eq!(edges[0].at, 16, "nothing left of the first bounce");
        assert_eq!(edges.last().map(|e| e.high), Some(true), "settles open");
    }
}
