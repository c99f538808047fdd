//! The snapshot encoding of cells, kept up to date as the grid is fused.
//!
//! A `sonar/grid` snapshot carries one byte per cell, `round(p · 254)` or 255 for a cell never
//! observed ([`sonar_common::ipc::encode_probability`]), and the header counts the cells with
//! p > 0.5, p < 0.5 and unknown. Encoding a whole grid per snapshot (an `expf` and a `roundf` per
//! cell with log-odds cells) cost more than fusing the readings in between, so the grid keeps the
//! encoded bytes and the counts beside its cells and, when a snapshot is asked for, re-encodes
//! only the cells fused since the last one (each once, however many readings touched it); a
//! snapshot copies the bytes.
//!
//! Every rule reads a cell out as a probability that rises with one number, the cell's *key*
//! ([`crate::rule::Combine::key`]: the probability itself, the log-odds, the pignistic probability
//! of a mass pair, a HIMM counter). The byte is then a non-decreasing step function of the key,
//! and a [`KeyEncoder`] holds its steps: the key range is cut into buckets narrower than the
//! smallest distance between two steps, and per bucket the table keeps the byte at its start and
//! the first key of the bucket at which the byte is one higher. Encoding is a subtraction, a
//! multiplication, two loads and a comparison, and gives the reference encoder's byte bit for bit:
//! the steps are found by bisection over the reference encoder itself, on the same float-to-bucket
//! mapping the lookup uses. Keys outside the range a rule keeps its cells in (only a hand-made
//! state could hold them) take the reference encoder. The counts, and whether a cell is
//! confidently occupied ([`CONFIDENT_PROBABILITY`], the cells the features' walls grow
//! along), are thresholds on the key, found the same way.

use sonar_common::ipc::{CELL_UNKNOWN, encode_probability};

use crate::rule::Combine;

/// Occupancy probability from which a cell is confidently occupied
/// ([`crate::grid::OccupancyGrid::confident_cells`]): the cells that lend their position to a wall's segment
/// in the feature map (`crate::features`).
pub const CONFIDENT_PROBABILITY: f32 = 0.8;

/// What a cell says, for the snapshot header's counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum CellClass {
    /// 0.5 < p < [`CONFIDENT_PROBABILITY`].
    Occupied = 0,
    /// p < 0.5.
    Free = 1,
    /// Never reached by a reading.
    Unknown = 2,
    /// p = 0.5 exactly after readings: counted as neither.
    Even = 3,
    /// p ≥ [`CONFIDENT_PROBABILITY`]: counted as occupied.
    Confident = 4,
}

impl CellClass {
    pub(crate) const COUNT: usize = 5;
}

// [`crate::grid::OccupancyGrid::confident_cells`] finds the confident cells by their one bit.
const _: () = assert!(CellClass::Confident as u8 == 1 << 2 && CellClass::COUNT == 5);

/// Buckets tried first; doubled until no bucket holds two steps.
const FIRST_BUCKETS: usize = 512;
/// More than any rule needs (log-odds clamps 100 apart would need about 8 k).
const MAX_BUCKETS: usize = 1 << 16;

/// The snapshot encoding of keys in `lo..=hi` for one probability function.
#[derive(Debug, Clone)]
pub(crate) struct KeyEncoder {
    lo: f32,
    hi: f32,
    /// Buckets per unit of key.
    scale: f32,
    /// Per bucket, its step.
    steps: Vec<Step>,
    /// Keys at or above this read as p > 0.5.
    occupied_from: f32,
    /// Keys below this read as p < 0.5.
    free_below: f32,
    /// Keys at or above this read as p ≥ [`CONFIDENT_PROBABILITY`] (found over every float, not
    /// only the rule's range: a rule whose clamp stays below it has no confident cell, and a
    /// hand-made key beyond the clamp is still told right).
    confident_from: f32,
}

/// One bucket of a [`KeyEncoder`]'s table.
#[derive(Debug, Clone, Copy)]
struct Step {
    /// The first key at which the byte is `base + 1`; +∞ if none.
    at: f32,
    /// The byte at the bucket's first key.
    base: u8,
}

/// `x`'s position in the order of floats, as an integer (−0 just below +0).
fn ordinal(x: f32) -> i64 {
    let bits = x.to_bits() as i32;
    i64::from(bits ^ (((bits >> 31) as u32) >> 1) as i32)
}

/// The float at `ordinal`.
fn from_ordinal(ordinal: i64) -> f32 {
    let bits = ordinal as i32;
    f32::from_bits((bits ^ (((bits >> 31) as u32) >> 1) as i32) as u32)
}

/// The first float in `lo..=hi` for which `holds` is true, given that it is false then true along
/// the floats; `None` if it holds nowhere.
fn first_where(lo: f32, hi: f32, holds: impl Fn(f32) -> bool) -> Option<f32> {
    let (mut a, mut b) = (ordinal(lo), ordinal(hi));
    if !holds(hi) {
        return None;
    }
    while a < b {
        let mid = a + (b - a) / 2;
        if holds(from_ordinal(mid)) {
            b = mid;
        } else {
            a = mid + 1;
        }
    }
    Some(from_ordinal(a))
}

impl KeyEncoder {
    /// The encoder of `rule`'s keys, over the range it keeps them in.
    pub fn new<R: Combine>(rule: &R) -> Self {
        let [lo, hi] = rule.key_range();
        let probability = |key| rule.key_probability(key);
        let reference = |key| encode_probability(probability(key));
        let occupied_from = first_where(lo, hi, |k| probability(k) > 0.5).unwrap_or(f32::INFINITY);
        let free_below = first_where(lo, hi, |k| probability(k) >= 0.5).unwrap_or(f32::INFINITY);
        let confident_from = first_where(f32::NEG_INFINITY, f32::INFINITY, |k| {
            probability(k) >= CONFIDENT_PROBABILITY
        })
        .unwrap_or(f32::INFINITY);
        let mut buckets = FIRST_BUCKETS;
        loop {
            let scale = buckets as f32 / (hi - lo);
            let bucket = |key: f32| ((key - lo) * scale) as usize;
            let last = bucket(hi);
            let starts: Vec<f32> = (0..=last)
                .map(|i| first_where(lo, hi, |k| bucket(k) >= i).unwrap_or(hi))
                .collect();
            let mut steps = Vec::with_capacity(starts.len());
            let mut fits = true;
            for (i, &start) in starts.iter().enumerate() {
                let end = starts
                    .get(i + 1)
                    .map_or(hi, |&next| from_ordinal(ordinal(next) - 1));
                let (first, last) = (reference(start), reference(end));
                fits &= last <= first.saturating_add(1);
                let at = if last == first {
                    None
                } else {
                    first_where(start, end, |k| reference(k) > first)
                };
                steps.push(Step {
                    at: at.unwrap_or(f32::INFINITY),
                    base: first,
                });
            }
            if fits || buckets >= MAX_BUCKETS {
                return Self {
                    lo,
                    hi,
                    scale,
                    steps,
                    occupied_from,
                    free_below,
                    confident_from,
                };
            }
            buckets *= 2;
        }
    }

    /// The snapshot byte of a cell of `rule` with `key` (NaN: never observed).
    #[inline(always)]
    pub fn byte<R: Combine>(&self, rule: &R, key: f32) -> u8 {
        if key >= self.lo && key <= self.hi {
            // SAFETY: with the key in `lo..=hi` the product is finite and within
            // 0..=buckets·(1 + ε), far inside u32 (a saturating `as` costs a dozen instructions
            // per cell here).
            let bucket = unsafe { ((key - self.lo) * self.scale).to_int_unchecked::<u32>() };
            // The bucket is within the table by construction; `get` keeps a wrong one from
            // reading past it.
            match self.steps.get(bucket as usize) {
                Some(step) => step.base + u8::from(key >= step.at),
                None => encode_probability(rule.key_probability(key)),
            }
        } else if key.is_nan() {
            CELL_UNKNOWN
        } else {
            encode_probability(rule.key_probability(key))
        }
    }

    /// What a cell with `key` says, for the snapshot header's counts and the confident cells.
    #[inline(always)]
    pub(crate) fn class(&self, key: f32) -> CellClass {
        if key.is_nan() {
            CellClass::Unknown
        } else if key >= self.confident_from {
            CellClass::Confident
        } else if key >= self.occupied_from {
            CellClass::Occupied
        } else if key < self.free_below {
            CellClass::Free
        } else {
            CellClass::Even
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rule::{BayesRule, DempsterShaferRule, HimmRule, LogOddsRule};
    use proptest::prelude::*;

    /// What the encoder must give for `key`: the snapshot byte and the counts as the reference
    /// encoder ([`encode_probability`] of the rule's probability) and the documented header say.
    fn reference<R: Combine>(rule: &R, key: f32) -> (u8, CellClass) {
        if key.is_nan() {
            return (CELL_UNKNOWN, CellClass::Unknown);
        }
        let p = rule.key_probability(key);
        let class = if p >= CONFIDENT_PROBABILITY {
            CellClass::Confident
        } else if p > 0.5 {
            CellClass::Occupied
        } else if p < 0.5 {
            CellClass::Free
        } else {
            CellClass::Even
        };
        (encode_probability(p), class)
    }

    fn check<R: Combine>(rule: &R, encoder: &KeyEncoder, key: f32) {
        let got = (encoder.byte(rule, key), encoder.class(key));
        assert_eq!(
            got,
            reference(rule, key),
            "key {key:e} ({:#x})",
            key.to_bits()
        );
    }

    /// Every step and bucket edge of the table, and the float on each side of it: where a table
    /// that is off by one float would show.
    fn check_edges<R: Combine>(rule: &R) {
        let encoder = KeyEncoder::new(rule);
        let edges = encoder
            .steps
            .iter()
            .map(|s| s.at)
            .filter(|at| at.is_finite())
            .chain([
                encoder.occupied_from,
                encoder.free_below,
                encoder.confident_from,
                encoder.lo,
                encoder.hi,
            ])
            .chain((0..encoder.steps.len()).map(|i| encoder.lo + i as f32 / encoder.scale));
        for edge in edges {
            for key in [edge.next_down(), edge, edge.next_up()] {
                check(rule, &encoder, key);
            }
        }
        for key in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.0, 0.0] {
            check(rule, &encoder, key);
        }
    }

    fn rules() -> (Vec<LogOddsRule>, Vec<HimmRule>) {
        let log_odds = vec![
            LogOddsRule::default(),
            LogOddsRule {
                min_log_odds: -7.25,
                max_log_odds: 12.0,
            },
            LogOddsRule {
                min_log_odds: -0.01,
                max_log_odds: 0.02,
            },
        ];
        let himm = [1u8, 15, 100, 254]
            .map(|max_count| HimmRule {
                max_count,
                ..HimmRule::default()
            })
            .to_vec();
        (log_odds, himm)
    }

    #[test]
    fn the_table_is_exact_at_every_step_and_edge() {
        check_edges(&BayesRule);
        check_edges(&DempsterShaferRule);
        let (log_odds, himm) = rules();
        log_odds.iter().for_each(check_edges);
        himm.iter().for_each(check_edges);
    }

    #[test]
    fn every_himm_counter_encodes_as_the_reference() {
        for rule in rules().1 {
            let encoder = KeyEncoder::new(&rule);
            for cell in 0..=u8::MAX {
                check(&rule, &encoder, rule.key(cell));
            }
        }
    }

    /// The encoders of the property test, built once.
    #[allow(clippy::type_complexity)]
    static ENCODERS: std::sync::LazyLock<(KeyEncoder, KeyEncoder, Vec<(LogOddsRule, KeyEncoder)>)> =
        std::sync::LazyLock::new(|| {
            (
                KeyEncoder::new(&BayesRule),
                KeyEncoder::new(&DempsterShaferRule),
                rules()
                    .0
                    .into_iter()
                    .map(|r| (r, KeyEncoder::new(&r)))
                    .collect(),
            )
        });

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(20_000))]

        /// Over the keys a rule's cells hold and beyond them (a hand-made state), bit for bit.
        #[test]
        fn bytes_and_counts_equal_the_reference_encoder(
            unit in -0.5f32..1.5,
            bits in any::<u32>(),
        ) {
            let (bayes, dempster_shafer, log_odds) = &*ENCODERS;
            check(&BayesRule, bayes, unit);
            check(&DempsterShaferRule, dempster_shafer, unit);
            for (rule, encoder) in log_odds {
                let [lo, hi] = rule.key_range();
                let key = lo - 1.0 + unit / 2.0 * (hi - lo + 2.0);
                check(rule, encoder, key);
            }
            // Any float at all, NaNs and infinities included.
            check(&log_odds[0].0, &log_odds[0].1, f32::from_bits(bits));
            check(&BayesRule, bayes, f32::from_bits(bits));
        }
    }

    #[test]
    fn ordinals_follow_the_order_of_floats() {
        let xs = [-3.5f32, -1e-30, -0.0, 0.0, 1e-30, 0.5, 2.0];
        for w in xs.windows(2) {
            assert!(ordinal(w[0]) < ordinal(w[1]), "{w:?}");
        }
        for x in xs {
            assert_eq!(from_ordinal(ordinal(x)).to_bits(), x.to_bits());
        }
        assert_eq!(ordinal(0.0) - ordinal(-0.0), 1);
    }

    #[test]
    fn first_where_finds_the_first_float() {
        assert_eq!(first_where(0.0, 1.0, |x| x >= 0.3), Some(0.3));
        assert_eq!(
            first_where(-2.0, 1.0, |x| x > -1.0),
            Some((-1.0f32).next_up())
        );
        assert_eq!(first_where(0.0, 1.0, |x| x > 1.0), None);
    }
}
