//! A sweep's estimate as `sonar-slam` publishes it on `sonar/slam_correction`
//! ([`SlamCorrection`], byte layout in `docs/ipc.md`).

use nalgebra::{Isometry2, Matrix3};
use sonar_common::ipc::{LAYOUT_VERSION, SlamCorrection, slam_state};

use crate::estimator::{FixState, SweepEstimate, SweepPose};

/// The [`slam_state`] code of a fix state.
pub fn state_code(state: FixState) -> u32 {
    match state {
        FixState::Fix => slam_state::FIX,
        FixState::NoLandmarks => slam_state::NO_LANDMARKS,
        FixState::Uncertain => slam_state::UNCERTAIN,
        FixState::Refused => slam_state::REFUSED,
    }
}

/// What the SLAM holds besides the sweep's estimate, counted since the process started.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Totals {
    pub landmarks: usize,
    pub fixes: u32,
    pub refused: u32,
}

/// The message of one sweep's estimate.
pub fn correction_message(estimate: &SweepEstimate, totals: Totals) -> SlamCorrection {
    message(
        Estimated {
            stamp_ns: estimate.stamp_ns,
            sweep_id: estimate.sweep_id,
            state: state_code(estimate.state),
            matched: estimate.matched,
            pose: &estimate.pose,
            covariance: &estimate.covariance,
            correction_covariance: &estimate.correction_covariance(),
            odometry: &estimate.odometry,
        },
        totals,
    )
}

/// The message of an earlier sweep whose pose later sweeps moved ([`slam_state::REVISED`]): its
/// pose and correction as estimated now, so that a map follows. The covariances are not
/// computed for a revision and are NaN.
pub fn revision_message(sweep: &SweepPose, totals: Totals) -> SlamCorrection {
    let unknown = Matrix3::from_element(f64::NAN);
    message(
        Estimated {
            stamp_ns: sweep.stamp_ns,
            sweep_id: sweep.sweep_id,
            state: slam_state::REVISED,
            matched: 0,
            pose: &sweep.pose,
            covariance: &unknown,
            correction_covariance: &unknown,
            odometry: &sweep.odometry,
        },
        totals,
    )
}

/// What one message says of one sweep.
struct Estimated<'a> {
    stamp_ns: u64,
    sweep_id: u32,
    state: u32,
    matched: usize,
    pose: &'a Isometry2<f64>,
    covariance: &'a Matrix3<f64>,
    correction_covariance: &'a Matrix3<f64>,
    odometry: &'a Isometry2<f64>,
}

fn message(e: Estimated, totals: Totals) -> SlamCorrection {
    let (cx, cy, ct) = parts(&(e.pose * e.odometry.inverse()));
    let [ccxx, ccxy, ccxt, ccyy, ccyt, cctt] = upper(e.correction_covariance);
    let (x, y, t) = parts(e.pose);
    let [cxx, cxy, cxt, cyy, cyt, ctt] = upper(e.covariance);
    let (ox, oy, ot) = parts(e.odometry);
    SlamCorrection {
        stamp_ns: e.stamp_ns,
        layout_version: LAYOUT_VERSION,
        sweep_id: e.sweep_id,
        state: e.state,
        matched: u32::try_from(e.matched).unwrap_or(u32::MAX),
        correction_x_m: cx,
        correction_y_m: cy,
        correction_theta_rad: ct,
        correction_cov_xx: ccxx,
        correction_cov_xy: ccxy,
        correction_cov_xtheta: ccxt,
        correction_cov_yy: ccyy,
        correction_cov_ytheta: ccyt,
        correction_cov_thetatheta: cctt,
        x_m: x,
        y_m: y,
        theta_rad: t,
        cov_xx: cxx,
        cov_xy: cxy,
        cov_xtheta: cxt,
        cov_yy: cyy,
        cov_ytheta: cyt,
        cov_thetatheta: ctt,
        odometry_x_m: ox,
        odometry_y_m: oy,
        odometry_theta_rad: ot,
        landmarks: u32::try_from(totals.landmarks).unwrap_or(u32::MAX),
        fixes: totals.fixes,
        refused: totals.refused,
    }
}

fn parts(pose: &Isometry2<f64>) -> (f32, f32, f32) {
    (
        pose.translation.x as f32,
        pose.translation.y as f32,
        pose.rotation.angle() as f32,
    )
}

/// xx, xy, xθ, yy, yθ, θθ.
fn upper(c: &Matrix3<f64>) -> [f32; 6] {
    [
        c[(0, 0)],
        c[(0, 1)],
        c[(0, 2)],
        c[(1, 1)],
        c[(1, 2)],
        c[(2, 2)],
    ]
    .map(|v| v as f32)
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector2;

    use super::*;

    #[test]
    fn the_message_carries_the_correction_the_pose_and_the_state() {
        let pose = Isometry2::new(Vector2::new(1.0, 2.0), 0.5);
        let odometry = Isometry2::new(Vector2::new(1.2, 1.7), 0.45);
        let covariance = Matrix3::new(1e-4, 2e-5, 3e-6, 2e-5, 4e-4, 5e-6, 3e-6, 5e-6, 6e-5);
        let estimate = SweepEstimate {
            sweep_id: 7,
            stamp_ns: 123,
            pose,
            covariance,
            odometry,
            state: FixState::Uncertain,
            observations: 5,
            matched: 3,
            admitted: 1,
            ranged: 0,
            moving: false,
        };
        let totals = Totals {
            landmarks: 4,
            fixes: 2,
            refused: 1,
        };
        let m = correction_message(&estimate, totals);
        assert_eq!((m.stamp_ns, m.sweep_id, m.matched), (123, 7, 3));
        assert_eq!(m.layout_version, LAYOUT_VERSION);
        assert_eq!(m.state, slam_state::UNCERTAIN);
        assert!(!m.is_fix());
        assert_eq!((m.landmarks, m.fixes, m.refused), (4, 2, 1));
        assert_eq!((m.x_m, m.y_m, m.theta_rad), (1.0, 2.0, 0.5));
        assert_eq!((m.cov_xx, m.cov_yy), (1e-4, 4e-4));
        assert_eq!(m.cov_thetatheta, 6e-5);
        // The published correction places the odometry's pose on the map's.
        let correction = Isometry2::new(
            Vector2::new(f64::from(m.correction_x_m), f64::from(m.correction_y_m)),
            f64::from(m.correction_theta_rad),
        );
        let placed = correction * odometry;
        assert!((placed.translation.vector - pose.translation.vector).norm() < 1e-6);
        assert!((placed.rotation.angle() - 0.5).abs() < 1e-6);
        // Heading's variance is the pose's; the position's grows with the lever arm.
        assert!((m.correction_cov_thetatheta - 6e-5).abs() < 1e-9);
        assert!(m.correction_cov_xx > 0.0 && m.correction_cov_yy > 0.0);
    }

    #[test]
    fn a_revision_carries_the_pose_as_estimated_now_and_no_covariance() {
        let sweep = SweepPose {
            sweep_id: 3,
            stamp_ns: 99,
            pose: Isometry2::new(Vector2::new(0.5, -1.0), 0.2),
            odometry: Isometry2::new(Vector2::new(0.6, -0.9), 0.1),
        };
        let m = revision_message(&sweep, Totals::default());
        assert_eq!(
            (m.stamp_ns, m.sweep_id, m.state),
            (99, 3, slam_state::REVISED)
        );
        assert!(!m.is_fix());
        let correction = Isometry2::new(
            Vector2::new(f64::from(m.correction_x_m), f64::from(m.correction_y_m)),
            f64::from(m.correction_theta_rad),
        );
        let placed = correction * sweep.odometry;
        assert!((placed.translation.vector - sweep.pose.translation.vector).norm() < 1e-6);
        assert!(m.cov_xx.is_nan() && m.correction_cov_thetatheta.is_nan());
    }

    #[test]
    fn every_state_has_its_own_code_and_only_a_fix_is_a_fix() {
        let codes = [
            FixState::Fix,
            FixState::NoLandmarks,
            FixState::Uncertain,
            FixState::Refused,
        ]
        .map(state_code);
        assert_eq!(codes[0], slam_state::FIX);
        for (i, a) in codes.iter().enumerate() {
            for b in &codes[i + 1..] {
                assert_ne!(a, b);
            }
        }
    }
}
