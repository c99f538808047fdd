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
//! A constant is all one wall can tell. A scale error (the speed of sound, 0.17 % per °C of a
//! wrong air temperature) grows with the range: two walls at different distances would tell it
//! apart; here it is the air temperature's to get right.

use crate::config::FeatureConfig;
use crate::error::FeatureError;
use crate::feature::FeatureKind;
use crate::geometry::wrap_deg;
use crate::map::FeatureMap;
use crate::pings::Sweep;

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
/// whose normal lies nearest `bearing_deg`, or without it the nearest wall. `cfg`'s range offset
/// is not applied (it is what is measured). `None` when the sweep saw no wall whole.
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
        .map(|o| WallSighting {
            distance_m: o.range_m,
            sigma_m: o.range_sigma_random_m,
            normal_deg: o.bearing_deg,
            pings: rcds[o.rcd].pings,
        });
    let chosen = match bearing_deg {
        Some(b) => walls.min_by(|x, y| {
            let off = |w: &WallSighting| wrap_deg(w.normal_deg - b).abs();
            off(x).total_cmp(&off(y))
        }),
        None => walls.min_by(|x, y| x.distance_m.total_cmp(&y.distance_m)),
    };
    Ok(chosen)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pings::Ping;

    /// A standing sweep from −150° to 150° in `step` of a flat wall at `distance` whose normal
    /// lies at `normal` (degrees): every ping within `cutoff` of the normal hears the wall's foot,
    /// `bias` added and jittered by `jitter` (a fixed pattern, so the test is exact), the others
    /// nothing.
    fn wall_sweep(distance: f64, normal: f64, bias: f64, jitter: f64, step: f64) -> Sweep {
        let cutoff = 28.0;
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
        };
        let offset = range_offset(&[whole(0.97), whole(0.97), whole(0.97)], 1.0, Some(0.01))
            .expect("plausible");
        assert!((offset.offset_m + 0.03).abs() < 1e-9, "{offset:?}");
        assert!(
            (offset.sigma_m - 0.01 / 12f64.sqrt()).abs() < 1e-12,
            "{offset:?}"
        );
    }
}
