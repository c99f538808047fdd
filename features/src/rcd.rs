//! Regions of constant depth (Leonard & Durrant-Whyte): runs of neighbouring pings that heard the
//! same range.
//!
//! A sonar reports the range of the first echo above its threshold. While the head turns across a
//! reflector, every ping whose axis lies inside the reflector's effective cone hears it, and hears
//! it at the **same** range: the wall's perpendicular distance, the corner's vertex, the post's
//! nearest point, whatever the angle of the ping. A target therefore shows as a run of pings of
//! constant depth, as wide as its cone, centred on its bearing; the ping just beyond each end of
//! the run says why the run ended ([`End`]).
//!
//! The extraction, over the pings of one sweep sorted by bearing:
//!
//! 1. **Runs**: grow a run while the next ping lies within the [`Gate`] of the run's mean: a few σ
//!    of the sensor's range noise, estimated online from the pings themselves
//!    ([`crate::noise`]). Up to three pings that heard **nothing** (dropouts), one of
//!    which may have heard **nearer** than the run (a transient: the SRF05's spurious echoes end a
//!    ping early, by any amount), are bridged when the ping after them continues the run, and
//!    counted as outliers. A ping that hears **farther** is not bridged here: the beam went past
//!    the target there, which is evidence of a gap (two posts with a way between them). Runs are then
//!    split at significant steps in range (targets nearer in range than the gate), touching runs
//!    at one range joined again, and the pings at their boundaries settled.
//! 2. **Ends**: [`End::Natural`] when the next ping heard farther or nothing (the target left the
//!    cone there), [`End::Occluded`] when it heard nearer (a nearer target may hide the rest of this
//!    one), [`End::Unknown`] at the end of the scan, at lost readings, at an ambiguous neighbour,
//!    or where the run's range comes back past a burst of lost pings. A lone nearer ping followed
//!    by farther or nothing is a transient: the end is natural.
//!    Beyond each end the next pings are also looked at for a **slope** ([`Slope`]): a range
//!    that climbs on smoothly from the region's is a rough wall going on at a slant (it
//!    scatters from wherever the beam's edge meets it), so a region with climbs on both sides
//!    is a rough wall's foot, and one between a climb and a nearer echo is a piece of the climb.
//! 3. **Joining**: two runs at the same range, separated only by pings that heard nearer, are one
//!    target partly hidden (the wall behind a post): they are joined, the hidden pings counted —
//!    unless together they would be wider than any one target's region at that range (the four
//!    corners of a square room, all at one range between the nearer walls, stay four). With
//!    amplitude jitter, runs at one range separated by one or two pings that heard farther or
//!    nothing where the jitter can lose a faint post's echo are one run too (`join_missed`).
//! 4. Runs of fewer than `min_pings` pings are dropped; the rest become [`Rcd`]s, their range the
//!    mean of their pings less the sensor's calibrated offset (`range_offset_m`).

use crate::config::FeatureConfig;
use crate::noise::NoiseModel;
use crate::pings::{Ping, Sweep};

/// Why a region of constant depth ends where it does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum End {
    /// The next ping heard something farther, or nothing: the target left its cone there, so the
    /// end marks the edge of its effective cone.
    Natural,
    /// The next ping heard something nearer, which may hide the rest of this target.
    Occluded,
    /// The scan ended, readings were lost, or the neighbour's range was too close to tell.
    Unknown,
}

impl End {
    /// Whether the end marks the edge of the target's cone.
    pub fn is_natural(self) -> bool {
        self == End::Natural
    }
}

/// A region of constant depth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rcd {
    /// Range of the target: the mean of the pings less the sensor's calibrated offset, metres.
    pub range_m: f64,
    /// Standard error of that mean from the pings' jitter (independent from sweep to sweep).
    pub range_sigma_m: f64,
    /// Bearing of the first (lowest-angle) ping of the run, degrees.
    pub first_deg: f64,
    /// Bearing of the last ping of the run.
    pub last_deg: f64,
    /// Step between pings, degrees.
    pub step_deg: f64,
    /// Pings that heard the target.
    pub pings: u32,
    /// Pings bridged inside the run (transients, dropouts).
    pub outliers: u32,
    /// Pings inside the run that heard a nearer target (joined runs).
    pub hidden: u32,
    /// End at the lower bearing.
    pub start: End,
    /// End at the higher bearing.
    pub end: End,
    /// Span of bearings in which the cone's edge at the start lies: one step (between the first
    /// ping that heard the target and the one before), two when the one before was a transient,
    /// which may have heard it too.
    pub start_interval_deg: f64,
    /// The same at the end.
    pub end_interval_deg: f64,
    /// Mean bearing of every ping of the sweep at the run's range within the widest cone a
    /// reference point target could be heard over about the run's middle
    /// ([`heard_centre_deg`]); the middle between the edges ([`Rcd::centre_deg`]) when the
    /// threshold does not jitter.
    pub heard_centre_deg: f64,
    /// Beyond each end (start, end), the pings' ranges rise on smoothly from the region's: the
    /// same surface going on at a slant, heard where it is nearest in the beam. A smooth wall
    /// answers only near square on, so past its region the pings hear something else or nothing;
    /// a rough one (brick, a full bookshelf) scatters from wherever the beam meets it, so past
    /// the region of its foot the range climbs as the beam's edge slides along it ([`slope`]).
    /// Climbing on both sides: a rough wall's foot; climbing on one and falling on the other:
    /// a piece of a rough wall's climb, no target of its own.
    pub sloping: [Option<Slope>; 2],
}

impl Rcd {
    /// The foot of a rough wall: the range climbs on beyond both ends ([`Rcd::sloping`]), so the
    /// region is where the wall's nearest point lies inside the beam, centred on its normal
    /// whatever its width.
    pub fn is_sloping_foot(&self) -> bool {
        self.sloping == [Some(Slope::Climbing); 2]
    }

    /// A piece of a rough wall's climb: the range climbs on beyond one end and falls away, or
    /// was cut short by a nearer echo, beyond the other ([`Rcd::sloping`]), so its pings heard
    /// the wall where the beam's edge met it, no target at their own range.
    pub fn is_on_a_slope(&self) -> bool {
        // Falling beyond an end, or cut short there by a nearer echo (the climb's lower part,
        // split from it within the noise).
        let lower =
            |slope: Option<Slope>, end: End| slope == Some(Slope::Falling) || end == End::Occluded;
        match self.sloping {
            [Some(Slope::Climbing), other] => lower(other, self.end),
            [other, Some(Slope::Climbing)] => lower(other, self.start),
            _ => false,
        }
    }

    /// Both ends natural: the target left its cone on each side, so the width was measured,
    /// not bounded.
    pub fn is_whole(&self) -> bool {
        self.start.is_natural() && self.end.is_natural()
    }

    /// Estimated edge of the cone at the lower bearing: the middle of its interval.
    pub fn start_edge_deg(&self) -> f64 {
        self.first_deg - self.start_interval_deg / 2.0
    }

    /// Estimated edge of the cone at the higher bearing.
    pub fn end_edge_deg(&self) -> f64 {
        self.last_deg + self.end_interval_deg / 2.0
    }

    /// σ of the edge estimates: uniform over their intervals.
    pub fn start_edge_sigma_deg(&self) -> f64 {
        self.start_interval_deg / 12f64.sqrt()
    }

    pub fn end_edge_sigma_deg(&self) -> f64 {
        self.end_interval_deg / 12f64.sqrt()
    }

    /// Angular width: from edge to edge, the best estimate of the cone's full width.
    pub fn width_deg(&self) -> f64 {
        self.end_edge_deg() - self.start_edge_deg()
    }

    /// Middle between the edges: the target's bearing when both ends are natural.
    pub fn centre_deg(&self) -> f64 {
        (self.start_edge_deg() + self.end_edge_deg()) / 2.0
    }

    /// How far the measured width may lie from a modelled one: half of each edge's interval, and
    /// each modelled cone edge's σ (`cone_sigma_deg`) twice.
    pub fn width_tolerance_deg(&self, cone_sigma_deg: f64) -> f64 {
        (self.start_interval_deg + self.end_interval_deg) / 2.0 + 2.0 * cone_sigma_deg
    }
}

/// Running statistics of a run's ranges.
#[derive(Debug, Clone, Copy)]
struct Stats {
    n: u32,
    sum: f64,
    sum_sq: f64,
    lo: f64,
    hi: f64,
}

impl Stats {
    fn new(r: f64) -> Self {
        Self {
            n: 1,
            sum: r,
            sum_sq: r * r,
            lo: r,
            hi: r,
        }
    }

    fn add(&mut self, r: f64) {
        self.n += 1;
        self.sum += r;
        self.sum_sq += r * r;
        self.lo = self.lo.min(r);
        self.hi = self.hi.max(r);
    }

    fn merge(&mut self, o: &Stats) {
        self.n += o.n;
        self.sum += o.sum;
        self.sum_sq += o.sum_sq;
        self.lo = self.lo.min(o.lo);
        self.hi = self.hi.max(o.hi);
    }

    fn mean(&self) -> f64 {
        self.sum / f64::from(self.n)
    }

    fn sample_sd(&self) -> f64 {
        if self.n < 2 {
            return 0.0;
        }
        let n = f64::from(self.n);
        ((self.sum_sq - self.sum * self.sum / n) / (n - 1.0))
            .max(0.0)
            .sqrt()
    }
}

/// Whether a ping heard the same target as a run: within [`crate::NoiseConfig::gate_sigmas`] σ of
/// the noise estimated for the sensor ([`NoiseModel`]) around the run's mean.
#[derive(Debug, Clone, Copy)]
pub struct Gate {
    noise: NoiseModel,
    sigmas: f64,
}

impl Gate {
    pub fn new(noise: NoiseModel, cfg: &FeatureConfig) -> Self {
        Self {
            noise,
            sigmas: cfg.noise.gate_sigmas,
        }
    }

    /// The noise it was made with.
    pub fn noise(&self) -> &NoiseModel {
        &self.noise
    }

    /// How far one ping's range may lie from a target's at `range_m` and still be the target's.
    pub fn tolerance_at(&self, range_m: f64) -> f64 {
        self.sigmas * self.noise.sigma_at(range_m)
    }

    /// Half-width of the interval around a run's mean in which a further ping of its target falls
    /// (the prediction interval: the ping's noise and the mean's).
    fn reach(&self, s: &Stats) -> f64 {
        self.tolerance_at(s.mean()) * (1.0 + 1.0 / f64::from(s.n)).sqrt()
    }

    /// Within the reach, and the run's spread with it no wider than the noise makes one target's
    /// (so a range that creeps, ping by ping, does not make one long run).
    fn fits(&self, s: &Stats, r: f64) -> bool {
        (r - s.mean()).abs() <= self.reach(s)
            && s.hi.max(r) - s.lo.min(r) <= 2.0 * self.tolerance_at(s.mean())
    }

    /// Neither farther nor nearer: a ping of the run's target.
    fn at_range(&self, s: &Stats, r: f64) -> bool {
        (r - s.mean()).abs() <= self.reach(s)
    }

    fn farther(&self, s: &Stats, r: f64) -> bool {
        r > s.mean() + self.reach(s)
    }

    fn nearer(&self, s: &Stats, r: f64) -> bool {
        r < s.mean() - self.reach(s)
    }

    /// Two runs at one range: their means within the noise of the two means.
    fn same_range(&self, a: &Stats, b: &Stats) -> bool {
        let n = 1.0 / f64::from(a.n) + 1.0 / f64::from(b.n);
        (a.mean() - b.mean()).abs() <= self.tolerance_at(a.mean()) * n.sqrt()
    }
}

/// A run of pings: indices of its first and last ping, its ranges and ends.
#[derive(Debug, Clone, Copy)]
struct Run {
    first: usize,
    last: usize,
    stats: Stats,
    outliers: u32,
    hidden: u32,
    start: End,
    end: End,
    /// Edge intervals in steps (see [`Rcd::start_interval_deg`]).
    start_steps: f64,
    end_steps: f64,
    /// Mean range of the part this run was split from beyond each end, and the span (steps) in
    /// which the step between them lies ([`split_steps`]).
    start_neighbour: Option<(f64, f64)>,
    end_neighbour: Option<(f64, f64)>,
}

/// The regions of constant depth of one sweep, in order of bearing, their pings grouped by
/// `gate` (the sensor's noise).
pub fn extract(sweep: &Sweep, cfg: &FeatureConfig, gate: &Gate) -> Vec<Rcd> {
    let runs = split_steps(sweep, find_runs(sweep, gate), cfg, gate);
    let mut runs = join_touching(sweep, runs, cfg, gate);
    settle_boundaries(sweep, &mut runs, cfg, gate);
    for run in &mut runs {
        (run.start, run.start_steps) = end_kind(sweep, run, gate, Side::Start);
        (run.end, run.end_steps) = end_kind(sweep, run, gate, Side::End);
    }
    let runs = join_hidden(sweep, runs, cfg, gate);
    let runs = join_missed(sweep, runs, cfg, gate);
    let pings = sweep.pings();
    let runs: Vec<Run> = runs
        .into_iter()
        .filter(|r| r.stats.n >= cfg.min_pings)
        .collect();
    runs.iter()
        .map(|&r| {
            let mut rcd = Rcd {
                range_m: r.stats.mean() - cfg.range_offset_m,
                // The sensor's noise is a floor: a few pings can agree by chance; a wider sample
                // spread (a transient absorbed into the run) is kept.
                range_sigma_m: r.stats.sample_sd().max(gate.noise.sigma_at(r.stats.mean()))
                    / f64::from(r.stats.n).sqrt(),
                first_deg: pings[r.first].bearing_deg,
                last_deg: pings[r.last].bearing_deg,
                step_deg: sweep.step_deg(),
                pings: r.stats.n,
                outliers: r.outliers,
                hidden: r.hidden,
                start: r.start,
                end: r.end,
                start_interval_deg: r.start_steps * sweep.step_deg(),
                end_interval_deg: r.end_steps * sweep.step_deg(),
                heard_centre_deg: 0.0,
                sloping: [Side::Start, Side::End].map(|side| slope(sweep, &r, gate, side)),
            };
            rcd.heard_centre_deg = if cfg.echo.threshold_jitter_db > 0.0 {
                let own = own_span(sweep, &runs, &r, cfg, gate);
                heard_centre_deg(sweep, &r.stats, rcd.centre_deg(), own, cfg, gate)
            } else {
                rcd.centre_deg()
            };
            rcd
        })
        .collect()
}

/// The pings (indices) between the regions of `runs` beside `run` that are other targets at its
/// range: regions at the same range whose union with it no point target's cone could span
/// (wider than the reference point heard through the lowest threshold), or with a ping between
/// the two that missed it inside the cone it keeps whatever the jitter (a way between two
/// targets, as [`join_missed`] tells them). A piece of the same target's cone split off by
/// missed pings is neither, and is looked into.
fn own_span(
    sweep: &Sweep,
    runs: &[Run],
    run: &Run,
    cfg: &FeatureConfig,
    gate: &Gate,
) -> std::ops::Range<usize> {
    let pings = sweep.pings();
    let range = run.stats.mean();
    let widest = 2.0 * point_widest_deg(cfg, range) + cfg.width_tolerance_deg(sweep.step_deg());
    let kept = point_kept_deg(cfg, range);
    let another_target = |o: &Run| {
        let (a, b) = (run.first.min(o.first), run.last.max(o.last));
        let span = pings[b].bearing_deg - pings[a].bearing_deg + sweep.step_deg();
        let middle = (pings[a].bearing_deg + pings[b].bearing_deg) / 2.0;
        let gap = if o.first > run.last {
            run.last + 1..o.first
        } else {
            o.last + 1..run.first
        };
        span > widest || !outside_kept(pings, gap, middle, kept)
    };
    let others = runs
        .iter()
        .filter(|o| o.first != run.first && gate.same_range(&o.stats, &run.stats))
        .filter(|o| another_target(o));
    let after = others
        .clone()
        .map(|o| o.last)
        .filter(|&l| l < run.first)
        .max();
    let before = others.map(|o| o.first).filter(|&f| f > run.last).min();
    after.map_or(0, |l| l + 1)..before.unwrap_or(pings.len())
}

/// Every ping of `gap` lies farther than `kept` degrees from `middle`: outside the cone a
/// point target there keeps whatever the jitter, where a miss may be the jitter's.
fn outside_kept(pings: &[Ping], gap: std::ops::Range<usize>, middle: f64, kept: f64) -> bool {
    gap.into_iter()
        .all(|k| (pings[k].bearing_deg - middle).abs() > kept)
}

/// Half-angle of the widest cone the reference point target is heard over at `range_m`: the
/// threshold at the low end of its jitter (the classifier's widest point cone too).
pub(crate) fn point_widest_deg(cfg: &FeatureConfig, range_m: f64) -> f64 {
    cfg.echo.cone_with_threshold_moved_deg(
        cfg.echo.reference_point(),
        range_m,
        f64::from(cfg.sensor.beam_half_angle_deg),
        -cfg.echo.threshold_jitter_db,
    )
}

/// Half-angle of the cone the reference point target is heard over whatever the jitter: the
/// threshold at the top of it.
fn point_kept_deg(cfg: &FeatureConfig, range_m: f64) -> f64 {
    cfg.echo.cone_with_threshold_moved_deg(
        cfg.echo.reference_point(),
        range_m,
        f64::from(cfg.sensor.beam_half_angle_deg),
        cfg.echo.threshold_jitter_db,
    )
}

/// The bearing of a point target from every ping of `sweep` that heard its range (`stats`)
/// within the widest cone the reference point is heard over at that range (the threshold at
/// the low end of its jitter, one step to spare) about `about_deg`, looked at twice, the second
/// time about the first mean. With the threshold jittering a faint target is heard by each ping
/// on its cone's flanks only by chance (the `srf05` profile's post at 1 m, about 1 dB over its
/// threshold, by a ping at 6° from its axis about half the time), so a region's two outermost
/// pings, and the region itself, end wherever a ping first missed: its middle wandered by 2° from
/// sweep to sweep, and a flank ping beyond a miss was left out of the region (bridged as a
/// transient of the wall behind, or a region of its own). The mean of every ping the target
/// answered weighs each by its chance of being heard, which falls off symmetrically about the
/// axis: 1.3° from sweep to sweep there. Only the pings in `between` (indices), the span up to
/// the regions of other targets at that range.
fn heard_centre_deg(
    sweep: &Sweep,
    stats: &Stats,
    about_deg: f64,
    between: std::ops::Range<usize>,
    cfg: &FeatureConfig,
    gate: &Gate,
) -> f64 {
    let half = point_widest_deg(cfg, stats.mean()) + sweep.step_deg();
    let mean_about = |centre: f64| {
        let (sum, n) = sweep.pings()[between.clone()]
            .iter()
            .filter(|p| p.range_m.is_some_and(|r| gate.at_range(stats, r)))
            .map(|p| crate::geometry::wrap_deg(p.bearing_deg - centre))
            .filter(|off| off.abs() <= half)
            .fold((0.0, 0u32), |(sum, n), off| (sum + off, n + 1));
        (n > 0).then(|| centre + sum / f64::from(n))
    };
    let first = mean_about(about_deg).unwrap_or(about_deg);
    mean_about(first).unwrap_or(first)
}

/// Most consecutive pings bridged inside one run: a sensor that loses a share p of its pings
/// loses two in a row p² of the time, often enough to break a wall's region in a few sweeps at
/// 2 %, and a transient beside a lost ping as often; three (p³) almost never. A gap between two
/// targets with nothing behind them is wider: each target's cone is 10° or more.
const MAX_BRIDGED: usize = 3;

/// How far past a run's end a burst of lost pings is looked through for the run's range again.
const RESUME_LOOKAHEAD: usize = 6;

/// Maximal runs of constant depth, single transients and short dropouts bridged.
fn find_runs(sweep: &Sweep, gate: &Gate) -> Vec<Run> {
    let pings = sweep.pings();
    let mut runs = Vec::new();
    let mut i = 0;
    while i < pings.len() {
        let Some(r0) = pings[i].range_m else {
            i += 1;
            continue;
        };
        let mut stats = Stats::new(r0);
        let (mut last, mut outliers) = (i, 0);
        let mut j = i + 1;
        while j < pings.len() && !sweep.gap_before(j) {
            match pings[j].range_m {
                Some(r) if gate.fits(&stats, r) => {
                    stats.add(r);
                    last = j;
                    j += 1;
                }
                other => {
                    // Up to MAX_BRIDGED pings that heard nothing, one of which may have heard
                    // nearer than the run (a transient ends a ping early by any amount); never
                    // farther.
                    let mut nearer = 0;
                    let skip = if other.is_some_and(|r| gate.farther(&stats, r)) {
                        0
                    } else {
                        (j..pings.len())
                            .take(MAX_BRIDGED)
                            .take_while(|&k| {
                                let ok = match pings[k].range_m {
                                    None => true,
                                    Some(r) if gate.nearer(&stats, r) && nearer == 0 => {
                                        nearer += 1;
                                        true
                                    }
                                    Some(_) => false,
                                };
                                ok && (k == j || !sweep.gap_before(k))
                            })
                            .count()
                    };
                    let next = j + skip;
                    let resumes = skip > 0
                        && next < pings.len()
                        && !sweep.gap_before(next)
                        && pings[next].range_m.is_some_and(|r| gate.fits(&stats, r));
                    if resumes {
                        outliers += skip as u32;
                        j = next;
                    } else {
                        break;
                    }
                }
            }
        }
        runs.push(Run {
            first: i,
            last,
            stats,
            outliers,
            hidden: 0,
            start: End::Unknown,
            end: End::Unknown,
            start_steps: 1.0,
            end_steps: 1.0,
            start_neighbour: None,
            end_neighbour: None,
        });
        i = last + 1;
    }
    runs
}

/// A step in range this many σ of the difference of the two sides' means splits a run: pure
/// noise reaches it by chance about once in 10⁵ runs.
const STEP_SIGMAS: f64 = 5.0;
/// In a run wider than any one target can be at its range, which must hold several, its largest
/// step splits it from this many σ.
const WIDE_STEP_SIGMAS: f64 = 2.5;

/// Splits runs that hold targets at nearby ranges: targets closer in range than the noise's
/// gate run into one another (a wall and the corner beside it, at 1.80 and 1.71 m under 3 cm of
/// noise), but the means of their pings differ by many times their standard errors. Each run is
/// split at its most significant step in range while that step is significant; both parts keep
/// at least `min_pings` pings.
fn split_steps(sweep: &Sweep, runs: Vec<Run>, cfg: &FeatureConfig, gate: &Gate) -> Vec<Run> {
    let pings = sweep.pings();
    let beam = f64::from(cfg.sensor.beam_half_angle_deg);
    let min = cfg.min_pings.max(2) as usize;
    let mut out = Vec::with_capacity(runs.len());
    let mut todo: Vec<Run> = runs.into_iter().rev().collect();
    while let Some(run) = todo.pop() {
        // The run's own pings: those with a range that is not a bridged transient.
        let own: Vec<(usize, f64)> = (run.first..=run.last)
            .filter_map(|k| pings[k].range_m.map(|r| (k, r)))
            .filter(|&(_, r)| !gate.nearer(&run.stats, r))
            .collect();
        let width = pings[run.last].bearing_deg - pings[run.first].bearing_deg + sweep.step_deg();
        let too_wide = width
            > cfg.echo.widest_region_deg(run.stats.mean(), beam)
                + cfg.width_tolerance_deg(sweep.step_deg());
        let threshold = if too_wide {
            WIDE_STEP_SIGMAS
        } else {
            STEP_SIGMAS
        };
        let sigma = gate.noise().sigma_at(run.stats.mean());
        let total: f64 = own.iter().map(|p| p.1).sum();
        let n = own.len();
        // t[nl]: the step between the first nl pings and the rest, in σ of its estimate.
        let mut left = 0.0;
        let mut t = vec![0.0; n];
        for (k, &(_, r)) in own.iter().enumerate().take(n.saturating_sub(min)) {
            left += r;
            let nl = k + 1;
            if nl < min {
                continue;
            }
            let nr = n - nl;
            let diff = left / nl as f64 - (total - left) / nr as f64;
            t[nl] = diff.abs() / (sigma * (1.0 / nl as f64 + 1.0 / nr as f64).sqrt());
        }
        let Some((nl, best)) = t
            .iter()
            .copied()
            .enumerate()
            .filter(|&(_, t)| t > threshold)
            .max_by(|a, b| a.1.total_cmp(&b.1))
        else {
            out.push(run);
            continue;
        };
        // Where the step lies is known to the split points whose likelihood is within e² of
        // the best (t² within 4, ≈ 95 %): the pings within `m` of it may belong to either part
        // and are left out of both; the edges lie somewhere among them.
        let near = |k: usize| t[k] * t[k] >= best * best - 4.0;
        let below = (1..=nl).rev().take_while(|&k| near(k)).count() - 1;
        let above = (nl..n).take_while(|&k| near(k)).count() - 1;
        let m = below.max(above).min(nl - min).min(n - nl - min);
        let steps = (2 * m + 1) as f64;
        let part = |from: usize, to: usize| {
            let mut stats = Stats::new(own[from].1);
            for p in &own[from + 1..to] {
                stats.add(p.1);
            }
            let (first, last) = (own[from].0, own[to - 1].0);
            let bridged = (first..=last).count() as u32 - stats.n;
            Run {
                first,
                last,
                stats,
                outliers: bridged,
                ..run
            }
        };
        let (mut lower, mut upper) = (part(0, nl - m), part(nl + m, n));
        lower.end_neighbour = Some((upper.stats.mean(), steps));
        upper.start_neighbour = Some((lower.stats.mean(), steps));
        // The upper part first, so the lower one is looked at next.
        todo.push(upper);
        todo.push(lower);
    }
    out
}

/// Joins runs that touch (nothing but lost pings between them) at one range: a piece a step
/// split off the neighbouring run and this one, or a run that a transient ended early, are one
/// target again.
fn join_touching(sweep: &Sweep, runs: Vec<Run>, cfg: &FeatureConfig, gate: &Gate) -> Vec<Run> {
    let pings = sweep.pings();
    let beam = f64::from(cfg.sensor.beam_half_angle_deg);
    let mut out: Vec<Run> = Vec::with_capacity(runs.len());
    for run in runs {
        if let Some(prev) = out.last_mut() {
            let between = prev.last + 1..run.first;
            let touching = between.len() <= MAX_BRIDGED
                && between.clone().all(|k| pings[k].range_m.is_none())
                && (prev.last + 1..=run.first).all(|k| !sweep.gap_before(k));
            // Not where a step split them, nor wider than one target can be.
            let width =
                pings[run.last].bearing_deg - pings[prev.first].bearing_deg + sweep.step_deg();
            let one_target = width
                <= cfg.echo.widest_region_deg(prev.stats.mean(), beam)
                    + cfg.width_tolerance_deg(sweep.step_deg());
            if touching
                && prev.end_neighbour.is_none()
                && one_target
                && gate.same_range(&prev.stats, &run.stats)
            {
                prev.stats.merge(&run.stats);
                prev.outliers += run.outliers + between.len() as u32;
                prev.last = run.last;
                prev.end_neighbour = run.end_neighbour;
                continue;
            }
        }
        out.push(run);
    }
    out
}

/// The statistics of the pings with a range in `first..=last`, but those nearer than
/// `reference` (bridged transients).
fn stats_of(sweep: &Sweep, first: usize, last: usize, reference: &Stats, gate: &Gate) -> Stats {
    let mut ranges = sweep.pings()[first..=last]
        .iter()
        .filter_map(|p| p.range_m)
        .filter(|&r| !gate.nearer(reference, r));
    let mut stats = Stats::new(ranges.next().unwrap_or(reference.mean()));
    for r in ranges {
        stats.add(r);
    }
    stats
}

/// Between two runs that touch (no ping between them), moves each ping at the boundary to the
/// run whose mean it lies nearer: a run grown ping by ping takes in the first pings of a
/// neighbour at a range within its gate (a corner 10 cm behind its wall under 2 cm of noise),
/// which shifts its edge and its range.
fn settle_boundaries(sweep: &Sweep, runs: &mut [Run], cfg: &FeatureConfig, gate: &Gate) {
    let pings = sweep.pings();
    let min = cfg.min_pings.max(2);
    for k in 1..runs.len() {
        let (mut a, mut b) = (runs[k - 1], runs[k]);
        if b.first != a.last + 1 || a.stats.n < min || b.stats.n < min {
            continue;
        }
        let reference = (a.stats, b.stats);
        let nearer_to_other = |r: Option<f64>, own: &Stats, other: &Stats| {
            r.is_some_and(|r| (r - other.mean()).abs() < (r - own.mean()).abs())
        };
        // Each ping moves at most once, towards the run it fits better; the runs keep their
        // smallest size.
        for _ in 0..(a.stats.n + b.stats.n) {
            if a.stats.n > min && nearer_to_other(pings[a.last].range_m, &a.stats, &b.stats) {
                b.first = a.last;
                a.last -= 1;
                while a.last > a.first && pings[a.last].range_m.is_none() {
                    a.last -= 1;
                }
            } else if b.stats.n > min && nearer_to_other(pings[b.first].range_m, &b.stats, &a.stats)
            {
                a.last = b.first;
                b.first += 1;
                while b.first < b.last && pings[b.first].range_m.is_none() {
                    b.first += 1;
                }
            } else {
                break;
            }
            a.stats = stats_of(sweep, a.first, a.last, &reference.0, gate);
            b.stats = stats_of(sweep, b.first, b.last, &reference.1, gate);
        }
        for run in [&mut a, &mut b] {
            run.outliers = (run.first..=run.last).count() as u32 - run.stats.n;
        }
        if let (Some((_, steps)), Some(_)) = (a.end_neighbour, b.start_neighbour) {
            a.end_neighbour = Some((b.stats.mean(), steps));
            b.start_neighbour = Some((a.stats.mean(), steps));
        }
        runs[k - 1] = a;
        runs[k] = b;
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Side {
    Start,
    End,
}

/// Pings beyond a region's end looked at for a slope ([`slope`]), and the fewest that must
/// have an echo, one after the other.
const SLOPE_PINGS: usize = 8;
const SLOPE_MIN_PINGS: usize = 3;
/// The first of them lies within this share of the region's range (beyond its noise): farther
/// or nearer, the beam met another target.
const SLOPE_FIRST_SHARE: f64 = 0.08;
/// The slope must stand out of the pings' noise by this many standard errors.
const SLOPE_T: f64 = 3.0;
/// No ping lies off the straight line through them by more than this many of the noise's σ (a
/// step to another target would).
const SLOPE_RESIDUAL_SIGMAS: f64 = 3.5;

/// How the range goes on beyond a region's end ([`slope`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Slope {
    /// It climbs on from the region's: the surface goes on at a slant, heard where the beam's
    /// edge meets it ([`Rcd::sloping`]).
    Climbing,
    /// It steps down to a nearer surface within a few percent of the region's range: beside a
    /// climb, the region lies on it.
    Falling,
}

/// The index of the ping `steps` beyond `run` on `side`, if no readings are lost on the way;
/// past a full circle's last ping comes its first.
fn beyond(sweep: &Sweep, run: &Run, side: Side, steps: usize) -> Option<usize> {
    let n = sweep.pings().len();
    let circular = sweep.is_circular();
    match side {
        Side::Start => (0..steps).try_fold(run.first, |k, _| match k.checked_sub(1) {
            Some(j) => Some(j).filter(|_| !sweep.gap_before(k)),
            None => circular.then(|| n - 1),
        }),
        Side::End => (0..steps).try_fold(run.last, |k, _| {
            if k + 1 < n {
                Some(k + 1).filter(|&j| !sweep.gap_before(j))
            } else {
                circular.then_some(0)
            }
        }),
    }
}

/// How the range goes on beyond `run`'s end on `side` ([`Rcd::sloping`]): the pings there,
/// [`SLOPE_MIN_PINGS`] to [`SLOPE_PINGS`] of them each with an echo, start within
/// [`SLOPE_FIRST_SHARE`] of the run's range; they **climb** when none is nearer than the run,
/// they lie along a straight line (by step) rising [`SLOPE_T`] standard errors above level, and
/// none lies off that line by more than the noise allows; they **fall** when none is farther
/// than the run and the first is nearer or the line falls as steeply. The pings past a smooth
/// wall's region hear nothing, or another target at a step; past a post's, the wall behind it.
fn slope(sweep: &Sweep, run: &Run, gate: &Gate, side: Side) -> Option<Slope> {
    let pings = sweep.pings();
    let ranges: Vec<f64> = (1..=SLOPE_PINGS)
        .map_while(|steps| beyond(sweep, run, side, steps).and_then(|k| pings[k].range_m))
        .collect();
    if ranges.len() < SLOPE_MIN_PINGS {
        return None;
    }
    let mean = run.stats.mean();
    let reach = gate.reach(&run.stats);
    if (ranges[0] - mean).abs() > mean * SLOPE_FIRST_SHARE + reach {
        return None;
    }
    // Least squares of range on the step.
    let n = ranges.len() as f64;
    let k_mean = (n + 1.0) / 2.0;
    let r_mean = ranges.iter().sum::<f64>() / n;
    let sxx: f64 = (1..=ranges.len())
        .map(|k| (k as f64 - k_mean).powi(2))
        .sum();
    let sxy: f64 = ranges
        .iter()
        .enumerate()
        .map(|(i, r)| (i as f64 + 1.0 - k_mean) * (r - r_mean))
        .sum();
    let gradient = sxy / sxx;
    let sigma = gate.noise.sigma_at(r_mean);
    let off_line = ranges
        .iter()
        .enumerate()
        .map(|(i, r)| (r - r_mean - gradient * (i as f64 + 1.0 - k_mean)).abs())
        .fold(0.0, f64::max);
    let significant = SLOPE_T * sigma / sxx.sqrt();
    let climbs = gradient > significant
        && off_line <= SLOPE_RESIDUAL_SIGMAS * sigma
        && ranges.iter().all(|&r| r >= mean - reach);
    // Down to a nearer surface that may then run level (a rough wall's foot): no straight line.
    let falls = (ranges[0] < mean - reach || gradient < -significant)
        && ranges.iter().all(|&r| r <= mean + reach);
    if climbs {
        Some(Slope::Climbing)
    } else if falls {
        Some(Slope::Falling)
    } else {
        None
    }
}

/// What the ping just outside a run's end says about it, and the span (in steps) in which the
/// cone's edge lies.
fn end_kind(sweep: &Sweep, run: &Run, gate: &Gate, side: Side) -> (End, f64) {
    let pings = sweep.pings();
    let outside = |steps: usize| beyond(sweep, run, side, steps);
    // Split from a part at another range: nearer beyond hides this one, farther is its edge.
    let neighbour = match side {
        Side::Start => run.start_neighbour,
        Side::End => run.end_neighbour,
    };
    if let Some((m, steps)) = neighbour {
        return if m < run.stats.mean() {
            (End::Occluded, steps)
        } else {
            (End::Natural, steps)
        };
    }
    let Some(k) = outside(1) else {
        return (End::Unknown, 1.0);
    };
    let past = |r: Option<f64>| r.is_none_or(|r| gate.farther(&run.stats, r));
    // Pings lost beyond the end (nothing, at most one transient), then the run's own range
    // again: the target goes on past a burst of lost pings, its edge is not known.
    let lost = |steps: usize| {
        let mut nearer = 0;
        (1..steps).all(|s| {
            outside(s).is_some_and(|i| match pings[i].range_m {
                None => true,
                Some(r) if gate.nearer(&run.stats, r) => {
                    nearer += 1;
                    nearer <= 1
                }
                Some(_) => false,
            })
        })
    };
    let resumes = (2..=RESUME_LOOKAHEAD).any(|steps| {
        lost(steps)
            && outside(steps)
                .is_some_and(|j| pings[j].range_m.is_some_and(|r| gate.fits(&run.stats, r)))
    });
    if resumes {
        return (End::Unknown, 1.0);
    }
    match pings[k].range_m {
        // A lost ping right before a nearer target: that target may hide the rest.
        None if outside(2)
            .is_some_and(|j| pings[j].range_m.is_some_and(|r| gate.nearer(&run.stats, r))) =>
        {
            (End::Occluded, 1.0)
        }
        r if past(r) => (End::Natural, 1.0),
        Some(r) if gate.nearer(&run.stats, r) => {
            // A lone nearer ping with nothing or something farther beyond it is a transient, not
            // a target hiding this one: the run ended there or one ping later — unless past a
            // lost ping the nearer target goes on (a dropout inside its region).
            let nearer_goes_on = outside(2).is_some_and(|j| pings[j].range_m.is_none())
                && outside(3)
                    .is_some_and(|j| pings[j].range_m.is_some_and(|r| gate.nearer(&run.stats, r)));
            if !nearer_goes_on && outside(2).is_some_and(|j| past(pings[j].range_m)) {
                (End::Natural, 2.0)
            } else {
                (End::Occluded, 1.0)
            }
        }
        _ => (End::Unknown, 1.0),
    }
}

/// Most pings between two runs at one range that a faint target's amplitude jitter may have
/// lost ([`join_missed`]).
const MAX_MISSED: usize = 2;

/// Joins runs at the same range separated by at most [`MAX_MISSED`] pings that heard farther or
/// nothing, where the amplitude jitter lets a point target miss them: near the limit of a post's
/// range the threshold moving by ±[`crate::EchoPhysics::threshold_jitter_db`] loses pings inside
/// its cone (the `srf05` profile's post at 1 m, 1 dB over its threshold, was broken into two or
/// three regions in a third of its sweeps, each taken for a post of its own). Only where such a
/// miss can happen: the gap lies outside the cone the reference post keeps whatever the jitter
/// (its cone with the threshold at the top of it) about the joined run's middle, and the joined
/// run is no wider than that post heard through the lowest threshold. Without jitter the cone
/// kept is the cone, and nothing is joined: a ping that heard past a target inside its cone says
/// there is a gap (two posts with a way between them).
fn join_missed(sweep: &Sweep, runs: Vec<Run>, cfg: &FeatureConfig, gate: &Gate) -> Vec<Run> {
    let jitter = cfg.echo.threshold_jitter_db;
    if jitter <= 0.0 {
        return runs;
    }
    let pings = sweep.pings();
    let mut out: Vec<Run> = Vec::with_capacity(runs.len());
    for r in runs {
        if let Some(prev) = out.last_mut() {
            let gap = r.first.saturating_sub(prev.last + 1);
            let missed = (prev.last + 1..r.first).all(|k| {
                !sweep.gap_before(k)
                    && pings[k]
                        .range_m
                        .is_none_or(|range| gate.farther(&prev.stats, range))
            });
            let mut stats = prev.stats;
            stats.merge(&r.stats);
            let range = stats.mean();
            let middle = (pings[prev.first].bearing_deg + pings[r.last].bearing_deg) / 2.0;
            let width =
                pings[r.last].bearing_deg - pings[prev.first].bearing_deg + sweep.step_deg();
            let outside_kept = outside_kept(
                pings,
                prev.last + 1..r.first,
                middle,
                point_kept_deg(cfg, range),
            );
            if (1..=MAX_MISSED).contains(&gap)
                && missed
                && !sweep.gap_before(r.first)
                && prev.end == End::Natural
                && r.start == End::Natural
                && gate.same_range(&prev.stats, &r.stats)
                && outside_kept
                && width
                    <= 2.0 * point_widest_deg(cfg, range)
                        + cfg.width_tolerance_deg(sweep.step_deg())
            {
                prev.stats = stats;
                prev.outliers += gap as u32 + r.outliers;
                prev.hidden += r.hidden;
                prev.last = r.last;
                prev.end = r.end;
                prev.end_steps = r.end_steps;
                prev.end_neighbour = r.end_neighbour;
                continue;
            }
        }
        out.push(r);
    }
    out
}

/// Joins runs at the same range separated only by pings that heard nearer: one target, partly
/// hidden by a nearer one, if no wider than one target's region can be.
fn join_hidden(sweep: &Sweep, runs: Vec<Run>, cfg: &FeatureConfig, gate: &Gate) -> Vec<Run> {
    let beam = f64::from(cfg.sensor.beam_half_angle_deg);
    let pings = sweep.pings();
    let mut out: Vec<Run> = Vec::with_capacity(runs.len());
    let mut consumed = vec![false; runs.len()];
    for a in 0..runs.len() {
        if consumed[a] {
            continue;
        }
        let mut joined = runs[a];
        // Each step looks past the pings that heard nearer, for a run at the same range.
        while joined.end == End::Occluded {
            let mut k = joined.last + 1;
            // (A lost ping among them hid nothing either.)
            while k < pings.len()
                && !sweep.gap_before(k)
                && pings[k]
                    .range_m
                    .is_none_or(|r| gate.nearer(&joined.stats, r))
            {
                k += 1;
            }
            let next = runs
                .iter()
                .enumerate()
                .skip(a + 1)
                .find(|(b, r)| !consumed[*b] && r.first == k);
            // One target: ranges within the tolerance, no wider than one target can be.
            let one_target = |r: &Run| {
                let mut s = joined.stats;
                s.merge(&r.stats);
                let width =
                    pings[r.last].bearing_deg - pings[joined.first].bearing_deg + sweep.step_deg();
                gate.same_range(&joined.stats, &r.stats)
                    && width
                        <= cfg.echo.widest_region_deg(s.mean(), beam)
                            + cfg.width_tolerance_deg(sweep.step_deg())
            };
            match next {
                Some((b, r))
                    if k < pings.len()
                        && !sweep.gap_before(k)
                        && r.start == End::Occluded
                        && one_target(r) =>
                {
                    joined.hidden += (k - joined.last - 1) as u32 + r.hidden;
                    joined.stats.merge(&r.stats);
                    joined.outliers += r.outliers;
                    joined.last = r.last;
                    joined.end = r.end;
                    joined.end_steps = r.end_steps;
                    consumed[b] = true;
                }
                _ => break,
            }
        }
        out.push(joined);
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A sweep of pings 1.5° apart from `from_deg`, with these ranges (0 = no echo).
    pub(crate) fn sweep(from_deg: f64, ranges: &[f64]) -> Sweep {
        let pings = ranges
            .iter()
            .enumerate()
            .map(|(i, &r)| Ping {
                bearing_deg: from_deg + 1.5 * i as f64,
                range_m: (r > 0.0).then_some(r),
            })
            .collect();
        Sweep::from_pings(pings, 1.5).unwrap()
    }

    /// `n` pings at `r`.
    pub(crate) fn run(n: usize, r: f64) -> Vec<f64> {
        vec![r; n]
    }

    fn cat(parts: &[Vec<f64>]) -> Vec<f64> {
        parts.concat()
    }

    /// The regions of `sweep` with the noise estimated from its own pings, as the map does.
    pub(crate) fn regions(sweep: &Sweep) -> Vec<Rcd> {
        regions_with(sweep, &FeatureConfig::default())
    }

    /// The same, the features set up with `cfg`.
    fn regions_with(sweep: &Sweep, cfg: &FeatureConfig) -> Vec<Rcd> {
        let noise = NoiseModel::estimate(sweep.pairs().iter().copied(), &cfg.noise);
        extract(sweep, cfg, &Gate::new(noise, cfg))
    }

    /// The features set up for the `srf05` profile's echoes, the threshold steady: its 5 cm post
    /// at 1 m about 1 dB over the threshold on its axis.
    pub(crate) fn srf05_echoes() -> FeatureConfig {
        let mut cfg = FeatureConfig::default();
        cfg.echo.tvg_db_per_m = 6.0;
        cfg.echo.tvg_max_range_m = 4.0;
        cfg.echo.threshold_db = -19.5;
        cfg
    }

    /// `n` pings from `from_deg` that hear a target at 0.975 m within `half_deg` of `axis_deg`
    /// and a wall at 2 m elsewhere.
    fn cone_sweep_ranges(from_deg: f64, n: usize, axis_deg: f64, half_deg: f64) -> Vec<f64> {
        (0..n)
            .map(|i| {
                let off = from_deg + 1.5 * i as f64 - axis_deg;
                if off.abs() <= half_deg { 0.975 } else { 2.0 }
            })
            .collect()
    }

    fn rcds(from_deg: f64, ranges: &[f64]) -> Vec<Rcd> {
        regions(&sweep(from_deg, ranges))
    }

    /// A rough wall `d` m away, its normal at 0°, swept from −60° to 60°: heard at its foot
    /// while the foot lies within 30° of a ping's axis, beyond that where the beam's edge meets
    /// it, and not past 50°; ±3 mm of jitter.
    fn rough_wall_ranges(d: f64) -> Vec<f64> {
        (0..=80)
            .map(|i| {
                let bearing = -60.0 + 1.5 * f64::from(i);
                let past_edge = (f64::abs(bearing) - 30.0).max(0.0);
                let jitter = if i % 2 == 0 { 0.003 } else { -0.003 };
                if f64::abs(bearing) > 50.0 {
                    0.0
                } else {
                    d / past_edge.to_radians().cos() + jitter
                }
            })
            .collect()
    }

    #[test]
    fn a_rough_walls_foot_climbs_on_beyond_both_ends_and_its_climbs_are_no_targets() {
        for d in [0.8, 1.5, 2.5] {
            let found = rcds(-60.0, &rough_wall_ranges(d));
            let foot = found
                .iter()
                .filter(|r| (r.range_m - d).abs() < 0.01)
                .max_by_key(|r| r.pings)
                .unwrap_or_else(|| panic!("{found:?}"));
            assert!(foot.is_sloping_foot(), "{foot:?}");
            let classes = crate::classify::classify(&found, &FeatureConfig::default());
            for (r, class) in found.iter().zip(&classes.classes) {
                if std::ptr::eq(r, foot) {
                    assert_eq!(*class, crate::classify::Class::Plane, "{r:?}");
                } else {
                    // The climbs: no post, corner or wall of their own.
                    assert_eq!(*class, crate::classify::Class::Unclassified, "{r:?}");
                }
            }
            let wall = classes
                .observations
                .iter()
                .find(|o| o.kind == crate::feature::FeatureKind::Plane)
                .expect("the wall");
            // Its normal within two of its own σ.
            assert!(
                wall.bearing_deg.abs() <= 2.0 * wall.bearing_sigma_deg,
                "{wall:?}"
            );
            assert!((wall.range_m - d).abs() < 0.01, "{wall:?}");
        }
    }

    #[test]
    fn a_posts_region_and_a_smooth_walls_do_not_slope() {
        // A post with the wall behind it, and a smooth wall heard within its cut-off only.
        let post = rcds(-30.0, &cone_sweep_ranges(-30.0, 41, 0.0, 10.0));
        let smooth: Vec<f64> = (0..=80)
            .map(|i| {
                if (-60.0 + 1.5 * f64::from(i)).abs() <= 28.0 {
                    1.5
                } else {
                    0.0
                }
            })
            .collect();
        let wall = rcds(-60.0, &smooth);
        for r in post.iter().chain(&wall) {
            assert_eq!(r.sloping, [None, None], "{r:?}");
        }
    }

    #[test]
    fn a_faint_posts_pings_lost_to_the_amplitude_jitter_leave_one_region() {
        // The SRF05 profile's 5 cm post at 1 m, about 1 dB over its threshold: a ping on its
        // flank heard the wall behind it.
        let mut cfg = srf05_echoes();
        let posts = |cfg: &FeatureConfig, ranges: &[f64], nearer_than: f64| -> Vec<Rcd> {
            regions_with(&sweep(-15.0, ranges), cfg)
                .into_iter()
                .filter(|r| r.range_m < nearer_than)
                .collect()
        };
        let flank = cat(&[
            run(3, 2.0),
            run(3, 0.975),
            run(1, 2.0),
            run(12, 0.975),
            run(3, 2.0),
        ]);
        // Told the threshold does not move, the pings that heard past it are a gap.
        assert_eq!(posts(&cfg, &flank, 1.5).len(), 2);
        cfg.echo.threshold_jitter_db = 1.0;
        let joined = posts(&cfg, &flank, 1.5);
        assert_eq!(joined.len(), 1, "{joined:?}");
        let r = joined[0];
        assert_eq!((r.pings, r.outliers), (15, 1), "{r:?}");
        assert!(r.is_whole());
        // On the post's axis even the highest threshold hears it; and a post heard well over its
        // threshold (half a metre away) keeps every ping of its cone whatever the jitter: a gap
        // there is a way between two posts.
        let on_axis = cat(&[
            run(3, 2.0),
            run(7, 0.975),
            run(1, 2.0),
            run(7, 0.975),
            run(3, 2.0),
        ]);
        assert_eq!(posts(&cfg, &on_axis, 1.5).len(), 2);
        let near: Vec<f64> = flank
            .iter()
            .map(|&r| if r < 1.0 { 0.475 } else { r })
            .collect();
        assert_eq!(posts(&cfg, &near, 1.0).len(), 2);
    }

    #[test]
    fn a_faint_posts_bearing_is_the_mean_of_every_ping_that_heard_it() {
        use rand::{Rng, SeedableRng, rngs::StdRng};
        // The SRF05 profile's post at 0.975 m, 1° off the ping grid, a wall behind at 2 m; each
        // ping's threshold moved by up to ±1 dB, so its flanks are heard by chance and a miss
        // ends the region anywhere.
        let mut cfg = srf05_echoes();
        cfg.echo.threshold_jitter_db = 1.0;
        let beam = f64::from(cfg.sensor.beam_half_angle_deg);
        let axis = 1.0;
        let mut rng = StdRng::seed_from_u64(7);
        let (mut heard, mut edges) = (Vec::new(), Vec::new());
        for _ in 0..300 {
            let ranges: Vec<f64> = (0..40)
                .map(|i| {
                    let off = -30.0 + 1.5 * i as f64 - axis;
                    let by_db = rng.random_range(-1.0..=1.0);
                    let cone = cfg.echo.cone_with_threshold_moved_deg(
                        cfg.echo.reference_point(),
                        0.975,
                        beam,
                        by_db,
                    );
                    if off.abs() <= cone { 0.975 } else { 2.0 }
                })
                .collect();
            let post = regions_with(&sweep(-30.0, &ranges), &cfg)
                .into_iter()
                .filter(|r| r.range_m < 1.5)
                .max_by_key(|r| r.pings);
            if let Some(r) = post {
                heard.push(r.heard_centre_deg - axis);
                edges.push(r.centre_deg() - axis);
            }
        }
        let stats = |v: &[f64]| {
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
            (mean, sd)
        };
        let ((mean, sd), (_, edges_sd)) = (stats(&heard), stats(&edges));
        assert!(heard.len() >= 290, "{}", heard.len());
        assert!(mean.abs() < 0.2, "{mean} {sd}");
        assert!(sd < 0.8 * edges_sd, "{sd} against the edges' {edges_sd}");
        // Without jitter the bearing is the middle between the edges.
        cfg.echo.threshold_jitter_db = 0.0;
        let steady = cone_sweep_ranges(-30.0, 40, axis, 11.6);
        for r in regions_with(&sweep(-30.0, &steady), &cfg) {
            assert_eq!(r.heard_centre_deg, r.centre_deg());
        }
    }

    #[test]
    fn a_faint_posts_bearing_is_not_drawn_to_another_post_at_its_range() {
        // Two faint posts 0.975 m away, their cones 9° apart with the wall heard between: the
        // pings at 0° and ±1.5° missed inside the cone either would keep whatever the jitter,
        // so neither post's bearing looks into the other's pings.
        let mut cfg = srf05_echoes();
        cfg.echo.threshold_jitter_db = 1.0;
        let ranges = cat(&[
            run(6, 2.0),
            run(7, 0.975),
            run(3, 2.0),
            run(7, 0.975),
            run(6, 2.0),
        ]);
        let posts: Vec<Rcd> = regions_with(&sweep(-21.0, &ranges), &cfg)
            .into_iter()
            .filter(|r| r.range_m < 1.5)
            .collect();
        assert_eq!(posts.len(), 2, "{posts:?}");
        assert!((posts[0].heard_centre_deg + 7.5).abs() < 1e-9, "{posts:?}");
        assert!((posts[1].heard_centre_deg - 7.5).abs() < 1e-9, "{posts:?}");
    }

    #[test]
    fn a_post_is_a_run_with_natural_ends_centred_on_its_bearing() {
        // 18 pings at 0.98 m between no-echo pings: a 5 cm post at 1 m.
        let ranges = cat(&[run(3, 0.0), run(18, 0.98), run(3, 0.0)]);
        let r = rcds(-30.0, &ranges);
        assert_eq!(r.len(), 1);
        let r = r[0];
        assert_eq!((r.start, r.end), (End::Natural, End::Natural));
        assert_eq!(r.pings, 18);
        assert!((r.width_deg() - 27.0).abs() < 1e-9);
        // Pings from -25.5 to 0: centre -12.75.
        assert!((r.centre_deg() + 12.75).abs() < 1e-9);
        // Without a calibrated offset the range is the pings' mean.
        assert!((r.range_m - 0.98).abs() < 1e-9, "{}", r.range_m);
        assert!(r.range_sigma_m > 0.0 && r.range_sigma_m < 0.002);
    }

    #[test]
    fn jitter_within_the_tolerance_stays_one_run_and_a_step_in_range_splits() {
        let jitter = [1.0, 1.004, 1.0086, 1.0, 1.0043, 1.0086, 1.0, 1.0043];
        let r = rcds(0.0, &jitter);
        assert_eq!(r.len(), 1);
        assert_eq!(r[0].pings, 8);
        let steps = cat(&[run(5, 1.0), run(5, 1.05)]);
        let r = rcds(0.0, &steps);
        assert_eq!(r.len(), 2);
        assert_eq!(r[0].end, End::Natural);
        assert_eq!(r[1].start, End::Occluded);
    }

    #[test]
    fn one_transient_or_dropout_is_bridged_but_a_farther_ping_is_a_gap() {
        let transient = cat(&[run(6, 1.0), vec![0.4], run(6, 1.0)]);
        let r = rcds(0.0, &transient);
        assert_eq!(r.len(), 1);
        assert_eq!((r[0].pings, r[0].outliers), (12, 1));
        // Also one that ended just short of the target, too short to count as jitter.
        let slight = cat(&[run(6, 1.0086), vec![0.985], run(6, 1.0)]);
        assert_eq!(rcds(0.0, &slight).len(), 1);
        let dropout = cat(&[run(6, 1.0), vec![0.0], run(6, 1.0)]);
        assert_eq!(rcds(0.0, &dropout)[0].outliers, 1);
        // Up to three lost pings in a row are bridged (a sensor that loses 2 % of its pings loses
        // two every few sweeps), one of them may be a transient; four are a gap, and two nearer
        // pings a target.
        let three = cat(&[run(6, 1.0), vec![0.0, 0.6, 0.0], run(6, 1.0)]);
        assert_eq!(rcds(0.0, &three)[0].outliers, 3);
        let four = cat(&[run(6, 1.0), vec![0.0; 4], run(6, 1.0)]);
        assert_eq!(rcds(0.0, &four).len(), 2);
        let nearer = cat(&[run(6, 1.0), vec![0.5, 0.5], run(6, 1.0)]);
        let r = rcds(0.0, &nearer);
        assert_eq!((r[0].outliers, r[0].hidden), (0, 2), "{r:?}");
        // One ping that heard past the target: two targets with a way between them.
        // A transient just past the end of a run does not make it look hidden.
        let r = rcds(0.0, &cat(&[run(6, 1.0), vec![0.5, 0.0], run(6, 2.0)]));
        assert_eq!(r[0].end, End::Natural);
        // It may have heard the target: the edge lies within two steps, the width is one more.
        assert_eq!(r[0].end_interval_deg, 3.0);
        assert!((r[0].width_deg() - 9.75).abs() < 1e-9);
        let r = rcds(0.0, &cat(&[run(6, 1.0), vec![0.5, 0.5], run(6, 2.0)]));
        assert_eq!(r[0].end, End::Occluded);
        // A nearer target whose region lost a ping next to this run still hides it: the wall
        // behind a post on each side of it is one wall.
        let hidden = cat(&[run(6, 1.0), vec![0.5, 0.0], run(6, 0.5), run(6, 1.0)]);
        let r = rcds(0.0, &hidden);
        assert_eq!(
            (r[0].pings, r[0].hidden),
            (12, 8),
            "joined across the post: {r:?}"
        );
        let gap = cat(&[run(6, 1.0), vec![2.0], run(6, 1.0)]);
        let r = rcds(0.0, &gap);
        assert_eq!(r.len(), 2);
        assert_eq!((r[0].end, r[1].start), (End::Natural, End::Natural));
    }

    #[test]
    fn a_wall_behind_a_post_is_joined_across_it() {
        // Wall at 2 m, a post at 1 m hides its middle.
        let ranges = cat(&[
            run(2, 0.0),
            run(6, 2.0),
            run(10, 0.98),
            run(6, 2.0),
            run(2, 0.0),
        ]);
        let r = rcds(-20.0, &ranges);
        assert_eq!(r.len(), 2, "{r:?}");
        let post = r.iter().find(|r| r.range_m < 1.5).unwrap();
        let wall = r.iter().find(|r| r.range_m > 1.5).unwrap();
        assert_eq!((post.start, post.end), (End::Natural, End::Natural));
        assert_eq!((wall.start, wall.end), (End::Natural, End::Natural));
        assert_eq!((wall.pings, wall.hidden), (12, 10));
        assert!((wall.width_deg() - 22.0 * 1.5).abs() < 1e-9);
        // Four corners of a room, at one range between nearer walls, are not one target.
        let room = cat(&[
            run(20, 1.7),
            run(37, 1.2),
            run(22, 1.7),
            run(37, 1.2),
            run(20, 1.7),
        ]);
        assert_eq!(rcds(0.0, &room).len(), 5);
        // Not across a farther ping, nor across lost readings.
        let far = cat(&[run(6, 2.0), run(3, 0.98), vec![3.0], run(6, 2.0)]);
        // The lone 3 m ping is too short a run to keep: two walls and the post.
        assert_eq!(rcds(0.0, &far).len(), 3);
    }

    #[test]
    fn short_runs_are_dropped_and_scan_ends_are_unknown() {
        let ranges = cat(&[run(2, 1.0), vec![0.0, 0.0], run(5, 1.5)]);
        let r = rcds(0.0, &ranges);
        assert_eq!(r.len(), 1);
        assert_eq!((r[0].start, r[0].end), (End::Natural, End::Unknown));
        // One lost ping right before a nearer target: that target may hide the rest.
        let ranges = cat(&[run(2, 1.0), vec![0.0], run(5, 1.5)]);
        assert_eq!(rcds(0.0, &ranges)[0].start, End::Occluded);
        // Lost readings end a run like the end of the scan.
        let mut pings: Vec<Ping> = sweep(0.0, &run(6, 1.0)).pings().to_vec();
        for p in &mut pings[3..] {
            p.bearing_deg += 6.0;
        }
        let gapped = Sweep::from_pings(pings, 1.5).unwrap();
        let r = regions(&gapped);
        assert_eq!(r.len(), 2);
        assert_eq!((r[0].end, r[1].start), (End::Unknown, End::Unknown));
    }
}
