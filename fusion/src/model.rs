//! Inverse sensor models: what one reading says about one cell of its cone.
//!
//! A model turns a [`Beam`] into a per-reading [`CellEvidence`] (the reading's constants worked
//! out once), which then answers for any cell at range `r` and angle `alpha` off the beam axis with
//! the occupancy probability the reading alone implies (prior 0.5), or its log-odds — whichever the
//! combination rule consumes, so neither rule pays for a conversion when the model is native in
//! its domain. NaN means "no evidence": the cell lies beyond the reading (region III) and stays as
//! it is.
//!
//! A model may also remember, per cell, the bearing it last heard the cell occupied from
//! ([`CellEvidence::HEARD`]): the smooth model weighs a later reading's free evidence at that cell
//! by whether a specular reflector heard from there could have answered this reading at all.

use std::f32::consts::{FRAC_PI_2, PI, TAU};
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::config_error::{ConfigError, UnknownName, check};
use crate::geometry;
use crate::observation::Beam;
use crate::regions::DepthTolerance;

/// What one reading says about the cells of its cone, with its constants worked out.
pub(crate) trait CellEvidence: Copy {
    /// Whether the evidence for a cell depends on the bearing the cell was last heard occupied
    /// from ([`Self::heard_log_odds`]); if not, the kernels pass no such bearings.
    const HEARD: bool = false;

    /// Farthest range this reading updates.
    fn reach(&self) -> f32;
    /// Farthest angle off the axis, radians, at which this reading can give evidence: cells
    /// beyond it get none at any range, so the kernels need not visit them.
    fn half_angle(&self) -> f32 {
        f32::INFINITY
    }
    /// Nearest range at which this reading can give evidence: cells nearer get none at any
    /// angle, so the kernels need not visit them (an echo without free evidence).
    fn near(&self) -> f32 {
        0.0
    }
    /// P(occupied | this reading) for a cell at range `r`, `alpha` radians off the axis; NaN for
    /// no evidence. By default from [`Self::log_odds`], for models native in log-odds.
    #[inline(always)]
    fn probability(&self, r: f32, alpha: f32) -> f32 {
        sigmoid(self.log_odds(r, alpha))
    }
    /// The same as log-odds, ln(p / (1 − p)); NaN for no evidence.
    fn log_odds(&self, r: f32, alpha: f32) -> f32;

    /// [`Self::log_odds`] for a cell at world bearing `bearing` from the sensor that was last
    /// heard occupied from world bearing `heard` (NaN: never), which it updates. Only called when
    /// [`Self::HEARD`].
    #[inline(always)]
    fn heard_log_odds(&self, r: f32, alpha: f32, _bearing: f32, _heard: &mut f32) -> f32 {
        self.log_odds(r, alpha)
    }

    /// Whether this evidence is weighted by the [`radial_trust`] of the cell's range (at
    /// [`Self::fade_range`]): a pure function of the range, so a kernel that keeps the cells'
    /// ranges keeps their trust too and passes it to [`Self::trusted_heard_log_odds`].
    const FADES: bool = false;

    /// The range at which the evidence's [`radial_trust`] is one half, if [`Self::FADES`].
    fn fade_range(&self) -> f32 {
        f32::NAN
    }

    /// [`Self::heard_log_odds`] given the cell's `trust`, `radial_trust(r, self.fade_range())`
    /// computed by the caller (ignored unless [`Self::FADES`]): the same bits.
    #[inline(always)]
    fn trusted_heard_log_odds(
        &self,
        r: f32,
        alpha: f32,
        bearing: f32,
        heard: &mut f32,
        _trust: f32,
    ) -> f32 {
        self.heard_log_odds(r, alpha, bearing, heard)
    }

    /// [`Self::log_odds`] given the cell's `trust`, as [`Self::trusted_heard_log_odds`].
    #[inline(always)]
    fn trusted_log_odds(&self, r: f32, alpha: f32, _trust: f32) -> f32 {
        self.log_odds(r, alpha)
    }

    /// [`Self::heard_log_odds`] as a probability.
    #[inline(always)]
    fn heard_probability(&self, r: f32, alpha: f32, bearing: f32, heard: &mut f32) -> f32 {
        sigmoid(self.heard_log_odds(r, alpha, bearing, heard))
    }
}

/// The items of a [`CellEvidence`] whose evidence is weighted by the [`radial_trust`] at its
/// `fade_range` field: the forms without a trust work it out and call the trusted forms, which
/// the type writes itself (one definition of the model per type, whoever computes the trust).
macro_rules! fades_at_its_fade_range {
    () => {
        #[inline(always)]
        fn log_odds(&self, r: f32, alpha: f32) -> f32 {
            self.trusted_log_odds(r, alpha, radial_trust(r, self.fade_range))
        }

        #[inline(always)]
        fn heard_log_odds(&self, r: f32, alpha: f32, bearing: f32, heard: &mut f32) -> f32 {
            let trust = radial_trust(r, self.fade_range);
            self.trusted_heard_log_odds(r, alpha, bearing, heard, trust)
        }

        const FADES: bool = true;

        fn fade_range(&self) -> f32 {
            self.fade_range
        }
    };
}

/// ln(p / (1 − p)); ±∞ at 0 and 1, which the log-odds rule's clamping absorbs.
pub(crate) fn logit(p: f32) -> f32 {
    (p / (1.0 - p)).ln()
}

/// max(v, 0), NaN to 0 (as f32::max), written as a comparison so that it compiles to a single
/// vector max instruction.
#[inline(always)]
fn positive(v: f32) -> f32 {
    if v > 0.0 { v } else { 0.0 }
}

/// How much a reading counts at range `r`: 1 near the sensor, one half at `fade_range`, towards
/// 0 beyond (ROS `range_sensor_layer`'s φ_v, as a smooth step).
#[inline(always)]
pub(crate) fn radial_trust(r: f32, fade_range: f32) -> f32 {
    let x = 2.0 * (r - fade_range);
    0.5 - 0.5 * x / (1.0 + x * x).sqrt()
}

/// 1 / (1 + e^(−l)).
pub(crate) fn sigmoid(l: f32) -> f32 {
    1.0 / (1.0 + (-l).exp())
}

/// The names a model goes by in configuration files and on command lines.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ModelKind {
    /// The paper's eqs. 1–3.
    Paper,
    /// The inverse range-sensor model of *Probabilistic Robotics* (Table 9.2).
    LogOdds,
    /// Smooth angular and radial fall-off after ROS `range_sensor_layer`.
    Smooth,
}

impl ModelKind {
    pub const ALL: [ModelKind; 3] = [ModelKind::Paper, ModelKind::LogOdds, ModelKind::Smooth];
    const NAMES: [&'static str; 3] = ["paper", "log-odds", "smooth"];

    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }

    /// The `sonar_common::ipc::model_code` of this model.
    pub fn code(self) -> u32 {
        use sonar_common::ipc::model_code;
        match self {
            ModelKind::Paper => model_code::PAPER,
            ModelKind::LogOdds => model_code::LOG_ODDS,
            ModelKind::Smooth => model_code::SMOOTH,
        }
    }

    /// The model with this `sonar_common::ipc::model_code`.
    pub fn from_code(code: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.code() == code)
    }
}

impl fmt::Display for ModelKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for ModelKind {
    type Err = UnknownName;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| UnknownName::new("sensor model", s, &Self::NAMES))
    }
}

/// A sensor model and its parameters; `[model]` in a configuration file, with `kind` naming it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum ModelConfig {
    Paper(PaperModel),
    LogOdds(LogOddsModel),
    Smooth(SmoothModel),
}

impl ModelConfig {
    /// `kind` with its default parameters.
    pub fn default_for(kind: ModelKind) -> Self {
        match kind {
            ModelKind::Paper => ModelConfig::Paper(PaperModel::default()),
            ModelKind::LogOdds => ModelConfig::LogOdds(LogOddsModel::default()),
            ModelKind::Smooth => ModelConfig::Smooth(SmoothModel::default()),
        }
    }

    pub fn kind(&self) -> ModelKind {
        match self {
            ModelConfig::Paper(_) => ModelKind::Paper,
            ModelConfig::LogOdds(_) => ModelKind::LogOdds,
            ModelConfig::Smooth(_) => ModelKind::Smooth,
        }
    }

    pub fn validate(&self) -> Result<(), ConfigError> {
        match self {
            ModelConfig::Paper(m) => m.validate(),
            ModelConfig::LogOdds(m) => m.validate(),
            ModelConfig::Smooth(m) => m.validate(),
        }
    }

    /// Farthest range any reading can update when ranges go up to `max_range`.
    pub(crate) fn max_reach(&self, max_range: f32) -> f32 {
        match self {
            ModelConfig::Paper(m) => max_range * (1.0 + m.tolerance),
            ModelConfig::LogOdds(_) => max_range,
            ModelConfig::Smooth(m) => m.max_reach(max_range),
        }
    }

    /// Whether the model keeps, per cell, the bearing the cell was last heard occupied from
    /// ([`CellEvidence::HEARD`]).
    pub(crate) fn hears(&self) -> bool {
        match self {
            ModelConfig::Paper(_) => PaperReading::HEARD,
            ModelConfig::LogOdds(_) => LogOddsReading::HEARD,
            ModelConfig::Smooth(_) => SmoothReading::HEARD,
        }
    }

    /// Farthest angle off the axis, radians, at which any reading can give evidence.
    pub(crate) fn max_half_angle(&self) -> f32 {
        match self {
            ModelConfig::Paper(_) | ModelConfig::LogOdds(_) => f32::INFINITY,
            ModelConfig::Smooth(m) => m.max_half_angle(),
        }
    }
}

/// Runs `$body` with `$m` bound to the concrete model inside a [`ModelConfig`], so the kernels are
/// compiled once per model with its evidence inlined into their loops.
macro_rules! with_model {
    ($model:expr, $m:ident => $body:expr) => {
        match $model {
            $crate::model::ModelConfig::Paper($m) => $body,
            $crate::model::ModelConfig::LogOdds($m) => $body,
            $crate::model::ModelConfig::Smooth($m) => $body,
        }
    };
}
pub(crate) use with_model;

/// What the paper's β stands for.
///
/// The paper calls β "the beam width" yet tests membership with ±30° (so the width is 60°), and
/// its source \[2\] (Murphy) defines β as *half* the field of view. With β the half-angle the term
/// (β − |α|)/β runs from 1 on the axis to 0 at the edge, like (R − r)/R runs from 1 at the sensor
/// to 0 at the maximum range; with the full width it never falls below one half, so the cone's
/// edge would count as much as the middle of a half-as-wide beam. We read β as the half-angle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BeamWidth {
    #[default]
    HalfAngle,
    FullWidth,
}

/// How the paper's α enters eqs. 1–2.
///
/// The paper defines α = a − θ (signed) and writes (β − α)/β. Taken literally the model is not
/// symmetric about the beam axis: one edge gets (β + β)/β = 2 and the probabilities leave [0, 1].
/// Murphy's model (the paper's \[2\]) is symmetric; we use |α| and keep the literal form as an
/// option (its results are clamped to [0, 1]). α is counter-clockwise positive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AlphaSign {
    #[default]
    Absolute,
    Signed,
}

/// The paper's sensor model, eqs. 1–3.
///
/// With s = ((R − r)/R + (β − |α|)/β) / 2:
/// - region I, d(1 − p) ≤ r ≤ d(1 + p): P(s|H) = s · MaxOccupied (eq. 1);
/// - region II, r < d(1 − p): P(s|H) = 1 − s (eq. 2);
/// - region III, beyond: unknown, no update (eq. 3).
///
/// With the prior 0.5, P(H|s) = P(s|H) (eq. 4). Both eqs. are flawed: s < 1/2 wherever
/// (R − r)/R + (β − |α|)/β < 1, i.e. far from the sensor or near the beam's edge, and there eq. 2
/// exceeds 0.5 — evidence of *occupancy* in front of the echo, which paints phantom wedges along
/// the cone's edges — while eq. 1 falls below 0.5, evidence of *free* space where the echo came
/// from. This model keeps both, as written; the recommended [`SmoothModel`] has neither.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PaperModel {
    /// The paper's % error p, as a fraction: region I is d(1 − p)..d(1 + p). The paper gives no
    /// value; 0.05 is the 5 % of Murphy's worked example (tolerance 0.5 at a range of 10) and covers
    /// the SRF05's 3–4 cm quoted accuracy at ranges beyond 0.7 m.
    pub tolerance: f32,
    /// MaxOccupied: 0.98 as in Murphy's example (the paper gives no value); below 1 so no single
    /// reading makes a cell certain.
    pub max_occupied: f32,
    pub beam_width: BeamWidth,
    pub alpha: AlphaSign,
}

impl Default for PaperModel {
    fn default() -> Self {
        Self {
            tolerance: 0.05,
            max_occupied: 0.98,
            beam_width: BeamWidth::HalfAngle,
            alpha: AlphaSign::Absolute,
        }
    }
}

impl PaperModel {
    fn validate(&self) -> Result<(), ConfigError> {
        check(
            "model.tolerance",
            self.tolerance,
            (0.0..1.0).contains(&self.tolerance),
            "a fraction in [0, 1)",
        )?;
        check(
            "model.max_occupied",
            self.max_occupied,
            self.max_occupied > 0.5 && self.max_occupied <= 1.0,
            "in (0.5, 1]",
        )
    }

    pub(crate) fn reading(&self, beam: &Beam) -> PaperReading {
        let beta = match self.beam_width {
            BeamWidth::HalfAngle => beam.half_angle,
            BeamWidth::FullWidth => 2.0 * beam.half_angle,
        };
        let (inner, outer) = match beam.echo {
            Some(d) => (d * (1.0 - self.tolerance), d * (1.0 + self.tolerance)),
            // Clearing: region II up to the maximum range, no region I.
            None => (beam.max_range, f32::NEG_INFINITY),
        };
        PaperReading {
            inv_range: 1.0 / beam.max_range,
            range: beam.max_range,
            beta,
            inv_beta: 1.0 / beta,
            inner,
            outer,
            max_occupied: self.max_occupied,
            signed: self.alpha == AlphaSign::Signed,
        }
    }
}

#[derive(Debug, Clone, Copy)]
pub(crate) struct PaperReading {
    range: f32,
    inv_range: f32,
    beta: f32,
    inv_beta: f32,
    inner: f32,
    outer: f32,
    max_occupied: f32,
    signed: bool,
}

impl CellEvidence for PaperReading {
    fn reach(&self) -> f32 {
        self.inner.max(self.outer)
    }

    #[inline(always)]
    fn probability(&self, r: f32, alpha: f32) -> f32 {
        let alpha = if self.signed { alpha } else { alpha.abs() };
        let s = ((self.range - r) * self.inv_range + (self.beta - alpha) * self.inv_beta) * 0.5;
        let p = if r < self.inner {
            1.0 - s // eq. 2
        } else if r <= self.outer {
            s * self.max_occupied // eq. 1
        } else {
            f32::NAN // eq. 3
        };
        p.clamp(0.0, 1.0)
    }

    #[inline(always)]
    fn log_odds(&self, r: f32, alpha: f32) -> f32 {
        logit(self.probability(r, alpha))
    }
}

/// The inverse range-sensor model of Thrun, Burgard & Fox, *Probabilistic Robotics*, Table 9.2,
/// for one beam: l_occ within `thickness_m / 2` of the measured range, l_free in front of it,
/// nothing beyond, uniformly across the cone. Native in log-odds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LogOddsModel {
    /// p_occ: the occupancy the reading implies at the echo.
    pub occupied_probability: f32,
    /// p_free: the occupancy the reading implies in front of the echo.
    pub free_probability: f32,
    /// The book's α: thickness of obstacles, metres.
    pub thickness_m: f32,
}

impl Default for LogOddsModel {
    fn default() -> Self {
        // Values commonly used with the book's algorithm; 5 cm covers the SRF05's 3–4 cm accuracy.
        Self {
            occupied_probability: 0.7,
            free_probability: 0.3,
            thickness_m: 0.05,
        }
    }
}

impl LogOddsModel {
    fn validate(&self) -> Result<(), ConfigError> {
        check(
            "model.occupied_probability",
            self.occupied_probability,
            self.occupied_probability > 0.5 && self.occupied_probability < 1.0,
            "in (0.5, 1)",
        )?;
        check(
            "model.free_probability",
            self.free_probability,
            self.free_probability > 0.0 && self.free_probability < 0.5,
            "in (0, 0.5)",
        )?;
        check(
            "model.thickness_m",
            self.thickness_m,
            self.thickness_m > 0.0 && self.thickness_m.is_finite(),
            "a positive number of metres",
        )
    }

    pub(crate) fn reading(&self, beam: &Beam) -> LogOddsReading {
        let half = self.thickness_m / 2.0;
        let (free_to, occupied_to) = match beam.echo {
            // The book stops at min(z_max, z + α/2).
            Some(d) => (d - half, (d + half).min(beam.max_range)),
            None => (beam.max_range, f32::NEG_INFINITY),
        };
        LogOddsReading {
            free_to,
            occupied_to,
            p_occ: self.occupied_probability,
            p_free: self.free_probability,
            l_occ: logit(self.occupied_probability),
            l_free: logit(self.free_probability),
        }
    }
}

#[derive(Debug, Clone, Copy)]
pub(crate) struct LogOddsReading {
    free_to: f32,
    occupied_to: f32,
    p_occ: f32,
    p_free: f32,
    l_occ: f32,
    l_free: f32,
}

impl LogOddsReading {
    #[inline(always)]
    fn pick(&self, r: f32, free: f32, occupied: f32) -> f32 {
        if r <= self.free_to {
            free
        } else if r < self.occupied_to {
            occupied
        } else {
            f32::NAN
        }
    }
}

impl CellEvidence for LogOddsReading {
    fn reach(&self) -> f32 {
        self.free_to.max(self.occupied_to)
    }

    #[inline(always)]
    fn probability(&self, r: f32, _alpha: f32) -> f32 {
        self.pick(r, self.p_free, self.p_occ)
    }

    #[inline(always)]
    fn log_odds(&self, r: f32, _alpha: f32) -> f32 {
        self.pick(r, self.l_free, self.l_occ)
    }
}

/// A model with smooth angular and radial fall-off, shaped after ROS `range_sensor_layer`, native
/// in log-odds, with separate angular profiles for occupied and free evidence.
///
/// With γ(α; θ) = max(0, 1 − (α/θ)²) (ROS's angular weight), w = max(`min_band_m`,
/// `band_fraction`·d) (ROS's δ·r), and the radial trust f(r) = (1 − x/√(1 + x²))/2 with
/// x = 2(r − `fade_range_m`) (ROS's (1 − tanh x)/2, with an algebraic sigmoid of the same midpoint
/// and slope that costs a square root instead of an exponential, so the kernel vectorises):
/// - free, r < d − 2w: l = `free_log_odds` · γ(α; θ_free) · f(r);
/// - ramp, d − 2w ≤ r < d − w: the same times 1 − t², t = (r − (d − 2w))/w (ROS's quadratic ramp);
/// - occupied, d − w ≤ r < d + w: l = `occupied_log_odds` · γ(α; θ_occ) · f(r) · (1 − ((r − d)/w)²);
/// - beyond: nothing.
///
/// It never raises occupancy in front of the occupied band d ± w (the range's own uncertainty), nor
/// lowers it within the band.
///
/// **Free evidence only where a reflector would have answered.** A flat board or wall is a
/// specular reflector: it returns an echo only to a sensor near its perpendicular, and a beam that
/// passes along it or meets it at a slant hears whatever lies beyond. So each cell remembers the
/// world bearing from which a reading last put occupied evidence on it (the sensor then lay near
/// the reflector's perpendicular, or the echo would not have come back). A later reading's free
/// evidence at that cell is weighted by the incidence i, the angle between the bearing it sees
/// the cell at and the remembered one, folded into [0°, 90°] (a thin board answers from either
/// side): full up to `incidence_full_deg`, falling linearly to none at `incidence_none_deg`. A
/// cell never heard occupied takes full free evidence, so truly empty space is cleared as before;
/// the readings of one standing sweep see every cell at the bearing they heard it from (i = 0),
/// so a single sweep's map is the same as without this weighting.
///
/// ROS scales the probability's deviation from one half by the weights, with extremes 0 and 1
/// (infinite log-odds on the axis); scaling log-odds keeps every reading's evidence finite, and
/// the two separate angular widths let free-space evidence reach wider than occupied evidence,
/// which stays near the axis, where a small object is actually heard.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SmoothModel {
    /// Log-odds added at the measured range on the axis, near the sensor (> 0).
    pub occupied_log_odds: f32,
    /// Log-odds added in front of the measured range on the axis, near the sensor (< 0).
    pub free_log_odds: f32,
    /// Angle off the axis where occupied evidence falls to zero.
    pub occupied_half_angle_deg: f32,
    /// Angle off the axis where free evidence falls to zero.
    pub free_half_angle_deg: f32,
    /// Half-thickness of the occupied band as a fraction of the measured range (ROS's δ).
    pub band_fraction: f32,
    /// Smallest half-thickness of the occupied band, metres.
    pub min_band_m: f32,
    /// Range at which the radial trust has fallen to one half (ROS's φ_v).
    pub fade_range_m: f32,
    /// Incidence up to which a cell heard occupied still takes a reading's full free evidence.
    pub incidence_full_deg: f32,
    /// Incidence from which it takes none (above `incidence_full_deg`; beyond 90° never reached,
    /// so the weight then stays above zero).
    pub incidence_none_deg: f32,
    /// Where a reading's echo puts its occupied evidence.
    pub echo_placement: EchoPlacement,
    /// With `echo_placement = "region"`: two readings are the same depth while their ranges differ
    /// by at most this many metres …
    pub region_tolerance_m: f32,
    /// … plus this fraction of the range.
    pub region_tolerance_fraction: f32,
    /// With `echo_placement = "region"`: half the angle, seen from the sensor, of the straight patch
    /// a region's occupied evidence is drawn on, square to its middle bearing at its range.
    pub region_half_angle_deg: f32,
    /// With `echo_placement = "region"`: when above 0, a region's patch also reaches at most this
    /// many metres along the wall each side of its foot, whatever its range. A foot heard says
    /// nothing of where its wall ends, and an angle claims more of it the farther it is: 18° is
    /// 0.3 m each side at 1 m and 1.3 m at 4 m, past many a board's end (docs/fusion.md,
    /// twenty-ninth round). 0: the angle alone.
    pub region_half_width_m: f32,
    /// With `echo_placement = "region"`: a region heard to stop on one side and running to the
    /// sweep's limit (or a gap in the angles) on the other is placed at the sweep's end one lobe
    /// half-width in from its natural end, the lobe learnt from the whole regions
    /// ([`crate::regions::LobeWidth`]); its readings clear nothing unless
    /// [`Self::region_one_end_free`].
    pub region_one_end: bool,
    /// With `region_one_end`: a one-ended region that is placed gives its readings' free evidence
    /// as a whole region's do (each up to its own range less the depth tolerance and band): its
    /// reflector's bearing is known from its natural end, and its readings heard that reflector.
    /// Without it, the space in front of a wall heard up to the sweep's limit (a servo head's
    /// side walls) is never observed.
    pub region_one_end_free: bool,
    /// With `echo_placement = "region"`: a region cut short on both sides, narrower than the
    /// lobe, is placed as a point at its middle bearing if two walls heard so far meet there (a
    /// corner masked by the nearer feet of its own walls); its readings clear nothing.
    pub region_corners: bool,
    /// With `echo_placement = "region"`: walls are drawn from their patches to where they end
    /// (at most 3 m): to the concave corner where two walls' lines meet, if some region heard an
    /// echo at its range and bearing, and to a whole region's reflector on the wall's line (a
    /// jamb, an edge); unless readings saw through the stretch
    /// ([`crate::lines::Lines::join_ends`]).
    pub region_corner_walls: bool,
    /// With `echo_placement = "region"`: the readings of a region that is not whole put this
    /// much occupied log-odds on their own axis at their range (0: nothing), with no free
    /// evidence, unless the grid holds an occupied cell on the axis in front of the echo: a
    /// standing scan then shows what it heard where no region can be placed. Like any echo, its
    /// cells remember the bearing they were heard from.
    pub region_weak_echo_log_odds: f32,
    /// With weak echoes: at each sweep's end, a weak echo is taken back (its log-odds subtracted)
    /// once the grid holds an occupied cell on its axis in front of it, a wall drawn after it
    /// that its axis would have met first (the echo came from off the axis, behind that wall).
    pub region_weak_echo_withdrawn: bool,
    /// With `region_weak_echo_withdrawn`: a weak echo is also taken back once a wall drawn since
    /// (a cell above what weak echoes make) lies in the lobe at the echo's range, within the
    /// depth tolerance and band, and the axis does not meet that wall's line (square to the
    /// bearing it was heard from) at the echo's range: the reading heard that wall at its foot,
    /// off its axis, and the echo put on the axis lies in front of the wall or beyond its end.
    /// A weak echo on the line of such a wall is kept (the wall may run on beyond what was drawn).
    pub region_weak_echo_explained: bool,
    /// With weak echoes: how far across its axis each is drawn at its range, metres (its
    /// profile falls to nothing there, never wider than the occupied profile's
    /// ±`occupied_half_angle_deg`); 0: across the occupied profile. A weak echo is one reading of
    /// a region that is not whole: it measured a range along its axis and nothing across it (a
    /// region's width is what tells a reflector's extent), and its reflector may lie anywhere in
    /// the lobe; an arc across the axis draws cells on no surface wherever the axis meets a wall
    /// at a slant or the echo came from off the axis. A grid cell (0.02) draws it as a point.
    pub region_weak_echo_half_width_m: f32,
    /// With weak echoes: the readings of a region heard to stop on one side and cut short by a
    /// nearer echo on the other put their weak echoes on the bearing its reflector was heard
    /// from, a lobe less half a step in from the natural end
    /// ([`crate::regions::Region::cut_short_axis`]), instead of on their own axes, once the lobe
    /// has been learnt: a wall heard beside a post, its foot hidden behind the post, is heard at
    /// the lobe's edge, not on the axes.
    pub region_weak_echo_at_reflector: bool,
    /// With `echo_placement = "region"`: the readings of a region cut short on both sides by
    /// nearer echoes clear their axes up to the nearer of those echoes' ranges
    /// ([`crate::regions::Region::masking_range`]) less its depth tolerance and band: whatever
    /// their own echo came from, a reflector on their axes nearer than the ones heard a step of
    /// the head away on either side would have answered them first (the space in front of a
    /// corner heard between its walls' feet). Not up to their own range: a region not whole may
    /// have heard its echo off its axes, and clearing up to it erased the room's walls.
    pub region_masked_free: bool,
    /// With `region_masked_free`: when both regions that cut it short are small reflectors'
    /// ([`crate::regions::Region::is_small`]: whole, two readings or more, narrower than half the
    /// lobe over which a wall is heard, as a post's or an edge's is and a wall's foot is not), the
    /// region's readings clear their axes up to their own ranges less the depth tolerance and
    /// band instead: their axes passed beside two small reflectors, and a reflector on an axis
    /// nearer than its echo would have answered first (the gap between two posts). Cut short by
    /// a wall's foot, an axis may have crossed that wall at a slant, which is silent, and its
    /// echo come from off the axis: only up to the nearer cutting echo, as without this.
    pub region_small_cutters_free: bool,
    /// With `echo_placement = "region"`: a stretch of wall between two patches of one wall
    /// (which no reading heard) is refused only where a reading refutes it
    /// ([`crate::sightlines`]): the foot of the perpendicular from its sensor lies on the
    /// stretch, within the lobe learnt at that range, unhidden, and it heard its first echo
    /// farther than the foot (a flat wall there would have answered at the foot). Off: refused
    /// where the grid holds three cells in a row along it free, which the free evidence of
    /// readings that crossed the wall at a slant, towards an echo heard beyond it in the lobe,
    /// also makes.
    pub region_stretch_foot_check: bool,
    /// With `region_corner_walls`: the same check for the stretches drawn from a patch on to
    /// where its wall ends, instead of the grid's free cells.
    pub region_corner_walls_foot_check: bool,
    /// With `region_corner_walls`: a wall is drawn on to a corner from its patch only if another
    /// viewpoint's patch lies on its line (the wall's line is then known from two places), or if
    /// both walls that meet there were heard from one place (a room's walls around its
    /// viewpoint). A patch heard from one place may be a post's or an edge's, square to the
    /// bearing it was heard from: followed on to wherever its line crosses another wall's near
    /// some echo, it drew walls across rooms, a star of them around each post heard from several
    /// places.
    pub region_corner_walls_confirmed: bool,
    /// With `echo_placement = "region"`: a reflector heard whole at one spot from two viewpoints
    /// whose bearings to it differ by 6° or more is a point (a post, an edge, a corner: a wall
    /// answers each viewpoint at its own foot), and its patches are drawn a cell wide, those
    /// drawn before taken back ([`crate::points`]); nor is it followed as a wall.
    pub region_points: bool,
    /// With `region_corner_walls`: a wall is drawn on from its patch only where the sensor that
    /// heard the patch, or another viewpoint a whole region was heard from, sees it, as far as
    /// the grid shows (no wall between): not behind walls, where no reading could check it.
    pub region_corner_walls_seen: bool,
    /// With `region_points` and `region_corner_walls`: at a sweep's end, a whole region's patch
    /// drawn in that sweep whose reflector lies where two other walls heard so far meet
    /// ([`crate::lines::Lines::corner_of_others_at`]) is a corner's (a concave corner answers from any
    /// bearing, as a point does, over the whole lobe when its walls are met too slantwise to
    /// answer) and is drawn a cell wide, its patch taken back; nor is it followed as a wall.
    /// Drawn as a wall it was a stretch across the corner square to the bearing it was heard
    /// from, half of it behind the room's walls.
    pub region_corner_points: bool,
    /// With `region_corner_walls`: the patches that lie on one line from several viewpoints,
    /// their feet at least 0.5 m apart along it, are put on the line through their feet (a
    /// total least-squares fit) before walls are followed from them. A foot lies on its wall to
    /// within the range's error whatever the bearing's; a patch's own facing is its region's
    /// middle bearing, a degree or two off, which a wall followed 3 m to its corner turns into
    /// centimetres.
    pub region_lines_through_feet: bool,
    /// With `region_stretch_foot_check` or `region_corner_walls_foot_check`: a stretch drawn and
    /// refuted later by a reading heard farther at its foot is taken back only within 10 cm of
    /// that foot, not whole (a 1 m piece): a reading refutes the wall where it would have
    /// answered, and a whole piece taken back with it can hold wall another viewpoint drew.
    pub region_stretch_withdrawn_at_feet: bool,
    /// With `echo_placement = "region"`: at a sweep's end, an occupied cell that every viewpoint
    /// within the sensor's reach sees only through something a reading heard (within 1° of its
    /// axis at its echo's range) and the grid holds above p = 0.97, more than 10 cm in front of
    /// it, is set back to unknown unless a reading heard it too: sound does not pass what
    /// echoed, so no echo could have come from there ([`crate::hidden`]).
    pub region_hidden_unknown: bool,
    /// With `region_hidden_unknown`: any cell the grid holds above p = 0.97 hides what lies
    /// behind it, walls drawn on included. Fewer wrong cells, but a wall drawn on wrongly in
    /// front of a true one hides that one too.
    pub region_hidden_behind_walls: bool,
}

/// Where a reading's echo puts its occupied evidence ([`SmoothModel::echo_placement`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EchoPlacement {
    /// On the reading's own axis, at its range: each reading alone.
    #[default]
    Reading,
    /// Once per region of constant depth (the readings of a sweep that heard the same range one
    /// after the other, [`crate::regions`]), on a straight patch at the region's middle bearing,
    /// where the reflector is; only the readings of a region whose reflector stopped being heard
    /// on both sides give evidence, occupied or free.
    Region,
}

impl Default for SmoothModel {
    /// The recommended preset's parameters, but for where echoes go and the parts of the region
    /// model (each reading's echo on its own axis here; the preset places them by region,
    /// [`crate::config::FusionConfig::preset`]); `lib.rs` explains the choice.
    fn default() -> Self {
        Self {
            occupied_log_odds: 1.0,
            free_log_odds: -1.5,
            occupied_half_angle_deg: 6.0,
            free_half_angle_deg: 7.0,
            band_fraction: 0.01,
            min_band_m: 0.025,
            fade_range_m: 3.0,
            incidence_full_deg: 0.0,
            incidence_none_deg: 10.0,
            echo_placement: EchoPlacement::Reading,
            region_tolerance_m: 0.02,
            region_tolerance_fraction: 0.02,
            region_half_angle_deg: 18.0,
            region_half_width_m: 0.0,
            region_one_end: false,
            region_one_end_free: false,
            region_corners: false,
            region_corner_walls: false,
            region_weak_echo_log_odds: 0.0,
            region_weak_echo_withdrawn: false,
            region_weak_echo_explained: false,
            region_weak_echo_at_reflector: false,
            region_weak_echo_half_width_m: 0.0,
            region_masked_free: false,
            region_small_cutters_free: false,
            region_stretch_foot_check: false,
            region_corner_walls_foot_check: false,
            region_corner_walls_confirmed: false,
            region_points: false,
            region_corner_walls_seen: false,
            region_corner_points: false,
            region_lines_through_feet: false,
            region_stretch_withdrawn_at_feet: false,
            region_hidden_unknown: false,
            region_hidden_behind_walls: false,
        }
    }
}

impl SmoothModel {
    fn validate(&self) -> Result<(), ConfigError> {
        check(
            "model.occupied_log_odds",
            self.occupied_log_odds,
            self.occupied_log_odds > 0.0 && self.occupied_log_odds.is_finite(),
            "a positive number",
        )?;
        check(
            "model.free_log_odds",
            self.free_log_odds,
            self.free_log_odds < 0.0 && self.free_log_odds.is_finite(),
            "a negative number",
        )?;
        for (name, v) in [
            (
                "model.occupied_half_angle_deg",
                self.occupied_half_angle_deg,
            ),
            ("model.free_half_angle_deg", self.free_half_angle_deg),
        ] {
            check(name, v, v > 0.0 && v < 90.0, "in (0, 90) degrees")?;
        }
        check(
            "model.band_fraction",
            self.band_fraction,
            (0.0..0.5).contains(&self.band_fraction),
            "a fraction in [0, 0.5)",
        )?;
        check(
            "model.min_band_m",
            self.min_band_m,
            self.min_band_m > 0.0 && self.min_band_m.is_finite(),
            "a positive number of metres",
        )?;
        check(
            "model.fade_range_m",
            self.fade_range_m,
            self.fade_range_m > 0.0 && self.fade_range_m.is_finite(),
            "a positive number of metres",
        )?;
        check(
            "model.incidence_full_deg",
            self.incidence_full_deg,
            (0.0..=90.0).contains(&self.incidence_full_deg),
            "in [0, 90] degrees",
        )?;
        check(
            "model.incidence_none_deg",
            self.incidence_none_deg,
            self.incidence_none_deg > self.incidence_full_deg && self.incidence_none_deg <= 180.0,
            "above model.incidence_full_deg, at most 180 degrees",
        )?;
        for (name, v) in [
            ("model.region_tolerance_m", self.region_tolerance_m),
            (
                "model.region_tolerance_fraction",
                self.region_tolerance_fraction,
            ),
        ] {
            check(name, v, (0.0..1.0).contains(&v), "in [0, 1)")?;
        }
        check(
            "model.region_weak_echo_log_odds",
            self.region_weak_echo_log_odds,
            (0.0..=self.occupied_log_odds).contains(&self.region_weak_echo_log_odds),
            "in [0, model.occupied_log_odds]",
        )?;
        check(
            "model.region_weak_echo_half_width_m",
            self.region_weak_echo_half_width_m,
            (0.0..=1.0).contains(&self.region_weak_echo_half_width_m),
            "in [0, 1] metres",
        )?;
        check(
            "model.region_half_angle_deg",
            self.region_half_angle_deg,
            self.region_half_angle_deg > 0.0 && self.region_half_angle_deg < 60.0,
            "in (0, 60) degrees",
        )?;
        check(
            "model.region_half_width_m",
            self.region_half_width_m,
            (0.0..=10.0).contains(&self.region_half_width_m),
            "in [0, 10] metres (0: no limit)",
        )
    }

    /// The depth tolerance of a region, with `echo_placement = "region"`, else `None`.
    pub(crate) fn regions(&self) -> Option<DepthTolerance> {
        (self.echo_placement == EchoPlacement::Region).then_some(DepthTolerance {
            absolute_m: self.region_tolerance_m,
            fraction: self.region_tolerance_fraction,
        })
    }

    /// The half-angle of a region's patch, radians, when echoes are placed by region, else 0.
    fn region_half_angle(&self) -> f32 {
        match self.echo_placement {
            EchoPlacement::Reading => 0.0,
            EchoPlacement::Region => self.region_half_angle_deg.to_radians(),
        }
    }

    /// The farthest range a reading or a region's patch can update when ranges go up to
    /// `max_range`.
    pub(crate) fn max_reach(&self, max_range: f32) -> f32 {
        (max_range + self.band(max_range)) / self.region_half_angle().cos()
    }

    /// The widest angle off the axis at which a reading or a region's patch gives evidence.
    pub(crate) fn max_half_angle(&self) -> f32 {
        self.half_angle().max(self.region_half_angle() * 1.001)
    }

    pub(crate) fn band(&self, d: f32) -> f32 {
        self.min_band_m.max(self.band_fraction * d)
    }

    /// How far a reflector heard at range `d` may lie from it along the beam and still be the
    /// one heard: the regions' `depth` tolerance and the occupied band together.
    pub(crate) fn depth_and_band(&self, depth: DepthTolerance, d: f32) -> f32 {
        depth.at(d) + self.band(d)
    }

    /// The wider profile's half-angle, radians, 0.1 % wider: beyond it 1 − (α/θ)² rounds to below
    /// zero for both profiles, so no cell there gets evidence.
    pub(crate) fn half_angle(&self) -> f32 {
        let widest = self.occupied_half_angle_deg.max(self.free_half_angle_deg);
        widest.to_radians() * 1.001
    }

    pub(crate) fn reading(&self, beam: &Beam) -> SmoothReading {
        let inv_sq = |deg: f32| {
            let t = deg.to_radians();
            1.0 / (t * t)
        };
        let (d, band) = match beam.echo {
            Some(d) => (d, self.band(d)),
            // Clearing: free at full strength up to the maximum range, no occupied band.
            None => (f32::NEG_INFINITY, 0.0),
        };
        let (ramp_from, free_to) = match beam.echo {
            Some(_) => (d - 2.0 * band, d - band),
            None => (beam.max_range, beam.max_range),
        };
        SmoothReading {
            d,
            ramp_from,
            free_to,
            occupied_to: d + band,
            inv_band: if band > 0.0 { 1.0 / band } else { 0.0 },
            // Placed by region, a reading's echo waits for its region to close
            // ([`Self::region_echo`]).
            l_occ: match self.echo_placement {
                EchoPlacement::Reading => self.occupied_log_odds,
                EchoPlacement::Region => 0.0,
            },
            l_free: self.free_log_odds,
            inv_sq_occ: inv_sq(self.occupied_half_angle_deg),
            inv_sq_free: inv_sq(self.free_half_angle_deg),
            fade_range: self.fade_range_m,
            half_angle: self.half_angle(),
            incidence_none: self.incidence_none_deg.to_radians(),
            inv_incidence_span: 1.0
                / (self.incidence_none_deg - self.incidence_full_deg).to_radians(),
        }
    }

    /// A weak echo on `beam`'s own axis: occupied evidence `log_odds` on the axis at its range and
    /// no free evidence; its cells remember the bearing they were heard from, as any echo's. With
    /// `region_weak_echo_half_width_m`, the profile falls to nothing that far off the axis at the
    /// echo's range, if nearer than the occupied profile does.
    pub(crate) fn weak_echo(&self, beam: &Beam, log_odds: f32) -> WeakEcho {
        let reading = self.reading(beam);
        let half_width = self.region_weak_echo_half_width_m;
        let inv_sq_occ = match beam.echo {
            Some(range) if half_width > 0.0 => {
                let half_angle = (half_width / range).atan();
                (1.0 / (half_angle * half_angle)).max(reading.inv_sq_occ)
            }
            _ => reading.inv_sq_occ,
        };
        WeakEcho(SmoothReading {
            l_occ: log_odds,
            l_free: 0.0,
            inv_sq_occ,
            ..reading
        })
    }

    /// The occupied evidence of a closed region of constant depth seen along world bearing `axis`
    /// (its middle bearing) at `range` (its mean range), heard by `readings` readings: a straight
    /// patch square to the axis at the range, `band` thick, fading as 1 − (α/θ)² to the patch's
    /// half-angle θ = `half_angle`, as strong as the readings' occupied evidence together (each
    /// of them heard the reflector, as each reading of the per-reading placement puts its own;
    /// a negative count takes as many back); each of its cells remembers the axis as the bearing
    /// it was heard from (the reflector's normal, if it is a wall).
    pub(crate) fn region_echo(
        &self,
        axis: f32,
        range: f32,
        half_angle: f32,
        readings: f32,
    ) -> RegionEcho {
        let band = self.band(range);
        RegionEcho {
            d: range,
            band,
            inv_band: 1.0 / band,
            l_occ: self.occupied_log_odds * readings,
            inv_sq: 1.0 / (half_angle * half_angle),
            fade_range: self.fade_range_m,
            half_angle: half_angle * 1.001,
            normal: axis,
        }
    }

    /// The half-angle of the patch of a region `half_width` wide each side at `range`, radians:
    /// its own width, at most `region_half_angle_deg` and `region_half_width_m` along the wall,
    /// at least 3° (a single reading).
    pub(crate) fn region_patch_half_angle(&self, half_width: f32, range: f32) -> f32 {
        let mut widest = self.region_half_angle_deg.to_radians();
        if self.region_half_width_m > 0.0 {
            widest = widest.min((self.region_half_width_m / range).atan());
        }
        // A reading's width even where the metres would allow less (beyond 9.5 m at 0.5 m).
        half_width.min(widest).max(3f32.to_radians())
    }
}

/// A region's occupied evidence ([`SmoothModel::region_echo`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct RegionEcho {
    d: f32,
    band: f32,
    inv_band: f32,
    l_occ: f32,
    inv_sq: f32,
    fade_range: f32,
    half_angle: f32,
    normal: f32,
}

impl CellEvidence for RegionEcho {
    const HEARD: bool = true;

    fn reach(&self) -> f32 {
        (self.d + self.band) / self.half_angle.cos()
    }

    fn half_angle(&self) -> f32 {
        self.half_angle
    }

    /// Nearer than the band, r·cos α < d − band: no evidence at any angle.
    fn near(&self) -> f32 {
        self.d - self.band
    }

    fades_at_its_fade_range!();

    #[inline(always)]
    fn trusted_log_odds(&self, r: f32, alpha: f32, trust: f32) -> f32 {
        // The distance along the axis, not the range: the patch is straight, as a wall is.
        let j = (r * geometry::cos(alpha) - self.d) * self.inv_band;
        let l = self.l_occ
            * positive(1.0 - alpha * alpha * self.inv_sq)
            * positive(1.0 - j * j)
            * trust;
        if l != 0.0 { l } else { f32::NAN }
    }

    #[inline(always)]
    fn trusted_heard_log_odds(
        &self,
        r: f32,
        alpha: f32,
        _bearing: f32,
        heard: &mut f32,
        trust: f32,
    ) -> f32 {
        let l = self.trusted_log_odds(r, alpha, trust);
        *heard = if l > 0.0 { self.normal } else { *heard };
        l
    }
}

/// A reading's echo alone, weak ([`SmoothModel::weak_echo`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct WeakEcho(SmoothReading);

impl CellEvidence for WeakEcho {
    const HEARD: bool = true;

    #[inline(always)]
    fn heard_log_odds(&self, r: f32, alpha: f32, bearing: f32, heard: &mut f32) -> f32 {
        self.0.heard_log_odds(r, alpha, bearing, heard)
    }

    const FADES: bool = true;

    fn fade_range(&self) -> f32 {
        self.0.fade_range
    }

    #[inline(always)]
    fn trusted_heard_log_odds(
        &self,
        r: f32,
        alpha: f32,
        bearing: f32,
        heard: &mut f32,
        trust: f32,
    ) -> f32 {
        self.0
            .trusted_heard_log_odds(r, alpha, bearing, heard, trust)
    }

    #[inline(always)]
    fn trusted_log_odds(&self, r: f32, alpha: f32, trust: f32) -> f32 {
        self.0.trusted_log_odds(r, alpha, trust)
    }

    fn reach(&self) -> f32 {
        self.0.reach()
    }

    fn half_angle(&self) -> f32 {
        self.0.half_angle()
    }

    /// Its free evidence is zero ([`SmoothModel::weak_echo`]): nothing in front of the echo's
    /// band.
    fn near(&self) -> f32 {
        self.0.free_to
    }

    #[inline(always)]
    fn log_odds(&self, r: f32, alpha: f32) -> f32 {
        self.0.log_odds(r, alpha)
    }
}

#[derive(Debug, Clone, Copy)]
pub(crate) struct SmoothReading {
    d: f32,
    ramp_from: f32,
    free_to: f32,
    occupied_to: f32,
    inv_band: f32,
    l_occ: f32,
    l_free: f32,
    inv_sq_occ: f32,
    inv_sq_free: f32,
    fade_range: f32,
    half_angle: f32,
    incidence_none: f32,
    inv_incidence_span: f32,
}

impl SmoothReading {
    /// The evidence with free evidence weighted by `free_weight`, for a cell whose radial trust is
    /// `trust`: the model's formula, written as arithmetic and selects, without early returns, so
    /// the loop vectorises.
    #[inline(always)]
    fn weighted_log_odds(&self, r: f32, alpha: f32, free_weight: f32, trust: f32) -> f32 {
        let a2 = alpha * alpha;
        // `positive` rather than f32::max: the same values, one instruction in the loop.
        let t = positive((r - self.ramp_from) * self.inv_band);
        let j = (r - self.d) * self.inv_band;
        let free = self.l_free * positive(1.0 - a2 * self.inv_sq_free) * (1.0 - t * t);
        let occupied = self.l_occ * positive(1.0 - a2 * self.inv_sq_occ) * (1.0 - j * j);
        let l = if r < self.free_to {
            free * free_weight
        } else if r < self.occupied_to {
            occupied
        } else {
            0.0
        } * trust;
        // A zero weight (outside a profile's angle, at a band's end) is no evidence: the cell stays
        // unknown rather than "seen, undecided".
        if l != 0.0 { l } else { f32::NAN }
    }

    /// How much of a reading's free evidence a cell heard occupied from world bearing `heard`
    /// takes when this reading sees it at world bearing `bearing`: 1 up to the full incidence,
    /// none from `incidence_none`, linear between; 1 for a cell never heard (NaN).
    #[inline(always)]
    fn free_weight(&self, bearing: f32, heard: f32) -> f32 {
        // Both bearings lie in [−π, π]; the difference folded into [0, π/2]. NaN passes through
        // every fold (its comparisons are false) and gives the weight 1.
        let d = (bearing - heard).abs();
        let d = if d > PI { TAU - d } else { d };
        let incidence = if d > FRAC_PI_2 { PI - d } else { d };
        let w = (self.incidence_none - incidence) * self.inv_incidence_span;
        if w < 1.0 { positive(w) } else { 1.0 }
    }
}

impl CellEvidence for SmoothReading {
    const HEARD: bool = true;

    fn reach(&self) -> f32 {
        self.free_to.max(self.occupied_to)
    }

    fn half_angle(&self) -> f32 {
        self.half_angle
    }

    fades_at_its_fade_range!();

    #[inline(always)]
    fn trusted_log_odds(&self, r: f32, alpha: f32, trust: f32) -> f32 {
        self.weighted_log_odds(r, alpha, 1.0, trust)
    }

    #[inline(always)]
    fn trusted_heard_log_odds(
        &self,
        r: f32,
        alpha: f32,
        bearing: f32,
        heard: &mut f32,
        trust: f32,
    ) -> f32 {
        let free_weight = self.free_weight(bearing, *heard);
        let l = self.weighted_log_odds(r, alpha, free_weight, trust);
        // Occupied evidence (NaN compares false): the sensor lay near this cell's perpendicular.
        *heard = if l > 0.0 { bearing } else { *heard };
        l
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rule::{BayesRule, Combine};
    use nalgebra::Vector2;

    fn beam(echo: Option<f32>) -> Beam {
        Beam {
            position: Vector2::zeros(),
            axis: 0.0,
            half_angle: 30f32.to_radians(),
            max_range: 4.0,
            echo,
        }
    }

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() < 1e-5
    }

    #[test]
    fn paper_equations_by_hand() {
        let m = PaperModel::default().reading(&beam(Some(2.0)));
        // Region I, r = 2.0, α = 10°: s = ((4−2)/4 + (30−10)/30)/2 = (0.5 + 0.6667)/2 = 0.58333;
        // eq. 1: 0.58333 · 0.98 = 0.57167.
        assert!(close(m.probability(2.0, 10f32.to_radians()), 0.571_667));
        // Region I edge, r = 2.1 = d(1 + p), α = 0: s = (0.475 + 1)/2 = 0.7375 → 0.72275.
        assert!(close(m.probability(2.1, 0.0), 0.722_75));
        // Region II, r = 1.0, α = 0: s = (0.75 + 1)/2 = 0.875; eq. 2: 1 − 0.875 = 0.125.
        assert!(close(m.probability(1.0, 0.0), 0.125));
        // Region II, r = 1.8, α = −25°: s = (0.55 + 0.16667)/2 = 0.35833; eq. 2 gives 0.64167 — the
        // flaw: occupancy evidence in front of the echo.
        assert!(close(m.probability(1.8, -25f32.to_radians()), 0.641_667));
        // Region III.
        assert!(m.probability(2.2, 0.0).is_nan());
        assert!(close(m.log_odds(1.0, 0.0), (0.125f32 / 0.875).ln()));
    }

    /// The smooth model with round parameters the hand-computed values below were worked out
    /// with (the defaults are tuned on the simulator and may move).
    fn round_smooth() -> SmoothModel {
        SmoothModel {
            occupied_log_odds: 1.0,
            free_log_odds: -1.0,
            occupied_half_angle_deg: 12.0,
            free_half_angle_deg: 30.0,
            // Each reading's own evidence, occupied part included.
            echo_placement: EchoPlacement::Reading,
            ..SmoothModel::default()
        }
    }

    /// A weak echo and a region's echo give nothing nearer than their [`CellEvidence::near`],
    /// at any angle (the kernel leaves those cells out), and something just beyond it.
    #[test]
    fn echoes_give_no_evidence_nearer_than_their_near_range() {
        fn nothing_nearer<E: CellEvidence>(evidence: &E) {
            let near = evidence.near();
            assert!(near > 1.5 && near < 2.0, "{near}");
            for k in 0..400 {
                let r = near * k as f32 / 400.0;
                for deg in -90..=90 {
                    let l = evidence.log_odds(r, (deg as f32).to_radians());
                    assert!(l.is_nan(), "{l} at {r} m, {deg}°");
                }
            }
            assert!(!evidence.log_odds(near + 0.01, 0.0).is_nan());
        }
        let model = SmoothModel::default();
        nothing_nearer(&model.weak_echo(&beam(Some(2.0)), 0.4));
        nothing_nearer(&model.region_echo(0.0, 2.0, 10f32.to_radians(), 3.0));
    }

    /// The worked example of `docs/fusion.md`: one echo at 2 m straight ahead (R = 4 m, β = 30°),
    /// five cells, the paper's model, the smooth model with round parameters and with the
    /// recommended ones (the table in the document shows the first and the last).
    #[test]
    fn worked_example_of_the_eq2_flaw() {
        let paper = PaperModel::default().reading(&beam(Some(2.0)));
        let smooth = round_smooth().reading(&beam(Some(2.0)));
        // The recommended parameters with the echo on the reading's own axis (placed by region,
        // the occupied part waits for the region: [`SmoothModel::region_echo`]).
        let recommended = SmoothModel {
            echo_placement: EchoPlacement::Reading,
            ..SmoothModel::default()
        }
        .reading(&beam(Some(2.0)));
        let deg = |a: f32| a.to_radians();
        // (r, α) → eq. 1–2 value; smooth model's probability σ(l) (None: no evidence), with
        // l = ∓1 · (1 − (α/θ)²) · f(r) and the radial trust f(r) = 0.985071 at 1 m, 0.961538 at
        // 1.8 m, 0.947214 at 2 m; the same with the recommended −1.5 free evidence within 7°
        // and occupied evidence within 6°.
        let cells = [
            // Region II on the axis: s = (0.75 + 1)/2 = 0.875, eq. 2: 0.125.
            (1.0, 0.0, 0.125, Some(0.271_887), Some(0.185_789)),
            // Region II near the edge: s = (0.75 + 5/30)/2 = 0.458333, eq. 2: 0.541667 > 0.5.
            (1.0, 25.0, 0.541_667, Some(0.425_315), None),
            // Closer to the echo: s = (0.55 + 5/30)/2 = 0.358333, eq. 2: 0.641667.
            (1.8, 25.0, 0.641_667, Some(0.427_073), None),
            // Region I on the axis: s = 0.75, eq. 1: 0.735.
            (2.0, 0.0, 0.735, Some(0.720_554), Some(0.720_554)),
            // Region I near the edge: s = 0.333333, eq. 1: 0.326667 < 0.5, free evidence at the
            // echo; the smooth model's occupied evidence stops at 12° (6°).
            (2.0, 25.0, 0.326_667, None, None),
        ];
        for (r, a, p, q, rec) in cells {
            let got = paper.probability(r, deg(a));
            assert!((got - p).abs() < 1e-5, "paper r {r} α {a}: {got}");
            for (model, want) in [(&smooth, q), (&recommended, rec)] {
                let got = model.probability(r, deg(a));
                match want {
                    Some(q) => assert!((got - q).abs() < 1e-5, "smooth r {r} α {a}: {got}"),
                    None => assert!(got.is_nan(), "smooth r {r} α {a}: {got}"),
                }
            }
        }
        // The next reading of the sweep, at 6° with its echo also at 2 m, sees the cell
        // (1.8 m, 25°) at α = 19°: s = (0.55 + 11/30)/2 = 0.458333, eq. 2: 0.541667, occupied
        // again; eq. 6 fuses the two into 0.641667·0.541667 / (… + 0.358333·0.458333) = 0.679104.
        let next = paper.probability(1.8, deg(19.0));
        assert!((next - 0.541_667).abs() < 1e-5);
        let mut cell = BayesRule::UNKNOWN;
        BayesRule.fuse(&mut cell, paper.probability(1.8, deg(25.0)));
        BayesRule.fuse(&mut cell, next);
        assert!((cell - 0.679_104).abs() < 1e-5, "{cell}");
        // The boundary of the flaw at r = 1.8: |α| = 7.5·(4 − 1.8) = 16.5° gives exactly 0.5.
        assert!((paper.probability(1.8, deg(16.5)) - 0.5).abs() < 1e-5);
        assert!(paper.probability(1.8, deg(16.0)) < 0.5);
        assert!(paper.probability(1.8, deg(17.0)) > 0.5);
        // β read as the full width (60°) moves the boundary to |α| = 15·(4 − r): beyond the beam
        // (30°) for every r ≤ 2 m, so this echo's region II has no such cell.
        let full = PaperModel {
            beam_width: BeamWidth::FullWidth,
            ..Default::default()
        }
        .reading(&beam(Some(2.0)));
        for i in 0..190 {
            let r = i as f32 * 0.01;
            assert!(full.probability(r, deg(30.0)) <= 0.5, "r {r}");
        }
        // ... but an echo at 3.5 m has it again: r = 3.0, α = 20° > 15°.
        let far = PaperModel {
            beam_width: BeamWidth::FullWidth,
            ..Default::default()
        }
        .reading(&beam(Some(3.5)));
        assert!(far.probability(3.0, deg(20.0)) > 0.5);
    }

    #[test]
    fn paper_conventions_change_the_angular_term() {
        let full = PaperModel {
            beam_width: BeamWidth::FullWidth,
            ..Default::default()
        }
        .reading(&beam(Some(2.0)));
        // β = 60°: s = (0.5 + (60 − 10)/60)/2 = 0.66667 → 0.65333.
        assert!(close(full.probability(2.0, 10f32.to_radians()), 0.653_333));
        let signed = PaperModel {
            alpha: AlphaSign::Signed,
            ..Default::default()
        }
        .reading(&beam(Some(2.0)));
        // α = −10°: s = (0.5 + 40/30)/2 = 0.91667 → 0.89833; +10° as before.
        assert!(close(
            signed.probability(2.0, -10f32.to_radians()),
            0.898_333
        ));
        assert!(close(
            signed.probability(2.0, 10f32.to_radians()),
            0.571_667
        ));
        // The literal form leaves [0, 1]; clamped. α = −30° on the sensor: 1 − (1 + 2)/2 < 0.
        assert_eq!(signed.probability(0.0, -30f32.to_radians()), 0.0);
    }

    #[test]
    fn paper_model_clearing_has_no_region_one() {
        let m = PaperModel::default().reading(&beam(None));
        assert!(close(
            m.probability(3.9, 0.0),
            1.0 - (0.1 / 4.0 + 1.0) / 2.0
        ));
        assert!(m.probability(4.01, 0.0).is_nan());
        assert_eq!(m.reach(), 4.0);
    }

    #[test]
    fn book_model_regions() {
        let m = LogOddsModel::default().reading(&beam(Some(2.0)));
        assert!(close(m.log_odds(1.0, 0.4), logit(0.3)));
        assert!(close(m.log_odds(2.02, 0.0), logit(0.7)));
        assert!(close(m.probability(1.98, -0.4), 0.7));
        assert!(m.log_odds(2.03, 0.0).is_nan());
        // Clipped at the maximum range and cleared up to it without an echo.
        let far = LogOddsModel::default().reading(&beam(Some(3.99)));
        assert!(far.log_odds(4.001, 0.0).is_nan());
        let clear = LogOddsModel::default().reading(&beam(None));
        assert!(close(clear.log_odds(3.99, 0.0), logit(0.3)));
    }

    #[test]
    fn smooth_model_never_raises_occupancy_in_front_nor_lowers_it_at_the_range() {
        let m = SmoothModel {
            fade_range_m: 100.0,
            ..round_smooth()
        }
        .reading(&beam(Some(2.0)));
        for i in 0..400 {
            let r = i as f32 * 0.01;
            for a in [-29.0f32, -12.0, -5.0, 0.0, 3.0, 11.9, 25.0] {
                let l = m.log_odds(r, a.to_radians());
                if r < 2.0 - 0.025 {
                    assert!(l.is_nan() || l < 0.0, "r {r} α {a}: {l}");
                } else if !l.is_nan() {
                    assert!(l > 0.0, "r {r} α {a}: {l}");
                }
            }
        }
        // On the axis: full free evidence well in front, full occupied evidence at the range
        // (the far trust is ≈ 1 with the fade pushed away).
        assert!(close(m.log_odds(1.0, 0.0), -1.0));
        assert!(close(m.log_odds(2.0, 0.0), 1.0));
        // Half-way along the ramp: 1 − 0.5² of the free evidence.
        assert!(close(m.log_odds(2.0 - 0.0375, 0.0), -0.75));
        // Occupied evidence stops at its own angle, free evidence at the beam's.
        assert!(m.log_odds(2.0, 12.5f32.to_radians()).is_nan());
        assert!(m.log_odds(1.0, 20f32.to_radians()) < 0.0);
        assert!(m.log_odds(2.03, 0.0).is_nan());
    }

    #[test]
    fn smooth_model_gives_no_evidence_beyond_its_half_angle() {
        for (occ, free) in [
            (4.0, 14.0),
            (12.0, 30.0),
            (30.0, 5.0),
            (0.5, 89.0),
            (17.3, 17.3),
        ] {
            let model = SmoothModel {
                occupied_half_angle_deg: occ,
                free_half_angle_deg: free,
                ..Default::default()
            };
            let limit = model.half_angle();
            assert!(limit > f32::max(occ, free).to_radians());
            for echo in [Some(0.3), Some(2.0), Some(3.9), None] {
                let m = model.reading(&beam(echo));
                assert_eq!(m.half_angle(), limit);
                for i in 0..=420 {
                    let r = i as f32 * 0.01;
                    for a in [limit, limit * 1.000_001, limit + 0.01, 3.1] {
                        assert!(
                            m.log_odds(r, a).is_nan(),
                            "{occ} {free} {echo:?} r {r} α {a}"
                        );
                        assert!(m.log_odds(r, -a).is_nan());
                    }
                }
            }
        }
    }

    #[test]
    fn smooth_model_fades_with_range() {
        let m = round_smooth().reading(&beam(Some(3.5)));
        // At the fade range the trust is one half.
        assert!(close(m.log_odds(3.0, 0.0), -0.5));
        assert!(m.log_odds(1.0, 0.0) < -0.98);
    }

    #[test]
    fn model_names_parse_and_list_the_valid_ones() {
        for kind in ModelKind::ALL {
            assert_eq!(kind.name().parse::<ModelKind>(), Ok(kind));
            assert_eq!(ModelKind::from_code(kind.code()), Some(kind));
            assert_eq!(ModelConfig::default_for(kind).kind(), kind);
        }
        let err = "ros".parse::<ModelKind>().unwrap_err();
        assert_eq!(
            err.to_string(),
            "unknown sensor model \"ros\"; valid names: paper, log-odds, smooth"
        );
    }
}
