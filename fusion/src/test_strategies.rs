//! Property-test strategies the crate's tests share.

use proptest::prelude::*;

/// Steps between the ends of a [`between`] range.
const STEPS: u32 = 1 << 20;

/// f32 values from `low` to `high` in 2²⁰ even steps. Proptest's own float ranges trip a debug
/// assertion of theirs on rare draws (`float_samplers.rs`: a first split overshooting the low
/// end by more than a step), which failed a CI run of a test drawing 170 000 floats; an integer
/// mapped onto the range cannot.
pub(crate) fn between(low: f32, high: f32) -> impl Strategy<Value = f32> {
    (0..=STEPS).prop_map(move |k| low + (high - low) * (k as f32 / STEPS as f32))
}
