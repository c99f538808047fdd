//! The `[slam]` table of a pipeline configuration file: `enabled` (whether `sonar-pipeline`
//! starts `sonar-slam`) and every field of [`SlamConfig`], validated as it is read. `sonar-slam`
//! and the launcher read it the same way.
//!
//! The SLAM's feature extraction (`[slam.features]`) starts from the file's `[features]`, the
//! fusion's description of the head (its pings, its echoes' cones, its calibrated range offset),
//! with what `[slam.features]` sets on top ([`with_pipeline_features`]): one head, described once.

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

/// The fusion's switches in `[features]`, which are not the extraction's settings.
const FUSION_SWITCHES: [&str; 2] = ["enabled", "localize"];

/// `file` (a whole pipeline configuration file) with its `[slam.features]` table made of its
/// `[features]` table (less the fusion's `enabled` and `localize`) with what `[slam.features]`
/// sets laid over it, key by key, nested tables too. Without `[features]`, `file` as it is; a
/// `[slam]` that is not a table is left for its reading to refuse.
pub fn with_pipeline_features(mut file: toml::Table) -> toml::Table {
    let Some(toml::Value::Table(mut features)) = file.get("features").cloned() else {
        return file;
    };
    for switch in FUSION_SWITCHES {
        features.remove(switch);
    }
    let slam = file
        .entry("slam")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let toml::Value::Table(slam) = slam {
        if let Some(toml::Value::Table(own)) = slam.get("features") {
            overlay(&mut features, own);
        }
        slam.insert("features".into(), toml::Value::Table(features));
    }
    file
}

/// Lays `top` over `base`: its values replace `base`'s, its tables are laid over `base`'s.
fn overlay(base: &mut toml::Table, top: &toml::Table) {
    for (key, value) in top {
        match (base.get_mut(key), value) {
            (Some(toml::Value::Table(below)), toml::Value::Table(above)) => overlay(below, above),
            _ => {
                base.insert(key.clone(), value.clone());
            }
        }
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

    #[test]
    fn the_slam_describes_the_head_as_the_features_table_does_unless_told_otherwise() {
        #[derive(Debug, serde::Deserialize)]
        struct File {
            #[serde(default)]
            slam: SlamSection,
        }
        let read = |text: &str| -> SlamSection {
            let table: toml::Table = toml::from_str(text).unwrap_or_else(|e| panic!("{e}"));
            let file: File = with_pipeline_features(table)
                .try_into()
                .unwrap_or_else(|e| panic!("{e}"));
            file.slam
        };
        // The head's pings, its echoes and its calibrated offset, from [features]; the fusion's
        // switches left to it.
        let text = "[features]\nenabled = true\nlocalize = false\nrange_offset_m = -0.03\n\
                    [features.sensor]\nstep_deg = 3.0\npings_per_reading = 2\n\
                    [features.echo]\nspecular_cutoff_deg = 20.0\n\
                    [slam]\nenabled = true\n";
        let slam = read(text).config.features;
        assert_eq!(slam.range_offset_m, -0.03);
        assert_eq!(slam.sensor.step_deg, 3.0);
        assert_eq!(slam.sensor.pings_per_reading, 2);
        assert_eq!(slam.echo.specular_cutoff_deg, 20.0);
        // [slam.features] on top, key by key: its own odometry, the echo's other keys kept.
        let text = format!(
            "{text}[slam.features]\nrange_offset_m = -0.02\n[slam.features.echo]\n\
             threshold_db = -22.0\n[slam.features.odometry]\nscale_sigma = 0.01\n"
        );
        let slam = read(&text).config.features;
        assert_eq!(slam.range_offset_m, -0.02);
        assert_eq!(slam.echo.specular_cutoff_deg, 20.0);
        assert_eq!(slam.echo.threshold_db, -22.0);
        assert_eq!(slam.sensor.step_deg, 3.0);
        assert_eq!(slam.odometry.scale_sigma, 0.01);
        // No [features]: the library's defaults, as before; no [slam]: one is made for it.
        assert_eq!(
            read("[slam]\nenabled = true\n").config,
            SlamConfig::default()
        );
        let only_features = read("[features]\nrange_offset_m = 0.01\n");
        assert!(!only_features.enabled);
        assert_eq!(only_features.config.features.range_offset_m, 0.01);
        // A wrong key in [features] is refused as the SLAM reads it too.
        let table: toml::Table = toml::from_str("[features]\nrange_ofset_m = 0.01\n").unwrap();
        assert!(with_pipeline_features(table).try_into::<File>().is_err());
    }
}
