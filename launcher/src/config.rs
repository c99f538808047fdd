//! The pipeline's one configuration: a TOML file (see `examples/sonar.toml`), overridden by the
//! launcher's flags and their environment variables, turned into each process's command line.
//!
//! The launcher passes a process only the settings the user gave, so every default lives in one
//! place: the process that uses it. The `[fusion]` table is validated here, before anything starts,
//! and handed to `sonar-fusion` as the same file.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;
use sonar_fusion::{FeaturesSection, FusionSection};
use sonar_slam::SlamSection;

/// How long a process that died waits for its first restart.
pub const DEFAULT_RESTART_DELAY: Duration = Duration::from_secs(1);

/// A configuration file the pipeline cannot start with.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("invalid configuration in {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("invalid [fusion] settings in {path}: {source}")]
    Fusion {
        path: PathBuf,
        source: sonar_fusion::ConfigError,
    },
}

/// The file's tables. Every key is optional; unknown keys are errors (a typo must not be ignored).
#[derive(Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PipelineFile {
    pub iceoryx2: Iceoryx2Section,
    pub serial: SerialSection,
    pub sensor: SensorSection,
    pub simulator: SimulatorSection,
    /// `sonar-fusion` reads this table from the same file.
    pub fusion: FusionSection,
    /// `sonar-fusion` reads this table too (walls, corners and posts; validated as it is read).
    pub features: FeaturesSection,
    /// `sonar-slam` reads this table from the same file (validated as it is read); with
    /// `enabled = true` the launcher starts it and has the fusion take its correction.
    pub slam: SlamSection,
    pub viewer: ViewerSection,
    pub foxglove: FoxgloveSection,
    pub launcher: LauncherSection,
    /// `sonar-bridge` reads and validates this table from the same file (zenoh stays out of the
    /// launcher); the launcher only looks at `enabled`.
    pub bridge: toml::Table,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Iceoryx2Section {
    /// Prefix of the shared-memory names: separates pipelines on one machine.
    pub prefix: Option<String>,
    /// Directory of iceoryx2's service and node files.
    pub root: Option<PathBuf>,
    /// A full iceoryx2 configuration file instead.
    pub config: Option<PathBuf>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SerialSection {
    /// The sensor head's serial device; without it the simulator runs instead.
    pub port: Option<PathBuf>,
    pub baud: Option<u32>,
    /// `native` or `hobby`.
    pub dialect: Option<String>,
    /// `full`, `none` or `FROM..TO` degrees.
    pub scan: Option<String>,
    /// The hobby dialect's distance for "no echo": `0`, cm (`255`) or cm and beyond (`400+`).
    pub no_echo: Option<String>,
    /// Play of the head's gears, degrees (`sonar-driver --backlash-deg`).
    pub backlash_deg: Option<f32>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorSection {
    pub air_temperature_c: Option<f32>,
    pub beam_half_angle_deg: Option<f32>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimulatorSection {
    /// Built-in scene (`room`, `corner`, `obstacle`, `two-obstacles`) or scene file.
    pub scene: Option<String>,
    /// Speed factor or `max`.
    pub speed: Option<String>,
    pub seed: Option<u64>,
}

#[derive(Debug, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ViewerSection {
    /// Start the terminal viewer in front (off for a robot started at boot).
    pub enabled: bool,
    /// `map`, `radar` or `split`.
    pub view: Option<String>,
    /// `auto`, `truecolor`, `256`, `16` or `none` (the viewer's `--color`).
    pub color: Option<String>,
}

impl Default for ViewerSection {
    fn default() -> Self {
        Self {
            enabled: true,
            view: None,
            color: None,
        }
    }
}

/// `sonar-foxglove`, the live view in Foxglove (docs/foxglove.md); unset keys keep its defaults.
#[derive(Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FoxgloveSection {
    /// Start it with the pipeline.
    pub enabled: bool,
    /// Address it listens on (127.0.0.1 unless set; the protocol has no authentication).
    pub host: Option<String>,
    /// TCP port (8765 unless set).
    pub port: Option<u16>,
    /// Seconds between maps sent (1 unless set).
    pub grid_period: Option<f64>,
}

impl FoxgloveSection {
    /// `grid_period` as `sonar-foxglove --grid-period` takes it: a positive number of seconds.
    fn check(&self) -> Result<(), String> {
        match self.grid_period {
            Some(s) if !(s.is_finite() && s > 0.0) => Err(format!(
                "[foxglove] grid_period = {s} is not a positive number of seconds"
            )),
            _ => Ok(()),
        }
    }
}

#[derive(Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LauncherSection {
    /// Where each process's log goes.
    pub log_dir: Option<PathBuf>,
    /// Restarts of one process within a minute before the launcher gives up.
    pub max_restarts: Option<u32>,
    /// Seconds before a process that died is started again; each further restart of it within a
    /// minute waits twice as long as the one before, up to 16 times this.
    pub restart_delay: Option<f64>,
}

impl PipelineFile {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_owned(),
            source,
        })?;
        Self::parse(&text, path)
    }

    fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let file: Self =
            sonar_common::toml_file::parse(text).map_err(|message| ConfigError::Parse {
                path: path.to_owned(),
                message,
            })?;
        file.fusion
            .engine
            .validate()
            .map_err(|source| ConfigError::Fusion {
                path: path.to_owned(),
                source,
            })?;
        file.bridge_enabled()
            .and_then(|_| file.check_correction())
            .map_err(|message| ConfigError::Parse {
                path: path.to_owned(),
                message,
            })?;
        file.launcher
            .restart_delay()
            .map(drop)
            .and_then(|()| file.foxglove.check())
            .map_err(|message| ConfigError::Parse {
                path: path.to_owned(),
                message,
            })?;
        Ok(file)
    }
}

impl PipelineFile {
    /// The fusion's correction comes from one place: `sonar-slam` or its own localisation.
    fn check_correction(&self) -> Result<(), String> {
        let slam = self.slam.enabled || self.fusion.slam_correction;
        if slam && self.features.localize {
            return Err(
                "[features] localize = true and sonar-slam's correction ([slam] enabled \
                 or [fusion] slam_correction) exclude each other: the fusion takes its \
                 correction from one of them"
                    .to_owned(),
            );
        }
        Ok(())
    }

    /// Whether `[bridge] enabled = true`: then the launcher starts `sonar-bridge` too.
    pub fn bridge_enabled(&self) -> Result<bool, String> {
        match self.bridge.get("enabled") {
            None => Ok(false),
            Some(toml::Value::Boolean(on)) => Ok(*on),
            Some(other) => Err(format!("[bridge] enabled = {other} is not true or false")),
        }
    }
}

impl LauncherSection {
    /// The first restart's delay, [`DEFAULT_RESTART_DELAY`] unless set.
    pub fn restart_delay(&self) -> Result<Duration, String> {
        self.restart_delay.map_or(Ok(DEFAULT_RESTART_DELAY), |s| {
            Duration::try_from_secs_f64(s).map_err(|_| {
                format!("[launcher] restart_delay = {s} is not a number of seconds >= 0")
            })
        })
    }
}

/// Appends `--flag value` when the value is set.
pub fn push_opt<T: ToString>(args: &mut Vec<String>, flag: &str, value: Option<T>) {
    if let Some(v) = value {
        args.push(flag.to_owned());
        args.push(v.to_string());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_fusion::FusionConfig;

    #[test]
    fn the_example_configuration_parses() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/sonar.toml");
        let file = PipelineFile::load(&path).unwrap();
        assert_eq!(file.simulator.scene.as_deref(), Some("room"));
        assert!(file.viewer.enabled);
        assert_eq!(file.fusion.engine, FusionConfig::default());
        assert!(file.features.enabled && !file.features.localize);
        assert!(!file.foxglove.enabled);

        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/corridor.toml");
        let tour = PipelineFile::load(&path).unwrap();
        assert_eq!(tour.simulator.scene.as_deref(), Some("corridor"));
        assert!(tour.slam.enabled && !tour.features.localize);
        assert_eq!(tour.fusion.engine.grid.centre_x_m, 3.0);
        // Its [slam.features.odometry] spells out the defaults.
        assert_eq!(
            tour.slam.config.features.odometry,
            sonar_fusion::FeaturesSection::default().config.odometry
        );
    }

    #[test]
    fn the_slam_table_is_checked_and_excludes_the_fusions_localisation() {
        let on = PipelineFile::parse(
            "[slam]\nenabled = true\nfix_max_sigma_m = 0.08\n",
            Path::new("x.toml"),
        )
        .unwrap();
        assert!(on.slam.enabled);
        assert_eq!(on.slam.config.fix_max_sigma_m, 0.08);
        assert!(
            !PipelineFile::parse("", Path::new("x.toml"))
                .unwrap()
                .slam
                .enabled
        );
        for bad in [
            "[slam]\nenabled = \"yes\"\n",
            "[slam]\nfix_max_sigma = 0.1\n",
            "[slam]\ngate_chi2 = 0.0\n",
        ] {
            assert!(
                PipelineFile::parse(bad, Path::new("x.toml")).is_err(),
                "{bad}"
            );
        }
        for both in [
            "[slam]\nenabled = true\n[features]\nlocalize = true\n",
            "[fusion]\nslam_correction = true\n[features]\nlocalize = true\n",
        ] {
            let err = PipelineFile::parse(both, Path::new("x.toml"))
                .unwrap_err()
                .to_string();
            assert!(err.contains("exclude each other"), "{both}: {err}");
        }
    }

    #[test]
    fn an_empty_file_means_every_default() {
        let file = PipelineFile::parse("", Path::new("x.toml")).unwrap();
        assert!(file.serial.port.is_none());
        assert!(file.viewer.enabled);
    }

    #[test]
    fn typos_and_bad_fusion_settings_are_errors() {
        let typo = PipelineFile::parse("[serial]\nbuad = 9600\n", Path::new("x.toml"));
        assert!(
            matches!(&typo, Err(ConfigError::Parse { message, .. }) if message.contains("buad")),
            "{typo:?}"
        );
        let bad = PipelineFile::parse("[fusion.grid]\nresolution_m = -1.0\n", Path::new("x.toml"));
        assert!(matches!(bad, Err(ConfigError::Fusion { .. })), "{bad:?}");
        // A value of the wrong type is shown at its own line, in [fusion] and [features] too
        // (issue 28: it was shown at the table's header).
        for (text, line) in [
            (
                "[fusion]\n\n[fusion.grid]\ncells = 400\nresolution_m = \"2 cm\"\n",
                5,
            ),
            // Inside [fusion.model] and [fusion.rule] too, read by `kind` (serde's tagged enums
            // keep no positions: the value the message quotes tells the key).
            (
                "[fusion]\n[fusion.model]\nkind = \"smooth\"\nfade_range_m = \"far\"\n",
                4,
            ),
            (
                "[fusion.rule]\nkind = \"log-odds\"\nmax_log_odds = true\n",
                3,
            ),
            ("[features]\nenabled = true\nmin_pings = \"x\"\n", 3),
            ("[simulator]\nseed = 1\nspeed = 20\n", 3),
        ] {
            let wrong = PipelineFile::parse(text, Path::new("x.toml"));
            assert!(
                matches!(&wrong, Err(ConfigError::Parse { message, .. })
                    if message.starts_with(&format!("TOML parse error at line {line},"))),
                "{text}: {wrong:?}"
            );
        }
        // The map's persistence keys belong to [fusion] too.
        let persist = "[fusion]\nsave_period = 2.0\npersist = true\n";
        assert!(PipelineFile::parse(persist, Path::new("x.toml")).is_ok());
        let features = PipelineFile::parse("[features]\nmin_pings = 0\n", Path::new("x.toml"));
        assert!(
            matches!(&features, Err(ConfigError::Parse { message, .. }) if message.contains("min_pings")),
            "{features:?}"
        );
        let bridge = PipelineFile::parse(
            "[bridge]\nenabled = true\nrobot = \"r1\"\n",
            Path::new("x.toml"),
        );
        assert_eq!(bridge.unwrap().bridge_enabled(), Ok(true));
        assert!(PipelineFile::parse("[bridge]\nenabled = 1\n", Path::new("x.toml")).is_err());
        let bad = PipelineFile::parse("[launcher]\nrestart_delay = -1\n", Path::new("x.toml"));
        assert!(
            matches!(&bad, Err(ConfigError::Parse { message, .. }) if message.contains("restart_delay")),
            "{bad:?}"
        );
        let foxglove =
            "[foxglove]\nenabled = true\nhost = \"0.0.0.0\"\nport = 9000\ngrid_period = 0.5\n";
        let foxglove = PipelineFile::parse(foxglove, Path::new("x.toml"))
            .unwrap()
            .foxglove;
        assert!(foxglove.enabled);
        assert_eq!(
            (
                foxglove.host.as_deref(),
                foxglove.port,
                foxglove.grid_period
            ),
            (Some("0.0.0.0"), Some(9000), Some(0.5))
        );
        for bad in [
            "grid_period = 0",
            "grid_period = -1.0",
            "port = 70000",
            "hots = \"x\"",
        ] {
            let file = PipelineFile::parse(&format!("[foxglove]\n{bad}\n"), Path::new("x.toml"));
            assert!(
                matches!(file, Err(ConfigError::Parse { .. })),
                "{bad}: {file:?}"
            );
        }
    }

    #[test]
    fn only_given_settings_become_flags() {
        let mut args = Vec::new();
        push_opt(&mut args, "--baud", Some(9600));
        push_opt::<u32>(&mut args, "--seed", None);
        assert_eq!(args, ["--baud", "9600"]);
    }
}
