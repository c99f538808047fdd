//! The figures of the evaluation, computed from a map and the scene's ground truth.
//!
//! A map is a [`MapView`]: one value per cell of the fusion grid (2 cm cells, sensor at the
//! origin), either an occupancy probability ([`MapKind::Probability`], `None` for never observed)
//! or the basic method's raster ([`MapKind::Basic`], `Some(1.0)` on an arc, `None` elsewhere). A
//! cell is **occupied** when its value is above 0.5.
//!
//! - [`apparent_width`]: how wide a post looks. The occupied cells near the post's true position
//!   seed a region that grows through occupied neighbours (8-connected) within a radial window
//!   around the post's range; the width is the region's extent perpendicular to the sensor's ray
//!   to the post, cell centres' spread plus one cell.
//! - [`gap_between`]: whether the map shows a way between two posts. For every bearing between
//!   the posts' tangents, the most occupied cell along that ray within ± `depth` of the posts'
//!   near faces; the gap is resolved when the least of these maxima is below 0.5 — some ray
//!   between them crosses the posts' range band through free cells only. A never-observed cell
//!   counts as 0.5 in a probability map (it shows no gap) and as empty in the basic raster (which
//!   never marks anything free: there, resolved means nothing is drawn on some ray between them).
//!   Taking the maximum over a few cells of depth, rather than the probability on one line, keeps
//!   a line that happens to pass a cell behind the occupied band from faking a gap.
//! - [`wall_fit`]: for maps of walls (the room, the corner). The median distance from the centres
//!   of the occupied cells to the nearest true surface, and the fraction of the visible surface
//!   (sampled every cell along each wall; visible = in the line of sight, in range, inside the
//!   beams' reach) with an occupied cell centre within two cells. To tell why a figure is what it
//!   is, it also counts the occupied cells lying behind a wall (where no ping can pass to clear
//!   them), the median over the others, and the share of the visible walls whose own cell the
//!   map calls free.
//! - [`scene_walls`]: the same distances for a map taken from a moving sensor, and the share of
//!   every wall's whole length (no single viewpoint decides what is visible) with an occupied cell
//!   centre within a tolerance.
//! - Diagnostics: [`peak_near`], the highest value near a post (how close an undetected post
//!   came), and [`passing_readings`], the readings aimed between two posts that heard past them
//!   (the only direct evidence of a gap).

use sonar_fusion::GridGeometry;
use sonar_sim::{Vec2, Wall};

/// What the values of a [`MapView`] are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapKind {
    /// Occupancy probabilities; `None` = never observed (at the prior 0.5).
    Probability,
    /// The basic method's arcs: `Some(p > 0.5)` on an arc, `None` where nothing is drawn.
    Basic,
}

/// A cell is occupied above this probability unless a view says otherwise
/// ([`MapView::with_occupied_above`]): more likely occupied than not.
pub const OCCUPIED_ABOVE: f32 = 0.5;

/// One value per cell of a grid, row-major, row 0 at the lowest y (the fusion grid's layout).
#[derive(Debug, Clone)]
pub struct MapView {
    geometry: GridGeometry,
    kind: MapKind,
    cells: Vec<Option<f32>>,
    occupied_above: f32,
}

impl MapView {
    /// # Panics
    /// If `cells` does not hold one value per cell of `geometry`.
    pub fn new(geometry: GridGeometry, kind: MapKind, cells: Vec<Option<f32>>) -> Self {
        assert_eq!(cells.len(), geometry.len(), "one value per cell");
        Self {
            geometry,
            kind,
            cells,
            occupied_above: OCCUPIED_ABOVE,
        }
    }

    /// The same map with its cells counted occupied above `p` instead of [`OCCUPIED_ABOVE`]: the
    /// map as a consumer with another threshold reads it (a ROS map's `occupied_thresh`).
    pub fn with_occupied_above(self, p: f32) -> Self {
        Self {
            occupied_above: p,
            ..self
        }
    }

    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    pub fn kind(&self) -> MapKind {
        self.kind
    }

    pub fn value(&self, x: usize, y: usize) -> Option<f32> {
        self.cells[self.geometry.index(x, y)]
    }

    pub fn is_occupied(&self, x: usize, y: usize) -> bool {
        self.value(x, y).is_some_and(|p| p > self.occupied_above)
    }

    /// How occupied a cell counts for the gap test: its probability; a never-observed cell 0.5 in
    /// a probability map, 0 in the basic raster.
    pub fn score(&self, x: usize, y: usize) -> f32 {
        match (self.value(x, y), self.kind) {
            (Some(p), _) => p,
            (None, MapKind::Probability) => 0.5,
            (None, MapKind::Basic) => 0.0,
        }
    }

    /// Number of occupied cells.
    pub fn occupied_count(&self) -> usize {
        self.cells
            .iter()
            .filter(|c| c.is_some_and(|p| p > self.occupied_above))
            .count()
    }

    /// The cell containing world point `p`.
    pub fn cell_at(&self, p: Vec2) -> Option<(usize, usize)> {
        self.geometry
            .cell_at(nalgebra::Point2::new(p.x as f32, p.y as f32))
    }

    pub fn centre(&self, x: usize, y: usize) -> Vec2 {
        let c = self.geometry.cell_centre(x, y);
        Vec2::new(f64::from(c.x), f64::from(c.y))
    }

    fn resolution(&self) -> f64 {
        f64::from(self.geometry.resolution())
    }

    /// Cells whose centre lies within `radius` of `p`.
    fn cells_near(&self, p: Vec2, radius: f64) -> impl Iterator<Item = (usize, usize)> + '_ {
        let n = self.geometry.cells_per_side() as i64;
        let res = self.resolution();
        let origin = self.geometry.origin();
        let span = (radius / res).ceil() as i64 + 1;
        let cx = ((p.x - f64::from(origin.x)) / res).floor() as i64;
        let cy = ((p.y - f64::from(origin.y)) / res).floor() as i64;
        (cy - span..=cy + span)
            .flat_map(move |y| (cx - span..=cx + span).map(move |x| (x, y)))
            .filter(move |&(x, y)| x >= 0 && y >= 0 && x < n && y < n)
            .map(|(x, y)| (x as usize, y as usize))
            .filter(move |&(x, y)| (self.centre(x, y) - p).norm() <= radius)
    }
}

/// The apparent size of a post in a map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Width {
    /// Extent of the occupied region perpendicular to the sensor's ray, metres.
    pub width_m: f64,
    /// Cells in the region.
    pub cells: usize,
}

/// How wide the post at `centre` (radius `radius`) appears in `map`, the sensor at the origin;
/// `None` when no occupied cell lies within two cells of the post. The region is grown only
/// through cells whose range differs from the post centre's by at most `window_m`, so that it
/// measures the post's smear across the beam, not a connection to a wall behind it.
pub fn apparent_width(map: &MapView, centre: Vec2, radius: f64, window_m: f64) -> Option<Width> {
    let res = map.resolution();
    let range = centre.norm();
    let n = map.geometry.cells_per_side();
    let inside = |x: usize, y: usize| {
        map.is_occupied(x, y) && (map.centre(x, y).norm() - range).abs() <= window_m
    };
    let mut seen = vec![false; map.geometry.len()];
    let mut stack: Vec<(usize, usize)> = map
        .cells_near(centre, radius + 2.0 * res)
        .filter(|&(x, y)| inside(x, y))
        .collect();
    if stack.is_empty() {
        return None;
    }
    for &(x, y) in &stack {
        seen[map.geometry.index(x, y)] = true;
    }
    // Unit vector across the ray.
    let across = Vec2::new(-centre.y / range, centre.x / range);
    let (mut lo, mut hi, mut cells) = (f64::INFINITY, f64::NEG_INFINITY, 0);
    while let Some((x, y)) = stack.pop() {
        cells += 1;
        let t = map.centre(x, y).dot(across);
        lo = lo.min(t);
        hi = hi.max(t);
        for dy in -1i64..=1 {
            for dx in -1i64..=1 {
                let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                if nx < 0 || ny < 0 || nx >= n as i64 || ny >= n as i64 {
                    continue;
                }
                let (nx, ny) = (nx as usize, ny as usize);
                let i = map.geometry.index(nx, ny);
                if !seen[i] && inside(nx, ny) {
                    seen[i] = true;
                    stack.push((nx, ny));
                }
            }
        }
    }
    Some(Width {
        width_m: hi - lo + res,
        cells,
    })
}

/// The highest probability among the observed cells within two cells of the post at `centre`
/// (radius `radius`): how close a post that is not detected came to it. `None` if none of those
/// cells was observed (or, in the basic raster, drawn).
pub fn peak_near(map: &MapView, centre: Vec2, radius: f64) -> Option<f32> {
    map.cells_near(centre, radius + 2.0 * map.resolution())
        .filter_map(|(x, y)| map.value(x, y))
        .reduce(f32::max)
}

/// Readings aimed between the posts at `a` and `b` (bearings strictly between their centres) whose
/// range reaches more than `beyond_m` past the farther post's centre: pings that passed between
/// the posts, the only direct evidence of the gap.
pub fn passing_readings(
    readings: &[sonar_common::ipc::Reading],
    a: Vec2,
    b: Vec2,
    beyond_m: f64,
) -> usize {
    let (lo, hi) = {
        let (x, y) = (a.angle_deg(), b.angle_deg());
        (x.min(y), x.max(y))
    };
    let far = a.norm().max(b.norm()) + beyond_m;
    readings
        .iter()
        .filter(|r| {
            let deg = f64::from(r.angle_deg);
            deg > lo && deg < hi && r.is_valid_range() && f64::from(r.distance_m) > far
        })
        .count()
}

/// The gap test between two posts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    /// The least, over the bearings between the posts, of the most occupied cell on that ray
    /// within the depth window.
    pub min_score: f32,
    /// Bearing where that least value was found, degrees.
    pub bearing_deg: f64,
    /// `min_score < 0.5`.
    pub resolved: bool,
}

/// Whether `map` shows the gap between the posts at `a` and `b` (radius `radius`, the sensor at
/// the origin), looking at ranges within `depth_m` of their near faces. `None` if the posts
/// overlap as seen from the sensor (no bearing passes between them).
pub fn gap_between(map: &MapView, a: Vec2, b: Vec2, radius: f64, depth_m: f64) -> Option<Gap> {
    let res = map.resolution();
    let (a, b) = if a.angle_deg() <= b.angle_deg() {
        (a, b)
    } else {
        (b, a)
    };
    let half = |c: Vec2| (radius / c.norm()).asin();
    let lo = a.y.atan2(a.x) + half(a);
    let hi = b.y.atan2(b.x) - half(b);
    if lo >= hi {
        return None;
    }
    let face = (a.norm() + b.norm()) / 2.0 - radius;
    // Half a cell at the posts' range, across and along the ray.
    let bearing_step = res / 2.0 / face;
    let steps = ((hi - lo) / bearing_step).ceil().max(1.0) as usize;
    let radial = ((2.0 * depth_m) / (res / 2.0)).ceil() as usize;
    let mut best = Gap {
        min_score: f32::INFINITY,
        bearing_deg: f64::NAN,
        resolved: false,
    };
    for i in 0..=steps {
        let theta = lo + (hi - lo) * i as f64 / steps as f64;
        let dir = Vec2::new(theta.cos(), theta.sin());
        let worst = (0..=radial)
            .filter_map(|j| {
                let r = face - depth_m + 2.0 * depth_m * j as f64 / radial as f64;
                map.cell_at(dir * r)
            })
            .map(|(x, y)| map.score(x, y))
            .fold(f32::NEG_INFINITY, f32::max);
        if worst < best.min_score {
            best.min_score = worst;
            best.bearing_deg = theta.to_degrees();
        }
    }
    best.resolved = best.min_score < 0.5;
    Some(best)
}

/// How well a map draws the walls.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallFit {
    pub occupied_cells: usize,
    /// Median distance from the occupied cells' centres to the nearest true surface, metres;
    /// `None` without occupied cells.
    pub median_distance_m: Option<f64>,
    /// 90th percentile of the same.
    pub p90_distance_m: Option<f64>,
    /// Occupied cells more than `tolerance_cells` behind a true wall as seen from the sensor
    /// (their line of sight crosses a wall): where no reading can ever pass to clear them.
    pub behind_walls: usize,
    /// Median distance to the truth of the other occupied cells, metres.
    pub median_in_front_m: Option<f64>,
    /// Length of wall visible from the sensor, metres.
    pub visible_m: f64,
    /// Share of the visible wall length with an occupied cell centre within `tolerance_cells`.
    pub coverage: f64,
    /// Share of the visible wall length whose own cell the map calls free (p < 0.5): a wall the
    /// map contradicts.
    pub marked_free: f64,
}

/// Where the sensor can see: bearings (degrees, may extend past ±180) and range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Visibility {
    pub from_deg: f64,
    pub to_deg: f64,
    pub max_range_m: f64,
}

impl Visibility {
    fn sees_bearing(&self, deg: f64) -> bool {
        [-360.0, 0.0, 360.0]
            .iter()
            .any(|k| (self.from_deg..=self.to_deg).contains(&(deg + k)))
    }
}

/// Whether the straight path from the origin to `p` crosses a wall other than the one `p` lies on
/// (`own`; `usize::MAX` for none).
fn blocked(walls: &[Wall], own: usize, p: Vec2) -> bool {
    walls.iter().enumerate().any(|(i, w)| {
        if i == own {
            return false;
        }
        let e = w.b - w.a;
        let denom = p.cross(e);
        if denom.abs() < 1e-12 {
            return false;
        }
        let s = w.a.cross(e) / denom; // along the path, 0 at the sensor, 1 at p
        let u = w.a.cross(p) / denom; // along the wall
        s > 1e-9 && s < 1.0 - 1e-9 && (0.0..=1.0).contains(&u)
    })
}

/// Median and 90th percentile distance of the occupied cells to the truth (`distance` gives the
/// distance of a point to the nearest true surface), and the coverage of the visible `walls`.
pub fn wall_fit(
    map: &MapView,
    walls: &[Wall],
    distance: impl Fn(Vec2) -> f64,
    visibility: Visibility,
    tolerance_cells: f64,
) -> WallFit {
    let n = map.geometry.cells_per_side();
    let res = map.resolution();
    let tolerance = tolerance_cells * res;
    // Each occupied cell's distance to the truth, and whether it lies behind a wall (its line of
    // sight, stopped `tolerance` short, crosses one).
    let cells: Vec<(f64, bool)> = (0..n)
        .flat_map(|y| (0..n).map(move |x| (x, y)))
        .filter(|&(x, y)| map.is_occupied(x, y))
        .map(|(x, y)| {
            let p = map.centre(x, y);
            let r = p.norm().max(f64::MIN_POSITIVE);
            let pulled = p * ((r - tolerance).max(0.0) / r);
            (distance(p), blocked(walls, usize::MAX, pulled))
        })
        .collect();
    let sorted = |keep: fn(bool) -> bool| {
        let mut d: Vec<f64> = cells.iter().filter(|c| keep(c.1)).map(|c| c.0).collect();
        d.sort_by(f64::total_cmp);
        d
    };
    let d = sorted(|_| true);
    let in_front = sorted(|behind| !behind);
    let (mut visible, mut covered, mut free) = (0.0, 0.0, 0.0);
    for (i, w) in walls.iter().enumerate() {
        let len = (w.b - w.a).norm();
        let pieces = (len / res).round().max(1.0) as usize;
        let piece = len / pieces as f64;
        for k in 0..pieces {
            let p = w.a + (w.b - w.a) * ((k as f64 + 0.5) / pieces as f64);
            if p.norm() > visibility.max_range_m
                || !visibility.sees_bearing(p.angle_deg())
                || blocked(walls, i, p)
            {
                continue;
            }
            visible += piece;
            if map
                .cells_near(p, tolerance)
                .any(|(x, y)| map.is_occupied(x, y))
            {
                covered += piece;
            }
            if map
                .cell_at(p)
                .and_then(|(x, y)| map.value(x, y))
                .is_some_and(|v| v < 0.5)
            {
                free += piece;
            }
        }
    }
    let share = |part: f64| if visible > 0.0 { part / visible } else { 0.0 };
    WallFit {
        occupied_cells: d.len(),
        median_distance_m: quantile(&d, 0.5),
        p90_distance_m: quantile(&d, 0.9),
        behind_walls: d.len() - in_front.len(),
        median_in_front_m: quantile(&in_front, 0.5),
        visible_m: visible,
        coverage: share(covered),
        marked_free: share(free),
    }
}

/// The value at quantile `q` of `sorted` (nearest rank); `None` when empty.
pub fn quantile(sorted: &[f64], q: f64) -> Option<f64> {
    (!sorted.is_empty()).then(|| sorted[((sorted.len() - 1) as f64 * q).round() as usize])
}

/// How well a map drawn from many places draws every wall of its scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneWalls {
    pub occupied_cells: usize,
    /// Median distance from the occupied cells' centres to the nearest true surface, metres;
    /// `None` without occupied cells.
    pub median_distance_m: Option<f64>,
    /// 90th percentile of the same.
    pub p90_distance_m: Option<f64>,
    /// Share of the scene's whole wall length with an occupied cell centre within the tolerance.
    pub coverage: f64,
}

/// [`wall_fit`] for a map taken from a moving sensor: no single viewpoint decides what is
/// visible, so the coverage is of every wall's whole length (sampled every cell), with an
/// occupied cell centre within `tolerance_m`.
pub fn scene_walls(
    map: &MapView,
    walls: &[Wall],
    distance: impl Fn(Vec2) -> f64,
    tolerance_m: f64,
) -> SceneWalls {
    let n = map.geometry.cells_per_side();
    let res = map.resolution();
    let mut d: Vec<f64> = (0..n)
        .flat_map(|y| (0..n).map(move |x| (x, y)))
        .filter(|&(x, y)| map.is_occupied(x, y))
        .map(|(x, y)| distance(map.centre(x, y)))
        .collect();
    d.sort_by(f64::total_cmp);
    let (mut length, mut covered) = (0.0, 0.0);
    for w in walls {
        let len = (w.b - w.a).norm();
        let pieces = (len / res).round().max(1.0) as usize;
        let piece = len / pieces as f64;
        for k in 0..pieces {
            let p = w.a + (w.b - w.a) * ((k as f64 + 0.5) / pieces as f64);
            length += piece;
            if map
                .cells_near(p, tolerance_m)
                .any(|(x, y)| map.is_occupied(x, y))
            {
                covered += piece;
            }
        }
    }
    SceneWalls {
        occupied_cells: d.len(),
        median_distance_m: quantile(&d, 0.5),
        p90_distance_m: quantile(&d, 0.9),
        coverage: if length > 0.0 { covered / length } else { 0.0 },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_sim::{Scene, Surface};

    const RES: f32 = 0.02;

    /// A 200 × 200 grid of 2 cm cells (±2 m), every cell set to `fill`.
    fn map(kind: MapKind, fill: Option<f32>) -> MapView {
        let g = GridGeometry::new(200, RES);
        MapView::new(g, kind, vec![fill; g.len()])
    }

    fn set(m: &mut MapView, p: Vec2, v: Option<f32>) {
        let (x, y) = m.cell_at(p).unwrap();
        let i = m.geometry.index(x, y);
        m.cells[i] = v;
    }

    /// Sets every cell whose centre lies within `r` of `p`.
    fn disc(m: &mut MapView, p: Vec2, r: f64, v: Option<f32>) {
        let cells: Vec<_> = m.cells_near(p, r).collect();
        for (x, y) in cells {
            let i = m.geometry.index(x, y);
            m.cells[i] = v;
        }
    }

    /// Marks an arc of radius `r` (one cell thick) between bearings `from`..`to` degrees.
    fn arc(m: &mut MapView, r: f64, from: f64, to: f64, v: Option<f32>) {
        let mut deg = from;
        while deg <= to {
            let t = deg.to_radians();
            set(m, Vec2::new(t.cos(), t.sin()) * r, v);
            deg += 0.05;
        }
    }

    #[test]
    fn a_view_with_another_threshold_counts_only_the_cells_above_it() {
        let mut m = map(MapKind::Probability, Some(0.2));
        set(&mut m, Vec2::new(0.5, 0.0), Some(0.6));
        set(&mut m, Vec2::new(1.0, 0.0), Some(0.9));
        let (x, y) = m.cell_at(Vec2::new(0.5, 0.0)).unwrap();
        assert!(m.is_occupied(x, y));
        assert_eq!(m.occupied_count(), 2);
        let ros = m.with_occupied_above(0.65);
        assert!(!ros.is_occupied(x, y));
        assert_eq!(ros.occupied_count(), 1);
    }

    #[test]
    fn width_is_the_extent_across_the_ray_of_the_connected_region() {
        let mut m = map(MapKind::Probability, Some(0.2));
        // A straight bar across the ray at x = 0.97, from y = −0.09 to 0.09: 10 cells.
        for k in -5..5 {
            set(
                &mut m,
                Vec2::new(0.97, 0.01 + 0.02 * f64::from(k)),
                Some(0.9),
            );
        }
        let w = apparent_width(&m, Vec2::new(1.0, 0.0), 0.025, 0.25).unwrap();
        assert!((w.width_m - 0.20).abs() < 1e-6, "{w:?}");
        assert_eq!(w.cells, 10);
        // A separate blob beside it (a gap of one free cell) does not count …
        set(&mut m, Vec2::new(0.97, 0.13), Some(0.9));
        let w2 = apparent_width(&m, Vec2::new(1.0, 0.0), 0.025, 0.25).unwrap();
        assert_eq!(w2, w);
        // … but a diagonal neighbour joins it.
        set(&mut m, Vec2::new(0.99, 0.11), Some(0.9));
        let w3 = apparent_width(&m, Vec2::new(1.0, 0.0), 0.025, 0.25).unwrap();
        assert!((w3.width_m - 0.24).abs() < 1e-6, "{w3:?}");
        // Cells at exactly 0.5 are not occupied.
        set(&mut m, Vec2::new(0.97, -0.11), Some(0.5));
        assert_eq!(
            apparent_width(&m, Vec2::new(1.0, 0.0), 0.025, 0.25),
            Some(w3)
        );
    }

    #[test]
    fn width_is_measured_across_the_ray_and_stays_in_its_window() {
        let mut m = map(MapKind::Basic, None);
        // An arc of radius 1 m from −20° to 20° around a post at 1 m on the axis: its chord is
        // 2·sin 20° = 0.684 m.
        arc(&mut m, 0.99, -20.0, 20.0, Some(1.0));
        let w = apparent_width(&m, Vec2::new(1.0, 0.0), 0.025, 0.25).unwrap();
        assert!(
            (w.width_m - 2.0 * 0.99 * 20f64.to_radians().sin()).abs() < 0.03,
            "{w:?}"
        );
        // A radial spoke from the arc out to the wall at 2 m: only its part inside the window
        // counts, and it adds nothing across the ray.
        for k in 0..50 {
            set(&mut m, Vec2::new(1.0 + 0.02 * f64::from(k), 0.0), Some(1.0));
        }
        arc(&mut m, 1.99, -20.0, 20.0, Some(1.0));
        let w2 = apparent_width(&m, Vec2::new(1.0, 0.0), 0.025, 0.25).unwrap();
        assert!((w2.width_m - w.width_m).abs() < 1e-9, "{w2:?}");
        // The same post seen at 45°: a bar across that ray, 7 cells along the diagonal.
        let mut d = map(MapKind::Probability, Some(0.1));
        let c = Vec2::new(0.71, 0.71);
        let across = Vec2::new(-1.0, 1.0) * (0.5f64.sqrt());
        for k in -3..=3 {
            set(
                &mut d,
                c + across * (0.02 * 2f64.sqrt() * f64::from(k)),
                Some(0.8),
            );
        }
        let w = apparent_width(&d, c, 0.025, 0.25).unwrap();
        // Centres 6 diagonal steps apart (6·0.0283 m) plus one cell.
        assert!(
            (w.width_m - (6.0 * 0.02 * 2f64.sqrt() + 0.02)).abs() < 1e-6,
            "{w:?}"
        );
    }

    #[test]
    fn an_undetected_post_has_no_width() {
        let mut m = map(MapKind::Probability, Some(0.3));
        // Occupied cells 10 cm away from the post's surface do not seed.
        set(&mut m, Vec2::new(0.85, 0.0), Some(0.9));
        assert_eq!(apparent_width(&m, Vec2::new(1.0, 0.0), 0.025, 0.25), None);
        assert_eq!(
            apparent_width(&map(MapKind::Basic, None), Vec2::new(1.0, 0.0), 0.025, 0.25),
            None
        );
    }

    #[test]
    fn peak_near_a_post_shows_how_close_an_undetected_post_came() {
        let mut m = map(MapKind::Probability, None);
        assert_eq!(peak_near(&m, Vec2::new(1.0, 0.0), 0.025), None);
        set(&mut m, Vec2::new(0.97, 0.01), Some(0.45));
        set(&mut m, Vec2::new(0.99, -0.01), Some(0.3));
        set(&mut m, Vec2::new(0.89, 0.01), Some(0.9)); // 11 cm away: not near
        assert_eq!(peak_near(&m, Vec2::new(1.0, 0.0), 0.025), Some(0.45));
        assert_eq!(apparent_width(&m, Vec2::new(1.0, 0.0), 0.025, 0.25), None);
    }

    #[test]
    fn passing_readings_are_aimed_between_the_posts_and_reach_past_them() {
        use sonar_common::ipc::{Reading, flags};
        let r = |angle_deg: f32, distance_m: f32, flags: u32| Reading {
            angle_deg,
            distance_m,
            flags,
            ..Default::default()
        };
        let readings = [
            r(-3.0, 2.0, 0),             // between, hears the wall: passes
            r(3.0, 0.98, 0),             // between, hears a post
            r(5.0, 2.0, flags::NO_ECHO), // between, no range
            r(9.0, 2.0, 0),              // outside the posts' bearings (±8.5°)
            r(8.0, 1.3, 0),              // between, only 0.29 m past the posts' centres
        ];
        assert_eq!(passing_readings(&readings, A, B, 0.2), 2);
        assert_eq!(passing_readings(&readings, B, A, 0.2), 2);
        assert_eq!(passing_readings(&readings, A, B, 0.3), 1);
    }

    const A: Vec2 = Vec2::new(1.0, 0.15);
    const B: Vec2 = Vec2::new(1.0, -0.15);

    #[test]
    fn a_free_ray_between_the_posts_resolves_the_gap() {
        let mut m = map(MapKind::Probability, Some(0.2));
        disc(&mut m, A, 0.05, Some(0.9));
        disc(&mut m, B, 0.05, Some(0.9));
        let g = gap_between(&m, A, B, 0.025, 0.05).unwrap();
        assert!(g.resolved, "{g:?}");
        assert!((g.min_score - 0.2).abs() < 1e-6);
        assert!(g.bearing_deg.abs() < 6.0);
        // The same with the posts given the other way round.
        assert_eq!(gap_between(&m, B, A, 0.025, 0.05), Some(g));
    }

    #[test]
    fn a_bridge_anywhere_in_the_depth_window_closes_the_gap() {
        let mut m = map(MapKind::Probability, Some(0.2));
        disc(&mut m, A, 0.05, Some(0.9));
        disc(&mut m, B, 0.05, Some(0.9));
        // An occupied band at the posts' near face, r = 0.97, from one post to the other; the
        // line through the post centres (x = 1.0) stays free, so a test on that line alone would
        // call this a gap.
        arc(&mut m, 0.97, -10.0, 10.0, Some(0.6));
        for y in [-0.01, 0.01] {
            let (cx, cy) = m.cell_at(Vec2::new(1.0, y)).unwrap();
            assert_eq!(m.value(cx, cy), Some(0.2));
        }
        let g = gap_between(&m, A, B, 0.025, 0.05).unwrap();
        assert!(!g.resolved, "{g:?}");
        assert!((g.min_score - 0.6).abs() < 1e-6);
        // Beyond the window (10 cm in front) it does not matter.
        let mut far = map(MapKind::Probability, Some(0.2));
        arc(&mut far, 0.85, -10.0, 10.0, Some(0.9));
        assert!(gap_between(&far, A, B, 0.025, 0.05).unwrap().resolved);
        // One free ray through the bridge reopens it.
        let mut holed = m.clone();
        for r in [0.93, 0.95, 0.97, 0.99, 1.01] {
            set(&mut holed, Vec2::new(r, 0.0), Some(0.3));
            set(&mut holed, Vec2::new(r, -0.001), Some(0.3));
        }
        assert!(gap_between(&holed, A, B, 0.025, 0.05).unwrap().resolved);
    }

    #[test]
    fn unknown_cells_show_no_gap_in_a_probability_map_but_an_empty_basic_raster_does() {
        let unknown = map(MapKind::Probability, None);
        let g = gap_between(&unknown, A, B, 0.025, 0.05).unwrap();
        assert_eq!(g.min_score, 0.5);
        assert!(!g.resolved);
        let mut basic = map(MapKind::Basic, None);
        arc(&mut basic, 0.975, 5.0, 30.0, Some(1.0));
        arc(&mut basic, 0.975, -30.0, -5.0, Some(1.0));
        assert!(gap_between(&basic, A, B, 0.025, 0.05).unwrap().resolved);
        arc(&mut basic, 0.975, -30.0, 30.0, Some(1.0));
        assert!(!gap_between(&basic, A, B, 0.025, 0.05).unwrap().resolved);
        // Posts that overlap as seen from the sensor have no bearing between them.
        assert_eq!(
            gap_between(
                &basic,
                Vec2::new(1.0, 0.0),
                Vec2::new(1.5, 0.03),
                0.025,
                0.05
            ),
            None
        );
    }

    fn room() -> Scene {
        Scene::builtin("room").unwrap()
    }

    const ALL_ROUND: Visibility = Visibility {
        from_deg: -180.0,
        to_deg: 180.0,
        max_range_m: 4.0,
    };

    #[test]
    fn scene_walls_cover_the_whole_length_of_every_wall() {
        let scene = room();
        let mut m = map(MapKind::Probability, Some(0.2));
        for k in 0..60 {
            set(
                &mut m,
                Vec2::new(1.19, -0.59 + 0.02 * f64::from(k)),
                Some(0.9),
            );
        }
        let fit = scene_walls(&m, scene.walls(), |p| scene.distance_to_surface(p), 0.04);
        assert_eq!(fit.occupied_cells, 60);
        assert!((fit.median_distance_m.unwrap() - 0.01).abs() < 1e-6);
        // As in wall_fit: 1.24 m of the 9.6 m of wall, whatever a viewpoint would see.
        assert!((fit.coverage * 9.6 - 1.24).abs() < 1e-6, "{fit:?}");
        let empty = map(MapKind::Probability, None);
        let none = scene_walls(
            &empty,
            scene.walls(),
            |p| scene.distance_to_surface(p),
            0.04,
        );
        assert_eq!((none.occupied_cells, none.median_distance_m), (0, None));
        assert_eq!(none.coverage, 0.0);
    }

    #[test]
    fn wall_fit_measures_distance_to_the_truth_and_coverage_of_the_walls() {
        let scene = room();
        let mut m = map(MapKind::Probability, Some(0.2));
        // The cells along the wall x = 1.2 for |y| < 0.6: their centres lie 1 cm off it.
        for k in 0..60 {
            set(
                &mut m,
                Vec2::new(1.19, -0.59 + 0.02 * f64::from(k)),
                Some(0.9),
            );
        }
        let fit = wall_fit(
            &m,
            scene.walls(),
            |p| scene.distance_to_surface(p),
            ALL_ROUND,
            2.0,
        );
        assert_eq!(fit.occupied_cells, 60);
        assert!(
            (fit.median_distance_m.unwrap() - 0.01).abs() < 1e-6,
            "{fit:?}"
        );
        assert!((fit.visible_m - 4.0 * 2.4).abs() < 1e-9);
        // 1.2 m of wall marked, plus the 2 cm samples within 2 cells of either end: 62 samples.
        let covered = fit.coverage * fit.visible_m;
        assert!((covered - 1.24).abs() < 1e-6, "{covered}");
        // A ring of cells 30 cm inside the room raises the median past it.
        arc(&mut m, 0.9, -180.0, 180.0, Some(0.7));
        let fit2 = wall_fit(
            &m,
            scene.walls(),
            |p| scene.distance_to_surface(p),
            ALL_ROUND,
            2.0,
        );
        assert!(fit2.median_distance_m.unwrap() > 0.2, "{fit2:?}");
        assert!(fit2.p90_distance_m.unwrap() >= fit2.median_distance_m.unwrap());
        assert_eq!(fit2.coverage, fit.coverage);
        assert_eq!(fit.behind_walls, 0);
        assert_eq!(fit.median_in_front_m, fit.median_distance_m);

        // Cells 1 cm behind the wall are on it, not behind it; an arc of 1.7 m radius around the
        // +x wall lies behind it and is counted apart.
        let mut m = map(MapKind::Probability, Some(0.2));
        for k in 0..60 {
            set(
                &mut m,
                Vec2::new(1.21, -0.59 + 0.02 * f64::from(k)),
                Some(0.9),
            );
        }
        let on = wall_fit(
            &m,
            scene.walls(),
            |p| scene.distance_to_surface(p),
            ALL_ROUND,
            2.0,
        );
        assert_eq!((on.occupied_cells, on.behind_walls), (60, 0));
        arc(&mut m, 1.7, -30.0, 30.0, Some(0.9));
        let behind = wall_fit(
            &m,
            scene.walls(),
            |p| scene.distance_to_surface(p),
            ALL_ROUND,
            2.0,
        );
        assert_eq!(behind.behind_walls, behind.occupied_cells - 60);
        assert!(behind.behind_walls > 40, "{behind:?}");
        assert!(behind.median_distance_m.unwrap() > 0.2, "{behind:?}");
        assert!(
            (behind.median_in_front_m.unwrap() - 0.01).abs() < 1e-6,
            "{behind:?}"
        );
        // An empty map: no distance, nothing covered.
        let empty = wall_fit(
            &map(MapKind::Basic, None),
            scene.walls(),
            |p| scene.distance_to_surface(p),
            ALL_ROUND,
            2.0,
        );
        assert_eq!(empty.median_distance_m, None);
        assert_eq!(empty.coverage, 0.0);
        assert_eq!(empty.marked_free, 0.0);
        // The first map calls every cell but the marked ones free (0.2): the other three walls
        // and the unmarked rest of the +x wall at least (the marked part's samples lie on the
        // cell boundary x = 1.2, between the occupied and the free cells).
        assert!(fit.marked_free >= (9.6 - 1.24) / 9.6 - 1e-9, "{fit:?}");
        let mut unknown = map(MapKind::Probability, None);
        set(&mut unknown, Vec2::new(-1.19, 0.01), Some(0.1));
        set(&mut unknown, Vec2::new(-1.21, 0.01), Some(0.1));
        let f = wall_fit(
            &unknown,
            scene.walls(),
            |p| scene.distance_to_surface(p),
            ALL_ROUND,
            2.0,
        );
        // The sample at (−1.2, 0.01) falls in the cell whose centre is (−1.19, 0.01).
        assert!((f.marked_free * f.visible_m - 0.02).abs() < 1e-9, "{f:?}");
    }

    #[test]
    fn only_visible_walls_count() {
        let wall = |a: [f64; 2], b: [f64; 2]| Wall {
            a: a.into(),
            b: b.into(),
            surface: Surface::Hard,
        };
        // A 2 m wall at x = 1 hides the middle 4 m (±45°) of a 6 m wall at x = 2.
        let walls = [wall([1.0, -1.0], [1.0, 1.0]), wall([2.0, -3.0], [2.0, 3.0])];
        let m = map(MapKind::Probability, Some(0.2));
        let fit = wall_fit(&m, &walls, |_| 0.0, ALL_ROUND, 2.0);
        assert!((fit.visible_m - (2.0 + 2.0)).abs() < 0.03, "{fit:?}");
        // Looking only at ±30°: the near wall's part within it, none of the far wall's.
        let narrow = Visibility {
            from_deg: -30.0,
            to_deg: 30.0,
            max_range_m: 4.0,
        };
        let fit = wall_fit(&m, &walls, |_| 0.0, narrow, 2.0);
        let expect = 2.0 * 30f64.to_radians().tan();
        assert!((fit.visible_m - expect).abs() < 0.03, "{fit:?}");
        // Out of range.
        let short = Visibility {
            max_range_m: 0.5,
            ..ALL_ROUND
        };
        assert_eq!(wall_fit(&m, &walls, |_| 0.0, short, 2.0).visible_m, 0.0);
    }
}
