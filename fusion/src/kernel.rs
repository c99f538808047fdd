//! The update of the grid by one reading: the fast cone kernel, and what every kernel shares.
//!
//! The paper's arrays (GridAngles, GridLength, AngleInside; see [`crate::reference`]) imply a pass
//! over the whole grid per reading, though a 60° cone to 4 m covers a sixth of the disc around the
//! sensor and far less of a large grid. The fast kernel visits only the cells of the cone:
//!
//! - **Stencil.** The range and bearing of every cell within reach, relative to the sensor's cell,
//!   computed once (the paper's GridLength and GridAngles, cut to the reach instead of the grid).
//!   It depends only on where the sensor sits inside its cell, so it serves every reading taken
//!   from there, and, for a sensor parked elsewhere, is rebuilt once it has stayed put for
//!   [`REBUILD_AFTER`] readings.
//! - **Row spans per beam angle.** The stepper's angles are discrete (reading centres every 6°,
//!   pings every 1.5°), so per beam direction, quantised to [`ANGLE_STEP`], the cache keeps for
//!   each stencil row the first and last column inside the cone (widened by half a step and a
//!   rounding margin), worked out on first use by testing only the cells near the ends of each
//!   row's stretch across the cone (a new direction costs a few cells per row, not the whole
//!   stencil: the first sweep of a new mapper at 1 cm cells no longer costs a scan of 645 k cells
//!   per direction). A reading clips those spans to its own reach and
//!   to the grid and runs along contiguous row slices of cells and stencil values: no gathers, no
//!   branches in the loop (models and rules are written with selects), so it vectorises; and the
//!   exact cone test in the loop makes the result independent of the quantisation. The cone is the
//!   beam's, narrowed to the rule's (HIMM updates only near the axis) and to the angles at which
//!   the model can give evidence at all (the smooth model's profiles end inside the beam). Each
//!   row's run is widened to whole vectors where the stencil and the grid allow (the extra cells
//!   lie outside the cone or the reach and get no evidence), so the scalar remainder rarely runs.
//!   Where the CPU has AVX2 (detected at run time) the row loop is compiled a second time for it,
//!   with vectors twice as wide as the portable build's SSE2, and where it has AVX-512 (F and VL)
//!   a third time: 512-bit vectors and twice as many vector registers (on an Intel Xeon 1.2–1.3×
//!   faster than the AVX2 build, `docs/benchmarks.md`).
//! - **Bounding-box fallback.** A moving robot rarely repeats a sub-cell position, and a stencil
//!   per pose would cost more than it saves, so readings from positions other than the stencil's
//!   visit the bounding box of their cone instead, computing each cell's range and bearing (a
//!   square root and an arctangent), still touching a fraction of the grid.
//!
//! No path allocates once warm: the stencil and the spans of an angle are built the first time
//! they are needed and kept.
//!
//! Every path computes a cell's range and bearing with the same function and fuses it with
//! [`fuse_run`], so they agree with the reference to the last bit.

use std::f32::consts::{FRAC_PI_2, PI};

use crate::config::FusionConfig;
use crate::geometry::{GridGeometry, SensorCell, off_axis};
use crate::grid::Layer;
use crate::model::CellEvidence;
use crate::observation::{Beam, Limits};
use crate::rule::{Combine, Domain};

/// Quantum of the beam directions the row spans are cached for: 0.25°, a sixth of a stepper step,
/// so the spans are only 0.125° wider each side than the cone itself.
pub(crate) const ANGLE_STEP: f32 = PI / 720.0;
const ANGLE_KEYS: usize = 1440;
/// Readings in a row from one new sub-cell position before the stencil moves there.
pub(crate) const REBUILD_AFTER: u32 = 16;

/// A reading's evidence for the cell at range `r` and world bearing `bearing`, in the rule's
/// domain; NaN (no evidence) outside the rule's cone of `cone` radians around `axis`.
#[inline(always)]
pub(crate) fn cell_evidence<R: Combine, E: CellEvidence>(
    evidence: &E,
    axis: f32,
    cone: f32,
    r: f32,
    bearing: f32,
) -> f32 {
    let alpha = off_axis(bearing, axis);
    let e = match R::DOMAIN {
        Domain::Probability => evidence.probability(r, alpha),
        Domain::LogOdds => evidence.log_odds(r, alpha),
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
    r: f32,
    bearing: f32,
    heard: &mut f32,
) -> f32 {
    let alpha = off_axis(bearing, axis);
    let inside = alpha.abs() <= cone;
    let mut h = *heard;
    let e = match R::DOMAIN {
        Domain::Probability => evidence.heard_probability(r, alpha, bearing, &mut h),
        Domain::LogOdds => evidence.heard_log_odds(r, alpha, bearing, &mut h),
    };
    *heard = if inside { h } else { *heard };
    if inside { e } else { f32::NAN }
}

/// Fuses a reading into a run of cells whose (range, bearing) `polar` yields in order; returns how
/// many cells it updated. `heard` holds the run's bearings each cell was last heard occupied from
/// if the model hears ([`CellEvidence::HEARD`]), and is empty otherwise.
#[inline(always)]
pub(crate) fn fuse_run<R: Combine, E: CellEvidence>(
    rule: &R,
    evidence: &E,
    axis: f32,
    cone: f32,
    cells: &mut [R::Cell],
    heard: &mut [f32],
    polar: impl Iterator<Item = (f32, f32)>,
) -> usize {
    // Counted in u32, the width of the cells' lanes: a usize counter would make the vectoriser
    // pair each f32 lane with a 64-bit one and halve the vector width. A run is at most a grid
    // row (≤ `MAX_CELLS_PER_SIDE` cells), so it cannot overflow.
    let mut updated = 0u32;
    if E::HEARD {
        for ((cell, heard), (r, bearing)) in cells.iter_mut().zip(heard).zip(polar) {
            let e = heard_cell_evidence::<R, E>(evidence, axis, cone, r, bearing, heard);
            updated += u32::from(rule.fuse(cell, e));
        }
    } else {
        for (cell, (r, bearing)) in cells.iter_mut().zip(polar) {
            let e = cell_evidence::<R, E>(evidence, axis, cone, r, bearing);
            updated += u32::from(rule.fuse(cell, e));
        }
    }
    updated as usize
}

/// Range and bearing of the cells around a sensor's cell, row-major, `side` = 2·radius + 1.
struct Stencil {
    fraction: [u32; 2],
    /// From the sensor to the centre of its cell, cells ([`SensorCell`]).
    to_centre: [f32; 2],
    resolution: f32,
    radius: i64,
    side: usize,
    range: Vec<f32>,
    bearing: Vec<f32>,
}

impl Stencil {
    fn new(sensor: &SensorCell, radius: i64) -> Self {
        let side = (2 * radius + 1) as usize;
        let mut range = Vec::with_capacity(side * side);
        let mut bearing = Vec::with_capacity(side * side);
        for oy in -radius..=radius {
            for ox in -radius..=radius {
                let (r, a) = sensor.polar(ox, oy);
                range.push(r);
                bearing.push(a);
            }
        }
        Self {
            fraction: sensor.fraction_bits(),
            to_centre: sensor.to_centre,
            resolution: sensor.resolution(),
            radius,
            side,
            range,
            bearing,
        }
    }

    fn at(&self, ox: i64, oy: i64) -> usize {
        (oy + self.radius) as usize * self.side + (ox + self.radius) as usize
    }
}

/// For one beam direction, per stencil row from `first_row` on, the first and last column offset
/// of the cells that can lie in the cone (`lo > hi`: none).
struct Spans {
    first_row: i64,
    rows: Vec<[i64; 2]>,
}

impl Spans {
    /// The spans of the cone of half-angle `cone` around `axis`, up to `reach`: per row, the first
    /// and last cell for which the stencil's own range and bearing pass the cone test (the same
    /// test the eager scan of every stencil cell made, so the spans are the same). Only a few
    /// cells per row are tested: those near the ends of the row's stretch across the cone, worked
    /// out in f64 for a cone a little wider and longer than the test's (by far more than the f32
    /// values' rounding), scanning inwards from each end to the first cell that passes.
    fn new(stencil: &Stencil, axis: f32, cone: f32, reach: f32) -> Self {
        let window = RowWindows::new(stencil, axis, cone_margin(cone), reach);
        Self::from_rows(stencil, axis, cone, reach, |oy, inside| {
            let [from, to] = window.at(oy);
            match (from..=to).find(|&ox| inside(ox)) {
                Some(lo) => [lo, (lo..=to).rev().find(|&ox| inside(ox)).unwrap_or(lo)],
                None => [i64::MAX, i64::MIN],
            }
        })
    }

    /// The spans whose row `oy` is `span(oy, inside)`, where `inside(ox)` is the cone test of the
    /// cell (`ox`, `oy`), from the first row with a cell on (so `first_row` is that row's).
    fn from_rows(
        stencil: &Stencil,
        axis: f32,
        cone: f32,
        reach: f32,
        span: impl Fn(i64, &dyn Fn(i64) -> bool) -> [i64; 2],
    ) -> Self {
        let margin = cone_margin(cone);
        let k = stencil.radius;
        let mut first_row = None;
        let mut rows = Vec::new();
        for oy in -k..=k {
            let inside = |ox: i64| {
                let i = stencil.at(ox, oy);
                stencil.range[i] <= reach && off_axis(stencil.bearing[i], axis).abs() <= margin
            };
            let span = span(oy, &inside);
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

/// Where along each stencil row a cone can hold cells: the row's stretch across a sector a little
/// wider and longer than the cone, in column offsets, clipped to the stencil.
struct RowWindows {
    radius: i64,
    to_centre: [f64; 2],
    /// The sector's radius, cells.
    reach: f64,
    /// Its two edges, as unit vectors: the sector is the set left of `edges[0]` and right of
    /// `edges[1]` (< 180° wide), or `None` for a sector of 180° or more (then the window is the
    /// whole row within reach).
    edges: Option<[[f64; 2]; 2]>,
}

/// How much wider than the cone the sector is, radians: far more than the f32 bearing's rounding
/// (about 1e-7 rad), so no cell the cone test passes lies outside it.
const WINDOW_ANGLE_SLACK: f64 = 1e-5;
/// How much longer, cells (the test compares ranges in f32 metres).
const WINDOW_REACH_SLACK: f64 = 2.0;
/// Cells added at each end of a row's window for rounding the stretch to columns.
const WINDOW_CELL_SLACK: i64 = 2;

impl RowWindows {
    fn new(stencil: &Stencil, axis: f32, margin: f32, reach: f32) -> Self {
        let half = f64::from(margin) + WINDOW_ANGLE_SLACK;
        let axis = f64::from(axis);
        let edge = |a: f64| [a.cos(), a.sin()];
        Self {
            radius: stencil.radius,
            to_centre: stencil.to_centre.map(f64::from),
            reach: f64::from(reach) / f64::from(stencil.resolution) + WINDOW_REACH_SLACK,
            edges: (half < std::f64::consts::FRAC_PI_2 - 1e-6)
                .then(|| [edge(axis - half), edge(axis + half)]),
        }
    }

    /// The window of row `oy`: columns `[from, to]`, empty if `from > to`.
    fn at(&self, oy: i64) -> [i64; 2] {
        let dy = oy as f64 + self.to_centre[1];
        let chord = self.reach * self.reach - dy * dy;
        if chord < 0.0 {
            return [1, 0];
        }
        let chord = chord.sqrt();
        // The stretch in x (relative to the sensor) of the sector's points on the line y = dy.
        let (mut lo, mut hi) = (-chord, chord);
        if let Some([d1, d2]) = self.edges {
            // Left of edge 1: d1.x·dy − d1.y·x ≥ 0; right of edge 2: x·d2.y − dy·d2.x ≥ 0.
            for (normal, offset) in [(-d1[1], d1[0] * dy), (d2[1], -dy * d2[0])] {
                // normal·x + offset ≥ 0
                if normal > 0.0 {
                    lo = lo.max(-offset / normal);
                } else if normal < 0.0 {
                    hi = hi.min(-offset / normal);
                } else if offset < 0.0 {
                    return [1, 0];
                }
            }
        }
        let from = (lo - self.to_centre[0]).ceil() as i64 - WINDOW_CELL_SLACK;
        let to = (hi - self.to_centre[0]).floor() as i64 + WINDOW_CELL_SLACK;
        [from.max(-self.radius), to.min(self.radius)]
    }
}

/// A stencil and the row spans worked out on it so far, per angle key.
struct Prepared {
    stencil: Stencil,
    spans: Vec<Option<Box<Spans>>>,
}

/// The fast kernel's caches for one grid geometry, one reach and one rule.
pub(crate) struct ConeCache {
    radius: i64,
    reach: f32,
    /// The model's angular reach (see [`CellEvidence::half_angle`]).
    model_half_angle: f32,
    limits: Limits,
    prepared: Option<Prepared>,
    /// A sub-cell position other than the stencil's, and how many readings in a row came from it.
    candidate: Option<([u32; 2], u32)>,
}

impl ConeCache {
    pub fn new(config: &FusionConfig) -> Self {
        Self {
            radius: (config.stencil_side() as i64 - 1) / 2,
            reach: config.model.max_reach(config.sensor.max_range_m),
            model_half_angle: config.model.max_half_angle(),
            limits: config.sensor.limits(),
            prepared: None,
            candidate: None,
        }
    }

    /// The stencil for a sensor at `sensor`, built or moved there when due; `None` while the
    /// sensor is elsewhere.
    fn prepared_for(&mut self, sensor: &SensorCell) -> Option<&mut Prepared> {
        let fraction = sensor.fraction_bits();
        let current = self.prepared.as_ref().map(|p| p.stencil.fraction);
        if current.is_some_and(|f| f != fraction) {
            let seen = match self.candidate {
                Some((f, n)) if f == fraction => n + 1,
                _ => 1,
            };
            self.candidate = Some((fraction, seen));
            if seen < REBUILD_AFTER {
                return None;
            }
        }
        if current != Some(fraction) {
            self.candidate = None;
            self.prepared = Some(Prepared {
                stencil: Stencil::new(sensor, self.radius),
                spans: (0..ANGLE_KEYS).map(|_| None).collect(),
            });
        }
        self.prepared.as_mut()
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
        let (max_reach, envelope) = (
            self.reach,
            layer
                .rule
                .cone_half_angle(self.limits.half_angle)
                .min(self.model_half_angle),
        );
        let Some(Prepared { stencil, spans }) = self.prepared_for(&sensor) else {
            return bounding_box(layer, heard, geometry, &sensor, beam, cone, reach, evidence);
        };
        let key = ((beam.axis + PI) / ANGLE_STEP).round() as usize % ANGLE_KEYS;
        let spans = spans[key].get_or_insert_with(|| {
            let axis = key as f32 * ANGLE_STEP - PI;
            Box::new(Spans::new(stencil, axis, envelope, max_reach))
        });

        let pass = RowPass {
            stencil,
            spans,
            n: geometry.cells_per_side() as i64,
            sensor: sensor.cell,
            k: (reach / geometry.resolution()).ceil() as i64 + 1,
        };
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512vl")
        {
            // SAFETY: the CPU has AVX-512F and VL, checked just above.
            return unsafe { fuse_rows_avx512(layer, heard, evidence, beam.axis, cone, &pass) };
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            return unsafe { fuse_rows_avx2(layer, heard, evidence, beam.axis, cone, &pass) };
        }
        fuse_rows(layer, heard, evidence, beam.axis, cone, &pass)
    }
}

/// What a reading's pass over the stencil rows needs besides the layer and the evidence.
struct RowPass<'a> {
    stencil: &'a Stencil,
    spans: &'a Spans,
    /// Cells per side of the grid.
    n: i64,
    /// The sensor's cell.
    sensor: [i64; 2],
    /// The reading's reach in cells, plus one.
    k: i64,
}

/// The fast kernel's pass: [`fuse_run`] along each stencil row's span, clipped to the reach and
/// the grid.
#[inline(always)]
fn fuse_rows<R: Combine, E: CellEvidence>(
    layer: &mut Layer<R>,
    heard: &mut [f32],
    evidence: &E,
    axis: f32,
    cone: f32,
    pass: &RowPass<'_>,
) -> usize {
    let RowPass {
        stencil,
        spans,
        n,
        sensor: [cx, cy],
        k,
    } = *pass;
    let mut updated = 0;
    for (row, &[lo, hi]) in (spans.first_row..).zip(&spans.rows) {
        let gy = cy + row;
        if row.abs() > k || !(0..n).contains(&gy) {
            continue;
        }
        // The reach's disc, conservatively: a cell centre lies within half a cell of its
        // offset, so the disc is widened by a cell.
        let near = (row.abs() - 1).max(0) as f32;
        let half = ((k * k) as f32 - near * near).max(0.0).sqrt().ceil() as i64 + 1;
        let lo = lo.max(-half).max(-cx);
        let hi = hi.min(half).min(n - 1 - cx);
        if lo > hi {
            continue;
        }
        let (lo, hi) = whole_vectors(
            lo,
            hi,
            (-stencil.radius).max(-cx),
            stencil.radius.min(n - 1 - cx),
        );
        let first = (gy * n + cx + lo) as usize;
        let len = (hi - lo + 1) as usize;
        let s = stencil.at(lo, row);
        let polar = stencil.range[s..s + len]
            .iter()
            .copied()
            .zip(stencil.bearing[s..s + len].iter().copied());
        let run = first..first + len;
        let (rule, cells) = layer.begin_run(run.clone());
        let changed = fuse_run(
            rule,
            evidence,
            axis,
            cone,
            cells,
            heard_run(heard, &run),
            polar,
        );
        layer.end_run(run, changed);
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
fn fuse_rows_avx2<R: Combine, E: CellEvidence>(
    layer: &mut Layer<R>,
    heard: &mut [f32],
    evidence: &E,
    axis: f32,
    cone: f32,
    pass: &RowPass<'_>,
) -> usize {
    fuse_rows(layer, heard, evidence, axis, cone, pass)
}

/// [`fuse_rows`] compiled for AVX-512 (F and VL): 512-bit vectors and 32 vector registers where
/// AVX2 has 16 (its loop keeps constants on the stack). As for AVX2, no fused multiply-adds (Rust
/// does not contract), so the same bits as the other builds: the maps of every model and rule
/// were compared by fingerprint with the AVX2 build's (`docs/benchmarks.md`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl")]
fn fuse_rows_avx512<R: Combine, E: CellEvidence>(
    layer: &mut Layer<R>,
    heard: &mut [f32],
    evidence: &E,
    axis: f32,
    cone: f32,
    pass: &RowPass<'_>,
) -> usize {
    fuse_rows(layer, heard, evidence, axis, cone, pass)
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

/// The fallback: every cell of the bounding box of the cone, up to `reach`.
#[allow(clippy::too_many_arguments)]
fn bounding_box<R: Combine, E: CellEvidence>(
    layer: &mut Layer<R>,
    heard: &mut [f32],
    geometry: &GridGeometry,
    sensor: &SensorCell,
    beam: &Beam,
    cone: f32,
    reach: f32,
    evidence: &E,
) -> usize {
    // The sector's extreme points: its apex, the ends of its arc, and the arc's crossings of the
    // axes' directions.
    let mut lo = [0.0f32; 2];
    let mut hi = [0.0f32; 2];
    let mut include = |angle: f32| {
        let (s, c) = angle.sin_cos();
        for (i, v) in [c * reach, s * reach].into_iter().enumerate() {
            lo[i] = lo[i].min(v);
            hi[i] = hi[i].max(v);
        }
    };
    include(beam.axis - cone);
    include(beam.axis + cone);
    for quarter in -2..=2 {
        let angle = quarter as f32 * FRAC_PI_2;
        if off_axis(angle, beam.axis).abs() <= cone {
            include(angle);
        }
    }
    let n = geometry.cells_per_side() as i64;
    let res = geometry.resolution();
    // Offsets from the sensor's cell, a cell wider each side for the sub-cell position.
    let span = |axis: usize| {
        let c = sensor.cell[axis];
        let from = ((lo[axis] / res).floor() as i64 - 1).max(-c);
        let to = ((hi[axis] / res).ceil() as i64 + 1).min(n - 1 - c);
        (from, to)
    };
    let ((x0, x1), (y0, y1)) = (span(0), span(1));
    if x0 > x1 {
        return 0;
    }
    let mut updated = 0;
    for oy in y0..=y1 {
        let first = ((sensor.cell[1] + oy) * n + sensor.cell[0] + x0) as usize;
        let len = (x1 - x0 + 1) as usize;
        let run = first..first + len;
        let (rule, cells) = layer.begin_run(run.clone());
        let polar = (x0..=x1).map(|ox| sensor.polar(ox, oy));
        let heard = heard_run(heard, &run);
        let changed = fuse_run(rule, evidence, beam.axis, cone, cells, heard, polar);
        layer.end_run(run, changed);
        updated += changed;
    }
    updated
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::GridGeometry;
    use nalgebra::Vector2;

    /// The spans as first written: every stencil cell tested.
    fn eager_spans(stencil: &Stencil, axis: f32, cone: f32, reach: f32) -> Spans {
        let k = stencil.radius;
        Spans::from_rows(stencil, axis, cone, reach, |_, inside| {
            let mut span = [i64::MAX, i64::MIN];
            for ox in (-k..=k).filter(|&ox| inside(ox)) {
                span = [span[0].min(ox), span[1].max(ox)];
            }
            span
        })
    }

    #[test]
    fn spans_equal_those_of_a_scan_of_the_whole_stencil() {
        // 10 cm cells and a 4 m reach (a stencil of 83² cells; the test is the same at 1 cm, only
        // slower); sensors on a corner, a centre and odd fractions of a cell; every 29th
        // direction key and the four axes; the cones of HIMM, the smooth model, the beam, and
        // one of 90° and more (where the windows give up and scan whole rows).
        let geometry = GridGeometry::new(100, 0.1);
        let positions = [
            Vector2::new(0.0, 0.0),
            Vector2::new(0.05, 0.05),
            Vector2::new(0.0137, -0.0411),
            Vector2::new(-0.099, 0.0001),
        ];
        let keys = (0..ANGLE_KEYS).step_by(11).chain([
            0,
            ANGLE_KEYS / 4,
            ANGLE_KEYS / 2,
            3 * ANGLE_KEYS / 4,
        ]);
        let keys: Vec<usize> = keys.collect();
        let mut compared = 0;
        for position in positions {
            let stencil = Stencil::new(&geometry.sensor_cell(position), 41);
            for cone_deg in [3.0f32, 14.0, 30.0, 89.9, 120.0] {
                for reach in [0.4f32, 4.0] {
                    for &key in &keys {
                        let axis = key as f32 * ANGLE_STEP - PI;
                        let cone = cone_deg.to_radians();
                        let lazy = Spans::new(&stencil, axis, cone, reach);
                        let eager = eager_spans(&stencil, axis, cone, reach);
                        assert_eq!(
                            (lazy.first_row, &lazy.rows),
                            (eager.first_row, &eager.rows),
                            "{position:?} cone {cone_deg}° reach {reach} key {key}"
                        );
                        compared += usize::from(!eager.rows.is_empty());
                    }
                }
            }
        }
        assert!(compared > 500, "{compared}");
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
