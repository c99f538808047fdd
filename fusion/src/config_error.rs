//! What a configuration can be refused for: an unknown name, or a value out of its range. Every
//! module checks its own settings with these; [`crate::config`] assembles them.

/// A name no model, rule or preset goes by.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown {what} {given:?}; valid names: {}", .valid.join(", "))]
pub struct UnknownName {
    pub what: &'static str,
    pub given: String,
    pub valid: &'static [&'static str],
}

impl UnknownName {
    pub(crate) fn new(what: &'static str, given: &str, valid: &'static [&'static str]) -> Self {
        Self {
            what,
            given: given.to_owned(),
            valid,
        }
    }
}

/// A configuration the engine cannot run with.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error("grid.resolution_m must be a positive number of metres, got {0}")]
    InvalidResolution(f32),
    #[error("grid.cells must be between 1 and {max} per side, got {cells}")]
    GridSize { cells: u32, max: usize },
    #[error(
        "a cone of {max_range_m} m at {resolution_m} m cells needs a stencil of {side} cells per \
         side, more than the {max} allowed: coarser cells or a shorter max_range_m"
    )]
    StencilTooLarge {
        max_range_m: f32,
        resolution_m: f32,
        side: usize,
        max: usize,
    },
    #[error("{name} = {value} is invalid: expected {expected}")]
    InvalidParameter {
        name: &'static str,
        value: f32,
        expected: &'static str,
    },
}

/// `Ok` if `ok`, else the error naming the parameter.
pub(crate) fn check(
    name: &'static str,
    value: f32,
    ok: bool,
    expected: &'static str,
) -> Result<(), ConfigError> {
    if ok {
        Ok(())
    } else {
        Err(ConfigError::InvalidParameter {
            name,
            value,
            expected,
        })
    }
}
