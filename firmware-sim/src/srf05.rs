//! The SRF05 in mode 1 (separate TRIG and ECHO): a trigger pulse of at least 10 µs starts a ping
//! on its falling edge; ECHO rises when the burst has gone out and falls when the echo comes back,
//! or after 30 ms without one.

use sonar_sim::Transducer;

use crate::pins::{CYCLES_PER_US, ECHO};
use crate::schedule::Schedule;

/// Shortest trigger pulse the module answers (datasheet: ≥ 10 µs).
pub const MIN_TRIGGER_US: u64 = 10;
/// From the trigger's falling edge to ECHO rising: the module sends its 8 cycles at 40 kHz (200 µs)
/// and arms its receiver. The datasheets give no number; 500 µs is **assumed** (HC-SR04 modules are
/// measured at 450–500 µs).
pub const ECHO_DELAY_US: u64 = 500;

/// Counters of the sensor.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PingStats {
    /// Pings sent (trigger pulses answered).
    pub pings: u64,
    /// Of those, how many heard an echo.
    pub echoes: u64,
    /// Trigger pulses shorter than [`MIN_TRIGGER_US`], ignored.
    pub short_triggers: u64,
    /// Trigger pulses while a ping was in progress, ignored.
    pub busy_triggers: u64,
}

/// The sensor: TRIG in, ECHO pulses out, echo times from the scene through a [`Transducer`].
#[derive(Debug, Clone)]
pub struct Srf05<T> {
    transducer: T,
    /// The ECHO pulse when nothing returns, µs.
    timeout_us: u32,
    /// When TRIG went high, if it is high.
    trig_rose: Option<u64>,
    /// The ping in progress ends (ECHO falls) at this cycle.
    busy_until: u64,
    stats: PingStats,
}

impl<T: Transducer> Srf05<T> {
    /// `timeout_us`: the width of the ECHO pulse without an echo (SRF05: 30 ms).
    pub fn new(transducer: T, timeout_us: u32) -> Self {
        Self {
            transducer,
            timeout_us,
            trig_rose: None,
            busy_until: 0,
            stats: PingStats::default(),
        }
    }

    /// TRIG is `high` from cycle `now`; the head points at `aim_deg`. A ping schedules its ECHO
    /// pulse.
    pub fn on_trig(&mut self, high: bool, now: u64, aim_deg: f64, schedule: &mut Schedule) {
        if high {
            self.trig_rose.get_or_insert(now);
            return;
        }
        let Some(rose) = self.trig_rose.take() else {
            return;
        };
        if now - rose < MIN_TRIGGER_US * CYCLES_PER_US {
            self.stats.short_triggers += 1;
            return;
        }
        if now < self.busy_until {
            self.stats.busy_triggers += 1;
            return;
        }
        let echo_us = self.transducer.ping(aim_deg);
        let heard = echo_us != 0 && echo_us <= self.timeout_us;
        let width_us = if heard { echo_us } else { self.timeout_us };
        let rise = now + ECHO_DELAY_US * CYCLES_PER_US;
        let fall = rise + u64::from(width_us) * CYCLES_PER_US;
        schedule.push(rise, ECHO, true);
        schedule.push(fall, ECHO, false);
        self.busy_until = fall;
        self.stats.pings += 1;
        self.stats.echoes += u64::from(heard);
        tracing::trace!(aim_deg, echo_us, "ping");
    }

    pub fn stats(&self) -> PingStats {
        self.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::schedule::Edge;

    /// Answers the aim in tenths of a degree as the echo time, and remembers the aims.
    #[derive(Debug, Default)]
    struct Probe {
        aims: Vec<f64>,
        echo_us: Option<u32>,
    }

    impl Transducer for Probe {
        fn ping(&mut self, aim_deg: f64) -> u32 {
            self.aims.push(aim_deg);
            self.echo_us.unwrap_or((aim_deg * 10.0) as u32)
        }
    }

    fn us(t: u64) -> u64 {
        t * CYCLES_PER_US
    }

    fn edges(s: &mut Schedule) -> Vec<(u64, bool)> {
        let mut out = Vec::new();
        s.take_due(u64::MAX, &mut out);
        out.iter()
            .map(|&Edge { at, pin, high }| {
                assert_eq!(pin, ECHO);
                (at, high)
            })
            .collect()
    }

    #[test]
    fn a_trigger_gives_an_echo_pulse_as_wide_as_the_echo_time_after_the_delay() {
        let mut srf = Srf05::new(Probe::default(), 30_000);
        let mut s = Schedule::default();
        srf.on_trig(true, us(100), 12.0, &mut s);
        srf.on_trig(false, us(112), 70.0, &mut s);
        assert_eq!(
            edges(&mut s),
            [(us(612), true), (us(612 + 700), false)],
            "aimed where the shaft is at the falling edge"
        );
        assert_eq!(srf.transducer.aims, [70.0]);
        assert_eq!(
            srf.stats(),
            PingStats {
                pings: 1,
                echoes: 1,
                ..PingStats::default()
            }
        );
    }

    #[test]
    fn no_echo_holds_echo_high_for_the_timeout() {
        let mut srf = Srf05::new(
            Probe {
                echo_us: Some(0),
                ..Probe::default()
            },
            30_000,
        );
        let mut s = Schedule::default();
        srf.on_trig(true, 0, 0.0, &mut s);
        srf.on_trig(false, us(10), 0.0, &mut s);
        assert_eq!(edges(&mut s), [(us(510), true), (us(30_510), false)]);
        assert_eq!(srf.stats().echoes, 0);
    }

    #[test]
    fn short_pulses_and_triggers_during_a_ping_are_ignored() {
        let mut srf = Srf05::new(Probe::default(), 30_000);
        let mut s = Schedule::default();
        srf.on_trig(true, 0, 1.0, &mut s);
        srf.on_trig(false, us(9), 1.0, &mut s);
        assert!(edges(&mut s).is_empty());
        srf.on_trig(true, us(1000), 1.0, &mut s);
        srf.on_trig(false, us(1020), 1.0, &mut s);
        assert_eq!(edges(&mut s).len(), 2);
        // The echo of 10 µs ends at 1020 + 500 + 10 µs.
        srf.on_trig(true, us(1515), 1.0, &mut s);
        srf.on_trig(false, us(1529), 1.0, &mut s);
        assert!(edges(&mut s).is_empty());
        srf.on_trig(true, us(1530), 1.0, &mut s);
        srf.on_trig(false, us(1540), 1.0, &mut s);
        assert_eq!(edges(&mut s).len(), 2, "free again when ECHO has fallen");
        let stats = srf.stats();
        assert_eq!(
            (stats.pings, stats.short_triggers, stats.busy_triggers),
            (2, 1, 1)
        );
    }
}
