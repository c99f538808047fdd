//! The scene every head maps (`tests/scenes/room-post.toml`): the paper's square room 2.4 m wide,
//! the sensor at its centre facing +x, and a 5 cm post 0.9 m ahead, with what a head must find
//! there on `sonar/features`, checked against the true geometry.
//!
//! Tolerances, from what limits each estimate (`docs/features.md`, "Uncertainty"):
//! - a bearing is the middle of a region (or one modelled half-cone in from a natural end), whose
//!   ends are each known to one step between pings: at worst **half a step** for a centre, **one
//!   step** for an end, plus the cones' 0.5°; across the beam that is range × that angle;
//! - a range is the mean of the region's pings: the simulator's detector fires up to two cycles
//!   late (≤ 8.6 mm), whole-centimetre heads round by ≤ 5 mm: **2 cm** covers both with margin
//!   (a wrong target, a wall taken for a corner, is off by 50 cm).

use std::path::PathBuf;

use sonar_common::ipc::{FeatureRecord, feature_kind};

/// The walls' distance from the sensor, metres.
pub const WALL_M: f64 = 1.2;
/// The post's near face, where its echo comes from: centre 0.9 m, radius 2.5 cm.
pub const POST_ECHO_M: f64 = 0.875;
/// Range tolerance (module docs).
const RANGE_TOLERANCE_M: f64 = 0.02;
/// Uncertainty of a modelled cone.
const CONE_SIGMA_DEG: f64 = 0.5;

/// The scene file, for `--scene`.
pub fn scene() -> String {
    crate::workspace()
        .join("tests/scenes/room-post.toml")
        .to_str()
        .unwrap()
        .to_owned()
}

/// The scene file's path.
pub fn scene_path() -> PathBuf {
    PathBuf::from(scene())
}

/// What a head whose pings are `step_deg` apart must find of the room.
#[derive(Debug, Clone)]
pub struct Expected {
    pub step_deg: f64,
    /// Normals of the walls it faces (0° = ahead, 90° = left), degrees.
    pub walls_deg: Vec<f64>,
    /// Bearings of the corners in its view (±45°, ±135°).
    pub corners_deg: Vec<f64>,
}

/// A true corner at `bearing_deg`.
fn corner_at(bearing_deg: f64) -> (f64, f64) {
    let (s, c) = bearing_deg.to_radians().sin_cos();
    (WALL_M * c.signum(), WALL_M * s.signum())
}

impl Expected {
    /// Across-the-beam tolerance at `range_m` for a bearing good to `angle_deg`.
    fn across_m(range_m: f64, angle_deg: f64) -> f64 {
        RANGE_TOLERANCE_M + range_m * angle_deg.to_radians()
    }

    fn near(&self, r: &FeatureRecord, x: f64, y: f64) -> bool {
        let range = x.hypot(y);
        let tolerance = Self::across_m(range, self.step_deg + CONE_SIGMA_DEG);
        (f64::from(r.x_m) - x).hypot(f64::from(r.y_m) - y) <= tolerance
    }

    /// A plane record on the wall of normal `normal_deg`: its normal within a step (and the
    /// cones' uncertainty), its distance within the range tolerance.
    fn on_wall(&self, r: &FeatureRecord, normal_deg: f64) -> bool {
        let angle = f64::from(r.angle_deg) - normal_deg;
        let angle = (angle + 180.0).rem_euclid(360.0) - 180.0;
        let distance = f64::from(r.x_m).hypot(f64::from(r.y_m));
        r.kind == feature_kind::PLANE
            && angle.abs() <= self.step_deg + CONE_SIGMA_DEG
            && (distance - WALL_M).abs() <= RANGE_TOLERANCE_M
    }

    fn on_corner(&self, r: &FeatureRecord, bearing_deg: f64) -> bool {
        let (x, y) = corner_at(bearing_deg);
        r.kind == feature_kind::CORNER && self.near(r, x, y)
    }

    fn on_post(&self, r: &FeatureRecord) -> bool {
        r.kind == feature_kind::POINT && self.near(r, POST_ECHO_M, 0.0)
    }

    /// Whether `records` hold every expected wall, corner and the post, and nothing that is not
    /// on the room's true walls, corners or post; else what is wrong.
    pub fn check(&self, records: &[FeatureRecord]) -> Result<(), String> {
        let mut wrong = Vec::new();
        for &w in &self.walls_deg {
            if !records.iter().any(|r| self.on_wall(r, w)) {
                wrong.push(format!("no wall of normal {w}°"));
            }
        }
        for &c in &self.corners_deg {
            if !records.iter().any(|r| self.on_corner(r, c)) {
                wrong.push(format!("no corner at {c}°"));
            }
        }
        if !records.iter().any(|r| self.on_post(r)) {
            wrong.push("no post".to_owned());
        }
        let all = [0.0, 90.0, 180.0, -90.0];
        let corners = [45.0, 135.0, -135.0, -45.0];
        for r in records {
            let true_feature = self.on_post(r)
                || all.iter().any(|&w| self.on_wall(r, w))
                || corners.iter().any(|&c| self.on_corner(r, c));
            if !true_feature {
                wrong.push(format!(
                    "false feature: kind {} at ({:.3}, {:.3}), angle {:.1}°, seen {}",
                    r.kind, r.x_m, r.y_m, r.angle_deg, r.times_seen
                ));
            }
        }
        if wrong.is_empty() {
            Ok(())
        } else {
            Err(wrong.join("; "))
        }
    }
}
