//! The paper's basic method (§III.A): the latest distance per beam angle, drawn as arcs.

use nalgebra::Isometry2;
use serde::{Deserialize, Serialize};
use sonar_common::ipc::{CELL_UNKNOWN, RADAR_MAX_BINS, encode_probability};
use sonar_common::sensor::SensorConfig;

use crate::config::{ConfigError, check};
use crate::geometry::{GridGeometry, wrap_angle};
use crate::observation::Observation;
use crate::state::{SavedRadar, StateError, check_len};

/// The angle bins of the radar array, in the sensor's frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RadarConfig {
    /// Centre of bin 0, degrees counter-clockwise from the sensor's forward axis.
    pub first_bin_deg: f32,
    pub bin_width_deg: f32,
    pub bin_count: u32,
}

impl Default for RadarConfig {
    /// One bin per reading centre of the paper's sweep: −147° … 147° in 6°, 50 bins.
    fn default() -> Self {
        let s = SensorConfig::default();
        let centres = s.reading_centres_deg();
        Self {
            first_bin_deg: centres.first().copied().unwrap_or(0.0),
            bin_width_deg: s.reading_span_deg(),
            bin_count: centres.len() as u32,
        }
    }
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
    config: RadarConfig,
    distances: Vec<f32>,
    current_angle_deg: Option<f32>,
}

impl RadarMap {
    pub fn new(config: RadarConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        Ok(Self {
            config,
            distances: vec![f32::NAN; config.bin_count as usize],
            current_angle_deg: None,
        })
    }

    pub fn config(&self) -> &RadarConfig {
        &self.config
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
        self.config.first_bin_deg + i as f32 * self.config.bin_width_deg
    }

    /// The bin of angle `deg`, if one covers it.
    pub fn bin_of(&self, deg: f32) -> Option<usize> {
        let i = ((deg - self.config.first_bin_deg) / self.config.bin_width_deg).round();
        (i >= 0.0 && i < self.config.bin_count as f32).then_some(i as usize)
    }

    /// Stores the observation's range in its angle's bin; returns the bin, or `None` if no bin
    /// covers the angle. A range at or beyond the maximum counts as no echo.
    pub fn record(&mut self, obs: &Observation) -> Option<usize> {
        let deg = obs.angle_rad.to_degrees();
        let bin = self.bin_of(deg)?;
        self.distances[bin] = obs
            .range_m
            .filter(|&d| d < obs.max_range_m)
            .unwrap_or(f32::INFINITY);
        self.current_angle_deg = Some(deg);
        Some(bin)
    }

    /// Copies the array into `out`, for saving (into its allocation).
    pub(crate) fn save_into(&self, out: &mut SavedRadar) {
        out.distances_m.clone_from(&self.distances);
        out.current_angle_deg = self.current_angle_deg;
    }

    /// Takes a saved array back, if it has one value per bin.
    pub(crate) fn restore(&mut self, saved: SavedRadar) -> Result<(), StateError> {
        check_len("the radar", self.distances.len(), saved.distances_m.len())?;
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
    /// about them. The result compares cell by cell with [`crate::OccupancyGrid::encode_into`].
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
            self.config.first_bin_deg,
            self.config.bin_width_deg,
            self.config.bin_count as f32,
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
            beam_half_angle_rad: 30f32.to_radians(),
            max_range_m: 4.0,
        }
    }

    #[test]
    fn one_bin_per_reading_centre_keeps_the_latest() {
        let mut radar = RadarMap::new(RadarConfig::default()).unwrap();
        assert_eq!(radar.distances_m().len(), 50);
        assert!(radar.distances_m().iter().all(|d| d.is_nan()));
        assert_eq!(radar.record(&obs(-147.0, Some(1.0))), Some(0));
        assert_eq!(radar.record(&obs(3.0, Some(2.0))), Some(25));
        assert_eq!(radar.record(&obs(3.0, Some(1.5))), Some(25));
        assert_eq!(radar.distances_m()[25], 1.5);
        assert_eq!(radar.record(&obs(147.0, None)), Some(49));
        assert_eq!(radar.distances_m()[49], f32::INFINITY);
        assert_eq!(radar.record(&obs(147.0, Some(4.0))), Some(49));
        assert_eq!(radar.distances_m()[49], f32::INFINITY);
        assert_eq!(radar.record(&obs(170.0, Some(1.0))), None);
        assert_eq!(radar.current_angle_deg(), Some(147.0));
        assert_eq!(radar.bin_centre_deg(25), 3.0);
        radar.clear();
        assert!(radar.distances_m().iter().all(|d| d.is_nan()));
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
        };
        assert!(RadarMap::new(full).is_ok());
    }
}
