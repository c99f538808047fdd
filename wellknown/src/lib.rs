//! The pipeline's data as messages the robot world's tools draw without plugins: Foxglove's
//! well-known schemas (protobuf, from the `foxglove` crate, so the schemas are the FileDescriptorSets
//! Foxglove's SDK writes) and, optionally, ROS 2 messages in CDR (`ros2 bag play` republishes them).
//!
//! | what | Foxglove (`/foxglove/…`) | ROS 2 |
//! |---|---|---|
//! | the map (`sonar/grid`) | `foxglove.Grid` on `/foxglove/map` | `nav_msgs/msg/OccupancyGrid` on `/map` |
//! | each sweep's readings | `foxglove.LaserScan` on `/foxglove/scan` | `sensor_msgs/msg/LaserScan` on `/scan` |
//! | the sensor's pose | `foxglove.FrameTransform` on `/foxglove/tf` | `tf2_msgs/msg/TFMessage` on `/tf` |
//! | walls, corners, posts | `foxglove.SceneUpdate` on `/foxglove/features` | — |
//! | each reading's beam (at most 10 a second) | `foxglove.SceneUpdate` on `/foxglove/beam` | — |
//!
//! Frames: `map` is the grid's world frame, `sonar` the sensor (x forward, angles counter-clockwise),
//! placed in `map` by the transforms. [`WellKnown`] turns the pipeline's payloads into these
//! messages at modest rates (the map at most once a `grid_period`, scans once a sweep, transforms at
//! most 20 a second); `sonar-record` writes them beside its own channels and `sonar-foxglove`
//! serves them live (and `sonar-bridge --mode ros2` publishes the ROS 2 ones over zenoh). The
//! conversion does no I/O; [`live`] reads the pipeline's services for the live servers.

pub mod foxglove_msgs;
pub mod live;
pub mod ros2;
pub mod scan;

use sonar_common::ipc::{CELL_UNKNOWN, FeatureRecord, FeaturesHeader, GridHeader, Pose2D, Reading};

pub use scan::{Scan, SweepScans};

/// The world frame of the map.
pub const MAP_FRAME: &str = "map";
/// The sensor's frame: x is its 0°, angles counter-clockwise.
pub const SENSOR_FRAME: &str = "sonar";
/// Transforms closer together than this are left out (the simulator publishes 20 poses a
/// simulated second, hundreds a real second when it runs fast).
const TRANSFORM_PERIOD_NS: u64 = 50_000_000;
/// Beams of readings closer together than this are left out: the real head takes a few readings a
/// second, all drawn; the simulator at 100× some 500, of which 10 a second are enough to watch.
pub const BEAM_PERIOD_NS: u64 = 100_000_000;

/// A cell as ROS's occupancy: −1 never observed, else the probability in percent (0–100), rounded
/// half up from the cell's `p · 254`.
pub fn occupancy(cell: u8) -> i8 {
    if cell == CELL_UNKNOWN {
        -1
    } else {
        ((u32::from(cell) * 100 + 127) / 254) as i8
    }
}

/// The quaternion (z, w) of a rotation by `theta` radians about z.
pub fn yaw_quaternion(theta: f64) -> (f64, f64) {
    ((theta / 2.0).sin(), (theta / 2.0).cos())
}

/// A planar transform: where `child`'s origin lies in `parent` and how it is turned.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform {
    pub stamp_ns: u64,
    pub parent: &'static str,
    pub child: &'static str,
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

impl Transform {
    /// The sensor in the map at a pose.
    pub fn sensor(stamp_ns: u64, x: f32, y: f32, theta: f32) -> Self {
        Self {
            stamp_ns,
            parent: MAP_FRAME,
            child: SENSOR_FRAME,
            x: f64::from(x),
            y: f64::from(y),
            theta: f64::from(theta),
        }
    }
}

/// A well-known channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Channel {
    FoxgloveMap,
    FoxgloveScan,
    FoxgloveTransform,
    FoxgloveFeatures,
    FoxgloveBeam,
    Ros2Map,
    Ros2Scan,
    Ros2Transform,
}

/// What a channel needs declared: topic, schema and encodings.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelSpec {
    pub topic: &'static str,
    pub schema_name: String,
    pub schema_encoding: String,
    pub schema: Vec<u8>,
    pub message_encoding: String,
}

impl Channel {
    pub const FOXGLOVE: [Channel; 5] = [
        Channel::FoxgloveMap,
        Channel::FoxgloveScan,
        Channel::FoxgloveTransform,
        Channel::FoxgloveFeatures,
        Channel::FoxgloveBeam,
    ];
    pub const ROS2: [Channel; 3] = [Channel::Ros2Map, Channel::Ros2Scan, Channel::Ros2Transform];

    pub fn topic(self) -> &'static str {
        match self {
            Channel::FoxgloveMap => "/foxglove/map",
            Channel::FoxgloveScan => "/foxglove/scan",
            Channel::FoxgloveTransform => "/foxglove/tf",
            Channel::FoxgloveFeatures => "/foxglove/features",
            Channel::FoxgloveBeam => "/foxglove/beam",
            Channel::Ros2Map => "/map",
            Channel::Ros2Scan => "/scan",
            Channel::Ros2Transform => "/tf",
        }
    }

    pub fn spec(self) -> ChannelSpec {
        use foxglove::messages as fm;
        let (schema_name, schema_encoding, schema, message_encoding) = match self {
            Channel::FoxgloveMap => foxglove_msgs::schema::<fm::Grid>(),
            Channel::FoxgloveScan => foxglove_msgs::schema::<fm::LaserScan>(),
            Channel::FoxgloveTransform => foxglove_msgs::schema::<fm::FrameTransform>(),
            Channel::FoxgloveFeatures | Channel::FoxgloveBeam => {
                foxglove_msgs::schema::<fm::SceneUpdate>()
            }
            Channel::Ros2Map => {
                ros2_spec("nav_msgs/msg/OccupancyGrid", ros2::occupancy_grid_schema())
            }
            Channel::Ros2Scan => ros2_spec("sensor_msgs/msg/LaserScan", ros2::laser_scan_schema()),
            Channel::Ros2Transform => {
                ros2_spec("tf2_msgs/msg/TFMessage", ros2::tf_message_schema())
            }
        };
        ChannelSpec {
            topic: self.topic(),
            schema_name,
            schema_encoding,
            schema,
            message_encoding,
        }
    }
}

/// Schema name, schema encoding, schema, message encoding.
type SchemaParts = (String, String, Vec<u8>, String);

fn ros2_spec(name: &str, text: String) -> SchemaParts {
    (
        name.into(),
        ros2::SCHEMA_ENCODING.into(),
        text.into_bytes(),
        ros2::MESSAGE_ENCODING.into(),
    )
}

/// One message for a well-known channel.
#[derive(Debug, Clone, PartialEq)]
pub struct Output {
    pub channel: Channel,
    /// The stamp of what it shows, ns since the Unix epoch (MCAP's publish time).
    pub stamp_ns: u64,
    pub data: Vec<u8>,
}

/// Settings of [`WellKnown`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Also the ROS 2 messages.
    pub ros2: bool,
    /// At most one map per this many ns of snapshot stamps (the latest is kept in between and
    /// given by [`WellKnown::finish`]).
    pub grid_period_ns: u64,
}

/// Turns the pipeline's payloads into well-known messages (see the crate docs).
#[derive(Debug)]
pub struct WellKnown {
    options: Options,
    scans: SweepScans,
    /// Stamp of the last map given out.
    last_grid_ns: Option<u64>,
    /// The newest snapshot not given out yet (it came within `grid_period_ns` of the last).
    pending_grid: Option<(GridHeader, Vec<u8>)>,
    /// A pose source exists: the transforms follow it, not the grid's copy of the pose.
    pose_seen: bool,
    last_transform_ns: Option<u64>,
    last_beam_ns: Option<u64>,
}

impl WellKnown {
    pub fn new(options: Options) -> Self {
        Self {
            options,
            scans: SweepScans::default(),
            last_grid_ns: None,
            pending_grid: None,
            pose_seen: false,
            last_transform_ns: None,
            last_beam_ns: None,
        }
    }

    /// The channels this converter writes on.
    pub fn channels(&self) -> Vec<Channel> {
        let mut channels = Channel::FOXGLOVE.to_vec();
        if self.options.ros2 {
            channels.extend(Channel::ROS2);
        }
        channels
    }

    /// A reading: the previous sweep's scan when it begins a new sweep, and its beam unless one
    /// was given less than [`BEAM_PERIOD_NS`] before (by the readings' stamps).
    pub fn reading(&mut self, reading: &Reading) -> Vec<Output> {
        let mut out = match self.scans.push(reading) {
            Some(scan) => self.scan(&scan),
            None => Vec::new(),
        };
        let stamp_ns = reading.host_stamp_ns;
        let due = self
            .last_beam_ns
            .is_none_or(|last| stamp_ns < last || stamp_ns >= last.saturating_add(BEAM_PERIOD_NS));
        if due {
            self.last_beam_ns = Some(stamp_ns);
            out.push(Output {
                channel: Channel::FoxgloveBeam,
                stamp_ns,
                data: foxglove_msgs::encode(&foxglove_msgs::beam(reading)),
            });
        }
        out
    }

    /// A pose of the sensor: its transform, unless one was given less than 50 ms before.
    pub fn pose(&mut self, pose: &Pose2D) -> Vec<Output> {
        self.pose_seen = true;
        let due = self
            .last_transform_ns
            .is_none_or(|last| pose.stamp_ns >= last.saturating_add(TRANSFORM_PERIOD_NS));
        if !due {
            return Vec::new();
        }
        self.transform(Transform::sensor(
            pose.stamp_ns,
            pose.x_m,
            pose.y_m,
            pose.theta_rad,
        ))
    }

    /// A features snapshot: the scene of walls, corners and posts.
    pub fn features(&mut self, header: &FeaturesHeader, records: &[FeatureRecord]) -> Vec<Output> {
        vec![Output {
            channel: Channel::FoxgloveFeatures,
            stamp_ns: header.stamp_ns,
            data: foxglove_msgs::encode(&foxglove_msgs::features(header, records)),
        }]
    }

    /// A map snapshot: the map if `grid_period` has passed since the last one given out, else
    /// nothing now (the snapshot is kept for later). A snapshot whose cells do not fill its
    /// width × height gives nothing.
    pub fn grid(&mut self, header: &GridHeader, cells: &[u8]) -> Vec<Output> {
        if (header.width as usize).checked_mul(header.height as usize) != Some(cells.len()) {
            return Vec::new();
        }
        let due = self
            .last_grid_ns
            .is_none_or(|last| header.stamp_ns >= last.saturating_add(self.options.grid_period_ns));
        if due {
            self.pending_grid = None;
            self.map(header, cells)
        } else {
            self.pending_grid = Some((*header, cells.to_vec()));
            Vec::new()
        }
    }

    /// The map kept back by [`Self::grid`] (a snapshot that came within `grid_period` of the last
    /// one given out), now, if there is one. A live server calls it once a `grid_period` has passed
    /// without a new snapshot: a pipeline that stopped would otherwise keep its last map back for
    /// ever.
    pub fn flush_map(&mut self) -> Vec<Output> {
        match self.pending_grid.take() {
            Some((header, cells)) => self.map(&header, &cells),
            None => Vec::new(),
        }
    }

    /// The end of the stream: the map kept back and the scan of the sweep in progress.
    pub fn finish(&mut self) -> Vec<Output> {
        let mut out = self.flush_map();
        if let Some(scan) = self.scans.finish() {
            out.extend(self.scan(&scan));
        }
        out
    }

    fn map(&mut self, header: &GridHeader, cells: &[u8]) -> Vec<Output> {
        self.last_grid_ns = Some(header.stamp_ns);
        let mut out = vec![Output {
            channel: Channel::FoxgloveMap,
            stamp_ns: header.stamp_ns,
            data: foxglove_msgs::encode(&foxglove_msgs::grid(header, cells)),
        }];
        if self.options.ros2 {
            out.push(Output {
                channel: Channel::Ros2Map,
                stamp_ns: header.stamp_ns,
                data: ros2::occupancy_grid(header, cells, MAP_FRAME),
            });
        }
        if !self.pose_seen {
            // A fixed head (no pose source): the sensor where the fusion placed it.
            out.extend(self.transform(Transform::sensor(
                header.stamp_ns,
                header.pose_x_m,
                header.pose_y_m,
                header.pose_theta_rad,
            )));
        }
        out
    }

    fn scan(&self, scan: &Scan) -> Vec<Output> {
        let mut out = vec![Output {
            channel: Channel::FoxgloveScan,
            stamp_ns: scan.stamp_ns,
            data: foxglove_msgs::encode(&foxglove_msgs::laser_scan(scan)),
        }];
        if self.options.ros2 {
            out.push(Output {
                channel: Channel::Ros2Scan,
                stamp_ns: scan.stamp_ns,
                data: ros2::laser_scan(scan, SENSOR_FRAME),
            });
        }
        out
    }

    fn transform(&mut self, t: Transform) -> Vec<Output> {
        self.last_transform_ns = Some(t.stamp_ns);
        let mut out = vec![Output {
            channel: Channel::FoxgloveTransform,
            stamp_ns: t.stamp_ns,
            data: foxglove_msgs::encode(&foxglove_msgs::frame_transform(&t)),
        }];
        if self.options.ros2 {
            out.push(Output {
                channel: Channel::Ros2Transform,
                stamp_ns: t.stamp_ns,
                data: ros2::tf_message(&[t]),
            });
        }
        out
    }
}

#[cfg(test)]
mod tests;
