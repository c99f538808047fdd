//! When the replay publishes each message: the recorded timing scaled by a speed factor, under a
//! rate ceiling that protects the consumers' buffers.
//!
//! iceoryx2 gives a publisher no view of its subscribers' queues (`sonar/readings` overwrites the
//! oldest sample when a queue of 256 is full, and never blocks the publisher), so a replay cannot
//! wait for a consumer to catch up. Instead it never publishes faster than a ceiling: a token
//! bucket of `burst` messages refilled at `max_rate` per second (the generic cell rate algorithm).
//! In any time span `t` at most `burst + max_rate · t` messages go out, so a consumer that
//! processes `max_rate` messages a second may stall for `(256 − burst) / max_rate` seconds without
//! losing one (224 ms with the defaults of 1000/s and 32).
//!
//! Pure: the caller passes the elapsed time, so tests need no clock.

use std::time::Duration;

/// How fast to replay (`Max`: as fast as the rate ceiling allows).
pub use sonar_common::speed::Speed;

/// Default rate ceiling, messages per second.
pub const DEFAULT_MAX_RATE: f64 = 1000.0;
/// Default burst: messages that may go out back to back.
pub const DEFAULT_BURST: u32 = 32;

/// Schedules a replay. Call [`due`](Self::due) for a message, wait until then, publish, then
/// call [`sent`](Self::sent) with the actual time.
#[derive(Debug, Clone)]
pub struct Pacer {
    speed: Speed,
    /// Time between messages at the ceiling; `None` without a ceiling.
    interval: Option<Duration>,
    /// How far ahead of the steady rate a burst may run.
    tolerance: Duration,
    /// Theoretical arrival time of the next message under the ceiling.
    tat: Duration,
    first_stamp: Option<u64>,
    last_stamp: u64,
}

impl Pacer {
    /// `max_rate` ≤ 0 or not finite: no ceiling. `burst` is at least 1.
    pub fn new(speed: Speed, max_rate: f64, burst: u32) -> Self {
        let interval = (max_rate.is_finite() && max_rate > 0.0)
            .then(|| Duration::from_secs_f64(1.0 / max_rate));
        let tolerance = interval.map_or(Duration::ZERO, |i| i * burst.max(1).saturating_sub(1));
        Self {
            speed,
            interval,
            tolerance,
            tat: Duration::ZERO,
            first_stamp: None,
            last_stamp: 0,
        }
    }

    /// When, counted from the start of the replay, the message recorded at `stamp_ns` is due.
    /// Stamps that go backwards are treated as equal to the latest one.
    pub fn due(&mut self, stamp_ns: u64) -> Duration {
        let first = *self.first_stamp.get_or_insert(stamp_ns);
        self.last_stamp = self.last_stamp.max(stamp_ns);
        let recorded = match self.speed {
            Speed::Max => Duration::ZERO,
            Speed::Factor(f) => {
                Duration::from_secs_f64(self.last_stamp.saturating_sub(first) as f64 / 1e9 / f)
            }
        };
        recorded.max(self.tat.saturating_sub(self.tolerance))
    }

    /// Records that a message went out at `at` (from the start of the replay).
    pub fn sent(&mut self, at: Duration) {
        if let Some(interval) = self.interval {
            self.tat = self.tat.max(at) + interval;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn run(pacer: &mut Pacer, stamps: &[u64]) -> Vec<Duration> {
        let mut now = Duration::ZERO;
        stamps
            .iter()
            .map(|&s| {
                now = now.max(pacer.due(s));
                pacer.sent(now);
                now
            })
            .collect()
    }

    #[test]
    fn real_time_follows_the_stamps() {
        let mut p = Pacer::new(Speed::Factor(1.0), 0.0, 1);
        let t0 = 1_700_000_000_000 * MS;
        let times = run(&mut p, &[t0, t0 + 100 * MS, t0 + 250 * MS]);
        assert_eq!(times, [0, 100, 250].map(Duration::from_millis).to_vec());
    }

    #[test]
    fn a_factor_divides_the_gaps_and_backward_stamps_do_not_go_back() {
        let mut p = Pacer::new(Speed::Factor(4.0), 0.0, 1);
        let times = run(&mut p, &[1000 * MS, 1400 * MS, 1200 * MS, 1800 * MS]);
        assert_eq!(
            times,
            [0, 100, 100, 200].map(Duration::from_millis).to_vec()
        );
    }

    #[test]
    fn max_speed_sends_a_burst_then_keeps_to_the_ceiling() {
        let mut p = Pacer::new(Speed::Max, 1000.0, 4);
        let times = run(&mut p, &[0; 8]);
        let ms = |x| Duration::from_millis(x);
        assert_eq!(
            times,
            vec![ms(0), ms(0), ms(0), ms(0), ms(1), ms(2), ms(3), ms(4)]
        );
    }

    #[test]
    fn the_ceiling_bounds_every_window_even_after_a_late_start() {
        // A replay that fell behind (the due times lie in the past) catches up, but never faster
        // than burst + rate · t in any window.
        let (rate, burst) = (500.0, 8u32);
        let mut p = Pacer::new(Speed::Factor(1.0), rate, burst);
        let mut now = Duration::ZERO;
        let mut times = Vec::new();
        for k in 0..300u64 {
            // recorded 10 kHz, i.e. far above the ceiling; the replay stalls 50 ms at k = 100
            if k == 100 {
                now += Duration::from_millis(50);
            }
            now = now.max(p.due(k * 100_000));
            p.sent(now);
            times.push(now);
        }
        for (i, a) in times.iter().enumerate() {
            for (j, b) in times.iter().enumerate().skip(i) {
                let window = (*b - *a).as_secs_f64();
                let allowed = f64::from(burst) + rate * window + 1e-6;
                assert!(((j - i + 1) as f64) <= allowed, "{i}..={j} in {window} s");
            }
        }
    }

    #[test]
    fn without_a_ceiling_max_speed_never_waits() {
        let mut p = Pacer::new(Speed::Max, 0.0, 1);
        assert!(run(&mut p, &[5, 1, 9]).iter().all(|t| t.is_zero()));
    }
}
