//! The SLAM's landmarks against the scene's true geometry: is each wall landmark on a true wall,
//! and does its covariance cover its error; is each point landmark on a surface.
//!
//! A wall landmark is an infinite line (φ, d): normal direction and signed distance from the
//! map's origin (the tour's world frame: the odometry starts at the true pose). It is on a true
//! wall when some wall of the scene runs within [`WALL_DEGREES`] of its direction and its line
//! passes within [`WALL_METRES`] of the landmark's along the normal; its error is then taken
//! against the nearest such wall, and its NEES against its own (φ, d) covariance. A point
//! landmark (a post or a corner: the SLAM does not tell them apart) is on a surface when it lies
//! within [`POINT_METRES`] of one. Landmarks that are on nothing are phantoms: echoes the SLAM
//! took for geometry and may anchor poses on.

use nalgebra::{Matrix2, Vector2};
use sonar_sim::{Scene, Vec2};
use sonar_slam::{Landmark, LandmarkKind};

/// A wall landmark farther than this from every true wall of its direction is a phantom (m).
pub const WALL_METRES: f64 = 0.10;
/// ... or turned more than this from every true wall (degrees).
pub const WALL_DEGREES: f64 = 5.0;
/// A point landmark farther than this from every surface is a phantom (m).
pub const POINT_METRES: f64 = 0.10;
/// χ² of 2 degrees of freedom at 95 %.
const CHI2_2_95: f64 = 5.991;

/// The landmarks of one tour's end, scored.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LandmarkScore {
    pub walls: usize,
    /// Walls on no true wall.
    pub phantom_walls: usize,
    /// Walls on a true wall with a covariance, and of those the ones whose error lies inside
    /// their own 95 % ellipse.
    pub walls_with_covariance: usize,
    pub walls_inside_95: usize,
    pub points: usize,
    pub phantom_points: usize,
}

/// Scores `landmarks` against `scene`.
pub fn score(scene: &Scene, landmarks: &[Landmark]) -> LandmarkScore {
    let mut s = LandmarkScore::default();
    for l in landmarks {
        match l.kind {
            LandmarkKind::Line => {
                s.walls += 1;
                match wall_error(scene, l.mean) {
                    None => s.phantom_walls += 1,
                    Some(error) => {
                        if let Some(nees) = l.covariance.and_then(|c| nees(&error, &c)) {
                            s.walls_with_covariance += 1;
                            if nees <= CHI2_2_95 {
                                s.walls_inside_95 += 1;
                            }
                        }
                    }
                }
            }
            LandmarkKind::Point => {
                s.points += 1;
                let at = Vec2 {
                    x: l.mean.x,
                    y: l.mean.y,
                };
                if scene.distance_to_surface(at) > POINT_METRES {
                    s.phantom_points += 1;
                }
            }
        }
    }
    s
}

/// The error (Δφ rad, Δd m) of the wall landmark (φ, d) against the nearest true wall running its
/// way, `None` if no true wall does within [`WALL_DEGREES`] and [`WALL_METRES`].
fn wall_error(scene: &Scene, line: Vector2<f64>) -> Option<Vector2<f64>> {
    let (phi, d) = (line.x, line.y);
    scene
        .walls()
        .iter()
        .filter_map(|w| {
            let along = Vector2::new(w.b.x - w.a.x, w.b.y - w.a.y);
            if along.norm() == 0.0 {
                return None;
            }
            // The true wall's normal, turned to the landmark's side.
            let mut normal = Vector2::new(-along.y, along.x).normalize();
            if normal.dot(&Vector2::new(phi.cos(), phi.sin())) < 0.0 {
                normal = -normal;
            }
            let true_phi = normal.y.atan2(normal.x);
            let true_d = normal.dot(&Vector2::new(w.a.x, w.a.y));
            let error = Vector2::new(wrap(true_phi - phi), true_d - d);
            (error.x.abs().to_degrees() <= WALL_DEGREES && error.y.abs() <= WALL_METRES)
                .then_some(error)
        })
        .min_by(|a, b| a.y.abs().total_cmp(&b.y.abs()))
}

fn nees(error: &Vector2<f64>, covariance: &Matrix2<f64>) -> Option<f64> {
    covariance
        .try_inverse()
        .map(|inverse| (error.transpose() * inverse * error)[(0, 0)])
}

fn wrap(angle: f64) -> f64 {
    (angle + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

#[cfg(test)]
mod tests {
    use super::*;

    fn room() -> Scene {
        Scene::from_toml_str(
            r#"
            name = "box"
            [[segments]]
            from = [-1.0, -1.0]
            to = [1.0, -1.0]
            [[segments]]
            from = [1.0, -1.0]
            to = [1.0, 1.0]
            [[circles]]
            centre = [0.0, 0.5]
            radius = 0.05
            "#,
            "box",
        )
        .unwrap()
    }

    fn wall(phi_deg: f64, d: f64, sigma_deg: f64, sigma_m: f64) -> Landmark {
        Landmark {
            kind: LandmarkKind::Line,
            mean: Vector2::new(phi_deg.to_radians(), d),
            covariance: Some(Matrix2::new(
                sigma_deg.to_radians().powi(2),
                0.0,
                0.0,
                sigma_m.powi(2),
            )),
            sightings: 2,
        }
    }

    #[test]
    fn walls_on_true_walls_are_scored_against_their_covariance_and_others_are_phantoms() {
        let scene = room();
        let landmarks = [
            // The wall at y = −1 seen from inside: normal −y, d = 1; 1 cm off, σ 2 cm: inside.
            wall(-90.0, 1.01, 1.0, 0.02),
            // The wall at x = 1 with its normal the other way round (d < 0): the same line.
            wall(180.0, -1.0, 1.0, 0.02),
            // The same wall 4 cm off but claiming 5 mm: on the wall, outside its ellipse.
            wall(0.0, 1.04, 0.5, 0.005),
            // Slanted 15°: no wall runs that way.
            wall(15.0, 0.5, 2.0, 0.05),
            // Parallel to the wall at x = 1 but 40 cm in front of it.
            wall(0.0, 0.6, 1.0, 0.02),
        ];
        let s = score(&scene, &landmarks);
        assert_eq!((s.walls, s.phantom_walls), (5, 2), "{s:?}");
        assert_eq!(
            (s.walls_with_covariance, s.walls_inside_95),
            (3, 2),
            "{s:?}"
        );
    }

    #[test]
    fn points_on_a_surface_count_and_points_in_the_air_are_phantoms() {
        let scene = room();
        let point = |x: f64, y: f64| Landmark {
            kind: LandmarkKind::Point,
            mean: Vector2::new(x, y),
            covariance: None,
            sightings: 2,
        };
        // The post's near side, the corner, and a point in the middle of the room.
        let s = score(
            &scene,
            &[point(0.0, 0.44), point(0.98, -0.98), point(0.0, 0.0)],
        );
        assert_eq!((s.points, s.phantom_points), (3, 1), "{s:?}");
    }
}
