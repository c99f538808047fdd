//! The zenoh configuration a bridge runs with: its endpoints, mutual TLS, the robot's access
//! control, and a cap on the messages zenoh reassembles for it.

use serde_json::{Value, json};

use crate::channel::{self, Channel};
use crate::config::{Mode, Settings};
use crate::ports;

/// What zenoh refused in the configuration made here.
#[derive(Debug, thiserror::Error)]
#[error("zenoh setting {key} = {value}: {message}")]
pub struct SessionConfigError {
    key: String,
    value: String,
    message: String,
}

/// Room for zenoh's own framing around the longest message a channel takes.
const MESSAGE_SLACK: usize = 64 * 1024;

/// The longest message zenoh may reassemble for this bridge: the longest frame any of its
/// inbound channels takes, plus framing. A robot takes only commands, so a 2 MB message sent to it
/// is dropped by zenoh before anything of ours sees it (zenoh's default is 1 GiB).
pub fn max_message_size(settings: &Settings) -> usize {
    settings
        .inbound_channels()
        .map(|c| ports::expect(c).max_frame_len())
        .max()
        .unwrap_or(0)
        + MESSAGE_SLACK
}

/// A zenoh peer with exactly the configured endpoints: no multicast or gossip scouting, so it
/// reaches only the machines it is told of, and retries them for ever. Over TLS both
/// ends present certificates signed by the same authority; a robot then serves only the peers its
/// allow lists name (`robot` is its name).
pub fn zenoh_config(
    settings: &Settings,
    robot: Option<&str>,
) -> Result<zenoh::Config, SessionConfigError> {
    let mut entries = vec![
        ("mode", json!("peer")),
        ("listen/endpoints", json!(settings.listen)),
        ("connect/endpoints", json!(settings.connect)),
        ("scouting/multicast/enabled", json!(false)),
        // No gossip: a peer would otherwise learn, from the robot, the address of every other peer
        // that reached it, and connect there directly, past the robot's access control (a remote
        // bridge joined an unlisted peer's plain-TCP listener that way and sent it its commands).
        ("scouting/gossip/enabled", json!(false)),
        // Keep retrying a robot that is not (yet) there instead of failing at start.
        ("connect/timeout_ms", json!(-1)),
        ("connect/exit_on_failure", json!(false)),
        (
            "transport/link/rx/max_message_size",
            json!(max_message_size(settings)),
        ),
    ];
    if let Some(tls) = &settings.tls {
        let path = |p: &std::path::Path| json!(p.display().to_string());
        entries.extend([
            ("transport/link/tls/root_ca_certificate", path(&tls.ca)),
            ("transport/link/tls/listen_certificate", path(&tls.cert)),
            ("transport/link/tls/listen_private_key", path(&tls.key)),
            ("transport/link/tls/connect_certificate", path(&tls.cert)),
            ("transport/link/tls/connect_private_key", path(&tls.key)),
            // Both ends show a certificate: a peer without one is refused in the handshake.
            ("transport/link/tls/enable_mtls", json!(true)),
            ("transport/link/tls/verify_name_on_connect", json!(true)),
            ("transport/link/tls/close_link_on_expiration", json!(true)),
        ]);
        if let (Mode::Robot, Some(robot)) = (settings.mode, robot) {
            entries.push(("access_control", access_control(settings, robot)));
        }
    }
    let mut config = zenoh::Config::default();
    for (key, value) in entries {
        let value = value.to_string();
        config
            .insert_json5(key, &value)
            .map_err(|e| SessionConfigError {
                key: key.to_owned(),
                value,
                message: e.to_string(),
            })?;
    }
    Ok(config)
}

/// The robot's access control: everything is denied but what the listed peers need. Readers (and
/// commanders) may subscribe to and ask for `sonar/<robot>/**`, hold their liveliness token and
/// find robots; the robot may send them everything of its own. Only commanders may put on the
/// command keys. A peer whose certificate is valid but not listed gets nothing and sends nothing.
fn access_control(settings: &Settings, robot: &str) -> Value {
    let own = format!("{}/{robot}/**", channel::KEY_ROOT);
    let commands: Vec<String> = Channel::ALL
        .into_iter()
        .filter(|c| c.is_command())
        .map(|c| c.key(robot))
        .collect();
    let readers: Vec<&String> = settings
        .allow_read
        .iter()
        .chain(&settings.allow_command)
        .collect();
    let mut subjects = vec![json!({ "id": "readers", "cert_common_names": readers })];
    let mut policies = vec![json!({ "rules": ["robot_out", "watch_in"], "subjects": ["readers"] })];
    if !settings.allow_command.is_empty() {
        subjects.push(json!({ "id": "commanders", "cert_common_names": settings.allow_command }));
        policies.push(json!({ "rules": ["command_in"], "subjects": ["commanders"] }));
    }
    json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": [
            {
                "id": "robot_out",
                "flows": ["egress"],
                "permission": "allow",
                "messages": [
                    "put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                    "liveliness_token", "liveliness_query", "declare_liveliness_subscriber",
                ],
                "key_exprs": [own],
            },
            {
                "id": "watch_in",
                "flows": ["ingress"],
                "permission": "allow",
                "messages": [
                    "declare_subscriber", "query", "liveliness_token", "liveliness_query",
                    "declare_liveliness_subscriber",
                ],
                "key_exprs": [own, channel::ALL_ROBOT_TOKENS],
            },
            {
                "id": "command_in",
                "flows": ["ingress"],
                "permission": "allow",
                "messages": ["put"],
                "key_exprs": commands,
            },
        ],
        "subjects": subjects,
        "policies": policies,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::config::{BridgeSection, Overrides};

    fn settings(flags: Overrides) -> Settings {
        Settings::resolve(&BridgeSection::default(), &flags).unwrap()
    }

    #[test]
    fn a_robot_takes_no_message_longer_than_a_command() {
        let robot = settings(Overrides {
            robot: Some("r1".into()),
            ..Default::default()
        });
        assert!(
            max_message_size(&robot) < 100 * 1024,
            "{}",
            max_message_size(&robot)
        );
        let remote = settings(Overrides {
            mode: Some(Mode::Remote),
            connect: vec!["tcp/127.0.0.1:7447".into()],
            ..Default::default()
        });
        // A remote takes the largest grid, compressed or not.
        assert!(max_message_size(&remote) > 4096 * 4096);
        zenoh_config(&robot, Some("r1")).unwrap();
        zenoh_config(&remote, None).unwrap();
    }

    #[test]
    fn the_robots_access_control_is_a_configuration_zenoh_accepts() {
        let dir = std::env::temp_dir().join(format!("sonar-bridge-acl-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for f in ["ca.pem", "r1.pem", "r1.key"] {
            std::fs::write(dir.join(f), "").unwrap();
        }
        let robot = settings(Overrides {
            robot: Some("r1".into()),
            listen: vec!["tls/0.0.0.0:7447".into()],
            ca: Some(dir.join("ca.pem")),
            cert: Some(dir.join("r1.pem")),
            key: Some(dir.join("r1.key")),
            allow_read: vec!["watcher".into()],
            allow_command: vec!["laptop".into()],
            ..Default::default()
        });
        let acl = access_control(&robot, "r1");
        assert_eq!(
            acl["subjects"][0]["cert_common_names"],
            json!(["watcher", "laptop"])
        );
        assert_eq!(acl["subjects"][1]["cert_common_names"], json!(["laptop"]));
        assert_eq!(
            acl["rules"][2]["key_exprs"],
            json!(["sonar/r1/commands", "sonar/r1/fusion_commands"])
        );
        zenoh_config(&robot, Some("r1")).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
