//! Regions of constant depth: where a sweep's echoes put their occupied evidence.
//!
//! A specular reflector (a wall, a board) answers every reading whose lobe holds the foot of its
//! perpendicular, and every one of them hears the same range, the perpendicular distance d. Each
//! reading alone can only put its echo on its own axis, so a sweep draws an arc of radius d
//! tangent to the wall, up to d·(1/cos 28° − 1) in front of it off the perpendicular (20 cm at
//! 1.5 m): only the reading aimed at the foot is right. The readings that heard the same range one
//! after the other form a region of constant depth (Leonard & Durrant-Whyte, *Directed Sonar
//! Sensing for Mobile Robot Navigation*, 1992); the reflector lies at the region's middle bearing,
//! whether it is the foot of a wall or a post, a corner or an edge heard over the lobe's width.
//!
//! [`RegionTracker`] follows the readings in the order the head takes them and hands back each
//! region once it is closed: by a reading that heard another range, by no echo, by a gap in the
//! angles or by the head turning back. It knows nothing of grids or models; the mapper places the
//! closed region's evidence ([`crate::model::SmoothModel`], `echo_placement = "region"`).

use nalgebra::Vector2;

use crate::geometry::wrap_angle;

/// Largest angle between two readings of one region, radians: two 6° readings and a little. A
/// wider gap means readings are missing between them (or the head jumped), and whatever lies in
/// between was not heard.
const MAX_GAP: f32 = 13.0 * std::f32::consts::PI / 180.0;

/// How far two ranges may differ and still be the same depth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DepthTolerance {
    /// Metres.
    pub absolute_m: f32,
    /// Fraction of the region's range.
    pub fraction: f32,
}

impl DepthTolerance {
    /// The tolerance at `range`, metres.
    pub fn at(&self, range: f32) -> f32 {
        self.absolute_m + self.fraction * range
    }

    fn admits(&self, region_range: f32, range: f32) -> bool {
        (range - region_range).abs() <= self.at(region_range)
    }

    /// Whether `range` is nearer than `region_range` by more than the tolerance.
    fn nearer(&self, range: f32, region_range: f32) -> bool {
        range < region_range - self.at(region_range)
    }
}

/// One reading as the tracker sees it: where the sensor was, where it pointed (world bearing),
/// and what it heard.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Heard {
    pub position: Vector2<f32>,
    pub axis: f32,
    /// `None`: no echo, which closes any open region.
    pub range: Option<f32>,
    /// Without a range because its pings disagreed, the nearest echo one of them heard
    /// ([`crate::observation::Observation::rejected_echo_m`]).
    pub rejected: Option<f32>,
}

/// What lies beside a region's first or last reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum End {
    /// No echo, or a farther one: the reflector stopped being heard there, so the region's width
    /// is the reflector's own and its middle bearing points at it.
    Natural,
    /// A nearer echo: the nearer reflector masks this one (the sensor reports the first echo), so
    /// the region is cut short on that side and its middle bearing is not the reflector's.
    Occluded,
    /// The sweep's end, a gap in the angles or the head turning back: nothing is known.
    Unknown,
}

/// A region heard by a head that moved no more than this, metres, from its first reading to its
/// last was heard from one place ([`Region::one_ended_axis`]).
pub(crate) const STOOD_STILL_M: f32 = 0.01;

/// Where a one-ended region's reflector lies ([`Region::one_ended_axis`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct OneEndedAxis {
    /// The bearing, radians.
    pub axis: f32,
    /// Whether the region's readings reach that bearing; if not, it lies beyond them.
    pub reached: bool,
}

/// A closed region of constant depth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Region {
    /// The sensor's position, midway between the region's first and last readings.
    pub position: Vector2<f32>,
    /// The middle bearing between the first and the last reading's axes, in [−π, π].
    pub axis: f32,
    /// The mean of the readings' ranges.
    pub range: f32,
    pub readings: u32,
    /// Half the angle between the first and the last reading's axes, radians.
    pub half_width: f32,
    /// The angle from the first reading's axis to the last one's, signed the way the head turned.
    pub span: f32,
    /// Beside the first and beside the last reading.
    pub ends: [End; 2],
    /// The range of the nearer echo beside each end that is [`End::Occluded`], else `None`.
    pub masking: [Option<f32>; 2],
    /// The signed angle between neighbouring readings where the region was heard (the way the
    /// head turned, even for a region of one reading), 0 when neither neighbour was adjacent.
    pub turn: f32,
    /// How far the sensor moved from the region's first reading to its last, metres.
    pub moved: f32,
}

impl Region {
    /// Whether the reflector stopped being heard on both sides: only then is the middle bearing
    /// the reflector's. On simulated scans (16 generated rooms, one sweep each) 93 % of the
    /// readings in such regions lie on the surface their middle bearing meets, against 40 % in
    /// regions cut short by a nearer echo on one side and 14 % on both.
    pub fn is_whole(&self) -> bool {
        self.ends == [End::Natural; 2]
    }

    /// Whether the reflector stopped being heard on one side and nothing is known of the other
    /// (the sweep's limit, a gap in the angles, the head turning back): its bearing is then one
    /// lobe half-width in from the natural end ([`Self::one_ended_axis`]). A region cut short by a
    /// nearer echo is not: on the generated suite, patches placed from those lay on a surface
    /// only a third to a half of the time.
    pub fn is_one_ended(&self) -> bool {
        matches!(
            self.ends,
            [End::Natural, End::Unknown] | [End::Unknown, End::Natural]
        )
    }

    /// Where the reflector of a one-ended region ([`Self::is_one_ended`]) lies: one lobe
    /// half-width `lobe` (radians, the half-width of the whole regions heard at this range) in
    /// from its natural end, as a whole region spans the lobe's width centred on its reflector.
    /// The reading beside the natural end heard it and the one beyond did not, so it lies there
    /// whether or not the region reaches that far: when it does not, beyond the region's last
    /// reading (the head turned back, or the readings stop, before coming to it). `None` if the
    /// region is not one-ended, or does not reach that far and was heard by a head that moved
    /// (more than [`STOOD_STILL_M`]): the bearing beyond its readings is then from no place the
    /// head stood (on the driven room tour, placed so, the map at true poses lost 0.08 of
    /// precision, `docs/fusion.md`).
    pub fn one_ended_axis(&self, lobe: f32) -> Option<OneEndedAxis> {
        let (end, inwards) = self.natural_end_beside(End::Unknown)?;
        let reached = self.span.abs() >= lobe;
        (reached || self.moved <= STOOD_STILL_M).then(|| OneEndedAxis {
            axis: wrap_angle(end + inwards * lobe),
            reached,
        })
    }

    /// The axis of the region's natural end and the sign of the way in from it, if one end is
    /// [`End::Natural`] and the other is `other`.
    fn natural_end_beside(&self, other: End) -> Option<(f32, f32)> {
        let half = 0.5 * self.span;
        match self.ends {
            [End::Natural, o] if o == other => Some((self.axis - half, self.turn.signum())),
            [o, End::Natural] if o == other => Some((self.axis + half, -self.turn.signum())),
            _ => None,
        }
    }
}

impl Region {
    /// Where the reflector of a region heard to stop on one side and cut short by a nearer echo
    /// on the other lies: `lobe` (radians, the half-width of the whole regions heard at this
    /// range) less half a step in from its natural end. Every reading of the region heard it, so
    /// it lies within a lobe of the last one next to the natural end; the reading beyond that end
    /// did not, so it lies a lobe or more from that one: between the two, a step wide. The
    /// nearer echo on the other side hides how far the region would have run, so its middle
    /// bearing says nothing (a wall heard beside a post, its foot behind the post). `None` for
    /// other regions, a region wider than two lobes (more than one reflector) or a lobe narrower
    /// than half a step.
    pub fn cut_short_axis(&self, lobe: f32) -> Option<f32> {
        let (end, inwards) = self.natural_end_beside(End::Occluded)?;
        let inset = lobe - 0.5 * self.turn.abs();
        (self.turn != 0.0 && inset > 0.0 && self.span.abs() <= 2.0 * lobe)
            .then(|| wrap_angle(end + inwards * inset))
    }

    /// The angle between its neighbouring readings, radians (0 for one reading).
    pub fn step(&self) -> f32 {
        if self.readings > 1 {
            self.span.abs() / (self.readings - 1) as f32
        } else {
            0.0
        }
    }

    /// The lobe's half-width when no whole region has taught it ([`LobeWidth`]): the sensor's
    /// beam half-angle `beam`, less half this region's step between readings (a whole region's
    /// end readings lie on average half a step inside the lobe).
    pub fn prior_lobe(&self, beam: f32) -> f32 {
        beam - 0.5 * self.step()
    }

    /// Whether the region was cut short on both sides by nearer echoes (or on one side and by the
    /// sweep's limit on the other) and is narrower than the lobe (`lobe`, its half-width): what a
    /// corner or a post, which answer from any bearing, heard between two nearer reflectors leaves.
    pub fn is_cut_and_narrow(&self, lobe: f32) -> bool {
        !self.ends.contains(&End::Natural)
            && self.ends.contains(&End::Occluded)
            && self.half_width < lobe
    }

    /// Whether the region is a small reflector's, a post's or an edge's: whole, two readings or
    /// more (one reading measures no width), and narrower than half of `lobe`, the half-width
    /// over which the sensor hears a wall met squarely. A wall answers across the lobe; a small
    /// reflector sends back too little off the axis to be heard that far out (in the paper
    /// scenes a 5 cm post at 1 m is heard within ±13.4°, the walls within ±27°).
    pub fn is_small(&self, lobe: f32) -> bool {
        self.is_whole() && self.readings >= 2 && self.half_width < 0.5 * lobe
    }

    /// The range of the nearest echo that cut the region short ([`End::Occluded`]), if any. Its
    /// readings heard farther than that echo's reflector, a step of the head away: along their
    /// axes nothing answered nearer, so the space in front of that range is free even when the
    /// region's own reflector cannot be placed.
    pub fn masking_range(&self) -> Option<f32> {
        self.masking.into_iter().flatten().reduce(f32::min)
    }
}

/// Range bins of the lobe estimate, metres wide.
const LOBE_BIN_M: f32 = 0.25;
/// Range bins kept: 0 to 5 m.
const LOBE_BINS: usize = 20;
/// Range bins a lobe must have been learnt in before [`LobeWidth::widest`] is trusted.
const WIDEST_MIN_BINS: usize = 2;
/// Whole regions a bin's running mean weighs at most: it follows a change of sensor over about
/// this many.
const LOBE_MEMORY: f32 = 50.0;

/// The half-width of the lobe within which a reflector is heard, as a function of range, learnt
/// online from the whole regions' half-widths (a whole region spans the lobe's width at its range,
/// centred on the reflector). Nothing is assumed of the sensor: until a whole region has been
/// heard at some range, nothing is known.
#[derive(Debug, Clone, Default)]
pub(crate) struct LobeWidth {
    /// Per range bin: the running mean half-width, radians, and the regions it weighs.
    bins: [(f32, f32); LOBE_BINS],
}

impl LobeWidth {
    fn bin(range: f32) -> usize {
        ((range / LOBE_BIN_M) as usize).min(LOBE_BINS - 1)
    }

    /// Learns from a whole region of two readings or more (one reading has no width).
    pub fn learn(&mut self, region: &Region) {
        if !region.is_whole() || region.readings < 2 {
            return;
        }
        let (mean, weight) = &mut self.bins[Self::bin(region.range)];
        *weight = (*weight + 1.0).min(LOBE_MEMORY);
        *mean += (region.half_width - *mean) / *weight;
    }

    /// The widest half-width learnt at any range, once whole regions have been heard in
    /// [`WIDEST_MIN_BINS`] range bins or more, else `None`: the lobe over which the sensor hears
    /// its strongest reflectors, walls met squarely (on the suite about 27° for `srf05`, but 9°
    /// for `hc-sr04`, whose configured beam is the paper's ±30°). Learnt at one range only, the
    /// regions may all be small reflectors' (two posts at the same range).
    pub fn widest(&self) -> Option<f32> {
        let learnt = self.bins.iter().filter(|(_, weight)| *weight > 0.0);
        (learnt.clone().count() >= WIDEST_MIN_BINS)
            .then(|| learnt.map(|(mean, _)| *mean).fold(0.0, f32::max))
    }

    /// The widest half-width learnt at any range, however few bins are learnt (so at least
    /// [`Self::at`] at every range); `None` before any.
    pub fn widest_learnt(&self) -> Option<f32> {
        self.bins
            .iter()
            .filter(|(_, weight)| *weight > 0.0)
            .map(|(mean, _)| *mean)
            .reduce(f32::max)
    }

    /// The half-width at `range`: its bin's, else the nearest learnt bin's; `None` before any.
    pub fn at(&self, range: f32) -> Option<f32> {
        let bin = Self::bin(range) as isize;
        (0..LOBE_BINS as isize)
            .flat_map(|k| [bin - k, bin + k])
            .filter_map(|b| usize::try_from(b).ok().and_then(|b| self.bins.get(b)))
            .find(|(_, weight)| *weight > 0.0)
            .map(|(mean, _)| *mean)
    }
}

#[derive(Debug, Clone, Copy)]
struct Open {
    first_position: Vector2<f32>,
    first_axis: f32,
    last_position: Vector2<f32>,
    last_axis: f32,
    /// The angle turned from the first reading's axis to the last one's, step by step: a
    /// region may span more than a half turn (a sensor close to a rough wall, a continuous
    /// head), where the difference of its end axes alone is ambiguous.
    swept: f32,
    range_sum: f32,
    readings: u32,
    start: End,
    /// The nearer echo's range beside the first reading, if it was cut short there.
    start_masking: Option<f32>,
    /// The step from the reading before the first, if adjacent, else 0.
    turn: f32,
}

impl Open {
    fn new(heard: &Heard, range: f32, start: End, start_masking: Option<f32>, turn: f32) -> Self {
        Self {
            first_position: heard.position,
            first_axis: heard.axis,
            last_position: heard.position,
            last_axis: heard.axis,
            swept: 0.0,
            range_sum: range,
            readings: 1,
            start,
            start_masking,
            turn,
        }
    }

    fn range(&self) -> f32 {
        self.range_sum / self.readings as f32
    }

    fn extend(&mut self, heard: &Heard, range: f32) {
        self.swept += wrap_angle(heard.axis - self.last_axis);
        self.last_position = heard.position;
        self.last_axis = heard.axis;
        self.range_sum += range;
        self.readings += 1;
    }

    /// The region, closed with `end` beside its last reading: `masking` is the next reading's
    /// range when that reading was nearer ([`End::Occluded`]), `step` the step to it (0 if not
    /// adjacent).
    fn close(&self, end: End, masking: Option<f32>, step: f32) -> Region {
        let span = self.swept;
        Region {
            turn: if self.turn != 0.0 { self.turn } else { step },
            position: (self.first_position + self.last_position) * 0.5,
            axis: wrap_angle(self.first_axis + 0.5 * span),
            range: self.range(),
            readings: self.readings,
            half_width: 0.5 * span.abs(),
            span,
            ends: [self.start, end],
            masking: [self.start_masking, masking],
            moved: (self.last_position - self.first_position).norm(),
        }
    }
}

/// The reading before the next one: its axis, what it heard, and the way the head was turning.
#[derive(Debug, Clone, Copy)]
struct Last {
    axis: f32,
    range: Option<f32>,
    /// [`Heard::rejected`].
    rejected: Option<f32>,
    turning: f32,
}

/// A reading without a range that came next after the open region, held until the reading after
/// it tells whether the region goes on over it ([`RegionTracker::push`]).
#[derive(Debug, Clone, Copy)]
struct Held {
    /// The step into it.
    step: f32,
    /// The nearest echo one of its pings heard, if nearer than the region ([`Heard::rejected`]).
    nearer: Option<f32>,
}

impl Held {
    /// How the region before it ends where it stopped going on: cut short by what it heard
    /// nearer, else stopping to answer there.
    fn close(self, open: &Open) -> Region {
        match self.nearer {
            Some(n) => open.close(End::Occluded, Some(n), self.step),
            None => open.close(End::Natural, None, self.step),
        }
    }
}

/// Groups readings, in the order the head takes them, into regions of constant depth.
#[derive(Debug, Clone, Default)]
pub(crate) struct RegionTracker {
    open: Option<Open>,
    last: Option<Last>,
    held: Option<Held>,
}

impl RegionTracker {
    /// Takes the next reading; returns the region it closed, if any.
    ///
    /// One reading without a range between readings of the same depth does not end the region:
    /// it goes on over it as over a reading missing from the angles (within [`MAX_GAP`]). A
    /// reading's pings must agree for it to have a range, so a lost or stray ping silences a
    /// reading now and then wherever the head points (most often with the `nxt` profile's two
    /// pings a reading); split there, a wall's region became two, each taken for a whole
    /// reflector at its own middle bearing, up to half the region's width off the wall's foot.
    /// When the region does not go on, it ended at that reading: cut short if one of its pings
    /// heard something nearer (an edge in front of it), else stopping to answer.
    pub fn push(&mut self, heard: &Heard, tolerance: &DepthTolerance) -> Option<Region> {
        // Whether this reading is the next angle on from the last one, the same way round.
        // The step from the last one if it is, else 0.
        let step_in = self.last.map_or(0.0, |last| {
            let step = wrap_angle(heard.axis - last.axis);
            let onwards = step != 0.0 && step.abs() <= MAX_GAP && step * last.turning >= 0.0;
            if onwards { step } else { 0.0 }
        });
        let adjacent = step_in != 0.0;
        let turning = if adjacent { step_in.signum() } else { 0.0 };
        let last = self.last.replace(Last {
            axis: heard.axis,
            range: heard.range,
            rejected: heard.rejected,
            turning,
        });
        // The open region goes on if this reading hears its depth, the next angle on from its
        // last reading or from one held after it (within MAX_GAP of its last either way).
        let held = self.held.take();
        if let Some(open) = &mut self.open
            && let Some(range) = heard.range
            && adjacent
            && wrap_angle(heard.axis - open.last_axis).abs() <= MAX_GAP
            && tolerance.admits(open.range(), range)
        {
            open.extend(heard, range);
            return None;
        }
        // Else, after a held reading, it ended there.
        let closed = held.and_then(|held| self.open.take().map(|o| held.close(&o)));
        let Some(range) = heard.range else {
            if adjacent && let Some(open) = &self.open {
                let nearer = heard
                    .rejected
                    .filter(|&n| tolerance.nearer(n, open.range()));
                self.held = Some(Held {
                    step: step_in,
                    nearer,
                });
                return closed;
            }
            return closed.or_else(|| {
                self.open
                    .take()
                    .map(|o| o.close(End::Unknown, None, step_in))
            });
        };
        // This reading starts a region; what lies beside it on each side.
        let beside = |other: f32, this: f32| {
            if other < this {
                End::Occluded
            } else {
                End::Natural
            }
        };
        let start = match last {
            Some(Last {
                range: None,
                rejected: Some(n),
                ..
            }) if adjacent && tolerance.nearer(n, range) => End::Occluded,
            Some(Last { range: None, .. }) if adjacent => End::Natural,
            Some(Last { range: Some(r), .. }) if adjacent => beside(r, range),
            _ => End::Unknown,
        };
        let cut = self.open.take().map(|o| {
            let end = if adjacent {
                beside(range, o.range())
            } else {
                End::Unknown
            };
            o.close(end, (end == End::Occluded).then_some(range), step_in)
        });
        let start_masking = match last {
            Some(Last {
                range, rejected, ..
            }) if start == End::Occluded => range.or(rejected),
            _ => None,
        };
        self.open = Some(Open::new(heard, range, start, start_masking, step_in));
        closed.or(cut)
    }

    /// Closes the open region, if any, at the end of a sweep or of a run of readings: its last
    /// end is unknown (or as the reading without a range after it says), and the next reading
    /// starts afresh.
    pub fn close(&mut self) -> Option<Region> {
        self.last = None;
        let held = self.held.take();
        let open = self.open.take()?;
        Some(match held {
            Some(held) => held.close(&open),
            None => open.close(End::Unknown, None, 0.0),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOLERANCE: DepthTolerance = DepthTolerance {
        absolute_m: 0.02,
        fraction: 0.02,
    };

    fn heard(axis_deg: f32, range: Option<f32>) -> Heard {
        Heard {
            position: Vector2::new(1.0, 2.0),
            axis: axis_deg.to_radians(),
            range,
            rejected: None,
        }
    }

    /// Feeds `(angle, range)` readings; returns the regions closed on the way and at the end.
    fn regions(readings: &[(f32, Option<f32>)]) -> Vec<Region> {
        regions_heard(readings.iter().map(|&(a, r)| heard(a, r)))
    }

    /// [`regions`] of readings as the tracker takes them.
    fn regions_heard(readings: impl IntoIterator<Item = Heard>) -> Vec<Region> {
        let mut tracker = RegionTracker::default();
        let mut out: Vec<Region> = readings
            .into_iter()
            .filter_map(|h| tracker.push(&h, &TOLERANCE))
            .collect();
        out.extend(tracker.close());
        out
    }

    /// (middle bearing in whole degrees, readings, ends) of each region.
    fn summary(found: &[Region]) -> Vec<(i32, u32, [End; 2])> {
        found
            .iter()
            .map(|r| (r.axis.to_degrees().round() as i32, r.readings, r.ends))
            .collect()
    }

    #[test]
    fn a_region_wider_than_a_half_turn_has_its_middle_bearing_in_its_middle() {
        // From −84° down through 180° to 96°, 31 readings at 0.55 m (a sensor close to rough
        // walls), nothing heard beside: 180° wide, its middle at −174°; and 37 readings, 216°
        // wide, from −72° down to 72°: its middle at 180°, not at 0°.
        for (first, readings, middle) in [(-84.0f32, 31, -174.0f32), (-72.0, 37, -180.0)] {
            let mut heard = vec![(first + 6.0, None)];
            heard.extend((0..readings).map(|k| (first - 6.0 * k as f32, Some(0.55))));
            heard.push((first - 6.0 * readings as f32, None));
            let width = 6.0 * (readings - 1) as f32;
            for (reading, turn) in [
                (heard.clone(), -1.0),
                (heard.into_iter().rev().collect(), 1.0),
            ] {
                let found = regions(&reading);
                assert_eq!(found.len(), 1, "{found:?}");
                let region = found[0];
                assert!(region.is_whole());
                let off = wrap_angle(region.axis - middle.to_radians()).to_degrees();
                assert!(off.abs() < 1e-2, "{off}° off: {region:?}");
                assert!((region.half_width.to_degrees() - width / 2.0).abs() < 1e-2);
                assert!((region.span.to_degrees() - turn * width).abs() < 1e-2);
            }
        }
    }

    #[test]
    fn a_wall_heard_off_its_perpendicular_is_one_whole_region_at_the_middle_bearing() {
        // The foot at 20°: every reading from −10° to 50° hears 1.5 m (± noise); nothing heard
        // either side.
        let mut readings = vec![(-16.0, None)];
        readings
            .extend((0..11).map(|k| (-10.0 + 6.0 * k as f32, Some(1.49 + 0.01 * (k % 3) as f32))));
        readings.push((56.0, None));
        let found = regions(&readings);
        assert_eq!(found.len(), 1);
        let wall = found[0];
        assert!((wall.axis.to_degrees() - 20.0).abs() < 1e-4);
        assert!((wall.half_width.to_degrees() - 30.0).abs() < 1e-3);
        assert!((wall.range - 1.5).abs() < 0.01);
        assert_eq!(wall.readings, 11);
        assert_eq!(wall.position, Vector2::new(1.0, 2.0));
        assert!(wall.is_whole());
    }

    #[test]
    fn what_lies_beside_a_region_tells_whether_it_is_whole() {
        use End::{Natural, Occluded, Unknown};
        let found = regions(&[
            (0.0, Some(1.0)), // the sweep's first reading: unknown before it
            (6.0, Some(1.0)),
            (12.0, Some(2.0)), // farther: 1 m ends naturally, 2 m starts occluded by 1 m
            (18.0, Some(2.0)),
            (24.0, None), // no echo and then another depth: a natural end
            (30.0, Some(2.2)),
            (36.0, Some(3.0)), // farther
            (42.0, None),
            (48.0, Some(2.5)),
            (90.0, Some(2.5)), // a gap: unknown on both sides of it
            (84.0, Some(2.5)), // the head turns back …
            (90.0, Some(2.5)), // … and again
        ]);
        assert_eq!(
            summary(&found),
            vec![
                (3, 2, [Unknown, Natural]),
                (15, 2, [Occluded, Natural]),
                (30, 1, [Natural, Natural]),
                (36, 1, [Occluded, Natural]),
                (48, 1, [Natural, Unknown]),
                (87, 2, [Unknown, Unknown]),
                (90, 1, [Unknown, Unknown]),
            ],
            "{found:?}"
        );
        let whole: Vec<_> = found.iter().map(Region::is_whole).collect();
        assert_eq!(whole, [false, false, true, false, false, false, false]);
    }

    #[test]
    fn one_silent_reading_between_readings_of_one_depth_does_not_end_their_region() {
        use End::{Natural, Unknown};
        // A wall's foot at 90°, one reading across it silent (its pings did not agree).
        let found = regions(&[
            (66.0, None),
            (72.0, Some(0.44)),
            (78.0, Some(0.44)),
            (84.0, None),
            (90.0, Some(0.44)),
            (96.0, Some(0.44)),
            (102.0, None),
            (108.0, None),
        ]);
        assert_eq!(summary(&found), vec![(84, 4, [Natural, Natural])]);
        assert!((found[0].half_width.to_degrees() - 12.0).abs() < 1e-3);
        // Two silent readings, a silent reading before another depth, and one at the sweep's
        // end: the region stopped being heard there.
        let found = regions(&[
            (0.0, Some(1.0)),
            (6.0, None),
            (12.0, None),
            (18.0, Some(1.0)),
            (24.0, None),
            (30.0, Some(1.5)),
            (36.0, None),
        ]);
        assert_eq!(
            summary(&found),
            vec![
                (0, 1, [Unknown, Natural]),
                (18, 1, [Natural, Natural]),
                (30, 1, [Natural, Natural]),
            ]
        );
    }

    #[test]
    fn a_reading_whose_pings_disagreed_with_one_nearer_cuts_a_region_short() {
        use End::{Natural, Occluded, Unknown};
        // A wall at 2 m, a post at 1 m in front of it: the readings across the post's edges
        // heard both; a stray ping later on the wall.
        let found = regions_heard(
            [
                (0.0, None, None),
                (6.0, Some(2.0), None),
                (12.0, Some(2.0), None),
                (18.0, None, Some(1.0)), // the post's edge: the wall's region cut short
                (24.0, Some(1.0), None),
                (30.0, Some(1.0), None),
                (36.0, None, Some(1.0)), // the other edge: the post stops being heard
                (42.0, Some(2.0), None),
                (48.0, None, Some(0.7)), // a stray ping: the wall goes on
                (54.0, Some(2.0), None),
            ]
            .map(|(axis, range, rejected)| Heard {
                rejected,
                ..heard(axis, range)
            }),
        );
        assert_eq!(
            summary(&found),
            vec![
                (9, 2, [Natural, Occluded]),
                (27, 2, [Natural, Natural]),
                (48, 2, [Occluded, Unknown]),
            ]
        );
        assert_eq!(found[0].masking, [None, Some(1.0)]);
        assert_eq!(found[2].masking, [Some(1.0), None]);
    }

    #[test]
    fn a_nearer_echo_after_a_region_cuts_it_short() {
        let found = regions(&[
            (0.0, None),
            (6.0, Some(2.0)),
            (12.0, Some(2.0)),
            (18.0, Some(1.0)),
            (24.0, None),
        ]);
        assert_eq!(found[0].ends, [End::Natural, End::Occluded]);
        assert_eq!(found[1].ends, [End::Natural, End::Natural]);
        assert_eq!(found[0].masking, [None, Some(1.0)]);
        assert_eq!(found[0].masking_range(), Some(1.0));
        assert_eq!(found[1].masking_range(), None);
    }

    #[test]
    fn a_region_between_two_nearer_echoes_is_masked_at_the_nearer_of_them() {
        // A wall at 2 m heard between two posts, at 1.2 m and 1.0 m.
        let found = regions(&[
            (0.0, Some(1.2)),
            (6.0, Some(2.0)),
            (12.0, Some(2.0)),
            (18.0, Some(1.0)),
        ]);
        assert_eq!(found[1].ends, [End::Occluded, End::Occluded]);
        assert_eq!(found[1].masking, [Some(1.2), Some(1.0)]);
        assert_eq!(found[1].masking_range(), Some(1.0));
        // The first post's own region: the wall beside it is farther, nothing masks it.
        assert_eq!(found[0].masking_range(), None);
    }

    #[test]
    fn a_region_across_the_back_of_the_circle_keeps_its_middle_bearing() {
        let found = regions(&[(174.0, Some(1.0)), (180.0, Some(1.0)), (-174.0, Some(1.0))]);
        assert_eq!(found.len(), 1);
        assert!((found[0].axis.abs().to_degrees() - 180.0).abs() < 1e-3);
    }

    #[test]
    fn a_region_stopping_on_one_side_only_is_placed_one_lobe_in_from_that_side() {
        let lobe = 27f32.to_radians();
        // A wall's foot at −45°, its lobe ±27°: heard from the local scan's limit at −57° to
        // −21°, then a farther echo (a corner). Turning the other way, the same from +57° to +21°.
        let rising: Vec<_> = (0..7)
            .map(|k| (-57.0 + 6.0 * k as f32, Some(0.85)))
            .chain([(-15.0, Some(1.2))])
            .collect();
        let falling: Vec<_> = rising.iter().map(|&(a, r)| (-a, r)).collect();
        for (readings, foot) in [(rising, -48.0), (falling, 48.0)] {
            let wall = regions(&readings)[0];
            assert_eq!(wall.ends, [End::Unknown, End::Natural]);
            assert!(wall.is_one_ended());
            let placed = wall.one_ended_axis(lobe).unwrap();
            let axis = placed.axis.to_degrees();
            assert!((axis - foot).abs() < 1e-3, "{axis}");
            assert!(placed.reached);
            // Narrower than a lobe of 37°: the foot lies beyond the last reading, still a lobe in
            // from the natural end (10° farther than with 27°).
            let beyond = wall.one_ended_axis(37f32.to_radians()).unwrap();
            let axis = beyond.axis.to_degrees();
            assert!(
                (axis - (foot + foot.signum() * 10.0)).abs() < 1e-3,
                "{axis}"
            );
            assert!(!beyond.reached);
            // Heard by a head that moved 5 cm meanwhile: placed only where its readings reach.
            let moving = Region {
                moved: 0.05,
                ..wall
            };
            assert!(moving.one_ended_axis(lobe).is_some());
            assert_eq!(moving.one_ended_axis(37f32.to_radians()), None);
        }
        // Cut short by a nearer echo: not one-ended (placed from those, patches lay on a surface
        // a third to a half of the time); whole: placed at its middle instead.
        let cut = regions(&[
            (0.0, None),
            (6.0, Some(2.0)),
            (12.0, Some(2.0)),
            (18.0, Some(1.0)),
        ]);
        assert!(!cut[0].is_one_ended());
        assert_eq!(cut[0].one_ended_axis(3f32.to_radians()), None);
        let whole = regions(&[
            (0.0, None),
            (6.0, Some(2.0)),
            (12.0, Some(2.0)),
            (18.0, None),
        ]);
        assert!(!whole[0].is_one_ended());
    }

    #[test]
    fn a_region_stopping_on_one_side_and_cut_short_on_the_other_has_its_reflector_a_lobe_in() {
        let lobe = 15f32.to_radians();
        // A wall heard beside a post: the post (nearer) up to 15°, the wall at 21° and 27°, then
        // farther. Every reading of the region heard the reflector, within 15° of 27°; the one at
        // 33° did not, so it lies 15° or more from 33°: between 12° and 18°, its middle 15°.
        // Turning the other way, the same from the other side; one reading alone as well.
        let rising = [
            (9.0, Some(0.9)),
            (15.0, Some(0.9)),
            (21.0, Some(1.2)),
            (27.0, Some(1.2)),
            (33.0, Some(1.4)),
        ];
        let falling: Vec<_> = rising.iter().rev().copied().collect();
        let alone = [(15.0, Some(0.9)), (21.0, Some(1.2)), (27.0, Some(1.4))];
        for (readings, ends, reflector) in [
            (rising.to_vec(), [End::Occluded, End::Natural], 15.0),
            (falling, [End::Natural, End::Occluded], 15.0),
            (alone.to_vec(), [End::Occluded, End::Natural], 9.0),
        ] {
            let wall = regions(&readings)
                .into_iter()
                .find(|r| (r.range - 1.2).abs() < 1e-3)
                .unwrap();
            assert_eq!(wall.ends, ends);
            let axis = wall.cut_short_axis(lobe).unwrap().to_degrees();
            assert!((axis - reflector).abs() < 1e-3, "{axis} for {readings:?}");
            // More than two lobes wide: more than one reflector.
            assert_eq!(wall.cut_short_axis(1f32.to_radians()), None);
        }
        // Not for a region stopping on both sides, nor one that runs to the sweep's limit, nor
        // one cut short on both.
        for readings in [
            vec![(15.0, Some(1.4)), (21.0, Some(1.2)), (27.0, Some(1.4))],
            vec![(21.0, Some(1.2)), (27.0, Some(1.4))],
            vec![(15.0, Some(0.9)), (21.0, Some(1.2)), (27.0, Some(0.9))],
        ] {
            let region = regions(&readings)
                .into_iter()
                .find(|r| (r.range - 1.2).abs() < 1e-3)
                .unwrap();
            assert_eq!(region.cut_short_axis(lobe), None, "{readings:?}");
        }
    }

    #[test]
    fn the_lobe_is_learnt_from_whole_regions_by_range() {
        let mut lobe = LobeWidth::default();
        assert_eq!(lobe.at(1.0), None);
        // Whole regions 24° and 30° wide each side at about 1 m; one reading, and a region cut
        // short, teach nothing.
        let readings = |half: i32, range: f32| {
            let mut r = vec![(-(half as f32) - 6.0, None)];
            r.extend((-half..=half).step_by(6).map(|a| (a as f32, Some(range))));
            r.push((half as f32 + 6.0, None));
            r
        };
        for found in [
            regions(&readings(24, 1.0)),
            regions(&readings(30, 1.1)),
            regions(&[(0.0, None), (6.0, Some(1.0)), (12.0, None)]),
            regions(&[
                (0.0, None),
                (6.0, Some(1.0)),
                (12.0, Some(1.0)),
                (18.0, Some(0.5)),
            ]),
        ] {
            found.iter().for_each(|r| lobe.learn(r));
        }
        let at = |lobe: &LobeWidth, range| lobe.at(range).map(|l| l.to_degrees().round() as i32);
        assert_eq!(at(&lobe, 1.0), Some(27));
        // Elsewhere: the nearest range learnt.
        assert_eq!(at(&lobe, 3.0), Some(27));
        regions(&readings(6, 3.0))
            .iter()
            .for_each(|r| lobe.learn(r));
        assert_eq!(at(&lobe, 3.1), Some(6));
        assert_eq!(at(&lobe, 1.0), Some(27));
    }

    #[test]
    fn a_small_reflector_is_heard_over_less_than_half_the_lobe_of_a_wall() {
        let lobe = 27f32.to_radians();
        // A post at 1 m heard by four readings (±9°) in front of a wall at 2 m; a wall's foot
        // heard by nine (±24°); one reading alone; a post cut short by a nearer echo.
        let post = regions(&[
            (-18.0, Some(2.0)),
            (-12.0, None),
            (-9.0, Some(1.0)),
            (-3.0, Some(1.0)),
            (3.0, Some(1.0)),
            (9.0, Some(1.0)),
            (15.0, Some(2.0)),
        ]);
        assert!(post[1].is_small(lobe), "{:?}", post[1]);
        let mut wall = vec![(-30.0, None)];
        wall.extend((-24..=24).step_by(6).map(|a| (a as f32, Some(1.5))));
        wall.push((30.0, None));
        let wall = regions(&wall);
        assert!(wall[0].is_whole() && !wall[0].is_small(lobe));
        let single = regions(&[(0.0, None), (6.0, Some(1.0)), (12.0, None)]);
        assert!(single[0].is_whole() && !single[0].is_small(lobe));
        let cut = regions(&[
            (0.0, None),
            (6.0, Some(1.0)),
            (12.0, Some(1.0)),
            (18.0, Some(0.5)),
        ]);
        assert!(!cut[0].is_small(lobe));
    }

    #[test]
    fn the_widest_lobe_is_trusted_once_learnt_at_two_ranges() {
        let mut lobe = LobeWidth::default();
        let whole = |half: i32, range: f32| {
            let mut r = vec![(-(half as f32) - 6.0, None)];
            r.extend((-half..=half).step_by(6).map(|a| (a as f32, Some(range))));
            r.push((half as f32 + 6.0, None));
            regions(&r)
        };
        assert_eq!(lobe.widest(), None);
        // Two posts at 1 m teach their own width, which says nothing of a wall's.
        whole(6, 1.0).iter().for_each(|r| lobe.learn(r));
        whole(12, 1.05).iter().for_each(|r| lobe.learn(r));
        assert_eq!(lobe.widest(), None);
        // A wall at 2 m: the widest of the ranges learnt.
        whole(24, 2.0).iter().for_each(|r| lobe.learn(r));
        assert_eq!(
            lobe.widest().map(|l| l.to_degrees().round() as i32),
            Some(24)
        );
    }

    #[test]
    fn the_depth_tolerance_grows_with_range() {
        // 2 cm + 2 %: at 3 m two readings 7 cm apart are one depth, at 0.5 m 4 cm apart are not.
        assert_eq!(regions(&[(0.0, Some(3.0)), (6.0, Some(3.07))]).len(), 1);
        assert_eq!(regions(&[(0.0, Some(0.5)), (6.0, Some(0.54))]).len(), 2);
    }
}
