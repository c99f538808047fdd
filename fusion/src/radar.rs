//! The paper's basic method (§III.A): the latest distance per beam angle, drawn as arcs.
//!
//! The bins follow the head (`follow_head`, on by default): the array starts as a full turn of the
//! paper's 6° bins (its sweep's 50 first), takes its phase from the first reading (so every reading of a head sits on a
//! bin centre) and narrows its bins to the angle between consecutive readings when that is finer
//! (a servo at 1°, a continuous head at 3°), down to 1° ([`RADAR_MAX_BINS`] over a turn): one
//! reading per bin, never two with the later one winning. What a head covers comes from its
//! readings themselves, so the same holds for a paper head (its `HELLO` geometry), a hobby sketch,
//! a continuous head and an imported log, which has no `HELLO`. Angles wrap: a reading at 170°,
//! at −200° or at 300° lands in its bin, never dropped.

use nalgebra::Isometry2;
use serde::{Deserialize, Serialize};
use sonar_common::ipc::{CELL_UNKNOWN, RADAR_MAX_BINS, encode_probability};
use sonar_common::sensor::SensorConfig;

use crate::config_error::{ConfigError, check};
use crate::geometry::{GridGeometry, wrap_angle};
use crate::observation::Observation;
use crate::state::{SavedRadar, StateError, check_len};

/// Finest bin the array takes from a head (a turn in at most [`RADAR_MAX_BINS`] bins).
const FINEST_BIN_DEG: f32 = 360.0 / RADAR_MAX_BINS as f32;
/// Consecutive readings closer than this are the same angle (a reversal, angle jitter).
const SAME_ANGLE_DEG: f32 = 0.25;

/// The angle bins of the radar array, in the sensor's frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RadarConfig {
    /// Centre of bin 0, degrees counter-clockwise from the sensor's forward axis.
    pub first_bin_deg: f32,
    pub bin_width_deg: f32,
    pub bin_count: u32,
    /// Take the phase of the bins from the first reading and narrow them to the angle between
    /// consecutive readings (the head's step): `false` keeps exactly the bins above.
    pub follow_head: bool,
}

impl Default for RadarConfig {
    /// A full turn of the paper's 6° bins from its first reading centre: bins 0…49 are its sweep's
    /// (−147° … 147°), 50…59 the rest of the turn; following the head.
    fn default() -> Self {
        let s = SensorConfig::default();
        let width = s.reading_span_deg();
        Self {
            first_bin_deg: s.reading_centres_deg().first().copied().unwrap_or(0.0),
            bin_width_deg: width,
            bin_count: (360.0 / width).round() as u32,
            follow_head: true,
        }
    }
}

/// `first` moved by less than half a bin of `width` so that `deg` lies on a bin centre.
fn centred_on(first: f32, width: f32, deg: f32) -> f32 {
    let off = deg - first;
    first + off - width * (off / width).round()
}

/// `deg` brought into (−180°, 180°].
fn wrap_deg(deg: f32) -> f32 {
    wrap_angle(deg.to_radians()).to_degrees()
}

impl RadarConfig {
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            "radar.first_bin_deg",
            self.first_bin_deg,
            self.first_bin_deg.is_finite(),
            "a number of degrees",
        )?;
        check(
            "radar.bin_width_deg",
            self.bin_width_deg,
            self.bin_width_deg > 0.0 && self.bin_width_deg.is_finite(),
            "a positive number of degrees",
        )?;
        let count = self.bin_count as f32;
        check(
            "radar.bin_count",
            count,
            self.bin_count > 0
                && self.bin_count as usize <= RADAR_MAX_BINS
                && count * self.bin_width_deg <= 360.0 + 1e-3,
            "in 1..=360, bins spanning at most a full turn",
        )
    }
}

/// The array of the latest distance per angle bin (the paper's "array of necessary size where each
/// element corresponds to the most up-to-date distance for that specific angle").
#[derive(Debug, Clone, PartialEq)]
pub struct RadarMap {
    /// The bins in use: as configured, or as taken from the head ([`RadarConfig::follow_head`]).
    bins: RadarConfig,
    distances: Vec<f32>,
    current_angle_deg: Option<f32>,
}

impl RadarMap {
    pub fn new(config: RadarConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        Ok(Self {
            bins: config,
            distances: vec![f32::NAN; config.bin_count as usize],
            current_angle_deg: None,
        })
    }

    /// The bins in use (those the snapshot carries).
    pub fn config(&self) -> &RadarConfig {
        &self.bins
    }

    /// Latest range per bin, metres: NaN = no reading yet, +∞ = the latest reading had no echo
    /// (the conventions of `sonar_common::ipc::Radar`).
    pub fn distances_m(&self) -> &[f32] {
        &self.distances
    }

    /// Angle of the latest reading, degrees: where the sweep line is.
    pub fn current_angle_deg(&self) -> Option<f32> {
        self.current_angle_deg
    }

    /// Centre angle of bin `i`, degrees.
    pub fn bin_centre_deg(&self, i: usize) -> f32 {
        self.bins.first_bin_deg + i as f32 * self.bins.bin_width_deg
    }

    /// The bin of angle `deg` (any number of turns), if one covers it.
    pub fn bin_of(&self, deg: f32) -> Option<usize> {
        let width = self.bins.bin_width_deg;
        let from_first_edge = (deg - self.bins.first_bin_deg + width / 2.0).rem_euclid(360.0);
        let i = (from_first_edge / width).floor() as usize;
        let count = self.bins.bin_count as usize;
        if i < count {
            Some(i)
        } else {
            // Only rounding puts an angle just short of a full turn past the last bin of bins
            // that cover the turn: it lies at bin 0's edge.
            (count as f32 * width >= 360.0 - 1e-3).then_some(0)
        }
    }

    /// Stores the observation's range in its angle's bin; returns the bin, or `None` if no bin
    /// covers the angle. A range at or beyond the maximum counts as no echo.
    pub fn record(&mut self, obs: &Observation) -> Option<usize> {
        let deg = obs.angle_rad.to_degrees();
        if self.bins.follow_head {
            self.follow_head(deg);
        }
        let bin = self.bin_of(deg)?;
        self.distances[bin] = obs
            .range_m
            .filter(|&d| d < obs.max_range_m)
            .unwrap_or(f32::INFINITY);
        self.current_angle_deg = Some(deg);
        Some(bin)
    }

    /// Puts the bins where the head's readings are: the phase from the first reading, and bins
    /// as fine as the angle between consecutive readings when that is finer than theirs. The
    /// array starts empty again when its bins change.
    fn follow_head(&mut self, deg: f32) {
        let width = self.bins.bin_width_deg;
        let Some(last) = self.current_angle_deg else {
            if self.distances.iter().all(|d| d.is_nan()) {
                self.bins.first_bin_deg = centred_on(self.bins.first_bin_deg, width, deg);
            }
            return;
        };
        let step = wrap_deg(deg - last).abs();
        if step < SAME_ANGLE_DEG || step > width - SAME_ANGLE_DEG {
            return;
        }
        // Whole bins to a turn, so that the readings of every revolution fall on the same ones.
        let count = (360.0 / step.max(FINEST_BIN_DEG))
            .round()
            .min(RADAR_MAX_BINS as f32);
        let width = 360.0 / count;
        self.bins.bin_width_deg = width;
        self.bins.bin_count = count as u32;
        self.bins.first_bin_deg = centred_on(self.bins.first_bin_deg, width, deg);
        self.distances = vec![f32::NAN; count as usize];
        tracing::info!(
            bin_width_deg = width,
            bins = count as u32,
            "the radar takes its bins from the head's step"
        );
    }

    /// Copies the array and its bins into `out`, for saving (into its allocation).
    pub(crate) fn save_into(&self, out: &mut SavedRadar) {
        out.distances_m.clone_from(&self.distances);
        out.current_angle_deg = self.current_angle_deg;
        out.first_bin_deg = self.bins.first_bin_deg;
        out.bin_width_deg = self.bins.bin_width_deg;
    }

    /// Takes a saved array back: with its bins when they were taken from the head, else if it has
    /// one value per configured bin.
    pub(crate) fn restore(&mut self, saved: SavedRadar) -> Result<(), StateError> {
        if self.bins.follow_head {
            let bins = RadarConfig {
                first_bin_deg: saved.first_bin_deg,
                bin_width_deg: saved.bin_width_deg,
                bin_count: saved.distances_m.len() as u32,
                follow_head: true,
            };
            if bins.validate().is_err() {
                return Err(StateError::Length {
                    what: "the radar",
                    expected: self.distances.len(),
                    found: saved.distances_m.len(),
                });
            }
            self.bins = bins;
        } else {
            check_len("the radar", self.distances.len(), saved.distances_m.len())?;
        }
        self.distances = saved.distances_m;
        self.current_angle_deg = saved.current_angle_deg;
        Ok(())
    }

    pub fn clear(&mut self) {
        self.distances.fill(f32::NAN);
        self.current_angle_deg = None;
    }

    /// Draws the array as the paper's radar display does, into `out` (one byte per cell of
    /// `geometry`, the snapshot encoding of `sonar_common::ipc`): each bin's distance as an arc one
    /// cell thick across the beam width (±`beam_half_angle_rad` around the bin's angle), seen from
    /// the sensor at `pose`. Arc cells are "occupied" (p = 1, the basic method's unchanging
    /// likelihood along the whole arc); every other cell is unknown, since the display says nothing
    /// about them. The result compares cell by cell with [`crate::grid::OccupancyGrid::encode_into`].
    ///
    /// # Panics
    /// If `out` does not hold one byte per cell.
    pub fn rasterise_into(
        &self,
        geometry: &GridGeometry,
        pose: &Isometry2<f32>,
        beam_half_angle_rad: f32,
        out: &mut [u8],
    ) {
        assert_eq!(out.len(), geometry.len(), "one byte per cell");
        let sensor = geometry.sensor_cell(pose.translation.vector);
        let heading = pose.rotation.angle();
        let half_beam = beam_half_angle_rad.to_degrees();
        let half_cell = geometry.resolution() / 2.0;
        let (first, width, count) = (
            self.bins.first_bin_deg,
            self.bins.bin_width_deg,
            self.bins.bin_count as f32,
        );
        let n = geometry.cells_per_side();
        let occupied = encode_probability(1.0);
        for (y, row) in out.chunks_exact_mut(n).enumerate() {
            for (x, cell) in row.iter_mut().enumerate() {
                let (r, a) = sensor.polar(x as i64 - sensor.cell[0], y as i64 - sensor.cell[1]);
                let bearing = wrap_angle(a - heading).to_degrees();
                // The bins whose beam covers this bearing, also across ±180°.
                let on_arc = [-360.0f32, 0.0, 360.0].into_iter().any(|turn| {
                    let b = bearing + turn;
                    let lo = ((b - half_beam - first) / width).ceil().max(0.0);
                    let hi = ((b + half_beam - first) / width).floor().min(count - 1.0);
                    (lo as i64..=hi as i64).any(|i| {
                        let d = self.distances[i as usize];
                        d.is_finite() && (r - d).abs() <= half_cell
                    })
                });
                *cell = if on_arc { occupied } else { CELL_UNKNOWN };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs(angle_deg: f32, range_m: Option<f32>) -> Observation {
        Observation {
            pose: Isometry2::identity(),
            angle_rad: angle_deg.to_radians(),
            range_m,
            rejected_echo_m: None,
            beam_half_angle_rad: 30f32.to_radians(),
            max_range_m: 4.0,
        }
    }

    #[test]
    fn one_bin_per_reading_centre_keeps_the_latest() {
        let mut radar = RadarMap::new(RadarConfig::default()).unwrap();
        assert_eq!(radar.distances_m().len(), 60);
        assert!(radar.distances_m().iter().all(|d| d.is_nan()));
        assert_eq!(radar.record(&obs(-147.0, Some(1.0))), Some(0));
        assert_eq!(radar.record(&obs(3.0, Some(2.0))), Some(25));
        assert_eq!(radar.record(&obs(3.0, Some(1.5))), Some(25));
        assert_eq!(radar.distances_m()[25], 1.5);
        assert_eq!(radar.record(&obs(147.0, None)), Some(49));
        assert_eq!(radar.distances_m()[49], f32::INFINITY);
        assert_eq!(radar.record(&obs(147.0, Some(4.0))), Some(49));
        assert_eq!(radar.distances_m()[49], f32::INFINITY);
        // Beyond the paper's switches, and written in other turns: the same bins, never dropped.
        assert_eq!(radar.record(&obs(171.0, Some(1.0))), Some(53));
        assert_eq!(radar.record(&obs(171.0 - 360.0, Some(1.0))), Some(53));
        assert_eq!(radar.record(&obs(-153.0, Some(1.0))), Some(59));
        assert_eq!(radar.record(&obs(3.0 + 720.0, Some(1.0))), Some(25));
        assert_eq!(radar.current_angle_deg(), Some(723.0));
        assert_eq!(radar.bin_centre_deg(25), 3.0);
        assert_eq!(
            radar.config().bin_width_deg,
            6.0,
            "the paper's head keeps 6° bins"
        );
        radar.clear();
        assert!(radar.distances_m().iter().all(|d| d.is_nan()));
    }

    /// A continuous head's readings at `step_deg` over one revolution, written from `from_deg` in
    /// direction `sign`, each at its own distance.
    fn revolution(step_deg: f32, from_deg: f32, sign: f32) -> Vec<(f32, f32)> {
        let n = (360.0 / step_deg).round() as usize;
        (0..n)
            .map(|k| (from_deg + sign * k as f32 * step_deg, 0.5 + k as f32 * 0.01))
            .collect()
    }

    #[test]
    fn a_360_degree_scan_at_3_degrees_keeps_every_reading() {
        for (from, sign) in [(0.0, 1.0), (0.0, -1.0), (-180.0, 1.0), (90.0, 1.0)] {
            let mut radar = RadarMap::new(RadarConfig::default()).unwrap();
            // The first revolution teaches the bins; the second must keep every one of its readings.
            for _ in 0..2 {
                for (deg, d) in revolution(3.0, from, sign) {
                    radar.record(&obs(deg, Some(d)));
                }
            }
            let bins = *radar.config();
            assert_eq!(
                (bins.bin_width_deg, bins.bin_count),
                (3.0, 120),
                "{from} {sign}"
            );
            let readings = revolution(3.0, from, sign);
            let mut kept: Vec<f32> = radar.distances_m().to_vec();
            kept.sort_by(f32::total_cmp);
            let mut sent: Vec<f32> = readings.iter().map(|&(_, d)| d).collect();
            sent.sort_by(f32::total_cmp);
            assert_eq!(
                kept, sent,
                "every reading in a bin of its own ({from}, {sign})"
            );
            for (deg, d) in readings {
                let bin = radar.bin_of(deg).unwrap();
                assert_eq!(radar.distances_m()[bin], d, "{deg}");
                let centre = radar.bin_centre_deg(bin);
                assert!(
                    wrap_deg(centre - deg).abs() < 1e-3,
                    "{deg} in bin at {centre}"
                );
            }
        }
    }

    #[test]
    fn bins_follow_a_servo_step_and_stay_when_fixed() {
        let mut radar = RadarMap::new(RadarConfig::default()).unwrap();
        for deg in -75..=75 {
            radar.record(&obs(deg as f32, Some(1.0)));
        }
        assert_eq!(radar.config().bin_count, 360);
        // Narrowed after the second reading: all but the first are kept, one per bin.
        let kept = radar.distances_m().iter().filter(|d| d.is_finite()).count();
        assert_eq!(kept, 150);
        // Half a degree is finer than a turn of 360 bins: two readings a bin.
        let mut fine = RadarMap::new(RadarConfig::default()).unwrap();
        for k in 0..20 {
            fine.record(&obs(k as f32 * 0.5, Some(1.0)));
        }
        assert_eq!(fine.config().bin_width_deg, 1.0);
        let fixed = RadarConfig {
            follow_head: false,
            ..RadarConfig::default()
        };
        let mut radar = RadarMap::new(fixed).unwrap();
        for k in 0..120 {
            radar.record(&obs(k as f32 * 3.0, Some(1.0)));
        }
        assert_eq!(*radar.config(), fixed);
    }

    #[test]
    fn bins_that_do_not_cover_a_turn_drop_what_lies_outside() {
        let paper = RadarConfig {
            first_bin_deg: -147.0,
            bin_width_deg: 6.0,
            bin_count: 50,
            follow_head: false,
        };
        let radar = RadarMap::new(paper).unwrap();
        assert_eq!(radar.bin_of(-150.0), Some(0));
        assert_eq!(radar.bin_of(149.9), Some(49));
        assert_eq!(radar.bin_of(170.0), None);
        assert_eq!(radar.bin_of(-147.0 + 360.0), Some(0));
    }

    #[test]
    fn a_saved_array_comes_back_with_the_bins_it_took_from_the_head() {
        let mut radar = RadarMap::new(RadarConfig::default()).unwrap();
        for (deg, d) in revolution(3.0, 0.0, 1.0) {
            radar.record(&obs(deg, Some(d)));
        }
        let mut saved = SavedRadar::default();
        radar.save_into(&mut saved);
        let mut restored = RadarMap::new(RadarConfig::default()).unwrap();
        restored.restore(saved.clone()).unwrap();
        assert_eq!(restored.config(), radar.config());
        let bits = |r: &RadarMap| {
            r.distances_m()
                .iter()
                .map(|d| d.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&restored), bits(&radar));
        assert_eq!(restored.current_angle_deg(), radar.current_angle_deg());
        let mut fixed = RadarMap::new(RadarConfig {
            follow_head: false,
            ..RadarConfig::default()
        })
        .unwrap();
        assert!(
            fixed.restore(saved).is_err(),
            "120 values for 60 fixed bins"
        );
    }

    #[test]
    fn an_arc_spans_the_beam_at_the_distance() {
        let mut radar = RadarMap::new(RadarConfig::default()).unwrap();
        radar.record(&obs(3.0, Some(1.0)));
        let g = GridGeometry::new(200, 0.02);
        let mut out = vec![0u8; g.len()];
        radar.rasterise_into(&g, &Isometry2::identity(), 30f32.to_radians(), &mut out);
        let marked: Vec<(usize, usize)> = (0..200)
            .flat_map(|y| (0..200).map(move |x| (x, y)))
            .filter(|&(x, y)| out[g.index(x, y)] == encode_probability(1.0))
            .collect();
        assert!(!marked.is_empty());
        let mut bearings = Vec::new();
        for &(x, y) in &marked {
            let c = g.cell_centre(x, y);
            let r = c.coords.norm();
            assert!((r - 1.0).abs() <= 0.011, "{r}");
            bearings.push(c.y.atan2(c.x).to_degrees());
        }
        let lo = bearings.iter().copied().fold(f32::MAX, f32::min);
        let hi = bearings.iter().copied().fold(f32::MIN, f32::max);
        assert!(
            (lo + 27.0).abs() < 1.5 && (hi - 33.0).abs() < 1.5,
            "{lo} {hi}"
        );
        // The rest is unknown.
        assert_eq!(
            out.iter().filter(|&&c| c == CELL_UNKNOWN).count(),
            g.len() - marked.len()
        );
    }

    #[test]
    fn bins_must_fit_a_turn() {
        let bad = RadarConfig {
            bin_count: 400,
            bin_width_deg: 1.0,
            ..Default::default()
        };
        assert!(RadarMap::new(bad).is_err());
        let full = RadarConfig {
            first_bin_deg: -179.5,
            bin_width_deg: 1.0,
            bin_count: 360,
            follow_head: false,
        };
        assert!(RadarMap::new(full).is_ok());
    }
}
