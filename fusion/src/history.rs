//! The observations kept behind the maps, and the maps fused again from them.
//!
//! The engine keeps its latest observations (`--history`) for two reasons: a switch of model,
//! rule or preset rebuilds the maps from them at once, and a **revision** of where some of them
//! were taken moves them and rebuilds the maps in steps. A revision comes from the SLAM
//! (`sonar/slam_correction`, issue 25): each sweep's readings were placed with the correction
//! (map ← odometry) known when they arrived, and the SLAM later estimates that sweep's own, and
//! moves earlier sweeps again when a loop closes. So every kept observation remembers its sweep
//! and the correction it was placed with; a revised correction for a sweep carries its
//! observations along (`new ∘ old⁻¹ ∘ pose`).
//!
//! Rebuilding is done in steps between readings ([`History::rebuild_step`]), so that a fusion
//! that holds 20 000 observations keeps taking readings while it re-fuses: the live maps go on
//! as they are until the rebuilt ones have caught up with every observation kept, the ones that
//! arrived meanwhile included, and then replace them. A revision during a rebuild starts it
//! again. The maps can be rebuilt only from everything they hold: once the history has let go
//! of an observation still in the maps (more readings than `--history`, or a restored map), a
//! revision moves the observations kept but the maps stay as they are ([`Revised::Uncovered`]).

use std::collections::VecDeque;

use nalgebra::{Isometry2, Point2};

use crate::mapper::Mapper;
use crate::observation::Observation;

/// Where a kept observation came from: its sweep, and the correction it was placed with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    pub sweep_id: u32,
    /// Map ← odometry when it was placed.
    pub correction: Isometry2<f32>,
}

#[derive(Debug, Clone, Copy)]
struct Kept {
    obs: Observation,
    /// `None` for observations restored from a saved map (their sweeps are not saved).
    placement: Option<Placement>,
}

/// What a revision did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Revised {
    /// No kept observation moved by more than the tolerance.
    Unmoved,
    /// This many moved; the maps are being rebuilt.
    Rebuilding(usize),
    /// This many moved, but the maps hold observations the history no longer has: not rebuilt.
    Uncovered(usize),
}

/// Maps being fused again from the history.
#[derive(Debug)]
struct Rebuild {
    mapper: Mapper,
    /// Index (counted from the first observation ever kept) of the next one to fuse.
    next: u64,
}

/// The kept observations, newest last, at most `limit`.
#[derive(Debug)]
pub struct History {
    kept: VecDeque<Kept>,
    limit: usize,
    /// Observations let go from the front since the start: index of `kept[0]`.
    dropped: u64,
    /// Whether every observation in the live maps is kept (they can be rebuilt from it).
    covers_maps: bool,
    rebuild: Option<Rebuild>,
}

impl History {
    pub fn new(limit: usize) -> Self {
        Self {
            kept: VecDeque::new(),
            limit,
            dropped: 0,
            covers_maps: true,
            rebuild: None,
        }
    }

    /// The observations of a restored map: they are not all the map holds, so no revision
    /// rebuilds it until it is cleared.
    pub fn restored(limit: usize, observations: impl IntoIterator<Item = Observation>) -> Self {
        let mut history = Self::new(limit);
        for obs in observations {
            history.push(obs, None);
        }
        history.covers_maps = false;
        history
    }

    pub fn limit(&self) -> usize {
        self.limit
    }

    pub fn len(&self) -> usize {
        self.kept.len()
    }

    pub fn is_empty(&self) -> bool {
        self.kept.is_empty()
    }

    pub fn observations(&self) -> impl Iterator<Item = &Observation> {
        self.kept.iter().map(|k| &k.obs)
    }

    /// Keeps `obs`, just fused into the live maps, letting go of the oldest beyond the limit.
    pub fn push(&mut self, obs: Observation, placement: Option<Placement>) {
        if self.limit == 0 {
            self.covers_maps = false;
            return;
        }
        if self.kept.len() == self.limit {
            self.kept.pop_front();
            self.dropped += 1;
            self.covers_maps = false;
            if self.rebuild.as_ref().is_some_and(|r| r.next < self.dropped) {
                // An observation it had not fused yet is gone: it cannot catch up.
                self.rebuild = None;
            }
        }
        self.kept.push_back(Kept { obs, placement });
    }

    /// The maps were emptied (and the history with them) or rebuilt from all of it at once.
    pub fn clear(&mut self) {
        self.dropped += self.kept.len() as u64;
        self.kept.clear();
        self.covers_maps = true;
        self.rebuild = None;
    }

    /// The live maps were just rebuilt from every kept observation: they hold what it holds.
    pub fn rebuilt_at_once(&mut self) {
        self.covers_maps = true;
        self.rebuild = None;
    }

    /// Moves the observations of every sweep in `corrections` (sweep id, its correction now) to
    /// where that correction places them; an observation counts as moved when its echo (or the
    /// end of its beam) moves by more than `tolerance_m`. When some moved and the history holds
    /// everything in the maps, a rebuild into `fresh` starts (or starts again).
    pub fn revise(
        &mut self,
        corrections: &[(u32, Isometry2<f32>)],
        tolerance_m: f32,
        fresh: impl FnOnce() -> Mapper,
    ) -> Revised {
        let mut moved = 0;
        for kept in &mut self.kept {
            let Some(placement) = &mut kept.placement else {
                continue;
            };
            let Some(&(_, correction)) = corrections
                .iter()
                .rev()
                .find(|(sweep, _)| *sweep == placement.sweep_id)
            else {
                continue;
            };
            let pose = correction * placement.correction.inverse() * kept.obs.pose;
            let reach = kept.obs.range_m.unwrap_or(kept.obs.max_range_m);
            let tip = |pose: &Isometry2<f32>| {
                pose * Point2::new(
                    reach * kept.obs.angle_rad.cos(),
                    reach * kept.obs.angle_rad.sin(),
                )
            };
            let shift = (tip(&pose) - tip(&kept.obs.pose))
                .norm()
                .max((pose.translation.vector - kept.obs.pose.translation.vector).norm());
            placement.correction = correction;
            kept.obs.pose = pose;
            if shift > tolerance_m {
                moved += 1;
            }
        }
        if moved == 0 {
            Revised::Unmoved
        } else if self.covers_maps {
            self.rebuild = Some(Rebuild {
                mapper: fresh(),
                next: self.dropped,
            });
            Revised::Rebuilding(moved)
        } else {
            Revised::Uncovered(moved)
        }
    }

    /// Whether a rebuild is under way.
    pub fn rebuilding(&self) -> bool {
        self.rebuild.is_some()
    }

    /// Fuses up to `budget` kept observations into the maps being rebuilt; when they have caught
    /// up with the history, returns them to replace the live ones.
    pub fn rebuild_step(&mut self, budget: usize) -> Option<Mapper> {
        let rebuild = self.rebuild.as_mut()?;
        let start = usize::try_from(rebuild.next - self.dropped).ok()?;
        let end = self.kept.len().min(start.saturating_add(budget));
        let mut previous_sweep = start
            .checked_sub(1)
            .and_then(|i| self.kept[i].placement.map(|p| p.sweep_id));
        for kept in self.kept.range(start..end) {
            let sweep = kept.placement.map(|p| p.sweep_id);
            if sweep.is_some() && previous_sweep.is_some() && sweep != previous_sweep {
                // As the engine does live: a sweep's last region is placed when the next begins.
                rebuild.mapper.close_region();
            }
            previous_sweep = sweep;
            // Every kept observation was accepted once, under the same settings.
            let _ = rebuild.mapper.update(&kept.obs);
        }
        rebuild.next = self.dropped + end as u64;
        if end < self.kept.len() {
            return None;
        }
        self.rebuild.take().map(|r| r.mapper)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::FusionConfig;
    use nalgebra::Vector2;

    fn obs(x: f32, angle: f32) -> Observation {
        Observation {
            pose: Isometry2::new(Vector2::new(x, 0.0), 0.0),
            angle_rad: angle,
            range_m: Some(1.0),
            rejected_echo_m: None,
            beam_half_angle_rad: 0.26,
            max_range_m: 3.0,
        }
    }

    fn placement(sweep_id: u32) -> Option<Placement> {
        Some(Placement {
            sweep_id,
            correction: Isometry2::identity(),
        })
    }

    fn mapper() -> Mapper {
        Mapper::new(FusionConfig::default()).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn a_revision_moves_its_sweep_only_and_rebuilds_in_steps() {
        let mut history = History::new(100);
        for i in 0..10 {
            history.push(obs(0.0, i as f32 * 0.1), placement(1));
        }
        for i in 0..10 {
            history.push(obs(0.5, i as f32 * 0.1), placement(2));
        }
        let shift = Isometry2::new(Vector2::new(0.0, 0.2), 0.0);
        assert_eq!(
            history.revise(&[(2, shift)], 0.01, mapper),
            Revised::Rebuilding(10)
        );
        let ys: Vec<f32> = history
            .observations()
            .map(|o| o.pose.translation.y)
            .collect();
        assert!(ys[..10].iter().all(|&y| y == 0.0));
        assert!(ys[10..].iter().all(|&y| (y - 0.2).abs() < 1e-6));
        // The same correction again moves nothing.
        assert_eq!(
            history.revise(&[(2, shift)], 0.01, mapper),
            Revised::Unmoved
        );
        // In steps of 8: 20 kept, done on the third.
        assert!(history.rebuild_step(8).is_none());
        assert!(history.rebuild_step(8).is_none());
        let rebuilt = history
            .rebuild_step(8)
            .unwrap_or_else(|| panic!("not done"));
        assert_eq!(rebuilt.readings_fused(), 20);
        assert!(!history.rebuilding());
    }

    #[test]
    fn observations_arriving_during_a_rebuild_are_fused_into_it() {
        let mut history = History::new(100);
        for i in 0..10 {
            history.push(obs(0.0, i as f32 * 0.1), placement(1));
        }
        let shift = Isometry2::new(Vector2::new(0.1, 0.0), 0.1);
        assert!(matches!(
            history.revise(&[(1, shift)], 0.01, mapper),
            Revised::Rebuilding(_)
        ));
        assert!(history.rebuild_step(5).is_none());
        for i in 0..3 {
            history.push(obs(1.0, i as f32 * 0.1), placement(2));
        }
        assert!(history.rebuild_step(5).is_none());
        let rebuilt = history
            .rebuild_step(5)
            .unwrap_or_else(|| panic!("not done"));
        assert_eq!(rebuilt.readings_fused(), 13);
    }

    #[test]
    fn maps_holding_more_than_the_history_are_not_rebuilt() {
        let mut history = History::new(5);
        for i in 0..8 {
            history.push(obs(0.0, i as f32 * 0.1), placement(1));
        }
        let shift = Isometry2::new(Vector2::new(0.3, 0.0), 0.0);
        assert_eq!(
            history.revise(&[(1, shift)], 0.01, mapper),
            Revised::Uncovered(5)
        );
        assert!(history.rebuild_step(100).is_none());
        // Emptied with its maps, it covers them again.
        history.clear();
        history.push(obs(0.0, 0.0), placement(3));
        assert_eq!(
            history.revise(&[(3, shift)], 0.01, mapper),
            Revised::Rebuilding(1)
        );
        let restored = History::restored(10, [obs(0.0, 0.0)]);
        assert_eq!(restored.len(), 1);
        assert!(!restored.covers_maps);
    }

    #[test]
    fn a_rebuild_that_loses_an_observation_it_needs_is_abandoned() {
        let mut history = History::new(4);
        for i in 0..4 {
            history.push(obs(0.0, i as f32 * 0.1), placement(1));
        }
        let shift = Isometry2::new(Vector2::new(0.3, 0.0), 0.0);
        assert!(matches!(
            history.revise(&[(1, shift)], 0.01, mapper),
            Revised::Rebuilding(4)
        ));
        history.push(obs(0.0, 1.0), placement(2));
        assert!(!history.rebuilding());
    }
}
