//! The pipeline's data as messages the robot world's tools draw without plugins: Foxglove's
//! well-known schemas (protobuf, from the `foxglove` crate, so the schemas are the FileDescriptorSets
//! Foxglove's SDK writes) and, optionally, ROS 2 messages in CDR (`ros2 bag play` republishes them).
//!
//! | what | Foxglove (`/foxglove/…`) | ROS 2 |
//! |---|---|---|
//! | the map (`sonar/grid`) | `foxglove.Grid` on `/foxglove/map` | `nav_msgs/msg/OccupancyGrid` on `/map` |
//! | each sweep's readings | `foxglove.LaserScan` on `/foxglove/scan` | `sensor_msgs/msg/LaserScan` on `/scan` |
//! | the frames `map → odom → sonar` | `foxglove.FrameTransform` on `/foxglove/tf` | `tf2_msgs/msg/TFMessage` on `/tf` |
//! | walls, corners, posts | `foxglove.SceneUpdate` on `/foxglove/features` | — |
//! | each reading's beam (at most 10 a second) | `foxglove.SceneUpdate` on `/foxglove/beam` | — |
//!
//! Frames: `map` is the grid's world frame, `sonar` the sensor (x forward, angles counter-clockwise),
//! `odom` the odometry's frame between them: `odom → sonar` is the pose of `robot/pose`, `map → odom`
//! the latest correction of the odometry (the fusion's localisation or `sonar-slam`; identity until
//! one is known), sent with each sensor transform ([`frame`]). [`WellKnown`] turns the pipeline's payloads into these
//! messages at modest rates (the map at most once a `grid_period`, scans once a sweep, transforms at
//! most 20 a second); `sonar-record` writes them beside its own channels and `sonar-foxglove`
//! serves them live (and `sonar-bridge --mode ros2` publishes the ROS 2 ones over zenoh). The
//! conversion does no I/O; [`live`] reads the pipeline's services for the live servers.

pub mod convert;
pub mod foxglove_msgs;
pub mod frame;
pub mod live;
pub mod occupancy;
pub mod ros2;
pub mod scan;
mod schema;

pub use convert::{BEAM_PERIOD_NS, Channel, ChannelSpec, Options, Output, WellKnown};
pub use frame::{Correction, MAP_FRAME, ODOM_FRAME, SENSOR_FRAME, Transform, yaw_quaternion};
pub use occupancy::occupancy;
pub use scan::{Scan, SweepScans};

#[cfg(test)]
mod tests;
