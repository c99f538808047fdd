//! The probability grid: per-cell state in the rule's own representation, one way to read it.

use std::collections::VecDeque;
use std::fmt;
use std::ops::Range;
use std::sync::atomic::{AtomicU64, Ordering};

use nalgebra::Vector2;
use sonar_common::ipc::CELL_UNKNOWN;

pub use crate::encoding::CONFIDENT_PROBABILITY;
use crate::encoding::{CellClass, KeyEncoder};
use crate::geometry::{GridGeometry, walk};
use crate::rule::{
    BayesRule, Combine, DempsterShaferRule, HimmRule, LogOddsRule, RuleConfig, RuleKind,
};
use crate::state::{SavedCells, StateError, check_len};

/// The cells of one rule, with the rule's parameters, and the cells in the snapshot encoding with
/// their counts ([`crate::encoding`]). The encoding lags behind the cells: a kernel's runs are
/// only noted as dirty, per row the span from the first to the last cell fused since the last
/// flush, and [`Self::flush`] re-encodes those spans when a snapshot is asked for (at most one
/// span per row: the bookkeeping is bounded by the grid, however long nothing asks).
/// Re-encoding each run as it was fused cost more than fusing it (a cell is touched by many
/// readings between two snapshots); once per snapshot, a cell costs one encoding however often it
/// was fused. The class a flush keeps per cell also says whether the cell is confidently occupied,
/// so the cells the features need are found without a probability per cell.
///
/// Each flush that re-encodes anything starts a new *generation* of the bytes and logs the spans
/// it re-encoded; the last [`RECENT_FLUSHES`] logs are kept, so a copy of the bytes as of a recent
/// generation (a snapshot's sample that the IPC hands back for reuse) is brought up to date by
/// copying those spans alone ([`Self::copy_changed_into`]).
pub(crate) struct Layer<R: Combine> {
    pub rule: R,
    cells: Vec<R::Cell>,
    encoder: KeyEncoder,
    bytes: Vec<u8>,
    /// Each cell's [`CellClass`] as of the last flush, so a flush can move it between the counts.
    classes: Vec<u8>,
    /// Cells per [`CellClass`], as of the last flush.
    tally: [u32; CellClass::COUNT],
    /// Cells per row.
    row_len: usize,
    /// Per row, the span of its cells (offsets within the row) that runs fused since the last
    /// flush lie in; empty for a row none touched.
    dirty_spans: Vec<Range<u32>>,
    /// The rows with a non-empty span, in the order first touched.
    dirty_rows: Vec<u32>,
    /// Flushes that re-encoded cells, and whole re-encodings, so far.
    generation: u64,
    /// The spans the last flushes re-encoded, oldest first, of consecutive generations ending at
    /// `generation` (empty after a whole re-encoding, which no span list stands for).
    recent: VecDeque<FlushLog>,
}

/// How many flushes' spans a [`Layer`] keeps for bringing older copies up to date: more than the
/// snapshots the grid's IPC service keeps in flight (`sonar_common::ipc::GRID_SEGMENT_SLOTS`), so a
/// reused sample is normally updated span by span; an older one is copied whole.
pub(crate) const RECENT_FLUSHES: usize = 32;

/// What one flush re-encoded: per row touched, the span of its cells (offsets within the row).
struct FlushLog {
    generation: u64,
    spans: Vec<(u32, Range<u32>)>,
}

impl<R: Combine> Layer<R> {
    /// `rows` rows of `row_len` cells.
    fn new(rule: R, row_len: usize, rows: usize) -> Self {
        let len = row_len * rows;
        let mut tally = [0; CellClass::COUNT];
        tally[CellClass::Unknown as usize] = len as u32;
        Self {
            encoder: KeyEncoder::new(&rule),
            rule,
            cells: vec![R::UNKNOWN; len],
            bytes: vec![CELL_UNKNOWN; len],
            classes: vec![CellClass::Unknown as u8; len],
            tally,
            row_len,
            dirty_spans: vec![0..0; rows],
            dirty_rows: Vec::new(),
            generation: 0,
            recent: VecDeque::with_capacity(RECENT_FLUSHES),
        }
    }

    /// The cells of `run`, for a kernel to fuse into; hand the run back to [`Self::end_row_run`] with
    /// how many cells changed. (Two calls rather than one taking the kernel as a closure: a
    /// closure is not inlined into the kernel's AVX2 build, and the kernel's loop would lose its
    /// vectors.)
    #[inline(always)]
    pub fn begin_run(&mut self, run: Range<usize>) -> (&R, &mut [R::Cell]) {
        (&self.rule, &mut self.cells[run])
    }

    /// Notes `run` for the next [`Self::flush`] if the kernel changed any of its cells: widens
    /// the dirty span of each row it covers. The tests' random runs may span rows; the cone
    /// kernel's lie within one, and it calls [`Self::end_row_run`].
    #[cfg(test)]
    pub fn end_run(&mut self, run: Range<usize>, updated: usize) {
        if updated > 0 {
            self.note_dirty(run);
        }
    }

    /// Notes `run`, within row `row`, for the next [`Self::flush`] if the kernel changed any of
    /// its cells: widens the row's dirty span (the kernel knows the row: no division to find it).
    #[inline(always)]
    pub fn end_row_run(&mut self, row: usize, run: Range<usize>, updated: usize) {
        if updated > 0 {
            let row_start = row * self.row_len;
            self.note_dirty_in_row(row, run.start - row_start, run.end - row_start);
        }
    }

    #[cfg(test)]
    fn note_dirty(&mut self, run: Range<usize>) {
        let mut start = run.start;
        while start < run.end {
            let row = start / self.row_len;
            let row_start = row * self.row_len;
            let end = run.end.min(row_start + self.row_len);
            self.note_dirty_in_row(row, start - row_start, end - row_start);
            start = end;
        }
    }

    /// Widens the dirty span of row `row` to hold its cells `a..b`.
    fn note_dirty_in_row(&mut self, row: usize, a: usize, b: usize) {
        // Offsets within a row fit: a row is a side of the grid.
        let (a, b) = (a as u32, b as u32);
        let span = &mut self.dirty_spans[row];
        if Range::is_empty(span) {
            self.dirty_rows.push(row as u32);
            *span = a..b;
        } else {
            *span = span.start.min(a)..span.end.max(b);
        }
    }

    /// Brings the bytes and counts up to date with the cells: re-encodes each row's dirty span,
    /// and logs the spans as a new generation if there were any.
    fn flush(&mut self) {
        if self.dirty_rows.is_empty() {
            return;
        }
        self.generation += 1;
        // The oldest log's allocation is reused once the ring is full.
        let mut log = match self.recent.len() {
            RECENT_FLUSHES => self.recent.pop_front().map(|l| l.spans),
            _ => None,
        }
        .unwrap_or_default();
        log.clear();
        let mut rows = std::mem::take(&mut self.dirty_rows);
        for row in rows.drain(..) {
            let span = std::mem::replace(&mut self.dirty_spans[row as usize], 0..0);
            let row_start = row as usize * self.row_len;
            self.encode_run(row_start + span.start as usize..row_start + span.end as usize);
            log.push((row, span));
        }
        // The allocation is kept for the next runs.
        self.dirty_rows = rows;
        self.recent.push_back(FlushLog {
            generation: self.generation,
            spans: log,
        });
    }

    /// Brings `out`, a copy of the bytes as of generation `held` (`None`: anything, or nothing
    /// yet), up to date: copies only the spans re-encoded since then if the logs reach back
    /// that far, else every byte. Returns the counts and the generation `out` now holds.
    ///
    /// # Panics
    /// If `out` does not hold one byte per cell.
    fn copy_changed_into(&mut self, out: &mut [u8], held: Option<u64>) -> (CellCounts, u64) {
        assert_eq!(out.len(), self.bytes.len(), "one byte per cell");
        self.flush();
        // The logs cover generations `recent.front()`..=`generation`, consecutively.
        let first_logged = self
            .recent
            .front()
            .map_or(self.generation + 1, |l| l.generation);
        match held {
            Some(held) if held == self.generation => {}
            Some(held) if held < self.generation && held + 1 >= first_logged => {
                for log in self.recent.iter().filter(|l| l.generation > held) {
                    for (row, span) in &log.spans {
                        let start = *row as usize * self.row_len;
                        let cells = start + span.start as usize..start + span.end as usize;
                        out[cells.clone()].copy_from_slice(&self.bytes[cells]);
                    }
                }
            }
            _ => out.copy_from_slice(&self.bytes),
        }
        (self.counts(), self.generation)
    }

    fn encode_run(&mut self, run: Range<usize>) {
        let rule = self.rule;
        let cells = &self.cells[run.clone()];
        let bytes = &mut self.bytes[run.clone()];
        let classes = &mut self.classes[run];
        let moved = self.encoder.encode_cells(&rule, cells, bytes, classes);
        for (tally, moved) in self.tally.iter_mut().zip(moved) {
            *tally = tally.wrapping_add(moved);
        }
    }

    /// Lets `fuse` change any cells, then encodes them all anew: for the whole-grid pass.
    pub fn update_all(&mut self, fuse: impl FnOnce(&R, &mut [R::Cell]) -> usize) -> usize {
        let updated = fuse(&self.rule, &mut self.cells);
        self.encode_all();
        updated
    }

    fn encode_all(&mut self) {
        for row in self.dirty_rows.drain(..) {
            self.dirty_spans[row as usize] = 0..0;
        }
        self.encode_run(0..self.cells.len());
        // No log stands for it: a copy of an earlier generation is copied whole.
        self.generation += 1;
        self.recent.clear();
    }

    fn set_cells(&mut self, cells: Vec<R::Cell>) {
        self.cells = cells;
        self.encode_all();
    }

    /// Sets the cells at `indices` back to unknown, noting them for the next [`Self::flush`].
    fn forget(&mut self, indices: &[usize]) {
        for &i in indices {
            self.cells[i] = R::UNKNOWN;
            let row = i / self.row_len;
            let at = i - row * self.row_len;
            self.note_dirty_in_row(row, at, at + 1);
        }
    }

    /// Each cell's class, brought up to date.
    fn classes(&mut self) -> &[u8] {
        self.flush();
        &self.classes
    }

    /// The bytes and counts, brought up to date.
    fn encoded(&mut self) -> (&[u8], CellCounts) {
        self.flush();
        (&self.bytes, self.counts())
    }

    /// The counts as of the last flush.
    fn counts(&self) -> CellCounts {
        let tally = self.tally;
        CellCounts {
            occupied: tally[CellClass::Occupied as usize] + tally[CellClass::Confident as usize],
            free: tally[CellClass::Free as usize],
            unknown: tally[CellClass::Unknown as usize],
        }
    }
}

/// The grid's state, in the representation of its rule.
pub(crate) enum CellStore {
    Bayes(Layer<BayesRule>),
    LogOdds(Layer<LogOddsRule>),
    DempsterShafer(Layer<DempsterShaferRule>),
    Himm(Layer<HimmRule>),
}

/// Runs `$body` with `$layer` bound to the concrete [`Layer`] inside a [`CellStore`], so code over
/// cells is compiled once per rule.
macro_rules! with_layer {
    ($store:expr, $layer:ident => $body:expr) => {
        match $store {
            $crate::grid::CellStore::Bayes($layer) => $body,
            $crate::grid::CellStore::LogOdds($layer) => $body,
            $crate::grid::CellStore::DempsterShafer($layer) => $body,
            $crate::grid::CellStore::Himm($layer) => $body,
        }
    };
}
pub(crate) use with_layer;

/// Cells by what they say, as counted for a snapshot header.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CellCounts {
    /// p > 0.5.
    pub occupied: u32,
    /// p < 0.5.
    pub free: u32,
    /// Never reached by a reading.
    pub unknown: u32,
}

/// Which state of which grid a copy of the snapshot bytes holds
/// ([`OccupancyGrid::copy_changed_into`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EncodedVersion {
    /// The grid's identity, unique in the process.
    grid: u64,
    /// The bytes' generation in that grid.
    generation: u64,
}

/// Identities of grids, so that a copy of one grid's bytes is never taken for another's.
static NEXT_GRID_ID: AtomicU64 = AtomicU64::new(0);

/// A probability as a threshold on a grid's cell keys ([`OccupancyGrid::above`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Above(f32);

/// Cells a side of the squares [`OccupancyGrid::square_above`] tells apart.
pub(crate) const SQUARE_CELLS: usize = 8;

/// Which squares of [`SQUARE_CELLS`]² cells hold a cell above a threshold, each found out the
/// first time a look needs it (a look touches few of a large grid's squares), so that a look
/// along a line steps over the others at once. What it found holds while the grid is unchanged.
#[derive(Debug)]
pub(crate) struct SquaresAbove {
    above: Above,
    /// Per square, row-major: not yet known, or whether it holds such a cell.
    squares: Vec<Option<bool>>,
    per_side: i64,
}

impl SquaresAbove {
    pub(crate) fn new(grid: &OccupancyGrid, above: Above) -> Self {
        let per_side = grid.geometry().cells_per_side().div_ceil(SQUARE_CELLS);
        Self {
            above,
            squares: vec![None; per_side * per_side],
            per_side: per_side as i64,
        }
    }

    /// Whether one of the cells a grid step apart from `from` along the unit vector `direction`
    /// (`from + direction · k · resolution` for k from 1 to `steps`, those on the grid) passes
    /// `test`, a test only a cell of `grid` above the threshold can pass: only the samples within
    /// one step of a square holding such a cell are tested, the same answer as testing them all.
    pub(crate) fn any_along(
        &mut self,
        grid: &OccupancyGrid,
        from: Vector2<f32>,
        direction: Vector2<f32>,
        steps: usize,
        mut test: impl FnMut(usize, usize) -> bool,
    ) -> bool {
        if steps == 0 {
            return false;
        }
        let geometry = grid.geometry();
        let res = geometry.resolution();
        let side = SQUARE_CELLS as f32;
        // In squares, from the grid's corner; the line's parameter stays in grid steps.
        let start = (from - geometry.origin()) / (res * side);
        let (per_side, above) = (self.per_side, self.above);
        let squares = &mut self.squares;
        let mut sample = |k: usize| {
            geometry
                .cell_at((from + direction * (k as f32 * res)).into())
                .is_some_and(|(x, y)| test(x, y))
        };
        walk(
            start,
            direction / side,
            1.0,
            steps as f32,
            |sx, sy, enter, leave| {
                let on_grid = (0..per_side).contains(&sx) && (0..per_side).contains(&sy);
                let holds = on_grid
                    && *squares[(sy * per_side + sx) as usize]
                        .get_or_insert_with(|| grid.square_above(sx as usize, sy as usize, above));
                holds && {
                    let first = (enter.floor() as usize).saturating_sub(1).max(1);
                    let last = (leave.ceil() as usize + 1).min(steps);
                    (first..=last).any(&mut sample)
                }
            },
        )
    }
}

/// The probability method's map (paper §III.B.2, "Grid-Probability Array").
pub struct OccupancyGrid {
    /// Unique in the process ([`EncodedVersion`]).
    id: u64,
    geometry: GridGeometry,
    store: CellStore,
    /// Per cell, the world bearing from the sensor at which a reading last gave it occupied
    /// evidence (NaN: never), for a model that hears (`crate::model::CellEvidence::HEARD`);
    /// empty for the others.
    heard: Vec<f32>,
}

impl fmt::Debug for OccupancyGrid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("OccupancyGrid")
            .field("geometry", &self.geometry)
            .field("rule", &self.rule_kind())
            .finish_non_exhaustive()
    }
}

impl OccupancyGrid {
    /// A grid of `geometry` where every cell is unknown (probability 0.5, the paper's prior), and,
    /// if `hears`, a bearing per cell for where it was heard occupied from (none yet).
    pub fn new(geometry: GridGeometry, rule: &RuleConfig, hears: bool) -> Self {
        let len = geometry.len();
        let n = geometry.cells_per_side();
        let store = match *rule {
            RuleConfig::Bayes => CellStore::Bayes(Layer::new(BayesRule, n, n)),
            RuleConfig::LogOdds(r) => CellStore::LogOdds(Layer::new(r, n, n)),
            RuleConfig::DempsterShafer => {
                CellStore::DempsterShafer(Layer::new(DempsterShaferRule, n, n))
            }
            RuleConfig::Himm(r) => CellStore::Himm(Layer::new(r, n, n)),
        };
        let heard = if hears {
            vec![f32::NAN; len]
        } else {
            Vec::new()
        };
        Self {
            id: NEXT_GRID_ID.fetch_add(1, Ordering::Relaxed),
            geometry,
            store,
            heard,
        }
    }

    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    pub fn rule_kind(&self) -> RuleKind {
        match self.store {
            CellStore::Bayes(_) => RuleKind::Bayes,
            CellStore::LogOdds(_) => RuleKind::LogOdds,
            CellStore::DempsterShafer(_) => RuleKind::DempsterShafer,
            CellStore::Himm(_) => RuleKind::Himm,
        }
    }

    pub(crate) fn parts_mut(&mut self) -> (&GridGeometry, &mut CellStore, &mut [f32]) {
        (&self.geometry, &mut self.store, &mut self.heard)
    }

    /// Occupancy probability of cell (`x`, `y`); `None` if no reading has reached it (it is then
    /// at the prior, 0.5).
    ///
    /// # Panics
    /// If the cell lies outside the grid.
    pub fn probability(&self, x: usize, y: usize) -> Option<f32> {
        let n = self.geometry.cells_per_side();
        assert!(x < n && y < n, "cell ({x}, {y}) outside a {n}² grid");
        let i = self.geometry.index(x, y);
        with_layer!(&self.store, l => l.rule.probability(l.cells[i]))
    }

    /// `p` as a threshold on the cells' keys ([`Combine::key`]): a cell's probability is above
    /// `p` exactly when its key is above the threshold ([`Self::is_above`]). The probability of a
    /// key never falls as the key rises, so the threshold is the highest key whose probability is
    /// at most `p`, found by halving the rule's range of keys down to neighbouring floats.
    pub(crate) fn above(&self, p: f32) -> Above {
        fn threshold<R: Combine>(rule: &R, p: f32) -> f32 {
            let [mut low, mut high] = rule.key_range();
            if rule.key_probability(high) <= p {
                return high;
            }
            if rule.key_probability(low) > p {
                return f32::NEG_INFINITY;
            }
            // probability(low) <= p < probability(high) throughout.
            while low.next_up() < high {
                let middle = low + 0.5 * (high - low);
                let middle = if middle <= low || middle >= high {
                    low.next_up()
                } else {
                    middle
                };
                if rule.key_probability(middle) <= p {
                    low = middle;
                } else {
                    high = middle;
                }
            }
            low
        }
        Above(with_layer!(&self.store, l => threshold(&l.rule, p)))
    }

    /// Whether cell (`x`, `y`) is reached and its probability above the threshold `above` was
    /// made from ([`Self::above`]): what `probability(x, y) > p` says, without the probability.
    ///
    /// # Panics
    /// If the cell lies outside the grid.
    pub(crate) fn is_above(&self, x: usize, y: usize, above: Above) -> bool {
        let n = self.geometry.cells_per_side();
        assert!(x < n && y < n, "cell ({x}, {y}) outside a {n}² grid");
        let i = self.geometry.index(x, y);
        // An unreached cell's key is NaN: not above.
        with_layer!(&self.store, l => l.rule.key(l.cells[i]) > above.0)
    }

    /// Whether square (`sx`, `sy`) of [`SQUARE_CELLS`]² cells (those of it on the grid) holds a
    /// cell above `above` ([`Self::is_above`]).
    ///
    /// # Panics
    /// If the square lies outside the grid.
    pub(crate) fn square_above(&self, sx: usize, sy: usize, above: Above) -> bool {
        let n = self.geometry.cells_per_side();
        let (x0, y0) = (sx * SQUARE_CELLS, sy * SQUARE_CELLS);
        assert!(x0 < n && y0 < n, "square ({sx}, {sy}) outside a {n}² grid");
        let columns = x0..(x0 + SQUARE_CELLS).min(n);
        with_layer!(&self.store, l => (y0..(y0 + SQUARE_CELLS).min(n)).any(|y| {
            // Without a branch per cell, so that a row's cells are compared at once.
            l.cells[y * n..][columns.clone()]
                .iter()
                .fold(false, |any, &cell| any | (l.rule.key(cell) > above.0))
        }))
    }

    /// The world bearing from which cell (`x`, `y`) was last heard occupied, if it was and the
    /// model hears.
    pub(crate) fn heard_from(&self, x: usize, y: usize) -> Option<f32> {
        let i = self.geometry.index(x, y);
        self.heard.get(i).copied().filter(|b| !b.is_nan())
    }

    /// Every cell's occupancy probability, row-major, unknown cells at the prior 0.5.
    ///
    /// # Panics
    /// If `out` does not hold one value per cell.
    pub fn probabilities_into(&self, out: &mut [f32]) {
        assert_eq!(out.len(), self.geometry.len(), "one value per cell");
        with_layer!(&self.store, l => {
            for (o, &c) in out.iter_mut().zip(&l.cells) {
                *o = l.rule.probability(c).unwrap_or(0.5);
            }
        });
    }

    /// A fingerprint of the map: FNV-1a over every cell's probability ([`Self::probabilities_into`]),
    /// bit for bit, so that a change meant to leave the maps as they were can be checked to.
    pub fn fingerprint(&self) -> u64 {
        let mut probabilities = vec![0.0f32; self.geometry.len()];
        self.probabilities_into(&mut probabilities);
        probabilities
            .iter()
            .flat_map(|p| p.to_bits().to_le_bytes())
            .fold(0xcbf2_9ce4_8422_2325, |h, b| {
                (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
            })
    }

    /// Every cell in the snapshot encoding of `sonar_common::ipc` (0 = free … 254 = occupied,
    /// 127 = even odds, [`CELL_UNKNOWN`] = 255 for never observed), row-major, and the counts for
    /// the snapshot header. Costs one encoding per cell fused since the last call.
    pub fn encoded(&mut self) -> (&[u8], CellCounts) {
        with_layer!(&mut self.store, l => l.encoded())
    }

    /// The cells at least [`CONFIDENT_PROBABILITY`] occupied, as (x, y), row by row (the order of
    /// the cell arrays). Brings the kept state up to date first, as [`Self::encoded`] does, so it
    /// costs the cells fused since the last flush and an OR over the classes kept per cell (blocks
    /// without a confident cell are skipped whole), not a probability per cell.
    pub fn confident_cells(&mut self) -> impl Iterator<Item = (usize, usize)> + '_ {
        /// Cells searched at once for a confident one.
        const BLOCK: usize = 256;
        let n = self.geometry.cells_per_side();
        let confident = CellClass::Confident as u8;
        let classes: &[u8] = with_layer!(&mut self.store, l => l.classes());
        (0..)
            .zip(classes.chunks(BLOCK))
            // Confident is the only class with bit 2 set: an OR over the block (vectorised) tells
            // whether it holds one.
            .filter(move |(_, block)| {
                block.iter().fold(0, |any, &class| any | class) & confident != 0
            })
            .flat_map(move |(b, block)| {
                (b * BLOCK..)
                    .zip(block)
                    .filter(move |&(_, &class)| class == confident)
                    .map(move |(i, _)| (i % n, i / n))
            })
    }

    /// Writes into `out` the index of every cell above p = 0.5, in row order. Brings the kept
    /// state up to date first, as [`Self::encoded`] does, and reads the class kept per cell.
    pub(crate) fn occupied_cells_into(&mut self, out: &mut Vec<usize>) {
        let classes: &[u8] = with_layer!(&mut self.store, l => l.classes());
        let (occupied, confident) = (CellClass::Occupied as u8, CellClass::Confident as u8);
        out.extend(
            classes
                .iter()
                .enumerate()
                .filter(|&(_, &c)| c == occupied || c == confident)
                .map(|(i, _)| i),
        );
    }

    /// Brings `out`, a copy of the snapshot bytes of version `held` (`None`: unknown contents,
    /// e.g. a sample never written), up to date with [`Self::encoded`]: only the spans of the
    /// rows re-encoded since then are copied, if the grid still knows them (the last
    /// [`RECENT_FLUSHES`] flushes of this grid), else every byte. Returns the counts and the
    /// version `out` now holds: a snapshot per reading copies what the reading changed, not the
    /// grid.
    ///
    /// # Panics
    /// If `out` does not hold one byte per cell.
    pub fn copy_changed_into(
        &mut self,
        out: &mut [u8],
        held: Option<EncodedVersion>,
    ) -> (CellCounts, EncodedVersion) {
        let held = held.filter(|v| v.grid == self.id).map(|v| v.generation);
        let (counts, generation) =
            with_layer!(&mut self.store, l => l.copy_changed_into(out, held));
        let version = EncodedVersion {
            grid: self.id,
            generation,
        };
        (counts, version)
    }

    /// The version of the bytes [`Self::encoded`] returns: brought up to date first, so the
    /// same as the bytes of a call to it just before.
    pub fn encoded_version(&mut self) -> EncodedVersion {
        let generation = with_layer!(&mut self.store, l => {
            l.flush();
            l.generation
        });
        EncodedVersion {
            grid: self.id,
            generation,
        }
    }

    /// [`Self::encoded`] copied into `out`; returns the counts.
    ///
    /// # Panics
    /// If `out` does not hold one byte per cell.
    pub fn encode_into(&mut self, out: &mut [u8]) -> CellCounts {
        let (bytes, counts) = self.encoded();
        out.copy_from_slice(bytes);
        counts
    }

    /// Copies the cells into `out`, for saving; into its own allocation if it already holds this
    /// rule's cells (a recycled copy: no page of it is new, so no page faults).
    pub(crate) fn save_cells_into(&self, out: &mut SavedCells) {
        fn copy<T: Copy>(out: &mut Vec<T>, cells: &[T]) {
            out.clear();
            out.extend_from_slice(cells);
        }
        match (&self.store, out) {
            (CellStore::Bayes(l), SavedCells::Bayes(v)) => copy(v, &l.cells),
            (CellStore::LogOdds(l), SavedCells::LogOdds(v)) => copy(v, &l.cells),
            (CellStore::DempsterShafer(l), SavedCells::DempsterShafer(v)) => copy(v, &l.cells),
            (CellStore::Himm(l), SavedCells::Himm(v)) => copy(v, &l.cells),
            (store, out) => {
                *out = match store {
                    CellStore::Bayes(l) => SavedCells::Bayes(l.cells.clone()),
                    CellStore::LogOdds(l) => SavedCells::LogOdds(l.cells.clone()),
                    CellStore::DempsterShafer(l) => SavedCells::DempsterShafer(l.cells.clone()),
                    CellStore::Himm(l) => SavedCells::Himm(l.cells.clone()),
                }
            }
        }
    }

    /// Copies the bearings each cell was last heard occupied from into `out` (none if the model
    /// does not hear), into its own allocation.
    pub(crate) fn save_heard_into(&self, out: &mut Vec<f32>) {
        out.clear();
        out.extend_from_slice(&self.heard);
    }

    /// Takes saved bearings back, if there are as many as this grid keeps (none when its model
    /// does not hear).
    pub(crate) fn restore_heard(&mut self, saved: Vec<f32>) -> Result<(), StateError> {
        check_len("the heard bearings", self.heard.len(), saved.len())?;
        self.heard = saved;
        Ok(())
    }

    /// Takes saved cells back, if they are this grid's rule's and one per cell.
    pub(crate) fn restore_cells(&mut self, saved: SavedCells) -> Result<(), StateError> {
        fn put<R: Combine>(layer: &mut Layer<R>, cells: Vec<R::Cell>) -> Result<(), StateError> {
            check_len("the grid", layer.cells.len(), cells.len())?;
            layer.set_cells(cells);
            Ok(())
        }
        let expected = self.rule_kind();
        match (&mut self.store, saved) {
            (CellStore::Bayes(l), SavedCells::Bayes(c)) => put(l, c),
            (CellStore::LogOdds(l), SavedCells::LogOdds(c)) => put(l, c),
            (CellStore::DempsterShafer(l), SavedCells::DempsterShafer(c)) => put(l, c),
            (CellStore::Himm(l), SavedCells::Himm(c)) => put(l, c),
            (_, saved) => Err(StateError::Rule {
                expected,
                found: saved.rule_kind(),
            }),
        }
    }

    /// Sets the cells at `indices` (row-major, as [`GridGeometry::index`] gives them) back to
    /// unknown, as if no reading had reached them: their evidence and the bearing they were heard
    /// from are forgotten.
    ///
    /// # Panics
    /// If an index lies outside the grid.
    pub(crate) fn forget_cells(&mut self, indices: &[usize]) {
        with_layer!(&mut self.store, l => l.forget(indices));
        if !self.heard.is_empty() {
            for &i in indices {
                self.heard[i] = f32::NAN;
            }
        }
    }

    /// Every cell back to unknown.
    pub fn clear(&mut self) {
        fn reset<R: Combine>(l: &mut Layer<R>) {
            l.cells.fill(R::UNKNOWN);
            l.encode_all();
        }
        with_layer!(&mut self.store, l => reset(l));
        self.heard.fill(f32::NAN);
    }
}

/// The snapshot encoding of every cell worked out afresh from the cells' probabilities, as the
/// snapshots were once encoded: what the bytes and counts kept up to date must equal.
#[cfg(test)]
pub(crate) fn reference_encoding(grid: &OccupancyGrid) -> (Vec<u8>, CellCounts) {
    use sonar_common::ipc::encode_probability;
    let mut counts = CellCounts::default();
    let bytes = with_layer!(&grid.store, l => l.cells.iter().map(|&c| match l.rule.probability(c) {
        None => {
            counts.unknown += 1;
            CELL_UNKNOWN
        }
        Some(p) => {
            counts.occupied += u32::from(p > 0.5);
            counts.free += u32::from(p < 0.5);
            encode_probability(p)
        }
    }).collect());
    (bytes, counts)
}

/// Fuses each run's evidence, given as a probability, into the grid's cells, as a kernel does
/// (the runs noted for the next flush).
#[cfg(test)]
pub(crate) fn fuse_runs(
    grid: &mut OccupancyGrid,
    runs: impl IntoIterator<Item = (Range<usize>, f32)>,
) {
    fn fuse<R: Combine>(layer: &mut Layer<R>, runs: impl IntoIterator<Item = (Range<usize>, f32)>) {
        for (run, p) in runs {
            let evidence = match R::DOMAIN {
                crate::rule::Domain::Probability => p,
                crate::rule::Domain::LogOdds => crate::model::logit(p),
            };
            let (rule, cells) = layer.begin_run(run.clone());
            let changed = cells
                .iter_mut()
                .filter_map(|c| rule.fuse(c, evidence).then_some(()))
                .count();
            layer.end_run(run, changed);
        }
    }
    with_layer!(&mut grid.store, l => fuse(l, runs));
}

/// Fuses `runs` random runs of random evidence (leaning to occupied, so that many cells cross
/// [`CONFIDENT_PROBABILITY`] and some fall back below it).
#[cfg(test)]
pub(crate) fn fuse_random_runs(
    grid: &mut OccupancyGrid,
    rng: &mut rand_chacha::ChaCha8Rng,
    runs: usize,
) {
    use rand::Rng;
    let len = grid.geometry.len();
    let runs: Vec<_> = (0..runs)
        .map(|_| {
            let start = rng.random_range(0..len);
            let end = rng.random_range(start + 1..=len.min(start + 90));
            (start..end, rng.random_range(0.2f32..0.97))
        })
        .collect();
    fuse_runs(grid, runs);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rule::LogOddsRule;
    use sonar_common::ipc::encode_probability;

    #[test]
    fn a_new_grid_is_unknown_and_encodes_as_such() {
        for kind in RuleKind::ALL {
            let mut g = OccupancyGrid::new(
                GridGeometry::new(8, 0.5),
                &RuleConfig::default_for(kind),
                false,
            );
            assert_eq!(g.rule_kind(), kind);
            assert_eq!(g.probability(3, 4), None);
            let mut bytes = vec![0u8; 64];
            let counts = g.encode_into(&mut bytes);
            assert!(bytes.iter().all(|&b| b == CELL_UNKNOWN));
            assert_eq!(
                counts,
                CellCounts {
                    unknown: 64,
                    ..Default::default()
                }
            );
            let mut p = vec![0.0f32; 64];
            g.probabilities_into(&mut p);
            assert!(p.iter().all(|&v| v == 0.5));
        }
    }

    /// A log-odds grid `n` cells a side of `resolution` metres holding `cells`, row-major.
    fn log_odds_grid(n: usize, resolution: f32, cells: Vec<f32>) -> OccupancyGrid {
        let mut g = OccupancyGrid::new(
            GridGeometry::new(n, resolution),
            &RuleConfig::LogOdds(LogOddsRule::default()),
            false,
        );
        let CellStore::LogOdds(l) = &mut g.parts_mut().1 else {
            unreachable!()
        };
        l.set_cells(cells);
        g
    }

    /// Equal maps have equal fingerprints; one cell's probability moved a little changes it.
    #[test]
    fn a_fingerprint_tells_maps_apart_by_a_bit() {
        let grid_of = |cells: Vec<f32>| log_odds_grid(4, 0.1, cells);
        let cells: Vec<f32> = (0..16).map(|k| k as f32 * 0.1 - 0.8).collect();
        let mut nudged = cells.clone();
        nudged[5] += 0.01;
        let fingerprint = grid_of(cells.clone()).fingerprint();
        assert_eq!(fingerprint, grid_of(cells).fingerprint());
        assert_ne!(fingerprint, grid_of(nudged).fingerprint());
    }

    #[test]
    fn a_square_is_above_when_one_of_its_cells_is() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        // Sides that are and are not whole squares.
        for n in [1usize, 8, 13, 40, 61] {
            let cells: Vec<f32> = (0..n * n)
                .map(|_| match rng.random_range(0..40) {
                    0 => 3.5,
                    1 => f32::NAN,
                    _ => rng.random_range(-2.0..0.5),
                })
                .collect();
            let g = log_odds_grid(n, 0.1, cells);
            let above = g.above(0.9);
            let per_side = n.div_ceil(SQUARE_CELLS);
            for k in 0..per_side * per_side {
                let (sx, sy) = (k % per_side, k / per_side);
                let square = g.square_above(sx, sy, above);
                let expected = (sy * SQUARE_CELLS..((sy + 1) * SQUARE_CELLS).min(n)).any(|y| {
                    (sx * SQUARE_CELLS..((sx + 1) * SQUARE_CELLS).min(n))
                        .any(|x| g.is_above(x, y, above))
                });
                assert_eq!(square, expected, "{n}² grid, square ({sx}, {sy})");
            }
        }
    }

    #[test]
    fn a_look_along_a_line_over_the_squares_tests_what_a_look_at_every_sample_does() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let n = 100;
        // Short walls scattered over open space.
        let mut cells = vec![-1.0f32; n * n];
        for _ in 0..12 {
            let (x, y) = (rng.random_range(0..n - 6), rng.random_range(0..n));
            cells[y * n + x..][..6].fill(3.5);
        }
        let g = log_odds_grid(n, 0.02, cells);
        let above = g.above(0.9);
        let mut squares = SquaresAbove::new(&g, above);
        let geometry = *g.geometry();
        let (mut met, mut missed) = (0, 0);
        for _ in 0..2000 {
            let from = Vector2::new(rng.random_range(-1.2..1.2), rng.random_range(-1.2..1.2));
            let angle: f32 = rng.random_range(0.0..std::f32::consts::TAU);
            let direction = Vector2::new(angle.cos(), angle.sin());
            let steps = rng.random_range(0..150);
            // A test that passes a third of the cells above, as the callers' tests of a cell's
            // place or bearing do.
            let test = |x: usize, y: usize| g.is_above(x, y, above) && !(x + y).is_multiple_of(3);
            let every_sample = (1..=steps)
                .filter_map(|k| {
                    geometry.cell_at((from + direction * (k as f32 * geometry.resolution())).into())
                })
                .any(|(x, y)| test(x, y));
            let over_squares = squares.any_along(&g, from, direction, steps, test);
            assert_eq!(over_squares, every_sample, "{from:?} {angle} {steps}");
            if every_sample { met += 1 } else { missed += 1 }
        }
        assert!(met > 100 && missed > 100, "{met} {missed}");
    }

    #[test]
    fn encoding_and_counts_follow_the_cells() {
        let mut g = log_odds_grid(2, 1.0, vec![-2.0, 0.0, 3.5, f32::NAN]);
        let mut bytes = [0u8; 4];
        let counts = g.encode_into(&mut bytes);
        assert_eq!(reference_encoding(&g), (bytes.to_vec(), counts));
        assert_eq!(
            bytes,
            [
                encode_probability(0.119_203),
                127,
                encode_probability(0.970_688),
                CELL_UNKNOWN
            ]
        );
        assert_eq!(
            counts,
            CellCounts {
                occupied: 1,
                free: 1,
                unknown: 1
            }
        );
        g.clear();
        assert_eq!(g.probability(0, 0), None);
    }

    /// The cells a walk over every cell's probability finds at least [`CONFIDENT_PROBABILITY`]
    /// occupied, row by row: what the features once read the grid with, and what
    /// [`OccupancyGrid::confident_cells`] must equal.
    fn walked_confident_cells(g: &OccupancyGrid) -> Vec<(usize, usize)> {
        let n = g.geometry().cells_per_side();
        (0..n)
            .flat_map(|y| (0..n).map(move |x| (x, y)))
            .filter(|&(x, y)| {
                g.probability(x, y)
                    .is_some_and(|p| p >= CONFIDENT_PROBABILITY)
            })
            .collect()
    }

    #[test]
    fn confident_cells_equal_a_walk_over_every_cell_on_random_grids() {
        use rand::{Rng, SeedableRng};
        for kind in RuleKind::ALL {
            for seed in 0..12 {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                // Sides that are and are not multiples of 64 cells.
                let n = rng.random_range(1..=90);
                let mut g = OccupancyGrid::new(
                    GridGeometry::new(n, 0.1),
                    &RuleConfig::default_for(kind),
                    false,
                );
                let mut seen_confident = false;
                // Several rounds of fusing between reads, so cells enter and leave the set.
                for round in 0..6 {
                    let runs = rng.random_range(0..4 * n + 1);
                    fuse_random_runs(&mut g, &mut rng, runs);
                    let kept: Vec<_> = g.confident_cells().collect();
                    assert_eq!(
                        kept,
                        walked_confident_cells(&g),
                        "{kind:?} seed {seed} round {round}"
                    );
                    seen_confident |= !kept.is_empty();
                    if round == 3 {
                        // A snapshot flushes the same runs; a clear empties the set.
                        g.encoded();
                        g.clear();
                        assert_eq!(g.confident_cells().count(), 0);
                    }
                }
                assert!(
                    seen_confident || n < 4,
                    "{kind:?} seed {seed}: the grid never held a confident cell"
                );
            }
        }
    }

    #[test]
    fn runs_fused_without_a_snapshot_keep_a_span_per_row_at_most() {
        let mut layer = Layer::new(LogOddsRule::default(), 4, 3);
        for i in 0..100_000 {
            // Runs within a row and across rows, over and over.
            let run = [1..3, 2..9, 0..12][i % 3].clone();
            let (rule, cells) = layer.begin_run(run.clone());
            // Evidence that changes the cells every time, also at the clamp.
            let evidence = if i % 2 == 0 { 0.01 } else { -0.005 };
            let changed = cells
                .iter_mut()
                .filter_map(|c| rule.fuse(c, evidence).then_some(()))
                .count();
            layer.end_run(run, changed);
            assert!(layer.dirty_rows.len() <= 3, "run {i}");
        }
        assert_eq!(layer.dirty_spans, [0..4, 0..4, 0..4]);
        let (bytes, counts) = layer.encoded();
        assert!(bytes.iter().all(|&b| b > 127 && b == bytes[0]), "{bytes:?}");
        assert_eq!(
            counts,
            CellCounts {
                occupied: 12,
                free: 0,
                unknown: 0
            }
        );
        assert!(layer.dirty_rows.is_empty() && layer.dirty_spans.iter().all(|s| s.is_empty()));
    }

    #[test]
    fn copies_brought_up_to_date_by_their_changes_equal_a_full_encoding_on_random_grids() {
        use rand::{Rng, SeedableRng};
        let mut incremental = 0;
        for kind in RuleKind::ALL {
            for seed in 0..8 {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                let n = rng.random_range(1..=90);
                let geometry = GridGeometry::new(n, 0.1);
                let rule = RuleConfig::default_for(kind);
                let mut g = OccupancyGrid::new(geometry, &rule, false);
                // Samples handed back in a random order, as an IPC service's slots are; each
                // starts as garbage that nothing says was written. More samples than flushes are
                // logged, so some are too old to be brought up to date span by span.
                let mut samples: Vec<(Vec<u8>, Option<EncodedVersion>)> = (0..RECENT_FLUSHES + 8)
                    .map(|i| (vec![i as u8; n * n], None))
                    .collect();
                for round in 0..120 {
                    let runs = rng.random_range(0..n / 2 + 2);
                    fuse_random_runs(&mut g, &mut rng, runs);
                    if round == 50 {
                        g.clear();
                    }
                    if round % 13 == 0 {
                        // A features snapshot's flush between two grid snapshots.
                        let _ = g.confident_cells().count();
                    }
                    // Mostly a few recent samples, now and then any (one unused for longer
                    // than the logs reach).
                    let reused = if rng.random_bool(0.1) {
                        samples.len()
                    } else {
                        3
                    };
                    let slot = rng.random_range(0..reused);
                    let (sample, held) = &mut samples[slot];
                    incremental += usize::from(held.is_some());
                    let (counts, version) = g.copy_changed_into(sample, *held);
                    *held = Some(version);
                    assert_eq!(
                        (sample.clone(), counts),
                        reference_encoding(&g),
                        "{kind:?} seed {seed} round {round}"
                    );
                }
                // A copy of another grid's bytes is never taken for this one's.
                let mut other = OccupancyGrid::new(geometry, &rule, false);
                let (sample, held) = &mut samples[0];
                other.copy_changed_into(sample, *held);
                assert_eq!(
                    sample.clone(),
                    reference_encoding(&other).0,
                    "{kind:?} {seed}"
                );
            }
        }
        assert!(incremental > 1000, "{incremental}");
    }

    #[test]
    fn bytes_and_counts_kept_by_dirty_rows_equal_a_full_encoding_on_random_grids() {
        use rand::{Rng, SeedableRng};
        for kind in RuleKind::ALL {
            for seed in 0..12 {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                let n = rng.random_range(1..=90);
                let mut g = OccupancyGrid::new(
                    GridGeometry::new(n, 0.1),
                    &RuleConfig::default_for(kind),
                    false,
                );
                for round in 0..6 {
                    // Random runs, within rows and across them, between two snapshots.
                    let runs = rng.random_range(0..4 * n + 1);
                    fuse_random_runs(&mut g, &mut rng, runs);
                    let (bytes, counts) = g.encoded();
                    let kept = (bytes.to_vec(), counts);
                    assert_eq!(
                        kept,
                        reference_encoding(&g),
                        "{kind:?} seed {seed} round {round}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_probability_threshold_on_the_keys_says_what_the_probabilities_say() {
        use rand::SeedableRng;
        for kind in RuleKind::ALL {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
            let mut g = OccupancyGrid::new(
                GridGeometry::new(64, 0.1),
                &RuleConfig::default_for(kind),
                false,
            );
            fuse_random_runs(&mut g, &mut rng, 2000);
            for p in [0.1, 0.3, 0.5, 0.7, 0.9, 0.97, 0.999] {
                let above = g.above(p);
                for y in 0..64 {
                    for x in 0..64 {
                        assert_eq!(
                            g.is_above(x, y, above),
                            g.probability(x, y).is_some_and(|q| q > p),
                            "{kind:?} p {p} at ({x}, {y}): {:?}",
                            g.probability(x, y)
                        );
                    }
                }
            }
        }
    }
}
