//! The update of the grid by one reading: the fast cone kernel, and what every kernel shares.
//!
//! The paper's arrays (GridAngles, GridLength, AngleInside; see [`crate::reference`]) imply a pass
//! over the whole grid per reading, though a 60° cone to 4 m covers a sixth of the disc around the
//! sensor and far less of a large grid. The fast kernel visits only the cells of the cone, from any
//! position of the sensor:
//!
//! - **Row spans per beam direction.** The stepper's angles are discrete (reading centres every
//!   6°, pings every 1.5°), so per beam direction, quantised to [`ANGLE_STEP`], the cache keeps for
//!   each row of cells around the sensor's cell the first and last column that can lie inside the
//!   cone (widened by half a step and a rounding margin) **wherever the sensor sits within its
//!   cell**: the row's stretch across the sector within the band of the cells' centres, worked out
//!   in f64 from the sector's geometry ([`Sector`]). They depend on the direction alone, not on
//!   the position, so a moving robot reuses them like a standing one. A reading clips those spans
//!   to its own reach and to the grid and runs along contiguous row slices of cells: no gathers,
//!   no branches in the loop (models and rules are written with selects), so it vectorises; and
//!   the exact cone test in the loop makes the result independent of the quantisation. The cone
//!   is the beam's, narrowed to the rule's (HIMM updates only near the axis) and to the angles at
//!   which the model can give evidence at all (the smooth model's profiles end inside the beam),
//!   and each row's run leaves out the cells nearer than the evidence's nearest range
//!   ([`CellEvidence::near`]): a region's patch and a weak echo have no free evidence, and
//!   visiting the whole cone in front of them cost the region model a third of its work.
//!   Each row's run is widened to whole vectors where the grid allows (the extra cells lie outside
//!   the cone or the reach and get no evidence), so the scalar remainder rarely runs. Where the
//!   CPU has AVX2 (detected at run time) the row loop is compiled a second time for it, with
//!   vectors twice as wide as the portable build's SSE2, and where it has AVX-512 (F and VL) a
//!   third time: 512-bit vectors and twice as many vector registers.
//! - **Range and bearing computed in the loop.** Each cell's range and bearing are computed in the
//!   row loop from its offset and the sensor's position in its cell ([`polar`]: a square root and
//!   a branch-free arctangent of our own, [`crate::geometry::atan2`], both of which vectorise), so
//!   a reading from a new position costs what one from an old position does. Until issue 29 the
//!   kernel kept only a stencil of precomputed ranges and bearings for one sub-cell position;
//!   readings from anywhere else took a scalar pass over the bounding box of the cone with the C
//!   library's `atan2f` per cell, and a robot that moves never repeats a sub-cell position: on a
//!   driven tour of the room that fallback cost 30× the fast path (`docs/benchmarks.md`, "Against
//!   MRPT").
//! - **Stencil of a parked sensor.** Loading a range and a bearing is still cheaper than
//!   computing them (the square root and the division share one unit of the core), so once
//!   [`PARKED_AFTER`] readings in a row came from one position within a cell, as from a head
//!   scanning standing still, the kernel keeps the cells' ranges and bearings around it
//!   ([`Stencil`], the same [`polar`]), with their radial trust (a pure function of the range,
//!   [`crate::model::radial_trust`], for the models weighted by it), and loads them for the
//!   readings from there. It fills each row's cells the first time a reading from there visits
//!   them: filling the whole square at once (641 k cells at 1 cm) cost about 1.2 ms per stop,
//!   more than a stop-and-scan robot's two sweeps there saved.
//! - **Runs planned, then fused.** A reading first clips each row's span and fills the stencil
//!   ([`plan_runs`], scalar), then the vectorised pass runs along those runs alone: the clipping
//!   inside the pass kept the loop's constants from staying in registers across rows, and cost as
//!   many instructions per row as a row's loop (`docs/benchmarks.md`, "The kernel per reading").
//!
//! No path allocates once warm: the spans of a direction are made on its first reading, the
//! stencil's memory when a sensor first parks (and kept when it parks elsewhere).
//!
//! Every path computes a cell's range and bearing with the same function and fuses it with
//! [`fuse_run`], so they agree with the reference to the last bit.

use std::f32::consts::PI;
use std::ops::RangeInclusive;

use crate::config::FusionConfig;
use crate::geometry::{GridGeometry, SensorCell, off_axis, polar};
use crate::grid::Layer;
use crate::model::{CellEvidence, radial_trust};
use crate::observation::{Beam, Limits};
use crate::rule::{Combine, Domain};

/// Quantum of the beam directions the row spans are cached for: 0.25°, a sixth of a stepper step,
/// so the spans are only 0.125° wider each side than the cone itself.
pub(crate) const ANGLE_STEP: f32 = PI / 720.0;
const ANGLE_KEYS: usize = 1440;
/// Readings in a row from one position within a cell before the kernel keeps a [`Stencil`] there.
pub(crate) const PARKED_AFTER: u32 = 16;

/// A reading's evidence for the cell at range `r` and world bearing `bearing`, in the rule's
/// domain; NaN (no evidence) outside the rule's cone of `cone` radians around `axis`. `trust`
/// is the cell's radial trust if the caller keeps it ([`CellEvidence::FADES`]; log-odds rules
/// only), else `None` and the model works it out: the same bits either way.
#[inline(always)]
pub(crate) fn cell_evidence<R: Combine, E: CellEvidence>(
    evidence: &E,
    axis: f32,
    cone: f32,
    r: f32,
    bearing: f32,
    trust: Option<f32>,
) -> f32 {
    let alpha = off_axis(bearing, axis);
    let e = match (R::DOMAIN, trust) {
        (Domain::Probability, _) => evidence.probability(r, alpha),
        (Domain::LogOdds, None) => evidence.log_odds(r, alpha),
        (Domain::LogOdds, Some(trust)) => evidence.trusted_log_odds(r, alpha, trust),
    };
    if alpha.abs() <= cone { e } else { f32::NAN }
}

/// [`cell_evidence`] for a model that hears ([`CellEvidence::HEARD`]), with the bearing `heard` the
/// cell was last heard occupied from, which it updates (only inside the rule's cone).
#[inline(always)]
pub(crate) fn heard_cell_evidence<R: Combine, E: CellEvidence>(
    evidence: &E,
    axis: f32,
    cone: f32,
    (r, bearing): (f32, f32),
    heard: &mut f32,
    trust: Option<f32>,
) -> f32 {
    let alpha = off_axis(bearing, axis);
    let inside = alpha.abs() <= cone;
    let mut h = *heard;
    let e = match (R::DOMAIN, trust) {
        (Domain::Probability, _) => evidence.heard_probability(r, alpha, bearing, &mut h),
        (Domain::LogOdds, None) => evidence.heard_log_odds(r, alpha, bearing, &mut h),
        (Domain::LogOdds, Some(trust)) => {
            evidence.trusted_heard_log_odds(r, alpha, bearing, &mut h, trust)
        }
    };
    *heard = if inside { h } else { *heard };
    if inside { e } else { f32::NAN }
}

/// A cell's range (metres), world bearing and radial trust, as the row loop takes them.
pub(crate) type Polar = (f32, f32, f32);

/// Fuses a reading into a run of cells whose (range, bearing, radial trust) `polar` yields in
/// order; returns how many cells it updated. `heard` holds the run's bearings each cell was last heard occupied from
/// if the model hears ([`CellEvidence::HEARD`]), and is empty otherwise.
#[inline(always)]
pub(crate) fn fuse_run<R: Combine, E: CellEvidence>(
    rule: &R,
    evidence: &E,
    axis: f32,
    cone: f32,
    cells: &mut [R::Cell],
    heard: &mut [f32],
    polar: impl Iterator<Item = Polar>,
) -> usize {
    // Counted in u32, the width of the cells' lanes: a usize counter would make the vectoriser
    // pair each f32 lane with a 64-bit one and halve the vector width. A run is at most a grid
    // row (≤ `MAX_CELLS_PER_SIDE` cells), so it cannot overflow.
    let mut updated = 0u32;
    if E::HEARD {
        for ((cell, heard), (r, bearing, trust)) in cells.iter_mut().zip(heard).zip(polar) {
            let e =
                heard_cell_evidence::<R, E>(evidence, axis, cone, (r, bearing), heard, Some(trust));
            updated += u32::from(rule.fuse(cell, e));
        }
    } else {
        for (cell, (r, bearing, trust)) in cells.iter_mut().zip(polar) {
            let e = cell_evidence::<R, E>(evidence, axis, cone, r, bearing, Some(trust));
            updated += u32::from(rule.fuse(cell, e));
        }
    }
    updated as usize
}

/// For one beam direction, per row of cells from `first_row` on (row offsets from the sensor's
/// cell), the first and last column offset of the cells that can lie in the cone for a sensor
/// anywhere in its cell (`lo > hi`: none).
struct Spans {
    first_row: i64,
    rows: Vec<[i64; 2]>,
}

impl Spans {
    /// The spans of the cone of half-angle `cone` around `axis`, up to `reach` metres, rows within
    /// `radius` cells of the sensor's cell, cells of `resolution` metres.
    fn new(radius: i64, resolution: f32, axis: f32, cone: f32, reach: f32) -> Self {
        let sector = Sector::new(axis, cone_margin(cone), reach / resolution);
        // Only the rows the sector reaches into (a narrow cone's are a fraction of the square:
        // a moving robot's heading meets every direction key, each computed once), with two
        // rows to spare each way for the rounding: the rows beyond hold none of its points.
        let [lowest, highest] = sector.extent_in_y();
        let first = ((lowest - 0.5).floor() as i64 - 2).max(-radius);
        let last = ((highest + 0.5).ceil() as i64 + 2).min(radius);
        Self::over_rows(radius, &sector, first..=last)
    }

    /// The spans of `sector`'s rows `oy` in `rows` (those beyond empty), within `radius` cells.
    fn over_rows(radius: i64, sector: &Sector, rows_looked_at: RangeInclusive<i64>) -> Self {
        let mut first_row = None;
        let mut rows = Vec::new();
        for oy in rows_looked_at {
            let span = match sector.across_band(oy as f64 - 0.5, oy as f64 + 0.5) {
                // The cell `ox` holds a sector point (x, y) of the band, for some sensor position
                // in the cell, when |ox − x| ≤ 1/2.
                Some([lo, hi]) => [
                    ((lo - 0.5).ceil() as i64).max(-radius),
                    ((hi + 0.5).floor() as i64).min(radius),
                ],
                None => [i64::MAX, i64::MIN],
            };
            if span[0] <= span[1] || first_row.is_some() {
                first_row.get_or_insert(oy);
                rows.push(span);
            }
        }
        // Trailing empty rows carry nothing.
        while rows.last().is_some_and(|s| s[0] > s[1]) {
            rows.pop();
        }
        Self {
            first_row: first_row.unwrap_or(0),
            rows,
        }
    }
}

/// The cone of the spans: the cone widened by half an [`ANGLE_STEP`] (they serve every direction
/// that rounds to theirs) and a rounding margin.
fn cone_margin(cone: f32) -> f32 {
    cone + ANGLE_STEP / 2.0 + 1e-4
}

/// A sector with its apex at the origin, in cells, a little wider and longer than a cone (by far
/// more than the f32 values' rounding), worked out in f64.
struct Sector {
    /// Its radius, cells.
    reach: f64,
    /// Its two edges, as unit vectors: the sector is the set left of `edges[0]` and right of
    /// `edges[1]` (< 180° wide, so convex), or `None` for a sector of 180° or more, taken as the
    /// whole disc.
    edges: Option<[[f64; 2]; 2]>,
    axis: f64,
    half: f64,
    /// The sine and cosine of its edges' bearings, `axis ∓ half`.
    edge_sin_cos: [(f64, f64); 2],
}

/// How much wider than the cone the sector is, radians: far more than the f32 bearing's rounding
/// (a few 1e-7 rad), so no cell the cone test passes lies outside it.
const WINDOW_ANGLE_SLACK: f64 = 1e-5;
/// How much longer, cells (the test compares ranges in f32 metres).
const WINDOW_REACH_SLACK: f64 = 2.0;

impl Sector {
    fn new(axis: f32, margin: f32, reach_cells: f32) -> Self {
        let half = f64::from(margin) + WINDOW_ANGLE_SLACK;
        let axis = f64::from(axis);
        let edge = |a: f64| [a.cos(), a.sin()];
        Self {
            reach: f64::from(reach_cells) + WINDOW_REACH_SLACK,
            edges: (half < std::f64::consts::FRAC_PI_2 - 1e-6)
                .then(|| [edge(axis - half), edge(axis + half)]),
            axis,
            half,
            edge_sin_cos: [(axis - half).sin_cos(), (axis + half).sin_cos()],
        }
    }

    /// The lowest and highest y of its points, cells: its apex's, its arc's ends', and the
    /// arc's top and bottom where it runs through them.
    fn extent_in_y(&self) -> [f64; 2] {
        if self.edges.is_none() {
            return [-self.reach, self.reach];
        }
        let ends = self.edge_sin_cos.map(|(s, _)| self.reach * s);
        let mut extent = [ends[0].min(ends[1]).min(0.0), ends[0].max(ends[1]).max(0.0)];
        if self.holds_direction(-std::f64::consts::FRAC_PI_2) {
            extent[0] = -self.reach;
        }
        if self.holds_direction(std::f64::consts::FRAC_PI_2) {
            extent[1] = self.reach;
        }
        extent
    }

    /// Whether the direction `angle` lies within the sector's angle.
    fn holds_direction(&self, angle: f64) -> bool {
        self.edges.is_none() || {
            let d = (angle - self.axis).rem_euclid(std::f64::consts::TAU);
            d.min(std::f64::consts::TAU - d) <= self.half
        }
    }

    /// The stretch in x of the sector's points on the line y = `y`, if any.
    fn across_line(&self, y: f64) -> Option<[f64; 2]> {
        let chord = self.reach * self.reach - y * y;
        if chord < 0.0 {
            return None;
        }
        let chord = chord.sqrt();
        let (mut lo, mut hi) = (-chord, chord);
        if let Some([d1, d2]) = self.edges {
            // Left of edge 1: d1.x·y − d1.y·x ≥ 0; right of edge 2: x·d2.y − y·d2.x ≥ 0.
            for (normal, offset) in [(-d1[1], d1[0] * y), (d2[1], -y * d2[0])] {
                // normal·x + offset ≥ 0
                if normal > 0.0 {
                    lo = lo.max(-offset / normal);
                } else if normal < 0.0 {
                    hi = hi.min(-offset / normal);
                } else if offset < 0.0 {
                    return None;
                }
            }
        }
        (lo <= hi).then_some([lo, hi])
    }

    /// The stretch in x of the sector's points with `y0` ≤ y ≤ `y1`, if any. The sector is convex
    /// (or the disc), so its part within the band is too, and the extremes in x lie on the band's
    /// edges, at the sector's corners (apex and the arc's ends) within the band, or where the arc
    /// runs vertical (straight ahead or behind, at y = 0).
    fn across_band(&self, y0: f64, y1: f64) -> Option<[f64; 2]> {
        let mut stretch: Option<[f64; 2]> = None;
        let mut include = |x: f64| {
            stretch = Some(stretch.map_or([x, x], |[lo, hi]| [lo.min(x), hi.max(x)]));
        };
        for y in [y0, y1] {
            if let Some([lo, hi]) = self.across_line(y) {
                include(lo);
                include(hi);
            }
        }
        let in_band = |y: f64| (y0..=y1).contains(&y);
        if in_band(0.0) {
            include(0.0);
            for (x, angle) in [(self.reach, 0.0), (-self.reach, std::f64::consts::PI)] {
                if self.holds_direction(angle) {
                    include(x);
                }
            }
        }
        if self.edges.is_some() {
            for (s, c) in self.edge_sin_cos {
                if in_band(self.reach * s) {
                    include(self.reach * c);
                }
            }
        }
        stretch
    }
}

/// Range and bearing of every cell within reach of a sensor parked at one position within its
/// cell, row-major, `side` = 2·radius + 1 cells a side: computed once with [`polar`], as the row
/// loop would compute them, so a reading from there loads them instead.
struct Stencil {
    /// The sensor's position in its cell ([`SensorCell::to_centre`]), bit for bit.
    to_centre: [u32; 2],
    /// That position, to compute the cells not yet filled.
    sensor: SensorCell,
    radius: i64,
    side: usize,
    range: Vec<f32>,
    bearing: Vec<f32>,
    /// The cells' radial trust at `fade` ([`radial_trust`]), if `fade` is a range (not NaN).
    trust: Vec<f32>,
    fade: f32,
    /// Per row, the columns filled so far (`lo > hi`: none): cells are computed the first time a
    /// reading from here visits them, so a sensor parked for one sweep pays for the cells its
    /// readings reach, not for the whole square.
    filled: Vec<[i64; 2]>,
}

impl Stencil {
    fn new(sensor: &SensorCell, radius: i64) -> Self {
        let side = (2 * radius + 1) as usize;
        let mut stencil = Self {
            to_centre: [0; 2],
            sensor: *sensor,
            radius,
            side,
            range: vec![0.0; side * side],
            bearing: vec![0.0; side * side],
            trust: vec![0.0; side * side],
            fade: f32::NAN,
            filled: vec![EMPTY_SPAN; side],
        };
        stencil.park(sensor);
        stencil
    }

    /// Keeps the cells' radial trust at `fade` from now on (NaN: as it was); the cells filled so
    /// far are filled again if it kept another (or none).
    fn keep_trust(&mut self, fade: f32) {
        if !fade.is_nan() && fade.to_bits() != self.fade.to_bits() {
            self.fade = fade;
            self.filled.fill(EMPTY_SPAN);
        }
    }

    /// Empties the stencil for a sensor parked at `sensor`; the memory is kept.
    fn park(&mut self, sensor: &SensorCell) {
        self.to_centre = sensor.to_centre.map(f32::to_bits);
        self.sensor = *sensor;
        self.filled.fill(EMPTY_SPAN);
    }

    /// Fills the cells `lo..=hi` of row `oy` that are not yet (keeping each row's filled columns
    /// one stretch).
    #[inline(always)]
    fn cover(&mut self, oy: i64, lo: i64, hi: i64) {
        let [from, to] = self.filled[(oy + self.radius) as usize];
        if from > lo || to < hi {
            self.extend(oy, lo, hi);
        }
    }

    /// [`Self::cover`] for a row not yet filled as far as `lo..=hi`.
    #[inline(never)]
    fn extend(&mut self, oy: i64, lo: i64, hi: i64) {
        let row = (oy + self.radius) as usize;
        let [from, to] = self.filled[row];
        if from > to {
            self.compute(oy, lo, hi);
            self.filled[row] = [lo, hi];
            return;
        }
        if lo < from {
            self.compute(oy, lo, from - 1);
        }
        if hi > to {
            self.compute(oy, to + 1, hi);
        }
        self.filled[row] = [lo.min(from), hi.max(to)];
    }

    /// Computes the cells `lo..=hi` of row `oy` (their trust only if the stencil keeps it).
    fn compute(&mut self, oy: i64, lo: i64, hi: i64) {
        let (s, len) = (self.at(lo, oy), (hi - lo + 1) as usize);
        let cells = self.range[s..s + len]
            .iter_mut()
            .zip(&mut self.bearing[s..s + len]);
        for ((r, a), (range, bearing, _)) in cells.zip(self.sensor.row(oy, lo, len, f32::NAN)) {
            (*r, *a) = (range, bearing);
        }
        if !self.fade.is_nan() {
            let fade = self.fade;
            for (t, &r) in self.trust[s..s + len]
                .iter_mut()
                .zip(&self.range[s..s + len])
            {
                *t = radial_trust(r, fade);
            }
        }
    }

    fn at(&self, ox: i64, oy: i64) -> usize {
        (oy + self.radius) as usize * self.side + (ox + self.radius) as usize
    }
}

/// A row's span with no cells.
const EMPTY_SPAN: [i64; 2] = [i64::MAX, i64::MIN];

/// Where the cells' ranges, bearings and radial trust of a row come from: computed from the
/// sensor's position ([`SensorCell`]), or loaded from the [`Stencil`] of a parked sensor. Both
/// give the same bits.
trait RowPolar {
    /// Makes the cells `lo`, `lo` + 1, … (`len` of them) of row `oy` ready for [`Self::row`]
    /// (before the pass over the rows: the stencil fills them).
    fn prepare(&mut self, _oy: i64, _lo: i64, _len: usize) {}

    /// Range, bearing and radial trust at `fade` (NaN: the reading has no use for it, and it is
    /// not to be relied on) of the cells `lo`, `lo` + 1, … (`len` of them) of row `oy`, in
    /// offsets from the sensor's cell.
    fn row(&self, oy: i64, lo: i64, len: usize, fade: f32) -> impl Iterator<Item = Polar>;
}

impl RowPolar for SensorCell {
    #[inline(always)]
    fn row(&self, oy: i64, lo: i64, _len: usize, fade: f32) -> impl Iterator<Item = Polar> {
        let dy = oy as f32 + self.to_centre[1];
        let (to_x, resolution) = (self.to_centre[0], self.resolution());
        // Offsets in i32, whose lanes are as wide as the cells' (an i64 counter would halve the
        // vectors, as for `fuse_run`'s count); a row's offsets are within the grid's side. The
        // trust, where the reading does not use it, is optimised away with its square root.
        (lo as i32..).map(move |ox| {
            let (r, bearing) = polar(ox as f32 + to_x, dy, resolution);
            (r, bearing, radial_trust(r, fade))
        })
    }
}

impl RowPolar for Stencil {
    #[inline(always)]
    fn prepare(&mut self, oy: i64, lo: i64, len: usize) {
        self.cover(oy, lo, lo + len as i64 - 1);
    }

    #[inline(always)]
    fn row(&self, oy: i64, lo: i64, len: usize, fade: f32) -> impl Iterator<Item = Polar> {
        let s = self.at(lo, oy);
        // Without a fade the trust is not used, and its loads are optimised away.
        let trust = if fade.is_nan() {
            &self.range
        } else {
            &self.trust
        };
        let range = self.range[s..s + len].iter().copied();
        let polar = range.zip(self.bearing[s..s + len].iter().copied());
        polar
            .zip(trust[s..s + len].iter().copied())
            .map(|((r, bearing), trust)| (r, bearing, trust))
    }
}

/// The fast kernel's caches for one grid geometry, one reach and one rule: the row spans per beam
/// direction, worked out on its first reading and kept, and the stencil of a parked sensor.
pub(crate) struct ConeCache {
    radius: i64,
    reach: f32,
    /// The model's angular reach (see [`CellEvidence::half_angle`]).
    model_half_angle: f32,
    limits: Limits,
    spans: Vec<Option<Box<Spans>>>,
    parking: Parking,
    /// The current reading's runs of cells, one per row ([`plan_runs`]); kept for the memory.
    runs: Vec<RowRun>,
}

/// The stencil of a parked sensor, and the position a sensor may be parking at.
#[derive(Default)]
struct Parking {
    stencil: Option<Stencil>,
    /// The position within its cell of the latest reading not from the stencil's, and how many
    /// readings in a row came from there.
    candidate: Option<([u32; 2], u32)>,
}

impl Parking {
    /// The stencil for a sensor at `sensor` if it is parked there: built (`radius` cells each
    /// way) once [`PARKED_AFTER`] readings in a row came from its position within its cell.
    fn stencil_for(&mut self, sensor: &SensorCell, radius: i64) -> Option<&mut Stencil> {
        let position = sensor.to_centre.map(f32::to_bits);
        if self
            .stencil
            .as_ref()
            .is_some_and(|s| s.to_centre == position)
        {
            return self.stencil.as_mut();
        }
        let seen = match self.candidate {
            Some((p, n)) if p == position => n + 1,
            _ => 1,
        };
        if seen < PARKED_AFTER {
            self.candidate = Some((position, seen));
            return None;
        }
        self.candidate = None;
        let stencil = match self.stencil.take() {
            Some(mut stencil) => {
                stencil.park(sensor);
                stencil
            }
            None => Stencil::new(sensor, radius),
        };
        Some(self.stencil.insert(stencil))
    }
}

impl ConeCache {
    pub fn new(config: &FusionConfig) -> Self {
        Self {
            radius: (config.stencil_side() as i64 - 1) / 2,
            reach: config.model.max_reach(config.sensor.max_range_m),
            model_half_angle: config.model.max_half_angle(),
            limits: config.sensor.limits(),
            spans: (0..ANGLE_KEYS).map(|_| None).collect(),
            parking: Parking::default(),
            runs: Vec::new(),
        }
    }

    /// Fuses the reading of `beam` (whose evidence is `evidence`) into `layer` and, if the model
    /// hears, into `heard` (one bearing per cell; empty otherwise); returns how many cells it
    /// updated.
    pub fn update<R: Combine, E: CellEvidence>(
        &mut self,
        layer: &mut Layer<R>,
        heard: &mut [f32],
        geometry: &GridGeometry,
        beam: &Beam,
        evidence: &E,
    ) -> usize {
        let sensor = geometry.sensor_cell(beam.position);
        // Cells the rule leaves alone or the model says nothing about are not visited.
        let cone = layer
            .rule
            .cone_half_angle(beam.half_angle)
            .min(evidence.half_angle());
        let reach = evidence.reach().min(self.reach);
        let envelope = layer
            .rule
            .cone_half_angle(self.limits.half_angle)
            .min(self.model_half_angle);
        let key = ((beam.axis + PI) / ANGLE_STEP).round() as usize % ANGLE_KEYS;
        let (radius, max_reach, resolution) = (self.radius, self.reach, geometry.resolution());
        let spans = self.spans[key].get_or_insert_with(|| {
            let axis = key as f32 * ANGLE_STEP - PI;
            Box::new(Spans::new(radius, resolution, axis, envelope, max_reach))
        });
        let stencil = self.parking.stencil_for(&sensor, radius);
        let (cell, n) = (sensor.cell, geometry.cells_per_side() as i64);
        let k = (reach / resolution).ceil() as i64 + 1;
        // Cells nearer than the evidence's nearest range, with a cell to spare for the rounding
        // (NaN or less than a cell: none).
        let near = ((evidence.near() / resolution).floor() as i64 - 1).max(0);
        // The cells' radial trust, for the evidence that is weighted by it and a rule that takes
        // log-odds (the probability forms work it out themselves).
        let fade = if E::FADES && R::DOMAIN == Domain::LogOdds {
            evidence.fade_range()
        } else {
            f32::NAN
        };
        let reach = RowReach {
            cell,
            radius,
            n,
            k,
            near,
        };
        let plan = (&**spans, &reach, &mut self.runs);
        let angles = (beam.axis, cone, fade);
        match stencil {
            Some(stencil) => {
                stencil.keep_trust(fade);
                plan_and_fuse(stencil, plan, layer, heard, evidence, angles)
            }
            None => plan_and_fuse(&mut { sensor }, plan, layer, heard, evidence, angles),
        }
    }
}

/// [`fuse_rows`] in the widest build the CPU runs.
#[inline(always)]
fn dispatch<R: Combine, E: CellEvidence, P: RowPolar>(
    layer: &mut Layer<R>,
    heard: &mut [f32],
    evidence: &E,
    axis: f32,
    cone: f32,
    pass: RowPass<'_>,
    polar: &P,
) -> usize {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512vl")
    {
        // SAFETY: the CPU has AVX-512F and VL, checked just above.
        return unsafe { fuse_rows_avx512(layer, heard, evidence, axis, cone, pass, polar) };
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { fuse_rows_avx2(layer, heard, evidence, axis, cone, pass, polar) };
    }
    fuse_rows(layer, heard, evidence, axis, cone, pass, polar)
}

/// Where a reading's rows may run: what [`plan_runs`] clips the spans to.
struct RowReach {
    /// The sensor's cell.
    cell: [i64; 2],
    /// Rows and columns the spans (and a stencil) reach from the sensor's cell.
    radius: i64,
    /// Cells per side of the grid.
    n: i64,
    /// The reading's reach in cells, plus one.
    k: i64,
    /// A range in cells within which no cell gets evidence ([`CellEvidence::near`]), less one.
    near: i64,
}

/// One row's run of cells for a reading: its cells `first..first + len` of the grid, in its row
/// `row`, which are the columns `lo`, `lo` + 1, … of row `oy` in offsets from the sensor's cell.
#[derive(Clone, Copy)]
struct RowRun {
    row: usize,
    oy: i64,
    lo: i64,
    first: usize,
    len: usize,
}

/// What the pass over the rows takes besides the layer and the evidence: the runs, and the
/// range at which the evidence's radial trust is one half (NaN: not used).
type RowPass<'a> = (&'a [RowRun], f32);

/// A reading's runs planned over `polar` (the parked sensor's stencil, or its own cell) from
/// `plan` (the spans of its direction, its reach, where the runs go), then fused; `angles` are
/// its axis, its cone's half-angle and its fade range ([`RowPass`]).
fn plan_and_fuse<R: Combine, E: CellEvidence, P: RowPolar>(
    polar: &mut P,
    plan: (&Spans, &RowReach, &mut Vec<RowRun>),
    layer: &mut Layer<R>,
    heard: &mut [f32],
    evidence: &E,
    (axis, cone, fade): (f32, f32, f32),
) -> usize {
    let (spans, reach, runs) = plan;
    plan_runs(spans, reach, runs, polar);
    dispatch(layer, heard, evidence, axis, cone, (runs, fade), polar)
}

/// The runs of a reading: each row's span clipped to the reach and the grid and widened to whole
/// vectors, the cells of each made ready by `polar` ([`RowPolar::prepare`]). Worked out before
/// the pass over the rows ([`fuse_rows`]), so that the pass carries only the vector loop and
/// what each run needs (the clipping kept the loop's constants from staying in registers).
fn plan_runs<P: RowPolar>(spans: &Spans, reach: &RowReach, runs: &mut Vec<RowRun>, polar: &mut P) {
    let RowReach {
        cell: [cx, cy],
        radius,
        n,
        k,
        near: skipped,
    } = *reach;
    runs.clear();
    // The rows within the reach and the grid alone: the spans run to the longest reach.
    let first = spans.first_row.max(-k).max(-cy);
    let last = (spans.first_row + spans.rows.len() as i64 - 1)
        .min(k)
        .min(n - 1 - cy);
    if first > last {
        return;
    }
    let rows = &spans.rows[(first - spans.first_row) as usize..=(last - spans.first_row) as usize];
    for (oy, &[lo, hi]) in (first..).zip(rows) {
        let gy = cy + oy;
        // The reach's disc, conservatively: a cell centre lies within half a cell of its
        // offset, so the disc is widened by a cell.
        let near = (oy.abs() - 1).max(0) as f32;
        let half = ceil_of_non_negative(((k * k) as f32 - near * near).max(0.0).sqrt()) + 1;
        let lo = lo.max(-half).max(-cx);
        let hi = hi.min(half).min(n - 1 - cx);
        let (lo, hi) = outside_near(lo, hi, oy, skipped);
        if lo > hi {
            continue;
        }
        let (lo, hi) = whole_vectors(lo, hi, (-radius).max(-cx), radius.min(n - 1 - cx));
        let len = (hi - lo + 1) as usize;
        polar.prepare(oy, lo, len);
        runs.push(RowRun {
            row: gy as usize,
            oy,
            lo,
            first: (gy * n + cx + lo) as usize,
            len,
        });
    }
}

/// ⌈`x`⌉ of a non-negative `x` below 2⁵², without the C library's `ceil` (a call per row where
/// the CPU the build targets has no rounding instruction).
#[inline(always)]
fn ceil_of_non_negative(x: impl Into<f64>) -> i64 {
    let x: f64 = x.into();
    let t = x as i64;
    t + i64::from((t as f64) < x)
}

/// The columns `lo..=hi` of row `oy` less those whose cells lie wholly within `near` cells of the
/// sensor for a sensor anywhere in its cell, where that leaves one stretch (`lo > hi`: none): the
/// cells of an echo without free evidence lie about its range, not all along the cone. A cell
/// `(ox, oy)` lies within (|ox| + 1, |oy| + 1) of the sensor; when the near columns lie inside
/// the stretch, both sides of them stay (a run split in two would be widened into itself).
fn outside_near(lo: i64, hi: i64, oy: i64, near: i64) -> (i64, i64) {
    let room = near * near - (oy.abs() + 1) * (oy.abs() + 1);
    if room <= 0 {
        return (lo, hi);
    }
    // The columns |ox| ≤ w, with (w + 1)² < room.
    let w = ceil_of_non_negative((room as f64).sqrt()) - 2;
    if w < 0 || hi < -w || lo > w {
        (lo, hi)
    } else if lo >= -w {
        (lo.max(w + 1), hi)
    } else if hi <= w {
        (lo, hi.min(-w - 1))
    } else {
        (lo, hi)
    }
}

/// The fast kernel's pass: [`fuse_run`] along each run of the reading ([`plan_runs`]), the
/// cells' ranges, bearings and radial trust from `polar`.
#[inline(always)]
fn fuse_rows<R: Combine, E: CellEvidence, P: RowPolar>(
    layer: &mut Layer<R>,
    heard: &mut [f32],
    evidence: &E,
    axis: f32,
    cone: f32,
    (runs, fade): RowPass<'_>,
    polar: &P,
) -> usize {
    let mut updated = 0;
    for &RowRun {
        row,
        oy,
        lo,
        first,
        len,
    } in runs
    {
        let run = first..first + len;
        let (rule, cells) = layer.begin_run(run.clone());
        let changed = fuse_run(
            rule,
            evidence,
            axis,
            cone,
            cells,
            heard_run(heard, &run),
            polar.row(oy, lo, len, fade),
        );
        layer.end_row_run(row, run, changed);
        updated += changed;
    }
    updated
}

/// [`fuse_rows`] compiled for AVX2: 256-bit vectors where the portable build (x86-64's SSE2) has
/// 128-bit ones, and the row loop's constants set up once per reading rather than per row. The
/// vector width changes only how many cells one instruction handles, not the arithmetic (no fused
/// multiply-adds), so both versions give the same bits.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn fuse_rows_avx2<R: Combine, E: CellEvidence, P: RowPolar>(
    layer: &mut Layer<R>,
    heard: &mut [f32],
    evidence: &E,
    axis: f32,
    cone: f32,
    pass: RowPass<'_>,
    polar: &P,
) -> usize {
    fuse_rows(layer, heard, evidence, axis, cone, pass, polar)
}

/// [`fuse_rows`] compiled for AVX-512 (F and VL): 512-bit vectors and 32 vector registers where
/// AVX2 has 16 (its loop keeps constants on the stack). As for AVX2, no fused multiply-adds (Rust
/// does not contract), so the same bits as the other builds: the maps of every model and rule
/// were compared by fingerprint with the AVX2 build's (`docs/benchmarks.md`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl")]
fn fuse_rows_avx512<R: Combine, E: CellEvidence, P: RowPolar>(
    layer: &mut Layer<R>,
    heard: &mut [f32],
    evidence: &E,
    axis: f32,
    cone: f32,
    pass: RowPass<'_>,
    polar: &P,
) -> usize {
    fuse_rows(layer, heard, evidence, axis, cone, pass, polar)
}

/// The heard bearings of the cells of `run`: none when the model does not hear (`heard` empty).
#[inline(always)]
fn heard_run<'a>(heard: &'a mut [f32], run: &std::ops::Range<usize>) -> &'a mut [f32] {
    if heard.is_empty() {
        heard
    } else {
        &mut heard[run.clone()]
    }
}

/// Cells a vector instruction handles at once in the widest row loop (AVX2, f32).
const LANES: i64 = 8;

/// The run `lo..=hi` widened to a whole number of [`LANES`], as far as `min..=max` allows: the loop
/// then has no scalar remainder, which on rows a few dozen cells long costs more than the extra
/// cells. Those lie outside the cone or beyond the reach (the spans and the reach's disc hold
/// every cell inside), so they get no evidence and stay as they are.
fn whole_vectors(lo: i64, hi: i64, min: i64, max: i64) -> (i64, i64) {
    let pad = (LANES - (hi - lo + 1) % LANES) % LANES;
    let up = pad.min(max - hi);
    let down = (pad - up).min(lo - min);
    (lo - down, hi + up)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::GridConfig;
    use crate::geometry::GridGeometry;
    use crate::mapper::{Kernel, Mapper};
    use crate::model::{ModelConfig, ModelKind};
    use crate::observation::Observation;
    use crate::rule::{RuleConfig, RuleKind};
    use crate::test_strategies::between;
    use nalgebra::{Isometry2, Vector2};
    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn spans_hold_every_cell_of_the_cone_from_anywhere_in_the_cell() {
        // 10 cm cells and a 4 m reach (rows of 83 cells; the test is the same at 1 cm, only
        // slower); sensors on a corner, a centre, odd fractions of a cell and random positions;
        // every 11th direction key and the four axes; the cones of HIMM, the smooth model, the
        // beam, and of 90° and more (whole discs). Every cell whose range and bearing, as the
        // row loop computes them, pass the cone test at the key's own axis and at the ends of the
        // directions the key serves, lies in its row's span; and the spans are not much wider
        // than the cone.
        let geometry = GridGeometry::new(100, 0.1);
        let mut rng = ChaCha8Rng::seed_from_u64(29);
        let positions: Vec<Vector2<f32>> = [
            Vector2::new(0.0, 0.0),
            Vector2::new(0.05, 0.05),
            Vector2::new(0.0137, -0.0411),
            Vector2::new(-0.099, 0.0001),
            Vector2::new(0.049_999, -0.050_001),
        ]
        .into_iter()
        .chain(
            (0..8).map(|_| Vector2::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5))),
        )
        .collect();
        let keys: Vec<usize> = (0..ANGLE_KEYS)
            .step_by(11)
            .chain([0, ANGLE_KEYS / 4, ANGLE_KEYS / 2, 3 * ANGLE_KEYS / 4])
            .collect();
        let radius = 41;
        let (mut inside, mut spanned) = (0usize, 0usize);
        for cone_deg in [3.0f32, 14.0, 30.0, 89.9, 120.0] {
            for reach in [0.4f32, 4.0] {
                for &key in &keys {
                    let axis = key as f32 * ANGLE_STEP - PI;
                    let cone = cone_deg.to_radians();
                    let spans = Spans::new(radius, geometry.resolution(), axis, cone, reach);
                    for position in &positions {
                        let sensor = geometry.sensor_cell(*position);
                        for oy in -radius..=radius {
                            let row = usize::try_from(oy - spans.first_row)
                                .ok()
                                .and_then(|i| spans.rows.get(i));
                            let [lo, hi] = row.copied().unwrap_or([i64::MAX, i64::MIN]);
                            spanned += if lo <= hi { (hi - lo + 1) as usize } else { 0 };
                            for ox in -radius..=radius {
                                let (r, bearing) = sensor.polar(ox, oy);
                                let held = [-0.5f32, 0.0, 0.5].iter().any(|step| {
                                    let beam_axis = axis + step * ANGLE_STEP;
                                    off_axis(bearing, beam_axis).abs() <= cone
                                });
                                if r <= reach && held {
                                    inside += 1;
                                    assert!(
                                        (lo..=hi).contains(&ox),
                                        "{position:?} cone {cone_deg}° reach {reach} key {key}: \
                                         cell ({ox}, {oy}) outside {lo}..={hi}"
                                    );
                                }
                            }
                        }
                    }
                }
            }
        }
        assert!(inside > 100_000, "{inside}");
        assert!(
            spanned < 3 * inside,
            "{spanned} cells spanned for {inside} inside"
        );
    }

    #[test]
    fn spans_from_the_rows_the_sector_reaches_are_those_of_every_row() {
        // Every direction key, cones from a degree to more than a half turn, reaches from a
        // cell to past the square, radii of the grids in use: computing only the rows the
        // sector reaches into leaves out rows with no span, nothing else.
        let mut checked = 0;
        for (radius, resolution) in [(200i64, 0.02f32), (400, 0.01), (41, 0.1)] {
            for cone_deg in [1.0f32, 7.0, 15.0, 30.0, 89.0, 91.0, 200.0] {
                for reach in [0.015f32, 0.5, 4.0, 9.0] {
                    for key in (0..ANGLE_KEYS).step_by(7).chain([0, 360, 720, 1080]) {
                        let axis = key as f32 * ANGLE_STEP - PI;
                        let cone = cone_deg.to_radians();
                        let spans = Spans::new(radius, resolution, axis, cone, reach);
                        let sector = Sector::new(axis, cone_margin(cone), reach / resolution);
                        let every = Spans::over_rows(radius, &sector, -radius..=radius);
                        assert_eq!(
                            (spans.first_row, &spans.rows),
                            (every.first_row, &every.rows),
                            "radius {radius} cone {cone_deg}° reach {reach} key {key}"
                        );
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked > 5000, "{checked}");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(96))]
        /// Every path of the cone kernel (ranges and bearings computed in the loop, or loaded from
        /// the stencil of a parked sensor) gives the whole-grid reference's map to the last bit:
        /// random poses (on and off the grid, any heading), grid centres, beam widths, angles,
        /// ranges, models and rules.
        #[test]
        fn every_path_agrees_with_the_reference_to_the_last_bit(
            model in 0..ModelKind::ALL.len(),
            rule in 0..RuleKind::ALL.len(),
            centre in (between(-0.2, 0.2), between(-0.2, 0.2)),
            pose in (between(-2.5, 2.5), between(-2.5, 2.5), between(-3.2, 3.2)),
            half_angle_deg in between(5.0, 45.0),
            parked in any::<bool>(),
            readings in prop::collection::vec(
                (
                    between(-180.0, 180.0),
                    prop::option::of(between(0.05, 4.3)),
                    (between(-0.2, 0.2), between(-0.2, 0.2)),
                ),
                1..8,
            ),
        ) {
            let config = FusionConfig {
                grid: GridConfig {
                    cells: 90,
                    resolution_m: 0.05,
                    centre_x_m: centre.0,
                    centre_y_m: centre.1,
                },
                model: ModelConfig::default_for(ModelKind::ALL[model]),
                rule: RuleConfig::default_for(RuleKind::ALL[rule]),
                ..FusionConfig::default()
            };
            let mut fast = Mapper::new(config).unwrap();
            let mut reference = Mapper::new(config).unwrap();
            // Parked: enough readings from the first pose for the stencil; else each from its own.
            let count = if parked { PARKED_AFTER as usize + readings.len() } else { readings.len() };
            for &(angle_deg, range_m, moved) in readings.iter().cycle().take(count) {
                let moved = if parked { (0.0, 0.0) } else { moved };
                let obs = Observation {
                    pose: Isometry2::new(Vector2::new(pose.0 + moved.0, pose.1 + moved.1), pose.2),
                    angle_rad: angle_deg.to_radians(),
                    range_m,
                    rejected_echo_m: None,
                    beam_half_angle_rad: half_angle_deg.to_radians(),
                    max_range_m: 4.0,
                };
                let a = fast.update_with(&obs, Kernel::Cone).unwrap();
                let b = reference.update_with(&obs, Kernel::WholeGrid).unwrap();
                prop_assert_eq!(a, b);
            }
            let n = config.grid.cells as usize;
            for y in 0..n {
                for x in 0..n {
                    let bits = |m: &Mapper| m.grid().probability(x, y).map(f32::to_bits);
                    prop_assert_eq!(bits(&fast), bits(&reference), "cell ({}, {})", x, y);
                }
            }
        }
    }

    #[test]
    fn columns_left_out_as_near_hold_only_cells_nearer_from_anywhere_in_the_cell() {
        // 1 cm cells; sensors on a corner, a centre and random positions in their cell; every
        // row and every stretch of columns around the sensor's cell. A column left out lies
        // nearer than `near` cells, as the row loop computes the range; the stretch left is one.
        let resolution = 0.01;
        let geometry = GridGeometry::new(200, resolution);
        let mut rng = ChaCha8Rng::seed_from_u64(29);
        let positions: Vec<Vector2<f32>> =
            [Vector2::new(0.0, 0.0), Vector2::new(0.005, 0.005)]
                .into_iter()
                .chain((0..6).map(|_| {
                    Vector2::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5))
                }))
                .collect();
        let mut left_out = 0usize;
        for near in [0i64, 1, 2, 5, 37] {
            for position in &positions {
                let sensor = geometry.sensor_cell(*position);
                for oy in -40i64..=40 {
                    for (lo, hi) in [(-45i64, 45i64), (-45, -3), (2, 45), (-10, 0), (0, 40)] {
                        let (a, b) = outside_near(lo, hi, oy, near);
                        assert!(a > b || (lo <= a && b <= hi), "{near} {oy}: {a}..={b}");
                        for ox in lo..=hi {
                            if a <= b && (a..=b).contains(&ox) {
                                continue;
                            }
                            left_out += 1;
                            let (r, _) = sensor.polar(ox, oy);
                            assert!(
                                r < near as f32 * resolution,
                                "near {near}: cell ({ox}, {oy}) at {r} m left out"
                            );
                        }
                    }
                }
            }
        }
        assert!(left_out > 10_000, "{left_out}");
    }

    #[test]
    fn runs_are_widened_to_whole_vectors_within_bounds() {
        // Room to the right: all the padding goes there.
        assert_eq!(whole_vectors(0, 0, -10, 10), (0, 7));
        // A multiple already: unchanged.
        assert_eq!(whole_vectors(-3, 4, -10, 10), (-3, 4));
        assert_eq!(whole_vectors(0, 15, -10, 20), (0, 15));
        // One cell of room to the right, the rest to the left.
        assert_eq!(whole_vectors(5, 9, -10, 10), (3, 10));
        // No room at all: as it was.
        assert_eq!(whole_vectors(0, 2, 0, 2), (0, 2));
        // Some room both sides, not enough: as wide as allowed.
        assert_eq!(whole_vectors(1, 2, 0, 3), (0, 3));
    }
}
