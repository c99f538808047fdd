//! Occupied cells that no viewpoint could have heard (`region_hidden_unknown`).
//!
//! Sound does not pass through a wall. A cell drawn occupied behind a wall, as seen from every
//! place the sensor stood within its reach, holds evidence no echo could have brought from
//! there: a weak echo's arc drawn across its lobe beyond the wall it grazed, a patch placed where
//! an echo that came round a wall's end seemed to be, a wall followed on past the corner it
//! should have stopped at. No reading can refute such a cell (a reading refutes only what it
//! would have heard), so it stays for good. On the generated scene suite (`tune` split, 8
//! viewpoints) more than half the occupied cells farther than 5 cm from every true surface lay out
//! of sight of every viewpoint (docs/fusion.md, "nineteenth round" and "twentieth round").
//!
//! What hides a cell is a cell some reading heard (within 1° of its axis, at its echo's range)
//! that the grid holds above p = 0.97, lying between it and the viewpoint, more than
//! [`HIDING_MARGIN_M`] in front of it and off the line of the wall the cell stands for: sound
//! does not pass what echoed. With `region_hidden_behind_walls` any cell above p = 0.97 hides,
//! walls drawn on included: more of the wrong cells go, but a wall drawn on wrongly in front of
//! a true one hides that one too. A cell a reading heard itself is never hidden (the echo came
//! from there, or past whatever the grid shows in between).
//!
//! A hidden cell is set back to unknown, not to free: nothing was heard there either way. A cell
//! farther than the sensor's reach from every viewpoint is left as it is. A map restored from a
//! file is told where its kept readings (the engine's history) were taken and what they heard
//! ([`crate::mapper::Mapper::remember_readings`]); readings older than those are forgotten.

use std::collections::HashSet;

use rustc_hash::FxHashMap;

use nalgebra::Vector2;

use crate::geometry::{GridGeometry, walk};

/// A viewpoint closer than this to one kept is not kept again, metres: a robot driving while
/// it scans stands somewhere new at every reading.
const VIEWPOINT_SPACING_M: f32 = 0.25;
/// A wall hides a cell only from this far in front of it along the sight line, metres: the
/// cell's own wall is drawn as a band 2.5 cm or more each side of its line.
pub(crate) const HIDING_MARGIN_M: f32 = 0.1;
/// A cell hides what lies behind it when its probability is above this: the ceiling of the
/// recommended preset's log-odds (3.5 → 0.971) less a little, so a wall heard or drawn again and
/// again, not once.
pub(crate) const HIDING_ABOVE: f32 = 0.97;
/// A cell within this of a reading's axis at its echo's range was heard, degrees.
const HEARD_OFF_AXIS_DEG: f32 = 1.0;
/// Hidden cells are looked for once this many readings were fused since the last look (half a
/// paper sweep): a head whose sweeps are never told apart ends one every reading or two, and a
/// look walks every occupied cell.
const READINGS_BETWEEN_LOOKS: u64 = 25;

/// A cell hidden from every viewpoint at a look is looked at again from the viewpoints added
/// since only, but from all of them at every this many looks: what hides it may have been taken
/// back since.
const FULL_LOOK_EVERY: u64 = 8;

/// Where the sensor stood, every [`VIEWPOINT_SPACING_M`] or so.
#[derive(Debug, Default, Clone)]
struct Viewpoints {
    kept: Vec<Vector2<f32>>,
    /// The lattice sites of the kept ones.
    sites: HashSet<(i32, i32)>,
}

impl Viewpoints {
    /// Notes that the sensor stood at `position`.
    fn note(&mut self, position: Vector2<f32>) {
        let site = |v: f32| (v / VIEWPOINT_SPACING_M).round() as i32;
        if self.sites.insert((site(position.x), site(position.y))) {
            self.kept.push(position);
        }
    }

    fn clear(&mut self) {
        self.kept.clear();
        self.sites.clear();
    }
}

/// A set of grid cells, one bit each.
#[derive(Debug, Clone)]
struct CellSet {
    bits: Vec<u64>,
}

impl CellSet {
    fn new(geometry: &GridGeometry) -> Self {
        Self {
            bits: vec![0; geometry.len().div_ceil(64)],
        }
    }

    /// Adds the cells whose centre lies within `half_thickness` (and half a cell) of the segment
    /// from `a` to `b`.
    fn add_segment(
        &mut self,
        geometry: &GridGeometry,
        a: Vector2<f32>,
        b: Vector2<f32>,
        half_thickness: f32,
    ) {
        let n = geometry.cells_per_side();
        let reach = half_thickness + 0.5 * geometry.resolution();
        let (Some((x0, y0)), Some((x1, y1))) = (
            clamped_cell(geometry, a.inf(&b) - Vector2::repeat(reach)),
            clamped_cell(geometry, a.sup(&b) + Vector2::repeat(reach)),
        ) else {
            return;
        };
        let along = b - a;
        let length_sq = along.norm_squared();
        for y in y0..=y1.min(n - 1) {
            for x in x0..=x1.min(n - 1) {
                let c: Vector2<f32> = geometry.cell_centre(x, y).coords;
                let t = if length_sq > 0.0 {
                    ((c - a).dot(&along) / length_sq).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                if (a + along * t - c).norm() <= reach {
                    self.insert(geometry.index(x, y));
                }
            }
        }
    }

    fn insert(&mut self, index: usize) {
        self.bits[index / 64] |= 1 << (index % 64);
    }

    fn contains(&self, index: usize) -> bool {
        self.bits[index / 64] & (1 << (index % 64)) != 0
    }

    fn clear(&mut self) {
        self.bits.fill(0);
    }
}

/// Side of the square blocks of cells [`Blocking`] notes as holding a cell that hides or not,
/// cells.
const BLOCK_CELLS: usize = 8;

/// The cells that hide, and which blocks of [`BLOCK_CELLS`]² cells hold one: a sight line
/// crosses mostly open space, and steps through an empty block at once.
#[derive(Debug, Clone)]
struct Blocking {
    cells: CellSet,
    blocks: Vec<bool>,
    blocks_per_side: usize,
}

impl Blocking {
    fn new(geometry: &GridGeometry) -> Self {
        let blocks_per_side = geometry.cells_per_side().div_ceil(BLOCK_CELLS);
        Self {
            cells: CellSet::new(geometry),
            blocks: vec![false; blocks_per_side * blocks_per_side],
            blocks_per_side,
        }
    }

    fn clear(&mut self) {
        self.cells.clear();
        self.blocks.fill(false);
    }

    fn insert(&mut self, geometry: &GridGeometry, index: usize) {
        self.cells.insert(index);
        let n = geometry.cells_per_side();
        let (x, y) = (index % n, index / n);
        self.blocks[(y / BLOCK_CELLS) * self.blocks_per_side + x / BLOCK_CELLS] = true;
    }

    /// Whether the sight line from `from` along the unit vector `direction`, from one cell's
    /// width out to `steps` cells' widths, crosses a cell that hides and `counts` it (given the
    /// middle of the stretch of line inside that cell). Every cell the line crosses is looked at
    /// once (a grid walk, Amanatides and Woo), and each block holding nothing that hides is
    /// crossed in one step.
    fn meets(
        &self,
        geometry: &GridGeometry,
        from: Vector2<f32>,
        direction: Vector2<f32>,
        steps: usize,
        counts: impl Fn(Vector2<f32>) -> bool,
    ) -> bool {
        let n = geometry.cells_per_side() as i64;
        let res = geometry.resolution();
        // In cells, from the grid's corner; the line's parameter is in cells' widths too.
        let start = (from - geometry.origin()) / res;
        let (first, last) = (1.0, steps as f32);
        if last < first {
            return false;
        }
        let blocks = self.blocks_per_side as i64;
        let block = BLOCK_CELLS as f32;
        walk(
            start / block,
            direction / block,
            first,
            last,
            |bx, by, enter, leave| {
                let holds = bx >= 0
                    && by >= 0
                    && bx < blocks
                    && by < blocks
                    && self.blocks[(by * blocks + bx) as usize];
                holds
                    && walk(start, direction, enter, leave, |cx, cy, enter, leave| {
                        cx >= 0
                            && cy >= 0
                            && cx < n
                            && cy < n
                            && self.cells.contains((cy * n + cx) as usize)
                            && counts(from + direction * (0.5 * (enter + leave) * res))
                    })
            },
        )
    }
}

/// The cell holding `p` once `p` is brought inside the grid; `None` for an empty grid.
fn clamped_cell(geometry: &GridGeometry, p: Vector2<f32>) -> Option<(usize, usize)> {
    let n = geometry.cells_per_side();
    if n == 0 {
        return None;
    }
    let origin = geometry.cell_centre(0, 0).coords;
    let res = geometry.resolution();
    let at = |v: f32, o: f32| (((v - o) / res).round().max(0.0) as usize).min(n - 1);
    Some((at(p.x, origin.x), at(p.y, origin.y)))
}

/// What tells the cells no viewpoint could have heard: where the sensor stood, the cells its
/// readings' echoes came from, and when hidden cells were last looked for.
#[derive(Debug, Clone)]
pub(crate) struct Hiding {
    viewpoints: Viewpoints,
    heard: CellSet,
    /// Readings fused at the last look.
    looked_at: u64,
    /// The cells that hide, as of the last look.
    blocking: Blocking,
    /// Per occupied cell at the last look, what it found.
    seen_from: FxHashMap<usize, Seen>,
    /// Looks taken.
    looks: u64,
}

/// What a look found of an occupied cell.
#[derive(Debug, Clone, Copy)]
enum Seen {
    /// Seen from the viewpoint kept at this place.
    From(usize),
    /// Hidden from the first this many viewpoints kept.
    HiddenFromFirst(usize),
}

impl Hiding {
    pub fn new(geometry: &GridGeometry) -> Self {
        Self {
            viewpoints: Viewpoints::default(),
            heard: CellSet::new(geometry),
            looked_at: 0,
            blocking: Blocking::new(geometry),
            seen_from: FxHashMap::default(),
            looks: 0,
        }
    }

    /// Notes a reading taken from `position` along world bearing `axis`, with its echo's range
    /// and the half-width of the band its wall is drawn as, if it heard one.
    pub fn note_reading(
        &mut self,
        geometry: &GridGeometry,
        position: Vector2<f32>,
        axis: f32,
        echo: Option<(f32, f32)>,
    ) {
        self.viewpoints.note(position);
        if let Some((range, band)) = echo {
            let at = |bearing: f32| position + Vector2::new(bearing.cos(), bearing.sin()) * range;
            let off = HEARD_OFF_AXIS_DEG.to_radians();
            self.heard
                .add_segment(geometry, at(axis - off), at(axis), band);
            self.heard
                .add_segment(geometry, at(axis), at(axis + off), band);
        }
    }

    /// Whether a look is due with `readings` fused so far; if so, it counts as taken.
    pub fn due(&mut self, readings: u64) -> bool {
        let due = readings >= self.looked_at + READINGS_BETWEEN_LOOKS;
        if due {
            self.looked_at = readings;
        }
        due
    }

    pub fn clear(&mut self) {
        self.viewpoints.clear();
        self.heard.clear();
        self.looked_at = 0;
        self.seen_from.clear();
        self.looks = 0;
    }

    /// Of the `occupied` cells (grid indices), writes into `out` those that no reading heard and
    /// that some viewpoint within `reach` of them has and none sees: every sight line from such a
    /// viewpoint meets a cell that hides (one a reading heard, or with `behind_walls` any) more
    /// than [`HIDING_MARGIN_M`] before the cell, off the line of the wall the cell stands for (a
    /// sight line that meets a wall at a slant runs through the wall's own band for a while
    /// before it reaches the cell). Sight lines are walked cell by cell ([`walk`]); the viewpoint
    /// that saw a cell at the last look is tried first, then the latest first (a cell drawn since
    /// was mostly drawn from where the sensor stands now).
    pub fn hidden_cells(
        &mut self,
        geometry: &GridGeometry,
        reach: f32,
        behind_walls: bool,
        occupied: &[usize],
        sight: &impl Sight,
        out: &mut Vec<usize>,
    ) {
        self.blocking.clear();
        for &j in occupied {
            if sight.hides(j) && (behind_walls || self.heard.contains(j)) {
                self.blocking.insert(geometry, j);
            }
        }
        let n = geometry.cells_per_side();
        let step = geometry.resolution();
        self.looks += 1;
        let full = self.looks.is_multiple_of(FULL_LOOK_EVERY);
        let seen_before = std::mem::take(&mut self.seen_from);
        let viewpoints = &self.viewpoints.kept;
        for &i in occupied {
            if self.heard.contains(i) {
                continue;
            }
            let cell: Vector2<f32> = geometry.cell_centre(i % n, i / n).coords;
            let normal = sight.own_normal(i);
            let sees = |from: Vector2<f32>| {
                let distance = (cell - from).norm();
                let direction = (cell - from) / distance.max(f32::EPSILON);
                let near_line = sight.near_line(distance);
                let steps = ((distance - HIDING_MARGIN_M) / step).floor().max(0.0) as usize;
                !self.blocking.meets(geometry, from, direction, steps, |at| {
                    normal.is_none_or(|normal| normal.dot(&(at - cell)).abs() > near_line)
                })
            };
            let in_reach =
                |&(_, v): &(usize, &Vector2<f32>)| (cell - v).norm_squared() <= reach * reach;
            let before = match seen_before.get(&i) {
                Some(&Seen::From(k)) => viewpoints.get(k).map(|v| (k, v)).filter(in_reach),
                _ => None,
            };
            // Hidden from every viewpoint kept at a recent look: only those added since are
            // looked from again.
            let first = match (full, seen_before.get(&i)) {
                (false, Some(&Seen::HiddenFromFirst(count))) => count,
                _ => 0,
            };
            let mut any_in_reach = first > 0;
            let seer = before
                .into_iter()
                .chain(
                    viewpoints
                        .iter()
                        .enumerate()
                        .skip(first)
                        .rev()
                        // The one tried first is not looked from again.
                        .filter(|&(k, _)| before.is_none_or(|(b, _)| b != k))
                        .filter(in_reach),
                )
                .inspect(|_| any_in_reach = true)
                .find(|&(_, &v)| sees(v));
            match seer {
                Some((k, _)) => {
                    self.seen_from.insert(i, Seen::From(k));
                }
                None if any_in_reach => {
                    self.seen_from
                        .insert(i, Seen::HiddenFromFirst(viewpoints.len()));
                    out.push(i);
                }
                None => {}
            }
        }
        // A hidden cell is unknown until something draws it again: what it was hidden from is
        // kept for then.
        for (i, seen) in seen_before {
            if let Seen::HiddenFromFirst(_) = seen {
                self.seen_from.entry(i).or_insert(seen);
            }
        }
    }
}

/// What [`Hiding::hidden_cells`] asks of the grid.
pub(crate) trait Sight {
    /// Whether the cell at `index` hides what lies behind it.
    fn hides(&self, index: usize) -> bool;
    /// The unit normal of the wall the cell at `index` stands for, if it was heard (the bearing
    /// it was heard from): the cells near that wall's own line hide nothing behind it.
    fn own_normal(&self, index: usize) -> Option<Vector2<f32>>;
    /// How far each side of a wall's line at `distance` from the sensor its cells lie, metres.
    fn near_line(&self, distance: f32) -> f32;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geometry() -> GridGeometry {
        GridGeometry::new(200, 0.02)
    }

    fn index_at(g: &GridGeometry, x: f32, y: f32) -> usize {
        let (cx, cy) = g.cell_at(nalgebra::Point2::new(x, y)).unwrap();
        g.index(cx, cy)
    }

    /// A grid holding walls (as segments 5 cm thick) whose cells all stand for a wall with
    /// `normal`, if any.
    struct Walls {
        cells: CellSet,
        normal: Option<Vector2<f32>>,
    }

    impl Walls {
        /// Walls along the segments given as `[ax, ay, bx, by]`.
        fn new(g: &GridGeometry, segments: &[[f32; 4]]) -> Self {
            let mut cells = CellSet::new(g);
            for &[ax, ay, bx, by] in segments {
                cells.add_segment(g, Vector2::new(ax, ay), Vector2::new(bx, by), 0.025);
            }
            Self {
                cells,
                normal: None,
            }
        }
    }

    impl Sight for Walls {
        fn hides(&self, index: usize) -> bool {
            self.cells.contains(index)
        }
        fn own_normal(&self, _: usize) -> Option<Vector2<f32>> {
            self.normal
        }
        fn near_line(&self, _: f32) -> f32 {
            0.05
        }
    }

    /// Of `cells`, those hidden behind `walls` (heard or not, if `behind_walls`), the walls'
    /// own cells occupied too.
    fn hidden_of(
        hiding: &Hiding,
        reach: f32,
        behind_walls: bool,
        cells: &[usize],
        walls: &Walls,
    ) -> Vec<usize> {
        let g = geometry();
        let mut occupied: Vec<usize> = (0..g.len()).filter(|&i| walls.cells.contains(i)).collect();
        occupied.extend(cells.iter().filter(|&&i| !walls.cells.contains(i)));
        let mut out = Vec::new();
        hiding
            .clone()
            .hidden_cells(&g, reach, behind_walls, &occupied, walls, &mut out);
        out.retain(|i| cells.contains(i));
        out
    }

    /// The `cells` hidden behind `walls`, heard or not.
    fn hidden(hiding: &Hiding, reach: f32, cells: &[usize], walls: &Walls) -> Vec<usize> {
        hidden_of(hiding, reach, true, cells, walls)
    }

    /// A reading from `at` that heard nothing.
    fn stood_at(hiding: &mut Hiding, at: (f32, f32)) {
        hiding.note_reading(&geometry(), Vector2::new(at.0, at.1), 0.0, None);
    }

    /// A wall along x = 1 from y = −0.5 to 0.5, and the sensor at the origin.
    fn wall_ahead_of_the_origin(g: &GridGeometry) -> (Walls, Hiding) {
        let walls = Walls::new(g, &[[1.0, -0.5, 1.0, 0.5]]);
        let mut hiding = Hiding::new(g);
        stood_at(&mut hiding, (0.0, 0.0));
        (walls, hiding)
    }

    #[test]
    fn a_cell_behind_a_wall_is_hidden_from_a_viewpoint_in_front_of_it() {
        let g = geometry();
        let (walls, mut hiding) = wall_ahead_of_the_origin(&g);
        let behind = index_at(&g, 1.5, 0.0);
        let on_wall = index_at(&g, 1.0, 0.0);
        let beside = index_at(&g, 1.5, 0.9);
        let cells = [behind, on_wall, beside];
        assert_eq!(hidden(&hiding, 4.0, &cells, &walls), vec![behind]);

        // A second viewpoint beyond the wall's end sees the cell behind it.
        stood_at(&mut hiding, (1.5, 1.0));
        assert!(hidden(&hiding, 4.0, &[behind], &walls).is_empty());
    }

    #[test]
    fn a_cell_a_reading_heard_is_kept_whatever_lies_in_front() {
        let g = geometry();
        // The wall drawn, perhaps wrongly: a reading along the x axis heard an echo at 1.5 m,
        // so something is there and sound reached it.
        let (walls, mut hiding) = wall_ahead_of_the_origin(&g);
        hiding.note_reading(&g, Vector2::zeros(), 0.0, Some((1.5, 0.025)));
        let heard = index_at(&g, 1.5, 0.0);
        let off_axis = index_at(&g, 1.5, 0.1);
        assert_eq!(
            hidden(&hiding, 4.0, &[heard, off_axis], &walls),
            vec![off_axis],
            "4° off the axis is not what the reading heard"
        );
    }

    #[test]
    fn only_what_a_reading_heard_hides_unless_every_wall_does() {
        let g = geometry();
        let (walls, mut hiding) = wall_ahead_of_the_origin(&g);
        let behind = index_at(&g, 1.5, 0.3);
        let behind_heard = |hiding: &Hiding| hidden_of(hiding, 4.0, false, &[behind], &walls);
        assert!(
            behind_heard(&hiding).is_empty(),
            "the wall was drawn, not heard"
        );
        // A reading square to the wall hears it at 1 m, within a degree of the sight line
        // to the cell behind it (11.3° off the x axis).
        let bearing = 0.3f32.atan2(1.5);
        hiding.note_reading(
            &g,
            Vector2::zeros(),
            bearing,
            Some((1.0 / bearing.cos(), 0.025)),
        );
        assert_eq!(behind_heard(&hiding), vec![behind]);
    }

    #[test]
    fn a_cell_out_of_every_viewpoints_reach_is_left_alone() {
        let g = geometry();
        let walls = Walls::new(&g, &[[0.5, -1.0, 0.5, 1.0]]);
        let mut hiding = Hiding::new(&g);
        stood_at(&mut hiding, (0.0, 0.0));
        let far = index_at(&g, 1.9, 0.0);
        assert!(hidden(&hiding, 1.5, &[far], &walls).is_empty());
        assert_eq!(hidden(&hiding, 4.0, &[far], &walls), vec![far]);
    }

    #[test]
    fn a_wall_seen_at_a_slant_does_not_hide_itself() {
        let g = geometry();
        // A wall along y = 0.3 from x = 0.2 to 1.8; the sensor near its line, so that the sight
        // line to its far end runs 10° off it, 20 cm within its band before it gets there.
        let mut walls = Walls::new(&g, &[[0.2, 0.3, 1.8, 0.3]]);
        let mut hiding = Hiding::new(&g);
        stood_at(&mut hiding, (0.0, 0.0));
        let far_end = index_at(&g, 1.7, 0.3);
        assert_eq!(
            hidden(&hiding, 4.0, &[far_end], &walls),
            vec![far_end],
            "without its own line, the wall lies in front of itself"
        );
        walls.normal = Some(Vector2::new(0.0, 1.0));
        assert!(hidden(&hiding, 4.0, &[far_end], &walls).is_empty());
    }

    #[test]
    fn viewpoints_closer_than_their_spacing_are_kept_once() {
        let mut viewpoints = Viewpoints::default();
        for k in 0..100 {
            viewpoints.note(Vector2::new(0.001 * k as f32, 0.0));
        }
        viewpoints.note(Vector2::new(1.0, 0.0));
        assert_eq!(viewpoints.kept.len(), 2);
    }

    #[test]
    fn a_look_is_due_every_so_many_readings() {
        let mut hiding = Hiding::new(&geometry());
        assert!(!hiding.due(READINGS_BETWEEN_LOOKS - 1));
        assert!(hiding.due(READINGS_BETWEEN_LOOKS));
        assert!(!hiding.due(READINGS_BETWEEN_LOOKS + 1));
        assert!(hiding.due(2 * READINGS_BETWEEN_LOOKS));
    }
}
