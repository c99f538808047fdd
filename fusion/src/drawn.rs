//! The stretches of wall drawn where no reading heard them, kept to be taken back if a later
//! reading refutes them ([`crate::sightlines`]).
//!
//! A stretch drawn again (the same wall joined to the same corner from another of its patches)
//! is counted with the one kept ([`Stretch::repeats`]) instead of kept twice. A moving robot
//! draws thousands of pieces a minute and keeps [`KEPT`]: looking through every one kept for
//! each piece drawn was an eighth of its fusing (issue 29). The kept ones are therefore also
//! filed by the square their first end lies in; a stretch repeats only one whose first end lies
//! within [`SAME_LINE_M`] of its own, so the nine squares about its own hold every one it can
//! repeat, and of those the oldest is the one taken, as a look through all of them in order
//! takes it.

use std::collections::VecDeque;

use nalgebra::Vector2;
use rustc_hash::FxHashMap;

use crate::lines::{SAME_LINE_M, Stretch};

/// Stretches kept to be taken back if refuted: about eight viewpoints' worth of walls.
pub(crate) const KEPT: usize = 1024;

/// Squares of this side, metres, file the stretches kept by their first end: at least
/// [`SAME_LINE_M`], with room for its rounding.
const SQUARE_M: f32 = 0.05;
const _: () = assert!(SQUARE_M > SAME_LINE_M * 1.001);

/// A stretch of wall drawn, as many readings as drew it all together, the first reading kept in
/// [`crate::sightlines::Sightlines`] it has not yet been checked against, and its number (kept
/// ones are numbered in the order they were kept).
#[derive(Debug)]
pub(crate) struct Drawn {
    pub stretch: Stretch,
    pub unchecked_from: u64,
    number: u64,
}

/// The stretches kept, oldest first, and filed by the square of their first end.
#[derive(Debug, Default)]
pub(crate) struct DrawnStretches {
    kept: VecDeque<Drawn>,
    /// The numbers of the kept ones by the square their first end lies in, oldest first.
    squares: FxHashMap<(i32, i32), Vec<u64>>,
    /// The number the next one kept takes.
    next: u64,
}

/// The square of [`SQUARE_M`] that holds `at` (a NaN's is (0, 0): it repeats nothing anyway).
fn square(at: Vector2<f32>) -> (i32, i32) {
    // Saturating casts: a position beyond ±1e8 m still lands in a square.
    (
        (at.x / SQUARE_M).floor() as i32,
        (at.y / SQUARE_M).floor() as i32,
    )
}

impl DrawnStretches {
    /// Keeps `stretch`, just drawn and checked against every reading before `now`: with the
    /// oldest kept one it repeats, counting its readings too, else as the newest, the oldest
    /// forgotten first once [`KEPT`] are kept.
    pub fn keep(&mut self, stretch: Stretch, now: u64) {
        if let Some(same) = self.oldest_repeated(&stretch) {
            same.stretch.readings = same.stretch.readings.saturating_add(stretch.readings);
            return;
        }
        if self.kept.len() >= KEPT {
            self.forget_oldest();
        }
        self.push(stretch, now);
    }

    /// Keeps `stretch` as the newest, unchecked from `now`, whether or not it repeats one kept
    /// (parts of a stretch taken back, drawn again), then forgets the oldest beyond [`KEPT`].
    pub fn push_unchecked(&mut self, parts: impl IntoIterator<Item = Stretch>, now: u64) {
        for stretch in parts {
            self.push(stretch, now);
        }
        while self.kept.len() > KEPT {
            self.forget_oldest();
        }
    }

    /// Keeps the stretches `keep` says to keep (it may mark them checked), in order.
    pub fn retain_mut(&mut self, mut keep: impl FnMut(&mut Drawn) -> bool) {
        let squares = &mut self.squares;
        self.kept.retain_mut(|drawn| {
            let kept = keep(drawn);
            if !kept {
                unfile(squares, drawn);
            }
            kept
        });
    }

    pub fn clear(&mut self) {
        self.kept.clear();
        self.squares.clear();
    }

    /// The oldest kept stretch that `stretch` repeats.
    fn oldest_repeated(&mut self, stretch: &Stretch) -> Option<&mut Drawn> {
        let (x, y) = square(stretch.a);
        let oldest = (x.saturating_sub(1)..=x.saturating_add(1))
            .flat_map(|x| (y.saturating_sub(1)..=y.saturating_add(1)).map(move |y| (x, y)))
            .filter_map(|key| self.squares.get(&key))
            .flatten()
            .copied()
            .filter(|&number| {
                self.position(number)
                    .is_some_and(|i| stretch.repeats(&self.kept[i].stretch))
            })
            .min()?;
        let i = self.position(oldest)?;
        self.kept.get_mut(i)
    }

    /// Where the one numbered `number` lies in `kept` (numbers rise from front to back).
    fn position(&self, number: u64) -> Option<usize> {
        let i = self.kept.partition_point(|d| d.number < number);
        (self.kept.get(i)?.number == number).then_some(i)
    }

    fn push(&mut self, stretch: Stretch, now: u64) {
        let number = self.next;
        self.next += 1;
        self.squares
            .entry(square(stretch.a))
            .or_default()
            .push(number);
        self.kept.push_back(Drawn {
            stretch,
            unchecked_from: now,
            number,
        });
    }

    fn forget_oldest(&mut self) {
        if let Some(oldest) = self.kept.pop_front() {
            unfile(&mut self.squares, &oldest);
        }
    }
}

/// Takes `drawn` out of the square it is filed in.
fn unfile(squares: &mut FxHashMap<(i32, i32), Vec<u64>>, drawn: &Drawn) {
    let key = square(drawn.stretch.a);
    if let Some(numbers) = squares.get_mut(&key) {
        numbers.retain(|&n| n != drawn.number);
        if numbers.is_empty() {
            squares.remove(&key);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn stretch(ax: f32, ay: f32, bx: f32, by: f32, facing: f32, readings: u32) -> Stretch {
        Stretch {
            a: Vector2::new(ax, ay),
            b: Vector2::new(bx, by),
            facing,
            readings,
        }
    }

    /// The same keeping done by looking through every stretch kept, in order.
    #[derive(Default)]
    struct LookThroughAll(VecDeque<(Stretch, u64)>);

    impl LookThroughAll {
        fn keep(&mut self, stretch: Stretch, now: u64) {
            if let Some(same) = self.0.iter_mut().find(|(d, _)| stretch.repeats(d)) {
                same.0.readings = same.0.readings.saturating_add(stretch.readings);
                return;
            }
            if self.0.len() >= KEPT {
                self.0.pop_front();
            }
            self.0.push_back((stretch, now));
        }
    }

    #[test]
    fn a_stretch_drawn_again_counts_with_the_oldest_it_repeats() {
        let mut drawn = DrawnStretches::default();
        drawn.keep(stretch(1.0, 0.0, 1.0, 1.0, 0.0, 2), 0);
        drawn.keep(stretch(3.0, 0.0, 3.0, 1.0, 0.0, 1), 0);
        // 2 cm off at both ends, across a square's edge: the same wall.
        drawn.keep(stretch(1.02, -0.01, 1.0, 1.02, 0.01, 5), 7);
        // Facing the other way: another wall.
        drawn.keep(stretch(1.0, 0.0, 1.0, 1.0, std::f32::consts::PI, 1), 7);
        let kept: Vec<(u32, u64)> = drawn
            .kept
            .iter()
            .map(|d| (d.stretch.readings, d.unchecked_from))
            .collect();
        assert_eq!(kept, vec![(7, 0), (1, 0), (1, 7)]);
    }

    #[test]
    fn stretches_taken_back_are_no_longer_repeated() {
        let mut drawn = DrawnStretches::default();
        drawn.keep(stretch(1.0, 0.0, 1.0, 1.0, 0.0, 1), 0);
        drawn.retain_mut(|_| false);
        drawn.keep(stretch(1.0, 0.0, 1.0, 1.0, 0.0, 1), 3);
        assert_eq!(drawn.kept.len(), 1);
        assert_eq!(drawn.kept[0].unchecked_from, 3);
        assert!(drawn.squares.values().all(|n| n.len() == 1));
    }

    proptest! {
        // Each case draws up to 1600 stretches: fewer cases than the default.
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// Whatever is drawn, taken back and drawn again, the kept stretches are those a look
        /// through every one kept keeps, with the same readings, in the same order; more than
        /// [`KEPT`] are drawn, so the oldest are forgotten inside the code checked.
        #[test]
        fn the_filing_keeps_what_a_look_through_all_keeps(
            draws in prop::collection::vec(
                (0u8..4, 0u8..40, 0u8..40, 0u8..3, 0u8..3, 1u32..4),
                1..1600,
            ),
        ) {
            let mut filed = DrawnStretches::default();
            let mut all = LookThroughAll::default();
            for (step, &(kind, x, y, dx, facing, readings)) in draws.iter().enumerate() {
                let now = step as u64;
                // Ends on a 2 cm lattice: many repeat, across squares' edges too.
                let (x, y) = (f32::from(x) * 0.02, f32::from(y) * 0.02);
                let (bx, facing) = (x + f32::from(dx) * 0.02, f32::from(facing));
                let s = stretch(x, y, bx, y + 1.0, facing, readings);
                match kind {
                    0 => {
                        // Those with a multiple of three readings taken back, two parts drawn
                        // again.
                        filed.retain_mut(|d| d.stretch.readings % 3 != 0);
                        all.0.retain(|(d, _)| d.readings % 3 != 0);
                        let parts = [s, stretch(x, y + 2.0, x, y + 3.0, 0.0, 1)];
                        filed.push_unchecked(parts, now);
                        all.0.extend(parts.map(|p| (p, now)));
                        while all.0.len() > KEPT {
                            all.0.pop_front();
                        }
                    }
                    _ => {
                        filed.keep(s, now);
                        all.keep(s, now);
                    }
                }
                if step % 64 == 63 || step + 1 == draws.len() {
                    let kept: Vec<(Stretch, u64)> =
                        filed.kept.iter().map(|d| (d.stretch, d.unchecked_from)).collect();
                    prop_assert_eq!(&kept, &all.0.iter().copied().collect::<Vec<_>>());
                }
            }
        }
    }
}
