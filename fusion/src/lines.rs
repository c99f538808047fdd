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

    fn on_line_with(&self, other: &Patch) -> bool {
        wrap_angle(self.facing - other.facing).abs() <= SAME_FACING
            && (self.offset - other.offset).abs()
                <= SAME_LINE_M + SAME_LINE_FRACTION * self.range.max(other.range)
            && (self.sensor - other.sensor).norm() >= OTHER_VIEWPOINT_M
    }
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

/// The patches placed so far.
#[derive(Debug, Clone, Default)]
pub(crate) struct Lines {
    patches: Vec<Patch>,
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
}
