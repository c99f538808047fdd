//! The sensor's range offset, measured on a wall at a known distance.
//!
//! A sensor's ranges can be off by a constant: its detector fires a cycle or two into the echo
//! (4–9 mm late at 40 kHz), the transducer sits on the head's arm rather than on its axis, a
//! processed sensor reports its own bias (the LEGO NXT's ranges are about 3 cm short,
//! `docs/sensor-facts.md`). The features, the grid and the SLAM subtract
//! [`FeatureConfig::range_offset_m`] from every range; this measures it.
//!
//! Face the head to a flat wall with nothing nearer, measure the perpendicular distance from the
//! head's turning axis to the wall (where the software places the sensor), and let it sweep
//! standing still. A wall answers every ping within its specular cut-off at the foot of the
//! perpendicular, so its region of constant depth, seen whole (both ends where the echo faded),
//! gives the wall's distance as the mean of its pings ([`wall_in_sweep`]). The offset is the
//! mean over the sweeps of those distances less the true one ([`range_offset`]): it holds the
//! sensor's lateness and the arm's length together, which is what the software must take off.
//!
//! The same sweeps check the head's description, which the features need to recognise a wall at
//! all: the readings' spacing over their pings gives the head's step ([`head_step_deg`]), and
//! the wall's region its width, against the plane cone `[features.echo]` predicts. Asked for the
//! wall by its bearing, the calibration takes the region seen whole there even when the
//! configured cones do not call it a wall, so a head described wrongly is still measured and
//! told what it shows.
//!
//! A constant is all one wall can tell. A scale error (the speed of sound, 0.17 % per °C of a
//! wrong air temperature) grows with the range: two walls at different distances would tell it
//! apart; here it is the air temperature's to get right.

use crate::config::FeatureConfig;
use crate::error::FeatureError;
use crate::feature::FeatureKind;
use crate::geometry::wrap_deg;
use crate::map::FeatureMap;
use crate::physics::Reflector;
use crate::pings::Sweep;
use crate::rcd::Rcd;
use sonar_common::ipc::Reading;

/// The wall one sweep heard, as the calibration uses it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallSighting {
    /// The wall's perpendicular distance as measured: the mean of its pings' ranges, with no
    /// offset taken off, metres.
    pub distance_m: f64,
    /// Standard error of that mean from the pings' jitter, metres.
    pub sigma_m: f64,
    /// Bearing of the wall's normal, degrees, in the sensor's frame.
    pub normal_deg: f64,
    /// Pings that heard it.
    pub pings: u32,
    /// Half the width of its region, degrees: the cone over which the wall answered.
    pub half_width_deg: f64,
    /// Whether the features took it for a wall (else: the region seen whole nearest the bearing
    /// asked for, which the configured cones do not call a wall).
    pub classified: bool,
}

impl WallSighting {
    /// The wall whose region is `rcd`, its normal at `normal_deg` (the region's range and its
    /// jitter are the observation's: `crate::classify` takes them from the region).
    fn of(rcd: &Rcd, normal_deg: f64, classified: bool) -> Self {
        Self {
            distance_m: rcd.range_m,
            sigma_m: rcd.range_sigma_m,
            normal_deg,
            pings: rcd.pings,
            half_width_deg: rcd.width_deg() / 2.0,
            classified,
        }
    }
}

/// The offset measured over several sweeps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RangeOffset {
    /// What to set [`FeatureConfig::range_offset_m`] to: measured less true, metres.
    pub offset_m: f64,
    /// Its uncertainty (1σ), metres: the spread of the sweeps' distances over the root of their
    /// number, or the pings' own standard error if larger, and never below a range's
    /// quantum over √12 (a sensor that reports whole centimetres tells nothing finer).
    pub sigma_m: f64,
    /// Sweeps it is measured over.
    pub sweeps: usize,
    /// The mean bearing of the wall's normal, degrees.
    pub normal_deg: f64,
}

/// What keeps an offset from being measured.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrationError {
    #[error("the wall's true distance must be positive and finite, got {0} m")]
    BadDistance(f64),
    #[error("no sweep saw the wall")]
    NoSightings,
    #[error(
        "the sweeps saw walls whose normals lie {spread_deg:.1}° apart: more than one wall, or \
         the head moved (keep it still, facing one flat wall with nothing nearer)"
    )]
    DifferentWalls { spread_deg: f64 },
    #[error(
        "the wall was measured at {measured_m:.3} m, {offset_m:+.3} m from the {true_m:.3} m \
         given: more than a sensor's offset can be (is the distance measured from the head's \
         axis to the wall, square to it?)"
    )]
    Implausible {
        measured_m: f64,
        true_m: f64,
        offset_m: f64,
    },
    #[error(transparent)]
    Features(#[from] FeatureError),
}

/// Normals of one wall seen from one place agree within this, degrees: the middle of a region
/// is known to about a step (1.5–3°).
const SAME_WALL_DEG: f64 = 10.0;

/// A sensor's offset is a detector's lateness and an arm's length: centimetres. Farther, the
/// distance given or the wall heard is wrong.
const MOST_OFFSET_M: f64 = 0.15;

/// The wall `sweep` heard whole: of the regions classified as a wall and seen whole, the one
/// whose normal lies nearest `bearing_deg` (within [`SAME_WALL_DEG`]), or without it the nearest
/// wall. With `bearing_deg`, when no such wall lies there, the region seen whole whose middle
/// lies nearest it (within [`SAME_WALL_DEG`]): the wall the person faced, which the configured
/// cones do not call one. `cfg`'s range offset is not applied (it is what is measured). `None`
/// when the sweep saw nothing whole there.
pub fn wall_in_sweep(
    sweep: &Sweep,
    cfg: &FeatureConfig,
    bearing_deg: Option<f64>,
) -> Result<Option<WallSighting>, CalibrationError> {
    let cfg = FeatureConfig {
        range_offset_m: 0.0,
        ..*cfg
    };
    let mut map = FeatureMap::new(cfg)?;
    map.learn_noise(sweep);
    let (rcds, classification) = map.observe(sweep);
    let walls = classification
        .observations
        .iter()
        .filter(|o| o.kind == FeatureKind::Plane && o.whole)
        .map(|o| WallSighting::of(&rcds[o.rcd], o.bearing_deg, true));
    let Some(b) = bearing_deg else {
        return Ok(walls.min_by(|x, y| x.distance_m.total_cmp(&y.distance_m)));
    };
    let off = |deg: f64| wrap_deg(deg - b).abs();
    let classified = walls
        .filter(|w| off(w.normal_deg) <= SAME_WALL_DEG)
        .min_by(|x, y| off(x.normal_deg).total_cmp(&off(y.normal_deg)));
    Ok(classified.or_else(|| {
        rcds.iter()
            .filter(|r| r.is_whole() && off(r.centre_deg()) <= SAME_WALL_DEG)
            .min_by(|x, y| off(x.centre_deg()).total_cmp(&off(y.centre_deg())))
            .map(|r| WallSighting::of(r, r.centre_deg(), false))
    }))
}

/// Half the width of the region `cfg` expects a wall at `range_m` to answer over, degrees
/// (its plane cone); `None` where it expects none.
pub fn expected_half_width_deg(cfg: &FeatureConfig, range_m: f64) -> Option<f64> {
    let beam = f64::from(cfg.sensor.beam_half_angle_deg);
    cfg.echo
        .cone_half_angle_deg(Reflector::Plane, range_m, beam)
}

/// The head's step between pings as its readings show it, degrees, and the pings of a reading:
/// the median spacing of consecutive readings (by `seq`, within one sweep) over the pings each
/// holds (the most common count). `None` with fewer than three readings or no spacing.
pub fn head_step_deg(readings: &[Reading]) -> Option<(f64, u8)> {
    let mut by_seq: Vec<&Reading> = readings.iter().collect();
    by_seq.sort_by_key(|r| r.seq);
    let mut spacings: Vec<f64> = by_seq
        .windows(2)
        .filter(|w| w[1].seq == w[0].seq + 1 && w[1].sweep_id == w[0].sweep_id)
        .map(|w| wrap_deg(f64::from(w[1].angle_deg) - f64::from(w[0].angle_deg)).abs())
        .filter(|d| *d > 1e-6)
        .collect();
    if spacings.len() < 2 {
        return None;
    }
    spacings.sort_by(f64::total_cmp);
    let spacing = spacings[spacings.len() / 2];
    let mut counts = [0usize; 256];
    for r in &by_seq {
        counts[usize::from(r.ping_count)] += 1;
    }
    let pings = (1..=255u8)
        .max_by_key(|&n| counts[usize::from(n)])
        .filter(|&n| counts[usize::from(n)] > 0)?;
    Some((spacing / f64::from(pings), pings))
}

/// The offset from the walls the sweeps saw (one per sweep) and the wall's true distance.
/// `quantum_m` is the sensor's range step, if it reports ranges rounded to one.
pub fn range_offset(
    sightings: &[WallSighting],
    true_distance_m: f64,
    quantum_m: Option<f64>,
) -> Result<RangeOffset, CalibrationError> {
    if !(true_distance_m.is_finite() && true_distance_m > 0.0) {
        return Err(CalibrationError::BadDistance(true_distance_m));
    }
    let first = sightings.first().ok_or(CalibrationError::NoSightings)?;
    // Normals about the first one's, so that a wall straight ahead (±180° wrapping) averages.
    let offsets: Vec<f64> = sightings
        .iter()
        .map(|s| wrap_deg(s.normal_deg - first.normal_deg))
        .collect();
    let (lo, hi) = offsets
        .iter()
        .fold((0.0f64, 0.0f64), |(lo, hi), &d| (lo.min(d), hi.max(d)));
    if hi - lo > SAME_WALL_DEG {
        return Err(CalibrationError::DifferentWalls {
            spread_deg: hi - lo,
        });
    }
    let n = sightings.len() as f64;
    let mean = sightings.iter().map(|s| s.distance_m).sum::<f64>() / n;
    let spread = if sightings.len() > 1 {
        (sightings
            .iter()
            .map(|s| (s.distance_m - mean).powi(2))
            .sum::<f64>()
            / (n - 1.0))
            .sqrt()
    } else {
        0.0
    };
    let pings_sigma = sightings.iter().map(|s| s.sigma_m).sum::<f64>() / n;
    let floor = quantum_m.map_or(0.0, |q| q / 12f64.sqrt());
    let offset_m = mean - true_distance_m;
    if offset_m.abs() > MOST_OFFSET_M {
        return Err(CalibrationError::Implausible {
            measured_m: mean,
            true_m: true_distance_m,
            offset_m,
        });
    }
    Ok(RangeOffset {
        offset_m,
        sigma_m: (spread.max(pings_sigma) / n.sqrt()).max(floor),
        sweeps: sightings.len(),
        normal_deg: wrap_deg(first.normal_deg + offsets.iter().sum::<f64>() / n),
    })
}

/// The walls seen so far, one per sweep looked at, and the range quantum the sweeps showed: what
/// the offset is measured from, sweep by sweep ([`Self::look`], [`Self::offset`]).
#[derive(Debug, Clone, Default)]
pub struct WallSightings {
    sightings: Vec<WallSighting>,
    quantum_m: Option<f64>,
}

impl WallSightings {
    /// Looks for the wall in one sweep's `readings` ([`wall_in_sweep`], the pings placed as `cfg`
    /// says) and keeps it; the wall, if the sweep saw it whole.
    pub fn look(
        &mut self,
        readings: &[Reading],
        cfg: &FeatureConfig,
        bearing_deg: Option<f64>,
    ) -> Result<Option<WallSighting>, CalibrationError> {
        let sweep = Sweep::from_readings(readings, cfg);
        self.quantum_m = self.quantum_m.or(sweep.range_quantum_m());
        let wall = wall_in_sweep(&sweep, cfg, bearing_deg)?;
        self.sightings.extend(wall);
        Ok(wall)
    }

    /// The walls kept, in the order seen.
    pub fn sightings(&self) -> &[WallSighting] {
        &self.sightings
    }

    /// The offset from the walls kept and the wall's true distance ([`range_offset`]).
    pub fn offset(&self, true_distance_m: f64) -> Result<RangeOffset, CalibrationError> {
        range_offset(&self.sightings, true_distance_m, self.quantum_m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pings::Ping;

    /// A standing sweep from −150° to 150° in `step` of a flat wall at `distance` whose normal
    /// lies at `normal` (degrees): every ping within the SRF05's 28° cut-off of the normal hears
    /// the wall's foot, `bias` added and jittered by `jitter` (a fixed pattern, so the test is
    /// exact), the others nothing.
    fn wall_sweep(distance: f64, normal: f64, bias: f64, jitter: f64, step: f64) -> Sweep {
        cut_off_wall_sweep(distance, normal, bias, jitter, step, 28.0)
    }

    /// [`wall_sweep`] with the specular cut-off `cutoff`.
    fn cut_off_wall_sweep(
        distance: f64,
        normal: f64,
        bias: f64,
        jitter: f64,
        step: f64,
        cutoff: f64,
    ) -> Sweep {
        let count = (300.0 / step) as usize + 1;
        let pings = (0..count)
            .map(|i| {
                let bearing_deg = -150.0 + step * i as f64;
                let heard = wrap_deg(bearing_deg - normal).abs() <= cutoff;
                let wiggle = jitter * [0.0, 1.0, -1.0, 0.5, -0.5][i % 5];
                Ping {
                    bearing_deg,
                    range_m: heard.then_some(distance + bias + wiggle),
                }
            })
            .collect();
        Sweep::from_pings(pings, step).expect("finite pings")
    }

    #[test]
    fn a_wall_heard_late_by_a_constant_gives_that_constant() {
        let cfg = FeatureConfig::default();
        let sightings: Vec<WallSighting> = [0.0, 0.3, -0.2]
            .iter()
            .map(|&turn| {
                let sweep = wall_sweep(1.2, 10.0 + turn, 0.012, 0.002, 1.5);
                wall_in_sweep(&sweep, &cfg, None)
                    .expect("valid configuration")
                    .expect("the wall is seen whole")
            })
            .collect();
        for s in &sightings {
            assert!((s.normal_deg - 10.0).abs() < 1.5, "{s:?}");
            assert!(s.pings >= 30, "{s:?}");
        }
        let offset = range_offset(&sightings, 1.2, None).expect("one wall, plausible");
        assert!((offset.offset_m - 0.012).abs() < 0.002, "{offset:?}");
        assert!(offset.sigma_m > 0.0 && offset.sigma_m < 0.002, "{offset:?}");
        assert_eq!(offset.sweeps, 3);
    }

    #[test]
    fn the_configured_offset_is_not_taken_off_what_it_measures() {
        let cfg = FeatureConfig {
            range_offset_m: 0.05,
            ..FeatureConfig::default()
        };
        let sweep = wall_sweep(0.8, -30.0, -0.03, 0.0, 1.5);
        let wall = wall_in_sweep(&sweep, &cfg, None)
            .expect("valid configuration")
            .expect("seen whole");
        assert!((wall.distance_m - 0.77).abs() < 1e-9, "{wall:?}");
    }

    #[test]
    fn the_wall_nearest_the_bearing_asked_for_is_taken() {
        // Two walls: one at 0.9 m ahead, one at 1.5 m to the left.
        let near = wall_sweep(0.9, 0.0, 0.0, 0.0, 1.5);
        let far = wall_sweep(1.5, 90.0, 0.0, 0.0, 1.5);
        let pings = near
            .pings()
            .iter()
            .zip(far.pings())
            .map(|(a, b)| Ping {
                bearing_deg: a.bearing_deg,
                range_m: a.range_m.or(b.range_m),
            })
            .collect();
        let both = Sweep::from_pings(pings, 1.5).expect("finite pings");
        let cfg = FeatureConfig::default();
        let nearest = wall_in_sweep(&both, &cfg, None)
            .expect("valid")
            .expect("seen");
        assert!((nearest.distance_m - 0.9).abs() < 1e-9, "{nearest:?}");
        let left = wall_in_sweep(&both, &cfg, Some(85.0))
            .expect("valid")
            .expect("seen");
        assert!((left.distance_m - 1.5).abs() < 1e-9, "{left:?}");
    }

    #[test]
    fn a_sweep_without_a_wall_seen_whole_gives_none() {
        // Nothing heard at all.
        let pings = (0..201)
            .map(|i| Ping {
                bearing_deg: -150.0 + 1.5 * f64::from(i),
                range_m: None,
            })
            .collect();
        let empty = Sweep::from_pings(pings, 1.5).expect("finite pings");
        let cfg = FeatureConfig::default();
        assert_eq!(wall_in_sweep(&empty, &cfg, None), Ok(None));
    }

    #[test]
    fn different_walls_a_wrong_distance_and_nothing_are_refused() {
        let at = |distance_m: f64, normal_deg: f64| WallSighting {
            distance_m,
            sigma_m: 0.001,
            normal_deg,
            pings: 30,
            half_width_deg: 28.0,
            classified: true,
        };
        assert!(matches!(
            range_offset(&[at(1.0, 0.0), at(1.0, 40.0)], 1.0, None),
            Err(CalibrationError::DifferentWalls { .. })
        ));
        assert!(matches!(
            range_offset(&[at(1.4, 0.0)], 1.0, None),
            Err(CalibrationError::Implausible { .. })
        ));
        assert_eq!(
            range_offset(&[], 1.0, None),
            Err(CalibrationError::NoSightings)
        );
        assert_eq!(
            range_offset(&[at(1.0, 0.0)], -1.0, None),
            Err(CalibrationError::BadDistance(-1.0))
        );
        // Normals either side of ±180° are one wall, averaged across the seam.
        let behind =
            range_offset(&[at(1.0, 179.0), at(1.0, -179.0)], 1.0, None).expect("one wall behind");
        assert!(
            wrap_deg(behind.normal_deg - 180.0).abs() < 1e-9,
            "{behind:?}"
        );
    }

    #[test]
    fn a_sensor_reporting_whole_centimetres_is_known_to_no_better_than_its_step() {
        let whole = |distance_m: f64| WallSighting {
            distance_m,
            sigma_m: 0.0,
            normal_deg: 0.0,
            pings: 10,
            half_width_deg: 20.0,
            classified: true,
        };
        let offset = range_offset(&[whole(0.97), whole(0.97), whole(0.97)], 1.0, Some(0.01))
            .expect("plausible");
        assert!((offset.offset_m + 0.03).abs() < 1e-9, "{offset:?}");
        assert!(
            (offset.sigma_m - 0.01 / 12f64.sqrt()).abs() < 1e-12,
            "{offset:?}"
        );
    }

    #[test]
    fn a_wall_narrower_than_configured_is_still_found_by_its_bearing_and_its_width_told() {
        // A sensor whose walls answer over ±20°, described as the SRF05 (±28°): not a wall to
        // the classifier, but the region seen whole where the person faced one.
        let sweep = cut_off_wall_sweep(1.0, 5.0, -0.02, 0.0, 1.5, 20.0);
        let cfg = FeatureConfig::default();
        assert_eq!(wall_in_sweep(&sweep, &cfg, None).expect("valid"), None);
        let wall = wall_in_sweep(&sweep, &cfg, Some(0.0))
            .expect("valid")
            .expect("the region faced");
        assert!(!wall.classified, "{wall:?}");
        assert!((wall.distance_m - 0.98).abs() < 1e-9, "{wall:?}");
        assert!((wall.normal_deg - 5.0).abs() < 1.0, "{wall:?}");
        assert!((wall.half_width_deg - 20.0).abs() <= 1.5, "{wall:?}");
        let expected = expected_half_width_deg(&cfg, 1.0).expect("a wall is heard at 1 m");
        assert!((expected - 28.0).abs() < 0.5, "{expected}");
        // Nothing whole within 10° of a bearing asked for: none.
        assert_eq!(
            wall_in_sweep(&sweep, &cfg, Some(60.0)).expect("valid"),
            None
        );
    }

    #[test]
    fn the_head_s_step_is_the_readings_spacing_over_their_pings() {
        let reading = |seq: u64, sweep_id: u32, angle_deg: f32, ping_count: u8| Reading {
            seq,
            sweep_id,
            angle_deg,
            ping_count,
            ..Reading::default()
        };
        // Two pings a reading, 6° apart, going clockwise, a sweep's turn and one lost reading.
        let readings: Vec<Reading> = (0..20u64)
            .filter(|&i| i != 7)
            .map(|i| reading(i, 3, 90.0 - 6.0 * i as f32, 2))
            .chain([reading(20, 4, -30.0, 2), reading(21, 4, -24.0, 1)])
            .collect();
        let (step, pings) = head_step_deg(&readings).expect("spacings");
        assert_eq!(pings, 2);
        assert!((step - 3.0).abs() < 1e-6, "{step}");
        assert_eq!(head_step_deg(&readings[..2]), None);
    }
}
