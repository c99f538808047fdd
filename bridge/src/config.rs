//! The `[bridge]` table of the pipeline's configuration file (`examples/sonar.toml`), and the
//! settings it makes together with the command line.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

use crate::channel::{Channel, check_robot_name};

/// Default TCP port of a robot's bridge (zenoh's usual one).
pub const DEFAULT_PORT: u16 = 7447;

/// Which side of the link this bridge is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// On the robot: its services out to the network, commands in.
    Robot,
    /// On a watching machine: a robot's services into this machine's iceoryx2, commands out.
    Remote,
}

/// A configuration the bridge cannot run with.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("invalid [bridge] table in {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{0}")]
    Invalid(String),
}

/// The `[bridge]` table. Every key is optional; unknown keys are errors.
#[derive(Debug, Default, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BridgeSection {
    /// `sonar-pipeline` starts the bridge beside the pipeline.
    pub enabled: bool,
    pub mode: Option<Mode>,
    /// This robot's name (robot mode) or the robot to watch (remote mode).
    pub robot: Option<String>,
    /// zenoh endpoints to listen on, e.g. `tcp/0.0.0.0:7447`.
    pub listen: Option<Vec<String>>,
    /// zenoh endpoints to connect to, e.g. `tcp/192.168.1.20:7447`.
    pub connect: Option<Vec<String>>,
    /// Channels to carry (`readings`, `grid`, …, `commands`); all by default.
    pub services: Option<Vec<String>>,
    /// Most messages per second on the link, per channel (0: no limit).
    pub max_rate_hz: BTreeMap<String, f64>,
}

/// The file's tables, of which the bridge reads only its own.
#[derive(Debug, Default, Deserialize)]
struct PipelineFile {
    #[serde(default)]
    bridge: BridgeSection,
}

impl BridgeSection {
    /// The `[bridge]` table of `path` (empty if the file has none).
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_owned(),
            source,
        })?;
        let file: PipelineFile = toml::from_str(&text).map_err(|e| ConfigError::Parse {
            path: path.to_owned(),
            message: e.to_string(),
        })?;
        Ok(file.bridge)
    }
}

/// What the command line sets; `None`/empty: the file's value, else the default.
#[derive(Debug, Default, Clone)]
pub struct Overrides {
    pub mode: Option<Mode>,
    pub robot: Option<String>,
    pub listen: Vec<String>,
    pub connect: Vec<String>,
    pub services: Vec<String>,
    pub grid_max_rate_hz: Option<f64>,
}

/// Everything the bridge runs with.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    pub mode: Mode,
    /// `None` in remote mode: the only robot seen is chosen.
    pub robot: Option<String>,
    pub listen: Vec<String>,
    pub connect: Vec<String>,
    pub channels: Vec<Channel>,
    /// The shortest interval between two messages of a channel on the link.
    pub min_interval: BTreeMap<Channel, Duration>,
}

impl Settings {
    pub fn resolve(file: &BridgeSection, flags: &Overrides) -> Result<Self, ConfigError> {
        let invalid = ConfigError::Invalid;
        let mode = flags.mode.or(file.mode).unwrap_or(Mode::Robot);
        let robot = flags.robot.clone().or(file.robot.clone());
        if let Some(name) = &robot {
            check_robot_name(name).map_err(invalid)?;
        }
        if mode == Mode::Robot && robot.is_none() {
            return Err(invalid(
                "robot mode needs a name: --robot NAME or [bridge] robot".into(),
            ));
        }
        let pick = |flag: &[String], file: &Option<Vec<String>>, default: Vec<String>| {
            if !flag.is_empty() {
                flag.to_vec()
            } else {
                file.clone().unwrap_or(default)
            }
        };
        // The robot waits for remotes to connect; a remote connects to the robots it is told of.
        let default_listen = match mode {
            Mode::Robot => vec![format!("tcp/0.0.0.0:{DEFAULT_PORT}")],
            Mode::Remote => Vec::new(),
        };
        let listen = pick(&flags.listen, &file.listen, default_listen);
        let connect = pick(&flags.connect, &file.connect, Vec::new());
        if listen.is_empty() && connect.is_empty() {
            return Err(invalid(
                "nothing to listen on and nowhere to connect: give --connect tcp/ROBOT:7447 \
                 (or [bridge] connect)"
                    .into(),
            ));
        }
        let names = pick(&flags.services, &file.services, Vec::new());
        let mut channels = if names.is_empty() {
            Channel::ALL.to_vec()
        } else {
            names
                .iter()
                .flat_map(|n| n.split(','))
                .map(|n| n.trim().parse::<Channel>())
                .collect::<Result<Vec<_>, _>>()
                .map_err(invalid)?
        };
        channels.sort();
        channels.dedup();

        let mut rates: BTreeMap<Channel, f64> = Channel::ALL
            .into_iter()
            .filter_map(|c| c.default_max_rate_hz().map(|hz| (c, hz)))
            .collect();
        for (name, &hz) in &file.max_rate_hz {
            rates.insert(name.parse().map_err(invalid)?, hz);
        }
        if let Some(hz) = flags.grid_max_rate_hz {
            rates.insert(Channel::Grid, hz);
        }
        let mut min_interval = BTreeMap::new();
        for (channel, hz) in rates {
            if !(hz.is_finite() && hz >= 0.0) {
                return Err(invalid(format!(
                    "max rate of {channel} = {hz} must be a number of messages per second >= 0"
                )));
            }
            if hz > 0.0 {
                min_interval.insert(channel, Duration::from_secs_f64(1.0 / hz));
            }
        }
        Ok(Self {
            mode,
            robot,
            listen,
            connect,
            channels,
            min_interval,
        })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn parse(text: &str) -> Result<BridgeSection, String> {
        toml::from_str::<PipelineFile>(text)
            .map(|f| f.bridge)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn the_example_files_bridge_table_is_valid() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/sonar.toml");
        let section = BridgeSection::load(&path).unwrap();
        let settings = Settings::resolve(&section, &Overrides::default()).unwrap();
        assert_eq!(settings.mode, Mode::Robot);
    }

    #[test]
    fn flags_override_the_file_and_defaults_fill_the_rest() {
        let file = parse(
            "[fusion]\nx = 1\n[bridge]\nmode = \"remote\"\nrobot = \"r1\"\n\
             connect = [\"tcp/10.0.0.1:7447\"]\nservices = [\"grid\", \"commands\"]\n\
             max_rate_hz = { grid = 0.5, radar = 0 }\n",
        )
        .unwrap();
        let s = Settings::resolve(&file, &Overrides::default()).unwrap();
        assert_eq!(s.mode, Mode::Remote);
        assert_eq!(s.channels, vec![Channel::Grid, Channel::Commands]);
        assert!(s.listen.is_empty());
        assert_eq!(s.min_interval[&Channel::Grid], Duration::from_secs(2));
        assert!(!s.min_interval.contains_key(&Channel::Radar));
        let flags = Overrides {
            robot: Some("r2".into()),
            services: vec!["readings,grid".into()],
            grid_max_rate_hz: Some(4.0),
            ..Default::default()
        };
        let s = Settings::resolve(&file, &flags).unwrap();
        assert_eq!(s.robot.as_deref(), Some("r2"));
        assert_eq!(s.channels, vec![Channel::Readings, Channel::Grid]);
        assert_eq!(s.min_interval[&Channel::Grid], Duration::from_millis(250));
    }

    #[test]
    fn bad_settings_are_refused_with_the_reason() {
        assert!(parse("[bridge]\nmode = \"laptop\"\n").is_err());
        assert!(parse("[bridge]\nrobto = \"r1\"\n").is_err());
        let err = |text: &str| {
            Settings::resolve(&parse(text).unwrap(), &Overrides::default())
                .unwrap_err()
                .to_string()
        };
        assert!(err("[bridge]\n").contains("needs a name"));
        assert!(err("[bridge]\nrobot = \"a/b\"\n").contains("robot name"));
        assert!(err("[bridge]\nrobot = \"r\"\nservices = [\"gird\"]\n").contains("gird"));
        assert!(err("[bridge]\nrobot = \"r\"\nmax_rate_hz = { grid = -1 }\n").contains("grid"));
        assert!(err("[bridge]\nmode = \"remote\"\n").contains("--connect"));
    }
}
