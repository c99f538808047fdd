//! Plane geometry in metres: the few vector operations the scene and the echo model need.

use std::ops::{Add, Mul, Sub};

use serde::{Deserialize, Serialize};

/// A point or vector in the scene plane, metres. Files write it as `[x, y]`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(from = "[f64; 2]", into = "[f64; 2]")]
pub struct Vec2 {
    pub x: f64,
    pub y: f64,
}

impl Vec2 {
    pub const fn new(x: f64, y: f64) -> Self {
        Self { x, y }
    }

    pub fn dot(self, o: Self) -> f64 {
        self.x * o.x + self.y * o.y
    }

    /// z component of the 3-D cross product: positive when `o` is counter-clockwise of `self`.
    pub fn cross(self, o: Self) -> f64 {
        self.x * o.y - self.y * o.x
    }

    pub fn norm(self) -> f64 {
        self.x.hypot(self.y)
    }

    /// Direction seen from the origin, degrees counter-clockwise from +x, in (−180, 180].
    pub fn angle_deg(self) -> f64 {
        self.y.atan2(self.x).to_degrees()
    }

    pub fn is_finite(self) -> bool {
        self.x.is_finite() && self.y.is_finite()
    }
}

impl From<[f64; 2]> for Vec2 {
    fn from([x, y]: [f64; 2]) -> Self {
        Self { x, y }
    }
}

impl From<Vec2> for [f64; 2] {
    fn from(v: Vec2) -> Self {
        [v.x, v.y]
    }
}

impl Add for Vec2 {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self::new(self.x + o.x, self.y + o.y)
    }
}

impl Sub for Vec2 {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Self::new(self.x - o.x, self.y - o.y)
    }
}

impl Mul<f64> for Vec2 {
    type Output = Self;
    fn mul(self, k: f64) -> Self {
        Self::new(self.x * k, self.y * k)
    }
}

/// Where the sensor's rotation axis stands in the scene and where its 0° points: `heading_rad`
/// counter-clockwise from +x (the robot's heading; the head's angles count from it). The default is
/// the fixed head: at the origin, facing +x.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose {
    pub at: Vec2,
    pub heading_rad: f64,
}

impl Pose {
    pub const fn new(x: f64, y: f64, heading_rad: f64) -> Self {
        Self {
            at: Vec2::new(x, y),
            heading_rad,
        }
    }

    pub fn is_finite(self) -> bool {
        self.at.is_finite() && self.heading_rad.is_finite()
    }
}

/// `a − b` wrapped into (−π, π], radians: how far direction `a` lies counter-clockwise of `b`.
pub fn angle_diff_rad(a: f64, b: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    let d = (a - b).rem_euclid(tau);
    if d > std::f64::consts::PI { d - tau } else { d }
}

/// `v` turned counter-clockwise by `rad`.
pub fn rotate(v: Vec2, rad: f64) -> Vec2 {
    let (s, c) = rad.sin_cos();
    Vec2::new(c * v.x - s * v.y, s * v.x + c * v.y)
}

/// Whether segments `a`–`b` and `c`–`d` cross or touch (collinear overlaps count as touching).
pub fn segments_intersect(a: Vec2, b: Vec2, c: Vec2, d: Vec2) -> bool {
    let (r, s) = (b - a, d - c);
    let denom = r.cross(s);
    if denom.abs() < 1e-12 {
        // Parallel: they meet only if collinear and overlapping.
        return (c - a).cross(r).abs() < 1e-12
            && (distance_to_segment(a, b, c) < 1e-9
                || distance_to_segment(a, b, d) < 1e-9
                || distance_to_segment(c, d, a) < 1e-9);
    }
    let t = (c - a).cross(s) / denom;
    let u = (c - a).cross(r) / denom;
    (0.0..=1.0).contains(&t) && (0.0..=1.0).contains(&u)
}

/// `a − b` wrapped into (−180, 180]: how far direction `a` lies counter-clockwise of `b`.
pub fn angle_diff_deg(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    if d > 180.0 { d - 360.0 } else { d }
}

/// Parameter in [0, 1] of the point of segment `a`–`b` nearest to `p`.
pub fn nearest_on_segment(a: Vec2, b: Vec2, p: Vec2) -> f64 {
    let e = b - a;
    let len2 = e.dot(e);
    if len2 == 0.0 {
        0.0
    } else {
        ((p - a).dot(e) / len2).clamp(0.0, 1.0)
    }
}

/// Distance from `p` to the segment `a`–`b`.
pub fn distance_to_segment(a: Vec2, b: Vec2, p: Vec2) -> f64 {
    let t = nearest_on_segment(a, b, p);
    (a + (b - a) * t - p).norm()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angles_wrap_into_half_open_interval() {
        assert_eq!(angle_diff_deg(10.0, 350.0), 20.0);
        assert_eq!(angle_diff_deg(350.0, 10.0), -20.0);
        assert_eq!(angle_diff_deg(-180.0, 0.0), 180.0);
        assert!((Vec2::new(0.0, 2.0).angle_deg() - 90.0).abs() < 1e-12);
    }

    #[test]
    fn segment_distance() {
        let (a, b) = (Vec2::new(1.0, -1.0), Vec2::new(1.0, 1.0));
        assert!((distance_to_segment(a, b, Vec2::default()) - 1.0).abs() < 1e-12);
        assert!((distance_to_segment(a, b, Vec2::new(1.0, 3.0)) - 2.0).abs() < 1e-12);
        assert_eq!(Vec2::new(1.0, 0.0).cross(Vec2::new(0.0, 1.0)), 1.0);
    }

    #[test]
    fn rotations_and_crossings() {
        let v = rotate(Vec2::new(1.0, 0.0), std::f64::consts::FRAC_PI_2);
        assert!((v - Vec2::new(0.0, 1.0)).norm() < 1e-12);
        assert!((angle_diff_rad(-3.0, 3.0) - (std::f64::consts::TAU - 6.0)).abs() < 1e-12);
        let (a, b) = (Vec2::new(0.0, 0.0), Vec2::new(2.0, 0.0));
        assert!(segments_intersect(
            a,
            b,
            Vec2::new(1.0, -1.0),
            Vec2::new(1.0, 1.0)
        ));
        assert!(!segments_intersect(
            a,
            b,
            Vec2::new(3.0, -1.0),
            Vec2::new(3.0, 1.0)
        ));
        assert!(segments_intersect(
            a,
            b,
            Vec2::new(1.5, 0.0),
            Vec2::new(4.0, 0.0)
        ));
        assert!(!segments_intersect(
            a,
            b,
            Vec2::new(0.0, 1.0),
            Vec2::new(2.0, 1.0)
        ));
    }
}
