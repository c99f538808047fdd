//! Walls between the feet: patches heard from different viewpoints that lie on one line.
//!
//! A specular wall answers a sensor only at the foot of its perpendicular, so each viewpoint's
//! region of constant depth ([`crate::regions`]) gives a short patch of wall around its own foot.
//! Two patches from different sensor positions that face the same way and lie on the same line
//! are one wall (a post or a corner, heard from two places, gives patches square to two different
//! bearings), and the stretch between them is wall too, unless a reading saw through it (the
//! mapper checks that against the grid before it fills the stretch).

use std::collections::VecDeque;

use rustc_hash::FxHashMap;

use nalgebra::Vector2;

use crate::geometry::{sector_box, wrap_angle};

/// Two patches face the same way within this angle, radians (3°).
const SAME_FACING: f32 = 3.0 * std::f32::consts::PI / 180.0;
/// Two patches lie on one line while their offsets differ by at most this much, metres …
pub(crate) const SAME_LINE_M: f32 = 0.03;
/// … plus this fraction of the farther patch's range.
const SAME_LINE_FRACTION: f32 = 0.01;
/// Patches from sensor positions closer than this are from one viewpoint (its repeated sweeps),
/// and say nothing about the wall between their feet.
pub(crate) const OTHER_VIEWPOINT_M: f32 = 0.1;
/// The longest stretch filled between two patches, metres: beyond it, a wall heard at two feet
/// is as likely to be two walls in line (a corridor's sides across a doorway).
pub(crate) const LONGEST_STRETCH_M: f32 = 4.0;
/// Two walls meet at a corner when their facings differ by at least this angle, radians (30°):
/// closer to parallel, their lines cross far from where either was heard.
const CORNER_ANGLE: f32 = 30.0 * std::f32::consts::PI / 180.0;
/// A patch's wall is followed this far beyond its ends, metres, to a corner.
const CORNER_REACH_M: f32 = 1.5;
/// A patch or a region repeats one kept only if their bearings (a patch's facing, a region's
/// middle and half-width) differ by at most this much, radians (0.5°, a twelfth of a 6° reading):
/// where two walls' lines cross moves by a wall's range per radian of either's facing, so a patch
/// 3° off the kept one (the same wall to [`SAME_FACING`]) may put their corner beyond the echo
/// that confirms it (the paper's corner scene: 80 % of its walls drawn, 49 % with 3°).
pub(crate) const SAME_BEARING: f32 = 0.5 * std::f32::consts::PI / 180.0;
/// Patches kept; the oldest are forgotten first.
const KEPT: usize = 4096;
/// Patches on one line are put on the line through their feet when the feet lie this far apart
/// along it at least, metres.
const FEET_APART_M: f32 = 0.5;
/// A wall is followed from its patch along its line this far at most to a corner, metres: on the
/// suite's `tune` split 2 m drew less of the walls, 4 m as much at less precision.
pub(crate) const CORNER_WALL_M: f32 = 3.0;
/// Regions heard kept, to confirm corners; the oldest are forgotten first.
const KEPT_ECHOES: usize = 4096;
/// A region confirms a corner whose bearing lies this far outside its first and last readings'
/// axes, radians (half a 6° reading).
const ECHO_MARGIN: f32 = 3.0 * std::f32::consts::PI / 180.0;

/// A region's patch: the line it lies on and the stretch of it that it covers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Patch {
    /// World bearing from the sensor to the wall, square to it.
    pub facing: f32,
    /// The line's distance from the world origin along `facing`.
    pub offset: f32,
    /// Where the patch begins and ends along the line (coordinates along the line's direction).
    pub from: f32,
    pub to: f32,
    pub range: f32,
    pub sensor: Vector2<f32>,
    /// The patch's ends in the world, at `from` and at `to`.
    pub ends: [Vector2<f32>; 2],
    /// The unit normal along `facing` and the line's direction ([`frame`]), kept: every pair of
    /// patches [`Lines::join_ends`] looks at needs both of them.
    normal: Vector2<f32>,
    along: Vector2<f32>,
    /// How far the offsets of the patches it stands for ([`Self::absorb`]) lay from its own.
    spread: f32,
    /// Whether a patch from another viewpoint lies on its line ([`Self::on_line_with`]): its
    /// wall's line is known from two places.
    confirmed: bool,
    /// Where it was heard: the foot of the perpendicular from its sensor, at its range along the
    /// bearing it was heard from. A foot lies on the wall to within the range's error whatever
    /// the bearing's; the line through several viewpoints' feet is steadier than any one
    /// bearing ([`Lines::add`]).
    foot: Vector2<f32>,
    /// Whether its wall is followed on (to a corner, to a jamb) only once [`Self::confirmed`]:
    /// a one-ended region's patch ([`Self::needing_confirmation`]).
    needs_confirming: bool,
}

impl Patch {
    /// The patch a region at `range` along `facing` from `sensor` draws, `half_angle` wide each
    /// side as seen from the sensor.
    pub fn new(sensor: Vector2<f32>, facing: f32, range: f32, half_angle: f32) -> Self {
        let (normal, along) = frame(facing);
        let foot = sensor + normal * range;
        let half = range * half_angle.tan();
        let middle = along.dot(&foot);
        Self {
            facing,
            offset: normal.dot(&foot),
            from: middle - half,
            to: middle + half,
            range,
            sensor,
            ends: [foot - along * half, foot + along * half],
            normal,
            along,
            spread: 0.0,
            confirmed: false,
            foot,
            needs_confirming: false,
        }
    }

    /// The patch, its wall followed on only once another viewpoint's patch lies on its line: a
    /// one-ended region's, whose bearing is known from its natural end alone (on the suite's
    /// `tune` split, `srf05`, 2.7° off its wall's at the median and 5–6° at the upper quartile).
    /// Followed on from it for metres, a wall a few degrees off ran beside the true one or
    /// across the room; on its line with another viewpoint's patch, both are put on the line
    /// through their feet first.
    pub fn needing_confirmation(self) -> Self {
        Self {
            needs_confirming: true,
            ..self
        }
    }

    /// Whether its wall may be followed on: confirmed; else, needing no confirmation, if
    /// `unconfirmed` (what the caller allows an unconfirmed patch); else if `between_feet`
    /// says so (asked only then).
    fn followed(&self, unconfirmed: bool, between_feet: impl FnOnce() -> bool) -> bool {
        self.confirmed
            || if self.needs_confirming {
                between_feet()
            } else {
                unconfirmed
            }
    }

    /// Puts it on the line square to `normal` at `offset` (facing along `normal`), its ends
    /// projected onto that line.
    fn move_to_line(&mut self, normal: Vector2<f32>, offset: f32) {
        let along = Vector2::new(-normal.y, normal.x);
        let project = |p: Vector2<f32>| p - normal * (normal.dot(&p) - offset);
        self.ends = self.ends.map(project);
        self.facing = normal.y.atan2(normal.x);
        self.normal = normal;
        self.along = along;
        self.offset = offset;
        self.from = along.dot(&self.ends[0]);
        self.to = along.dot(&self.ends[1]);
    }

    /// Stands for `other` too if `other` repeats it ([`Self::repeats`]), widening its spread to
    /// `other`'s offset; returns whether it does.
    fn absorb(&mut self, other: &Patch) -> bool {
        let repeats = other.repeats(self);
        if repeats {
            self.spread = self.spread.max((other.offset - self.offset).abs());
            self.confirmed |= other.confirmed;
            self.needs_confirming &= other.needs_confirming;
        }
        repeats
    }

    /// Whether this patch repeats `kept`: the same wall heard again from the same viewpoint
    /// (its next sweeps, a head standing still), both ends where `kept`'s are within the
    /// tolerance of one line. Such a patch says nothing `kept` does not.
    fn repeats(&self, kept: &Patch) -> bool {
        let tolerance = SAME_LINE_M + SAME_LINE_FRACTION * self.range.max(kept.range);
        (self.sensor - kept.sensor).norm() < OTHER_VIEWPOINT_M
            && wrap_angle(self.facing - kept.facing).abs() <= SAME_BEARING
            && self
                .ends
                .iter()
                .zip(&kept.ends)
                .all(|(end, kept_end)| (end - kept_end).norm() <= tolerance)
    }

    /// Whether `point` lies on this patch's line, within `tolerance`, and within
    /// [`CORNER_REACH_M`] of the patch.
    fn reaches(&self, point: Vector2<f32>, tolerance: f32) -> bool {
        self.passes_through(point, tolerance)
            && self
                .ends
                .iter()
                .any(|end| (end - point).norm() <= CORNER_REACH_M)
    }

    /// Whether `point` lies on this patch's line, within `tolerance`.
    fn passes_through(&self, point: Vector2<f32>, tolerance: f32) -> bool {
        (self.normal.dot(&point) - self.offset).abs() <= tolerance
    }

    /// The stretch of this patch's wall from its nearer end to `corner`, a point of its line
    /// beyond the patch, at most [`CORNER_WALL_M`] from that end.
    fn towards(&self, corner: Vector2<f32>) -> Option<Stretch> {
        let t = self.along.dot(&corner);
        let end = if t > self.to {
            self.ends[1]
        } else if t < self.from {
            self.ends[0]
        } else {
            return None;
        };
        ((corner - end).norm() <= CORNER_WALL_M).then_some(Stretch {
            a: end,
            b: corner,
            facing: self.facing,
            readings: 1,
        })
    }

    /// Whether it was heard from `sensor` (one viewpoint) square to `facing` (one bearing).
    fn heard_as(&self, sensor: Vector2<f32>, facing: f32) -> bool {
        (self.sensor - sensor).norm() < OTHER_VIEWPOINT_M
            && wrap_angle(self.facing - facing).abs() <= SAME_BEARING
    }

    fn on_line_with(&self, other: &Patch) -> bool {
        wrap_angle(self.facing - other.facing).abs() <= SAME_FACING
            && (self.offset - other.offset).abs()
                <= SAME_LINE_M + SAME_LINE_FRACTION * self.range.max(other.range)
            && (self.sensor - other.sensor).norm() >= OTHER_VIEWPOINT_M
    }
}

/// Where the walls of `a` and `b` meet, if they face at least 30° apart and each one's sensor
/// lies in front of the other's wall (the corner is concave as seen from where they were heard).
fn concave_corner(a: &Patch, b: &Patch) -> Option<Vector2<f32>> {
    let apart = wrap_angle(a.facing - b.facing).abs();
    if !(CORNER_ANGLE..=std::f32::consts::PI - CORNER_ANGLE).contains(&apart) {
        return None;
    }
    let (na, nb) = (a.normal, b.normal);
    // na·p = a.offset and nb·p = b.offset.
    let det = na.x * nb.y - na.y * nb.x;
    let p = Vector2::new(
        (a.offset * nb.y - b.offset * na.y) / det,
        (na.x * b.offset - nb.x * a.offset) / det,
    );
    (nb.dot(&a.sensor) < b.offset && na.dot(&b.sensor) < a.offset).then_some(p)
}

/// The unit normal (towards the wall, away from the sensor) and the line's direction.
fn frame(facing: f32) -> (Vector2<f32>, Vector2<f32>) {
    let (s, c) = facing.sin_cos();
    (Vector2::new(c, s), Vector2::new(-s, c))
}

/// A stretch of wall between two patches: its ends, the bearing it is faced from, and as how
/// many readings it counts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Stretch {
    pub a: Vector2<f32>,
    pub b: Vector2<f32>,
    pub facing: f32,
    /// A stretch was not heard: it counts as one reading for each pair of hearings that drew it
    /// (a wall's patch heard again joins the other wall's every hearing to their corner again).
    pub readings: u32,
}

impl Stretch {
    /// The parts of the stretch farther than `margin` from every point of `feet` (projected
    /// onto it), in order, each at least `shortest` long.
    pub(crate) fn without(
        &self,
        feet: &[Vector2<f32>],
        margin: f32,
        shortest: f32,
    ) -> Vec<Stretch> {
        let length = (self.b - self.a).norm();
        if length <= 0.0 {
            return Vec::new();
        }
        let direction = (self.b - self.a) / length;
        let mut holes: Vec<(f32, f32)> = feet
            .iter()
            .map(|f| direction.dot(&(f - self.a)))
            .map(|t| (t - margin, t + margin))
            .collect();
        holes.sort_by(|x, y| x.0.total_cmp(&y.0));
        let mut parts = Vec::new();
        let mut from = 0.0f32;
        for (start, end) in holes.into_iter().chain(std::iter::once((length, length))) {
            let to = start.min(length);
            if to - from >= shortest {
                parts.push(Stretch {
                    a: self.a + direction * from,
                    b: self.a + direction * to,
                    ..*self
                });
            }
            from = from.max(end);
        }
        parts
    }

    /// The stretch cut into as few pieces as make each at most `longest` long, in order.
    pub(crate) fn pieces(self, longest: f32) -> impl Iterator<Item = Stretch> {
        let count = ((self.b - self.a).norm() / longest).ceil().max(1.0) as usize;
        let at = move |i: usize| self.a + (self.b - self.a) * (i as f32 / count as f32);
        (0..count).map(move |k| Stretch {
            a: at(k),
            b: at(k + 1),
            ..self
        })
    }

    /// Whether this stretch is `other` again: faced the same way, each end within
    /// [`SAME_LINE_M`] of `other`'s (two patches of one wall joined to the same corner).
    pub(crate) fn repeats(&self, other: &Stretch) -> bool {
        // The ends first: most stretches kept lie elsewhere, and they are cheaper to compare;
        // each end's coordinates before its distance (a square root), which holds them, with
        // room for the distance's rounding, so the answer is the distance's.
        let near = |p: Vector2<f32>, q: Vector2<f32>| {
            let d = p - q;
            let box_side = SAME_LINE_M * (1.0 + 1e-5);
            d.x.abs() <= box_side && d.y.abs() <= box_side && d.norm() <= SAME_LINE_M
        };
        near(self.a, other.a)
            && near(self.b, other.b)
            && wrap_angle(self.facing - other.facing).abs() <= SAME_FACING
    }
}

/// Stretches that lie on one line and overlap, as one ([`overlapping`]): the line, and each
/// stretch's span along it with its readings.
///
/// A robot that moves hears each wall from many places, and [`Lines::join_ends`] follows the wall
/// on to its corner from every patch of it, the whole way each time: in a 6 m room, a hundred
/// metres of wall a sweep and more, the same few metres drawn over and over (issue 29). Drawn as
/// the pieces of their union, each with the readings of every stretch that covers it, they put
/// the same evidence on the wall at the cost of the union.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Overlapping {
    /// A point of the line, its unit direction and the bearing it is faced from: spans are
    /// measured along the direction from the point.
    origin: Vector2<f32>,
    along: Vector2<f32>,
    facing: f32,
    /// Each stretch's span, `[from, to]` in metres along the line, and its readings.
    spans: Vec<(f32, f32, u32)>,
}

impl Overlapping {
    fn new(stretch: &Stretch) -> Self {
        let length = (stretch.b - stretch.a).norm();
        let along = if length > 0.0 {
            (stretch.b - stretch.a) / length
        } else {
            frame(stretch.facing).1
        };
        Self {
            origin: stretch.a,
            along,
            facing: stretch.facing,
            spans: vec![(0.0, length, stretch.readings)],
        }
    }

    /// `stretch`'s span along the line if it lies on it and overlaps the spans so far.
    fn span_of(&self, stretch: &Stretch) -> Option<(f32, f32)> {
        let on_line = |p: Vector2<f32>| self.along.perp(&(p - self.origin)).abs() <= SAME_LINE_M;
        let [u, v] = [stretch.a, stretch.b].map(|p| self.along.dot(&(p - self.origin)));
        let (from, to) = (u.min(v), u.max(v));
        let (first, last) = self.extent();
        (wrap_angle(stretch.facing - self.facing).abs() <= SAME_FACING
            && on_line(stretch.a)
            && on_line(stretch.b)
            && from <= last
            && to >= first)
            .then_some((from, to))
    }

    /// Where the union begins and ends along the line.
    fn extent(&self) -> (f32, f32) {
        self.spans.iter().fold(
            (f32::INFINITY, f32::NEG_INFINITY),
            |(first, last), &(from, to, _)| (first.min(from), last.max(to)),
        )
    }

    fn at(&self, t: f32) -> Vector2<f32> {
        self.origin + self.along * t
    }

    /// The union's ends.
    pub(crate) fn ends(&self) -> (Vector2<f32>, Vector2<f32>) {
        let (first, last) = self.extent();
        (self.at(first), self.at(last))
    }

    /// The pieces of the union covered by the stretches `kept` keeps (given each one's span as
    /// fractions of the way from the union's first end to its last), in order along the line,
    /// each with the readings of the kept stretches covering it; neighbours with as many
    /// readings make one piece.
    pub(crate) fn pieces(&self, kept: impl Fn(f32, f32) -> bool) -> Vec<Stretch> {
        let (first, last) = self.extent();
        let length = last - first;
        let fraction = |t: f32| {
            if length > 0.0 {
                (t - first) / length
            } else {
                0.0
            }
        };
        let kept: Vec<(f32, f32, u32)> = self
            .spans
            .iter()
            .copied()
            .filter(|&(from, to, _)| kept(fraction(from), fraction(to)))
            .collect();
        let mut bounds: Vec<f32> = kept.iter().flat_map(|&(from, to, _)| [from, to]).collect();
        bounds.sort_by(f32::total_cmp);
        bounds.dedup();
        let mut pieces: Vec<Stretch> = Vec::new();
        // Whether the last piece ends where this one begins (no uncovered gap between them).
        let mut joined = false;
        for pair in bounds.windows(2) {
            let (from, to) = (pair[0], pair[1]);
            let readings = kept
                .iter()
                .filter(|&&(f, t, _)| f <= from && t >= to)
                .map(|&(_, _, r)| r)
                .fold(0u32, u32::saturating_add);
            match pieces.last_mut() {
                _ if readings == 0 => {}
                Some(last) if joined && last.readings == readings => last.b = self.at(to),
                _ => pieces.push(Stretch {
                    a: self.at(from),
                    b: self.at(to),
                    facing: self.facing,
                    readings,
                }),
            }
            joined = readings > 0;
        }
        pieces
    }
}

/// `stretches` grouped into those that lie on one line and overlap ([`Overlapping`]), each
/// stretch in the first group whose line it lies on and whose union it overlaps, in order.
pub(crate) fn overlapping(stretches: &[Stretch]) -> Vec<Overlapping> {
    let mut groups: Vec<Overlapping> = Vec::new();
    for stretch in stretches {
        match groups
            .iter_mut()
            .find_map(|g| g.span_of(stretch).map(|span| (g, span)))
        {
            Some((group, (from, to))) => group.spans.push((from, to, stretch.readings)),
            None => groups.push(Overlapping::new(stretch)),
        }
    }
    groups
}

/// A region of constant depth heard: where from, the bearings it spans and its range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Echo {
    pub sensor: Vector2<f32>,
    /// The middle bearing and half the angle between its first and last readings, radians.
    pub axis: f32,
    pub half_width: f32,
    pub range: f32,
    /// How far its range may be from a corner's and still be the corner's echo, metres.
    pub tolerance: f32,
    /// Whether the reflector stopped being heard on both sides (its middle bearing is the
    /// reflector's).
    pub whole: bool,
    /// Whether nearer echoes cut it short on both sides: a concave corner's, heard between its
    /// walls' feet ([`Lines::join_ends`]).
    pub masked: bool,
}

impl Echo {
    /// Where its reflector lies if it is whole: at its middle bearing and range.
    fn reflector(&self) -> Vector2<f32> {
        self.sensor + Vector2::new(self.axis.cos(), self.axis.sin()) * self.range
    }

    /// Whether this region could be the echo of a reflector at `point`: its range, within its
    /// bearings. A concave corner answers from any bearing within the lobe.
    /// `slack` widens its tolerance: how far the point is known.
    fn heard(&self, point: Vector2<f32>, slack: f32) -> bool {
        let to = point - self.sensor;
        (to.norm() - self.range).abs() <= self.tolerance + slack
            && wrap_angle(to.y.atan2(to.x) - self.axis).abs() <= self.half_width + ECHO_MARGIN
    }

    /// Whether this region repeats `kept`: heard from where `kept` was, over the same bearings,
    /// whole or not as it was, and its sensor and range together within half the smaller depth
    /// tolerance of `kept`'s (a head standing still hears its walls so sweep after sweep). Its
    /// reflector and the points it hears are then `kept`'s within that tolerance.
    fn repeats(&self, kept: &Echo) -> bool {
        self.whole == kept.whole
            && (self.sensor - kept.sensor).norm() + (self.range - kept.range).abs()
                <= 0.5 * self.tolerance.min(kept.tolerance)
            && wrap_angle(self.axis - kept.axis).abs() <= SAME_BEARING
            && (self.half_width - kept.half_width).abs() <= SAME_BEARING
    }
}

/// What [`Lines`] keeps of a patch or a region: it, how many times it was heard (added, or heard
/// again: [`Patch::repeats`], [`Echo::repeats`]), and how many of those since [`Lines::join_ends`]
/// last ran.
#[derive(Debug, Clone, Copy)]
struct Kept<T> {
    item: T,
    heard: u32,
    fresh: u32,
}

impl<T> Kept<T> {
    /// `item`, heard once, that once fresh.
    fn new(item: T) -> Self {
        Self {
            item,
            heard: 1,
            fresh: 1,
        }
    }

    /// Counts one more hearing, fresh.
    fn heard_again(&mut self) {
        self.heard = self.heard.saturating_add(1);
        self.fresh = self.fresh.saturating_add(1).min(self.heard);
    }

    /// How many pairs of a hearing of this and one of `other` have a fresh one in them: as many
    /// times as [`Lines::join_ends`] would draw what the two make if every hearing were kept
    /// apart, each paired once with every other.
    fn fresh_pairs<U>(&self, other: &Kept<U>) -> u32 {
        let all = u64::from(self.heard) * u64::from(other.heard);
        let stale = u64::from(self.heard - self.fresh) * u64::from(other.heard - other.fresh);
        u32::try_from(all - stale).unwrap_or(u32::MAX)
    }
}

/// Keeps `item` in `kept`, at most `most` of them: if one kept already `absorb`s it (stands for
/// it too), that one counts one more hearing instead, else it is added, the oldest forgotten
/// first.
fn keep<T>(
    kept: &mut VecDeque<Kept<T>>,
    item: T,
    most: usize,
    absorb: impl Fn(&mut T, &T) -> bool,
) {
    if let Some(same) = kept
        .iter_mut()
        .find_map(|k| absorb(&mut k.item, &item).then_some(k))
    {
        same.heard_again();
        return;
    }
    if kept.len() == most {
        // The oldest goes: a queue, not a shift of thousands.
        kept.pop_front();
    }
    kept.push_back(Kept::new(item));
}

/// Adds `stretch`, counting `readings`, to `out`: to the one there it repeats, if any, else as a
/// new one.
fn push_new(out: &mut Vec<Stretch>, stretch: Stretch, readings: u32) {
    match out.iter_mut().find(|s| stretch.repeats(s)) {
        Some(same) => same.readings = same.readings.saturating_add(readings),
        None => out.push(Stretch {
            readings,
            ..stretch
        }),
    }
}

/// The patches placed so far, and the regions heard, each kept once: a patch or a region that
/// repeats one kept ([`Patch::repeats`], [`Echo::repeats`]) counts as one more hearing of that
/// one instead, so a head standing still for hours keeps what it heard in its first sweeps, not
/// thousands of copies that every new patch would be paired with ([`Self::join_ends`]).
#[derive(Debug, Clone, Default)]
pub(crate) struct Lines {
    patches: VecDeque<Kept<Patch>>,
    /// The regions heard, to confirm corners.
    echoes: VecDeque<Kept<Echo>>,
    /// Where the kept regions were heard from ([`EchoPlaces`]).
    places: EchoPlaces,
    /// Whether the patches on one line from several viewpoints are put on the line through
    /// their feet ([`Lines::add`]).
    through_feet: bool,
}

impl Lines {
    /// With `through_feet`, patches on one line are put on the line through their feet.
    pub fn new(through_feet: bool) -> Self {
        Self {
            through_feet,
            ..Self::default()
        }
    }

    /// Adds `patch`; writes into `out` the stretches between it and the nearest patch on its line
    /// on either side, from another viewpoint, at most [`LONGEST_STRETCH_M`] away.
    pub fn add(&mut self, mut patch: Patch, out: &mut Vec<Stretch>) {
        out.clear();
        // The nearest gap before the patch and after it, and the patch across it.
        let mut before: Option<(f32, Patch)> = None;
        let mut after: Option<(f32, Patch)> = None;
        let mut confirmed = false;
        if self.through_feet {
            self.refit(&mut patch);
        }
        for kept in self
            .patches
            .iter_mut()
            .filter(|k| patch.on_line_with(&k.item))
        {
            if kept.item.needs_confirming && !kept.item.confirmed {
                // Not followed on so far: at the next join, with every hearing it had.
                kept.fresh = kept.heard;
            }
            kept.item.confirmed = true;
            confirmed = true;
            let other = kept.item;
            if other.to < patch.from {
                let gap = patch.from - other.to;
                if before.is_none_or(|(g, _)| gap < g) {
                    before = Some((gap, other));
                }
            } else if other.from > patch.to {
                let gap = other.from - patch.to;
                if after.is_none_or(|(g, _)| gap < g) {
                    after = Some((gap, other));
                }
            }
        }
        // From the other patch's near end to this one's, each on its own line, so that two
        // patches a few degrees apart are joined without a step.
        for (gap, a, b, other) in [
            before.map(|(g, o)| (g, o.ends[1], patch.ends[0], o)),
            after.map(|(g, o)| (g, patch.ends[1], o.ends[0], o)),
        ]
        .into_iter()
        .flatten()
        {
            if gap <= LONGEST_STRETCH_M {
                out.push(Stretch {
                    a,
                    b,
                    facing: patch.facing + 0.5 * wrap_angle(other.facing - patch.facing),
                    readings: 1,
                });
            }
        }
        patch.confirmed = confirmed;
        keep(&mut self.patches, patch, KEPT, Patch::absorb);
    }

    /// Puts `patch` and the patches on its line from other viewpoints on the line through all
    /// their feet, when those feet lie at least [`FEET_APART_M`] apart along it.
    fn refit(&mut self, patch: &mut Patch) {
        let on_line: Vec<usize> = self
            .patches
            .iter()
            .enumerate()
            .filter(|(_, k)| patch.on_line_with(&k.item))
            .map(|(i, _)| i)
            .collect();
        if on_line.is_empty() {
            return;
        }
        let feet: Vec<Vector2<f32>> = on_line
            .iter()
            .map(|&i| self.patches[i].item.foot)
            .chain(std::iter::once(patch.foot))
            .collect();
        let along: Vec<f32> = feet.iter().map(|f| patch.along.dot(f)).collect();
        let span = along.iter().copied().fold(f32::NEG_INFINITY, f32::max)
            - along.iter().copied().fold(f32::INFINITY, f32::min);
        if span < FEET_APART_M {
            return;
        }
        let n = feet.len() as f32;
        let centre = feet.iter().sum::<Vector2<f32>>() / n;
        let (mut xx, mut xy, mut yy) = (0.0, 0.0, 0.0);
        for f in &feet {
            let d = f - centre;
            xx += d.x * d.x;
            xy += d.x * d.y;
            yy += d.y * d.y;
        }
        // The feet's direction of greatest spread (the principal axis) is the line's.
        let angle = 0.5 * (2.0 * xy).atan2(xx - yy);
        let mut normal = Vector2::new(-angle.sin(), angle.cos());
        if normal.dot(&patch.normal) < 0.0 {
            normal = -normal;
        }
        if wrap_angle(normal.y.atan2(normal.x) - patch.facing).abs() > SAME_FACING {
            return;
        }
        let offset = normal.dot(&centre);
        patch.move_to_line(normal, offset);
        for i in on_line {
            self.patches[i].item.move_to_line(normal, offset);
        }
    }

    /// Remembers a region heard, which may confirm a corner ([`Self::join_ends`]): as one more
    /// hearing of the oldest kept one it repeats ([`Echo::repeats`]), else as the newest, the
    /// oldest forgotten first (what [`keep`] does, with the kept ones found by place).
    pub fn hear(&mut self, echo: Echo) {
        self.hear_keeping(echo, KEPT_ECHOES);
    }

    /// [`Self::hear`], keeping at most `most` regions.
    fn hear_keeping(&mut self, echo: Echo, most: usize) {
        let first = self.places.first;
        let repeated = match self.places.near(&echo) {
            Some(near) => near
                .filter(|&n| echo.repeats(&self.echoes[(n - first) as usize].item))
                .min(),
            None => (first..)
                .zip(&self.echoes)
                .find_map(|(n, kept)| echo.repeats(&kept.item).then_some(n)),
        };
        if let Some(n) = repeated {
            self.echoes[(n - first) as usize].heard_again();
            return;
        }
        if self.echoes.len() >= most {
            self.forget_oldest_echo();
        }
        self.places
            .add(&echo, self.places.first + self.echoes.len() as u64);
        self.echoes.push_back(Kept::new(echo));
    }

    /// Forgets the oldest region kept, and where it was heard from.
    fn forget_oldest_echo(&mut self) {
        if let Some(oldest) = self.echoes.pop_front() {
            self.places.forget_first(&oldest.item);
        }
    }

    /// Whether some region kept heard `point` ([`Echo::heard`], with `slack`): among those whose
    /// reach holds it ([`EchoPlaces::reaching`]), or all of them when `slack` is wider than the
    /// reach was filed with.
    fn heard_at(&self, point: Vector2<f32>, slack: f32) -> bool {
        self.heard_at_by(point, slack, |_| true)
    }

    /// [`Self::heard_at`], by the regions `counted` counts only.
    fn heard_at_by(
        &self,
        point: Vector2<f32>,
        slack: f32,
        counted: impl Fn(&Echo) -> bool,
    ) -> bool {
        let heard = |e: &Echo| counted(e) && e.heard(point, slack);
        let first = self.places.first;
        match self.places.reaching(point, slack) {
            Some(mut numbers) => numbers.any(|n| heard(&self.echoes[(n - first) as usize].item)),
            None => self.echoes.iter().any(|e| heard(&e.item)),
        }
    }

    /// Writes into `out` the stretches of wall from patches to where their walls end, at most
    /// [`CORNER_WALL_M`] beyond each patch, for the patches and echoes added or heard again since
    /// the last call, each stretch once:
    ///
    /// - to the corner where two walls meet: their lines cross at least 30° apart, each wall's
    ///   sensor lies in front of the other wall (a concave corner, as a room's, seen from
    ///   inside), and some region heard an echo at the corner's range and bearing (a concave
    ///   corner answers from any bearing in the lobe; two walls that end before meeting do not);
    /// - to a whole region's reflector that lies on a wall's line: the wall's end (a door's jamb,
    ///   a partition's edge, a corner heard whole).
    ///
    /// With `confirmed_corners`, a wall is followed to a corner only from a patch
    /// [`Patch::confirmed`] from another viewpoint, or from either of two patches heard from one
    /// place ([`crate::model::SmoothModel::region_corner_walls_confirmed`]). A patch
    /// [`Patch::needing_confirmation`] is followed, to a corner or a jamb, only once confirmed.
    pub fn join_ends(
        &mut self,
        confirmed_corners: bool,
        seen: impl Fn(Vector2<f32>, &Stretch, &mut Vec<Stretch>),
        out: &mut Vec<Stretch>,
    ) {
        out.clear();
        let mut pieces = Vec::new();
        // The pieces of `stretch`, followed on from `p`, that `p`'s sensor sees.
        let mut push_seen = |out: &mut Vec<Stretch>, p: &Patch, stretch: &Stretch, readings| {
            pieces.clear();
            seen(p.sensor, stretch, &mut pieces);
            for piece in &pieces {
                push_new(out, *piece, readings);
            }
        };
        // Each pair with a fresh patch once: a fresh one with every patch before it, and with
        // those after it that are not fresh.
        for (i, a) in self.patches.iter().enumerate().filter(|(_, k)| k.fresh > 0) {
            let partners = self
                .patches
                .range(..i)
                .chain(self.patches.range(i + 1..).filter(|k| k.fresh == 0));
            for b in partners {
                let readings = a.fresh_pairs(b);
                let (a, b) = (&a.item, &b.item);
                let Some(corner) = concave_corner(a, b) else {
                    continue;
                };
                // Within reach of either patch before the echoes are searched: in a large map
                // most pairs of walls meet far from both.
                let one_place = (a.sensor - b.sensor).norm() < OTHER_VIEWPOINT_M;
                // The corner of two patches that stand for others moves with their lines: as
                // far as their spreads together across the sine of the angle between them, so
                // that it is confirmed if the corner of any two of the patches they stand for
                // would have been.
                let slack = (a.spread + b.spread) / a.normal.perp(&b.normal).abs();
                // A patch needing confirmation is followed from the place both walls were heard
                // only to a corner heard between their feet (a region cut short on both sides),
                // as a local scan hears a room's corner between two walls that each run to the
                // scan's limit; looked for once, if such a patch reaches the corner.
                let mut between_feet = None;
                let mut followed = |p: &Patch| {
                    p.followed(!confirmed_corners || one_place, || {
                        *between_feet.get_or_insert_with(|| {
                            one_place && self.heard_at_by(corner, slack, |e| e.masked)
                        })
                    })
                };
                let stretches =
                    [a, b].map(|p| p.towards(corner).filter(|_| followed(p)).map(|s| (p, s)));
                if stretches.iter().all(Option::is_none) || !self.heard_at(corner, slack) {
                    continue;
                }
                for (p, stretch) in stretches.into_iter().flatten() {
                    push_seen(out, p, &stretch, readings);
                }
            }
        }
        // A whole region's reflector on a wall's line beyond its patch: where the wall ends (a
        // door's jamb, a partition's edge, a corner heard whole), on patches new or old: a fresh
        // patch with every echo, the others with the fresh echoes alone (found once, not looked
        // for among thousands for each of thousands of patches).
        let fresh_echoes: Vec<&Kept<Echo>> = self.echoes.iter().filter(|e| e.fresh > 0).collect();
        for a in &self.patches {
            let echoes: &mut dyn Iterator<Item = &Kept<Echo>> = if a.fresh > 0 {
                &mut self.echoes.iter()
            } else {
                &mut fresh_echoes.iter().copied()
            };
            for e in echoes {
                let echo = &e.item;
                if echo.whole
                    && let reflector = echo.reflector()
                    && a.item.followed(true, || false)
                    && a.item.passes_through(reflector, echo.tolerance)
                    && let Some(stretch) = a.item.towards(reflector)
                {
                    push_seen(out, &a.item, &stretch, a.fresh_pairs(e));
                }
            }
        }
        for kept in &mut self.patches {
            kept.fresh = 0;
        }
        for kept in &mut self.echoes {
            kept.fresh = 0;
        }
    }

    /// Whether two walls heard so far meet at `point` (within `tolerance`): two patches whose
    /// lines pass through it, facing ways at least 30° apart, each within 1.5 m of it.
    pub fn corner_at(&self, point: Vector2<f32>, tolerance: f32) -> bool {
        self.walls_meet_at(point, tolerance, |_| true)
    }

    /// [`Self::corner_at`], not counting the patches heard from `sensor` square to `facing`: a
    /// whole region's own patch, whose line passes through its reflector whatever it is.
    pub fn corner_of_others_at(
        &self,
        point: Vector2<f32>,
        tolerance: f32,
        sensor: Vector2<f32>,
        facing: f32,
    ) -> bool {
        self.walls_meet_at(point, tolerance, |p| !p.heard_as(sensor, facing))
    }

    fn walls_meet_at(
        &self,
        point: Vector2<f32>,
        tolerance: f32,
        counted: impl Fn(&Patch) -> bool,
    ) -> bool {
        let through: Vec<&Patch> = self
            .patches
            .iter()
            .map(|k| &k.item)
            .filter(|p| counted(p) && p.reaches(point, tolerance))
            .collect();
        through.iter().enumerate().any(|(i, a)| {
            through[i + 1..].iter().any(|b| {
                let apart = wrap_angle(a.facing - b.facing).abs();
                (CORNER_ANGLE..=std::f32::consts::PI - CORNER_ANGLE).contains(&apart)
            })
        })
    }

    /// Forgets the patches heard from `sensor` square to `facing` at `range` (within `tolerance`):
    /// a point's ([`crate::points`]), which is no wall to follow.
    pub fn forget(&mut self, sensor: Vector2<f32>, facing: f32, range: f32, tolerance: f32) {
        self.patches.retain(|k| {
            let p = &k.item;
            !(p.heard_as(sensor, facing) && (p.range - range).abs() <= tolerance)
        });
    }

    pub fn clear(&mut self) {
        self.patches.clear();
        self.echoes.clear();
        self.places = EchoPlaces::default();
    }
}

/// Squares of this side, metres, hold the places regions were heard from ([`EchoPlaces`]).
const PLACE_M: f32 = 0.1;

/// The kept regions filed two ways, each by its number (the kept ones are numbered in the order
/// they were heard, from `first`, the oldest kept), so that a moving robot's look for a region
/// does not go through all of the thousands kept (issue 29):
///
/// - by the square of [`PLACE_M`] their sensor stood in: a region repeats only one heard within
///   half its depth tolerance of where it was heard ([`Echo::repeats`]), so where that is within
///   a square, the kept ones in the nine squares about it are all it can repeat;
/// - by the squares of [`REACH_M`] their reach crosses ([`Self::reach`]): a corner can have been
///   heard only by the regions filed in its own square ([`Lines::join_ends`]).
#[derive(Debug, Clone, Default)]
struct EchoPlaces {
    /// The kept regions by the square their sensor stood in.
    squares: FxHashMap<(i32, i32), VecDeque<u64>>,
    /// The kept regions by the squares of [`REACH_M`] their reach crosses ([`Self::reach`]), and
    /// those whose reach crosses more than [`WIDEST_REACH`] squares a side (looked at for every
    /// point).
    reach: FxHashMap<(i32, i32), VecDeque<u64>>,
    wide: VecDeque<u64>,
    first: u64,
}

/// Squares of this side, metres, hold where the regions kept may have heard something.
const REACH_M: f32 = 1.0;
/// A corner's slack up to which the regions' reach, filed, holds every region that heard it.
const SLACK_FILED_M: f32 = 0.25;
/// A region whose reach crosses more squares a side than this is looked at for every point.
const WIDEST_REACH: f32 = 16.0;

impl EchoPlaces {
    /// The square of side `side` that holds `at`.
    fn square(at: Vector2<f32>, side: f32) -> (i32, i32) {
        // Saturating casts: a position beyond ±2e8 m still lands in a square.
        ((at.x / side).floor() as i32, (at.y / side).floor() as i32)
    }

    /// Every square from `first` to `last` (corners), both ways.
    fn each_square((first, last): ((i32, i32), (i32, i32))) -> impl Iterator<Item = (i32, i32)> {
        (first.0..=last.0).flat_map(move |x| (first.1..=last.1).map(move |y| (x, y)))
    }

    /// The numbers of the kept regions `echo` may repeat, if the squares about its place hold
    /// every one (else `None`: look through them all).
    fn near(&self, echo: &Echo) -> Option<impl Iterator<Item = u64> + '_> {
        // Repeating needs the sensors within half the smaller of the two tolerances (a NaN one
        // is looked for everywhere, as before).
        let within_a_square = 0.5 * echo.tolerance <= PLACE_M;
        if !within_a_square {
            return None;
        }
        let (x, y) = Self::square(echo.sensor, PLACE_M);
        let about = (
            (x.saturating_sub(1), y.saturating_sub(1)),
            (x.saturating_add(1), y.saturating_add(1)),
        );
        Some(
            Self::each_square(about)
                .filter_map(|key| self.squares.get(&key))
                .flatten()
                .copied(),
        )
    }

    /// The squares of [`REACH_M`] (the first and the last, both ways) in which the points
    /// `echo` hears with a slack up to [`SLACK_FILED_M`] may lie: its reach, the box round its
    /// sector; `None` if that spans more than [`WIDEST_REACH`] squares a side or is no box.
    fn reach(echo: &Echo) -> Option<((i32, i32), (i32, i32))> {
        let lobe = echo.half_width + ECHO_MARGIN;
        // The box round a sector of a half turn or more each side is no bound of it (nor is a
        // NaN's).
        let bounded = lobe < std::f32::consts::PI;
        if !bounded {
            return None;
        }
        let (lower, upper) = sector_box(
            echo.sensor,
            echo.axis,
            echo.range,
            lobe,
            echo.tolerance + SLACK_FILED_M,
        );
        let square = |v: f32| (v / REACH_M).floor();
        let (first, last) = (lower.map(square), upper.map(square));
        let span = last - first;
        // Also false for a NaN.
        let narrow = span.x <= WIDEST_REACH && span.y <= WIDEST_REACH;
        narrow.then(|| {
            (
                (first.x as i32, first.y as i32),
                (last.x as i32, last.y as i32),
            )
        })
    }

    /// The numbers of the kept regions that may have heard `point` with `slack`, if they were
    /// filed for it (else `None`: look at them all).
    fn reaching(&self, point: Vector2<f32>, slack: f32) -> Option<impl Iterator<Item = u64> + '_> {
        let filed = slack <= SLACK_FILED_M;
        if !filed {
            return None;
        }
        Some(
            self.reach
                .get(&Self::square(point, REACH_M))
                .into_iter()
                .flatten()
                .chain(&self.wide)
                .copied(),
        )
    }

    fn add(&mut self, echo: &Echo, number: u64) {
        self.squares
            .entry(Self::square(echo.sensor, PLACE_M))
            .or_default()
            .push_back(number);
        match Self::reach(echo) {
            Some(reach) => {
                for key in Self::each_square(reach) {
                    self.reach.entry(key).or_default().push_back(number);
                }
            }
            None => self.wide.push_back(number),
        }
    }

    /// Forgets the oldest kept region, `echo`.
    fn forget_first(&mut self, echo: &Echo) {
        // Numbers are pushed in order, so the oldest of a square is its first.
        let first = self.first;
        let forget = |map: &mut FxHashMap<(i32, i32), VecDeque<u64>>, key| {
            if let Some(numbers) = map.get_mut(&key) {
                if numbers.front() == Some(&first) {
                    numbers.pop_front();
                }
                if numbers.is_empty() {
                    map.remove(&key);
                }
            }
        };
        forget(&mut self.squares, Self::square(echo.sensor, PLACE_M));
        match Self::reach(echo) {
            Some(reach) => {
                for key in Self::each_square(reach) {
                    forget(&mut self.reach, key);
                }
            }
            None => {
                if self.wide.front() == Some(&first) {
                    self.wide.pop_front();
                }
            }
        }
        self.first += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_strategies::between;
    use proptest::prelude::*;

    const DEG: f32 = std::f32::consts::PI / 180.0;

    /// Every stretch seen whole from where its patch was heard.
    fn all_seen(_: Vector2<f32>, stretch: &Stretch, out: &mut Vec<Stretch>) {
        out.push(*stretch);
    }

    /// A wall along x = 2 m heard square (facing 0) from (0, y) at 2 m, patch ±5°.
    fn heard_from(y: f32) -> Patch {
        Patch::new(Vector2::new(0.0, y), 0.0, 2.0, 5.0 * DEG)
    }

    #[test]
    fn two_feet_of_one_wall_from_two_viewpoints_give_the_wall_between_them() {
        let mut lines = Lines::default();
        let mut out = Vec::new();
        lines.add(heard_from(0.0), &mut out);
        assert!(out.is_empty());
        lines.add(heard_from(1.0), &mut out);
        assert_eq!(out.len(), 1);
        let s = out[0];
        let half = 2.0 * (5.0 * DEG).tan();
        assert!((s.a - Vector2::new(2.0, half)).norm() < 1e-4, "{s:?}");
        assert!((s.b - Vector2::new(2.0, 1.0 - half)).norm() < 1e-4, "{s:?}");
        // A third foot between them fills towards the nearest patch on each side only.
        lines.add(heard_from(0.5), &mut out);
        assert_eq!(out.len(), 2);
        assert!(out.iter().all(|s| (s.b - s.a).norm() < 0.5));
    }

    #[test]
    fn a_corner_is_where_two_walls_heard_beside_it_meet() {
        let mut lines = Lines::default();
        let mut out = Vec::new();
        // Two walls 0.85 m from the origin square to ±45°: they meet at (1.2, 0).
        for side in [1.0, -1.0] {
            lines.add(
                Patch::new(Vector2::zeros(), side * 45.0 * DEG, 0.85, 13.0 * DEG),
                &mut out,
            );
        }
        let corner = Vector2::new(0.85 * 2f32.sqrt(), 0.0);
        assert!(lines.corner_at(corner, 0.05));
        assert!(!lines.corner_at(corner + Vector2::new(0.1, 0.0), 0.05));
        // One wall alone, or two walls in line, make no corner.
        let mut one = Lines::default();
        one.add(heard_from(0.0), &mut out);
        one.add(heard_from(1.0), &mut out);
        assert!(!one.corner_at(Vector2::new(2.0, 0.5), 0.05));
        // Beyond the reach of both patches: no corner.
        assert!(!lines.corner_at(corner * 3.0, 10.0));
        // A corner heard whole from the origin, its patch square to 0°: with one wall beside
        // it, its own patch makes the second wall for `corner_at`, not for
        // `corner_of_others_at`; with both walls, a corner either way.
        let mut one_wall = Lines::default();
        one_wall.add(
            Patch::new(Vector2::zeros(), 45.0 * DEG, 0.85, 13.0 * DEG),
            &mut out,
        );
        one_wall.add(
            Patch::new(Vector2::zeros(), 0.0, corner.x, 20.0 * DEG),
            &mut out,
        );
        assert!(one_wall.corner_at(corner, 0.05));
        assert!(!one_wall.corner_of_others_at(corner, 0.05, Vector2::zeros(), 0.0));
        lines.add(
            Patch::new(Vector2::zeros(), 0.0, corner.x, 20.0 * DEG),
            &mut out,
        );
        assert!(lines.corner_of_others_at(corner, 0.05, Vector2::zeros(), 0.0));
    }

    #[test]
    fn patches_of_one_wall_from_several_viewpoints_lie_on_the_line_through_their_feet() {
        // The wall x = 2 heard at range 2 from (0, 0), (0, 0.6) and (0, 1.2), each region's
        // middle bearing 1.5° off one way or the other: the feet lie on the wall within a
        // millimetre, the facings 1.5° off it.
        let heard = [(0.0, 1.5), (0.6, -1.5), (1.2, 1.0)]
            .map(|(y, off)| Patch::new(Vector2::new(0.0, y), off * DEG, 2.0, 5.0 * DEG));
        let fitted = |through_feet: bool| {
            let mut lines = Lines::new(through_feet);
            let mut out = Vec::new();
            for patch in heard {
                lines.add(patch, &mut out);
            }
            lines
                .patches
                .iter()
                .map(|k| (k.item.facing, k.item.offset))
                .collect::<Vec<_>>()
        };
        for (facing, offset) in fitted(true) {
            assert!(facing.abs() < 0.1 * DEG, "{}°", facing / DEG);
            assert!((offset - 2.0).abs() < 0.002, "{offset}");
        }
        // Left as heard: the first patch's facing stays 1.5° off.
        assert!((fitted(false)[0].0 - 1.5 * DEG).abs() < 1e-4);
        // Two feet 0.3 m apart say less about the line than the bearings: left as heard.
        let mut lines = Lines::new(true);
        let mut out = Vec::new();
        lines.add(heard[0], &mut out);
        lines.add(
            Patch::new(Vector2::new(0.0, 0.3), -1.5 * DEG, 2.0, 5.0 * DEG),
            &mut out,
        );
        assert!((lines.patches[0].item.facing - 1.5 * DEG).abs() < 1e-4);
    }

    #[test]
    fn a_stretch_without_the_spots_around_feet_keeps_the_rest_in_order() {
        let stretch = Stretch {
            a: Vector2::new(0.0, 0.0),
            b: Vector2::new(1.0, 0.0),
            facing: 0.0,
            readings: 2,
        };
        let feet = [Vector2::new(0.95, 0.0), Vector2::new(0.5, 0.2)];
        let parts: Vec<(f32, f32)> = stretch
            .without(&feet, 0.1, 0.05)
            .iter()
            .map(|p| (p.a.x, p.b.x))
            .collect();
        let expected = [(0.0, 0.4), (0.6, 0.85)];
        assert_eq!(parts.len(), expected.len(), "{parts:?}");
        for ((a, b), (ea, eb)) in parts.iter().zip(expected) {
            assert!((a - ea).abs() < 1e-6 && (b - eb).abs() < 1e-6, "{parts:?}");
        }
        // No feet: the whole stretch; a part shorter than the shortest is left out.
        assert_eq!(stretch.without(&[], 0.1, 0.05), vec![stretch]);
        assert!(
            stretch
                .without(&[Vector2::new(0.5, 0.0)], 0.48, 0.05)
                .is_empty()
        );
    }

    #[test]
    fn patches_that_are_not_one_wall_seen_twice_give_nothing() {
        let mut lines = Lines::default();
        let mut out = Vec::new();
        lines.add(heard_from(0.0), &mut out);
        // The same viewpoint's next sweep.
        lines.add(heard_from(0.05), &mut out);
        assert!(out.is_empty());
        // Parallel, 10 cm farther: another wall.
        lines.add(
            Patch::new(Vector2::new(0.0, 1.0), 0.0, 2.1, 5.0 * DEG),
            &mut out,
        );
        assert!(out.is_empty());
        // Facing another way (a post heard from two sides).
        lines.add(
            Patch::new(Vector2::new(0.0, 1.0), 10.0 * DEG, 2.0, 5.0 * DEG),
            &mut out,
        );
        assert!(out.is_empty());
        // On the line but farther than the longest stretch.
        lines.add(heard_from(5.0), &mut out);
        assert!(out.is_empty());
    }
    proptest! {
        /// Regions heard from a head standing still (repeats) and from a robot driving (new
        /// places), beyond what is kept: found by place, they are kept as looking through every
        /// kept one finds them ([`keep`]), the same hearings counted on the same ones.
        #[test]
        fn echoes_found_by_place_are_kept_as_a_look_through_all_keeps_them(
            heard in proptest::collection::vec(
                (0u8..6, 0u8..4, 0u8..3, any::<bool>(), prop_oneof![Just(0.05f32), Just(0.3f32)]),
                1..300,
            ),
        ) {
            let mut lines = Lines::default();
            let mut all: VecDeque<Kept<Echo>> = VecDeque::new();
            for (i, &(place, bearing, range, whole, tolerance)) in heard.iter().enumerate() {
                let echo = Echo {
                    // Six places 2 cm apart, across a square's edge; some heard once, on the move.
                    sensor: if i % 7 == 0 {
                        Vector2::new(0.013 * i as f32, -0.37)
                    } else {
                        Vector2::new(0.08 + 0.02 * f32::from(place), 0.1)
                    },
                    axis: f32::from(bearing) * 2.0 * DEG,
                    half_width: 5.0 * DEG,
                    range: 1.0 + 0.01 * f32::from(range),
                    tolerance,
                    whole,
                    masked: false,
                };
                // At most 40 kept, so that the oldest are forgotten many times over.
                lines.hear_keeping(echo, 40);
                keep(&mut all, echo, 40, |kept, echo| echo.repeats(kept));
            }
            let seen = |k: &VecDeque<Kept<Echo>>| {
                k.iter().map(|k| (k.item, k.heard, k.fresh)).collect::<Vec<_>>()
            };
            prop_assert_eq!(seen(&lines.echoes), seen(&all));
        }
    }

    proptest! {
        /// Whether some kept region heard a point, asked of the regions filed by their reach,
        /// is what asking every kept one says: for points in and out of reach, slacks filed and
        /// not, regions wide and narrow, and after the oldest are forgotten.
        #[test]
        fn a_point_heard_by_the_regions_filed_by_reach_is_heard_by_all(
            heard in proptest::collection::vec(
                (
                    between(-3.0, 3.0),
                    between(-3.0, 3.0),
                    between(-3.2, 3.2),
                    between(0.1, 4.0),
                    between(0.0, 3.2),
                    between(0.01, 0.3),
                ),
                1..80,
            ),
            points in proptest::collection::vec(
                (between(-7.0, 7.0), between(-7.0, 7.0), between(0.0, 0.5)),
                1..60,
            ),
        ) {
            let mut lines = Lines::default();
            for &(x, y, axis, range, half_width, tolerance) in &heard {
                lines.hear_keeping(
                    Echo {
                        sensor: Vector2::new(x, y),
                        axis,
                        half_width,
                        range,
                        tolerance,
                        whole: false,
                        masked: false,
                    },
                    50,
                );
            }
            for &(x, y, slack) in &points {
                let point = Vector2::new(x, y);
                let all = lines.echoes.iter().any(|e| e.item.heard(point, slack));
                prop_assert_eq!(lines.heard_at(point, slack), all, "{:?} with slack {}", point, slack);
            }
            // Points each region heard, on its axis at its range.
            for e in &lines.echoes {
                let e = e.item;
                let point = e.sensor + Vector2::new(e.axis.cos(), e.axis.sin()) * e.range;
                prop_assert!(lines.heard_at(point, 0.0));
            }
        }
    }

    /// A region heard from the origin at `range` about 36.9°, 6° each side, not whole: the
    /// corner (2, 1.5) of the walls x = 2 and y = 1.5 when `range` is 2.5.
    fn corner_echo(range: f32) -> Echo {
        Echo {
            sensor: Vector2::zeros(),
            axis: 36.9 * DEG,
            half_width: 6.0 * DEG,
            range,
            tolerance: 0.05,
            whole: false,
            masked: false,
        }
    }

    #[test]
    fn walls_are_drawn_to_the_concave_corner_where_an_echo_was_heard() {
        // A room's walls x = 2 m and y = 1.5 m heard square from the origin (patches ±10°); their
        // corner at (2, 1.5) answers 2.5 m away at 36.9°, between the feet's regions.
        let corner = Vector2::new(2.0, 1.5);
        let walls = [
            Patch::new(Vector2::zeros(), 0.0, 2.0, 10.0 * DEG),
            Patch::new(Vector2::zeros(), 90.0 * DEG, 1.5, 10.0 * DEG),
        ];
        let echo = corner_echo;
        let joined = |echoes: &[Echo], walls: &[Patch]| {
            let mut lines = Lines::default();
            let mut out = Vec::new();
            echoes.iter().for_each(|&e| lines.hear(e));
            walls.iter().for_each(|&w| lines.add(w, &mut out));
            lines.join_ends(false, all_seen, &mut out);
            out
        };
        let out = joined(&[echo(2.5)], &walls);
        assert_eq!(out.len(), 2, "{out:?}");
        for wall in &walls {
            let s = out.iter().find(|s| s.facing == wall.facing).unwrap();
            assert!((s.b - corner).norm() < 1e-4, "{s:?}");
            // From the patch's end nearer the corner.
            let near = wall
                .ends
                .iter()
                .map(|e| (e - corner).norm())
                .fold(f32::MAX, f32::min);
            assert!(((s.a - corner).norm() - near).abs() < 1e-4, "{s:?}");
        }
        // Nothing heard at the corner's range (two walls ending before they meet, as at a
        // doorway): nothing drawn.
        assert!(joined(&[echo(2.2)], &walls).is_empty());
        // The same walls seen from outside (a box's convex corner, each face heard from its own
        // side): no corner.
        let outside = [
            Patch::new(Vector2::new(3.0, 0.0), 180.0 * DEG, 1.0, 10.0 * DEG),
            Patch::new(Vector2::new(0.0, 2.5), -90.0 * DEG, 1.0, 10.0 * DEG),
        ];
        let heard_outside = Echo {
            sensor: Vector2::new(3.0, 2.5),
            axis: (-1.0f32).atan2(-1.0),
            half_width: 6.0 * DEG,
            range: 2f32.sqrt() * 1.0,
            tolerance: 0.05,
            whole: false,
            masked: false,
        };
        assert!(joined(&[heard_outside], &outside).is_empty());
        // Only once per patch added: a second call without new patches draws nothing.
        let mut lines = Lines::default();
        let mut out = Vec::new();
        lines.hear(echo(2.5));
        walls.iter().for_each(|&w| lines.add(w, &mut out));
        lines.join_ends(false, all_seen, &mut out);
        lines.join_ends(false, all_seen, &mut out);
        assert!(out.is_empty());
    }
    #[test]
    fn a_patch_needing_confirmation_is_followed_on_once_another_viewpoint_confirms_it() {
        // The room of the test above, its wall x = 2 heard one-ended from the origin.
        let corner = Vector2::new(2.0, 1.5);
        let echo = corner_echo(2.5);
        let one_ended = Patch::new(Vector2::zeros(), 0.0, 2.0, 10.0 * DEG).needing_confirmation();
        let other_wall = Patch::new(Vector2::zeros(), 90.0 * DEG, 1.5, 10.0 * DEG);
        let mut lines = Lines::default();
        let mut out = Vec::new();
        lines.hear(echo);
        lines.add(one_ended, &mut out);
        lines.add(other_wall, &mut out);
        lines.join_ends(false, all_seen, &mut out);
        // The other wall is followed on to the corner; the one-ended one is not.
        assert_eq!(out.len(), 1, "{out:?}");
        assert_eq!(out[0].facing, other_wall.facing);
        assert!((out[0].b - corner).norm() < 1e-4, "{out:?}");
        // From the one place, a corner heard between the walls' feet (its region cut short on
        // both sides, as a local scan hears a room's corner): followed on from there too.
        let mut between_feet = Lines::default();
        let mut joined = Vec::new();
        between_feet.hear(Echo {
            masked: true,
            ..echo
        });
        between_feet.add(one_ended, &mut joined);
        between_feet.add(other_wall, &mut joined);
        between_feet.join_ends(false, all_seen, &mut joined);
        assert_eq!(joined.len(), 2, "{joined:?}");
        // The wall x = 2 heard from (0, −0.6) as well: both its patches are followed on.
        let mut confirmed = Vec::new();
        lines.add(
            Patch::new(Vector2::new(0.0, -0.6), 0.0, 2.0, 10.0 * DEG),
            &mut confirmed,
        );
        lines.join_ends(false, all_seen, &mut confirmed);
        let from_one_ended = one_ended.ends[1];
        assert!(
            confirmed.iter().any(|s| s.facing == one_ended.facing
                && (s.a - from_one_ended).norm() < 1e-4
                && (s.b - corner).norm() < 1e-4),
            "{confirmed:?}"
        );
    }

    #[test]
    fn with_confirmed_corners_a_wall_is_followed_from_patches_two_places_agree_on() {
        // The room of the test above, but its wall y = 1.5 heard from (1, 0) instead: the two
        // patches come from two places, each alone on its line. A post there, heard from each
        // place, would give the same patches.
        let corner = Vector2::new(2.0, 1.5);
        let echo = corner_echo(2.5);
        let east = Patch::new(Vector2::zeros(), 0.0, 2.0, 10.0 * DEG);
        let north = Patch::new(Vector2::new(1.0, 0.0), 90.0 * DEG, 1.5, 10.0 * DEG);
        let joined = |confirmed: bool, walls: &[Patch]| {
            let mut lines = Lines::default();
            let mut out = Vec::new();
            lines.hear(echo);
            walls.iter().for_each(|&w| lines.add(w, &mut out));
            lines.join_ends(confirmed, all_seen, &mut out);
            out
        };
        assert_eq!(joined(false, &[east, north]).len(), 2);
        assert!(joined(true, &[east, north]).is_empty());
        // The wall y = 1.5 heard from a third place, (-0.5, 0), too: that wall's line is known
        // from two places and is followed to the corner; the east wall's is not.
        let north_again = Patch::new(Vector2::new(-0.5, 0.0), 90.0 * DEG, 1.5, 10.0 * DEG);
        let out = joined(true, &[east, north, north_again]);
        assert!(!out.is_empty(), "{out:?}");
        assert!(
            out.iter()
                .all(|s| (s.facing - 90.0 * DEG).abs() < 1e-4 && (s.b - corner).norm() < 1e-4),
            "{out:?}"
        );
        // Both walls heard from one place: followed, as without the rule.
        let north_here = Patch::new(Vector2::zeros(), 90.0 * DEG, 1.5, 10.0 * DEG);
        assert_eq!(joined(true, &[east, north_here]).len(), 2);
    }

    #[test]
    fn a_wall_is_drawn_to_the_edge_a_whole_region_heard_on_its_line() {
        // A wall along x = 2 m heard square from the origin (patch ±10°, to y = ±0.35 m); its
        // end at (2, 1.2), a jamb, heard as a whole region from (1, 1.5); a post off the line
        // heard whole too.
        let wall = Patch::new(Vector2::zeros(), 0.0, 2.0, 10.0 * DEG);
        let whole = |sensor: Vector2<f32>, point: Vector2<f32>| {
            let to: Vector2<f32> = point - sensor;
            Echo {
                sensor,
                axis: to.y.atan2(to.x),
                half_width: 20.0 * DEG,
                range: to.norm(),
                tolerance: 0.05,
                whole: true,
                masked: false,
            }
        };
        let jamb = Vector2::new(2.0, 1.2);
        let mut lines = Lines::default();
        let mut out = Vec::new();
        lines.add(wall, &mut out);
        lines.hear(whole(Vector2::new(1.0, 1.5), jamb));
        lines.hear(whole(Vector2::new(1.0, 1.5), Vector2::new(1.7, 0.8)));
        lines.join_ends(false, all_seen, &mut out);
        assert_eq!(out.len(), 1, "{out:?}");
        assert!((out[0].b - jamb).norm() < 1e-4, "{out:?}");
        assert!((out[0].a - wall.ends[1]).norm() < 1e-4, "{out:?}");
        // The same echo cut short by a nearer one says nothing of where the wall ends.
        let mut lines = Lines::default();
        lines.add(wall, &mut out);
        lines.hear(Echo {
            whole: false,
            ..whole(Vector2::new(1.0, 1.5), jamb)
        });
        lines.join_ends(false, all_seen, &mut out);
        assert!(out.is_empty(), "{out:?}");
    }

    #[test]
    fn a_room_heard_a_thousand_times_from_one_place_keeps_its_first_hearings_and_its_corner() {
        // The walls x = 2 m and y = 1.5 m heard square from the origin sweep after sweep, their
        // ranges within ±1 cm of noise, and the corner between them heard at 2.5 m.
        let corner = Vector2::new(2.0, 1.5);
        let noise = |sweep: u32, k: u32| ((sweep * 7 + k * 3) % 21) as f32 * 0.001 - 0.01;
        let mut lines = Lines::default();
        let mut out = Vec::new();
        for sweep in 0..1000 {
            lines.add(
                Patch::new(Vector2::zeros(), 0.0, 2.0 + noise(sweep, 0), 10.0 * DEG),
                &mut out,
            );
            lines.add(
                Patch::new(
                    Vector2::zeros(),
                    90.0 * DEG,
                    1.5 + noise(sweep, 1),
                    10.0 * DEG,
                ),
                &mut out,
            );
            lines.hear(Echo {
                sensor: Vector2::zeros(),
                axis: 36.9 * DEG,
                half_width: 6.0 * DEG,
                range: 2.5 + noise(sweep, 2),
                tolerance: 0.05,
                whole: false,
                masked: false,
            });
            lines.join_ends(false, all_seen, &mut out);
            // Both walls drawn on to the corner, every sweep, each once: as many readings as
            // pairs of hearings of the two walls with this sweep's in them.
            assert_eq!(out.len(), 2, "sweep {sweep}: {out:?}");
            for stretch in &out {
                assert!((stretch.b - corner).norm() < 0.05, "{stretch:?}");
                assert_eq!(stretch.readings, 2 * sweep + 1, "{stretch:?}");
            }
        }
        // One patch per wall (the noise lies within the tolerance of one line), one region.
        assert_eq!(lines.patches.len(), 2);
        assert_eq!(lines.echoes.len(), 1);
        assert!(
            lines
                .patches
                .iter()
                .all(|k| k.heard == 1000 && k.fresh == 0)
        );
        // Heard from elsewhere, the same wall is a patch of its own, joined to the one kept.
        lines.add(heard_from(1.0), &mut out);
        assert_eq!(lines.patches.len(), 3);
        assert_eq!(out.len(), 1, "{out:?}");
    }

    #[test]
    fn a_patch_kept_for_many_confirms_the_corner_any_of_them_would_have() {
        // Two walls whose corner lies just beyond the echo's tolerance as first heard, and
        // within it as heard next, 2 cm nearer: the second hearing is kept as the first, which
        // stands for both.
        let walls = |range: f32| {
            [
                Patch::new(Vector2::zeros(), 45.0 * DEG, range, 10.0 * DEG),
                Patch::new(Vector2::zeros(), -45.0 * DEG, range, 10.0 * DEG),
            ]
        };
        let echo = Echo {
            sensor: Vector2::zeros(),
            axis: 0.0,
            half_width: 10.0 * DEG,
            range: 1.2,
            tolerance: 0.05,
            whole: false,
            masked: false,
        };
        // The corner of walls at 0.9 m lies at 1.273 m: 0.073 from the echo's range.
        let mut lines = Lines::default();
        let mut out = Vec::new();
        lines.hear(echo);
        walls(0.9).iter().for_each(|&w| lines.add(w, &mut out));
        lines.join_ends(false, all_seen, &mut out);
        assert!(out.is_empty(), "{out:?}");
        // At 0.88 m, 1.245 m: within. Kept apart, those would have been joined.
        walls(0.88).iter().for_each(|&w| lines.add(w, &mut out));
        assert_eq!(lines.patches.len(), 2);
        lines.join_ends(false, all_seen, &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
    }

    /// A stretch along the wall y = 3 (faced from below, 90°) from x = `from` to x = `to`.
    fn along_y3(from: f32, to: f32, readings: u32) -> Stretch {
        Stretch {
            a: Vector2::new(from, 3.0),
            b: Vector2::new(to, 3.0),
            facing: 90.0 * DEG,
            readings,
        }
    }

    #[test]
    fn one_wall_followed_to_its_corner_from_two_patches_is_drawn_once_with_both_readings() {
        // From patches ending at x = 0 and x = 1 on to the corner at x = 3 (the corner 1 cm off
        // in the second); and the other wall's stretch, elsewhere.
        let other = Stretch {
            a: Vector2::new(3.0, 0.0),
            b: Vector2::new(3.0, 3.0),
            facing: 0.0,
            readings: 1,
        };
        let mut second = along_y3(1.0, 3.0, 3);
        second.b.y += 0.01;
        let groups = overlapping(&[along_y3(0.0, 3.0, 2), other, second]);
        assert_eq!(groups.len(), 2, "{groups:?}");
        let pieces = groups[0].pieces(|_, _| true);
        assert_eq!(pieces.len(), 2, "{pieces:?}");
        let (near, far) = (pieces[0], pieces[1]);
        assert!((near.a - Vector2::new(0.0, 3.0)).norm() < 1e-5, "{near:?}");
        assert!((near.b - Vector2::new(1.0, 3.0)).norm() < 1e-5, "{near:?}");
        assert!((far.b - Vector2::new(3.0, 3.0)).norm() < 0.011, "{far:?}");
        assert_eq!((near.readings, far.readings), (2, 5));
        assert_eq!(groups[1].pieces(|_, _| true), vec![other]);
        // The longer stretch refused (a reading's foot at x = 0.5, a sixth of the way): the
        // shorter alone is drawn.
        let refused = |from: f32, to: f32| !(from..=to).contains(&(1.0 / 6.0));
        let pieces = groups[0].pieces(refused);
        assert_eq!(pieces.len(), 1, "{pieces:?}");
        assert!((pieces[0].a - Vector2::new(1.0, 3.0)).norm() < 1e-5);
        assert_eq!(pieces[0].readings, 3);
    }

    #[test]
    fn stretches_apart_on_one_line_or_on_other_lines_are_drawn_apart() {
        let apart = along_y3(2.0, 3.0, 1);
        let behind = Stretch {
            a: Vector2::new(0.0, 3.2),
            b: Vector2::new(1.0, 3.2),
            ..along_y3(0.0, 1.0, 1)
        };
        let facing_away = Stretch {
            facing: -90.0 * DEG,
            ..along_y3(0.0, 1.0, 1)
        };
        let stretches = [along_y3(0.0, 1.0, 1), apart, behind, facing_away];
        let groups = overlapping(&stretches);
        assert_eq!(groups.len(), 4, "{groups:?}");
        for (group, stretch) in groups.iter().zip(&stretches) {
            assert_eq!(group.pieces(|_, _| true), vec![*stretch]);
        }
    }
}
