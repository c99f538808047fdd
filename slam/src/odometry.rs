//! The odometry as the graph uses it: stamped poses interpolated at any instant, the steps between
//! two sweeps, those steps corrected by the odometry's systematic errors, and the covariance of
//! their random part.
//!
//! The error model is the one [`sonar_features::DriftFilter`] learns (UMBmark's systematic errors
//! plus white noise): a step (δx, δy, δθ) reported over |δ| metres was truly
//!
//! ```text
//! translation (δx, δy) / (1 + a)          a: scale error
//! turn        (δθ − b·|δ|) / (1 + c)      b: heading drift per metre reported, c: turn error
//! ```
//!
//! with a, b, c unknown constants of the robot (variables of the graph, with the prior of
//! [`OdometryErrors`]) and a random error growing with √distance and √turn. Keeping the
//! systematic part out of the random covariance is what keeps the covariance honest over a long
//! leg: a constant drift grows linearly with distance, not with its square root.

use nalgebra::{Isometry2, Matrix3, Vector2, Vector3};
use sonar_features::{OdometryErrors, wrap_rad};

/// Smallest σ of a segment's random error, metres and degrees: two sweeps at one stop are
/// still two estimates, and a zero covariance would make the graph singular.
const FLOOR_M: f64 = 0.001;
const FLOOR_DEG: f64 = 0.05;

/// One odometry step in the frame of its start: (δx, δy, δθ).
pub type Step = Vector3<f64>;

/// Stamped odometry poses, oldest first.
#[derive(Debug, Clone, Default)]
pub struct OdometryTrack {
    samples: Vec<(u64, Isometry2<f64>)>,
}

impl OdometryTrack {
    /// Adds the odometry's pose at `stamp_ns`; `false` (nothing added) for a stamp older than the
    /// last one or a pose that is not finite.
    pub fn push(&mut self, stamp_ns: u64, pose: Isometry2<f64>) -> bool {
        let finite = pose.translation.vector.iter().all(|v| v.is_finite())
            && pose.rotation.angle().is_finite();
        if !finite || self.samples.last().is_some_and(|(t, _)| *t > stamp_ns) {
            return false;
        }
        self.samples.push((stamp_ns, pose));
        true
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The oldest sample kept: its stamp and pose.
    pub fn first(&self) -> Option<(u64, Isometry2<f64>)> {
        self.samples.first().copied()
    }

    /// The pose at `stamp_ns`, interpolated between the samples around it (linearly in
    /// position, the shorter way in heading) and held beyond them; `None` without samples.
    pub fn at(&self, stamp_ns: u64) -> Option<Isometry2<f64>> {
        let i = self.samples.partition_point(|(t, _)| *t <= stamp_ns);
        match (
            i.checked_sub(1).and_then(|k| self.samples.get(k)),
            self.samples.get(i),
        ) {
            (Some((ta, a)), Some((tb, b))) => {
                let f = (stamp_ns - ta) as f64 / (tb - ta) as f64;
                let t = a.translation.vector.lerp(&b.translation.vector, f);
                let (ha, hb) = (a.rotation.angle(), b.rotation.angle());
                Some(Isometry2::new(t, ha + wrap_rad(hb - ha) * f))
            }
            (Some((_, only)), None) | (None, Some((_, only))) => Some(*only),
            (None, None) => None,
        }
    }

    /// The steps from the pose at `from_ns` to the pose at `to_ns`, through every sample between.
    pub fn steps(&self, from_ns: u64, to_ns: u64) -> Vec<Step> {
        let (Some(start), Some(end)) = (self.at(from_ns), self.at(to_ns)) else {
            return Vec::new();
        };
        let inner = self
            .samples
            .iter()
            .filter(|(t, _)| *t > from_ns && *t < to_ns)
            .map(|(_, p)| *p);
        let mut steps = Vec::new();
        let mut last = start;
        for pose in inner.chain(std::iter::once(end)) {
            let d = last.inverse() * pose;
            steps.push(Vector3::new(
                d.translation.x,
                d.translation.y,
                d.rotation.angle(),
            ));
            last = pose;
        }
        steps
    }

    /// Forgets the samples before the last one at or before `stamp_ns` (kept for interpolation).
    pub fn forget_before(&mut self, stamp_ns: u64) {
        let keep_from = self
            .samples
            .partition_point(|(t, _)| *t <= stamp_ns)
            .saturating_sub(1);
        self.samples.drain(..keep_from);
    }
}

/// `steps` composed after correcting each by the systematic errors `calibration` = (a, b, c):
/// the true motion they describe, in the frame of their start.
pub fn corrected(steps: &[Step], calibration: &Vector3<f64>) -> Vector3<f64> {
    let (a, b, c) = (calibration.x, calibration.y, calibration.z);
    let mut pose = Vector3::<f64>::zeros();
    for s in steps {
        let ds = s.x.hypot(s.y);
        let (tx, ty) = (s.x / (1.0 + a), s.y / (1.0 + a));
        let turn = (s.z - b * ds) / (1.0 + c);
        let (sin, cos) = pose.z.sin_cos();
        pose.x += cos * tx - sin * ty;
        pose.y += sin * tx + cos * ty;
        pose.z += turn;
    }
    pose
}

/// Covariance of the random error of `steps` composed, in the frame of their start (x, y, θ),
/// propagated step by step, with a floor of 1 mm and 0.05° (`FLOOR_M`, `FLOOR_DEG`).
pub fn random_covariance(steps: &[Step], errors: &OdometryErrors) -> Matrix3<f64> {
    let position = errors.position_noise_m_per_sqrt_m.powi(2);
    let heading = errors.heading_noise_deg_per_sqrt_m.to_radians().powi(2);
    let turning = errors.turn_noise_deg_per_sqrt_rad.to_radians().powi(2);
    let mut pose = Vector3::<f64>::zeros();
    let mut p = Matrix3::from_diagonal(&Vector3::new(
        FLOOR_M.powi(2),
        FLOOR_M.powi(2),
        FLOOR_DEG.to_radians().powi(2),
    ));
    for s in steps {
        let ds = s.x.hypot(s.y);
        let (sin, cos) = pose.z.sin_cos();
        let moved = Vector2::new(cos * s.x - sin * s.y, sin * s.x + cos * s.y);
        let mut f = Matrix3::identity();
        f[(0, 2)] = -moved.y;
        f[(1, 2)] = moved.x;
        let q = Matrix3::from_diagonal(&Vector3::new(
            position * ds,
            position * ds,
            heading * ds + turning * s.z.abs(),
        ));
        p = f * p * f.transpose() + q;
        pose += Vector3::new(moved.x, moved.y, s.z);
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(x: f64, y: f64, deg: f64) -> Isometry2<f64> {
        Isometry2::new(Vector2::new(x, y), deg.to_radians())
    }

    #[test]
    fn poses_are_interpolated_and_held_beyond_the_samples() {
        let mut track = OdometryTrack::default();
        assert_eq!(track.at(5), None);
        assert!(track.push(10, pose(0.0, 0.0, 170.0)));
        assert!(track.push(20, pose(1.0, 0.0, -170.0)));
        assert!(!track.push(15, pose(2.0, 0.0, 0.0)), "older stamp refused");
        let mid = track.at(15).unwrap();
        assert!((mid.translation.x - 0.5).abs() < 1e-12);
        // Across ±180° the shorter way.
        assert!(wrap_rad(mid.rotation.angle() - std::f64::consts::PI).abs() < 1e-9);
        assert_eq!(track.at(0), Some(pose(0.0, 0.0, 170.0)));
        assert_eq!(track.at(99), Some(pose(1.0, 0.0, -170.0)));
    }

    #[test]
    fn steps_compose_back_to_the_relative_pose_and_forgetting_keeps_interpolation() {
        let mut track = OdometryTrack::default();
        for k in 0..=10 {
            let k = f64::from(k);
            track.push((k * 100.0) as u64, pose(0.1 * k, 0.02 * k * k, 9.0 * k));
        }
        let steps = track.steps(150, 850);
        let relative = track.at(150).unwrap().inverse() * track.at(850).unwrap();
        let composed = corrected(&steps, &Vector3::zeros());
        assert!((composed.x - relative.translation.x).abs() < 1e-9);
        assert!((composed.y - relative.translation.y).abs() < 1e-9);
        assert!(wrap_rad(composed.z - relative.rotation.angle()).abs() < 1e-9);
        let before = track.at(450);
        track.forget_before(450);
        assert_eq!(track.at(450), before);
    }

    #[test]
    fn the_correction_takes_a_known_drift_out() {
        // 1 m straight ahead reported 3 % long in 100 steps, with 2°/m of heading drift: the
        // corrected motion ends 1 m ahead with no turn.
        let a = 0.03;
        let b = 2.0_f64.to_radians();
        let steps: Vec<Step> = (0..100)
            .map(|_| Vector3::new(0.01 * (1.0 + a), 0.0, b * 0.01 * (1.0 + a)))
            .collect();
        let truth = corrected(&steps, &Vector3::new(a, b, 0.0));
        assert!((truth.x - 1.0).abs() < 1e-9 && truth.y.abs() < 1e-9 && truth.z.abs() < 1e-9);
        // Uncorrected, it is 3 % long and turned by 2.06°.
        let raw = corrected(&steps, &Vector3::zeros());
        assert!((raw.z.to_degrees() - 2.06).abs() < 1e-9, "{raw}");
    }

    #[test]
    fn the_random_error_grows_with_the_distance_and_across_with_the_heading() {
        let errors = OdometryErrors::default();
        let steps: Vec<Step> = (0..100).map(|_| Vector3::new(0.02, 0.0, 0.0)).collect();
        let p = random_covariance(&steps, &errors);
        // 2 m: along σ² = 0.01² · 2 (+ floor); across more, from the heading's error.
        assert!((p[(0, 0)] - (2e-4 + 1e-6)).abs() < 1e-9, "{p}");
        assert!(p[(1, 1)] > p[(0, 0)], "{p}");
        assert!(p[(1, 2)] > 0.0, "{p}");
        let none = random_covariance(&[], &errors);
        assert!(none.determinant() > 0.0);
    }
}
