//! The odometry's systematic errors, learnt from the fixes: an extended Kalman filter over the
//! sensor's pose in the map **and** the odometry's scale error, heading drift and turn error.
//!
//! # Why estimate the drift, not only the pose
//!
//! A wheel odometry is wrong in a repeatable way (UMBmark's "systematic errors"): a wheel a little
//! larger than its nominal size reports every metre a few percent long, and two unequal wheels
//! turn the reported heading by so many degrees per metre driven. Between two fixes the pose then
//! drifts by the same law every time: correcting only the pose (a fixed map ← odometry transform,
//! as the first localisation did) lets 3 % and 2°/m grow again from every fix, 10 cm and 6° over
//! a 3 m leg without a fix. Once the filter knows the law, it predicts the next leg with what is
//! left: the odometry's random error and what the estimate of the law still lacks.
//!
//! # The model
//!
//! An odometry step (δx, δy, δθ) in the frame of its start (the odometry pose before it, inverted,
//! times the one after) is brought to the truth by three parameters:
//!
//! ```text
//! true translation = (δx, δy) / (1 + a)                 a: scale error (+0.03: reports 3 % long)
//! true turn        = (δθ − b·|δ|) / (1 + c)             b: heading drift, rad per metre reported
//!                                                       c: turn scale error
//! ```
//!
//! and applied to the pose (x, y, θ): translation rotated by θ, then the turn. The state is
//! (x, y, θ, a, b, c) plus a **clone** of the pose at the start of the sweep being taken: a fix
//! is of the sweep's start, found after the sweep has ended, and the clone's correlation with the
//! current pose and the parameters carries the fix to both (stochastic cloning, Roumeliotis &
//! Burdick 2002).
//!
//! # A fix as a measurement
//!
//! [`crate::FeatureMap::localize`] combines the sonar's matches with a prior (the clone's mean and
//! covariance, handed out by [`DriftFilter::sweep_prior`]) into a posterior. What the sonar alone
//! added is the difference of informations, Λ = P_post⁻¹ − P_prior⁻¹, and Λ·z = P_post⁻¹·δ (δ the
//! posterior's shift from the prior): a wall in a corridor constrains the heading and the distance
//! across, not along, and Λ says so. The filter takes Λ's eigen-directions as scalar measurements
//! of the clone, so a fix moves the current pose and the odometry's parameters through their
//! correlations, and a direction the sonar did not see is left to the odometry.
use nalgebra::{Isometry2, Matrix3, SMatrix, SVector, Vector2, Vector3};

use crate::geometry::{pose_vector, vector_pose, wrap_rad};
use crate::localize::{PoseFix, WallAhead};
use crate::odometry::OdometryErrors;

const N: usize = 9;
type State = SVector<f64, N>;
type Covariance = SMatrix<f64, N, N>;

/// Index of the pose (x, y, θ), the parameters a, b, c, and the clone's pose.
const POSE: usize = 0;
const SCALE: usize = 3;
const DRIFT: usize = 4;
const TURN: usize = 5;
const CLONE: usize = 6;

/// The odometry's drift as the filter knows it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftEstimate {
    /// Scale error a: +0.03 means the odometry reports 3 % more than driven.
    pub scale: f64,
    /// Heading drift b, degrees per metre reported.
    pub drift_deg_per_m: f64,
    /// Turn scale error c.
    pub turn: f64,
    /// Their σ, same units.
    pub scale_sigma: f64,
    pub drift_sigma_deg_per_m: f64,
    pub turn_sigma: f64,
}

/// Pose and odometry drift, predicted from the odometry and corrected by the fixes.
#[derive(Debug, Clone)]
pub struct DriftFilter {
    errors: OdometryErrors,
    x: State,
    p: Covariance,
    /// The odometry pose the state was last advanced to.
    odometry: Option<Isometry2<f64>>,
}

/// Largest squared innovation of a ping's range, in variances: χ² of one degree of freedom at
/// 99 %.
const RANGE_GATE: f64 = 6.63;

/// Smallest information (1/σ², in the units of x, y, θ) a fix's direction must add to count as a
/// measurement: σ = 10 m or 570°, i.e. none.
const MIN_INFORMATION: f64 = 0.01;

impl DriftFilter {
    /// A filter with the odometry's parameters unknown to within `errors`. The map's frame is the
    /// odometry's where it starts: the first odometry pose is taken as exact.
    pub fn new(errors: OdometryErrors) -> Self {
        let mut p = Covariance::zeros();
        // A tiny start uncertainty keeps every covariance the localisation sees invertible.
        p[(POSE, POSE)] = 1e-6;
        p[(POSE + 1, POSE + 1)] = 1e-6;
        p[(POSE + 2, POSE + 2)] = 0.01_f64.to_radians().powi(2);
        p[(SCALE, SCALE)] = errors.scale_sigma.powi(2);
        p[(DRIFT, DRIFT)] = errors.drift_sigma_deg_per_m.to_radians().powi(2);
        p[(TURN, TURN)] = errors.turn_sigma.powi(2);
        let mut filter = Self {
            errors,
            x: State::zeros(),
            p,
            odometry: None,
        };
        filter.begin_sweep();
        filter
    }

    /// The current pose estimate in the map.
    pub fn pose(&self) -> Isometry2<f64> {
        vector_pose(&self.x.fixed_rows::<3>(POSE).into_owned())
    }

    /// Map ← odometry at the latest odometry pose: what to apply to the odometry's poses until the
    /// next one.
    pub fn correction(&self) -> Isometry2<f64> {
        self.odometry
            .map_or(Isometry2::identity(), |o| self.pose() * o.inverse())
    }

    /// σ of the current heading, radians.
    pub fn heading_sigma_rad(&self) -> f64 {
        self.p[(POSE + 2, POSE + 2)].sqrt()
    }

    /// The odometry's drift as estimated so far.
    pub fn drift(&self) -> DriftEstimate {
        DriftEstimate {
            scale: self.x[SCALE],
            drift_deg_per_m: self.x[DRIFT].to_degrees(),
            turn: self.x[TURN],
            scale_sigma: self.p[(SCALE, SCALE)].sqrt(),
            drift_sigma_deg_per_m: self.p[(DRIFT, DRIFT)].sqrt().to_degrees(),
            turn_sigma: self.p[(TURN, TURN)].sqrt(),
        }
    }

    /// Moves the estimate by the odometry's step from the pose it last saw to `odometry`;
    /// `true` if the odometry moved.
    pub fn advance(&mut self, odometry: &Isometry2<f64>) -> bool {
        let Some(last) = self.odometry.replace(*odometry) else {
            self.x
                .fixed_rows_mut::<3>(POSE)
                .copy_from(&pose_vector(odometry));
            self.begin_sweep();
            return false;
        };
        let step = last.inverse() * odometry;
        let (dx, dy) = (step.translation.x, step.translation.y);
        let dtheta = step.rotation.angle();
        let ds = dx.hypot(dy);
        if ds == 0.0 && dtheta == 0.0 {
            return false;
        }
        let (a, b, c) = (self.x[SCALE], self.x[DRIFT], self.x[TURN]);
        let k = 1.0 / (1.0 + a);
        let (tx, ty) = (dx * k, dy * k);
        let raw_turn = dtheta - b * ds;
        let turn = raw_turn / (1.0 + c);
        let theta = self.x[POSE + 2];
        let (sin, cos) = theta.sin_cos();
        self.x[POSE] += cos * tx - sin * ty;
        self.x[POSE + 1] += sin * tx + cos * ty;
        self.x[POSE + 2] = wrap_rad(theta + turn);

        let mut f = Covariance::identity();
        f[(POSE, POSE + 2)] = -sin * tx - cos * ty;
        f[(POSE + 1, POSE + 2)] = cos * tx - sin * ty;
        // ∂(δ/(1 + a))/∂a = −δ/(1 + a)²
        f[(POSE, SCALE)] = -(cos * dx - sin * dy) * k * k;
        f[(POSE + 1, SCALE)] = -(sin * dx + cos * dy) * k * k;
        f[(POSE + 2, DRIFT)] = -ds / (1.0 + c);
        f[(POSE + 2, TURN)] = -raw_turn / (1.0 + c).powi(2);
        let mut q = Covariance::zeros();
        let e = &self.errors;
        let position = e.position_noise_m_per_sqrt_m.powi(2) * ds;
        q[(POSE, POSE)] = position;
        q[(POSE + 1, POSE + 1)] = position;
        q[(POSE + 2, POSE + 2)] = e.heading_noise_deg_per_sqrt_m.to_radians().powi(2) * ds
            + e.turn_noise_deg_per_sqrt_rad.to_radians().powi(2) * dtheta.abs();
        self.p = f * self.p * f.transpose() + q;
        true
    }

    /// Takes one ping's range `measured_m` (σ `sigma_m`) to `wall`, heard on its perpendicular
    /// from the current pose: a measurement of the distance across the wall. `false` when the
    /// range is farther from the prediction than [`RANGE_GATE`] allows (the ping heard something
    /// else), and nothing changes.
    pub fn range_to_wall(&mut self, wall: &WallAhead, measured_m: f64, sigma_m: f64) -> bool {
        let n = Vector2::new(wall.normal_rad.cos(), wall.normal_rad.sin());
        let p = Vector2::new(self.x[POSE], self.x[POSE + 1]);
        let innovation = measured_m - (wall.distance_m - p.dot(&n));
        let mut h = SMatrix::<f64, 1, N>::zeros();
        h[(0, POSE)] = -n.x;
        h[(0, POSE + 1)] = -n.y;
        let noise = sigma_m.powi(2) + wall.distance_sigma_m.powi(2);
        let taken = self.scalar_update(&h, innovation, noise, RANGE_GATE);
        if taken {
            self.wrap_angles();
        }
        taken
    }

    fn wrap_angles(&mut self) {
        self.x[POSE + 2] = wrap_rad(self.x[POSE + 2]);
        self.x[CLONE + 2] = wrap_rad(self.x[CLONE + 2]);
    }

    /// One scalar measurement `h`·x, `innovation` off the estimate, with variance `noise`; refused
    /// (`false`, nothing changes) when innovation² exceeds `gate` times its variance. The angles
    /// are left unwrapped for the caller.
    fn scalar_update(
        &mut self,
        h: &SMatrix<f64, 1, N>,
        innovation: f64,
        noise: f64,
        gate: f64,
    ) -> bool {
        let ph = self.p * h.transpose();
        let s = (h * ph)[(0, 0)] + noise;
        if innovation * innovation > gate * s {
            return false;
        }
        let gain = ph / s;
        self.x += gain * innovation;
        self.p -= gain * ph.transpose();
        self.p = (self.p + self.p.transpose()) * 0.5;
        true
    }

    /// Marks the start of a sweep: the pose now is the one its fix will be of.
    pub fn begin_sweep(&mut self) {
        let pose = self.x.fixed_rows::<3>(POSE).into_owned();
        self.x.fixed_rows_mut::<3>(CLONE).copy_from(&pose);
        // The clone is the pose: same rows and columns, and perfectly correlated with it.
        for i in 0..3 {
            let row = self.p.row(POSE + i).into_owned();
            self.p.set_row(CLONE + i, &row);
        }
        for i in 0..3 {
            let column = self.p.column(POSE + i).into_owned();
            self.p.set_column(CLONE + i, &column);
        }
    }

    /// The pose at the start of the sweep and its covariance: the prior to localise it from.
    pub fn sweep_prior(&self) -> (Isometry2<f64>, Matrix3<f64>) {
        (
            vector_pose(&self.x.fixed_rows::<3>(CLONE).into_owned()),
            self.p.fixed_view::<3, 3>(CLONE, CLONE).into_owned(),
        )
    }

    /// Takes `fix`, found by localising the sweep from [`Self::sweep_prior`]'s `prior_covariance`
    /// (the same one: the sonar's own information is the fix's less the prior's). `false` when
    /// the covariances are not invertible (the fix is then ignored).
    pub fn apply_fix(&mut self, fix: &PoseFix, prior_covariance: &Matrix3<f64>) -> bool {
        let (Some(posterior_information), Some(prior_information)) =
            (fix.covariance.try_inverse(), prior_covariance.try_inverse())
        else {
            return false;
        };
        let (prior, _) = self.sweep_prior();
        let mut shift = pose_vector(&fix.pose) - pose_vector(&prior);
        shift.z = wrap_rad(shift.z);
        let sonar = posterior_information - prior_information;
        let sonar = (sonar + sonar.transpose()) * 0.5;
        let sonar_times_measurement = posterior_information * shift;
        let eigen = sonar.symmetric_eigen();
        let clone_at_prior = self.x.fixed_rows::<3>(CLONE).into_owned();
        for k in 0..3 {
            let information = eigen.eigenvalues[k];
            if information < MIN_INFORMATION {
                continue;
            }
            let u: Vector3<f64> = eigen.eigenvectors.column(k).into_owned();
            // The sonar's measurement along u, relative to the prior's clone.
            let measured = u.dot(&sonar_times_measurement) / information;
            let mut now = self.x.fixed_rows::<3>(CLONE).into_owned() - clone_at_prior;
            now.z = wrap_rad(now.z);
            let innovation = measured - u.dot(&now);
            let mut h = SMatrix::<f64, 1, N>::zeros();
            h.fixed_columns_mut::<3>(CLONE).copy_from(&u.transpose());
            // The localisation gated the fix already.
            self.scalar_update(&h, innovation, 1.0 / information, f64::INFINITY);
        }
        self.wrap_angles();
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The odometry of a robot driving `path` (metres, then turning by the angle, radians) in
    /// 5 cm steps, reporting 3 % long and drifting 2°/m: true and reported poses, each step.
    fn drive(path: &[(f64, f64)]) -> Vec<(Isometry2<f64>, Isometry2<f64>)> {
        let mut truth = Isometry2::identity();
        let mut odometry = Isometry2::identity();
        let mut out = vec![(truth, odometry)];
        for &(metres, turn) in path {
            let steps = (metres / 0.05).round() as usize;
            for _ in 0..steps {
                truth *= Isometry2::translation(0.05, 0.0);
                odometry *=
                    Isometry2::new(Vector2::new(0.05 * 1.03, 0.0), 0.05 * 2f64.to_radians());
                out.push((truth, odometry));
            }
            if turn != 0.0 {
                truth *= Isometry2::rotation(turn);
                odometry *= Isometry2::rotation(turn);
                out.push((truth, odometry));
            }
        }
        out
    }

    /// A fix of the sweep's start at the truth, good to `sigma_m` and `sigma_deg`, as the
    /// localisation would find it from `prior`.
    fn fix_at(
        truth: &Isometry2<f64>,
        prior: &Matrix3<f64>,
        sigma_m: f64,
        sigma_deg: f64,
    ) -> PoseFix {
        let sonar = Matrix3::from_diagonal(&Vector3::new(
            sigma_m.powi(-2),
            sigma_m.powi(-2),
            sigma_deg.to_radians().powi(-2),
        ));
        let prior_information = prior.try_inverse().unwrap();
        let covariance = (prior_information + sonar).try_inverse().unwrap();
        PoseFix {
            pose: *truth,
            covariance,
            matched: 3,
            iterations: 1,
        }
    }

    fn error(a: &Isometry2<f64>, b: &Isometry2<f64>) -> (f64, f64) {
        let d = a.inverse() * b;
        (
            d.translation.vector.norm(),
            d.rotation.angle().abs().to_degrees(),
        )
    }

    #[test]
    fn without_fixes_the_filter_is_the_odometry() {
        let run = drive(&[(2.0, 1.0), (1.0, 0.0)]);
        let mut filter = DriftFilter::new(OdometryErrors::default());
        for (_, odometry) in &run {
            filter.advance(odometry);
        }
        let (_, odometry) = run.last().unwrap();
        let (m, deg) = error(&filter.pose(), odometry);
        assert!(m < 1e-9 && deg < 1e-9, "{m} {deg}");
        // … and knows it is uncertain: 3 m at 3°/m of possible drift.
        let (_, p) = {
            filter.begin_sweep();
            filter.sweep_prior()
        };
        assert!(p[(2, 2)].sqrt().to_degrees() > 5.0, "{p}");
    }

    #[test]
    fn fixes_teach_the_filter_the_drift_and_it_predicts_the_next_leg() {
        // Out and back along a corridor, fixed at every stop.
        let legs = [
            (1.0, 0.0),
            (1.0, std::f64::consts::PI),
            (2.0, std::f64::consts::PI),
        ];
        let mut path = Vec::new();
        for _ in 0..3 {
            path.extend(legs);
        }
        let run = drive(&path);
        let mut filter = DriftFilter::new(OdometryErrors::default());
        let mut last_error = (0.0, 0.0);
        for (i, (truth, odometry)) in run.iter().enumerate() {
            filter.advance(odometry);
            // A sweep every 20 steps (1 m), fixed to 1 cm and 0.5°.
            if i % 20 == 0 {
                last_error = error(&filter.pose(), truth);
                filter.begin_sweep();
                let (_, prior) = filter.sweep_prior();
                assert!(filter.apply_fix(&fix_at(truth, &prior, 0.01, 0.5), &prior));
            }
        }
        let drift = filter.drift();
        assert!((drift.scale - 0.03).abs() < 0.01, "{drift:?}");
        assert!(
            (drift.drift_deg_per_m - 2.0 / 1.03).abs() < 0.5,
            "{drift:?}"
        );
        // The last leg's prediction, before its fix, is far better than the odometry's 3 % and 2°/m
        // (3 cm and 2° over the metre).
        assert!(last_error.0 < 0.01 && last_error.1 < 0.5, "{last_error:?}");
    }

    #[test]
    fn ranges_to_a_side_wall_hold_the_pose_across_the_corridor() {
        // Down a corridor whose wall y = 0.6 faces the sensor's left: every 5 cm a ping at 90°.
        let wall = WallAhead {
            normal_rad: std::f64::consts::FRAC_PI_2,
            distance_m: 0.6,
            distance_sigma_m: 0.005,
        };
        let run = drive(&[(3.0, 0.0)]);
        let mut filter = DriftFilter::new(OdometryErrors::default());
        let mut plain = DriftFilter::new(OdometryErrors::default());
        for (truth, odometry) in &run {
            plain.advance(odometry);
            filter.advance(odometry);
            let across = 0.6 - truth.translation.y;
            assert!(
                filter.range_to_wall(&wall, across, 0.02),
                "{:?}",
                filter.pose()
            );
        }
        let (truth, _) = run.last().unwrap();
        // The odometry's 2°/m leaves it 18 cm off across the corridor after 3 m; the ranges hold
        // the pose on the truth, and through the motion the heading too.
        let (odometry_error, _) = error(&plain.pose(), truth);
        assert!(odometry_error > 0.15, "{odometry_error}");
        let across = (filter.pose().translation.y - truth.translation.y).abs();
        assert!(across < 0.01, "{across}");
        let heading = filter.pose().rotation.angle().to_degrees().abs();
        assert!(heading < 1.0, "{heading}");
        // A ping that heard the room through a doorway (1.5 m, not 0.6) is refused, unchanged.
        let before = filter.pose();
        assert!(!filter.range_to_wall(&wall, 1.5, 0.02));
        assert_eq!(filter.pose(), before);
    }

    #[test]
    fn a_fix_along_one_direction_leaves_the_other_to_the_odometry() {
        // A corridor along x: a fix of y and θ only.
        let run = drive(&[(2.0, 0.0)]);
        let mut filter = DriftFilter::new(OdometryErrors::default());
        for (_, odometry) in &run {
            filter.advance(odometry);
        }
        filter.begin_sweep();
        let (before, prior) = filter.sweep_prior();
        let (truth, _) = run.last().unwrap();
        let mut fix = fix_at(truth, &prior, 1e3, 0.5);
        // Across the corridor and the heading only: x is where the prior had it.
        let sonar_y = Matrix3::from_diagonal(&Vector3::new(0.0, 0.01_f64.powi(-2), 0.0));
        fix.covariance = (fix.covariance.try_inverse().unwrap() + sonar_y)
            .try_inverse()
            .unwrap();
        fix.pose = Isometry2::new(Vector2::new(before.translation.x, truth.translation.y), 0.0);
        assert!(filter.apply_fix(&fix, &prior));
        let (after, _) = filter.sweep_prior();
        // Along the corridor only what the corrected heading implies (a straighter path reaches a
        // little farther): millimetres, against the 10 cm the scale error leaves open.
        assert!(
            (after.translation.x - before.translation.x).abs() < 0.005,
            "{after} {before}"
        );
        assert!(filter.drift().scale_sigma > 0.04, "{:?}", filter.drift());
        assert!(
            (after.translation.y - truth.translation.y).abs() < 0.01,
            "{after}"
        );
    }
}
