//! `sonar-bridge`: the pipeline's iceoryx2 services carried over zenoh, between a robot and the
//! machines that watch and command it.
//!
//! iceoryx2 stops at the host's edge. On the robot, the bridge subscribes to the chosen services
//! and publishes each sample to the zenoh key `sonar/<robot>/<channel>` (`sonar/r1/grid`, …); it
//! takes commands from `sonar/<robot>/commands` and `sonar/<robot>/fusion_commands` and publishes
//! them into the robot's iceoryx2. On a remote machine it does the mirror image into that
//! machine's own iceoryx2 namespace, so the unchanged viewer, exporter, recorder and Python
//! scripts run there as on the robot.
//!
//! - [`wire`]: each message is the sample's bytes in the documented layout behind a frame naming
//!   the layout; a receiver refuses (and counts) another version. Grid cells travel LZ4-compressed.
//! - [`channel`]: which service goes which way under which key, and how often.
//! - [`config`]: the `[bridge]` table of the pipeline's TOML file.
//! - [`ports`]: the iceoryx2 ends, one reader and one writer per service.
//! - [`ros2`]: `--mode ros2`, the map, scans and transforms as ROS 2 topics under `rmw_zenoh`'s keys.
//! - [`wake`]: the one wait of the main thread, on zenoh's deliveries and iceoryx2's events.
//!
//! One process talks to the network: zenoh and its tokio runtime live only in this crate. The
//! iceoryx2 side runs on the main thread (its ports are not `Send`) and uses zenoh's synchronous
//! API with channel handlers, so no async code is written here.

pub mod certs;
pub mod channel;
pub mod config;
pub mod ports;
pub mod ros2;
pub mod session;
pub mod wake;
pub mod wire;
