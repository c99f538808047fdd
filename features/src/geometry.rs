//! Angles wrapped into half-open intervals, and poses as the (x, y, θ) vectors localisation
//! estimates: the small pieces of geometry every module shares.

/// `deg` wrapped into (−180, 180].
pub fn wrap_deg(deg: f64) -> f64 {
    let d = deg.rem_euclid(360.0);
    if d > 180.0 { d - 360.0 } else { d }
}

/// `rad` wrapped into (−π, π].
pub fn wrap_rad(rad: f64) -> f64 {
    wrap_deg(rad.to_degrees()).to_radians()
}

/// A pose as (x, y, θ), the coordinates localisation estimates.
pub(crate) fn pose_vector(pose: &nalgebra::Isometry2<f64>) -> nalgebra::Vector3<f64> {
    nalgebra::Vector3::new(
        pose.translation.x,
        pose.translation.y,
        pose.rotation.angle(),
    )
}

/// (x, y, θ) as a pose.
pub(crate) fn vector_pose(x: &nalgebra::Vector3<f64>) -> nalgebra::Isometry2<f64> {
    nalgebra::Isometry2::new(nalgebra::Vector2::new(x.x, x.y), x.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angles_wrap_into_half_open_intervals() {
        assert_eq!(wrap_deg(190.0), -170.0);
        assert_eq!(wrap_deg(-180.0), 180.0);
        assert_eq!(wrap_deg(540.0), 180.0);
        assert!((wrap_rad(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
    }
}
