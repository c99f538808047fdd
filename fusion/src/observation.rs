//! What the kernels consume: one reading, placed in the world.

use nalgebra::{Isometry2, Vector2};
use sonar_common::ipc::{Reading, flags};

use crate::geometry::wrap_angle;

/// One reading of the rotating sensor, at the sensor's pose in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Pose of the sensor's rotation axis in the world; its x axis is the sensor's angle 0. The
    /// identity when the robot does not move (or no `robot/pose` service exists).
    pub pose: Isometry2<f32>,
    /// Beam centre, radians, counter-clockwise from the sensor's forward axis.
    pub angle_rad: f32,
    /// Measured range, metres; `None` when nothing echoed or the echo lay outside the sensor's range.
    pub range_m: Option<f32>,
    /// Without a range because the pings disagreed (the driver's `PINGS_REJECTED`), the nearest
    /// echo one of them heard within the sensor's range, metres: something was there. Between
    /// readings that heard a farther reflector, it cut that reflector's region short
    /// ([`crate::regions`]); the driver keeps a lone echo out of the range (a transient is as
    /// likely), and with two pings a reading (`nxt`) any reading across an edge has none.
    pub rejected_echo_m: Option<f32>,
    /// Half-width of the beam (the paper's ±30°), radians.
    pub beam_half_angle_rad: f32,
    /// Farthest range the sensor reports, metres (the paper's R).
    pub max_range_m: f32,
}

/// The nearest a calibrated range is placed, metres: an echo nearer than the sensor's calibrated
/// lateness is still an echo, at the sensor.
const NEAREST_CALIBRATED_M: f32 = 0.001;

impl Observation {
    /// This observation with the sensor's constant lateness `offset_m` (calibrated on a wall:
    /// `[features] range_offset_m`, negative for a sensor that reads short) taken off its range,
    /// as the features take it off their pings: one calibration for both maps.
    pub fn calibrated(self, offset_m: f32) -> Self {
        let calibrated = |r: f32| (r - offset_m).max(NEAREST_CALIBRATED_M);
        Self {
            range_m: self.range_m.map(calibrated),
            rejected_echo_m: self.rejected_echo_m.map(calibrated),
            ..self
        }
    }

    /// The reading as the driver published it, taken at `pose`. A reading flagged `NO_ECHO` or
    /// `OUT_OF_RANGE` carries no range: its distance is never used as an obstacle.
    pub fn from_reading(reading: &Reading, pose: Isometry2<f32>) -> Self {
        Self {
            pose,
            angle_rad: reading.angle_deg.to_radians(),
            range_m: reading.is_valid_range().then_some(reading.distance_m),
            rejected_echo_m: rejected_echo_m(reading),
            beam_half_angle_rad: reading.beam_half_angle_deg.to_radians(),
            max_range_m: reading.max_range_m,
        }
    }
}

/// [`Observation::rejected_echo_m`] of `reading` (a head that sends no raw pings has none). Each
/// ping's range as the features place pings (`sonar_features`' `placed_pings`, in f64 with
/// fallbacks for readings that carry no speed of sound).
fn rejected_echo_m(reading: &Reading) -> Option<f32> {
    if reading.is_valid_range()
        || !reading.has(flags::PINGS_REJECTED)
        || reading.has(flags::NO_RAW_PINGS)
    {
        return None;
    }
    let pings = usize::from(reading.ping_count).min(reading.echo_us.len());
    reading.echo_us[..pings]
        .iter()
        .filter(|&&t| t > 0)
        .map(|&t| 0.5e-6 * reading.speed_of_sound_mps * t as f32)
        .filter(|r| (reading.min_range_m..reading.max_range_m).contains(r))
        .reduce(f32::min)
}

/// An observation the kernels cannot place.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ObservationError {
    #[error("observation field {0} is not a finite number")]
    NotFinite(&'static str),
    #[error("observation field {0} must be positive")]
    NotPositive(&'static str),
}

/// Upper bounds on every observation: the cone the fast kernel's caches are built for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Limits {
    pub half_angle: f32,
    pub max_range: f32,
}

/// An observation made ready for a kernel: checked, clamped to the [`Limits`], and in world terms.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Beam {
    /// Sensor position in the world.
    pub position: Vector2<f32>,
    /// World bearing of the beam axis, in [−π, π].
    pub axis: f32,
    /// Half-width of the beam (the paper's β in our reading of it).
    pub half_angle: f32,
    /// The paper's R.
    pub max_range: f32,
    /// The measured range, or `None` to clear free space up to `max_range`.
    pub echo: Option<f32>,
}

impl Beam {
    /// The beam of `obs`, or `None` when it brings nothing to fuse: no echo while clearing on no
    /// echo is off (the paper ignores such readings).
    ///
    /// A range at or beyond the maximum range is treated as no echo: an SRF05 whose echo line times
    /// out reads the maximum, which is never an obstacle.
    pub fn new(
        obs: &Observation,
        limits: Limits,
        clear_on_no_echo: bool,
    ) -> Result<Option<Self>, ObservationError> {
        let finite = |v: f32, name| {
            if v.is_finite() {
                Ok(v)
            } else {
                Err(ObservationError::NotFinite(name))
            }
        };
        let positive = |v: f32, name| {
            if finite(v, name)? > 0.0 {
                Ok(v)
            } else {
                Err(ObservationError::NotPositive(name))
            }
        };
        let position = obs.pose.translation.vector;
        finite(position.x, "pose.x")?;
        finite(position.y, "pose.y")?;
        let heading = finite(obs.pose.rotation.angle(), "pose.rotation")?;
        let angle = finite(obs.angle_rad, "angle_rad")?;
        let half_angle = positive(obs.beam_half_angle_rad, "beam_half_angle_rad")?;
        let max_range = positive(obs.max_range_m, "max_range_m")?.min(limits.max_range);
        let echo = match obs.range_m {
            Some(d) => Some(positive(d, "range_m")?).filter(|&d| d < max_range),
            None => None,
        };
        if echo.is_none() && !clear_on_no_echo {
            return Ok(None);
        }
        Ok(Some(Self {
            position,
            axis: wrap_angle(heading + angle),
            half_angle: half_angle.min(limits.half_angle),
            max_range,
            echo,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: Limits = Limits {
        half_angle: 0.5,
        max_range: 4.0,
    };

    fn obs(range_m: Option<f32>) -> Observation {
        Observation {
            pose: Isometry2::identity(),
            angle_rad: 0.3,
            range_m,
            rejected_echo_m: None,
            beam_half_angle_rad: 0.6,
            max_range_m: 5.0,
        }
    }

    #[test]
    fn reading_flags_decide_whether_there_is_a_range() {
        let mut r = Reading {
            angle_deg: 90.0,
            distance_m: 1.5,
            beam_half_angle_deg: 30.0,
            max_range_m: 4.0,
            ..Default::default()
        };
        let o = Observation::from_reading(&r, Isometry2::identity());
        assert_eq!(o.range_m, Some(1.5));
        assert!((o.angle_rad - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        for flag in [flags::NO_ECHO, flags::OUT_OF_RANGE] {
            r.flags = flag;
            assert_eq!(
                Observation::from_reading(&r, Isometry2::identity()).range_m,
                None
            );
        }
    }

    #[test]
    fn a_reading_whose_pings_disagreed_keeps_the_nearest_echo_one_heard() {
        let v = 343.0;
        let us = |m: f32| (2.0 * m / v * 1e6).round() as u32;
        let mut r = Reading {
            flags: flags::NO_ECHO | flags::PINGS_REJECTED,
            speed_of_sound_mps: v,
            min_range_m: 0.03,
            max_range_m: 4.0,
            ping_count: 4,
            beam_half_angle_deg: 30.0,
            ..Default::default()
        };
        // A ping nearer than the sensor's minimum, one beyond its maximum, one silent: the
        // nearest in range is 1.2 m.
        r.echo_us[..5].copy_from_slice(&[us(0.01), us(2.5), 0, us(1.2), us(4.5)]);
        let o = Observation::from_reading(&r, Isometry2::identity());
        assert_eq!(o.range_m, None);
        let rejected = o.rejected_echo_m.unwrap();
        assert!((rejected - 1.2).abs() < 1e-3, "{rejected}");
        // Only the reading's own pings count (the fifth lies past its ping count), and
        // calibration takes the same offset off as off a range.
        assert!((o.calibrated(0.05).rejected_echo_m.unwrap() - 1.15).abs() < 1e-3);
        // Without the flag (nothing heard, or a range agreed on), or from a head that sends no raw
        // pings, there is none.
        r.flags = flags::NO_ECHO;
        assert_eq!(
            Observation::from_reading(&r, Isometry2::identity()).rejected_echo_m,
            None
        );
        r.flags = flags::NO_ECHO | flags::PINGS_REJECTED | flags::NO_RAW_PINGS;
        assert_eq!(
            Observation::from_reading(&r, Isometry2::identity()).rejected_echo_m,
            None
        );
        r.flags = flags::PINGS_REJECTED;
        r.distance_m = 2.5;
        let agreed = Observation::from_reading(&r, Isometry2::identity());
        assert_eq!((agreed.range_m, agreed.rejected_echo_m), (Some(2.5), None));
    }

    #[test]
    fn no_echo_is_ignored_unless_clearing() {
        assert_eq!(Beam::new(&obs(None), LIMITS, false), Ok(None));
        let b = Beam::new(&obs(None), LIMITS, true).unwrap().unwrap();
        assert_eq!(b.echo, None);
        // Clamped to the limits.
        assert_eq!(b.max_range, 4.0);
        assert_eq!(b.half_angle, 0.5);
    }

    #[test]
    fn a_range_at_max_range_is_no_obstacle() {
        assert_eq!(Beam::new(&obs(Some(4.0)), LIMITS, false), Ok(None));
        let b = Beam::new(&obs(Some(4.5)), LIMITS, true).unwrap().unwrap();
        assert_eq!(b.echo, None);
        let b = Beam::new(&obs(Some(3.9)), LIMITS, false).unwrap().unwrap();
        assert_eq!(b.echo, Some(3.9));
    }

    #[test]
    fn pose_turns_the_beam() {
        let mut o = obs(Some(1.0));
        o.pose = Isometry2::new(Vector2::new(1.0, 2.0), 3.0);
        let b = Beam::new(&o, LIMITS, false).unwrap().unwrap();
        assert!((b.axis - wrap_angle(3.3)).abs() < 1e-6);
        assert_eq!(b.position, Vector2::new(1.0, 2.0));
    }

    #[test]
    fn nonsense_is_rejected() {
        let mut o = obs(Some(f32::NAN));
        assert_eq!(
            Beam::new(&o, LIMITS, false),
            Err(ObservationError::NotFinite("range_m"))
        );
        o.range_m = Some(-1.0);
        assert_eq!(
            Beam::new(&o, LIMITS, false),
            Err(ObservationError::NotPositive("range_m"))
        );
        o.range_m = Some(1.0);
        o.beam_half_angle_rad = 0.0;
        assert_eq!(
            Beam::new(&o, LIMITS, false),
            Err(ObservationError::NotPositive("beam_half_angle_rad"))
        );
    }
}
