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
    /// On the robot, for ROS 2: `/map`, `/scan` and `/tf` in CDR under `rmw_zenoh`'s keys, so a
    /// ROS 2 machine with `rmw_zenoh` sees them (`bridge::ros2`); no ROS on the robot.
    Ros2,
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
    /// zenoh endpoints to listen on, e.g. `tls/192.168.1.20:7447` (default `tcp/127.0.0.1:7447`).
    pub listen: Option<Vec<String>>,
    /// zenoh endpoints to connect to, e.g. `tls/192.168.1.20:7447`.
    pub connect: Option<Vec<String>>,
    /// Channels to carry (`readings`, `grid`, …, `commands`); all by default.
    pub services: Option<Vec<String>>,
    /// Most messages per second on the link, per channel (0: no limit).
    pub max_rate_hz: BTreeMap<String, f64>,
    /// Allow plain TCP (no authentication, no encryption) beyond localhost.
    pub insecure: bool,
    /// The certificates of mutual TLS (`tls/` endpoints), made by `sonar-bridge certs`.
    pub tls: Option<TlsFiles>,
    /// Robot: the certificate names (common names) of the peers that may read its channels.
    pub allow_read: Vec<String>,
    /// Robot: the certificate names of the peers that may read and command.
    pub allow_command: Vec<String>,
}

/// This bridge's certificate and key, and the authority every peer's certificate must be signed
/// by (PEM files).
#[derive(Debug, Default, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TlsFiles {
    pub ca: PathBuf,
    pub cert: PathBuf,
    pub key: PathBuf,
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
        let file: PipelineFile =
            sonar_common::toml_file::parse(&text).map_err(|message| ConfigError::Parse {
                path: path.to_owned(),
                message,
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
    pub insecure: bool,
    pub ca: Option<PathBuf>,
    pub cert: Option<PathBuf>,
    pub key: Option<PathBuf>,
    pub allow_read: Vec<String>,
    pub allow_command: Vec<String>,
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
    /// Mutual TLS, when an endpoint is `tls/…`.
    pub tls: Option<TlsFiles>,
    /// Robot over TLS: who may read, who may also command (certificate common names).
    pub allow_read: Vec<String>,
    pub allow_command: Vec<String>,
    /// The plain-TCP endpoints beyond localhost that `insecure` let through (warned of at start).
    pub insecure_endpoints: Vec<String>,
}

/// How an endpoint's traffic travels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Protocol {
    Tcp,
    Tls,
}

/// The protocol of a zenoh endpoint (`tcp/HOST:PORT`, `tls/HOST:PORT`, optionally followed by
/// `?…` or `#…`), and whether its host is this machine only.
fn endpoint(text: &str) -> Result<(Protocol, bool), ConfigError> {
    let (protocol, rest) = text.split_once('/').ok_or_else(|| {
        ConfigError::Invalid(format!(
            "endpoint {text:?} is not PROTOCOL/HOST:PORT (e.g. tls/192.168.1.20:{DEFAULT_PORT})"
        ))
    })?;
    let protocol = match protocol {
        "tcp" => Protocol::Tcp,
        "tls" => Protocol::Tls,
        other => {
            return Err(ConfigError::Invalid(format!(
                "endpoint {text:?}: protocol {other:?} is not built in; use tls/ (or tcp/ on \
                 localhost)"
            )));
        }
    };
    let address = rest.split(['?', '#']).next().unwrap_or_default();
    let host = address
        .rsplit_once(':')
        .map_or(address, |(host, _port)| host)
        .trim_start_matches('[')
        .trim_end_matches(']');
    let local = host == "localhost"
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback());
    Ok((protocol, local))
}

impl Settings {
    /// The channels that come in from the link (commands on a robot, the rest on a remote).
    pub fn inbound_channels(&self) -> impl Iterator<Item = Channel> + '_ {
        self.channels.iter().copied().filter(|c| match self.mode {
            Mode::Robot => c.is_command(),
            Mode::Remote => !c.is_command(),
            // It only publishes.
            Mode::Ros2 => false,
        })
    }
}

/// Checks the endpoints against the security settings: plain TCP beyond localhost only when
/// asked for by name, TLS only with certificates, allow lists only where they mean something.
/// Returns the TLS files and the insecure endpoints.
fn check_security(
    mode: Mode,
    endpoints: &[&String],
    tls: Option<TlsFiles>,
    insecure: bool,
    allowed: usize,
) -> Result<(Option<TlsFiles>, Vec<String>), ConfigError> {
    let invalid = |m: String| ConfigError::Invalid(m);
    let mut insecure_endpoints = Vec::new();
    let mut any_tls = false;
    for text in endpoints {
        match endpoint(text)? {
            (Protocol::Tls, _) => any_tls = true,
            (Protocol::Tcp, true) => {}
            (Protocol::Tcp, false) if insecure => insecure_endpoints.push((*text).clone()),
            (Protocol::Tcp, false) => {
                return Err(invalid(format!(
                    "{text} is plain TCP beyond localhost: anyone who reaches it could read \
                     every channel and command the robot. Use tls/… with certificates \
                     (--ca, --cert, --key; `sonar-bridge certs` makes them, docs/bridge.md), or \
                     pass --insecure ([bridge] insecure = true) to accept that"
                )));
            }
        }
    }
    let tls = if any_tls {
        let files = tls.ok_or_else(|| {
            invalid(
                "tls/ endpoints need this bridge's certificate: --ca CA.pem --cert NAME.pem \
                 --key NAME.key (or [bridge.tls]); `sonar-bridge certs` makes them"
                    .into(),
            )
        })?;
        for path in [&files.ca, &files.cert, &files.key] {
            if !path.is_file() {
                return Err(invalid(format!(
                    "TLS file {} does not exist (or is not a file)",
                    path.display()
                )));
            }
        }
        if mode == Mode::Robot && allowed == 0 {
            return Err(invalid(
                "over TLS a robot serves only the peers it lists: give --allow-read NAME and/or \
                 --allow-command NAME (the names of their certificates) or [bridge] allow_read / \
                 allow_command"
                    .into(),
            ));
        }
        Some(files)
    } else {
        if allowed > 0 {
            return Err(invalid(
                "allow_read/allow_command name certificates: they need tls/ endpoints".into(),
            ));
        }
        None
    };
    if mode != Mode::Robot && allowed > 0 {
        return Err(invalid(
            "allow_read/allow_command are a robot bridge's lists; a remote or ros2 bridge has none \
             (over TLS only peers with a certificate of the same authority reach it)"
                .into(),
        ));
    }
    Ok((tls, insecure_endpoints))
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
        // The robot waits for remotes to connect (on this machine only unless told otherwise); a
        // remote connects to the robots it is told of; a ros2 bridge connects, as every rmw_zenoh
        // node does, to the zenoh router on this machine (`ros2 run rmw_zenoh_cpp rmw_zenohd`).
        let local = format!("tcp/127.0.0.1:{DEFAULT_PORT}");
        let (default_listen, default_connect) = match mode {
            Mode::Robot => (vec![local], Vec::new()),
            Mode::Remote => (Vec::new(), Vec::new()),
            Mode::Ros2 => (Vec::new(), vec![local]),
        };
        let listen = pick(&flags.listen, &file.listen, default_listen);
        let connect = pick(&flags.connect, &file.connect, default_connect);
        if listen.is_empty() && connect.is_empty() {
            return Err(invalid(
                "nothing to listen on and nowhere to connect: give --connect tls/ROBOT:7447 \
                 (or [bridge] connect)"
                    .into(),
            ));
        }
        let tls = match (&flags.ca, &flags.cert, &flags.key) {
            (None, None, None) => file.tls.clone(),
            (Some(ca), Some(cert), Some(key)) => Some(TlsFiles {
                ca: ca.clone(),
                cert: cert.clone(),
                key: key.clone(),
            }),
            _ => {
                return Err(invalid(
                    "--ca, --cert and --key go together (mutual TLS needs all three)".into(),
                ));
            }
        };
        let allow_read = pick(
            &flags.allow_read,
            &Some(file.allow_read.clone()),
            Vec::new(),
        );
        let allow_command = pick(
            &flags.allow_command,
            &Some(file.allow_command.clone()),
            Vec::new(),
        );
        if let Some(bad) = allow_read
            .iter()
            .chain(&allow_command)
            .find(|n| n.trim().is_empty())
        {
            return Err(invalid(format!(
                "empty certificate name {bad:?} in an allow list"
            )));
        }
        let endpoints: Vec<&String> = listen.iter().chain(&connect).collect();
        let (tls, insecure_endpoints) = check_security(
            mode,
            &endpoints,
            tls,
            flags.insecure || file.insecure,
            allow_read.len() + allow_command.len(),
        )?;
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
            tls,
            allow_read,
            allow_command,
            insecure_endpoints,
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
             connect = [\"tcp/127.0.0.1:7447\"]\nservices = [\"grid\", \"commands\"]\n\
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

    #[test]
    fn nothing_listens_beyond_localhost_without_authentication_unless_asked_by_name() {
        let robot = |extra: &str| parse(&format!("[bridge]\nrobot = \"r1\"\n{extra}")).unwrap();
        let resolve = |file: &BridgeSection, flags: &Overrides| Settings::resolve(file, flags);
        // The default: this machine only, nothing to warn of.
        let s = resolve(&robot(""), &Overrides::default()).unwrap();
        assert_eq!(s.listen, ["tcp/127.0.0.1:7447"]);
        assert!(s.insecure_endpoints.is_empty() && s.tls.is_none());
        for local in [
            "tcp/[::1]:7447",
            "tcp/localhost:7447",
            "tcp/127.0.0.2:7447#iface=lo",
        ] {
            let file = robot(&format!("listen = [\"{local}\"]\n"));
            assert!(resolve(&file, &Overrides::default()).is_ok(), "{local}");
        }
        // Plain TCP beyond localhost: refused, with the way out named.
        for open in ["tcp/0.0.0.0:7447", "tcp/192.168.1.20:7447", "tcp/[::]:7447"] {
            let file = robot(&format!("listen = [\"{open}\"]\n"));
            let err = resolve(&file, &Overrides::default())
                .unwrap_err()
                .to_string();
            assert!(err.contains("--insecure") && err.contains("tls/"), "{err}");
            let flags = Overrides {
                insecure: true,
                ..Default::default()
            };
            let s = resolve(&file, &flags).unwrap();
            assert_eq!(s.insecure_endpoints, [open]);
        }
        let file = parse("[bridge]\nmode = \"remote\"\nconnect = [\"tcp/10.0.0.1:7447\"]\n");
        assert!(resolve(&file.unwrap(), &Overrides::default()).is_err());
        let file = robot("listen = [\"udp/0.0.0.0:7447\"]\n");
        let err = resolve(&file, &Overrides::default())
            .unwrap_err()
            .to_string();
        assert!(err.contains("not built in"), "{err}");
    }

    #[test]
    fn a_ros2_bridge_connects_to_this_machine_s_router_and_keeps_the_same_rules() {
        let ros2 = |extra: &str| parse(&format!("[bridge]\nmode = \"ros2\"\n{extra}")).unwrap();
        let s = Settings::resolve(&ros2(""), &Overrides::default()).unwrap();
        assert_eq!(s.mode, Mode::Ros2);
        assert!(s.listen.is_empty() && s.robot.is_none());
        assert_eq!(s.connect, ["tcp/127.0.0.1:7447"]);
        // It takes nothing from the link.
        assert_eq!(s.inbound_channels().count(), 0);
        let open = ros2("connect = [\"tcp/192.168.1.30:7447\"]\n");
        let err = Settings::resolve(&open, &Overrides::default())
            .unwrap_err()
            .to_string();
        assert!(err.contains("--insecure") && err.contains("tls/"), "{err}");
        let flags = Overrides {
            allow_read: vec!["laptop".into()],
            ..Default::default()
        };
        assert!(Settings::resolve(&ros2(""), &flags).is_err());
    }

    #[test]
    fn tls_needs_certificates_and_a_robot_over_tls_its_allow_lists() {
        let dir = std::env::temp_dir().join(format!("sonar-bridge-tls-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for f in ["ca.pem", "r1.pem", "r1.key"] {
            std::fs::write(dir.join(f), "").unwrap();
        }
        let file = parse(&format!(
            "[bridge]\nrobot = \"r1\"\nlisten = [\"tls/0.0.0.0:7447\"]\n\
             allow_command = [\"laptop1\"]\n[bridge.tls]\nca = \"{0}/ca.pem\"\n\
             cert = \"{0}/r1.pem\"\nkey = \"{0}/r1.key\"\n",
            dir.display()
        ))
        .unwrap();
        let s = Settings::resolve(&file, &Overrides::default()).unwrap();
        assert_eq!(s.allow_command, ["laptop1"]);
        assert!(s.tls.is_some() && s.insecure_endpoints.is_empty());
        let flags = |f: Overrides| Settings::resolve(&BridgeSection::default(), &f);
        let tls_robot = Overrides {
            robot: Some("r1".into()),
            listen: vec!["tls/0.0.0.0:7447".into()],
            ca: Some(dir.join("ca.pem")),
            cert: Some(dir.join("r1.pem")),
            key: Some(dir.join("r1.key")),
            ..Default::default()
        };
        let err = flags(tls_robot.clone()).unwrap_err().to_string();
        assert!(err.contains("--allow-read"), "{err}");
        let err = flags(Overrides {
            key: None,
            allow_read: vec!["x".into()],
            ..tls_robot.clone()
        })
        .unwrap_err()
        .to_string();
        assert!(err.contains("go together"), "{err}");
        let err = flags(Overrides {
            cert: Some(dir.join("missing.pem")),
            allow_read: vec!["x".into()],
            ..tls_robot.clone()
        })
        .unwrap_err()
        .to_string();
        assert!(err.contains("missing.pem"), "{err}");
        let err = flags(Overrides {
            robot: Some("r1".into()),
            allow_read: vec!["x".into()],
            ..Default::default()
        })
        .unwrap_err()
        .to_string();
        assert!(err.contains("need tls/"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
