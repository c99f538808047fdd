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
    /// Per bucket, the first key at which the byte is one higher than at the bucket's first key;
    /// +∞ if none. Never empty.
    step_at: Vec<f32>,
    /// Per bucket, the byte at its first key (as i32: the vectorised lookup gathers 32-bit
    /// lanes).
    step_base: Vec<i32>,
    /// Keys at or above this read as p > 0.5.
    occupied_from: f32,
    /// Keys below this read as p < 0.5.
    free_below: f32,
    /// Keys at or above this read as p ≥ [`CONFIDENT_PROBABILITY`] (found over every float, not
    /// only the rule's range: a rule whose clamp stays below it has no confident cell, and a
    /// hand-made key beyond the clamp is still told right).
    confident_from: f32,
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
            let (mut step_at, mut step_base) = (Vec::new(), Vec::new());
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
                step_at.push(at.unwrap_or(f32::INFINITY));
                step_base.push(i32::from(first));
            }
            if fits || buckets >= MAX_BUCKETS {
                return Self {
                    lo,
                    hi,
                    scale,
                    step_at,
                    step_base,
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
            match (
                self.step_at.get(bucket as usize),
                self.step_base.get(bucket as usize),
            ) {
                // A byte: the bases are bytes, and a step is one up from a base below 255.
                (Some(&at), Some(&base)) => (base + i32::from(key >= at)) as u8,
                _ => encode_probability(rule.key_probability(key)),
            }
        } else if key.is_nan() {
            CELL_UNKNOWN
        } else {
            encode_probability(rule.key_probability(key))
        }
    }

    /// Encodes `cells` into `bytes` ([`Self::byte`]) and their classes into `classes`
    /// ([`Self::class`]), which held the cells' classes before; returns, per class, how many
    /// cells entered it less how many left it (wrapping). Cells that are their own keys (f32
    /// probabilities and log-odds) go 8 at a time where the CPU has AVX2 ([`Self::encode_keys_avx2`]),
    /// in optimised builds; the rest one by one.
    ///
    /// # Panics
    /// If the three slices differ in length.
    pub(crate) fn encode_cells<R: Combine>(
        &self,
        rule: &R,
        cells: &[R::Cell],
        bytes: &mut [u8],
        classes: &mut [u8],
    ) -> [u32; CellClass::COUNT] {
        // Unoptimised, each intrinsic is a call: the vector path made a debug build's snapshots
        // twice as slow as one by one, and the end-to-end tests run debug builds on loaded
        // machines. Its unit test runs it in every build.
        self.encode_cells_with(rule, cells, bytes, classes, !cfg!(debug_assertions))
    }

    /// [`Self::encode_cells`], 8 at a time where possible only if `vectors`.
    #[cfg_attr(not(target_arch = "x86_64"), allow(unused_variables))]
    fn encode_cells_with<R: Combine>(
        &self,
        rule: &R,
        cells: &[R::Cell],
        bytes: &mut [u8],
        classes: &mut [u8],
        vectors: bool,
    ) -> [u32; CellClass::COUNT] {
        assert!(cells.len() == bytes.len() && cells.len() == classes.len());
        let mut moved = [0u32; CellClass::COUNT];
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if let Some(keys) = R::cells_as_keys(cells).filter(|_| vectors)
            && std::arch::is_x86_feature_detected!("avx2")
        {
            // SAFETY: the CPU has AVX2, checked just above.
            let (n, outside) = unsafe { self.encode_keys_avx2(keys, bytes, classes, &mut moved) };
            if outside {
                // Keys beyond the table (only a hand-made state holds them): the reference.
                for (byte, &key) in bytes[..n].iter_mut().zip(keys) {
                    *byte = self.byte(rule, key);
                }
            }
            done = n;
        }
        for ((byte, class), &cell) in bytes[done..]
            .iter_mut()
            .zip(&mut classes[done..])
            .zip(&cells[done..])
        {
            let key = rule.key(cell);
            *byte = self.byte(rule, key);
            let now = self.class(key) as u8;
            moved[usize::from(*class)] = moved[usize::from(*class)].wrapping_sub(1);
            moved[usize::from(now)] = moved[usize::from(now)].wrapping_add(1);
            *class = now;
        }
        moved
    }

    /// The first multiple of 8 of `keys` encoded as [`Self::encode_cells`] does, 8 at a time: the
    /// same arithmetic as [`Self::byte`] and [`Self::class`] in vector lanes (the table's step by
    /// a gather), each class's moves added to `moved`. Returns how many were done and whether a
    /// key other than NaN lay outside the table, whose byte is then wrong (the caller encodes
    /// those again).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn encode_keys_avx2(
        &self,
        keys: &[f32],
        bytes: &mut [u8],
        classes: &mut [u8],
        moved: &mut [u32; CellClass::COUNT],
    ) -> (usize, bool) {
        use std::arch::x86_64::*;
        /// 8 lanes of 0 to 255 to 8 bytes, in order.
        #[inline]
        #[target_feature(enable = "avx2")]
        fn low_bytes(v: __m256i) -> u64 {
            let words = _mm256_packus_epi32(v, v);
            let bytes = _mm256_packus_epi16(words, words);
            let low = _mm256_extract_epi32::<0>(bytes) as u32;
            let high = _mm256_extract_epi32::<4>(bytes) as u32;
            u64::from(low) | (u64::from(high) << 32)
        }
        let n = keys.len().min(bytes.len()).min(classes.len()) / 8 * 8;
        let last = self.step_at.len().min(self.step_base.len()) - 1;
        // The table is small (at most `MAX_BUCKETS` entries): its indices fit in i32.
        let last_lane = _mm256_set1_epi32(last as i32);
        let (lo, hi, scale) = (
            _mm256_set1_ps(self.lo),
            _mm256_set1_ps(self.hi),
            _mm256_set1_ps(self.scale),
        );
        let (confident, occupied, free) = (
            _mm256_set1_ps(self.confident_from),
            _mm256_set1_ps(self.occupied_from),
            _mm256_set1_ps(self.free_below),
        );
        let class_lane = |c: CellClass| _mm256_set1_epi32(c as i32);
        let mut entered = [_mm256_setzero_si256(); CellClass::COUNT];
        let mut outside = _mm256_setzero_si256();
        for i in (0..n).step_by(8) {
            // SAFETY: i + 8 ≤ n ≤ every slice's length.
            let key = unsafe { _mm256_loadu_ps(keys.as_ptr().add(i)) };
            let in_range = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_GE_OQ>(key, lo),
                _mm256_cmp_ps::<_CMP_LE_OQ>(key, hi),
            );
            let inside = _mm256_blendv_ps(lo, key, in_range);
            // Truncation, as `to_int_unchecked` in `byte`: the same bucket.
            let bucket = _mm256_cvttps_epi32(_mm256_mul_ps(_mm256_sub_ps(inside, lo), scale));
            let beyond = _mm256_cmpgt_epi32(bucket, last_lane);
            let index = _mm256_min_epi32(bucket, last_lane);
            // SAFETY: every index is in 0..=last, within both tables.
            let (at, base) = unsafe {
                (
                    _mm256_i32gather_ps::<4>(self.step_at.as_ptr(), index),
                    _mm256_i32gather_epi32::<4>(self.step_base.as_ptr(), index),
                )
            };
            // A compare gives −1 where true: subtracting it adds the step.
            let up = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_GE_OQ>(inside, at));
            let nan = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_UNORD_Q>(key, key));
            let byte = _mm256_blendv_epi8(
                _mm256_sub_epi32(base, up),
                _mm256_set1_epi32(i32::from(CELL_UNKNOWN)),
                nan,
            );
            let out_of_table = _mm256_or_si256(
                _mm256_xor_si256(_mm256_castps_si256(in_range), _mm256_set1_epi32(-1)),
                beyond,
            );
            outside = _mm256_or_si256(outside, _mm256_andnot_si256(nan, out_of_table));
            // The classes in the order `class` tests them, the first test last.
            let below = |t| _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LT_OQ>(key, t));
            let from = |t| _mm256_castps_si256(_mm256_cmp_ps::<_CMP_GE_OQ>(key, t));
            let mut class = class_lane(CellClass::Even);
            class = _mm256_blendv_epi8(class, class_lane(CellClass::Free), below(free));
            class = _mm256_blendv_epi8(class, class_lane(CellClass::Occupied), from(occupied));
            class = _mm256_blendv_epi8(class, class_lane(CellClass::Confident), from(confident));
            class = _mm256_blendv_epi8(class, class_lane(CellClass::Unknown), nan);
            // SAFETY: i + 8 ≤ n ≤ the classes' length.
            let old =
                unsafe { _mm256_cvtepu8_epi32(_mm_loadl_epi64(classes.as_ptr().add(i).cast())) };
            for (c, entered) in (0..).zip(&mut entered) {
                let lane = _mm256_set1_epi32(c);
                *entered = _mm256_sub_epi32(*entered, _mm256_cmpeq_epi32(class, lane));
                *entered = _mm256_add_epi32(*entered, _mm256_cmpeq_epi32(old, lane));
            }
            // SAFETY: i + 8 ≤ n ≤ both slices' lengths; unaligned writes of 8 bytes.
            unsafe {
                bytes
                    .as_mut_ptr()
                    .add(i)
                    .cast::<u64>()
                    .write_unaligned(low_bytes(byte).to_le());
                classes
                    .as_mut_ptr()
                    .add(i)
                    .cast::<u64>()
                    .write_unaligned(low_bytes(class).to_le());
            }
        }
        for (moved, entered) in moved.iter_mut().zip(entered) {
            let mut lanes = [0i32; 8];
            // SAFETY: 8 i32 lanes into 8 i32s.
            unsafe { _mm256_storeu_si256(lanes.as_mut_ptr().cast(), entered) };
            *moved = lanes
                .iter()
                .fold(*moved, |sum, &lane| sum.wrapping_add(lane as u32));
        }
        (n, _mm256_testz_si256(outside, outside) == 0)
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
    use crate::test_strategies::between;
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
            .step_at
            .iter()
            .copied()
            .filter(|at| at.is_finite())
            .chain([
                encoder.occupied_from,
                encoder.free_below,
                encoder.confident_from,
                encoder.lo,
                encoder.hi,
            ])
            .chain((0..encoder.step_at.len()).map(|i| encoder.lo + i as f32 / encoder.scale));
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

    /// [`KeyEncoder::encode_cells`] on runs of `keys` (cells that are their own keys) against the
    /// reference key by key: bytes, classes and the counts' moves from random earlier classes; 8
    /// at a time (where the CPU has AVX2) or one by one at random, in every build.
    fn check_runs<R: Combine<Cell = f32>>(
        rule: &R,
        keys: &[f32],
        rng: &mut rand_chacha::ChaCha8Rng,
    ) {
        use rand::Rng;
        let encoder = KeyEncoder::new(rule);
        let mut start = 0;
        while start < keys.len() {
            // Runs of every length around the 8 lanes, and long ones.
            let len = rng.random_range(0..=40).min(keys.len() - start);
            let run = &keys[start..start + len];
            let mut classes: Vec<u8> = (0..len)
                .map(|_| rng.random_range(0..CellClass::COUNT as u8))
                .collect();
            let mut expected_moved = [0u32; CellClass::COUNT];
            for &old in &classes {
                expected_moved[usize::from(old)] = expected_moved[usize::from(old)].wrapping_sub(1);
            }
            let mut bytes = vec![0u8; len];
            let vectors = rng.random_bool(0.8);
            let moved = encoder.encode_cells_with(rule, run, &mut bytes, &mut classes, vectors);
            for (i, &key) in run.iter().enumerate() {
                let (byte, class) = reference(rule, key);
                assert_eq!(
                    (bytes[i], classes[i]),
                    (byte, class as u8),
                    "key {key:e} ({:#x}), {i} of a run of {len}",
                    key.to_bits()
                );
                expected_moved[class as usize] = expected_moved[class as usize].wrapping_add(1);
            }
            assert_eq!(moved, expected_moved, "a run of {len}");
            start += len.max(1);
        }
    }

    #[test]
    fn runs_encoded_8_at_a_time_equal_the_reference_key_by_key() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(29);
        let (log_odds, _) = rules();
        let check_rule = |rule: &dyn Fn(&[f32], &mut rand_chacha::ChaCha8Rng),
                          [lo, hi]: [f32; 2],
                          encoder: &KeyEncoder,
                          rng: &mut rand_chacha::ChaCha8Rng| {
            // Every step, bucket edge and threshold with the floats beside them; keys inside and
            // beyond the range; any float at all; shuffled so a vector mixes them.
            let mut keys: Vec<f32> = encoder
                .step_at
                .iter()
                .copied()
                .filter(|at| at.is_finite())
                .chain([
                    encoder.occupied_from,
                    encoder.free_below,
                    encoder.confident_from,
                    lo,
                    hi,
                ])
                .flat_map(|edge| [edge.next_down(), edge, edge.next_up()])
                .chain([f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.0, 0.0])
                .collect();
            keys.extend((0..3000).map(|_| rng.random_range(lo..=hi)));
            keys.extend((0..500).map(|_| rng.random_range(lo - 1.0..hi + 1.0)));
            keys.extend((0..500).map(|_| f32::from_bits(rng.random())));
            for i in (1..keys.len()).rev() {
                keys.swap(i, rng.random_range(0..=i));
            }
            rule(&keys, rng);
            // Runs all inside the table, where nothing is encoded again one by one.
            let inside: Vec<f32> = (0..2000).map(|_| rng.random_range(lo..=hi)).collect();
            rule(&inside, rng);
        };
        let bayes = KeyEncoder::new(&BayesRule);
        check_rule(
            &|keys, rng| check_runs(&BayesRule, keys, rng),
            BayesRule.key_range(),
            &bayes,
            &mut rng,
        );
        for rule in log_odds {
            let encoder = KeyEncoder::new(&rule);
            check_rule(
                &|keys, rng| check_runs(&rule, keys, rng),
                rule.key_range(),
                &encoder,
                &mut rng,
            );
        }
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
            unit in between(-0.5, 1.5),
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
