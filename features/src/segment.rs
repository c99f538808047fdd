//! Partial planes: each plane feature as a line segment with end points.
//!
//! A specular wall returns only from the foot of the sensor's perpendicular, so a plane feature
//! knows its line exactly but, from one place, only one point of it: the **feet** of the
//! perpendiculars from every place it was seen from. A segment grows from there along the line:
//!
//! - to the nearest **corner** feature lying on the line on each side (a concave corner is where
//!   the wall meets the next one: the wall runs from its foot to it);
//! - otherwise through **support points** (occupied grid cells, passed in by the caller) within
//!   [`SegmentConfig::support_tolerance_m`] of the line, as long as consecutive ones lie no
//!   farther apart than [`SegmentConfig::max_gap_m`] (a wider gap may be a doorway or the end).
//!
//! With neither, the segment is the span of the feet (a single point from one place).

use nalgebra::Point2;

use crate::config::SegmentConfig;
use crate::feature::{Feature, FeatureKind};

/// What fixed an end of a segment.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SegmentEnd {
    /// A corner feature (its id).
    Corner(u64),
    /// The last support point reached.
    Support,
    /// The outermost foot of a perpendicular: nothing beyond it is known.
    Foot,
}

/// A partial plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Id of the plane feature.
    pub plane_id: u64,
    /// End points, in the direction 90° counter-clockwise of the normal.
    pub a: Point2<f64>,
    pub b: Point2<f64>,
    /// What fixed `a` and `b`.
    pub ends: [SegmentEnd; 2],
}

impl Segment {
    pub fn length_m(&self) -> f64 {
        (self.b - self.a).norm()
    }
}

/// One segment per plane among `features`.
pub fn segments(
    features: &[&Feature],
    support: &[Point2<f64>],
    cfg: &SegmentConfig,
) -> Vec<Segment> {
    let corners: Vec<&Feature> = features
        .iter()
        .copied()
        .filter(|f| f.kind() == FeatureKind::Corner)
        .collect();
    features
        .iter()
        .filter_map(|plane| {
            let dir = plane.direction()?;
            let normal = plane.normal();
            let d = plane.distance_m()?;
            let along = |p: &Point2<f64>| p.coords.dot(&dir);
            let off_line = |p: &Point2<f64>| (p.coords.dot(&normal) - d).abs();
            let (lo, hi) = plane.feet();
            // Corners on the line, beyond the feet on either side: the nearest bounds each end.
            let on_line: Vec<(f64, u64)> = corners
                .iter()
                .filter(|c| off_line(&c.position()) <= cfg.corner_tolerance_m)
                .map(|c| (along(&c.position()), c.id()))
                .collect();
            let below = on_line
                .iter()
                .filter(|(t, _)| *t < lo)
                .max_by(|a, b| a.0.total_cmp(&b.0));
            let above = on_line
                .iter()
                .filter(|(t, _)| *t > hi)
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let mut ts: Vec<f64> = support
                .iter()
                .filter(|p| off_line(p) <= cfg.support_tolerance_m)
                .map(along)
                .collect();
            ts.sort_by(f64::total_cmp);
            let (a, end_a) = match below {
                Some(&(t, id)) => (t, SegmentEnd::Corner(id)),
                None => grow(ts.iter().rev().copied().map(|t| -t), -lo, cfg.max_gap_m)
                    .map_or((lo, SegmentEnd::Foot), |t| (-t, SegmentEnd::Support)),
            };
            let (b, end_b) = match above {
                Some(&(t, id)) => (t, SegmentEnd::Corner(id)),
                None => grow(ts.iter().copied(), hi, cfg.max_gap_m)
                    .map_or((hi, SegmentEnd::Foot), |t| (t, SegmentEnd::Support)),
            };
            let foot = plane.position().coords;
            Some(Segment {
                plane_id: plane.id(),
                a: Point2::from(foot + dir * a),
                b: Point2::from(foot + dir * b),
                ends: [end_a, end_b],
            })
        })
        .collect()
}

/// From `start`, the farthest of the increasing `ts` reached in hops of at most `max_gap`
/// (beginning with the support behind `start`), if it lies beyond `start`.
fn grow(ts: impl Iterator<Item = f64>, start: f64, max_gap: f64) -> Option<f64> {
    let mut reach = start;
    for t in ts {
        if t <= reach {
            continue;
        }
        if t - reach > max_gap {
            break;
        }
        reach = t;
    }
    (reach > start).then_some(reach)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classify::Observation;
    use crate::config::FeatureConfig;
    use crate::map::FeatureMap;
    use crate::pings::Sweep;
    use nalgebra::Isometry2;

    fn observation(kind: FeatureKind, range_m: f64, bearing_deg: f64) -> Observation {
        Observation {
            kind,
            range_m,
            bearing_deg,
            range_sigma_random_m: 0.001,
            range_sigma_systematic_m: 0.002,
            bearing_sigma_deg: 0.3,
            bearing_sigma_random_deg: 0.0,
            rcd: 0,
            whole: true,
            also_plane: false,
            also_corner: false,
            pair_centre_deg: None,
        }
    }

    /// A map holding the wall x = 1.2 (seen from the origin) and the given corners.
    fn wall_map(corners: &[(f64, f64)]) -> FeatureMap {
        let mut m = FeatureMap::new(FeatureConfig::default()).unwrap();
        let mut obs = vec![observation(FeatureKind::Plane, 1.2, 0.0)];
        obs.extend(corners.iter().map(|&(x, y)| {
            observation(
                FeatureKind::Corner,
                f64::hypot(x, y),
                y.atan2(x).to_degrees(),
            )
        }));
        m.merge(
            &obs,
            &Sweep::default(),
            &Isometry2::identity(),
            &nalgebra::Matrix3::zeros(),
        );
        m
    }

    #[test]
    fn a_wall_runs_from_corner_to_corner() {
        let m = wall_map(&[(1.2, 1.2), (1.2, -1.2), (-1.2, 1.2)]);
        let s = m.segments(&[]);
        assert_eq!(s.len(), 1);
        let s = s[0];
        assert!((s.a - Point2::new(1.2, -1.2)).norm() < 1e-6, "{s:?}");
        assert!((s.b - Point2::new(1.2, 1.2)).norm() < 1e-6, "{s:?}");
        assert!(matches!(
            s.ends,
            [SegmentEnd::Corner(_), SegmentEnd::Corner(_)]
        ));
    }

    #[test]
    fn support_points_extend_a_wall_until_a_gap() {
        let m = wall_map(&[(1.2, 1.2)]);
        // Cells along the wall below its foot, every 4 cm to y = -0.4, then a 30 cm gap; one cell
        // off the line is ignored.
        let mut support: Vec<Point2<f64>> = (1..=10)
            .map(|k| Point2::new(1.21, -0.04 * f64::from(k)))
            .collect();
        support.push(Point2::new(1.2, -0.7));
        support.push(Point2::new(1.5, -0.2));
        let s = m.segments(&support)[0];
        assert!((s.a - Point2::new(1.2, -0.4)).norm() < 1e-6, "{s:?}");
        assert_eq!(s.ends[0], SegmentEnd::Support);
        assert!(matches!(s.ends[1], SegmentEnd::Corner(_)));
        // Without support nor corners: just the foot.
        let bare = wall_map(&[]).segments(&[])[0];
        assert!(bare.length_m() < 1e-9);
        assert_eq!(bare.ends, [SegmentEnd::Foot, SegmentEnd::Foot]);
    }
}
