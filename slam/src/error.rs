//! What the estimator refuses.

/// What the library refuses.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SlamError {
    #[error("invalid SLAM configuration: {0}")]
    Config(String),
    #[error(transparent)]
    Features(#[from] sonar_features::FeatureError),
}
