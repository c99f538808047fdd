//! Combination rules: how a cell's fused state absorbs one reading's evidence.
//!
//! Each rule keeps the state it needs per cell (a probability for the paper's eq. 6, log-odds,
//! a pair of Dempster–Shafer masses, a HIMM counter) and reads it out as one occupancy probability.
//! A cell no reading has reached holds the rule's `UNKNOWN` sentinel (NaN, or 255 for HIMM), which
//! every `fuse` treats as the prior: so "never observed" needs no second array and stays apart from
//! "observed, undecided" in the snapshots.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::config_error::{ConfigError, UnknownName, check};

/// Which form of a model's evidence a rule consumes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Domain {
    Probability,
    LogOdds,
}

/// A combination rule over cells of type `Cell`.
pub(crate) trait Combine: Copy {
    type Cell: Copy + fmt::Debug;
    /// The state of a cell no reading has reached.
    const UNKNOWN: Self::Cell;
    /// The evidence `fuse` takes.
    const DOMAIN: Domain;

    /// Cells farther off the axis than this are left alone (HIMM updates only near the axis).
    fn cone_half_angle(&self, beam_half_angle: f32) -> f32 {
        beam_half_angle
    }

    /// Fuses `evidence` (a probability or log-odds, per `DOMAIN`) into `cell`; NaN evidence leaves
    /// it untouched. Returns whether the cell was updated. Branch-free (selects only), so a loop
    /// over a row of cells vectorises.
    fn fuse(&self, cell: &mut Self::Cell, evidence: f32) -> bool;

    /// The number a cell's probability rises with ([`Self::key_probability`]); NaN for a cell no
    /// reading has reached. What the snapshot encoding is a table over ([`crate::encoding`]).
    fn key(&self, cell: Self::Cell) -> f32;

    /// The occupancy probability of a cell with `key`, non-decreasing in it.
    fn key_probability(&self, key: f32) -> f32;

    /// The keys a fused cell can have, `[lowest, highest]`.
    fn key_range(&self) -> [f32; 2];

    /// The cells as their keys, if a cell is its own key (an f32 whose [`Self::key`] is itself):
    /// then the snapshot encoding reads them 8 at a time
    /// ([`crate::encoding::KeyEncoder::encode_cells`]).
    fn cells_as_keys(_cells: &[Self::Cell]) -> Option<&[f32]> {
        None
    }

    /// Occupancy probability of a cell; `None` if no reading has reached it.
    #[inline(always)]
    fn probability(&self, cell: Self::Cell) -> Option<f32> {
        let key = self.key(cell);
        (!key.is_nan()).then(|| self.key_probability(key))
    }
}

/// The names a rule goes by in configuration files and on command lines.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RuleKind {
    Bayes,
    LogOdds,
    DempsterShafer,
    Himm,
}

impl RuleKind {
    pub const ALL: [RuleKind; 4] = [
        RuleKind::Bayes,
        RuleKind::LogOdds,
        RuleKind::DempsterShafer,
        RuleKind::Himm,
    ];
    const NAMES: [&'static str; 4] = ["bayes", "log-odds", "dempster-shafer", "himm"];

    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }

    /// The `sonar_common::ipc::rule_code` of this rule.
    pub fn code(self) -> u32 {
        use sonar_common::ipc::rule_code;
        match self {
            RuleKind::Bayes => rule_code::BAYES,
            RuleKind::LogOdds => rule_code::LOG_ODDS,
            RuleKind::DempsterShafer => rule_code::DEMPSTER_SHAFER,
            RuleKind::Himm => rule_code::HIMM,
        }
    }

    /// The rule with this `sonar_common::ipc::rule_code`.
    pub fn from_code(code: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.code() == code)
    }
}

impl fmt::Display for RuleKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for RuleKind {
    type Err = UnknownName;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| UnknownName::new("combination rule", s, &Self::NAMES))
    }
}

/// A combination rule and its parameters; `[rule]` in a configuration file, with `kind` naming it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum RuleConfig {
    /// The paper's recursive Bayes, eq. 6, on probabilities, exactly as written.
    Bayes,
    LogOdds(LogOddsRule),
    DempsterShafer,
    Himm(HimmRule),
}

impl RuleConfig {
    /// `kind` with its default parameters.
    pub fn default_for(kind: RuleKind) -> Self {
        match kind {
            RuleKind::Bayes => RuleConfig::Bayes,
            RuleKind::LogOdds => RuleConfig::LogOdds(LogOddsRule::default()),
            RuleKind::DempsterShafer => RuleConfig::DempsterShafer,
            RuleKind::Himm => RuleConfig::Himm(HimmRule::default()),
        }
    }

    pub fn kind(&self) -> RuleKind {
        match self {
            RuleConfig::Bayes => RuleKind::Bayes,
            RuleConfig::LogOdds(_) => RuleKind::LogOdds,
            RuleConfig::DempsterShafer => RuleKind::DempsterShafer,
            RuleConfig::Himm(_) => RuleKind::Himm,
        }
    }

    pub fn validate(&self) -> Result<(), ConfigError> {
        match self {
            RuleConfig::Bayes | RuleConfig::DempsterShafer => Ok(()),
            RuleConfig::LogOdds(r) => r.validate(),
            RuleConfig::Himm(r) => r.validate(),
        }
    }
}

/// The paper's eq. 6: P ← p·P / (p·P + (1 − p)(1 − P)), on f32 probabilities.
///
/// Once rounding has taken a cell to exactly 0 or 1 (eight readings of 0.9 reach 1), p·P or
/// (1 − p)(1 − P) vanishes and no later reading can move it: the map cannot forget a moved
/// obstacle. That is the paper's rule; [`LogOddsRule`] clamps instead.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BayesRule;

impl Combine for BayesRule {
    type Cell = f32;
    const UNKNOWN: f32 = f32::NAN;
    const DOMAIN: Domain = Domain::Probability;

    #[inline(always)]
    fn fuse(&self, cell: &mut f32, p: f32) -> bool {
        let prior = if cell.is_nan() { 0.5 } else { *cell };
        let num = p * prior;
        let den = num + (1.0 - p) * (1.0 - prior);
        // 0/0 only when a certain cell meets certain contrary evidence: eq. 6 is undefined there;
        // the cell keeps its value.
        let posterior = if den > 0.0 { num / den } else { prior };
        let fused = !p.is_nan();
        *cell = if fused { posterior } else { *cell };
        fused
    }

    #[inline(always)]
    fn key(&self, cell: f32) -> f32 {
        cell
    }

    #[inline(always)]
    fn key_probability(&self, p: f32) -> f32 {
        p
    }

    fn key_range(&self) -> [f32; 2] {
        [0.0, 1.0]
    }

    fn cells_as_keys(cells: &[f32]) -> Option<&[f32]> {
        Some(cells)
    }
}

/// Log-odds accumulation, l ← clamp(l + l_reading, min, max): the same posterior as eq. 6 while
/// inside the clamps, but a cell never becomes certain, so contrary evidence can always bring it
/// back (as in OctoMap's clamping policy).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LogOddsRule {
    /// Floor of a cell's log-odds (< 0).
    pub min_log_odds: f32,
    /// Ceiling of a cell's log-odds (> 0).
    pub max_log_odds: f32,
}

impl Default for LogOddsRule {
    /// OctoMap's clamping thresholds: probabilities 0.12 and 0.97.
    fn default() -> Self {
        Self {
            min_log_odds: -2.0,
            max_log_odds: 3.5,
        }
    }
}

impl LogOddsRule {
    fn validate(&self) -> Result<(), ConfigError> {
        check(
            "rule.min_log_odds",
            self.min_log_odds,
            self.min_log_odds < 0.0 && self.min_log_odds.is_finite(),
            "a negative number",
        )?;
        check(
            "rule.max_log_odds",
            self.max_log_odds,
            self.max_log_odds > 0.0 && self.max_log_odds.is_finite(),
            "a positive number",
        )
    }
}

impl Combine for LogOddsRule {
    type Cell = f32;
    const UNKNOWN: f32 = f32::NAN;
    const DOMAIN: Domain = Domain::LogOdds;

    #[inline(always)]
    fn fuse(&self, cell: &mut f32, l: f32) -> bool {
        let prior = if cell.is_nan() { 0.0 } else { *cell };
        // ±∞ evidence (a model's p of 0 or 1) lands on the clamps. Comparisons rather than
        // f32::max/min, whose NaN handling costs instructions in the vectorised loop: a NaN sum
        // (NaN evidence) is never stored.
        let sum = prior + l;
        let posterior = if sum < self.min_log_odds {
            self.min_log_odds
        } else if sum > self.max_log_odds {
            self.max_log_odds
        } else {
            sum
        };
        let fused = !l.is_nan();
        *cell = if fused { posterior } else { *cell };
        fused
    }

    #[inline(always)]
    fn key(&self, cell: f32) -> f32 {
        cell
    }

    #[inline(always)]
    fn key_probability(&self, l: f32) -> f32 {
        crate::model::sigmoid(l)
    }

    fn key_range(&self) -> [f32; 2] {
        [self.min_log_odds, self.max_log_odds]
    }

    fn cells_as_keys(cells: &[f32]) -> Option<&[f32]> {
        Some(cells)
    }
}

/// Dempster's rule over the frame {occupied, free}: a cell holds the masses m(occupied) and
/// m(free); the rest, m(unknown) = 1 − both, is ignorance (1 before any reading).
///
/// A reading's probability p becomes the consonant masses m(occupied) = max(0, 2p − 1),
/// m(free) = max(0, 1 − 2p), whose pignistic probability is p again. (Murphy, the paper's [2],
/// uses eq. 1's value itself as m(occupied); that would count region-I values below 0.5 as
/// occupancy here but as free space under Bayes, and we keep one meaning for a model's output.)
/// Read out as the pignistic probability m(occupied) + m(unknown)/2. Like eq. 6 it saturates:
/// a mass that reaches 1 absorbs every later reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DempsterShaferRule;

impl Combine for DempsterShaferRule {
    /// [m(occupied), m(free)].
    type Cell = [f32; 2];
    const UNKNOWN: [f32; 2] = [f32::NAN, f32::NAN];
    const DOMAIN: Domain = Domain::Probability;

    #[inline(always)]
    fn fuse(&self, cell: &mut [f32; 2], p: f32) -> bool {
        let [o1, e1] = if cell[0].is_nan() { [0.0, 0.0] } else { *cell };
        let u1 = 1.0 - o1 - e1;
        let o2 = (2.0 * p - 1.0).max(0.0);
        let e2 = (1.0 - 2.0 * p).max(0.0);
        let u2 = 1.0 - o2 - e2;
        let norm = 1.0 - (o1 * e2 + e1 * o2);
        // Total conflict (certain occupied meets certain free) is undefined: keep the cell.
        let combined = if norm > 0.0 {
            [
                (o1 * o2 + o1 * u2 + u1 * o2) / norm,
                (e1 * e2 + e1 * u2 + u1 * e2) / norm,
            ]
        } else {
            [o1, e1]
        };
        let fused = !p.is_nan();
        *cell = if fused { combined } else { *cell };
        fused
    }

    /// The pignistic probability (NaN masses: NaN).
    #[inline(always)]
    fn key(&self, [o, e]: [f32; 2]) -> f32 {
        0.5 * (1.0 + o - e)
    }

    #[inline(always)]
    fn key_probability(&self, p: f32) -> f32 {
        p
    }

    fn key_range(&self) -> [f32; 2] {
        [0.0, 1.0]
    }
}

/// HIMM (Borenstein & Koren's Histogramic In-Motion Mapping, named in the paper): a small counter
/// per cell, raised by `increment` where a reading implies occupancy and lowered by `decrement`
/// where it implies free space, within 0..=`max_count`, only for cells near the beam axis (HIMM
/// updates the acoustic axis). Read out as count / `max_count`; counters start at 0 as in the
/// original, so a cell needs several hits before it reads as occupied. The growth-rate operator
/// of the original (raising neighbours) is not part of this rule.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HimmRule {
    pub increment: u8,
    pub decrement: u8,
    pub max_count: u8,
    /// Cells farther than this off the beam axis are not updated. 3° is half the spacing of the
    /// readings, so one sweep covers every bearing once.
    pub axis_half_angle_deg: f32,
}

impl Default for HimmRule {
    /// The original's I = 3, D = 1, counters 0..15.
    fn default() -> Self {
        Self {
            increment: 3,
            decrement: 1,
            max_count: 15,
            axis_half_angle_deg: 3.0,
        }
    }
}

/// HIMM's sentinel for a cell never reached; counters stay below it.
const HIMM_UNKNOWN: u8 = u8::MAX;

impl HimmRule {
    fn validate(&self) -> Result<(), ConfigError> {
        let max = f32::from(self.max_count);
        check(
            "rule.max_count",
            max,
            self.max_count > 0 && self.max_count < HIMM_UNKNOWN,
            "in 1..=254",
        )?;
        check(
            "rule.increment",
            f32::from(self.increment),
            self.increment > 0 && self.increment <= self.max_count,
            "in 1..=max_count",
        )?;
        check(
            "rule.decrement",
            f32::from(self.decrement),
            self.decrement > 0 && self.decrement <= self.max_count,
            "in 1..=max_count",
        )?;
        check(
            "rule.axis_half_angle_deg",
            self.axis_half_angle_deg,
            self.axis_half_angle_deg > 0.0 && self.axis_half_angle_deg < 90.0,
            "in (0, 90) degrees",
        )
    }
}

impl Combine for HimmRule {
    type Cell = u8;
    const UNKNOWN: u8 = HIMM_UNKNOWN;
    const DOMAIN: Domain = Domain::LogOdds;

    fn cone_half_angle(&self, beam_half_angle: f32) -> f32 {
        beam_half_angle.min(self.axis_half_angle_deg.to_radians())
    }

    #[inline(always)]
    fn fuse(&self, cell: &mut u8, l: f32) -> bool {
        let prior = if *cell == HIMM_UNKNOWN { 0 } else { *cell };
        let counted = if l > 0.0 {
            prior.saturating_add(self.increment).min(self.max_count)
        } else if l < 0.0 {
            prior.saturating_sub(self.decrement)
        } else {
            prior
        };
        let fused = !l.is_nan();
        *cell = if fused { counted } else { *cell };
        fused
    }

    /// The counter.
    #[inline(always)]
    fn key(&self, cell: u8) -> f32 {
        if cell == HIMM_UNKNOWN {
            f32::NAN
        } else {
            f32::from(cell)
        }
    }

    #[inline(always)]
    fn key_probability(&self, count: f32) -> f32 {
        count / f32::from(self.max_count)
    }

    fn key_range(&self) -> [f32; 2] {
        [0.0, f32::from(self.max_count)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::logit;

    /// Fuses `evidence` into a fresh cell, `times` times.
    fn repeat<R: Combine>(rule: R, mut cell: R::Cell, evidence: f32, times: usize) -> R::Cell {
        for _ in 0..times {
            assert!(rule.fuse(&mut cell, evidence));
        }
        cell
    }

    /// The evidence a rule takes for probability `p`.
    fn ev<R: Combine>(p: f32) -> f32 {
        match R::DOMAIN {
            Domain::Probability => p,
            Domain::LogOdds => logit(p),
        }
    }

    #[test]
    fn eq6_by_hand() {
        let mut c = BayesRule::UNKNOWN;
        assert_eq!(BayesRule.probability(c), None);
        // From the prior 0.5 the posterior is the reading itself (eq. 4).
        BayesRule.fuse(&mut c, 0.8);
        assert!((c - 0.8).abs() < 1e-6);
        // 0.8·0.3 / (0.8·0.3 + 0.2·0.7) = 0.24 / 0.38, with P(s|¬H) = 1 − P(s|H) (eq. 5).
        BayesRule.fuse(&mut c, 0.3);
        assert!((c - 0.24 / 0.38).abs() < 1e-6);
        assert!(!BayesRule.fuse(&mut c, f32::NAN));
        assert!((c - 0.24 / 0.38).abs() < 1e-6);
    }

    #[test]
    fn log_odds_matches_eq6_inside_the_clamps() {
        let rule = LogOddsRule {
            min_log_odds: -20.0,
            max_log_odds: 20.0,
        };
        let mut b = BayesRule::UNKNOWN;
        let mut l = LogOddsRule::UNKNOWN;
        for p in [0.8, 0.3, 0.45, 0.9, 0.2] {
            BayesRule.fuse(&mut b, p);
            rule.fuse(&mut l, logit(p));
            assert!((rule.probability(l).unwrap() - b).abs() < 1e-5);
        }
    }

    #[test]
    fn bayes_saturates_and_never_recovers() {
        // In f32, eight readings of 0.9 round the cell to exactly 1 (odds 9⁸ > 2²⁴).
        assert!(repeat(BayesRule, BayesRule::UNKNOWN, 0.9, 7) < 1.0);
        let c = repeat(BayesRule, BayesRule::UNKNOWN, 0.9, 8);
        assert_eq!(c, 1.0);
        let c = repeat(BayesRule, c, 0.02, 1000);
        assert_eq!(c, 1.0);
        // Certain contrary evidence meets a certain cell: eq. 6 is 0/0; the cell keeps its value.
        assert_eq!(repeat(BayesRule, c, 0.0, 1), 1.0);
    }

    #[test]
    fn log_odds_clamps_and_recovers() {
        let rule = LogOddsRule::default();
        let c = repeat(rule, LogOddsRule::UNKNOWN, logit(0.9), 1000);
        assert_eq!(c, 3.5);
        // Infinite evidence lands on the clamps too.
        assert_eq!(repeat(rule, c, f32::INFINITY, 1), 3.5);
        // 3.5 / ln(9) ≈ 1.6: two free readings of 0.1 take it below one half.
        let c = repeat(rule, c, logit(0.1), 2);
        assert!(rule.probability(c).unwrap() < 0.5);
        assert_eq!(repeat(rule, c, f32::NEG_INFINITY, 1), -2.0);
    }

    #[test]
    fn dempster_shafer_by_hand_and_saturation() {
        let rule = DempsterShaferRule;
        let mut c = DempsterShaferRule::UNKNOWN;
        // p = 0.8 → m(O) = 0.6, m(U) = 0.4; pignistic 0.8.
        rule.fuse(&mut c, 0.8);
        assert!((c[0] - 0.6).abs() < 1e-6 && c[1] == 0.0);
        assert!((rule.probability(c).unwrap() - 0.8).abs() < 1e-6);
        // p = 0.3 → m(E) = 0.4, m(U) = 0.6. Conflict 0.6·0.4 = 0.24;
        // m(O) = 0.6·0.6 / 0.76, m(E) = 0.4·0.4 / 0.76.
        rule.fuse(&mut c, 0.3);
        assert!((c[0] - 0.36 / 0.76).abs() < 1e-6);
        assert!((c[1] - 0.16 / 0.76).abs() < 1e-6);
        // Saturation: m(O) reaches 1 and absorbs everything after.
        let c = repeat(rule, DempsterShaferRule::UNKNOWN, 0.9, 40);
        assert_eq!(c, [1.0, 0.0]);
        assert_eq!(repeat(rule, c, 0.05, 1000), [1.0, 0.0]);
        // p = 0.5 carries no mass: ignorance stays.
        let c = repeat(rule, DempsterShaferRule::UNKNOWN, 0.5, 3);
        assert_eq!(rule.probability(c), Some(0.5));
    }

    #[test]
    fn himm_counts_clamps_and_recovers() {
        let rule = HimmRule::default();
        let c = repeat(rule, HimmRule::UNKNOWN, ev::<HimmRule>(0.7), 1);
        assert_eq!(c, 3);
        let c = repeat(rule, c, ev::<HimmRule>(0.7), 100);
        assert_eq!(c, 15);
        assert_eq!(rule.probability(c), Some(1.0));
        let c = repeat(rule, c, ev::<HimmRule>(0.3), 8);
        assert_eq!(c, 7);
        assert!(rule.probability(c).unwrap() < 0.5);
        assert_eq!(repeat(rule, c, ev::<HimmRule>(0.3), 100), 0);
        assert_eq!(rule.cone_half_angle(1.0), 3f32.to_radians());
    }

    #[test]
    fn nan_evidence_leaves_every_rule_alone() {
        fn untouched<R: Combine>(rule: R) {
            let mut c = R::UNKNOWN;
            assert!(!rule.fuse(&mut c, f32::NAN));
            assert_eq!(rule.probability(c), None);
        }
        untouched(BayesRule);
        untouched(LogOddsRule::default());
        untouched(DempsterShaferRule);
        untouched(HimmRule::default());
    }

    #[test]
    fn rule_names_parse_and_list_the_valid_ones() {
        for kind in RuleKind::ALL {
            assert_eq!(kind.name().parse::<RuleKind>(), Ok(kind));
            assert_eq!(RuleKind::from_code(kind.code()), Some(kind));
            assert_eq!(RuleConfig::default_for(kind).kind(), kind);
        }
        assert_eq!(
            "ds".parse::<RuleKind>().unwrap_err().to_string(),
            "unknown combination rule \"ds\"; valid names: bayes, log-odds, dempster-shafer, himm"
        );
    }
}
