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

/// A sightline kept, with the unit vector along its axis (what [`Sightlines::refuted_at`] compares
/// with the direction to a foot, without an angle per reading), its number and its sector.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Kept {
    sightline: Sightline,
    direction: Vector2<f32>,
    number: u64,
    sector: u8,
}

/// Sightlines are kept by the bearing of their axis, in this many sectors of equal width: a
/// stretch is refuted only by readings aimed within the lobe of its normal (the direction to any
/// foot on its line), so [`Sightlines::refuted_at`] looks into the few sectors about the normal's
/// two bearings instead of every reading kept.
const SECTORS: usize = 72;
const _: () = assert!(SECTORS <= 128, "a sector's bit in a u128");
const SECTOR_WIDTH: f32 = std::f32::consts::TAU / SECTORS as f32;

/// The sector of world bearing `bearing` (any angle).
fn sector(bearing: f32) -> usize {
    let turns = bearing.rem_euclid(std::f32::consts::TAU) / SECTOR_WIDTH;
    (turns as usize).min(SECTORS - 1)
}

/// The lobe within which a reading hears a wall at its foot, as learnt: its half-width at a
/// distance (`None`: none learnt there), and the widest at any distance (at least every `at`;
/// `None`: none learnt at all).
pub(crate) struct Lobe<F: Fn(f32) -> Option<f32>> {
    pub at: F,
    pub widest: Option<f32>,
}

/// When the readings since the number asked for are at most this many,
/// [`Sightlines::refuted_at`] goes through them in the order pushed, skipping those of other
/// sectors by a bit each, instead of looking into each sector: a moving robot's stretches are
/// checked at each sweep's end against that sweep's readings alone, a thousand stretches
/// against a few dozen readings (issue 29).
const LATEST_IN_ORDER: u64 = 256;

/// The latest readings with an echo.
#[derive(Debug, Clone)]
pub(crate) struct Sightlines {
    /// Per sector of axis bearing, oldest first.
    sectors: Vec<VecDeque<Kept>>,
    /// Every reading kept, oldest first: the oldest is forgotten first.
    order: VecDeque<Kept>,
    /// How many readings were ever pushed: the number of the next one.
    pushed: u64,
    /// [`LATEST_IN_ORDER`] (a test sets it to look both ways).
    latest_in_order: u64,
}

impl Default for Sightlines {
    fn default() -> Self {
        Self {
            sectors: vec![VecDeque::new(); SECTORS],
            order: VecDeque::new(),
            pushed: 0,
            latest_in_order: LATEST_IN_ORDER,
        }
    }
}

impl Sightlines {
    /// Remembers a reading with an echo.
    pub fn push(&mut self, reading: Sightline) {
        if self.order.len() == KEPT
            && let Some(oldest) = self.order.pop_front()
        {
            self.sectors[usize::from(oldest.sector)].pop_front();
        }
        let sector = sector(reading.axis);
        let kept = Kept {
            sightline: reading,
            direction: Vector2::new(reading.axis.cos(), reading.axis.sin()),
            number: self.pushed,
            // SECTORS ≤ 128.
            sector: sector as u8,
        };
        self.sectors[sector].push_back(kept);
        self.order.push_back(kept);
        self.pushed += 1;
    }

    /// The number the next reading pushed will have (readings are numbered from 0 as pushed):
    /// those pushed from now on are the ones [`Self::refuted_at`] from it looks at.
    pub fn pushed(&self) -> u64 {
        self.pushed
    }

    pub fn clear(&mut self) {
        self.sectors.iter_mut().for_each(VecDeque::clear);
        self.order.clear();
    }

    /// Where the readings kept, pushed as number `since` ([`Self::pushed`]) or later, that refute
    /// a wall from `a` to `b` have their feet on it, as fractions of the way from `a` to `b`, one
    /// per reading, in no order. A reading refutes the wall if the foot of its sensor's
    /// perpendicular lies on it, at most `lobe.at(distance)` off its axis (`None`: no lobe known
    /// at that distance, so no reading refutes), nearer than its echo by more than
    /// `margin(echo range)`, and `clear(sensor, foot)` says nothing hides the foot from the
    /// sensor. Only readings aimed within `lobe.widest` of the wall's normal are looked at. A
    /// stretch of that line is refuted if a foot lies on it: the wall is refuted if there is one.
    pub fn refuted_at<L: Fn(f32) -> Option<f32>>(
        &self,
        since: u64,
        a: Vector2<f32>,
        b: Vector2<f32>,
        lobe: Lobe<L>,
        margin: impl Fn(f32) -> f32,
        clear: impl Fn(Vector2<f32>, Vector2<f32>) -> bool,
    ) -> impl Iterator<Item = f32> {
        let along = b - a;
        let length2 = along.norm_squared();
        let widest_lobe = lobe.widest.filter(|_| length2 > f32::EPSILON);
        // A little wider than the widest lobe, so that rounding never passes over a reading the
        // exact test below would take.
        let reach = widest_lobe.map_or(0.0, |w| w + 1e-3);
        let refuted_at = move |kept: &Kept| {
            let reading = &kept.sightline;
            let t = (reading.position - a).dot(&along) / length2;
            if !(0.0..=1.0).contains(&t) {
                return None;
            }
            let foot = a + along * t;
            let to_foot = foot - reading.position;
            // Aimed away from the foot: the exact test below would fail too.
            if to_foot.dot(&kept.direction) <= 0.0 && reach < std::f32::consts::FRAC_PI_2 {
                return None;
            }
            let distance = to_foot.norm();
            (distance < reading.range - margin(reading.range)
                && (lobe.at)(distance).is_some_and(|lobe| {
                    wrap_angle(to_foot.y.atan2(to_foot.x) - reading.axis).abs() <= lobe
                })
                && clear(reading.position, foot))
            .then_some(t)
        };
        // Every sector if the lobe reaches a right angle; else those about the normal's two
        // bearings (the direction to any foot on the line is its normal, one way or the other);
        // none if no lobe is learnt.
        let sectors = |towards: f32| {
            let first = sector(towards - reach);
            let count = ((towards + reach) / SECTOR_WIDTH).floor()
                - ((towards - reach) / SECTOR_WIDTH).floor();
            (first, count as usize + 1)
        };
        let normal = along.y.atan2(along.x) + std::f32::consts::FRAC_PI_2;
        // (first, how many) sectors, twice.
        let ranges = match widest_lobe {
            None => [(0, 0); 2],
            Some(_) if reach >= std::f32::consts::FRAC_PI_2 => [(0, SECTORS), (0, 0)],
            Some(_) => [sectors(normal), sectors(normal + std::f32::consts::PI)],
        };
        let sectors = ranges
            .into_iter()
            .flat_map(|(first, count)| (0..count).map(move |k| (first + k) % SECTORS));
        // The readings since `since`, if few, in the order pushed (the latest are the last),
        // those of the sectors looked into by their bit; else each sector's.
        let latest = self.pushed.saturating_sub(since);
        let in_order = latest <= self.latest_in_order;
        let bits = sectors.fold(0u128, |bits, k| bits | (1u128 << k));
        let first_latest = self.order.len().saturating_sub(latest as usize);
        let latest_in_order = self
            .order
            .range(
                if in_order {
                    first_latest
                } else {
                    self.order.len()
                }..,
            )
            .filter(move |kept| bits & (1u128 << kept.sector) != 0);
        // Each sector once, even where the two bearings' sectors meet (a lobe near a right
        // angle).
        let mut unvisited = if in_order { 0 } else { bits };
        let by_sector = std::iter::from_fn(move || {
            (unvisited != 0).then(|| {
                let k = unvisited.trailing_zeros() as usize;
                unvisited &= unvisited - 1;
                k
            })
        })
        // Each sector holds its readings in the order they were pushed: those before `since`
        // are skipped whole.
        .flat_map(move |k| {
            let sector = &self.sectors[k];
            let first = match sector.back() {
                Some(newest) if newest.number >= since => {
                    sector.partition_point(|kept| kept.number < since)
                }
                _ => sector.len(),
            };
            sector.range(first..)
        });
        latest_in_order.chain(by_sector).filter_map(refuted_at)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const DEG: f32 = std::f32::consts::PI / 180.0;

    /// A lobe of ±10° at every distance.
    fn ten_degrees() -> Lobe<impl Fn(f32) -> Option<f32>> {
        Lobe {
            at: |_| Some(10.0 * DEG),
            widest: Some(10.0 * DEG),
        }
    }

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
        lines
            .refuted_at(0, a, b, ten_degrees(), |_| 0.05, |_, _| true)
            .next()
            .is_some()
    }

    #[test]
    fn each_refuting_reading_gives_where_its_foot_lies_on_the_wall() {
        // Sensors at y = -0.25 and 0.25 aimed square at the wall x = 2, echoes at 3 m: feet at a
        // quarter and three quarters of the way from (2, -0.5) to (2, 0.5); one at y = 0.3 heard
        // the wall itself.
        let mut lines = Sightlines::default();
        for (y, range) in [(-0.25, 3.0), (0.25, 3.0), (0.3, 2.0)] {
            lines.push(Sightline {
                position: Vector2::new(0.0, y),
                axis: 0.0,
                range,
            });
        }
        let (a, b) = stretch();
        let mut feet: Vec<f32> = lines
            .refuted_at(0, a, b, ten_degrees(), |_| 0.05, |_, _| true)
            .collect();
        feet.sort_by(f32::total_cmp);
        assert_eq!(feet.len(), 2, "{feet:?}");
        assert!(
            (feet[0] - 0.25).abs() < 1e-6 && (feet[1] - 0.75).abs() < 1e-6,
            "{feet:?}"
        );
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
        assert!(
            heard(0.0, 3.0)
                .refuted_at(0, a, b, ten_degrees(), |_| 0.05, |_, _| false)
                .next()
                .is_none()
        );
        // No lobe known at that distance.
        assert!(
            heard(0.0, 3.0)
                .refuted_at(
                    0,
                    a,
                    b,
                    Lobe {
                        at: |_| None,
                        widest: None
                    },
                    |_| 0.05,
                    |_, _| true
                )
                .next()
                .is_none()
        );
    }

    #[test]
    fn readings_aimed_across_the_half_turn_or_from_behind_are_found_and_the_oldest_forgotten() {
        // A stretch along x = -2 m: its foot from the origin is (-2, 0), at 180°.
        let (a, b) = (Vector2::new(-2.0, -0.5), Vector2::new(-2.0, 0.5));
        let refuted = |lines: &Sightlines| {
            lines
                .refuted_at(0, a, b, ten_degrees(), |_| 0.05, |_, _| true)
                .next()
                .is_some()
        };
        // Aimed 1° either side of the half turn (the sectors' seam), echo at 3 m: both refute.
        assert!(refuted(&heard(179.0, 3.0)));
        assert!(refuted(&heard(-179.0, 3.0)));
        // From behind the wall, at (-4, 0) aimed along +x: the foot lies 2 m ahead.
        let mut behind = Sightlines::default();
        behind.push(Sightline {
            position: Vector2::new(-4.0, 0.0),
            axis: 0.0,
            range: 3.0,
        });
        assert!(refuted(&behind));
        // Aimed square to the foot's direction: nothing.
        assert!(!refuted(&heard(90.0, 3.0)));
        // The refuting reading is forgotten once as many others as are kept came after it.
        let mut lines = heard(180.0, 3.0);
        for _ in 0..KEPT - 1 {
            lines.push(Sightline {
                position: Vector2::zeros(),
                axis: 90.0 * DEG,
                range: 3.0,
            });
        }
        assert!(refuted(&lines));
        lines.push(Sightline {
            position: Vector2::zeros(),
            axis: 90.0 * DEG,
            range: 3.0,
        });
        assert!(!refuted(&lines));
    }

    proptest! {
        /// Whichever way the readings are gone through, in the order pushed or sector by
        /// sector, the same readings refute a stretch, at the same feet; past [`KEPT`]
        /// readings, so that the oldest are forgotten inside the code checked.
        #[test]
        fn in_order_and_by_sector_the_same_feet(
            readings in prop::collection::vec(
                (-3.0f32..3.0, -3.0f32..3.0, -180.0f32..180.0, 0.3f32..4.0),
                1..4400,
            ),
            ends in (-3.0f32..3.0, -3.0f32..3.0, -3.0f32..3.0, -3.0f32..3.0),
            lobe_deg in 5.0f32..100.0,
            since_back in 0u64..600,
        ) {
            let mut lines = Sightlines::default();
            for &(x, y, axis, range) in &readings {
                lines.push(Sightline { position: Vector2::new(x, y), axis: axis * DEG, range });
            }
            let (a, b) = (Vector2::new(ends.0, ends.1), Vector2::new(ends.2, ends.3));
            let since = lines.pushed().saturating_sub(since_back);
            let mut feet = |latest_in_order| {
                lines.latest_in_order = latest_in_order;
                let lobe = Lobe {
                    at: |d: f32| (d < 3.5).then_some(lobe_deg * DEG),
                    widest: Some(lobe_deg * DEG),
                };
                let mut feet: Vec<f32> = lines
                    .refuted_at(since, a, b, lobe, |r| 0.02 + 0.01 * r, |_, _| true)
                    .collect();
                feet.sort_by(f32::total_cmp);
                feet
            };
            let (in_order, by_sector) = (feet(u64::MAX), feet(0));
            prop_assert_eq!(&in_order, &by_sector);
        }
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
        let refutes_since = |since| {
            lines
                .refuted_at(since, a, b, ten_degrees(), |_| 0.05, |_, _| true)
                .next()
                .is_some()
        };
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
