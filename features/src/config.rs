//! Configuration: the echo physics the expected widths come from, and the thresholds of
//! extraction, merging and segment assembly. Every default is documented with where it comes
//! from; [`FeatureConfig::validate`] refuses values that cannot describe a sensor.

use serde::{Deserialize, Serialize};
use sonar_common::sensor::SensorConfig;

use crate::error::FeatureError;
use crate::noise::NoiseConfig;
use crate::odometry::OdometryErrors;
use crate::physics::EchoPhysics;

/// How observations are merged into the map and how unconfirmed features fade.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MergeConfig {
    /// An observation refines a feature of its kind when the squared Mahalanobis distance of
    /// their difference is below this (2 degrees of freedom; 13.8 = 99.9 %).
    pub gate_chi2: f64,
    /// Confidence of a feature seen once.
    pub initial_confidence: f64,
    /// Each confirmation moves the confidence this share of the way to 1.
    pub confirm_gain: f64,
    /// Each sweep whose ping at the feature's bearing heard farther or nothing multiplies the
    /// confidence by this.
    pub miss_factor: f64,
    /// Features whose confidence falls below this are removed.
    pub remove_below: f64,
    /// Two point features this close, seen along rays more than [`Self::post_turn_deg`] apart,
    /// are one post seen from two places: its echo point (the surface nearest the sensor) moves
    /// round it, by up to its diameter.
    pub post_spread_m: f64,
    /// See [`Self::post_spread_m`].
    pub post_turn_deg: f64,
    /// Two corner features this close are one corner heard as two vertices, whatever the rays
    /// they were seen along (two concave corners 5 cm apart make a niche no sonar resolves).
    pub one_corner_m: f64,
    /// Two point features this close are one target, whatever the rays they were seen along: a
    /// thick post or a wall's end heard as two points (two posts this close make one echo).
    pub one_point_m: f64,
}

impl Default for MergeConfig {
    fn default() -> Self {
        Self {
            gate_chi2: 13.8,
            initial_confidence: 0.5,
            confirm_gain: 0.5,
            // From 0.5, three misses in a row remove a feature seen once; a long-confirmed one
            // (confidence near 1) goes after five.
            miss_factor: 0.7,
            remove_below: 0.2,
            // The thickest posts of the generated scenes are 10 cm across; from one place two
            // posts stand along rays a few degrees apart at most.
            post_spread_m: 0.10,
            post_turn_deg: 10.0,
            one_corner_m: 0.05,
            one_point_m: 0.05,
        }
    }
}

/// How partial planes are assembled into segments.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SegmentConfig {
    /// A support point (an occupied grid cell) belongs to a plane when it lies this close to its
    /// line: one and a half 2 cm cells.
    pub support_tolerance_m: f64,
    /// A segment grows along its line through support points no farther apart than this.
    pub max_gap_m: f64,
    /// A corner feature ends a plane when it lies this close to the plane's line.
    pub corner_tolerance_m: f64,
}

impl Default for SegmentConfig {
    fn default() -> Self {
        Self {
            support_tolerance_m: 0.03,
            max_gap_m: 0.10,
            corner_tolerance_m: 0.05,
        }
    }
}

/// Everything the feature pipeline needs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeatureConfig {
    /// The head: step between pings (1.5°), beam half-angle (±30°), range limits and the air
    /// temperature for readings that do not carry their speed of sound.
    pub sensor: SensorConfig,
    pub echo: EchoPhysics,
    /// Fewest pings a region of constant depth needs to become a feature: a transient is one
    /// ping, and even the weakest target the model hears (a 5 cm post at 2 m, ±9°) spans more
    /// than three.
    pub min_pings: u32,
    /// Subtracted from every range: the sensor's own constant lateness, metres (a detector that
    /// fires a cycle or two into the echo reads long). A property of one sensor: calibrate it
    /// against a wall at a known distance; 0 takes the ranges as they come.
    pub range_offset_m: f64,
    /// Uncertainty (1σ) of that offset, metres, shared by every range: a detector fires one or
    /// two cycles into the echo (4–9 mm at 40 kHz) and hobby sensors are often a centimetre or
    /// more off; left at 5 mm while the offset is not calibrated, so the reported uncertainty
    /// covers it. Lower it once the offset is measured.
    pub range_offset_sigma_m: f64,
    /// The range noise, estimated online from the pings ([`crate::noise`]).
    pub noise: NoiseConfig,
    /// Uncertainty (1σ) of every modelled cone half-angle: the specular cut-off and the effective
    /// cones. The simulator's are exact; on a real head measure them and raise this (sensor-facts
    /// only bounds the cut-off to 25–30°).
    pub cone_sigma_deg: f64,
    /// Relative systematic range error (1σ): the speed of sound's linear law is good to 0.2 %.
    pub range_sigma_rel: f64,
    pub merge: MergeConfig,
    pub segments: SegmentConfig,
    /// How the robot's odometry is expected to err, for localisation (`[features.odometry]`).
    pub odometry: OdometryErrors,
}

impl Default for FeatureConfig {
    fn default() -> Self {
        Self {
            sensor: SensorConfig::default(),
            echo: EchoPhysics::default(),
            min_pings: 3,
            range_offset_m: 0.0,
            range_offset_sigma_m: 0.005,
            noise: NoiseConfig::default(),
            cone_sigma_deg: 0.5,
            range_sigma_rel: 0.002,
            merge: MergeConfig::default(),
            segments: SegmentConfig::default(),
            odometry: OdometryErrors::default(),
        }
    }
}

fn check(ok: bool, what: &str) -> Result<(), FeatureError> {
    if ok {
        Ok(())
    } else {
        Err(FeatureError::Config(what.to_owned()))
    }
}

fn positive(value: f64, name: &str) -> Result<(), FeatureError> {
    check(
        value.is_finite() && value > 0.0,
        &format!("{name} must be > 0"),
    )
}

fn non_negative(value: f64, name: &str) -> Result<(), FeatureError> {
    check(
        value.is_finite() && value >= 0.0,
        &format!("{name} must be >= 0"),
    )
}

fn share(value: f64, name: &str) -> Result<(), FeatureError> {
    check(
        value > 0.0 && value < 1.0,
        &format!("{name} must be in (0, 1)"),
    )
}

impl FeatureConfig {
    pub fn validate(&self) -> Result<(), FeatureError> {
        self.sensor
            .validate()
            .map_err(|e| FeatureError::Config(e.to_string()))?;
        let e = &self.echo;
        check(
            e.beam_6db_half_angle_deg > 0.0 && e.beam_6db_half_angle_deg < 90.0,
            "echo.beam_6db_half_angle_deg must be in (0, 90)",
        )?;
        check(
            e.specular_cutoff_deg > 0.0 && e.specular_cutoff_deg <= 90.0,
            "echo.specular_cutoff_deg must be in (0, 90]",
        )?;
        non_negative(e.absorption_db_per_m, "echo.absorption_db_per_m")?;
        non_negative(e.tvg_db_per_m, "echo.tvg_db_per_m")?;
        non_negative(e.tvg_max_range_m, "echo.tvg_max_range_m")?;
        check(
            e.threshold_db.is_finite(),
            "echo.threshold_db must be a number",
        )?;
        non_negative(e.corner_loss_db, "echo.corner_loss_db")?;
        non_negative(e.threshold_jitter_db, "echo.threshold_jitter_db")?;
        positive(e.point_radius_m, "echo.point_radius_m")?;
        check(self.min_pings >= 1, "min_pings must be at least 1")?;
        check(
            self.range_offset_m.is_finite() && self.range_offset_m.abs() < 1.0,
            "range_offset_m must be within ±1 m",
        )?;
        non_negative(self.range_offset_sigma_m, "range_offset_sigma_m")?;
        let n = &self.noise;
        positive(n.floor_m, "noise.floor_m")?;
        non_negative(n.prior_sigma_m, "noise.prior_sigma_m")?;
        non_negative(n.prior_sigma_fraction, "noise.prior_sigma_fraction")?;
        check(
            n.gate_sigmas.is_finite() && n.gate_sigmas >= 1.0,
            "noise.gate_sigmas must be at least 1",
        )?;
        check(n.window >= 16, "noise.window must be at least 16")?;
        non_negative(self.cone_sigma_deg, "cone_sigma_deg")?;
        non_negative(self.range_sigma_rel, "range_sigma_rel")?;
        let m = &self.merge;
        positive(m.gate_chi2, "merge.gate_chi2")?;
        share(m.initial_confidence, "merge.initial_confidence")?;
        share(m.confirm_gain, "merge.confirm_gain")?;
        share(m.miss_factor, "merge.miss_factor")?;
        non_negative(m.one_corner_m, "merge.one_corner_m")?;
        non_negative(m.one_point_m, "merge.one_point_m")?;
        check(
            m.remove_below >= 0.0 && m.remove_below < m.initial_confidence,
            "merge.remove_below must be >= 0 and below merge.initial_confidence",
        )?;
        let s = &self.segments;
        positive(s.support_tolerance_m, "segments.support_tolerance_m")?;
        positive(s.max_gap_m, "segments.max_gap_m")?;
        positive(s.corner_tolerance_m, "segments.corner_tolerance_m")?;
        let o = &self.odometry;
        for (value, name) in [
            (o.scale_sigma, "odometry.scale_sigma"),
            (o.turn_sigma, "odometry.turn_sigma"),
        ] {
            check(
                value.is_finite() && (0.0..0.5).contains(&value),
                &format!("{name} must be in [0, 0.5)"),
            )?;
        }
        non_negative(o.drift_sigma_deg_per_m, "odometry.drift_sigma_deg_per_m")?;
        non_negative(
            o.position_noise_m_per_sqrt_m,
            "odometry.position_noise_m_per_sqrt_m",
        )?;
        non_negative(
            o.heading_noise_deg_per_sqrt_m,
            "odometry.heading_noise_deg_per_sqrt_m",
        )?;
        non_negative(
            o.turn_noise_deg_per_sqrt_rad,
            "odometry.turn_noise_deg_per_sqrt_rad",
        )
    }

    /// The stepper's angle between two pings, degrees.
    pub fn step_deg(&self) -> f64 {
        f64::from(self.sensor.step_deg)
    }

    /// Speed of sound at the configured air temperature, for readings that carry none.
    pub fn speed_of_sound_mps(&self) -> f64 {
        f64::from(self.sensor.speed_of_sound_mps())
    }

    /// The range error shared by every sweep at `range_m`, 1σ: the speed of sound's law and the
    /// sensor's offset.
    pub fn range_sigma_systematic_m(&self, range_m: f64) -> f64 {
        (self.range_sigma_rel * range_m).hypot(self.range_offset_sigma_m)
    }

    /// Tolerance on a width measured by pings `step_deg` apart: each end of a run is known to
    /// one step (the cone's edge lies between the last ping that heard the target and the first
    /// that did not), and each modelled cone edge to `cone_sigma_deg`, twice over for two ends.
    pub fn width_tolerance_deg(&self, step_deg: f64) -> f64 {
        step_deg + 2.0 * self.cone_sigma_deg
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_are_valid_and_nonsense_is_refused() {
        assert_eq!(FeatureConfig::default().validate(), Ok(()));
        let mut bad = FeatureConfig::default();
        bad.echo.point_radius_m = 0.0;
        let err = bad.validate().unwrap_err().to_string();
        assert!(err.contains("point_radius_m"), "{err}");
        let mut bad = FeatureConfig::default();
        bad.merge.remove_below = 0.6;
        assert!(bad.validate().is_err());
        let mut bad = FeatureConfig::default();
        bad.sensor.step_deg = -1.0;
        assert!(bad.validate().is_err());
        let mut bad = FeatureConfig::default();
        bad.echo.threshold_db = f64::NAN;
        assert!(bad.validate().is_err());
    }

    #[test]
    fn the_width_tolerance_follows_from_the_step_and_the_cones() {
        let cfg = FeatureConfig::default();
        assert!((cfg.width_tolerance_deg(cfg.step_deg()) - 2.5).abs() < 1e-9);
        assert!((cfg.width_tolerance_deg(3.0) - 4.0).abs() < 1e-9);
        let mut bad = FeatureConfig::default();
        bad.noise.gate_sigmas = 0.5;
        assert!(bad.validate().is_err());
    }

    #[test]
    fn a_toml_section_overrides_single_fields() {
        let cfg: FeatureConfig =
            toml::from_str("min_pings = 4\n[echo]\nspecular_cutoff_deg = 25.0\n").unwrap();
        assert_eq!(cfg.min_pings, 4);
        assert_eq!(cfg.echo.specular_cutoff_deg, 25.0);
        assert_eq!(cfg.echo.beam_6db_half_angle_deg, 27.0);
        assert!(toml::from_str::<FeatureConfig>("min_ping = 4\n").is_err());
    }
}
