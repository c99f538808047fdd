//! Walls between the feet: patches heard from different viewpoints that lie on one line.
//!
//! A specular wall answers a sensor only at the foot of its perpendicular, so each viewpoint's
//! region of constant depth ([`crate::regions`]) gives a short patch of wall around its own foot.
//! Two patches from different sensor positions that face the same way and lie on the same line
//! are one wall (a post or a corner, heard from two places, gives patches square to two different
//! bearings), and the stretch between them is wall too, unless a reading saw through it (the
//! mapper checks that against the grid before it fills the stretch).

use nalgebra::Vector2;

use crate::geometry::wrap_angle;

/// Two patches face the same way within this angle, radians (3°).
const SAME_FACING: f32 = 3.0 * std::f32::consts::PI / 180.0;
/// Two patches lie on one line while their offsets differ by at most this much, metres …
const SAME_LINE_M: f32 = 0.03;
/// … plus this fraction of the farther patch's range.
const SAME_LINE_FRACTION: f32 = 0.01;
/// Patches from sensor positions closer than this are from one viewpoint (its repeated sweeps),
/// and say nothing about the wall between their feet.
const OTHER_VIEWPOINT_M: f32 = 0.1;
/// The longest stretch filled between two patches, metres: beyond it, a wall heard at two feet
/// is as likely to be two walls in line (a corridor's sides across a doorway).
pub(crate) const LONGEST_STRETCH_M: f32 = 4.0;
/// Two walls meet at a corner when their facings differ by at least this angle, radians (30°):
/// closer to parallel, their lines cross far from where either was heard.
const CORNER_ANGLE: f32 = 30.0 * std::f32::consts::PI / 180.0;
/// A patch's wall is followed this far beyond its ends, metres, to a corner.
const CORNER_REACH_M: f32 = 1.5;
/// Patches kept; the oldest are forgotten first.
const KEPT: usize = 4096;
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
        }
    }

    /// Whether `point` lies on this patch's line, within `tolerance`, and within
    /// [`CORNER_REACH_M`] of the patch.
    fn reaches(&self, point: Vector2<f32>, tolerance: f32) -> bool {
        let (normal, _) = frame(self.facing);
        (normal.dot(&point) - self.offset).abs() <= tolerance
            && self
                .ends
                .iter()
                .any(|end| (end - point).norm() <= CORNER_REACH_M)
    }

    /// Whether `point` lies on this patch's line, within `tolerance`.
    fn passes_through(&self, point: Vector2<f32>, tolerance: f32) -> bool {
        let (normal, _) = frame(self.facing);
        (normal.dot(&point) - self.offset).abs() <= tolerance
    }

    /// The stretch of this patch's wall from its nearer end to `corner`, a point of its line
    /// beyond the patch, at most [`CORNER_WALL_M`] from that end.
    fn towards(&self, corner: Vector2<f32>) -> Option<Stretch> {
        let (_, along) = frame(self.facing);
        let t = along.dot(&corner);
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
        })
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
    let (na, _) = frame(a.facing);
    let (nb, _) = frame(b.facing);
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

/// A stretch of wall between two patches: its ends, and the bearing it is faced from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Stretch {
    pub a: Vector2<f32>,
    pub b: Vector2<f32>,
    pub facing: f32,
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
}

impl Echo {
    /// Whether this region could be the echo of a reflector at `point`: its range, within its
    /// bearings. A concave corner answers from any bearing within the lobe.
    /// Where its reflector lies if it is whole: at its middle bearing and range.
    fn reflector(&self) -> Vector2<f32> {
        self.sensor + Vector2::new(self.axis.cos(), self.axis.sin()) * self.range
    }

    fn heard(&self, point: Vector2<f32>) -> bool {
        let to = point - self.sensor;
        (to.norm() - self.range).abs() <= self.tolerance
            && wrap_angle(to.y.atan2(to.x) - self.axis).abs() <= self.half_width + ECHO_MARGIN
    }
}

/// The patches placed so far, and the regions heard.
#[derive(Debug, Clone, Default)]
pub(crate) struct Lines {
    patches: Vec<Patch>,
    /// The regions heard, to confirm corners.
    echoes: Vec<Echo>,
    /// How many of the last patches and echoes were added since [`Self::join_ends`] last ran.
    recent: usize,
    recent_echoes: usize,
}

impl Lines {
    /// Adds `patch`; writes into `out` the stretches between it and the nearest patch on its line
    /// on either side, from another viewpoint, at most [`LONGEST_STRETCH_M`] away.
    pub fn add(&mut self, patch: Patch, out: &mut Vec<Stretch>) {
        out.clear();
        // The nearest gap before the patch and after it, and the patch across it.
        let mut before: Option<(f32, &Patch)> = None;
        let mut after: Option<(f32, &Patch)> = None;
        for other in self.patches.iter().filter(|o| patch.on_line_with(o)) {
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
                });
            }
        }
        if self.patches.len() == KEPT {
            self.patches.remove(0);
        }
        self.patches.push(patch);
        self.recent = (self.recent + 1).min(self.patches.len());
    }

    /// Remembers a region heard, which may confirm a corner ([`Self::join_ends`]).
    pub fn hear(&mut self, echo: Echo) {
        if self.echoes.len() == KEPT_ECHOES {
            self.echoes.remove(0);
        }
        self.echoes.push(echo);
        self.recent_echoes = (self.recent_echoes + 1).min(self.echoes.len());
    }

    /// Writes into `out` the stretches of wall from patches to where their walls end, at most
    /// [`CORNER_WALL_M`] beyond each patch, for the patches and echoes added since the last call:
    ///
    /// - to the corner where two walls meet: their lines cross at least 30° apart, each wall's
    ///   sensor lies in front of the other wall (a concave corner, as a room's, seen from
    ///   inside), and some region heard an echo at the corner's range and bearing (a concave
    ///   corner answers from any bearing in the lobe; two walls that end before meeting do not);
    /// - to a whole region's reflector that lies on a wall's line: the wall's end (a door's jamb,
    ///   a partition's edge, a corner heard whole).
    pub fn join_ends(&mut self, out: &mut Vec<Stretch>) {
        out.clear();
        let recent = self.patches.len() - self.recent;
        self.recent = 0;
        for (i, a) in self.patches.iter().enumerate().skip(recent) {
            for b in &self.patches[..i] {
                let Some(corner) = concave_corner(a, b) else {
                    continue;
                };
                // Within reach of either patch before the echoes are searched: in a large map
                // most pairs of walls meet far from both.
                let stretches = [a.towards(corner), b.towards(corner)];
                if stretches.iter().all(Option::is_none)
                    || !self.echoes.iter().any(|e| e.heard(corner))
                {
                    continue;
                }
                out.extend(stretches.into_iter().flatten());
            }
        }
        // A whole region's reflector on a wall's line beyond its patch: where the wall ends (a
        // door's jamb, a partition's edge, a corner heard whole), on patches new or old.
        let new_echoes = self.echoes.len() - self.recent_echoes;
        self.recent_echoes = 0;
        for (i, a) in self.patches.iter().enumerate() {
            let echoes = if i >= recent {
                &self.echoes[..]
            } else {
                &self.echoes[new_echoes..]
            };
            out.extend(
                echoes
                    .iter()
                    .filter(|e| e.whole && a.passes_through(e.reflector(), e.tolerance))
                    .filter_map(|e| a.towards(e.reflector())),
            );
        }
    }

    /// Whether two walls heard so far meet at `point` (within `tolerance`): two patches whose
    /// lines pass through it, facing ways at least 30° apart, each within 1.5 m of it.
    pub fn corner_at(&self, point: Vector2<f32>, tolerance: f32) -> bool {
        let through: Vec<&Patch> = self
            .patches
            .iter()
            .filter(|p| p.reaches(point, tolerance))
            .collect();
        through.iter().enumerate().any(|(i, a)| {
            through[i + 1..].iter().any(|b| {
                let apart = wrap_angle(a.facing - b.facing).abs();
                (CORNER_ANGLE..=std::f32::consts::PI - CORNER_ANGLE).contains(&apart)
            })
        })
    }

    pub fn clear(&mut self) {
        self.patches.clear();
        self.echoes.clear();
        self.recent = 0;
        self.recent_echoes = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEG: f32 = std::f32::consts::PI / 180.0;

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
    #[test]
    fn walls_are_drawn_to_the_concave_corner_where_an_echo_was_heard() {
        // A room's walls x = 2 m and y = 1.5 m heard square from the origin (patches ±10°); their
        // corner at (2, 1.5) answers 2.5 m away at 36.9°, between the feet's regions.
        let corner = Vector2::new(2.0, 1.5);
        let walls = [
            Patch::new(Vector2::zeros(), 0.0, 2.0, 10.0 * DEG),
            Patch::new(Vector2::zeros(), 90.0 * DEG, 1.5, 10.0 * DEG),
        ];
        let echo = |range: f32| Echo {
            sensor: Vector2::zeros(),
            axis: 36.9 * DEG,
            half_width: 6.0 * DEG,
            range,
            tolerance: 0.05,
            whole: false,
        };
        let joined = |echoes: &[Echo], walls: &[Patch]| {
            let mut lines = Lines::default();
            let mut out = Vec::new();
            echoes.iter().for_each(|&e| lines.hear(e));
            walls.iter().for_each(|&w| lines.add(w, &mut out));
            lines.join_ends(&mut out);
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
        };
        assert!(joined(&[heard_outside], &outside).is_empty());
        // Only once per patch added: a second call without new patches draws nothing.
        let mut lines = Lines::default();
        let mut out = Vec::new();
        lines.hear(echo(2.5));
        walls.iter().for_each(|&w| lines.add(w, &mut out));
        lines.join_ends(&mut out);
        lines.join_ends(&mut out);
        assert!(out.is_empty());
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
            }
        };
        let jamb = Vector2::new(2.0, 1.2);
        let mut lines = Lines::default();
        let mut out = Vec::new();
        lines.add(wall, &mut out);
        lines.hear(whole(Vector2::new(1.0, 1.5), jamb));
        lines.hear(whole(Vector2::new(1.0, 1.5), Vector2::new(1.7, 0.8)));
        lines.join_ends(&mut out);
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
        lines.join_ends(&mut out);
        assert!(out.is_empty(), "{out:?}");
    }
}
