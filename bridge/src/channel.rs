//! The services the bridge carries: their zenoh names, direction and link policy.

use std::fmt;
use std::str::FromStr;

use sonar_common::ipc;

/// One iceoryx2 service as the bridge carries it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Channel {
    Readings,
    SweepEnds,
    DriverStatus,
    Grid,
    Radar,
    Features,
    FusionStatus,
    Pose,
    LocalizedPose,
    Commands,
    FusionCommands,
}

impl Channel {
    /// Every channel, telemetry first.
    pub const ALL: [Channel; 11] = [
        Channel::Readings,
        Channel::SweepEnds,
        Channel::DriverStatus,
        Channel::Grid,
        Channel::Radar,
        Channel::Features,
        Channel::FusionStatus,
        Channel::Pose,
        Channel::LocalizedPose,
        Channel::Commands,
        Channel::FusionCommands,
    ];

    /// The last chunk of its zenoh key, and its name in the configuration.
    pub fn name(self) -> &'static str {
        match self {
            Channel::Readings => "readings",
            Channel::SweepEnds => "sweep_ends",
            Channel::DriverStatus => "driver_status",
            Channel::Grid => "grid",
            Channel::Radar => "radar",
            Channel::Features => "features",
            Channel::FusionStatus => "fusion_status",
            Channel::Pose => "pose",
            Channel::LocalizedPose => "localized_pose",
            Channel::Commands => "commands",
            Channel::FusionCommands => "fusion_commands",
        }
    }

    /// The iceoryx2 service it carries.
    pub fn service(self) -> &'static str {
        match self {
            Channel::Readings => ipc::READINGS_SERVICE,
            Channel::SweepEnds => ipc::SWEEP_ENDS_SERVICE,
            Channel::DriverStatus => ipc::DRIVER_STATUS_SERVICE,
            Channel::Grid => ipc::GRID_SERVICE,
            Channel::Radar => ipc::RADAR_SERVICE,
            Channel::Features => ipc::FEATURES_SERVICE,
            Channel::FusionStatus => ipc::FUSION_STATUS_SERVICE,
            Channel::Pose => ipc::POSE_SERVICE,
            Channel::LocalizedPose => ipc::LOCALIZED_POSE_SERVICE,
            Channel::Commands => ipc::COMMANDS_SERVICE,
            Channel::FusionCommands => ipc::FUSION_COMMANDS_SERVICE,
        }
    }

    /// Commands travel from a remote machine to the robot; everything else the other way.
    pub fn is_command(self) -> bool {
        matches!(self, Channel::Commands | Channel::FusionCommands)
    }

    /// The wake-up event the service's consumers sleep on, which the publishing side must then
    /// notify: most carry their own service's name; a sweep's end wakes the readings' consumers
    /// (the fusion closes the sweep as it fuses readings); `None`: looked at by polling.
    pub fn wakeup_event(self) -> Option<&'static str> {
        match self {
            Channel::Readings
            | Channel::Grid
            | Channel::Radar
            | Channel::Features
            | Channel::Commands
            | Channel::FusionCommands => Some(self.service()),
            Channel::SweepEnds => Some(ipc::READINGS_SERVICE),
            Channel::DriverStatus
            | Channel::FusionStatus
            | Channel::Pose
            | Channel::LocalizedPose => None,
        }
    }

    /// A state (the latest value is all a newcomer needs), not a stream: the robot keeps its
    /// latest message for late joiners, and a rate limit may drop the ones in between.
    pub fn is_state(self) -> bool {
        !matches!(
            self,
            Channel::Readings
                | Channel::SweepEnds
                | Channel::Pose
                | Channel::Commands
                | Channel::FusionCommands
        )
    }

    /// The default rate limit on the link, messages per second; `None`: every message.
    pub fn default_max_rate_hz(self) -> Option<f64> {
        match self {
            // A 400² snapshot is ~160 KB raw, ~10–40 KB compressed: two a second suit a
            // Wi-Fi link and a human watching.
            Channel::Grid => Some(2.0),
            Channel::Radar => Some(5.0),
            _ => None,
        }
    }

    /// The zenoh key of this channel of `robot`.
    pub fn key(self, robot: &str) -> String {
        format!("{KEY_ROOT}/{robot}/{}", self.name())
    }
}

impl fmt::Display for Channel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Channel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Channel::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| {
                let names: Vec<_> = Channel::ALL.iter().map(|c| c.name()).collect();
                format!("unknown service {s:?}; valid: {}", names.join(", "))
            })
    }
}

/// First chunk of every key.
pub const KEY_ROOT: &str = "sonar";

/// The liveliness token a robot's bridge holds while it runs: remote bridges see the robot come
/// and go (the link), and `--list-robots` finds every robot by it.
pub fn robot_token(robot: &str) -> String {
    format!("{KEY_ROOT}/{robot}/bridge/robot")
}

/// Matches every robot's token.
pub const ALL_ROBOT_TOKENS: &str = "sonar/*/bridge/robot";

/// The token of one remote bridge watching `robot` (its zenoh id keeps remotes apart).
pub fn remote_token(robot: &str, id: &str) -> String {
    format!("{KEY_ROOT}/{robot}/bridge/remote/{id}")
}

/// Matches the tokens of every remote bridge watching `robot`.
pub fn remote_tokens(robot: &str) -> String {
    format!("{KEY_ROOT}/{robot}/bridge/remote/*")
}

/// The robot's name in a key made by [`robot_token`].
pub fn robot_of_token(key: &str) -> Option<&str> {
    let rest = key.strip_prefix(KEY_ROOT)?.strip_prefix('/')?;
    let (robot, tail) = rest.split_once('/')?;
    (tail == "bridge/robot").then_some(robot)
}

/// A robot name must be one key chunk: letters, digits, `-` and `_`.
pub fn check_robot_name(name: &str) -> Result<(), String> {
    if !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        Ok(())
    } else {
        Err(format!(
            "robot name {name:?} must be non-empty letters, digits, '-' or '_'"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_keys_follow_the_robot() {
        for c in Channel::ALL {
            assert_eq!(c.name().parse::<Channel>(), Ok(c));
        }
        assert!("gird".parse::<Channel>().unwrap_err().contains("grid"));
        assert_eq!(Channel::Grid.key("r1"), "sonar/r1/grid");
        assert_eq!(robot_of_token(&robot_token("r-2")), Some("r-2"));
        assert_eq!(robot_of_token("sonar/r1/bridge/remote/abc"), None);
    }

    #[test]
    fn robot_names_are_single_key_chunks() {
        assert!(check_robot_name("robot_1-a").is_ok());
        for bad in ["", "a/b", "*", "r$", "two words"] {
            assert!(check_robot_name(bad).is_err(), "{bad}");
        }
    }
}
