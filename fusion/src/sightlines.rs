//! Stretches of wall refuted by the readings that would have heard them.
//!
//! The region model draws walls no reading heard: between two patches of one wall heard from two
//! places, and on from a patch to the corner where its wall meets another ([`crate::lines`]). A
//! stretch is wrong where the wall ends before it (a doorway, two walls in line, a partition's
//! end), so before it is drawn the mapper asks whether readings saw through it. Counting the
//! grid's free cells along it cannot tell that: a specular wall met at a slant answers nothing,
//! so the free evidence of a reading whose axis crosses it at a slant, towards an echo heard off
//! that axis in the lobe, clears a wall that is there. On the suite's `tune` split that refused
//! most of the stretches that lay on true walls (docs/fusion.md, thirteenth round).
//!
//! What a reading does prove: a flat wall answers a reading whose lobe holds the foot of the
//! perpendicular from the sensor to it, at the foot's distance. So if the foot of some reading's
//! sensor on a stretch lies on the stretch, within that reading's lobe, with nothing between
//! the two that could hide it, and the reading heard its first echo farther than the foot by
//! more than the depth tolerance, the wall is not there: the stretch is refuted. A reading whose
//! axis crosses the stretch at a slant, with the foot outside its lobe, says nothing about it.

use std::collections::VecDeque;

use nalgebra::Vector2;

use crate::geometry::wrap_angle;

/// Readings kept; the oldest are forgotten first (8 viewpoints of two 300° sweeps are about 800).
const KEPT: usize = 4096;

/// One reading with an echo: where the sensor was, where it pointed (world bearing), and the
/// range of the first echo it heard.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Sightline {
    pub position: Vector2<f32>,
    pub axis: f32,
    pub range: f32,
}

/// The latest readings with an echo.
#[derive(Debug, Clone, Default)]
pub(crate) struct Sightlines {
    kept: VecDeque<Sightline>,
    /// How many readings were ever pushed: the number of the next one.
    pushed: u64,
}

impl Sightlines {
    /// Remembers a reading with an echo.
    pub fn push(&mut self, reading: Sightline) {
        if self.kept.len() == KEPT {
            self.kept.pop_front();
        }
        self.kept.push_back(reading);
        self.pushed += 1;
    }

    /// The number the next reading pushed will have (readings are numbered from 0 as pushed):
    /// those pushed from now on are the ones [`Self::refute`] from it looks at.
    pub fn pushed(&self) -> u64 {
        self.pushed
    }

    pub fn clear(&mut self) {
        self.kept.clear();
    }

    /// Whether a reading kept, pushed as number `since` ([`Self::pushed`]) or later, refutes a
    /// wall from `a` to `b`: the foot of its sensor's perpendicular lies on the stretch, at most
    /// `lobe(distance)` off its axis (`None`: no lobe known at that distance, so no reading
    /// refutes), nearer than its echo by more than `margin(echo range)`, and `clear(sensor,
    /// foot)` says nothing hides the foot from the sensor.
    pub fn refute(
        &self,
        since: u64,
        a: Vector2<f32>,
        b: Vector2<f32>,
        lobe: impl Fn(f32) -> Option<f32>,
        margin: impl Fn(f32) -> f32,
        clear: impl Fn(Vector2<f32>, Vector2<f32>) -> bool,
    ) -> bool {
        let along = b - a;
        let length2 = along.norm_squared();
        if length2 <= f32::EPSILON {
            return false;
        }
        let first_kept = self.pushed - self.kept.len() as u64;
        let skip = usize::try_from(since.saturating_sub(first_kept)).unwrap_or(usize::MAX);
        self.kept.iter().skip(skip).any(|reading| {
            let t = (reading.position - a).dot(&along) / length2;
            if !(0.0..=1.0).contains(&t) {
                return false;
            }
            let foot = a + along * t;
            let to_foot = foot - reading.position;
            let distance = to_foot.norm();
            distance < reading.range - margin(reading.range)
                && lobe(distance).is_some_and(|lobe| {
                    wrap_angle(to_foot.y.atan2(to_foot.x) - reading.axis).abs() <= lobe
                })
                && clear(reading.position, foot)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEG: f32 = std::f32::consts::PI / 180.0;

    /// A stretch along x = 2 m from y = −0.5 to y = 0.5: its foot from the origin is (2, 0).
    fn stretch() -> (Vector2<f32>, Vector2<f32>) {
        (Vector2::new(2.0, -0.5), Vector2::new(2.0, 0.5))
    }

    fn heard(axis_deg: f32, range: f32) -> Sightlines {
        let mut lines = Sightlines::default();
        lines.push(Sightline {
            position: Vector2::zeros(),
            axis: axis_deg * DEG,
            range,
        });
        lines
    }

    fn refutes(lines: &Sightlines) -> bool {
        let (a, b) = stretch();
        lines.refute(0, a, b, |_| Some(10.0 * DEG), |_| 0.05, |_, _| true)
    }

    #[test]
    fn a_reading_aimed_near_the_foot_that_heard_farther_refutes_the_wall() {
        // 8° off the foot, inside a 10° lobe, echo at 3 m: a wall at x = 2 would have answered
        // at 2 m.
        assert!(refutes(&heard(8.0, 3.0)));
        // Heard at the wall's distance: the wall may be what it heard.
        assert!(!refutes(&heard(8.0, 2.02)));
    }

    #[test]
    fn a_reading_that_crosses_the_stretch_at_a_slant_says_nothing() {
        // Aimed at (2, 0.45), on the stretch: its axis crosses the wall's line there, 12.7° off
        // the foot, outside its 10° lobe. A wall there, met at 12.7°, would not have answered
        // it, so its echo at 3 m says nothing about the wall.
        let axis = (0.45f32 / 2.0).atan() / DEG;
        assert!(axis > 10.0);
        assert!(!refutes(&heard(axis, 3.0)));
        // Aimed 9° off the foot, the same echo refutes it.
        assert!(refutes(&heard(9.0, 3.0)));
    }

    #[test]
    fn a_foot_beyond_the_stretch_or_hidden_refutes_nothing() {
        // The sensor at y = 1 m: its foot (2, 1) lies beyond the stretch's end at y = 0.5.
        let mut lines = Sightlines::default();
        lines.push(Sightline {
            position: Vector2::new(0.0, 1.0),
            axis: 0.0,
            range: 3.0,
        });
        assert!(!refutes(&lines));
        // Hidden: something between the sensor and the foot.
        let (a, b) = stretch();
        assert!(!heard(0.0, 3.0).refute(0, a, b, |_| Some(10.0 * DEG), |_| 0.05, |_, _| false));
        // No lobe known at that distance.
        assert!(!heard(0.0, 3.0).refute(0, a, b, |_| None, |_| 0.05, |_, _| true));
    }

    #[test]
    fn only_readings_pushed_since_the_number_given_refute() {
        // Reading 0 refutes; reading 1, heard at the wall's distance, does not.
        let mut lines = heard(8.0, 3.0);
        lines.push(Sightline {
            position: Vector2::zeros(),
            axis: 8.0 * DEG,
            range: 2.02,
        });
        assert_eq!(lines.pushed(), 2);
        let (a, b) = stretch();
        let refutes_since =
            |since| lines.refute(since, a, b, |_| Some(10.0 * DEG), |_| 0.05, |_, _| true);
        assert!(refutes_since(0));
        assert!(!refutes_since(1));
        assert!(!refutes_since(2));
    }

    #[test]
    fn the_oldest_readings_are_forgotten() {
        let mut lines = heard(0.0, 3.0);
        for _ in 0..KEPT {
            lines.push(Sightline {
                position: Vector2::new(0.0, 5.0),
                axis: 0.0,
                range: 3.0,
            });
        }
        assert!(!refutes(&lines));
    }
}
