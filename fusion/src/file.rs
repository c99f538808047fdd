//! The tables of a pipeline configuration file that the fusion reads (`[fusion]`, with the map's
//! persistence keys, and `[features]`), read the same way by `sonar-fusion` and the offline
//! `sonar-export`.

use std::path::{Path, PathBuf};

use serde::de::Error as _;
use serde::{Deserialize, Deserializer};
use sonar_features::FeatureConfig;

use crate::config::FusionConfig;
use crate::persist::PersistConfig;

/// The `[fusion]` table of a pipeline configuration file: the engine's settings and, in the same
/// table, where and how often its map is saved (the keys of [`PersistConfig`]). Unknown keys are
/// errors, as everywhere in the file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FusionSection {
    pub engine: FusionConfig,
    pub persistence: PersistConfig,
    /// `slam_correction = true`: readings are placed with `sonar-slam`'s correction of the
    /// odometry (`sonar/slam_correction`) instead of the fusion's own localisation.
    pub slam_correction: bool,
}

impl<'de> Deserialize<'de> for FusionSection {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        // serde's `flatten` cannot be combined with `deny_unknown_fields`, so the table is split
        // by key and each part read with its own type, which refuses what it does not know.
        let mut engine = toml::Table::deserialize(deserializer)?;
        let mut persistence = toml::Table::new();
        for key in PersistConfig::KEYS {
            if let Some(value) = engine.remove(key) {
                persistence.insert(key.to_owned(), value);
            }
        }
        let slam_correction = match engine.remove("slam_correction") {
            None => false,
            Some(toml::Value::Boolean(b)) => b,
            Some(other) => {
                return Err(D::Error::custom(format!(
                    "fusion.slam_correction must be true or false, got {other}"
                )));
            }
        };
        Ok(Self {
            engine: engine.try_into().map_err(D::Error::custom)?,
            persistence: persistence.try_into().map_err(D::Error::custom)?,
            slam_correction,
        })
    }
}

/// The tables of a pipeline configuration file that the fusion reads, `[fusion]` and
/// `[features]`; the other programs' tables are left to them. `sonar-fusion` and the offline
/// `sonar-export` read the same file the same way, so an export fuses as the pipeline did.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
pub struct FusionFile {
    #[serde(default)]
    pub fusion: FusionSection,
    #[serde(default)]
    pub features: FeaturesSection,
    /// Whether the pipeline runs `sonar-slam` (`[slam] enabled`; the table's other keys are
    /// sonar-slam's own and left to it).
    #[serde(default)]
    pub slam: SlamSwitch,
}

/// `enabled` of the `[slam]` table: `sonar-pipeline` then starts `sonar-slam` and the fusion places
/// its readings with its correction, as with `[fusion] slam_correction = true`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SlamSwitch {
    pub enabled: bool,
}

impl<'de> Deserialize<'de> for SlamSwitch {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let table = toml::Table::deserialize(deserializer)?;
        match table.get("enabled") {
            None => Ok(Self::default()),
            Some(toml::Value::Boolean(enabled)) => Ok(Self { enabled: *enabled }),
            Some(other) => Err(D::Error::custom(format!(
                "slam.enabled must be true or false, got {other}"
            ))),
        }
    }
}

impl FusionFile {
    /// Whether the readings are placed with `sonar-slam`'s correction: `[fusion]
    /// slam_correction = true`, or `[slam] enabled = true` (the pipeline runs sonar-slam).
    pub fn slam_correction(&self) -> bool {
        self.fusion.slam_correction || self.slam.enabled
    }
}

/// A configuration file that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum FusionFileError {
    #[error("cannot read config file {}", .path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// toml's message, placed at the offending value where it can be
    /// (`sonar_common::toml_file`).
    #[error("invalid config file {}: {message}", .path.display())]
    Parse { path: PathBuf, message: String },
}

impl FusionFile {
    /// The file at `path`, or the defaults without one.
    pub fn read(path: Option<&Path>) -> Result<Self, FusionFileError> {
        path.map_or_else(|| Ok(Self::default()), Self::load)
    }

    pub fn load(path: &Path) -> Result<Self, FusionFileError> {
        let text = std::fs::read_to_string(path).map_err(|source| FusionFileError::Read {
            path: path.to_owned(),
            source,
        })?;
        sonar_common::toml_file::parse(&text).map_err(|message| FusionFileError::Parse {
            path: path.to_owned(),
            message,
        })
    }
}

/// The `[features]` table of a pipeline configuration file: `enabled` (default true) and every
/// parameter of [`FeatureConfig`] (its fields, as nested tables: `[features.echo]`, …).
#[derive(Debug, Clone, PartialEq)]
pub struct FeaturesSection {
    /// Whether `sonar-fusion` extracts features and publishes `sonar/features`.
    pub enabled: bool,
    /// Whether each sweep is localised against the features to correct the odometry of
    /// `robot/pose` (needs `enabled`).
    pub localize: bool,
    pub config: FeatureConfig,
}

impl Default for FeaturesSection {
    fn default() -> Self {
        Self {
            enabled: true,
            localize: false,
            config: FeatureConfig::default(),
        }
    }
}

impl<'de> Deserialize<'de> for FeaturesSection {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        // As for [`FusionSection`]: `flatten` would lose `deny_unknown_fields`.
        let mut table = toml::Table::deserialize(deserializer)?;
        let mut switch = |key: &str, default: bool| match table.remove(key) {
            None => Ok(default),
            Some(toml::Value::Boolean(b)) => Ok(b),
            Some(other) => Err(D::Error::custom(format!(
                "features.{key} must be true or false, got {other}"
            ))),
        };
        let enabled = switch("enabled", true)?;
        let localize = switch("localize", false)?;
        let config: FeatureConfig = table.try_into().map_err(D::Error::custom)?;
        config.validate().map_err(D::Error::custom)?;
        Ok(Self {
            enabled,
            localize,
            config,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pipeline_running_sonar_slam_places_the_readings_with_its_correction() {
        let file = |text: &str| toml::from_str::<FusionFile>(text);
        assert!(!file("").unwrap().slam_correction());
        // sonar-slam's own keys are its business, not the fusion's.
        let slam = file(
            "[slam]\nenabled = true\ngate_chi2 = 9.0\n[slam.features.odometry]\nscale_sigma = 0.01\n",
        );
        assert!(slam.unwrap().slam_correction());
        assert!(!file("[slam]\nenabled = false\n").unwrap().slam_correction());
        assert!(
            file("[fusion]\nslam_correction = true\n")
                .unwrap()
                .slam_correction()
        );
        assert!(file("[slam]\nenabled = \"yes\"\n").is_err());
    }

    #[test]
    fn the_fusion_table_holds_the_engine_and_the_persistence_keys() {
        let section: FusionSection = toml::from_str(
            "clear_on_no_echo = true\nstate_file = \"/var/lib/sonar/map.bin\"\nsave_period = 2.5\n\
             persist = false\n[grid]\ncells = 100\n",
        )
        .unwrap();
        assert!(section.engine.clear_on_no_echo);
        assert_eq!(section.engine.grid.cells, 100);
        assert_eq!(
            section.persistence,
            PersistConfig {
                persist: false,
                state_file: Some("/var/lib/sonar/map.bin".into()),
                save_period: 2.5,
            }
        );
        let empty: FusionSection = toml::from_str("").unwrap();
        assert_eq!(empty, FusionSection::default());
        assert!(!section.slam_correction);
        let slam: FusionSection = toml::from_str("slam_correction = true\n").unwrap();
        assert!(slam.slam_correction);
        assert_eq!(slam.engine, FusionConfig::default());
        for bad in [
            "save_periode = 1.0",
            "[grid]\nsize = 3",
            "persist = \"yes\"",
            "slam_correction = 1",
        ] {
            assert!(toml::from_str::<FusionSection>(bad).is_err(), "{bad}");
        }
        // Every persistence key is split off, and no engine setting shares a name with one.
        let keys: Vec<String> = toml::Table::try_from(PersistConfig {
            state_file: Some("x".into()),
            ..PersistConfig::default()
        })
        .unwrap()
        .keys()
        .cloned()
        .collect();
        let mut expected = PersistConfig::KEYS.map(str::to_owned).to_vec();
        expected.sort();
        assert_eq!(keys, expected);
        let engine_keys = toml::Table::try_from(FusionConfig::default()).unwrap();
        assert!(
            PersistConfig::KEYS
                .iter()
                .all(|k| !engine_keys.contains_key(*k))
        );
    }

    /// `examples/sonar.toml` shows the persistence keys commented out; uncommented, they are the
    /// keys `sonar-fusion` reads.

    #[test]
    fn the_persistence_keys_of_the_example_configuration_parse() {
        #[derive(Deserialize)]
        struct File {
            fusion: FusionSection,
        }
        let example = include_str!("../../examples/sonar.toml");
        let uncommented: String = example
            .lines()
            .map(|line| match line.strip_prefix("# ") {
                Some(rest) if PersistConfig::KEYS.iter().any(|k| rest.starts_with(k)) => rest,
                _ => line,
            })
            .flat_map(|line| [line, "\n"])
            .collect();
        let section = toml::from_str::<File>(&uncommented).unwrap().fusion;
        assert_eq!(
            section.persistence,
            PersistConfig {
                persist: true,
                state_file: Some("/var/lib/sonar/fusion-map.bin".into()),
                save_period: 5.0,
            }
        );
        assert_eq!(section.engine, FusionConfig::default());
    }

    #[test]
    fn the_features_table_is_checked_and_enabled_by_default() {
        let parse = |text: &str| toml::from_str::<FeaturesSection>(text);
        assert_eq!(parse("").unwrap(), FeaturesSection::default());
        let off = parse("enabled = false\nmin_pings = 4\nlocalize = true\n").unwrap();
        assert!(!off.enabled && off.localize);
        assert_eq!(off.config.min_pings, 4);
        let typo = parse("min_ping = 4\n").unwrap_err().to_string();
        assert!(typo.contains("min_ping"), "{typo}");
        assert!(parse("enabled = 1\n").is_err());
        let invalid = parse("range_margin_m = -1.0\n").unwrap_err().to_string();
        assert!(invalid.contains("range_margin_m"), "{invalid}");
        // The odometry's expected errors, for localisation.
        let calibrated = parse("[odometry]\nscale_sigma = 0.01\n").unwrap();
        assert_eq!(calibrated.config.odometry.scale_sigma, 0.01);
        assert_eq!(
            calibrated.config.odometry.drift_sigma_deg_per_m,
            FeatureConfig::default().odometry.drift_sigma_deg_per_m
        );
        let wild = parse("[odometry]\nscale_sigma = 0.7\n")
            .unwrap_err()
            .to_string();
        assert!(wild.contains("odometry.scale_sigma"), "{wild}");
        let typo = parse("[odometry]\nscale = 0.01\n").unwrap_err().to_string();
        assert!(typo.contains("scale"), "{typo}");
    }
}
