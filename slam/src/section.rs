//! The `[slam]` table of a pipeline configuration file: `enabled` (whether `sonar-pipeline`
//! starts `sonar-slam`) and every field of [`SlamConfig`], validated as it is read. `sonar-slam`
//! and the launcher read it the same way.

use serde::de::Error as _;
use serde::{Deserialize, Deserializer};

use crate::estimator::SlamConfig;

#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SlamSection {
    /// `sonar-pipeline` starts `sonar-slam` and has the fusion place its readings with its
    /// correction (default false).
    pub enabled: bool,
    pub config: SlamConfig,
}

impl<'de> Deserialize<'de> for SlamSection {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        // `flatten` would lose `deny_unknown_fields`: the switch is split off by key and the rest
        // read as the SLAM's settings, which refuse what they do not know.
        let mut table = toml::Table::deserialize(deserializer)?;
        let enabled = match table.remove("enabled") {
            None => false,
            Some(toml::Value::Boolean(b)) => b,
            Some(other) => {
                return Err(D::Error::custom(format!(
                    "slam.enabled must be true or false, got {other}"
                )));
            }
        };
        let config: SlamConfig = table.try_into().map_err(D::Error::custom)?;
        config.validate().map_err(D::Error::custom)?;
        Ok(Self { enabled, config })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_slam_table_is_off_by_default_and_checked() {
        let parse = |text: &str| toml::from_str::<SlamSection>(text);
        assert_eq!(parse("").ok(), Some(SlamSection::default()));
        let on = parse(
            "enabled = true\nfix_max_sigma_m = 0.08\n[features.odometry]\nscale_sigma = 0.01\n",
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert!(on.enabled);
        assert_eq!(on.config.fix_max_sigma_m, 0.08);
        assert_eq!(on.config.features.odometry.scale_sigma, 0.01);
        for bad in [
            "enabled = 1",
            "fix_max_sigma = 0.1",
            "gate_chi2 = -1.0",
            "joint_probability = 1.5",
        ] {
            assert!(parse(bad).is_err(), "{bad}");
        }
        let typo = parse("gate = 9.0\n")
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(typo.contains("gate"), "{typo}");
    }
}
