//! [`WellKnown`]: the pipeline's payloads in, the well-known messages out, at modest rates (see
//! the crate's documentation); and the channels it writes on.

use sonar_common::ipc::{
    FeatureRecord, FeaturesHeader, GridHeader, LocalizedPose, Pose2D, Reading, SlamCorrection,
    slam_state,
};

use tracing::warn;

use crate::frame::{Correction, MAP_FRAME, SENSOR_FRAME, Transform};
use crate::scan::{Scan, SweepScans};
use crate::{foxglove_msgs, ros2};
/// Transforms closer together than this are left out (the simulator publishes 20 poses a
/// simulated second, hundreds a real second when it runs fast).
const TRANSFORM_PERIOD_NS: u64 = 50_000_000;
/// Beams of readings closer together than this are left out: the real head takes a few readings a
/// second, all drawn; the simulator at 100× some 500, of which 10 a second are enough to watch.
pub const BEAM_PERIOD_NS: u64 = 100_000_000;

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
                ros2::schema_parts("nav_msgs/msg/OccupancyGrid", ros2::occupancy_grid_schema())
            }
            Channel::Ros2Scan => {
                ros2::schema_parts("sensor_msgs/msg/LaserScan", ros2::laser_scan_schema())
            }
            Channel::Ros2Transform => {
                ros2::schema_parts("tf2_msgs/msg/TFMessage", ros2::tf_message_schema())
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
    /// The sensor's transform (`odom → sonar`) last given out, with the correction (`map →
    /// odom`) given out with it.
    last_sensor: Option<(Transform, Correction)>,
    /// The latest correction of the odometry (`map → odom`), sent with each sensor transform.
    correction: Correction,
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
            last_sensor: None,
            correction: Correction::IDENTITY,
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
    /// was given less than [`BEAM_PERIOD_NS`] before (by the readings' stamps); either after the
    /// sensor's latest transforms (`map → odom` and `odom → sonar` as they were given out) on
    /// Foxglove's channel. A live client that connected since the last transform (a pose's come at
    /// most 20 a second, a fixed head's with each map) would otherwise get a scan or a beam in
    /// frame `sonar` before any transform: Foxglove 1.48 keeps that complaint on a scan for good
    /// (its point history adds the error and never removes it).
    pub fn reading(&mut self, reading: &Reading) -> Vec<Output> {
        let scan = self.scans.push(reading);
        let stamp_ns = reading.host_stamp_ns;
        let beam_due = self
            .last_beam_ns
            .is_none_or(|last| stamp_ns < last || stamp_ns >= last.saturating_add(BEAM_PERIOD_NS));
        let mut out = Vec::new();
        if scan.is_none() && !beam_due {
            return out;
        }
        // Foxglove's channel only: the same transforms again on ROS 2's `/tf` are what tf2 warns
        // about (a repeated stamp).
        if let Some((sensor, correction)) = self.sensor_as_given_out(stamp_ns) {
            out.extend(foxglove_transforms(sensor, correction));
        }
        if let Some(scan) = scan {
            out.extend(self.scan(&scan));
        }
        if beam_due {
            self.last_beam_ns = Some(stamp_ns);
            out.push(Output {
                channel: Channel::FoxgloveBeam,
                stamp_ns,
                data: foxglove_msgs::encode(&foxglove_msgs::beam(reading)),
            });
        }
        out
    }

    /// The sensor's transform and correction as last given out; a fixed head before its first
    /// map at the origin (where the fusion places it) as of `stamp_ns`; a moving one before its
    /// first pose nowhere known yet.
    fn sensor_as_given_out(&self, stamp_ns: u64) -> Option<(Transform, Correction)> {
        match (self.last_sensor, self.pose_seen) {
            (Some(sent), _) => Some(sent),
            (None, false) => Some((
                Transform::sensor(stamp_ns, 0.0, 0.0, 0.0),
                Correction::IDENTITY,
            )),
            (None, true) => None,
        }
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
        self.transform(
            Transform::sensor(pose.stamp_ns, pose.x_m, pose.y_m, pose.theta_rad),
            self.correction,
        )
    }

    /// A correction of the odometry, map ← odom (`x`, `y` in metres, `theta` in radians), as of
    /// `stamp_ns`: from the next sensor transform on, `map → odom` is this one (the sources
    /// send theirs in order, one a sweep). One that is not finite is left out with a warning.
    pub fn correction(&mut self, stamp_ns: u64, x: f64, y: f64, theta: f64) {
        let correction = Correction { x, y, theta };
        if correction.is_finite() {
            self.correction = correction;
        } else {
            warn!(
                stamp_ns,
                ?correction,
                "correction of the odometry left out: not finite"
            );
        }
    }

    /// A `sonar-slam` estimate (`sonar/slam_correction`): its correction, unless it revises an
    /// earlier sweep (state `REVISED`: the current correction is the latest of the others).
    pub fn slam_correction(&mut self, c: &SlamCorrection) {
        if c.state != slam_state::REVISED {
            self.correction(
                c.stamp_ns,
                f64::from(c.correction_x_m),
                f64::from(c.correction_y_m),
                f64::from(c.correction_theta_rad),
            );
        }
    }

    /// The fusion's localised pose (`sonar/localized_pose`): the correction that carries its
    /// odometry pose onto its localised one.
    pub fn localized_pose(&mut self, p: &LocalizedPose) {
        let c = Correction::between(
            (f64::from(p.x_m), f64::from(p.y_m), f64::from(p.theta_rad)),
            (
                f64::from(p.odometry_x_m),
                f64::from(p.odometry_y_m),
                f64::from(p.odometry_theta_rad),
            ),
        );
        self.correction(p.stamp_ns, c.x, c.y, c.theta);
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
            // A fixed head (no pose source): the sensor where the fusion placed it, in the map
            // already (`map → odom` the identity).
            out.extend(self.transform(
                Transform::sensor(
                    header.stamp_ns,
                    header.pose_x_m,
                    header.pose_y_m,
                    header.pose_theta_rad,
                ),
                Correction::IDENTITY,
            ));
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

    /// The sensor's transform (`odom → sonar`) with a correction (`map → odom`) at its stamp, so
    /// that every lookup from `sonar` to `map` finds both.
    fn transform(&mut self, t: Transform, correction: Correction) -> Vec<Output> {
        self.last_transform_ns = Some(t.stamp_ns);
        self.last_sensor = Some((t, correction));
        let mut out = foxglove_transforms(t, correction).to_vec();
        if self.options.ros2 {
            out.push(Output {
                channel: Channel::Ros2Transform,
                stamp_ns: t.stamp_ns,
                data: ros2::tf_message(&[Transform::correction(t.stamp_ns, correction), t]),
            });
        }
        out
    }
}

/// `map → odom` (`correction`, at the sensor's stamp) and `odom → sonar`, each a FrameTransform on
/// Foxglove's channel.
fn foxglove_transforms(sensor: Transform, correction: Correction) -> [Output; 2] {
    [Transform::correction(sensor.stamp_ns, correction), sensor].map(|t| Output {
        channel: Channel::FoxgloveTransform,
        stamp_ns: t.stamp_ns,
        data: foxglove_msgs::encode(&foxglove_msgs::frame_transform(&t)),
    })
}
