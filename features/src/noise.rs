//! The sensor's range noise, estimated online from the spread of the pings of each reading.
//!
//! Nothing about a sensor's jitter is assumed: a real SRF05 or HC-SR04 jitters by about a
//! centimetre, more at range (sensor-facts quotes makers' 3–4 cm accuracy), a simulator by what it
//! was written with. What every reading shows is how much its own pings, taken 1.5° apart within
//! a few milliseconds, disagree. Most neighbouring pings hear the same target (a target is heard
//! over 10–60°, four pings span 4.5°), and then their ranges differ by the noise alone: for
//! Gaussian noise of σ the difference d of two pings is N(0, 2σ²), and the median of |d| is
//! 0.6745 · √2 · σ = 0.954 σ. The median over many pairs ignores the minority that straddle the
//! edge of a target (those differ by anything), so it needs no model of the scene.
//!
//! Noise grows with range (the echo is weaker, the detector fires on a later cycle), so the pairs
//! are split by range into bins of equal count, σ is estimated in each, and a line
//! σ(r) = a + b·r (b ≥ 0) is fitted through the bins' medians, never below a floor (the µs
//! rounding, a quantised sensor's steps). The pairs of the last sweeps are kept, up to
//! [`NoiseConfig::window`] of them: the estimate follows a sensor whose noise changes (warming,
//! another head plugged in) within a few sweeps.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// How the range noise is estimated and used.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NoiseConfig {
    /// The estimate never goes below this (1σ, metres): µs rounding, whole-centimetre sensors
    /// (1 cm / √12 = 2.9 mm), and a few pings that agree by chance.
    pub floor_m: f64,
    /// Before enough pairs have been seen (a sweep of a few readings, pings placed without
    /// readings): σ = `prior_sigma_m` + `prior_sigma_fraction` × range, the noise of a hobby
    /// sensor (sensor-facts).
    pub prior_sigma_m: f64,
    pub prior_sigma_fraction: f64,
    /// A ping belongs to a run when it lies within this many σ of the run's mean (its prediction
    /// interval): 4σ splits a run by chance once in ≈ 30 000 pings of Gaussian noise, and still
    /// once in a few hundred when one sweep's estimate is 20 % low.
    pub gate_sigmas: f64,
    /// Pairs of pings kept for the estimate (the last sweeps').
    pub window: usize,
}

impl Default for NoiseConfig {
    fn default() -> Self {
        Self {
            floor_m: 0.003,
            prior_sigma_m: 0.01,
            prior_sigma_fraction: 0.01,
            gate_sigmas: 4.0,
            window: 4096,
        }
    }
}

/// Two neighbouring pings of one reading that both heard something: where, and how far apart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PingPair {
    /// Mean of the two ranges, metres.
    pub range_m: f64,
    /// Absolute difference of the two ranges, metres.
    pub difference_m: f64,
}

impl PingPair {
    /// The pair of two ranges.
    pub fn of(a: f64, b: f64) -> Self {
        Self {
            range_m: (a + b) / 2.0,
            difference_m: (a - b).abs(),
        }
    }
}

/// Pairs of pings further apart than this (plus the share below of their range) are not noise:
/// 7σ of the difference of two pings of a sensor with σ = 1 cm + 1 % at 1 m.
const MAX_DIFFERENCE_M: f64 = 0.05;
const MAX_DIFFERENCE_PER_M: f64 = 0.15;

/// Fewest pairs an estimate is made from; below, the prior holds.
const MIN_PAIRS: usize = 8;
/// Fewest pairs in one range bin.
const PAIRS_PER_BIN: usize = 48;
/// Most range bins.
const MAX_BINS: usize = 6;
/// median |d| / σ for d = difference of two N(0, σ²): 0.6745 · √2.
const MEDIAN_ABS_DIFFERENCE_PER_SIGMA: f64 = 0.953_873;

/// The range noise of one ping as a function of range: σ(r) = max(floor, a + b·r).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseModel {
    /// a, metres.
    pub sigma_m: f64,
    /// b, metres per metre of range.
    pub sigma_per_m: f64,
    pub floor_m: f64,
    /// Pairs it was estimated from (0: the prior).
    pub pairs: usize,
    /// The ranges it was measured over: σ is held constant outside them.
    pub ranges_m: (f64, f64),
}

impl NoiseModel {
    /// The prior of `cfg`, before any pair is seen.
    pub fn prior(cfg: &NoiseConfig) -> Self {
        Self {
            sigma_m: cfg.prior_sigma_m,
            sigma_per_m: cfg.prior_sigma_fraction,
            floor_m: cfg.floor_m,
            pairs: 0,
            ranges_m: (0.0, f64::INFINITY),
        }
    }

    /// A fixed model (tests, a sensor whose noise is known).
    pub fn fixed(sigma_m: f64, sigma_per_m: f64) -> Self {
        Self {
            sigma_m,
            sigma_per_m,
            floor_m: 0.0,
            pairs: 0,
            ranges_m: (0.0, f64::INFINITY),
        }
    }

    /// σ of one ping's range at `range_m`.
    pub fn sigma_at(&self, range_m: f64) -> f64 {
        let r = range_m.clamp(self.ranges_m.0.max(0.0), self.ranges_m.1.max(0.0));
        (self.sigma_m + self.sigma_per_m * r).max(self.floor_m)
    }

    /// The model estimated from `pairs` (module docs), or the prior when there are too few.
    pub fn estimate(pairs: impl IntoIterator<Item = PingPair>, cfg: &NoiseConfig) -> Self {
        // A pair farther apart than any working ranger's noise makes straddles two targets; in
        // a scene of few targets at few ranges (two posts before a wall) such pairs would fill a
        // bin of their own.
        let mut ranked: Vec<(usize, PingPair)> = pairs
            .into_iter()
            .filter(|p| {
                p.range_m.is_finite()
                    && p.difference_m.is_finite()
                    && p.difference_m <= MAX_DIFFERENCE_M + MAX_DIFFERENCE_PER_M * p.range_m
            })
            .enumerate()
            .collect();
        let n = ranked.len();
        if n < MIN_PAIRS {
            return Self::prior(cfg);
        }
        // The pairs in order of range (ties in the order given, as a stable sort leaves them)
        // split into bins of equal count. Each bin's medians need only which pairs it holds, so
        // the bins are found by selection, O(n) each, not by sorting the window: an estimate is
        // made for every direction a sweep on the move is looked in (180 a sweep,
        // `FeatureMap::walls_on_the_move`), and sorting 4096 pairs each time was most of the
        // fusion's work on a moving robot.
        let by_rank = |a: &(usize, PingPair), b: &(usize, PingPair)| {
            a.1.range_m.total_cmp(&b.1.range_m).then(a.0.cmp(&b.0))
        };
        let bins = (n / PAIRS_PER_BIN).clamp(1, MAX_BINS);
        let edges: Vec<usize> = (0..=bins).map(|k| k * n / bins).collect();
        for k in 1..bins {
            // Everything before edges[k - 1] already ranks below everything after it.
            let (from, at) = (edges[k - 1], edges[k]);
            ranked[from..].select_nth_unstable_by(at - from, by_rank);
        }
        let points: Vec<(f64, f64)> = edges
            .windows(2)
            .map(|edge| {
                let bin = &ranked[edge[0]..edge[1]];
                let range = median(bin.iter().map(|(_, p)| p.range_m));
                let sigma = median(bin.iter().map(|(_, p)| p.difference_m))
                    / MEDIAN_ABS_DIFFERENCE_PER_SIGMA;
                (range, sigma)
            })
            .collect();
        let (a, b) = line_fit(&points);
        let ranges = ranked.iter().map(|(_, p)| p.range_m);
        Self {
            sigma_m: a,
            sigma_per_m: b,
            floor_m: cfg.floor_m,
            pairs: n,
            // Beyond the ranges it was measured at, the line is not extrapolated.
            ranges_m: (
                ranges.clone().min_by(f64::total_cmp).unwrap_or(0.0),
                ranges.max_by(f64::total_cmp).unwrap_or(0.0),
            ),
        }
    }
}

/// Median of a non-empty set (0 for an empty one), by selection.
fn median(values: impl Iterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = values.collect();
    let n = v.len();
    if n == 0 {
        return 0.0;
    }
    let (below, &mut middle, _) = v.select_nth_unstable_by(n / 2, f64::total_cmp);
    if n % 2 == 1 {
        middle
    } else {
        // The largest of the lower half is the other middle value.
        let lower = below
            .iter()
            .copied()
            .max_by(f64::total_cmp)
            .unwrap_or(middle);
        (lower + middle) / 2.0
    }
}

/// Least-squares line σ = a + b·r through the bins, its slope kept ≥ 0 (noise does not shrink
/// with range; a negative slope is the scatter of a few bins): then the bins' mean.
fn line_fit(points: &[(f64, f64)]) -> (f64, f64) {
    let n = points.len() as f64;
    let mean_r = points.iter().map(|p| p.0).sum::<f64>() / n;
    let mean_s = points.iter().map(|p| p.1).sum::<f64>() / n;
    let srr: f64 = points.iter().map(|p| (p.0 - mean_r).powi(2)).sum();
    let srs: f64 = points.iter().map(|p| (p.0 - mean_r) * (p.1 - mean_s)).sum();
    // Bins less than 10 cm apart in range say nothing about a slope.
    if srr < n * 0.1f64.powi(2) || srs <= 0.0 {
        return (mean_s, 0.0);
    }
    let b = srs / srr;
    (mean_s - b * mean_r, b)
}

/// The pairs of the last sweeps, for [`NoiseModel::estimate`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct NoiseLog {
    pairs: VecDeque<PingPair>,
}

impl NoiseLog {
    /// Keeps `pairs`, forgetting the oldest beyond `cfg.window`.
    pub fn add(&mut self, pairs: &[PingPair], cfg: &NoiseConfig) {
        self.pairs.extend(pairs.iter().copied());
        let excess = self.pairs.len().saturating_sub(cfg.window);
        self.pairs.drain(..excess);
    }

    /// The model from the kept pairs and `fresh` ones (the sweep being looked at).
    pub fn model_with(&self, fresh: &[PingPair], cfg: &NoiseConfig) -> NoiseModel {
        let keep = cfg.window.saturating_sub(fresh.len());
        let skip = self.pairs.len().saturating_sub(keep);
        NoiseModel::estimate(self.pairs.iter().skip(skip).chain(fresh).copied(), cfg)
    }

    pub fn len(&self) -> usize {
        self.pairs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use rand::{Rng, SeedableRng, rngs::StdRng};
    use rand_distr::{Distribution, Normal};

    /// Pairs of pings of readings at ranges spread over `from..to`, with Gaussian noise
    /// σ = `a` + `b` × range, and a share `straddling` of pairs across two targets 0.3–1 m apart.
    pub(crate) fn noisy_pairs(
        n: usize,
        from: f64,
        to: f64,
        (a, b): (f64, f64),
        straddling: f64,
        seed: u64,
    ) -> Vec<PingPair> {
        let mut rng = StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                let r = rng.random_range(from..to);
                let noise = Normal::new(0.0, a + b * r).unwrap();
                let x = r + noise.sample(&mut rng);
                let y = if rng.random_bool(straddling) {
                    r + rng.random_range(0.3..1.0)
                } else {
                    r + noise.sample(&mut rng)
                };
                PingPair::of(x, y)
            })
            .collect()
    }

    /// The estimate as first written: the window sorted by range (stably), the bins' medians of
    /// sorted copies.
    fn estimate_by_sorting(pairs: &[PingPair], cfg: &NoiseConfig) -> NoiseModel {
        let sorted_median = |values: &mut Vec<f64>| {
            values.sort_by(f64::total_cmp);
            let n = values.len();
            if n % 2 == 1 {
                values[n / 2]
            } else {
                (values[n / 2 - 1] + values[n / 2]) / 2.0
            }
        };
        let mut pairs: Vec<PingPair> = pairs
            .iter()
            .copied()
            .filter(|p| p.difference_m <= MAX_DIFFERENCE_M + MAX_DIFFERENCE_PER_M * p.range_m)
            .collect();
        let n = pairs.len();
        if n < MIN_PAIRS {
            return NoiseModel::prior(cfg);
        }
        pairs.sort_by(|a, b| a.range_m.total_cmp(&b.range_m));
        let bins = (n / PAIRS_PER_BIN).clamp(1, MAX_BINS);
        let points: Vec<(f64, f64)> = (0..bins)
            .map(|k| {
                let bin = &pairs[k * n / bins..(k + 1) * n / bins];
                let mut ranges: Vec<f64> = bin.iter().map(|p| p.range_m).collect();
                let mut differences: Vec<f64> = bin.iter().map(|p| p.difference_m).collect();
                (
                    sorted_median(&mut ranges),
                    sorted_median(&mut differences) / MEDIAN_ABS_DIFFERENCE_PER_SIGMA,
                )
            })
            .collect();
        let (a, b) = line_fit(&points);
        NoiseModel {
            sigma_m: a,
            sigma_per_m: b,
            floor_m: cfg.floor_m,
            pairs: n,
            ranges_m: (pairs[0].range_m, pairs[n - 1].range_m),
        }
    }

    #[test]
    fn selection_gives_the_estimate_sorting_gave_bit_for_bit() {
        let cfg = NoiseConfig::default();
        let mut rng = StdRng::seed_from_u64(11);
        for trial in 0..200 {
            let n = rng.random_range(0..1200);
            let mut pairs = noisy_pairs(n, 0.2, 3.5, (0.01, 0.01), 0.1, trial);
            // Whole centimetres (an `nxt`-like sensor): many pairs of equal range, across the
            // bins' edges, where the order of ties decides which bin a pair falls in.
            if trial % 2 == 0 {
                for p in &mut pairs {
                    let (x, y) = (
                        p.range_m - p.difference_m / 2.0,
                        p.range_m + p.difference_m / 2.0,
                    );
                    *p = PingPair::of((x * 100.0).round() / 100.0, (y * 100.0).round() / 100.0);
                }
            }
            assert_eq!(
                NoiseModel::estimate(pairs.iter().copied(), &cfg),
                estimate_by_sorting(&pairs, &cfg),
                "trial {trial}, {n} pairs"
            );
        }
    }

    #[test]
    fn the_estimate_finds_the_noise_and_its_growth_with_range() {
        let cfg = NoiseConfig::default();
        for (a, b) in [(0.003, 0.0), (0.01, 0.0), (0.01, 0.01), (0.005, 0.02)] {
            let pairs = noisy_pairs(1500, 0.4, 3.5, (a, b), 0.1, 7);
            let m = NoiseModel::estimate(pairs, &cfg);
            for r in [0.5, 1.0, 2.0, 3.0] {
                let truth = a + b * r;
                let got = m.sigma_at(r);
                // Within 20 % (the pairs straddling two targets bias it upwards a little).
                assert!(
                    (got / truth - 1.0).abs() < 0.2,
                    "σ = {a} + {b} r at {r} m: {got} vs {truth} ({m:?})"
                );
            }
        }
    }

    #[test]
    fn pairs_across_two_targets_do_not_make_noise() {
        // Two posts at 1 m before a wall at 2 m: most pairs on the posts, a few on the wall, a
        // tenth straddling a post's edge (1 m apart).
        let mut pairs = noisy_pairs(300, 1.0, 1.02, (0.003, 0.0), 0.0, 5);
        pairs.extend(noisy_pairs(30, 2.0, 2.01, (0.003, 0.0), 0.0, 6));
        pairs.extend((0..40).map(|_| PingPair::of(1.01, 2.0)));
        let m = NoiseModel::estimate(pairs, &NoiseConfig::default());
        for r in [1.0, 1.5, 2.0, 4.0] {
            assert!(m.sigma_at(r) < 0.005, "{r} m: {m:?}");
        }
    }

    #[test]
    fn too_few_pairs_give_the_prior_and_quiet_pings_the_floor() {
        let cfg = NoiseConfig::default();
        let few = noisy_pairs(5, 1.0, 2.0, (0.05, 0.0), 0.0, 1);
        assert_eq!(NoiseModel::estimate(few, &cfg), NoiseModel::prior(&cfg));
        let quiet = vec![PingPair::of(1.0, 1.0); 100];
        let m = NoiseModel::estimate(quiet, &cfg);
        assert_eq!(m.sigma_at(1.0), cfg.floor_m);
        assert_eq!(m.pairs, 100);
    }

    #[test]
    fn the_log_keeps_the_last_window_of_pairs() {
        let cfg = NoiseConfig {
            window: 200,
            ..NoiseConfig::default()
        };
        let mut log = NoiseLog::default();
        // An old, quiet sensor, then a noisy one: the estimate follows the new one.
        log.add(&noisy_pairs(500, 1.0, 2.0, (0.003, 0.0), 0.0, 2), &cfg);
        assert_eq!(log.len(), 200);
        let quiet = log.model_with(&[], &cfg).sigma_at(1.5);
        log.add(&noisy_pairs(150, 1.0, 2.0, (0.03, 0.0), 0.0, 3), &cfg);
        let fresh = noisy_pairs(100, 1.0, 2.0, (0.03, 0.0), 0.0, 4);
        let noisy = log.model_with(&fresh, &cfg).sigma_at(1.5);
        assert!(quiet < 0.004 && noisy > 0.025, "{quiet} {noisy}");
    }
}
