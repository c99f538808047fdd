//! The frames the messages are in, and a planar transform between two of them.
//!
//! The tree is `map → odom → sonar`: `odom → sonar` is the sensor's pose as the odometry has it
//! (`robot/pose`; a fixed head's pose in its grid), `map → odom` the correction of that odometry
//! (the fusion's localisation or `sonar-slam`; identity until one is known). A scan in `sonar`
//! looked up in `map` goes through both, so it is drawn where the corrected pose places it.

/// The world frame of the map.
pub const MAP_FRAME: &str = "map";
/// The odometry's frame: where `robot/pose` places the sensor, drift and all.
pub const ODOM_FRAME: &str = "odom";
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
    /// The sensor in the odometry's frame at a pose (`odom → sonar`).
    pub fn sensor(stamp_ns: u64, x: f32, y: f32, theta: f32) -> Self {
        Self {
            stamp_ns,
            parent: ODOM_FRAME,
            child: SENSOR_FRAME,
            x: f64::from(x),
            y: f64::from(y),
            theta: f64::from(theta),
        }
    }

    /// The odometry's frame in the map (`map → odom`): a correction, at `stamp_ns`.
    pub fn correction(stamp_ns: u64, correction: Correction) -> Self {
        Self {
            stamp_ns,
            parent: MAP_FRAME,
            child: ODOM_FRAME,
            x: correction.x,
            y: correction.y,
            theta: correction.theta,
        }
    }
}

/// A correction of the odometry, map ← odom: a pose `p` of `robot/pose` lies in the map at
/// `correction ∘ p`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correction {
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

impl Correction {
    /// No correction: the odometry is the map.
    pub const IDENTITY: Self = Self {
        x: 0.0,
        y: 0.0,
        theta: 0.0,
    };

    /// The correction that carries the odometry's pose (x, y, θ) onto the pose `placed` in the
    /// map: `placed ∘ odometry⁻¹`.
    pub fn between(placed: (f64, f64, f64), odometry: (f64, f64, f64)) -> Self {
        let theta = placed.2 - odometry.2;
        let (sin, cos) = theta.sin_cos();
        Self {
            x: placed.0 - (cos * odometry.0 - sin * odometry.1),
            y: placed.1 - (sin * odometry.0 + cos * odometry.1),
            theta,
        }
    }

    /// Whether every part is a number (a NaN correction would hide the whole tree).
    pub fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.theta.is_finite()
    }

    /// A point of the odometry's frame in the map.
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let (sin, cos) = self.theta.sin_cos();
        (self.x + cos * x - sin * y, self.y + sin * x + cos * y)
    }
}
