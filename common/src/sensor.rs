//! The sensor head of the paper: an SRF05 on a stepper, and the physics that turns echo time into range.

use serde::{Deserialize, Serialize};

/// Geometry and limits of the rotating sensor head. Defaults are the paper's hardware (§II.A) and the
/// SRF05 datasheet (see `../shared/docs/sensor-facts.md`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorConfig {
    /// One stepper step at the shaft: 7.5° motor step through the 1:5 gear.
    pub step_deg: f32,
    /// Pings taken at consecutive steps and combined into one reading (4 × 1.5° = 6°).
    pub pings_per_reading: u8,
    /// Limit switch at the clockwise end of the 300° sweep.
    pub sweep_min_deg: f32,
    /// Limit switch at the counter-clockwise end.
    pub sweep_max_deg: f32,
    /// Half of the beam width used for mapping (the paper's ±30°).
    pub beam_half_angle_deg: f32,
    /// Closest range the SRF05 reports (≈ 3 cm).
    pub min_range_m: f32,
    /// Farthest range (4 m); the echo line drops after `echo_timeout_us` without an echo.
    pub max_range_m: f32,
    /// The SRF05 ends the echo pulse after ≈ 30 ms when nothing returns.
    pub echo_timeout_us: u32,
    /// Air temperature, for the speed of sound.
    pub air_temperature_c: f32,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self {
            step_deg: 1.5,
            pings_per_reading: 4,
            sweep_min_deg: -150.0,
            sweep_max_deg: 150.0,
            beam_half_angle_deg: 30.0,
            min_range_m: 0.03,
            max_range_m: 4.0,
            echo_timeout_us: 30_000,
            air_temperature_c: 20.0,
        }
    }
}

/// A configuration value that cannot describe a real sensor.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid sensor configuration: {0}")]
pub struct SensorConfigError(pub String);

impl SensorConfig {
    /// Angle covered by one reading (6° by default).
    pub fn reading_span_deg(&self) -> f32 {
        self.step_deg * f32::from(self.pings_per_reading)
    }

    /// Centre angles of the readings of a full sweep, in increasing order.
    ///
    /// The sweep is cut into whole readings from the clockwise limit: reading `k` covers
    /// `[min + k·span, min + (k+1)·span]` and its pings sit at the steps inside, half a step in from
    /// the edges, so both directions produce the same centres.
    pub fn reading_centres_deg(&self) -> Vec<f32> {
        let span = self.reading_span_deg();
        let count = ((self.sweep_max_deg - self.sweep_min_deg) / span + 1e-3).floor() as usize;
        (0..count)
            .map(|k| self.sweep_min_deg + span * (k as f32 + 0.5))
            .collect()
    }

    /// Speed of sound at the configured air temperature.
    pub fn speed_of_sound_mps(&self) -> f32 {
        speed_of_sound_mps(self.air_temperature_c)
    }

    /// Echo time of a target at `range_m` (round trip).
    pub fn echo_time_us(&self, range_m: f32) -> f32 {
        2.0 * range_m / self.speed_of_sound_mps() * 1e6
    }

    /// Range of an echo that took `echo_us` for the round trip: d = V·t/2.
    pub fn range_m(&self, echo_us: f32) -> f32 {
        self.speed_of_sound_mps() * echo_us * 1e-6 / 2.0
    }

    pub fn validate(&self) -> Result<(), SensorConfigError> {
        let fail = |m: &str| Err(SensorConfigError(m.to_owned()));
        if !(self.step_deg > 0.0 && self.step_deg <= 45.0) {
            return fail("step_deg must be in (0, 45]");
        }
        if self.pings_per_reading == 0
            || usize::from(self.pings_per_reading) > crate::protocol::MAX_PINGS_PER_READING
        {
            return fail("pings_per_reading must be between 1 and 8");
        }
        if !(self.sweep_min_deg < self.sweep_max_deg
            && self.sweep_max_deg - self.sweep_min_deg <= 360.0)
        {
            return fail("sweep_min_deg must be below sweep_max_deg, at most 360° apart");
        }
        if self.sweep_max_deg - self.sweep_min_deg < self.reading_span_deg() {
            return fail("the sweep is narrower than one reading");
        }
        if !(self.beam_half_angle_deg > 0.0 && self.beam_half_angle_deg < 90.0) {
            return fail("beam_half_angle_deg must be in (0, 90)");
        }
        if !(self.min_range_m >= 0.0 && self.min_range_m < self.max_range_m) {
            return fail("min_range_m must be >= 0 and below max_range_m");
        }
        if !(-40.0..=60.0).contains(&self.air_temperature_c) {
            return fail("air_temperature_c must be within -40..60 °C");
        }
        if self.echo_time_us(self.max_range_m) > self.echo_timeout_us as f32 {
            return fail("echo_timeout_us is shorter than the echo time at max_range_m");
        }
        Ok(())
    }
}

/// The air temperature flag of every program that turns echo times into ranges or back (driver,
/// simulator, firmware simulator): one definition, so name, unit, default and range agree.
#[derive(Debug, Clone, Copy, clap::Args)]
pub struct AirTemperatureArg {
    /// Air temperature in °C, which sets the speed of sound (331.3 + 0.606·T m/s). Named as the
    /// file's `[sensor]` key; `--air-temperature` still works.
    #[arg(
        long = "air-temperature-c",
        value_name = "CELSIUS",
        alias = "air-temperature",
        default_value_t = 20.0,
        allow_hyphen_values = true
    )]
    pub air_temperature_c: f32,
}

/// Speed of sound in air, V = 331.3 + 0.606·T m/s (T in °C), the linear law the paper's PC software
/// would use; good to 0.2 % over ±30 °C against the exact 331.3·√(1 + T/273.15).
pub fn speed_of_sound_mps(air_temperature_c: f32) -> f32 {
    331.3 + 0.606 * air_temperature_c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speed_of_sound_matches_exact_law_within_two_tenths_of_a_percent() {
        for t in [-30.0f32, 0.0, 20.0, 30.0] {
            let exact = 331.3 * (1.0 + t / 273.15).sqrt();
            assert!((speed_of_sound_mps(t) - exact).abs() / exact < 2e-3, "{t}");
        }
        assert!((speed_of_sound_mps(20.0) - 343.42).abs() < 0.01);
    }

    #[test]
    fn datasheet_rule_of_thumb_58_us_per_cm() {
        let cfg = SensorConfig::default();
        assert!((cfg.range_m(5800.0) - 0.9959).abs() < 1e-3);
        assert!((cfg.range_m(cfg.echo_time_us(1.234)) - 1.234).abs() < 1e-5);
    }

    #[test]
    fn full_sweep_has_fifty_readings_six_degrees_apart() {
        let centres = SensorConfig::default().reading_centres_deg();
        assert_eq!(centres.len(), 50);
        assert_eq!(centres[0], -147.0);
        assert_eq!(centres[49], 147.0);
        assert!(centres.windows(2).all(|w| (w[1] - w[0] - 6.0).abs() < 1e-4));
    }

    #[test]
    fn default_is_valid_and_nonsense_is_not() {
        assert_eq!(SensorConfig::default().validate(), Ok(()));
        let bad = [
            SensorConfig {
                step_deg: -1.0,
                ..Default::default()
            },
            SensorConfig {
                pings_per_reading: 9,
                ..Default::default()
            },
            SensorConfig {
                sweep_min_deg: 10.0,
                sweep_max_deg: 0.0,
                ..Default::default()
            },
            SensorConfig {
                max_range_m: 6.0,
                ..Default::default()
            },
        ];
        for cfg in bad {
            assert!(cfg.validate().is_err(), "{cfg:?}");
        }
    }
}
