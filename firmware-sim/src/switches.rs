//! The two limit switches: closed (pin low; the firmware has its pull-ups on) while the shaft is at
//! or past ±150°, optionally bouncing for a couple of milliseconds at each change, and optionally
//! broken ([`SwitchFault`], `--switch-fault`): dead, stuck closed, closing early, bouncing badly.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sonar_sim::{SwitchFault, SwitchFaults};

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
/// A [`SwitchFault::Bouncing`] contact: the worst sensor-facts allows, 10 ms, with 4–10 pairs.
pub const BAD_BOUNCE_US: u64 = 10_000;
pub const BAD_BOUNCES: (u32, u32) = (4, 10);

/// Both switches as the shaft closes and opens them.
#[derive(Debug, Clone)]
pub struct LimitSwitches {
    min_closed: bool,
    max_closed: bool,
    faults: SwitchFaults,
    /// `Some` with `--switch-bounce` or a bouncing switch: the seeded contact bounce.
    bounce: Option<ChaCha8Rng>,
    /// Good switches bounce a little too (`--switch-bounce`).
    good_bounce: bool,
    changes: u64,
}

impl LimitSwitches {
    /// The switches for a shaft standing at `shaft` at power-on; `bounce_seed` makes good switches
    /// bounce a little (and seeds a [`SwitchFault::Bouncing`] one); `faults` breaks them.
    pub fn new(shaft: &Shaft, bounce_seed: Option<u64>, faults: SwitchFaults) -> Self {
        let bounce = (bounce_seed.is_some() || faults.bouncing())
            .then(|| ChaCha8Rng::seed_from_u64(bounce_seed.unwrap_or(0)));
        Self {
            min_closed: closed(shaft, MIN_DEG, faults.min),
            max_closed: closed(shaft, MAX_DEG, faults.max),
            faults,
            bounce,
            good_bounce: bounce_seed.is_some(),
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
        let min = closed(shaft, MIN_DEG, self.faults.min);
        let max = closed(shaft, MAX_DEG, self.faults.max);
        if min != self.min_closed {
            self.min_closed = min;
            self.change(SWITCH_MIN, min, self.faults.min, now, schedule);
        }
        if max != self.max_closed {
            self.max_closed = max;
            self.change(SWITCH_MAX, max, self.faults.max, now, schedule);
        }
    }

    fn change(
        &mut self,
        pin: Pin,
        closed: bool,
        fault: Option<SwitchFault>,
        now: u64,
        schedule: &mut Schedule,
    ) {
        self.changes += 1;
        // A bounce still going on is overtaken by the new change.
        schedule.cancel(pin);
        let settled = !closed;
        let bouncing = fault == Some(SwitchFault::Bouncing);
        let Some(rng) = self
            .bounce
            .as_mut()
            .filter(|_| bouncing || self.good_bounce)
        else {
            schedule.push(now, pin, settled);
            return;
        };
        let ((least, most), within_us) = if bouncing {
            (BAD_BOUNCES, BAD_BOUNCE_US)
        } else {
            ((1, MAX_BOUNCES), BOUNCE_US)
        };
        // Make, then bounces: open/close pairs at random moments within the window, ending settled.
        let pairs = rng.random_range(least..=most) as usize;
        let mut times: Vec<u64> = (0..2 * pairs)
            .map(|_| now + rng.random_range(1..=within_us * CYCLES_PER_US))
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

/// Whether the switch at `place_deg` (±150°) is closed with the shaft at `shaft`.
fn closed(shaft: &Shaft, place_deg: i64, fault: Option<SwitchFault>) -> bool {
    let early = match fault {
        Some(SwitchFault::Dead) => return false,
        Some(SwitchFault::Stuck) => return true,
        Some(SwitchFault::Early { deg }) => i64::from(deg),
        Some(SwitchFault::Bouncing) | None => 0,
    };
    if place_deg < 0 {
        shaft.cmp_deg(place_deg + early).is_le()
    } else {
        shaft.cmp_deg(place_deg - early).is_ge()
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
        let mut sw = LimitSwitches::new(&shaft, None, SwitchFaults::default());
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
        let sw = LimitSwitches::new(&shaft, None, SwitchFaults::default());
        assert_eq!(sw.levels(), [(SWITCH_MIN, true), (SWITCH_MAX, false)]);
    }

    #[test]
    fn bounces_toggle_within_two_ms_and_settle_to_the_new_level() {
        for seed in 0..20 {
            let mut shaft = Shaft::new(Motor::Paper, 149.25).unwrap();
            let mut sw = LimitSwitches::new(&shaft, Some(seed), SwitchFaults::default());
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
        let mut sw = LimitSwitches::new(&shaft, Some(7), SwitchFaults::default());
        let mut sched = Schedule::default();
        shaft.step(1);
        sw.update(&shaft, 0, &mut sched);
        shaft.step(-1);
        sw.update(&shaft, 16, &mut sched);
        let edges = drain(&mut sched);
        assert_eq!(edges[0].at, 16, "nothing left of the first bounce");
        assert_eq!(edges.last().map(|e| e.high), Some(true), "settles open");
    }

    #[test]
    fn broken_switches_close_as_their_fault_says() {
        let faults = |min, max| SwitchFaults { min, max };
        let at = |deg: f64| Shaft::new(Motor::Paper, deg).unwrap();
        let levels = |deg, f| LimitSwitches::new(&at(deg), None, f).levels();
        let open = [(SWITCH_MIN, true), (SWITCH_MAX, true)];
        // Dead: open even past its place; stuck: closed anywhere.
        assert_eq!(levels(-155.0, faults(Some(SwitchFault::Dead), None)), open);
        assert_eq!(
            levels(0.0, faults(None, Some(SwitchFault::Stuck))),
            [(SWITCH_MIN, true), (SWITCH_MAX, false)]
        );
        // Early by 5°: MAX closed from +145°, not before.
        let early = faults(None, Some(SwitchFault::Early { deg: 5 }));
        assert_eq!(levels(144.0, early), open);
        assert_eq!(
            levels(145.5, early),
            [(SWITCH_MIN, true), (SWITCH_MAX, false)]
        );
        let early_min = faults(Some(SwitchFault::Early { deg: 5 }), None);
        assert_eq!(
            levels(-145.5, early_min),
            [(SWITCH_MIN, false), (SWITCH_MAX, true)]
        );
    }

    #[test]
    fn a_bouncing_switch_bounces_for_up_to_ten_ms() {
        let bouncing = SwitchFaults {
            min: None,
            max: Some(SwitchFault::Bouncing),
        };
        let mut longest = 0;
        for seed in 0..20 {
            let mut shaft = Shaft::new(Motor::Paper, 149.25).unwrap();
            let mut sw = LimitSwitches::new(&shaft, Some(seed), bouncing);
            let mut sched = Schedule::default();
            shaft.step(1);
            sw.update(&shaft, 0, &mut sched);
            let edges = drain(&mut sched);
            assert!(edges.len() >= 9 && edges.len() % 2 == 1, "{edges:?}");
            assert_eq!(edges.last().map(|e| e.high), Some(false), "settles closed");
            longest = longest.max(edges.last().map_or(0, |e| e.at));
            assert!(longest <= BAD_BOUNCE_US * CYCLES_PER_US);
        }
        assert!(
            longest > BOUNCE_US * CYCLES_PER_US,
            "longer than a good switch"
        );
        // Without --switch-bounce, a bouncing switch still bounces (seeded from 0).
        let shaft = Shaft::new(Motor::Paper, 149.25).unwrap();
        assert!(LimitSwitches::new(&shaft, None, bouncing).bounce.is_some());
    }
}
