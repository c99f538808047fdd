//! The probability grid: per-cell state in the rule's own representation, one way to read it.

use std::fmt;

use sonar_common::ipc::{CELL_UNKNOWN, encode_probability};

use crate::geometry::GridGeometry;
use crate::rule::{
    BayesRule, Combine, DempsterShaferRule, HimmRule, LogOddsRule, RuleConfig, RuleKind,
};
use crate::state::{SavedCells, StateError, check_len};

/// The cells of one rule, with the rule's parameters.
pub(crate) struct Layer<R: Combine> {
    pub rule: R,
    pub cells: Vec<R::Cell>,
}

impl<R: Combine> Layer<R> {
    fn new(rule: R, len: usize) -> Self {
        Self {
            rule,
            cells: vec![R::UNKNOWN; len],
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

/// The probability method's map (paper §III.B.2, "Grid-Probability Array").
pub struct OccupancyGrid {
    geometry: GridGeometry,
    store: CellStore,
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
    /// A grid of `geometry` where every cell is unknown (probability 0.5, the paper's prior).
    pub fn new(geometry: GridGeometry, rule: &RuleConfig) -> Self {
        let len = geometry.len();
        let store = match *rule {
            RuleConfig::Bayes => CellStore::Bayes(Layer::new(BayesRule, len)),
            RuleConfig::LogOdds(r) => CellStore::LogOdds(Layer::new(r, len)),
            RuleConfig::DempsterShafer => {
                CellStore::DempsterShafer(Layer::new(DempsterShaferRule, len))
            }
            RuleConfig::Himm(r) => CellStore::Himm(Layer::new(r, len)),
        };
        Self { geometry, store }
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

    pub(crate) fn parts_mut(&mut self) -> (&GridGeometry, &mut CellStore) {
        (&self.geometry, &mut self.store)
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

    /// Every cell in the snapshot encoding of `sonar_common::ipc` (0 = free … 254 = occupied,
    /// 127 = even odds, [`CELL_UNKNOWN`] = 255 for never observed), row-major; returns the counts
    /// for the snapshot header.
    ///
    /// # Panics
    /// If `out` does not hold one byte per cell.
    pub fn encode_into(&self, out: &mut [u8]) -> CellCounts {
        assert_eq!(out.len(), self.geometry.len(), "one byte per cell");
        let mut counts = CellCounts::default();
        with_layer!(&self.store, l => {
            for (o, &c) in out.iter_mut().zip(&l.cells) {
                *o = match l.rule.probability(c) {
                    None => {
                        counts.unknown += 1;
                        CELL_UNKNOWN
                    }
                    Some(p) => {
                        counts.occupied += u32::from(p > 0.5);
                        counts.free += u32::from(p < 0.5);
                        encode_probability(p)
                    }
                };
            }
        });
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

    /// Takes saved cells back, if they are this grid's rule's and one per cell.
    pub(crate) fn restore_cells(&mut self, saved: SavedCells) -> Result<(), StateError> {
        fn put<R: Combine>(layer: &mut Layer<R>, cells: Vec<R::Cell>) -> Result<(), StateError> {
            check_len("the grid", layer.cells.len(), cells.len())?;
            layer.cells = cells;
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

    /// Every cell back to unknown.
    pub fn clear(&mut self) {
        fn reset<R: Combine>(l: &mut Layer<R>) {
            l.cells.fill(R::UNKNOWN);
        }
        with_layer!(&mut self.store, l => reset(l));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rule::LogOddsRule;

    #[test]
    fn a_new_grid_is_unknown_and_encodes_as_such() {
        for kind in RuleKind::ALL {
            let g = OccupancyGrid::new(GridGeometry::new(8, 0.5), &RuleConfig::default_for(kind));
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

    #[test]
    fn encoding_and_counts_follow_the_cells() {
        let mut g = OccupancyGrid::new(
            GridGeometry::new(2, 1.0),
            &RuleConfig::LogOdds(LogOddsRule::default()),
        );
        let CellStore::LogOdds(l) = &mut g.parts_mut().1 else {
            unreachable!()
        };
        l.cells[0] = -2.0;
        l.cells[1] = 0.0;
        l.cells[2] = 3.5;
        let mut bytes = [0u8; 4];
        let counts = g.encode_into(&mut bytes);
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
}
