//! Keeps emulated time (the AVR's cycle counter) from running ahead of wall time × `--speed`. The
//! emulator is never made to wait for anything else: at `max` it runs as fast as simavr can.

use std::time::{Duration, Instant};

use sonar_common::speed::Speed;

use crate::pins::CLOCK_HZ;

/// Running ahead by less than this is let be: sleeping for less costs more than it paces.
pub const MIN_SLEEP: Duration = Duration::from_millis(1);
/// Falling further behind than this (the host is slower than the factor asks) restarts the pacing
/// from now, rather than rushing to catch up later.
pub const MAX_LAG: Duration = Duration::from_secs(1);

/// Maps emulated cycles to wall time.
#[derive(Debug, Clone)]
pub struct Pacer {
    speed: Speed,
    wall0: Instant,
    cycle0: u64,
}

impl Pacer {
    /// Emulated cycle `cycle` happens at wall time `now`.
    pub fn new(speed: Speed, now: Instant, cycle: u64) -> Self {
        Self {
            speed,
            wall0: now,
            cycle0: cycle,
        }
    }

    /// How long to sleep at wall time `now` with the chip at `cycle` so that it does not run ahead;
    /// `None` to run on.
    pub fn ahead(&mut self, cycle: u64, now: Instant) -> Option<Duration> {
        let Speed::Factor(factor) = self.speed else {
            return None;
        };
        let emulated_s = cycle.saturating_sub(self.cycle0) as f64 / f64::from(CLOCK_HZ);
        let due = self.wall0 + Duration::from_secs_f64(emulated_s / factor);
        if now > due + MAX_LAG {
            self.wall0 = now;
            self.cycle0 = cycle;
            return None;
        }
        let ahead = due.saturating_duration_since(now);
        (ahead >= MIN_SLEEP).then_some(ahead)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SECOND: u64 = CLOCK_HZ as u64;

    #[test]
    fn a_factor_maps_emulated_seconds_to_wall_seconds() {
        let t0 = Instant::now();
        let mut p = Pacer::new(Speed::Factor(2.0), t0, 1000);
        assert_eq!(p.ahead(1000 + SECOND, t0), Some(Duration::from_millis(500)));
        assert_eq!(
            p.ahead(1000 + SECOND, t0 + Duration::from_millis(200)),
            Some(Duration::from_millis(300))
        );
        assert_eq!(
            p.ahead(1000 + SECOND, t0 + Duration::from_micros(499_500)),
            None,
            "less than MIN_SLEEP ahead"
        );
        assert_eq!(p.ahead(1000 + SECOND, t0 + Duration::from_secs(1)), None);
    }

    #[test]
    fn max_never_sleeps_and_a_long_lag_restarts_the_pacing() {
        let t0 = Instant::now();
        let mut max = Pacer::new(Speed::Max, t0, 0);
        assert_eq!(max.ahead(100 * SECOND, t0), None);
        let mut p = Pacer::new(Speed::Factor(1.0), t0, 0);
        let late = t0 + Duration::from_secs(5);
        assert_eq!(p.ahead(SECOND, late), None, "4 s behind: restart");
        assert_eq!(
            p.ahead(2 * SECOND, late),
            Some(Duration::from_secs(1)),
            "paced from the restart"
        );
    }
}
