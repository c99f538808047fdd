//! ROS 2 messages in CDR, as `ros2 bag` stores them in MCAP: message encoding `cdr`, schema
//! encoding `ros2msg` with the message definition followed by those of the types it uses.
//!
//! CDR (XCDR1, little endian) as Fast DDS writes it: a 4-byte encapsulation header
//! `00 01 00 00` (CDR_LE), then the fields in order, each primitive aligned to its own size (at
//! most 8) counted from the end of the header; a string is a `uint32` length including the
//! terminating NUL, the bytes and the NUL; a sequence a `uint32` count and the elements. Only the
//! three messages below are written, so a small writer does it.

use sonar_common::ipc::GridHeader;

use crate::frame::Transform;
use crate::occupancy::occupancy;
use crate::scan::Scan;
use crate::schema::SchemaParts;

/// Schema encoding of ROS 2 message definitions in MCAP.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// Message encoding of ROS 2 messages in MCAP.
pub const MESSAGE_ENCODING: &str = "cdr";

const SEPARATOR: &str =
    "================================================================================\n";

/// The definitions the three messages use, each once.
const HEADER: &str = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n";
const TIME: &str = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";
const POSE: &str = "MSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation\n";
const POINT: &str = "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n";
const QUATERNION: &str =
    "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n";
const VECTOR3: &str = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n";

fn definition(main: &str, uses: &[&str]) -> String {
    let mut text = main.to_owned();
    for used in uses {
        text.push_str(SEPARATOR);
        text.push_str(used);
    }
    text
}

/// `nav_msgs/msg/OccupancyGrid` with its dependencies.
pub fn occupancy_grid_schema() -> String {
    definition(
        "std_msgs/Header header\nMapMetaData info\nint8[] data\n",
        &[
            HEADER,
            TIME,
            "MSG: nav_msgs/MapMetaData\nbuiltin_interfaces/Time map_load_time\nfloat32 resolution\n\
             uint32 width\nuint32 height\ngeometry_msgs/Pose origin\n",
            POSE,
            POINT,
            QUATERNION,
        ],
    )
}

/// `sensor_msgs/msg/LaserScan` with its dependencies.
pub fn laser_scan_schema() -> String {
    definition(
        "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\nfloat32 angle_increment\n\
         float32 time_increment\nfloat32 scan_time\nfloat32 range_min\nfloat32 range_max\n\
         float32[] ranges\nfloat32[] intensities\n",
        &[HEADER, TIME],
    )
}

/// `tf2_msgs/msg/TFMessage` with its dependencies.
pub fn tf_message_schema() -> String {
    definition(
        "geometry_msgs/TransformStamped[] transforms\n",
        &[
            "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n\
             Transform transform\n",
            HEADER,
            TIME,
            "MSG: geometry_msgs/Transform\nVector3 translation\nQuaternion rotation\n",
            VECTOR3,
            QUATERNION,
        ],
    )
}

/// A CDR little-endian message under construction.
#[derive(Debug)]
struct Cdr {
    buf: Vec<u8>,
}

/// The CDR_LE encapsulation header.
const ENCAPSULATION: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

impl Cdr {
    fn new() -> Self {
        Self {
            buf: ENCAPSULATION.to_vec(),
        }
    }

    /// Pads to a multiple of `n` bytes counted from the end of the encapsulation header.
    fn align(&mut self, n: usize) {
        let offset = self.buf.len() - ENCAPSULATION.len();
        let pad = (n - offset % n) % n;
        self.buf.extend(std::iter::repeat_n(0, pad));
    }

    /// A primitive's little-endian bytes, aligned to its size.
    fn put<const N: usize>(&mut self, bytes: [u8; N]) {
        self.align(N);
        self.buf.extend_from_slice(&bytes);
    }

    fn u32(&mut self, v: u32) {
        self.put(v.to_le_bytes());
    }

    fn i32(&mut self, v: i32) {
        self.put(v.to_le_bytes());
    }

    fn f32(&mut self, v: f32) {
        self.put(v.to_le_bytes());
    }

    fn f64(&mut self, v: f64) {
        self.put(v.to_le_bytes());
    }

    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    fn len(&mut self, n: usize) {
        self.u32(u32::try_from(n).unwrap_or(u32::MAX));
    }

    /// `builtin_interfaces/Time`, from ns since the Unix epoch.
    fn time(&mut self, stamp_ns: u64) {
        let sec = i32::try_from(stamp_ns / 1_000_000_000).unwrap_or(i32::MAX);
        self.i32(sec);
        self.u32((stamp_ns % 1_000_000_000) as u32);
    }

    fn header(&mut self, stamp_ns: u64, frame_id: &str) {
        self.time(stamp_ns);
        self.string(frame_id);
    }

    /// A 3-vector then a quaternion (a `geometry_msgs/Pose` or `Transform`) for a planar pose.
    fn planar(&mut self, x: f64, y: f64, theta: f64) {
        for v in [x, y, 0.0] {
            self.f64(v);
        }
        let (qz, qw) = crate::frame::yaw_quaternion(theta);
        for v in [0.0, 0.0, qz, qw] {
            self.f64(v);
        }
    }
}

/// The map as `nav_msgs/msg/OccupancyGrid` in frame `frame_id`: the cells as
/// [`occupancy`](crate::occupancy::occupancy) (−1 unknown, 0–100), row 0 at the lowest y, like ours.
pub fn occupancy_grid(header: &GridHeader, cells: &[u8], frame_id: &str) -> Vec<u8> {
    let mut m = Cdr::new();
    m.header(header.stamp_ns, frame_id);
    m.time(header.stamp_ns); // map_load_time
    m.f32(header.resolution_m);
    m.u32(header.width);
    m.u32(header.height);
    m.planar(
        f64::from(header.origin_x_m),
        f64::from(header.origin_y_m),
        0.0,
    );
    m.len(cells.len());
    m.buf.extend(cells.iter().map(|&c| occupancy(c) as u8));
    m.buf
}

/// A sweep as `sensor_msgs/msg/LaserScan` in frame `frame_id`.
pub fn laser_scan(scan: &Scan, frame_id: &str) -> Vec<u8> {
    let mut m = Cdr::new();
    m.header(scan.stamp_ns, frame_id);
    m.f32(scan.start_rad as f32);
    m.f32(scan.end_rad() as f32);
    m.f32(scan.step_rad as f32);
    m.f32(0.0); // time_increment: unknown per reading
    m.f32(0.0); // scan_time: unknown
    m.f32(scan.min_range_m as f32);
    m.f32(scan.max_range_m as f32);
    m.len(scan.ranges.len());
    for &r in &scan.ranges {
        m.f32(r as f32);
    }
    m.len(0); // intensities
    m.buf
}

/// Transforms as `tf2_msgs/msg/TFMessage`.
pub fn tf_message(transforms: &[Transform]) -> Vec<u8> {
    let mut m = Cdr::new();
    m.len(transforms.len());
    for t in transforms {
        m.header(t.stamp_ns, t.parent);
        m.string(t.child);
        m.planar(t.x, t.y, t.theta);
    }
    m.buf
}

/// The schema of a ROS 2 message type from its definition's text.
pub(crate) fn schema_parts(name: &str, text: String) -> SchemaParts {
    (
        name.into(),
        SCHEMA_ENCODING.into(),
        text.into_bytes(),
        MESSAGE_ENCODING.into(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_are_aligned_from_the_end_of_the_encapsulation_header() {
        let mut m = Cdr::new();
        m.string("ab"); // 4 + 3 bytes: offset 7
        m.f64(1.5); // padded to 8
        m.u32(7);
        let mut expected = vec![0, 1, 0, 0, 3, 0, 0, 0, b'a', b'b', 0, 0];
        expected.extend(1.5f64.to_le_bytes());
        expected.extend(7u32.to_le_bytes());
        assert_eq!(m.buf, expected);
    }

    #[test]
    fn a_tf_message_has_its_layout_byte_for_byte() {
        let t = Transform {
            stamp_ns: 3_000_000_005,
            parent: "map",
            child: "sonar",
            x: 1.0,
            y: 2.0,
            theta: 0.0,
        };
        let bytes = tf_message(&[t]);
        let mut e = ENCAPSULATION.to_vec();
        e.extend(1u32.to_le_bytes()); // count
        e.extend(3i32.to_le_bytes()); // sec
        e.extend(5u32.to_le_bytes()); // nanosec
        e.extend(4u32.to_le_bytes());
        e.extend(b"map\0");
        e.extend(6u32.to_le_bytes());
        e.extend(b"sonar\0");
        e.extend([0, 0]); // offset 30 → 32
        for v in [1.0f64, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0] {
            e.extend(v.to_le_bytes());
        }
        assert_eq!(bytes, e);
    }

    #[test]
    fn schemas_name_each_dependency_once() {
        for schema in [
            occupancy_grid_schema(),
            laser_scan_schema(),
            tf_message_schema(),
        ] {
            let names: Vec<&str> = schema.lines().filter(|l| l.starts_with("MSG: ")).collect();
            let mut unique = names.clone();
            unique.sort_unstable();
            unique.dedup();
            assert_eq!(names.len(), unique.len(), "{schema}");
        }
    }
}
