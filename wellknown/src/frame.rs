//! The frames the messages are in, and a planar transform between two of them.

/// The world frame of the map.
pub const MAP_FRAME: &str = "map";
/// The sensor's frame: x is its 0°, angles counter-clockwise.
pub const SENSOR_FRAME: &str = "sonar";

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
