//! A sweep's estimate as `sonar-slam` publishes it on `sonar/slam_correction`
//! ([`SlamCorrection`]), and its landmarks on `sonar/slam_landmarks` ([`FeatureRecord`]s; byte
//! layouts in `docs/ipc.md`).

use nalgebra::{Isometry2, Matrix2, Matrix3};
use sonar_common::ipc::{
    FeatureRecord, FeaturesHeader, LAYOUT_VERSION, MAX_FEATURES, SlamCorrection, feature_flags,
    feature_kind, slam_state,
};

use crate::estimator::{FixState, Landmark, SweepEstimate, SweepPose};
use crate::graph::LandmarkKind;

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

/// What a landmarks snapshot says besides the landmarks.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LandmarksStamp {
    pub seq: u64,
    /// `host_stamp_ns` of the sweep after which the landmarks were estimated.
    pub stamp_ns: u64,
    pub sweep_id: u32,
    /// Sweeps estimated since the process started.
    pub sweeps: u64,
}

/// The `sonar/slam_landmarks` snapshot of the landmarks: the features' layout, in the map frame.
/// A wall is a plane through the foot of its perpendicular from the map's origin, with the
/// covariance of that foot carried from the estimate's (φ, d) and the σ of its normal's
/// direction; SLAM's walls are infinite lines, so the segment is NaN. A point landmark (a post
/// or a corner: the SLAM does not tell them apart) is a point with its covariance. Landmarks
/// beyond [`MAX_FEATURES`] are left out, the least seen first, and counted.
pub fn landmarks_snapshot(
    landmarks: &[Landmark],
    stamp: LandmarksStamp,
) -> (FeaturesHeader, Vec<FeatureRecord>) {
    let mut order: Vec<usize> = (0..landmarks.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(landmarks[i].sightings));
    let kept = order.len().min(MAX_FEATURES);
    let mut records: Vec<FeatureRecord> = order[..kept]
        .iter()
        .map(|&i| landmark_record(i, &landmarks[i]))
        .collect();
    records.sort_by_key(|r| r.id);
    let header = FeaturesHeader {
        seq: stamp.seq,
        stamp_ns: stamp.stamp_ns,
        sweeps: stamp.sweeps,
        layout_version: LAYOUT_VERSION,
        feature_count: u32::try_from(records.len()).unwrap_or(u32::MAX),
        last_sweep_id: stamp.sweep_id,
        features_left_out: u32::try_from(landmarks.len() - kept).unwrap_or(u32::MAX),
        ..FeaturesHeader::default()
    };
    (header, records)
}

/// One landmark as a feature record; its id is its index in the map plus one (landmarks are
/// never removed, so it is stable).
fn landmark_record(index: usize, l: &Landmark) -> FeatureRecord {
    let unknown = Matrix2::from_element(f64::NAN);
    let record = FeatureRecord {
        id: index as u64 + 1,
        times_seen: l.sightings,
        angle_deg: f32::NAN,
        angle_sigma_deg: f32::NAN,
        confidence: f32::NAN,
        segment_ax_m: f32::NAN,
        segment_ay_m: f32::NAN,
        segment_bx_m: f32::NAN,
        segment_by_m: f32::NAN,
        // A landmark is admitted only from sightings at two poses or more.
        flags: feature_flags::CONFIRMED,
        ..FeatureRecord::default()
    };
    let (x, y, c, kind) = match l.kind {
        LandmarkKind::Point => (
            l.mean.x,
            l.mean.y,
            l.covariance.unwrap_or(unknown),
            feature_kind::POINT,
        ),
        LandmarkKind::Line => {
            let (phi, d) = (l.mean.x, l.mean.y);
            let (sin, cos) = phi.sin_cos();
            // ∂(foot x, foot y) / ∂(φ, d) for the foot d·(cos φ, sin φ).
            let jacobian = Matrix2::new(-d * sin, cos, d * cos, sin);
            let c = l
                .covariance
                .map_or(unknown, |c| jacobian * c * jacobian.transpose());
            let (x, y) = (d * cos, d * sin);
            return FeatureRecord {
                kind: feature_kind::PLANE,
                x_m: x as f32,
                y_m: y as f32,
                cov_xx: c[(0, 0)] as f32,
                cov_xy: c[(0, 1)] as f32,
                cov_yy: c[(1, 1)] as f32,
                // Towards the wall from the origin: φ, or its opposite when d < 0.
                angle_deg: y.atan2(x).to_degrees() as f32,
                angle_sigma_deg: l
                    .covariance
                    .map_or(f64::NAN, |c| c[(0, 0)].sqrt().to_degrees())
                    as f32,
                ..record
            };
        }
    };
    FeatureRecord {
        kind,
        x_m: x as f32,
        y_m: y as f32,
        cov_xx: c[(0, 0)] as f32,
        cov_xy: c[(0, 1)] as f32,
        cov_yy: c[(1, 1)] as f32,
        ..record
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
    fn landmarks_become_records_in_the_map_frame_with_their_covariance() {
        use nalgebra::Matrix2;
        // A wall whose normal points along −y, 2 m from the origin (d < 0 with φ = π/2).
        let wall = Landmark {
            kind: LandmarkKind::Line,
            mean: Vector2::new(std::f64::consts::FRAC_PI_2, -2.0),
            covariance: Some(Matrix2::new(1e-4, 0.0, 0.0, 4e-4)),
            sightings: 5,
        };
        let post = Landmark {
            kind: LandmarkKind::Point,
            mean: Vector2::new(1.0, 0.5),
            covariance: None,
            sightings: 2,
        };
        let stamp = LandmarksStamp {
            seq: 3,
            stamp_ns: 77,
            sweep_id: 9,
            sweeps: 10,
        };
        let (header, records) = landmarks_snapshot(&[wall, post], stamp);
        assert_eq!((header.seq, header.stamp_ns, header.sweeps), (3, 77, 10));
        assert_eq!((header.feature_count, header.last_sweep_id), (2, 9));
        assert_eq!(header.layout_version, LAYOUT_VERSION);
        assert!(
            records.iter().all(FeatureRecord::is_confirmed),
            "landmarks are admitted from two poses"
        );
        let w = records[0];
        assert_eq!((w.id, w.kind, w.times_seen), (1, feature_kind::PLANE, 5));
        // The foot of the perpendicular: (0, −2); the normal from the origin towards it: −90°.
        assert!(w.x_m.abs() < 1e-6 && (w.y_m + 2.0).abs() < 1e-6, "{w:?}");
        assert!((w.angle_deg + 90.0).abs() < 1e-4, "{w:?}");
        // σ_φ = 0.01 rad moves the foot sideways by d·σ_φ = 2 cm; σ_d = 2 cm moves it along y.
        assert!(
            (w.cov_xx - 4e-4).abs() < 1e-8 && (w.cov_yy - 4e-4).abs() < 1e-8,
            "{w:?}"
        );
        assert!((w.angle_sigma_deg - 0.01f32.to_degrees()).abs() < 1e-4);
        assert!(w.segment_ax_m.is_nan());
        let p = records[1];
        assert_eq!((p.id, p.kind, p.times_seen), (2, feature_kind::POINT, 2));
        assert_eq!((p.x_m, p.y_m), (1.0, 0.5));
        assert!(p.cov_xx.is_nan() && p.angle_deg.is_nan());
    }

    #[test]
    fn beyond_the_snapshot_s_room_the_least_seen_landmarks_are_left_out() {
        let landmarks: Vec<Landmark> = (0..MAX_FEATURES as u32 + 3)
            .map(|i| Landmark {
                kind: LandmarkKind::Point,
                mean: Vector2::new(f64::from(i), 0.0),
                covariance: None,
                // The first three are seen once, the others more.
                sightings: if i < 3 { 1 } else { 2 + i },
            })
            .collect();
        let (header, records) = landmarks_snapshot(&landmarks, LandmarksStamp::default());
        assert_eq!(records.len(), MAX_FEATURES);
        assert_eq!(header.features_left_out, 3);
        assert!(
            records.iter().all(|r| r.id > 3),
            "ids kept in order, the first three out"
        );
        assert!(records.windows(2).all(|w| w[0].id < w[1].id));
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
