//! A sensor's range offset measured in the simulator the way a robot builder measures it on the
//! robot: `sonar calibrate-range` with the head standing still, facing a flat wall at a known
//! distance ([`sonar_features::calibrate`]).
//!
//! The head stands at the centre of the built-in `room` scene, its wall 1.20 m ahead (the
//! command `docs/features.md` shows), and sweeps [`SWEEPS`] times with the sensor under test;
//! each sweep's wall at bearing 0 gives a distance and [`WallSightings::offset`] their offset.
//! Nothing of the scene under evaluation is used, and the offset is what the sensor shows, not
//! what its profile was written with: an evaluation that takes it off the ranges is calibrated
//! as the robot would be, no better.

use anyhow::{Context, Result, bail};
use sonar_features::{RangeOffset, WallSightings};
use sonar_sim::Scene;

use crate::features::scene_feature_config;
use crate::pipeline::{Head, Scan, capture_with};

/// The built-in room's wall ahead of its centre: its perpendicular distance, metres.
pub const WALL_DISTANCE_M: f64 = 1.2;

/// Sweeps measured over, as `sonar calibrate-range` does by default.
pub const SWEEPS: u32 = 3;

/// The echo noise's seed of the calibration sweeps (no evaluated run uses the room).
pub const SEED: u64 = 1;

/// The range offset of the sensor `sensor` puts on a scene (its profile, its noise), measured
/// in the built-in room with the echo noise seeded by `seed`.
pub fn measured_range_offset(sensor: impl FnOnce(&mut Scene), seed: u64) -> Result<RangeOffset> {
    let mut room = Scene::builtin("room").context("loading the built-in room")?;
    sensor(&mut room);
    let cfg = scene_feature_config(&room);
    let capture = capture_with(room.clone(), Head::of(&room), Scan::Full, SWEEPS, seed)
        .context("sweeping the calibration room")?;
    let mut sightings = WallSightings::default();
    for readings in capture.readings.chunk_by(|a, b| a.sweep_id == b.sweep_id) {
        sightings.look(readings, &cfg, Some(0.0))?;
    }
    if sightings.sightings().is_empty() {
        bail!(
            "no sweep of {} in the calibration room heard its wall {WALL_DISTANCE_M} m ahead whole",
            capture.sweeps
        );
    }
    Ok(sightings.offset(WALL_DISTANCE_M)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_sim::SensorProfile;

    /// The profile that reads 3 cm short in whole centimetres is measured so, less the
    /// simulator's detector lateness (4–5 mm long), as `sonar calibrate-range` measured it
    /// through the real pipeline (−0.024 m).
    #[test]
    fn a_sensor_reading_short_is_measured_short() {
        let offset = measured_range_offset(|s| s.set_profile(SensorProfile::Nxt), 1).unwrap();
        assert!((-0.035..=-0.015).contains(&offset.offset_m), "{offset:?}");
        assert_eq!(offset.sweeps, SWEEPS as usize);
    }

    /// Without a profile the simulator's ranges are late by its detector's lateness only.
    #[test]
    fn the_default_sensor_reads_a_few_millimetres_long() {
        let offset = measured_range_offset(|_| {}, 1).unwrap();
        assert!((0.0..=0.01).contains(&offset.offset_m), "{offset:?}");
    }
}
