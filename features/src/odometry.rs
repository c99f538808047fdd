//! How a robot's odometry is expected to err: the settings of localisation's drift filter
//! ([`crate::drift`]) and of the SLAM's odometry factors.

use serde::{Deserialize, Serialize};

/// How the odometry is expected to err: the prior of its systematic errors and its random error
/// (`[features.odometry]` in the configuration). Set them from the robot: a calibrated odometry
/// (UMBmark) has smaller systematic errors, a wheel on carpet larger random ones.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryErrors {
    /// σ of the scale error a (fraction). Ordinary wheels: a few percent.
    pub scale_sigma: f64,
    /// σ of the heading drift b, degrees per metre.
    pub drift_sigma_deg_per_m: f64,
    /// σ of the turn scale error c (fraction).
    pub turn_sigma: f64,
    /// Random error of the position, metres per √metre driven.
    pub position_noise_m_per_sqrt_m: f64,
    /// Random error of the heading, degrees per √metre driven …
    pub heading_noise_deg_per_sqrt_m: f64,
    /// … and per √radian turned.
    pub turn_noise_deg_per_sqrt_rad: f64,
}

impl Default for OdometryErrors {
    /// 5 % scale and turn error, 3°/m of drift: wide enough for a hobby robot's wheels (UMBmark
    /// reports a few percent and a few degrees per metre before calibration). The random parts
    /// hold ten times the simulator's default white noise (0.5 mm and 0.05° per 50 ms step at
    /// 0.2 m/s: 5 mm and 0.5° per √m).
    fn default() -> Self {
        Self {
            scale_sigma: 0.05,
            drift_sigma_deg_per_m: 3.0,
            turn_sigma: 0.05,
            position_noise_m_per_sqrt_m: 0.01,
            heading_noise_deg_per_sqrt_m: 1.0,
            turn_noise_deg_per_sqrt_rad: 1.0,
        }
    }
}
