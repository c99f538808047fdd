//! The host time of a reading's instant, from the head's millisecond clock.
//!
//! A line reaches the driver some time after its last ping: the UART's few milliseconds, and on a
//! busy computer whatever the scheduler adds before the driver (or, in simulation, the simulator
//! writing it) runs again — 0.7 ms typically, but 50 to 1200 ms beside two busy loops on two cores.
//! Stamped on arrival, a reading of a robot driving at 0.2 m/s (2 m/s of a ×10 simulation) is
//! placed up to that much further along its path, and a sweep taken standing still looks taken on
//! the move. The head's own clock (`RD`'s `time_ms`) says when the ping was; what it lacks is the
//! mapping to the host's clock.
//!
//! The mapping is a line, host = offset + rate · device, under the points (device ms, arrival
//! ns) of the recent readings: every line arrives after its instant, and the readings that
//! arrived quickest lie on it. [`DeviceClock`] keeps the last [`WINDOW`] points and takes the
//! edge of their lower convex hull over their mean device time (the line under them all that is
//! nearest them all); its slope is learnt, so a head whose crystal runs fast, or a simulation at
//! ×10, maps as well as a real-time one. A reading is stamped on that line at its device time,
//! and never later than it arrived nor earlier than the reading before it. A backlog longer than
//! about half the window (a driver stalled for 30 s of a real head's readings) leaves too few
//! quick readings to draw the line by until it has passed.
//!
//! The line starts afresh (stamps are the arrival times until [`MIN_POINTS`] readings are in)
//! when the device's clock goes back (a reset, or the 32-bit wrap after 49 days), when a
//! reading arrives more than [`STEP_NS`] before the line's instant (the host's clock was set
//! back), and when [`LATE_RUN`] readings in a row, arriving over at least [`LATE_SPAN_NS`], come
//! more than [`STEP_NS`] after it (the host's clock was set forward, or a simulator that fell a
//! second behind restarted its pacing). A backlog is no such run: the readings a stalled driver
//! finds waiting arrive together, and those after them on time.

use std::collections::VecDeque;

/// Readings the line is drawn under: a minute of the paper's head, 6 s of a ×10 simulation.
pub const WINDOW: usize = 256;
/// Readings needed before the line is drawn.
pub const MIN_POINTS: usize = 8;
/// A reading this far off the line (before it, or after it [`LATE_RUN`] times in a row) means
/// the clocks' relation changed.
pub const STEP_NS: i64 = 250_000_000;
/// Readings in a row arriving more than [`STEP_NS`] after the line's instant, over at least
/// [`LATE_SPAN_NS`] of the host's clock, that restart it.
pub const LATE_RUN: usize = 8;
pub const LATE_SPAN_NS: i64 = 1_000_000_000;

/// Maps the head's millisecond clock onto the host's (see the module's docs).
#[derive(Debug, Clone, Default)]
pub struct DeviceClock {
    /// (device ms, arrival ns since the Unix epoch), oldest first.
    points: VecDeque<(i64, i64)>,
    /// Readings in a row that arrived more than [`STEP_NS`] after the line, and when the first
    /// of them arrived.
    late_run: usize,
    late_since_ns: i64,
    /// The last stamp given.
    last_stamp_ns: Option<u64>,
}

impl DeviceClock {
    /// Forgets the mapping: the head was reset or another head is on the port.
    pub fn restart(&mut self) {
        self.points.clear();
        self.late_run = 0;
    }

    /// The host time, ns since the Unix epoch, of the instant the head's clock read `device_ms`,
    /// for a reading that arrived at `arrival_ns`.
    pub fn stamp(&mut self, device_ms: u32, arrival_ns: u64) -> u64 {
        let (x, y) = (
            i64::from(device_ms),
            i64::try_from(arrival_ns).unwrap_or(i64::MAX),
        );
        if self.points.back().is_some_and(|&(last, _)| x <= last) {
            self.restart();
        }
        let on_line = self
            .line()
            .map(|(slope, x0, y0)| y0 + (slope * (x - x0) as f64) as i64);
        let mut stamp = y;
        if let Some(line) = on_line {
            if y < line - STEP_NS {
                self.restart();
            } else {
                if y <= line + STEP_NS {
                    self.late_run = 0;
                } else {
                    if self.late_run == 0 {
                        self.late_since_ns = y;
                    }
                    self.late_run += 1;
                }
                if self.late_run >= LATE_RUN && y - self.late_since_ns >= LATE_SPAN_NS {
                    // The points of the run stay: they are the new relation's.
                    let keep = self.points.len().saturating_sub(self.late_run - 1);
                    self.points.drain(..keep);
                    self.late_run = 0;
                } else {
                    stamp = stamp.min(line);
                }
            }
        }
        self.points.push_back((x, y));
        if self.points.len() > WINDOW {
            self.points.pop_front();
        }
        let stamp = u64::try_from(stamp).unwrap_or(0);
        let stamp = self.last_stamp_ns.map_or(stamp, |last| stamp.max(last));
        self.last_stamp_ns = Some(stamp);
        stamp
    }

    /// The line under the points: (ns per device ms, a point on it), once there are enough.
    /// Of the lines under every point, the one nearest them all (least sum of the points' heights
    /// above it, a linear programme whose optimum is the hull's edge over the points' mean device
    /// time: Moon, Skelly and Towsley, 1999).
    fn line(&self) -> Option<(f64, i64, i64)> {
        if self.points.len() < MIN_POINTS {
            return None;
        }
        let hull = lower_hull(&self.points);
        let mean =
            self.points.iter().map(|&(x, _)| x as f64).sum::<f64>() / self.points.len() as f64;
        let (a, b) = hull
            .windows(2)
            .map(|w| (w[0], w[1]))
            .find(|(_, b)| b.0 as f64 >= mean)?;
        if b.1 <= a.1 {
            return None;
        }
        Some(((b.1 - a.1) as f64 / (b.0 - a.0) as f64, a.0, a.1))
    }
}

/// The lower convex hull of points sorted by x (Andrew's monotone chain).
fn lower_hull(points: &VecDeque<(i64, i64)>) -> Vec<(i64, i64)> {
    let mut hull: Vec<(i64, i64)> = Vec::with_capacity(points.len());
    for &p in points {
        while let [.., o, a] = hull[..] {
            // Drop `a` unless o → a → p turns counter-clockwise (a lies below the chord o–p).
            let cross = (a.0 - o.0) as i128 * (p.1 - o.1) as i128
                - (a.1 - o.1) as i128 * (p.0 - o.0) as i128;
            if cross > 0 {
                break;
            }
            hull.pop();
        }
        hull.push(p);
    }
    hull
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Latencies of a loaded machine: mostly under a millisecond, every fifth reading late by up
    /// to 300 ms, and bursts where several wait together (deterministic, no seed needed).
    fn latency_ns(k: u64) -> u64 {
        let quick = 200_000 + (k * 7919 % 500) * 1_000;
        match k % 23 {
            5..=8 => quick + (9 - k % 23) * 60_000_000,
            _ if k % 5 == 2 => quick + (k * 104_729 % 300) * 1_000_000,
            _ => quick,
        }
    }

    /// Readings every 240 ms of device time; host ns per device ms `rate`.
    fn run(rate: u64, readings: u64, t0_ns: u64) -> Vec<(u64, u64, u64)> {
        let mut clock = DeviceClock::default();
        let mut last_arrival = 0;
        (0..readings)
            .map(|k| {
                let device_ms = 1000 + 240 * k;
                let instant = t0_ns + device_ms * rate;
                // A late line holds up the lines behind it.
                let arrival = (instant + latency_ns(k)).max(last_arrival);
                last_arrival = arrival;
                (instant, arrival, clock.stamp(device_ms as u32, arrival))
            })
            .collect()
    }

    #[test]
    fn a_late_reading_is_stamped_at_its_instant() {
        // A real-time head (1 ms per ms) and a simulation at ×10 (0.1 ms per ms).
        for rate in [1_000_000, 100_000] {
            let got = run(rate, 1000, 1_700_000_000_000_000_000);
            let worst_after_warmup = got[WINDOW..]
                .iter()
                .map(|&(instant, _, stamp)| stamp.abs_diff(instant))
                .max()
                .unwrap_or(0);
            // Arrival stamps are off by up to 300 ms; these by at most the quickest latency.
            assert!(
                worst_after_warmup < 1_000_000,
                "rate {rate}: {worst_after_warmup} ns"
            );
            for (k, w) in got.windows(2).enumerate() {
                assert!(w[1].2 >= w[0].2, "rate {rate}: stamps go back at {k}");
            }
            assert!(got.iter().all(|&(_, arrival, stamp)| stamp <= arrival));
        }
    }

    #[test]
    fn the_first_readings_are_stamped_on_arrival() {
        let got = run(1_000_000, MIN_POINTS as u64, 0);
        assert!(got.iter().all(|&(_, arrival, stamp)| stamp == arrival));
    }

    #[test]
    fn a_reset_head_or_a_stepped_host_clock_starts_the_line_afresh() {
        let mut clock = DeviceClock::default();
        let rate = 100_000;
        for k in 0..100u64 {
            clock.stamp(
                (240 * k) as u32,
                5_000_000_000 + 240 * k * rate + latency_ns(k),
            );
        }
        // The head reset: its clock starts at 0 again, a second later on the host.
        let t1 = 5_000_000_000 + 100 * 240 * rate + 1_000_000_000;
        let arrival = t1 + 300_000;
        assert_eq!(clock.stamp(0, arrival), arrival);
        for k in 1..400u64 {
            let instant = t1 + 240 * k * rate;
            let stamp = clock.stamp((240 * k) as u32, instant + latency_ns(k));
            if k > WINDOW as u64 {
                assert!(
                    stamp.abs_diff(instant) < 1_000_000,
                    "{k}: {stamp} for {instant}"
                );
            }
        }
        // The host's clock jumps 2 s ahead (a simulator's pacing restarted): after a run of
        // late readings the new relation is learnt.
        let t2 = t1 + 2_000_000_000;
        let mut last = (0, 0);
        for k in 400..900u64 {
            let instant = t2 + 240 * k * rate;
            last = (
                instant,
                clock.stamp((240 * k) as u32, instant + latency_ns(k)),
            );
        }
        assert!(last.1.abs_diff(last.0) < 1_000_000, "{last:?}");
    }

    #[test]
    fn a_stalled_driver_s_backlog_keeps_the_line() {
        let mut clock = DeviceClock::default();
        let rate = 100_000;
        // Readings every 24 ms of host time; the driver stalls 1.5 s from reading 100 on and
        // then reads the 62 lines waiting at once.
        let stall_end = 240 * 162 * rate + 1_000_000;
        let mut worst = 0;
        for k in 0..600u64 {
            let instant = 240 * k * rate;
            let arrival = if (100..162).contains(&k) {
                stall_end
            } else {
                instant + 300_000
            };
            let stamp = clock.stamp((240 * k) as u32, arrival);
            if k > WINDOW as u64 {
                worst = worst.max(stamp.abs_diff(instant));
            }
        }
        assert!(worst < 1_000_000, "{worst} ns");
    }
}
