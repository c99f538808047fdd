//! What the library refuses.

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FeatureError {
    #[error("invalid feature configuration: {0}")]
    Config(String),
    #[error(
        "ping {index}: bearing {bearing_deg}° and range {range_m:?} m must be finite (range > 0)"
    )]
    BadPing {
        index: usize,
        bearing_deg: f64,
        range_m: Option<f64>,
    },
}
