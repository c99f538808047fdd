//! Sonar localisation: one sweep's observations matched against the feature map built so far, to
//! correct a pose predicted by odometry.
//!
//! The robot's odometry drifts (a wheel's scale error, a heading that creeps); the features of
//! the map do not move. A sweep taken at an odometry pose sees the walls, corners and posts a
//! little off from where the map has them; the pose that puts them back is the correction.
//!
//! # The estimate
//!
//! A maximum a-posteriori pose by Gauss–Newton over x = (x, y, θ):
//!
//! ```text
//! minimise  (x − x₀)ᵀ P₀⁻¹ (x − x₀)  +  Σᵢ vᵢ(x)ᵀ Sᵢ⁻¹ vᵢ(x)
//! ```
//!
//! where x₀ is the predicted pose with covariance P₀ (the odometry's uncertainty since the last
//! fix), vᵢ the innovation of observation i placed at x against its matched feature — the same
//! innovation the map merges with: (x, y) for points and corners, (φ, d) for planes — and Sᵢ the
//! feature's covariance plus the observation's. The Jacobians of vᵢ are taken numerically, so every
//! kind uses the one placement function the merging uses. The posterior covariance is the inverse
//! of the final normal matrix.
//!
//! A wall constrains only the distance across it and the heading; a point or corner the position.
//! Directions no match constrains stay at the prediction (the prior term), with its uncertainty:
//! in a long corridor with no corners the estimate along the corridor is odometry's.
//!
//! # Association
//!
//! Each observation goes to the nearest feature of its kind (one sweep's sighting is enough: a
//! robot that stops once at each place sees most features from one stop only)
//! within the merge gate (χ² of [`crate::MergeConfig::gate_chi2`]), with the pose's own
//! uncertainty added to the gate: a prediction 5 cm off must still find its wall. Associations are
//! made again at each iteration, from the current estimate.
//!
//! # Refusing a fix
//!
//! A fix lying farther from the prediction than the prediction's own uncertainty allows (χ² of 3
//! degrees of freedom at 99.9 %) is refused, and so is one resting on less than the caller asks
//! ([`Needs`]): the sweep is then placed at the prediction. A sweep taken standing still is fixed
//! by one wall (its heading and the distance across it; the odometry keeps the direction along
//! it); one taken on the move needs more — its pings were brought together by the odometry, and
//! a turn during the sweep breaks a wall's run into phantom walls that a single match may take
//! for a real one (`fusion/src/features.rs` chooses, with the figures).

use nalgebra::{Isometry2, Matrix2, Matrix3};

use crate::classify::Observation;
use crate::feature::FeatureKind;
use crate::map::{FeatureMap, Placed, innovation};

/// Most Gauss–Newton iterations.
const MAX_ITERATIONS: usize = 10;
/// An update smaller than this (metres and radians) ends the iterations.
const CONVERGED: f64 = 1e-6;
/// What a fix must rest on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Needs {
    /// One matched wall, or two matches of any kind (never one post or corner: it leaves the
    /// heading to the prior's linearisation, and one wrong association turns the robot).
    OneWallOrTwo,
    /// At least this many matches of any kind.
    Matches(usize),
}

impl Needs {
    fn met_by(self, matched: usize, walls: usize) -> bool {
        match self {
            Needs::OneWallOrTwo => walls >= 1 || matched >= 2,
            Needs::Matches(n) => matched >= n,
        }
    }
}
/// Largest squared Mahalanobis distance of a fix from its prediction, χ² of 3 degrees of freedom
/// at 99.9 %: a fix farther than the odometry can have drifted is a wrong association.
const FIX_GATE: f64 = 16.27;

/// Smallest number of sweeps a wall must have been seen in to range on it from a single ping: a
/// wall seen once may be a phantom of a sweep.
const RANGING_MIN_SIGHTINGS: u32 = 3;

/// A wall a ping is expected to hear on its perpendicular, in the map: the normal's direction φ
/// (radians) and the distance d from the map's origin, with σ of d. From a sensor at p the range
/// is d − p·n(φ).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallAhead {
    pub normal_rad: f64,
    pub distance_m: f64,
    pub distance_sigma_m: f64,
}

/// A corrected pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseFix {
    /// The sensor's pose in the map.
    pub pose: Isometry2<f64>,
    /// Covariance of (x, y, θ): m², m·rad, rad².
    pub covariance: Matrix3<f64>,
    /// Observations matched to a feature.
    pub matched: usize,
    pub iterations: usize,
}

impl FeatureMap {
    /// The nearest wall a ping from `pose` along `bearing_rad` (sensor frame) hears on its
    /// perpendicular: a wall seen in [`RANGING_MIN_SIGHTINGS`] sweeps or more, in front of the
    /// sensor, its normal within `cone_rad` of the ping's axis (the specular cut-off, less a
    /// margin). `None` when no wall qualifies. Whether the ping heard that wall and not something
    /// nearer, or a doorway's far side, is for the range gate to decide.
    pub fn wall_ahead(
        &self,
        pose: &Isometry2<f64>,
        bearing_rad: f64,
        cone_rad: f64,
    ) -> Option<WallAhead> {
        let axis = pose.rotation.angle() + bearing_rad;
        let p = pose.translation.vector;
        self.tracked()
            .iter()
            .filter(|f| f.kind() == FeatureKind::Plane && f.times_seen() >= RANGING_MIN_SIGHTINGS)
            .filter_map(|f| {
                let (phi, d) = (f.mean_own().x, f.mean_own().y);
                let range = d - p.dot(&f.normal());
                (range > 0.0 && crate::geometry::wrap_rad(phi - axis).abs() <= cone_rad).then(
                    || {
                        (
                            range,
                            WallAhead {
                                normal_rad: phi,
                                distance_m: d,
                                distance_sigma_m: f.covariance_own()[(1, 1)].sqrt(),
                            },
                        )
                    },
                )
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, wall)| wall)
    }

    /// The pose at which `observations` (one sweep's, in the sensor's frame) fit the map best,
    /// starting from `prior` with covariance `prior_covariance` (of x, y, θ). `None` when the
    /// matches are fewer than `needs`, the fix lies beyond what the prior allows, or the prior
    /// covariance is not invertible.
    pub fn localize(
        &self,
        observations: &[Observation],
        needs: Needs,
        prior: &Isometry2<f64>,
        prior_covariance: &Matrix3<f64>,
    ) -> Option<PoseFix> {
        let prior_information = prior_covariance.try_inverse()?;
        let x0 = crate::geometry::pose_vector(prior);
        let gate = self.config().merge.gate_chi2;
        let anchors = self.tracked();
        let mut x = x0;
        let mut covariance = *prior_covariance;
        let mut matched = 0;
        let mut walls = 0;
        let mut iterations = 0;
        while iterations < MAX_ITERATIONS {
            iterations += 1;
            let mut h = prior_information;
            let mut d = x - x0;
            d.z = crate::geometry::wrap_rad(d.z);
            let mut g = prior_information * d;
            matched = 0;
            walls = 0;
            for o in observations {
                let (placed, jacobian) = Placed::with_jacobian(o, &x);
                let jt = jacobian.transpose();
                let observed = placed.covariance();
                let best = anchors
                    .iter()
                    .filter(|f| f.kind() == o.kind)
                    .filter_map(|f| {
                        let v = innovation(f, &placed);
                        let s = f.covariance_own() + observed;
                        let gated: Matrix2<f64> = s + jt.transpose() * covariance * jt;
                        let d2 = (v.transpose() * gated.try_inverse()? * v)[(0, 0)];
                        (d2 <= gate).then_some((d2, v, jt, s))
                    })
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                let Some((_, v, jt, s)) = best else { continue };
                let Some(w) = s.try_inverse() else { continue };
                h += jt * w * jt.transpose();
                g += jt * w * v;
                matched += 1;
                walls += usize::from(o.kind == FeatureKind::Plane);
            }
            if matched == 0 {
                return None;
            }
            let h_inv = h.try_inverse()?;
            let step = -(h_inv * g);
            x += step;
            x.z = crate::geometry::wrap_rad(x.z);
            covariance = h_inv;
            if step.norm() < CONVERGED {
                break;
            }
        }
        let mut d = x - x0;
        d.z = crate::geometry::wrap_rad(d.z);
        let d2 = (d.transpose() * prior_information * d)[(0, 0)];
        (needs.met_by(matched, walls) && d2 <= FIX_GATE).then_some(PoseFix {
            pose: crate::geometry::vector_pose(&x),
            covariance,
            matched,
            iterations,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{FeatureConfig, FeatureKind, Sweep};
    use nalgebra::Point2;
    use nalgebra::{Vector2, Vector3};

    /// What a sensor at `pose` observes of: a wall x = 2 (normal +x), a wall y = 1.5 (normal
    /// +y), a post at (1, −0.8) and a corner at (2, 1.5).
    fn observe(pose: &Isometry2<f64>, with: &[FeatureKind]) -> Vec<Observation> {
        let theta = pose.rotation.angle();
        let t = pose.translation.vector;
        let mut out = Vec::new();
        let polar = |kind, p: Point2<f64>| {
            let local = pose.inverse() * p;
            Observation {
                kind,
                range_m: local.coords.norm(),
                bearing_deg: local.y.atan2(local.x).to_degrees(),
                range_sigma_random_m: 0.003,
                range_sigma_systematic_m: 0.002,
                bearing_sigma_deg: 0.4,
                bearing_sigma_random_deg: 0.0,
                rcd: 0,
                whole: true,
                also_plane: false,
                also_corner: false,
                pair_centre_deg: None,
            }
        };
        for kind in with {
            match kind {
                FeatureKind::Plane => {
                    for (normal_deg, d) in [(0.0_f64, 2.0), (90.0, 1.5)] {
                        let n = Vector2::new(
                            normal_deg.to_radians().cos(),
                            normal_deg.to_radians().sin(),
                        );
                        out.push(Observation {
                            kind: FeatureKind::Plane,
                            range_m: d - t.dot(&n),
                            bearing_deg: crate::geometry::wrap_deg(normal_deg - theta.to_degrees()),
                            range_sigma_random_m: 0.003,
                            range_sigma_systematic_m: 0.002,
                            bearing_sigma_deg: 0.4,
                            bearing_sigma_random_deg: 0.0,
                            rcd: 0,
                            whole: true,
                            also_plane: false,
                            also_corner: false,
                            pair_centre_deg: None,
                        });
                    }
                }
                FeatureKind::Point => out.push(polar(FeatureKind::Point, Point2::new(1.0, -0.8))),
                FeatureKind::Corner => out.push(polar(FeatureKind::Corner, Point2::new(2.0, 1.5))),
            }
        }
        out
    }

    const ALL: [FeatureKind; 3] = [FeatureKind::Plane, FeatureKind::Point, FeatureKind::Corner];

    /// A map of the scene built from two places, each seen twice.
    fn built_map() -> FeatureMap {
        let mut map = FeatureMap::new(FeatureConfig::default()).unwrap();
        let no_pings = Sweep::from_pings(Vec::new(), 1.5).unwrap();
        for pose in [
            Isometry2::new(Vector2::new(0.0, 0.0), 0.0),
            Isometry2::new(Vector2::new(0.3, 0.2), 0.5),
        ] {
            for _ in 0..2 {
                map.merge(&observe(&pose, &ALL), &no_pings, &pose, &Matrix3::zeros());
            }
        }
        assert_eq!(map.tracked().len(), 4, "{:?}", map.tracked());
        map
    }

    fn prior_covariance() -> Matrix3<f64> {
        Matrix3::from_diagonal(&Vector3::new(
            0.1_f64.powi(2),
            0.1_f64.powi(2),
            5.0_f64.to_radians().powi(2),
        ))
    }

    #[test]
    fn a_drifted_pose_is_pulled_back_onto_the_map() {
        let map = built_map();
        let truth = Isometry2::new(Vector2::new(0.6, 0.1), -0.3);
        let drifted = Isometry2::new(Vector2::new(0.65, 0.06), -0.3 + 3.0_f64.to_radians());
        let fix = map
            .localize(
                &observe(&truth, &ALL),
                Needs::Matches(2),
                &drifted,
                &prior_covariance(),
            )
            .expect("a fix");
        let err = truth.inverse() * fix.pose;
        assert!(err.translation.vector.norm() < 0.005, "{fix:?}");
        assert!(err.rotation.angle().abs() < 0.2_f64.to_radians(), "{fix:?}");
        assert_eq!(fix.matched, 4);
        // The fix is far more certain than the prediction.
        assert!(
            fix.covariance[(0, 0)] < 0.01 * prior_covariance()[(0, 0)],
            "{fix:?}"
        );
    }

    #[test]
    fn a_single_match_is_no_fix_but_one_wall_fixes_a_standing_sweep() {
        let map = built_map();
        let truth = Isometry2::new(Vector2::new(0.6, 0.1), 0.0);
        let drifted = Isometry2::new(Vector2::new(0.65, 0.16), 2.0_f64.to_radians());
        // Only the wall x = 2 is seen. From a sweep on the move, where one wrong association
        // would turn the robot: refused.
        let wall: Vec<Observation> = observe(&truth, &[FeatureKind::Plane])
            .into_iter()
            .take(1)
            .collect();
        assert_eq!(
            map.localize(&wall, Needs::Matches(2), &drifted, &prior_covariance()),
            None
        );
        // From a standing sweep the wall alone fixes the heading and the distance across it (x,
        // the wall being x = 2), and leaves y at the prediction.
        let fix = map
            .localize(&wall, Needs::OneWallOrTwo, &drifted, &prior_covariance())
            .expect("a fix");
        assert_eq!(fix.matched, 1);
        assert!(
            (fix.pose.translation.x - truth.translation.x).abs() < 0.005,
            "{fix:?}"
        );
        assert!(
            fix.pose.rotation.angle().abs() < 0.2_f64.to_radians(),
            "{fix:?}"
        );
        assert!(
            (fix.pose.translation.y - drifted.translation.y).abs() < 0.005,
            "{fix:?}"
        );
        // A post alone is no fix either way.
        let post = observe(&truth, &[FeatureKind::Point]);
        assert_eq!(
            map.localize(&post, Needs::OneWallOrTwo, &drifted, &prior_covariance()),
            None
        );
        // With the post beside it, the fix stands.
        let both: Vec<Observation> = wall
            .into_iter()
            .chain(observe(&truth, &[FeatureKind::Point]))
            .collect();
        let fix = map
            .localize(&both, Needs::Matches(2), &drifted, &prior_covariance())
            .expect("a fix");
        assert_eq!(fix.matched, 2);
        assert!(
            (truth.inverse() * fix.pose).translation.vector.norm() < 0.005,
            "{fix:?}"
        );
    }

    #[test]
    fn a_fix_farther_than_the_drift_allows_is_refused() {
        let map = built_map();
        let truth = Isometry2::new(Vector2::new(0.6, 0.1), 0.0);
        let drifted = Isometry2::new(Vector2::new(0.65, 0.16), 2.0_f64.to_radians());
        // A prediction that claims to be good to 5 mm and 0.2° but is 8 cm off.
        let tight = Matrix3::from_diagonal(&Vector3::new(
            0.005_f64.powi(2),
            0.005_f64.powi(2),
            0.2_f64.to_radians().powi(2),
        ));
        assert_eq!(
            map.localize(
                &observe(&truth, &ALL),
                Needs::OneWallOrTwo,
                &drifted,
                &tight
            ),
            None
        );
    }

    #[test]
    fn a_ping_ranges_on_the_wall_it_faces_on_its_perpendicular() {
        let map = built_map();
        let pose = Isometry2::new(Vector2::new(0.6, 0.1), 0.3);
        let cone = 20.0_f64.to_radians();
        let ahead = |deg: f64| map.wall_ahead(&pose, deg.to_radians() - 0.3, cone);
        // Straight at the wall x = 2 (and 15° off its normal, still within the cone).
        for deg in [0.0, 15.0] {
            let wall = ahead(deg).expect("the wall x = 2");
            assert!(wall.normal_rad.abs() < 0.01 && (wall.distance_m - 2.0).abs() < 0.01);
        }
        let wall = ahead(90.0).expect("the wall y = 1.5");
        assert!((wall.normal_rad - std::f64::consts::FRAC_PI_2).abs() < 0.01);
        assert!((wall.distance_m - 1.5).abs() < 0.01, "{wall:?}");
        // Between the walls' cones, and behind the sensor: no wall on its perpendicular.
        assert_eq!(ahead(45.0), None);
        assert_eq!(ahead(180.0), None);
        // A wall seen in one sweep only may be a phantom: not ranged on.
        let mut once = FeatureMap::new(FeatureConfig::default()).unwrap();
        let no_pings = Sweep::from_pings(Vec::new(), 1.5).unwrap();
        let origin = Isometry2::identity();
        once.merge(
            &observe(&origin, &[FeatureKind::Plane]),
            &no_pings,
            &origin,
            &Matrix3::zeros(),
        );
        assert_eq!(once.wall_ahead(&origin, 0.0, cone), None);
    }

    #[test]
    fn nothing_matched_is_no_fix() {
        let map = built_map();
        let far = Isometry2::new(Vector2::new(0.6, 0.1), 0.0);
        let obs = observe(&far, &ALL);
        // A prediction a metre off and certain of itself finds nothing within the gate.
        let wrong = Isometry2::new(Vector2::new(-0.6, -1.0), 1.0);
        let tight = Matrix3::from_diagonal(&Vector3::new(1e-6, 1e-6, 1e-6));
        for needs in [Needs::OneWallOrTwo, Needs::Matches(2)] {
            assert_eq!(map.localize(&obs, needs, &wrong, &tight), None);
            assert_eq!(map.localize(&[], needs, &far, &prior_covariance()), None);
        }
    }
}
