//! Sweep ids as published: the device's, continued across its resets.
//!
//! A reset head counts its sweeps from 1 again. Published as they come, its first sweep after the
//! reset would merge with the one the reset interrupted (consumers, which tell sweeps apart by
//! their id, saw one "sweep" of 84 readings, and `--sweeps` counted one too few). So after a reset
//! (the head's unprompted `HELLO`), or whenever the device's ids go backwards (a reconnect to a
//! head that was power-cycled meanwhile), ids are published on from the last one published: the
//! interrupted sweep ends there, and no id is ever used twice.

/// Maps the device's sweep ids to the published ones.
#[derive(Debug, Default)]
pub struct SweepIds {
    /// Added to the device's ids.
    base: u32,
    /// The device's latest sweep id (`None` right after a reset).
    last_device: Option<u32>,
    /// The highest id published.
    last_published: u32,
}

impl SweepIds {
    /// The published id of device sweep `device`, which starts or goes on now (`SWP,START`, `RD`).
    pub fn of(&mut self, device: u32) -> u32 {
        if self.last_device.is_some_and(|last| device < last) {
            self.base = self.last_published;
        }
        self.last_device = Some(device);
        let id = self.base.wrapping_add(device);
        self.last_published = self.last_published.max(id);
        id
    }

    /// The published id of device sweep `device` that the head reports ended (`SWP,END`): the
    /// sweep going on, or `None` for any other (an end that crossed a reset, or came twice late).
    pub fn ended(&self, device: u32) -> Option<u32> {
        (self.last_device == Some(device)).then(|| self.base.wrapping_add(device))
    }

    /// The head was reset: its next sweep is published as a new one, whatever its id.
    pub fn head_was_reset(&mut self) {
        self.base = self.last_published;
        self.last_device = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_pass_unchanged_until_the_head_resets_then_go_on() {
        let mut ids = SweepIds::default();
        assert_eq!([1, 1, 2, 2, 3].map(|d| ids.of(d)), [1, 1, 2, 2, 3]);
        // Reset in the middle of sweep 3: the device starts at 1 again.
        ids.head_was_reset();
        assert_eq!([1, 1, 2].map(|d| ids.of(d)), [4, 4, 5]);
    }

    #[test]
    fn an_end_names_the_sweep_going_on_and_no_other() {
        let mut ids = SweepIds::default();
        assert_eq!(ids.ended(1), None, "no sweep yet");
        assert_eq!(ids.of(1), 1);
        assert_eq!(ids.ended(1), Some(1));
        ids.head_was_reset();
        assert_eq!(
            ids.ended(1),
            None,
            "the interrupted sweep's end, after the reset"
        );
        assert_eq!(ids.of(1), 2);
        assert_eq!(ids.ended(1), Some(2));
        assert_eq!(ids.ended(0), None, "not the sweep going on");
        assert_eq!(ids.of(1), 2, "looking an end up changes nothing");
    }

    #[test]
    fn a_reset_during_the_first_sweep_still_ends_it() {
        let mut ids = SweepIds::default();
        assert_eq!(ids.of(1), 1);
        ids.head_was_reset();
        assert_eq!(ids.of(1), 2, "the same device id, a new sweep");
    }

    #[test]
    fn ids_going_backwards_without_a_reset_are_a_reset_too() {
        let mut ids = SweepIds::default();
        assert_eq!([7, 8].map(|d| ids.of(d)), [7, 8]);
        assert_eq!([1, 2].map(|d| ids.of(d)), [9, 10]);
    }
}
