//! A sweep's readings as one planar scan at evenly spaced bearings, the shape both
//! `foxglove.LaserScan` and `sensor_msgs/msg/LaserScan` require.
//!
//! The head reports a reading every few degrees (6° with the paper's settings) and sweeps back and
//! forth, so a sweep's readings lie on a regular ladder of bearings but arrive in either order, and
//! a lost reading leaves a hole. [`SweepScans`] collects the readings of one `sweep_id`; when the
//! next sweep begins (or the stream ends) it lays them out from the smallest bearing upwards at the
//! sweep's step — the median gap between consecutive readings, robust to a hole or a turn — each at
//! its nearest bin. Bins no reading reached hold NaN; readings without an echo (or out of range)
//! +∞, as ROS's REP 117 says for "nothing detected".

use sonar_common::ipc::{Reading, flags};

/// At most this many bins (a tenth of a degree over a full turn): a pathological step (two readings
/// a hair apart) cannot make a scan of millions of NaNs.
const MAX_BINS: usize = 3600;

/// One sweep as evenly spaced ranges.
#[derive(Debug, Clone, PartialEq)]
pub struct Scan {
    /// The stamp of the sweep's last reading (`host_stamp_ns`), ns since the Unix epoch.
    pub stamp_ns: u64,
    pub sweep_id: u32,
    /// Bearing of `ranges[0]`, radians counter-clockwise from the sensor's forward axis.
    pub start_rad: f64,
    /// Bearing step between consecutive ranges, radians (0 with a single range).
    pub step_rad: f64,
    /// Metres; NaN where no reading fell, +∞ where a reading heard no echo in range.
    pub ranges: Vec<f64>,
    /// The sensor's maximum range in this sweep, metres (for ROS's `range_max`).
    pub max_range_m: f64,
    /// The sensor's minimum range, metres (for ROS's `range_min`).
    pub min_range_m: f64,
}

impl Scan {
    /// Bearing of the last range, radians.
    pub fn end_rad(&self) -> f64 {
        self.start_rad + self.step_rad * (self.ranges.len().saturating_sub(1)) as f64
    }

    /// Lays out the readings of one sweep (in arrival order; at least one).
    fn from_readings(readings: &[Reading]) -> Option<Self> {
        let last = readings.last()?;
        let angles: Vec<f64> = readings.iter().map(|r| f64::from(r.angle_deg)).collect();
        if angles.iter().any(|a| !a.is_finite()) {
            return None;
        }
        let min = angles.iter().copied().fold(f64::INFINITY, f64::min);
        let max = angles.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut gaps: Vec<f64> = angles
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .filter(|g| *g > 1e-3)
            .collect();
        gaps.sort_by(f64::total_cmp);
        let step_deg = gaps.get(gaps.len() / 2).copied().unwrap_or(0.0);
        let bins = if step_deg > 0.0 {
            (((max - min) / step_deg).round() as usize + 1).min(MAX_BINS)
        } else {
            1
        };
        let mut ranges = vec![f64::NAN; bins];
        for (r, a) in readings.iter().zip(&angles) {
            let i = if step_deg > 0.0 {
                (((a - min) / step_deg).round() as usize).min(bins - 1)
            } else {
                0
            };
            ranges[i] = if r.flags & (flags::NO_ECHO | flags::OUT_OF_RANGE) != 0 {
                f64::INFINITY
            } else {
                f64::from(r.distance_m)
            };
        }
        Some(Self {
            stamp_ns: last.host_stamp_ns,
            sweep_id: last.sweep_id,
            start_rad: min.to_radians(),
            step_rad: step_deg.to_radians(),
            ranges,
            max_range_m: f64::from(last.max_range_m),
            min_range_m: f64::from(last.min_range_m),
        })
    }
}

/// Collects readings sweep by sweep.
#[derive(Debug, Default)]
pub struct SweepScans {
    current: Vec<Reading>,
}

impl SweepScans {
    /// Adds a reading; returns the previous sweep's scan when this reading begins a new sweep.
    pub fn push(&mut self, reading: &Reading) -> Option<Scan> {
        let ended = match self.current.last() {
            Some(last) if last.sweep_id != reading.sweep_id => self.finish(),
            _ => None,
        };
        self.current.push(*reading);
        ended
    }

    /// The scan of the readings collected so far (the sweep in progress), if any; starts afresh.
    pub fn finish(&mut self) -> Option<Scan> {
        let scan = Scan::from_readings(&self.current);
        self.current.clear();
        scan
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(sweep_id: u32, angle_deg: f32, distance_m: f32) -> Reading {
        Reading {
            sweep_id,
            angle_deg,
            distance_m,
            host_stamp_ns: 1_000 + u64::from(sweep_id),
            max_range_m: 4.0,
            min_range_m: 0.02,
            ..Reading::default()
        }
    }

    #[test]
    fn a_sweep_ends_when_the_next_begins_and_its_bins_run_upwards_at_its_step() {
        let mut scans = SweepScans::default();
        // Clockwise: bearings falling by 6°, one reading lost (at 0°), one without echo.
        let mut echo_less = reading(1, -6.0, 0.0);
        echo_less.flags = flags::NO_ECHO;
        for r in [reading(1, 12.0, 1.2), reading(1, 6.0, 1.3)] {
            assert_eq!(scans.push(&r), None);
        }
        assert_eq!(scans.push(&echo_less), None);
        assert_eq!(scans.push(&reading(1, -12.0, 1.5)), None);
        let scan = scans.push(&reading(2, -12.0, 2.0)).unwrap();
        assert_eq!(scan.sweep_id, 1);
        assert!((scan.start_rad - (-12f64).to_radians()).abs() < 1e-9);
        assert!((scan.step_rad - 6f64.to_radians()).abs() < 1e-9);
        assert!((scan.end_rad() - 12f64.to_radians()).abs() < 1e-9);
        assert_eq!(scan.ranges.len(), 5);
        assert_eq!(scan.ranges[0], f64::from(1.5f32));
        assert_eq!(scan.ranges[1], f64::INFINITY);
        assert!(scan.ranges[2].is_nan(), "no reading at 0°");
        assert_eq!(scan.ranges[3], f64::from(1.3f32));
        assert_eq!(scan.ranges[4], f64::from(1.2f32));
        let rest = scans.finish().unwrap();
        assert_eq!((rest.sweep_id, rest.ranges.len()), (2, 1));
        assert_eq!(rest.step_rad, 0.0);
        assert_eq!(scans.finish(), None);
    }

    #[test]
    fn bins_are_bounded_and_non_finite_bearings_give_no_scan() {
        let mut scans = SweepScans::default();
        scans.push(&reading(1, 0.0, 1.0));
        scans.push(&reading(1, 0.01, 1.0));
        scans.push(&reading(1, 0.02, 1.0));
        scans.push(&reading(1, 300.0, 1.0));
        assert_eq!(scans.finish().unwrap().ranges.len(), MAX_BINS);
        scans.push(&reading(1, f32::NAN, 1.0));
        assert_eq!(scans.finish(), None);
    }
}
