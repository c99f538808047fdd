//! Point reflectors: a reflector heard whole from two viewpoints at two bearings.
//!
//! A whole region of constant depth ([`crate::regions`]) is drawn as a straight patch square to
//! its middle bearing: what a wall met squarely gives. A post, an edge or a corner gives the same
//! region from one viewpoint, and its patch is then a stretch of wall that is not there, across
//! the room in front of a corner and outside it behind (Leonard and Durrant-Whyte's regions of
//! constant depth: one viewpoint cannot tell a plane from a point). Two viewpoints can: a wall
//! answers each at the foot of its own perpendicular, so two viewpoints hear it at one spot only
//! along one bearing; a point answers every viewpoint at itself, whatever the bearing. So a
//! reflector heard whole at the same spot from two viewpoints whose bearings to it differ by
//! [`POINT_APART`] or more is a point, and both its patches are drawn again a cell wide. Bearings
//! are compared folded, as a wall's incidence is: a thin wall heard at one spot from its two sides
//! is heard along one line from opposite ways.

use std::collections::VecDeque;

use nalgebra::Vector2;

use crate::geometry::{incidence, wrap_angle};
// One viewpoint, and one bearing heard again, as the lines tell them.
use crate::lines::{OTHER_VIEWPOINT_M, SAME_BEARING};

/// Two viewpoints' bearings to one spot differ by at least this much for it to be a point,
/// radians (6°, a reading's step): a wall's foot is heard at one spot from one bearing only, to
/// within the few degrees a region's middle bearing is off (its ends are known to a reading).
const POINT_APART: f32 = 6.0 * std::f32::consts::PI / 180.0;
/// Patches kept; the oldest are forgotten first.
const KEPT: usize = 4096;

/// A whole region's patch as drawn: from where, along which bearing, how far, how wide, as
/// strong as how many readings (all its hearings together), whether it is drawn as a point, and
/// the head's step between the region's readings (radians; 0 if unknown).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Drawn {
    pub position: Vector2<f32>,
    pub axis: f32,
    pub range: f32,
    pub half_angle: f32,
    pub readings: f32,
    pub point: bool,
    pub step: f32,
}

impl Drawn {
    /// Where the reflector is: on the middle bearing, at the range.
    pub fn reflector(&self) -> Vector2<f32> {
        self.position + Vector2::new(self.axis.cos(), self.axis.sin()) * self.range
    }

    /// How far across its bearing the reflector may lie from [`Self::reflector`]: the region's
    /// ends are known to a step of the head, so its middle bearing to half a step.
    fn lateral(&self) -> f32 {
        self.range * (0.5 * self.step).tan()
    }

    fn same_viewpoint(&self, other: &Drawn) -> bool {
        (self.position - other.position).norm() < OTHER_VIEWPOINT_M
    }
}

/// The whole regions' patches drawn so far (each repeated hearing counted in the one it repeats).
#[derive(Debug, Default)]
pub(crate) struct Points {
    kept: VecDeque<Drawn>,
    /// How many of the newest kept patches [`Points::corners`] has not looked at.
    unchecked: usize,
}

/// What [`Points::add`] found: whether the new patch's reflector is a point, and the patches kept
/// that became points with it (as they were drawn, to be taken back).
#[derive(Debug, Default, PartialEq)]
pub(crate) struct Found {
    pub point: bool,
    pub became_points: Vec<Drawn>,
}

impl Points {
    /// Adds `patch` (its `point` ignored), whose reflector lies within `tolerance` of where it
    /// is along its bearing; says whether it is a point and which kept patches became points
    /// with it, marking them so.
    ///
    /// Two patches' reflectors are one spot if they lie within `tolerance` and half their
    /// lateral errors together ([`Drawn::lateral`]) of each other: a middle bearing half a step
    /// off puts a reflector 10 cm aside at 2 m, and a corner heard from two viewpoints, each
    /// patch square to its own bearing, was two walls drawn across each other. Half, not the
    /// whole sum (both bearings off by their most, opposite ways): on the generated suite's
    /// `tune` split the whole sum cost the `srf05` profile 0.01 of recall for no precision
    /// (docs/fusion.md, twenty-seventh round).
    pub fn add(&mut self, mut patch: Drawn, tolerance: f32) -> Found {
        let reflector = patch.reflector();
        let mut found = Found::default();
        for kept in &mut self.kept {
            let apart = tolerance + 0.5 * (kept.lateral() + patch.lateral());
            if !kept.same_viewpoint(&patch)
                && incidence(kept.axis, patch.axis) >= POINT_APART
                && (kept.reflector() - reflector).norm() <= apart
            {
                found.point = true;
                if !kept.point {
                    found.became_points.push(*kept);
                    kept.point = true;
                }
            }
        }
        patch.point = found.point;
        let repeated = self.kept.iter_mut().find(|kept| {
            kept.same_viewpoint(&patch)
                && wrap_angle(kept.axis - patch.axis).abs() <= SAME_BEARING
                && (kept.range - patch.range).abs() <= tolerance
        });
        match repeated {
            // Drawn as the kept one is: a point again, or a wall that may become one; or, when
            // another viewpoint now shows the spot to be a point (within this hearing's
            // tolerance, wider than the kept one's was), a point, the kept one with it.
            Some(kept) => {
                if found.point && !kept.point {
                    found.became_points.push(*kept);
                    kept.point = true;
                }
                kept.readings += patch.readings;
                found.point = kept.point;
            }
            None => {
                if self.kept.len() >= KEPT {
                    self.kept.pop_front();
                }
                self.kept.push_back(patch);
                self.unchecked = (self.unchecked + 1).min(self.kept.len());
            }
        }
        found
    }

    /// Marks as points the patches kept since the last call, not points yet, that `is_corner`
    /// says are a corner's, and returns them as drawn (to be taken back).
    pub fn corners(&mut self, is_corner: impl Fn(&Drawn) -> bool) -> Vec<Drawn> {
        let from = self.kept.len() - self.unchecked;
        self.unchecked = 0;
        let mut found = Vec::new();
        for kept in self.kept.range_mut(from..) {
            if !kept.point && is_corner(kept) {
                kept.point = true;
                found.push(*kept);
            }
        }
        found
    }

    pub fn clear(&mut self) {
        self.kept.clear();
        self.unchecked = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn heard_from(x: f32, y: f32, at: Vector2<f32>, readings: f32) -> Drawn {
        let position = Vector2::new(x, y);
        let to = at - position;
        Drawn {
            position,
            axis: to.y.atan2(to.x),
            range: to.norm(),
            half_angle: 0.3,
            readings,
            point: false,
            step: 0.0,
        }
    }

    #[test]
    fn a_post_heard_from_two_bearings_is_a_point_and_the_first_patch_becomes_one() {
        let post = Vector2::new(2.0, 0.0);
        let mut points = Points::default();
        assert_eq!(
            points.add(heard_from(0.0, 0.0, post, 5.0), 0.05),
            Found::default()
        );
        let found = points.add(heard_from(0.5, -1.0, post, 4.0), 0.05);
        assert!(found.point);
        assert_eq!(found.became_points, vec![heard_from(0.0, 0.0, post, 5.0)]);
        // A third viewpoint: a point, and nothing kept to draw again.
        let found = points.add(heard_from(1.0, 1.0, post, 4.0), 0.05);
        assert_eq!((found.point, found.became_points.len()), (true, 0));
    }

    #[test]
    fn a_wall_heard_at_two_feet_or_twice_from_one_place_is_no_point() {
        let mut points = Points::default();
        // The wall x = 2 from (0, 0) and (0, 1): each at its own foot, along one bearing.
        points.add(heard_from(0.0, 0.0, Vector2::new(2.0, 0.0), 5.0), 0.05);
        let found = points.add(heard_from(0.0, 1.0, Vector2::new(2.0, 1.0), 5.0), 0.05);
        assert_eq!(found, Found::default());
        // From (1, 0), on the first foot's perpendicular: the same spot, the same bearing.
        let found = points.add(heard_from(1.0, 0.0, Vector2::new(2.0, 0.0), 5.0), 0.05);
        assert_eq!(found, Found::default());
        // A thin wall heard at that foot from its other side, from (3, 0): the opposite way.
        let found = points.add(heard_from(3.0, 0.0, Vector2::new(2.0, 0.0), 5.0), 0.05);
        assert_eq!(found, Found::default());
        // One viewpoint, 10° round, within the tolerance: one viewpoint cannot tell.
        let mut points = Points::default();
        points.add(heard_from(0.0, 0.0, Vector2::new(2.0, 0.0), 5.0), 0.4);
        let found = points.add(heard_from(0.05, 0.0, Vector2::new(2.0, 0.35), 5.0), 0.4);
        assert!(!found.point);
    }

    #[test]
    fn a_wall_heard_again_where_another_viewpoint_heard_a_point_becomes_one() {
        let post = Vector2::new(2.0, 0.0);
        let beside = Vector2::new(2.0, 0.03);
        let mut points = Points::default();
        // From (0.5, -1.0) at the post; from the origin 3 cm beside it, within neither's 1 cm.
        points.add(heard_from(0.5, -1.0, post, 4.0), 0.01);
        let first = heard_from(0.0, 0.0, beside, 5.0);
        assert_eq!(points.add(first, 0.01), Found::default());
        // Heard again from the origin with a 5 cm tolerance: the post from (0.5, -1.0) lies
        // within it, so this hearing is a point, and both kept patches become points: the one
        // from (0.5, -1.0) and the first from the origin, which this hearing repeats.
        let found = points.add(first, 0.05);
        assert!(found.point);
        assert_eq!(
            found.became_points,
            vec![heard_from(0.5, -1.0, post, 4.0), first]
        );
        let kept: Vec<(f32, bool)> = points.kept.iter().map(|d| (d.readings, d.point)).collect();
        assert_eq!(kept, vec![(4.0, true), (10.0, true)]);
    }

    #[test]
    fn a_point_heard_again_from_one_place_stays_a_point_and_counts_its_readings() {
        let post = Vector2::new(2.0, 0.0);
        let mut points = Points::default();
        points.add(heard_from(0.0, 0.0, post, 5.0), 0.05);
        points.add(heard_from(0.5, -1.0, post, 4.0), 0.05);
        let found = points.add(heard_from(0.0, 0.0, post, 3.0), 0.05);
        assert_eq!((found.point, found.became_points.len()), (true, 0));
        let first = points.kept.front().copied();
        assert_eq!(first.map(|d| (d.readings, d.point)), Some((8.0, true)));
    }

    #[test]
    fn two_reflectors_apart_by_what_their_bearings_leave_open_are_one_point() {
        // A post at (2, 0) heard from two places, each middle bearing 2° off (a 6° step leaves
        // 3°): its reflectors lie 10 cm apart, beyond the 5 cm depth tolerance.
        let post = Vector2::new(2.0, 0.0);
        let off = |x: f32, y: f32, turn_deg: f32| {
            let mut d = heard_from(x, y, post, 3.0);
            d.axis += turn_deg.to_radians();
            d
        };
        let (a, b) = (off(0.0, 0.0, 2.0), off(2.0, -2.0, -2.0));
        assert!((a.reflector() - b.reflector()).norm() > 0.1);
        let mut points = Points::default();
        points.add(a, 0.05);
        assert!(!points.add(b, 0.05).point, "no step known: 5 cm");
        let step = 6f32.to_radians();
        let mut points = Points::default();
        points.add(Drawn { step, ..a }, 0.05);
        let found = points.add(Drawn { step, ..b }, 0.05);
        assert!(found.point && found.became_points.len() == 1);
    }

    #[test]
    fn corners_looks_at_each_new_patch_once_and_makes_the_corners_points() {
        let corner = Vector2::new(2.0, 2.0);
        let at_corner = heard_from(0.0, 0.0, corner, 5.0);
        let mut points = Points::default();
        points.add(at_corner, 0.05);
        points.add(heard_from(0.0, 0.0, Vector2::new(2.0, 0.0), 5.0), 0.05);
        let found = points.corners(|d| (d.reflector() - corner).norm() < 0.01);
        assert_eq!(
            found,
            vec![Drawn {
                point: true,
                ..at_corner
            }]
        );
        // Each patch looked at once: nothing more, though the wall's patch is no point.
        assert!(points.corners(|_| true).is_empty());
        // Heard from another viewpoint at another bearing: a point already, nothing to take
        // back; the new patch is looked at next time.
        let found = points.add(heard_from(0.5, -1.0, corner, 4.0), 0.05);
        assert!(found.point && found.became_points.is_empty());
        assert!(points.corners(|_| true).is_empty());
        let wall = heard_from(0.0, 1.0, Vector2::new(2.0, 1.0), 5.0);
        points.add(wall, 0.05);
        assert_eq!(
            points.corners(|_| true),
            vec![Drawn {
                point: true,
                ..wall
            }]
        );
    }
}
