//! Where the cells are: the square grid centred on the world origin, and the polar coordinates of a
//! cell as seen from the sensor.
//!
//! Every kernel (the paper-style whole-grid pass and the cone kernel's row loop) obtains a cell's
//! range and bearing from [`polar`], with the same operands in the same order and an arctangent of
//! our own ([`atan2`], branch-free so that it vectorises), so the kernels agree to the last bit
//! and their grids can be compared exactly.

use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI, TAU};

use nalgebra::{Point2, Vector2};

/// A square grid of `cells × cells` cells of `resolution` metres, centred on the world origin (the
/// sensor's position when the robot does not move). Row-major, row 0 at the lowest y and column 0
/// at the lowest x, as in ROS `OccupancyGrid` and `sonar_common::ipc::GridHeader`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridGeometry {
    cells: usize,
    resolution: f32,
    origin: Vector2<f32>,
}

impl GridGeometry {
    /// The grid of `cells` cells per side of `resolution` metres. The caller has validated both
    /// (see [`crate::config::GridConfig`]).
    pub fn new(cells: usize, resolution: f32) -> Self {
        Self::centred_at(cells, resolution, Vector2::zeros())
    }

    /// [`Self::new`] with the grid's centre at `centre` instead of the world's origin.
    pub fn centred_at(cells: usize, resolution: f32, centre: Vector2<f32>) -> Self {
        let half = cells as f32 * resolution / 2.0;
        Self {
            cells,
            resolution,
            origin: centre - Vector2::new(half, half),
        }
    }

    /// Cells per side.
    pub fn cells_per_side(&self) -> usize {
        self.cells
    }

    /// Cells in the grid.
    pub fn len(&self) -> usize {
        self.cells * self.cells
    }

    /// Always false: a valid grid has at least one cell. Present because `len` is.
    pub fn is_empty(&self) -> bool {
        self.cells == 0
    }

    /// Cell edge, metres.
    pub fn resolution(&self) -> f32 {
        self.resolution
    }

    /// World position of the outer corner of cell (0, 0).
    pub fn origin(&self) -> Vector2<f32> {
        self.origin
    }

    /// Index of cell (`x`, `y`) in the row-major cell arrays.
    pub fn index(&self, x: usize, y: usize) -> usize {
        y * self.cells + x
    }

    /// World position of the centre of cell (`x`, `y`).
    pub fn cell_centre(&self, x: usize, y: usize) -> Point2<f32> {
        Point2::new(
            self.origin.x + (x as f32 + 0.5) * self.resolution,
            self.origin.y + (y as f32 + 0.5) * self.resolution,
        )
    }

    /// The cell containing world point `p`, if it lies on the grid.
    pub fn cell_at(&self, p: Point2<f32>) -> Option<(usize, usize)> {
        let u = (p.coords - self.origin) / self.resolution;
        let n = self.cells as f32;
        (u.x >= 0.0 && u.y >= 0.0 && u.x < n && u.y < n).then(|| (u.x as usize, u.y as usize))
    }

    /// Where a sensor at world position `p` sits relative to the cells.
    pub(crate) fn sensor_cell(&self, p: Vector2<f32>) -> SensorCell {
        // Continuous cell coordinates: cell i spans [i, i + 1). Splitting them into an integer cell
        // and a fraction is exact in f32, so a sensor that stays put (or returns to a position a
        // whole number of cells away, when that sum is exact) gets the same fraction bit for bit.
        let u = (p - self.origin) / self.resolution;
        let (cx, cy) = (u.x.floor(), u.y.floor());
        SensorCell {
            cell: [cx as i64, cy as i64],
            to_centre: [0.5 - (u.x - cx), 0.5 - (u.y - cy)],
            resolution: self.resolution,
        }
    }
}

/// The sensor's position in cell units: the cell it is in (possibly off the grid) and the vector
/// from the sensor to that cell's centre, in cells.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SensorCell {
    pub cell: [i64; 2],
    pub to_centre: [f32; 2],
    resolution: f32,
}

impl SensorCell {
    /// Range (metres) and bearing (radians, counter-clockwise from the world x axis, in [−π, π]) of
    /// the centre of the cell `offset` cells away from the sensor's cell.
    #[inline(always)]
    pub fn polar(&self, offset_x: i64, offset_y: i64) -> (f32, f32) {
        let dx = offset_x as f32 + self.to_centre[0];
        let dy = offset_y as f32 + self.to_centre[1];
        polar(dx, dy, self.resolution)
    }

    /// Cell edge, metres.
    pub fn resolution(&self) -> f32 {
        self.resolution
    }
}

/// Range (metres) and bearing of the point `dx`, `dy` cells from the sensor, cells of
/// `resolution` metres: the one formula every kernel uses (through [`SensorCell::polar`], or, in
/// the cone kernel's row loop, with `dy` fixed per row), so they agree to the last bit.
#[inline(always)]
pub(crate) fn polar(dx: f32, dy: f32, resolution: f32) -> (f32, f32) {
    ((dx * dx + dy * dy).sqrt() * resolution, atan2(dy, dx))
}

/// atan(t) − t = t³·Q(t²) on [0, 1]: Q's coefficients, highest power first (Chebyshev fit of degree
/// 7 with mpmath's `chebyfit`, |error of Q| < 1e-7, so atan within about an ulp of f32).
const ATAN_Q: [f32; 8] = [
    0.003_866_739,
    -0.020_026_748,
    0.048_914_32,
    -0.080_096_82,
    0.108_657_59,
    -0.142_570_45,
    0.199_986_82,
    -0.333_333_22,
];

/// The four-quadrant arctangent of `y`/`x`, in [−π, π], as `f32::atan2` to about an ulp: the
/// angle folded into [0, π/4] by selects, a polynomial there, unfolded by selects. Unlike the
/// C library's `atan2f` (a call per cell, with branches) it has no branches and no calls, so
/// the kernels' loops vectorise with it; and as it is plain IEEE arithmetic (+, ×, ÷, no fused
/// multiply-adds), every vector width gives the same bits as the scalar code.
#[inline(always)]
pub(crate) fn atan2(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    let steep = ay > ax;
    let (num, den) = if steep { (ax, ay) } else { (ay, ax) };
    // 0 / 0 only at the origin, whose angle is 0 (as atan2(±0, +0)).
    let t = num / den;
    let t = if den > 0.0 { t } else { 0.0 };
    let t2 = t * t;
    let mut q = ATAN_Q[0];
    for c in &ATAN_Q[1..] {
        q = q * t2 + c;
    }
    let a = t + t * t2 * q;
    // The diagonals exactly, as the C library has them: the stepper's beam edges fall on them
    // (15° + 30°), and so do whole lines of cells, which would otherwise flip in or out of a cone
    // on an ulp.
    let a = if t == 1.0 { FRAC_PI_4 } else { a };
    let a = if steep { FRAC_PI_2 - a } else { a };
    let a = if x.is_sign_negative() { PI - a } else { a };
    a.copysign(y)
}

/// cos x = C(x²) on [0, π/2]: C's coefficients, highest power first (Chebyshev fit of degree 5
/// in x² with mpmath's `chebyfit`, |error| < 3e-10; in f32 arithmetic within 1.4e-7 of the C
/// library's `cosf`, and exactly 1 at 0).
const COS_C: [f32; 6] = [
    -2.605_065_7e-7,
    2.476_011e-5,
    -0.001_388_836_1,
    0.041_666_634,
    -0.5,
    1.0,
];

/// π − `PI`, rounded to f32: f32's π is 8.7e-8 above π.
const PI_LESS_F32_PI: f32 = -8.742_278e-8;

/// The cosine of `x` in [−π, π], as `f32::cos` to about an ulp: folded into [0, π/2] by
/// selects, a polynomial there. Like [`atan2`] it has no branches and no calls, so the kernels'
/// loops vectorise with it where the C library's `cosf` is a call per cell.
#[inline(always)]
pub(crate) fn cos(x: f32) -> f32 {
    let a = x.abs();
    let far = a > FRAC_PI_2;
    // π − a in two parts: f32's π is 8.7e-8 off π, which a quarter turn from it is as much off
    // the cosine.
    let a = if far { (PI - a) + PI_LESS_F32_PI } else { a };
    let u = a * a;
    let mut c = COS_C[0];
    for k in &COS_C[1..] {
        c = c * u + k;
    }
    if far { -c } else { c }
}

/// A box (lower and upper corners, world metres) holding the sector of a lobe seen from
/// `position`, `lobe` radians each side of `axis`, from `range` less `depth` to `range` plus
/// `depth`: the square about the point at `range` on the axis that holds every point of it.
pub(crate) fn sector_box(
    position: Vector2<f32>,
    axis: f32,
    range: f32,
    lobe: f32,
    depth: f32,
) -> (Vector2<f32>, Vector2<f32>) {
    let middle = position + Vector2::new(axis.cos(), axis.sin()) * range;
    // The sector's farthest points from its middle are its corners.
    let corner = |r: f32| Vector2::new(r * lobe.cos() - range, r * lobe.sin()).norm();
    let reach = corner(range + depth)
        .max(corner((range - depth).max(0.0)))
        .max(depth);
    let reach = Vector2::repeat(reach);
    (middle - reach, middle + reach)
}

/// `angle` wrapped into [−π, π].
pub(crate) fn wrap_angle(angle: f32) -> f32 {
    angle - TAU * (angle / TAU).round()
}

/// The angle between two bearings folded into [0, π/2] (a wall answers from either side).
pub(crate) fn incidence(a: f32, b: f32) -> f32 {
    let d = wrap_angle(a - b).abs();
    if d > FRAC_PI_2 { PI - d } else { d }
}

/// Signed angle of bearing `bearing` off the beam axis `axis`, both in [−π, π]; the difference is
/// brought back into [−π, π] with selects rather than a division so the kernels' loops vectorise.
#[inline(always)]
pub(crate) fn off_axis(bearing: f32, axis: f32) -> f32 {
    let d = bearing - axis;
    let d = if d > PI { d - TAU } else { d };
    if d < -PI { d + TAU } else { d }
}

/// Walks the unit squares of a grid crossed by the line `start + direction · t` for t from
/// `first` to `last` (in order, each once), calling `visit(x, y, enter, leave)` with the square
/// and the stretch of t inside it, until `visit` says true; whether it did.
pub(crate) fn walk(
    start: Vector2<f32>,
    direction: Vector2<f32>,
    first: f32,
    last: f32,
    mut visit: impl FnMut(i64, i64, f32, f32) -> bool,
) -> bool {
    let at = start + direction * first;
    let (mut x, mut y) = (at.x.floor() as i64, at.y.floor() as i64);
    // Per axis: the step, the t at which the line next crosses a square's edge, and the t
    // between two such crossings.
    let axis = |p: f32, d: f32, cell: i64| {
        if d > 0.0 {
            (1, first + ((cell + 1) as f32 - p) / d, 1.0 / d)
        } else if d < 0.0 {
            (-1, first + (cell as f32 - p) / d, -1.0 / d)
        } else {
            (0, f32::INFINITY, f32::INFINITY)
        }
    };
    let (step_x, mut next_x, delta_x) = axis(at.x, direction.x, x);
    let (step_y, mut next_y, delta_y) = axis(at.y, direction.y, y);
    let mut enter = first;
    loop {
        let leave = next_x.min(next_y).min(last);
        if visit(x, y, enter, leave) {
            return true;
        }
        if leave >= last {
            return false;
        }
        enter = leave;
        if next_x < next_y {
            x += step_x;
            next_x += delta_x;
        } else {
            y += step_y;
            next_y += delta_y;
        }
    }
}

/// Boxes (lower and upper corners, world metres) kept as four columns, so that whether any of
/// them meets a box (overlaps it, edges included) is asked of [`BOX_LANES`] at a time: a moving
/// robot asks it of hundreds of boxes for each of thousands of weak echoes at every sweep's end
/// (issue 29).
#[derive(Debug, Clone, Default)]
pub(crate) struct Boxes {
    /// [`BOX_LANES`] boxes at a time, the last lanes of the last empty (they meet nothing).
    lanes: Vec<BoxLanes>,
    len: usize,
}

/// How many boxes [`Boxes::any_meets`] compares at once, without a branch between them.
const BOX_LANES: usize = 8;

#[derive(Debug, Clone, Copy)]
struct BoxLanes {
    lower_x: [f32; BOX_LANES],
    lower_y: [f32; BOX_LANES],
    upper_x: [f32; BOX_LANES],
    upper_y: [f32; BOX_LANES],
}

impl BoxLanes {
    /// Empty boxes: lower corners above every upper corner, so none meets anything.
    const EMPTY: Self = Self {
        lower_x: [f32::INFINITY; BOX_LANES],
        lower_y: [f32::INFINITY; BOX_LANES],
        upper_x: [f32::NEG_INFINITY; BOX_LANES],
        upper_y: [f32::NEG_INFINITY; BOX_LANES],
    };
}

impl Boxes {
    pub fn push(&mut self, (lower, upper): (Vector2<f32>, Vector2<f32>)) {
        let lane = self.len % BOX_LANES;
        if lane == 0 {
            self.lanes.push(BoxLanes::EMPTY);
        }
        if let Some(last) = self.lanes.last_mut() {
            last.lower_x[lane] = lower.x;
            last.lower_y[lane] = lower.y;
            last.upper_x[lane] = upper.x;
            last.upper_y[lane] = upper.y;
        }
        self.len += 1;
    }

    pub fn clear(&mut self) {
        self.lanes.clear();
        self.len = 0;
    }

    /// Whether one of the boxes meets (overlaps, edges included) `area`, lower and upper corners.
    pub fn any_meets(&self, (lower, upper): (Vector2<f32>, Vector2<f32>)) -> bool {
        self.lanes.iter().any(|b| {
            (0..BOX_LANES).fold(false, |any, i| {
                any | ((b.lower_x[i] <= upper.x)
                    & (lower.x <= b.upper_x[i])
                    & (b.lower_y[i] <= upper.y)
                    & (lower.y <= b.upper_y[i]))
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Whether two boxes (lower and upper corners) overlap, one pair at a time.
    fn boxes_meet(a: (Vector2<f32>, Vector2<f32>), b: (Vector2<f32>, Vector2<f32>)) -> bool {
        a.0.x <= b.1.x && b.0.x <= a.1.x && a.0.y <= b.1.y && b.0.y <= a.1.y
    }

    #[test]
    fn default_grid_is_centred_on_the_origin() {
        let g = GridGeometry::new(400, 0.02);
        assert_eq!(g.origin(), Vector2::new(-4.0, -4.0));
        assert_eq!(g.cell_at(Point2::new(0.001, 0.001)), Some((200, 200)));
        assert_eq!(g.cell_at(Point2::new(-0.001, -0.001)), Some((199, 199)));
        assert_eq!(g.cell_at(Point2::new(4.1, 0.0)), None);
        let c = g.cell_centre(200, 199);
        assert!((c.x - 0.01).abs() < 1e-6 && (c.y + 0.01).abs() < 1e-6);
    }

    #[test]
    fn a_grid_centred_elsewhere_is_shifted_whole() {
        let g = GridGeometry::centred_at(400, 0.02, Vector2::new(3.0, 1.5));
        assert_eq!(g.origin(), Vector2::new(-1.0, -2.5));
        assert_eq!(g.cell_at(Point2::new(3.001, 1.501)), Some((200, 200)));
        assert_eq!(g.cell_at(Point2::new(-1.01, 0.0)), None);
        assert_eq!(g.cell_at(Point2::new(6.99, 5.49)), Some((399, 399)));
    }

    #[test]
    fn polar_of_cells_around_a_sensor_on_a_corner() {
        let g = GridGeometry::new(4, 1.0);
        let s = g.sensor_cell(Vector2::zeros());
        assert_eq!(s.cell, [2, 2]);
        let (r, a) = s.polar(0, 0);
        assert!((r - 0.5f32.hypot(0.5)).abs() < 1e-6);
        assert!((a - PI / 4.0).abs() < 1e-6);
        let (_, a) = s.polar(-1, -1);
        assert!((a + 3.0 * PI / 4.0).abs() < 1e-6);
    }

    #[test]
    fn whole_cell_moves_keep_the_fraction() {
        // Binary fractions keep the arithmetic exact, so the fraction survives the move.
        let g = GridGeometry::new(64, 0.25);
        let a = g.sensor_cell(Vector2::new(0.125, -0.0625));
        let b = g.sensor_cell(Vector2::new(0.125 + 1.5, -0.0625 - 0.75));
        assert_eq!(a.to_centre.map(f32::to_bits), b.to_centre.map(f32::to_bits));
        assert_eq!([b.cell[0] - a.cell[0], b.cell[1] - a.cell[1]], [6, -3]);
        let c = g.sensor_cell(Vector2::new(0.1, -0.0625));
        assert_ne!(a.to_centre.map(f32::to_bits), c.to_centre.map(f32::to_bits));
    }

    #[test]
    fn cos_is_within_a_few_ulps_of_the_exact_cosine_over_a_half_turn_each_way() {
        // A dense sweep of [−π, π] and its ends, against f64's cosine: within 1.5e-7 (about
        // two ulps of 1; the C library's cosf is within half an ulp), exactly 1 at 0, even.
        let mut worst = 0.0f64;
        for i in 0..=400_000 {
            let x =
                (-std::f64::consts::PI + std::f64::consts::TAU * f64::from(i) / 400_000.0) as f32;
            let x = x.clamp(-PI, PI);
            let err = (f64::from(cos(x)) - f64::from(x).cos()).abs();
            assert!(
                err <= 1.5e-7,
                "cos({x}) = {}, exact {}",
                cos(x),
                f64::from(x).cos()
            );
            assert_eq!(cos(x).to_bits(), cos(-x).to_bits());
            worst = worst.max(err);
        }
        assert_eq!(cos(0.0), 1.0);
        assert!(worst > 0.0, "compared against nothing");
    }

    #[test]
    fn atan2_is_within_two_epsilons_of_the_exact_angle_everywhere() {
        // Every octant, the axes, both zeros, tiny and huge operands, and a dense sweep of
        // directions: against f64's atan2 (exact to f32's precision).
        let mut checked = 0;
        let mut worst = 0.0f64;
        let mut check = |y: f32, x: f32| {
            let got = atan2(y, x);
            let exact = f64::from(y).atan2(f64::from(x));
            let ulp = f64::from(f32::EPSILON) * exact.abs().max(f64::from(f32::MIN_POSITIVE));
            let err = (f64::from(got) - exact).abs() / ulp.max(f64::from(f32::EPSILON) / 2.0);
            assert!(err <= 2.0, "atan2({y}, {x}) = {got}, exact {exact}");
            assert!((-PI..=PI).contains(&got), "atan2({y}, {x}) = {got}");
            worst = worst.max(err);
            checked += 1;
        };
        for i in 0..200_000 {
            let angle = -std::f64::consts::PI + std::f64::consts::TAU * f64::from(i) / 200_000.0;
            for r in [1e-3f64, 0.7, 3.0, 451.5] {
                check((r * angle.sin()) as f32, (r * angle.cos()) as f32);
            }
        }
        for (y, x) in [
            (0.0, 1.0),
            (1.0, 0.0),
            (0.0, -1.0),
            (-1.0, 0.0),
            (1.0, 1.0),
            (-1.0, -1.0),
            (3.0, -3.0),
            (1e-30, 1.0),
            (1.0, 1e-30),
            (-400.5, 0.5),
        ] {
            check(y, x);
        }
        assert!(checked > 800_000 && worst > 0.0, "{checked} {worst}");
        assert_eq!(atan2(0.0, 0.0), 0.0);
        for (y, x) in [(1.0f32, 1.0f32), (2.5, -2.5), (-0.5, 0.5), (-7.0, -7.0)] {
            assert_eq!(atan2(y, x), y.atan2(x), "the diagonal ({y}, {x})");
        }
        assert_eq!(atan2(0.0, -1.0), PI);
        assert_eq!(atan2(-0.0, -1.0), -PI);
    }

    #[test]
    fn off_axis_wraps_across_the_back() {
        assert!((off_axis(3.0, -3.0) - (6.0 - TAU)).abs() < 1e-6);
        assert!((off_axis(-3.0, 3.0) - (TAU - 6.0)).abs() < 1e-6);
        assert!((off_axis(0.25, -0.25) - 0.5).abs() < 1e-6);
        assert!((wrap_angle(7.0) - (7.0 - TAU)).abs() < 1e-6);
    }

    #[test]
    fn a_walk_crosses_every_square_the_line_passes_through_once_and_in_order() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for _ in 0..500 {
            let start = Vector2::new(rng.random_range(0.0..50.0), rng.random_range(0.0..50.0));
            let angle: f32 = rng.random_range(0.0..std::f32::consts::TAU);
            let direction = Vector2::new(angle.cos(), angle.sin());
            let (first, last) = (1.0, rng.random_range(1.0..40.0));
            let mut walked = Vec::new();
            walk(start, direction, first, last, |x, y, enter, leave| {
                assert!(enter <= leave);
                walked.push((x, y));
                false
            });
            for pair in walked.windows(2) {
                let (a, b) = (pair[0], pair[1]);
                assert_eq!((a.0 - b.0).abs() + (a.1 - b.1).abs(), 1, "{walked:?}");
            }
            // Every point of the line, sampled finely, lies in a square walked, away from the
            // squares' edges (where rounding may put it either side).
            let samples = ((last - first) * 100.0) as usize;
            for k in 0..=samples {
                let p = start + direction * (first + k as f32 * 0.01);
                let off_edge = |v: f32| (v - v.round()).abs() > 1e-3;
                if off_edge(p.x) && off_edge(p.y) {
                    let square = (p.x.floor() as i64, p.y.floor() as i64);
                    assert!(walked.contains(&square), "{square:?} not walked");
                }
            }
        }
    }

    #[test]
    fn boxes_that_touch_meet() {
        let a = (Vector2::new(0.0, 0.0), Vector2::new(1.0, 1.0));
        assert!(boxes_meet(
            a,
            (Vector2::new(1.0, 0.5), Vector2::new(2.0, 2.0))
        ));
        assert!(!boxes_meet(
            a,
            (Vector2::new(1.1, 0.5), Vector2::new(2.0, 2.0))
        ));
    }

    proptest! {
        /// Asked eight at a time, the boxes meet a box exactly when one of them does, one by one.
        #[test]
        fn boxes_meet_an_area_as_one_of_them_does(
            boxes in prop::collection::vec(
                (-5.0f32..5.0, -5.0f32..5.0, 0.0f32..2.0, 0.0f32..2.0),
                0..40,
            ),
            area in (-5.0f32..5.0, -5.0f32..5.0, 0.0f32..2.0, 0.0f32..2.0),
        ) {
            let as_box = |(x, y, w, h): (f32, f32, f32, f32)| {
                (Vector2::new(x, y), Vector2::new(x + w, y + h))
            };
            let mut columns = Boxes::default();
            for &b in &boxes {
                columns.push(as_box(b));
            }
            let area = as_box(area);
            prop_assert_eq!(
                columns.any_meets(area),
                boxes.iter().any(|&b| boxes_meet(as_box(b), area))
            );
        }
    }
}
