//! What the fusion process counts about its input and output, published on `sonar/fusion_status`
//! ([`FusionStatus`]).
//!
//! # Lost readings
//!
//! The driver numbers its readings (`Reading::seq`: from 0, no gaps), and iceoryx2 never makes it
//! wait: when the fusion's subscriber buffer (256 readings) is full, the oldest reading is
//! overwritten, without a word to either side. The numbering is how the fusion finds out: a jump
//! from n to n + k + 1 means k readings were published that it never received, counted as lost
//! (and logged, at most once a second, by the process). A number that goes backwards or repeats is
//! a restarted driver counting from 0 again (or a second publisher, such as a replay, beside the
//! driver): counted apart as out of order, never as a loss, and the next gap is measured from it.
//!
//! After a restore, the count goes on from the saved map's last `seq`: readings the driver
//! published while the fusion was down are a gap like any other, lost to the map. (A driver that
//! restarted meanwhile and got past that number cannot be told apart from one that did not.)

use std::time::Duration;

use sonar_common::ipc::{FusionStatus, LAYOUT_VERSION};

use crate::persist::SaveReport;

/// What a reading's `seq` says about the readings before it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SeqStep {
    /// The first reading seen.
    First,
    /// The one after the previous.
    Next,
    /// This many readings were skipped.
    Gap(u64),
    /// Back to an earlier (or the same) number: a restarted driver.
    Backwards,
}

/// The counters behind [`FusionStatus`].
#[derive(Debug, Clone)]
pub struct Ledger {
    status: FusionStatus,
    last_seq: Option<u64>,
}

fn micros(d: Duration) -> u32 {
    u32::try_from(d.as_micros()).unwrap_or(u32::MAX)
}

impl Ledger {
    /// Counters of a process that restored a map (`restored`) whose last reading was `last_seq`.
    pub fn new(restored: bool, last_seq: Option<u64>) -> Self {
        Self {
            status: FusionStatus {
                restored: u32::from(restored),
                last_seq: last_seq.unwrap_or(FusionStatus::NO_SEQ),
                ..FusionStatus::default()
            },
            last_seq,
        }
    }

    /// A reading with number `seq` taken from `sonar/readings`.
    pub fn received(&mut self, seq: u64) -> SeqStep {
        let s = &mut self.status;
        s.readings_received += 1;
        let step = match self.last_seq {
            None => SeqStep::First,
            Some(last) if seq > last => match seq - last - 1 {
                0 => SeqStep::Next,
                lost => SeqStep::Gap(lost),
            },
            Some(_) => SeqStep::Backwards,
        };
        match step {
            SeqStep::Gap(lost) => s.readings_lost += lost,
            SeqStep::Backwards => s.readings_out_of_order += 1,
            SeqStep::First | SeqStep::Next => {}
        }
        self.last_seq = Some(seq);
        s.last_seq = seq;
        step
    }

    /// Readings lost so far.
    pub fn readings_lost(&self) -> u64 {
        self.status.readings_lost
    }

    /// A reading received but not fused.
    pub fn rejected(&mut self) {
        self.status.readings_rejected += 1;
    }

    /// The features have skipped `total` readings so far (no raw pings to place).
    pub fn feature_readings_skipped(&mut self, total: u64) {
        self.status.feature_readings_skipped = u32::try_from(total).unwrap_or(u32::MAX);
    }

    pub fn snapshot_published(&mut self) {
        self.status.snapshots_published += 1;
    }

    /// A snapshot not published for want of a free shared-memory sample.
    pub fn snapshot_skipped(&mut self) {
        self.status.snapshots_skipped += 1;
    }

    /// A save's copy held the readings loop for `copy_time`.
    pub fn save_taken(&mut self, copy_time: Duration) {
        self.status.last_save_copy_us = micros(copy_time);
    }

    /// A save the saver thread finished.
    pub fn save_finished(&mut self, report: &SaveReport) {
        let s = &mut self.status;
        match report.result {
            Ok(()) => {
                s.saves += 1;
                s.last_save_ns = report.taken_ns;
                s.saved_readings_fused = report.readings_fused;
                s.last_save_write_us = micros(report.write_time);
            }
            Err(_) => s.save_failures += 1,
        }
    }

    /// The status to publish, for a map of `readings_fused` readings, at `stamp_ns`.
    pub fn status(&self, readings_fused: u64, stamp_ns: u64) -> FusionStatus {
        FusionStatus {
            stamp_ns,
            readings_fused,
            layout_version: LAYOUT_VERSION,
            ..self.status
        }
    }

    /// Whether something a consumer should hear at once (a loss, a restart of the numbering, a
    /// save or a failed one) happened since `published` was published.
    pub fn news_since(&self, published: &FusionStatus) -> bool {
        let s = &self.status;
        (
            s.readings_lost,
            s.readings_out_of_order,
            s.saves,
            s.save_failures,
        ) != (
            published.readings_lost,
            published.readings_out_of_order,
            published.saves,
            published.save_failures,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::SavedMap;
    use crate::persist::SaveError;

    #[test]
    fn gaps_are_lost_readings_and_a_restart_is_not() {
        let mut l = Ledger::new(false, None);
        assert_eq!(l.status(0, 0).last_seq, FusionStatus::NO_SEQ);
        let steps: Vec<SeqStep> = [0, 1, 2, 5, 6, 0, 1, 1, 10]
            .into_iter()
            .map(|seq| l.received(seq))
            .collect();
        assert_eq!(
            steps,
            [
                SeqStep::First,
                SeqStep::Next,
                SeqStep::Next,
                SeqStep::Gap(2),
                SeqStep::Next,
                SeqStep::Backwards,
                SeqStep::Next,
                SeqStep::Backwards,
                SeqStep::Gap(8),
            ]
        );
        let s = l.status(7, 99);
        assert_eq!(s.readings_received, 9);
        assert_eq!(s.readings_lost, 10);
        assert_eq!(s.readings_out_of_order, 2);
        assert_eq!((s.last_seq, s.readings_fused, s.stamp_ns), (10, 7, 99));
        assert_eq!(s.restored, 0);
    }

    #[test]
    fn after_a_restore_the_gap_is_measured_from_the_saved_seq() {
        let mut l = Ledger::new(true, Some(41));
        assert_eq!(l.status(0, 0).restored, 1);
        assert_eq!(l.status(0, 0).last_seq, 41);
        assert_eq!(l.received(50), SeqStep::Gap(8));
        // A driver restarted meanwhile: not a loss.
        let mut l = Ledger::new(true, Some(41));
        assert_eq!(l.received(0), SeqStep::Backwards);
        assert_eq!(l.status(0, 0).readings_lost, 0);
    }

    #[test]
    fn news_is_loss_restarts_and_saves() {
        let mut l = Ledger::new(false, None);
        let published = l.status(0, 0);
        l.received(0);
        l.received(1);
        l.rejected();
        l.snapshot_published();
        assert!(!l.news_since(&published), "steady counting is no news");
        l.received(3);
        assert!(l.news_since(&published));
        let published = l.status(0, 0);
        l.save_finished(&SaveReport {
            taken_ns: 5,
            readings_fused: 3,
            write_time: Duration::from_millis(2),
            result: Ok(()),
            spare: SavedMap::default(),
        });
        assert!(l.news_since(&published));
        let s = l.status(3, 6);
        assert_eq!((s.saves, s.last_save_ns, s.saved_readings_fused), (1, 5, 3));
        assert_eq!((s.last_save_write_us, s.readings_rejected), (2000, 1));
        l.save_finished(&SaveReport {
            taken_ns: 9,
            readings_fused: 4,
            write_time: Duration::ZERO,
            result: Err(SaveError::SaverGone),
            spare: SavedMap::default(),
        });
        let s = l.status(3, 6);
        assert_eq!((s.saves, s.save_failures, s.last_save_ns), (1, 1, 5));
    }
}
