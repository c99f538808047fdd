//! The engine's state as a value that can be saved and restored: everything needed to go on fusing
//! exactly as if the process had never stopped.
//!
//! That is more than the snapshot a consumer sees: the grid's cells in the combination rule's own
//! representation (f32 probabilities or log-odds, Dempster–Shafer mass pairs, HIMM counters; the
//! one-byte snapshot encoding cannot be fused into again), the radar array, the observations kept
//! for re-fusing after a switch of model, rule or preset, the scan state and both poses (the last
//! fused reading's, for the snapshot header, and the robot's latest, at which the next reading is
//! placed), and the counters. Floats are kept bit for bit, NaN sentinels included. What is left
//! out is derived: the fast kernel's caches are rebuilt on the first reading (its results do not
//! depend on them, see [`crate::kernel`]), and the settings travel beside the state
//! ([`crate::engine::SavedMap`]).

use nalgebra::{Complex, Isometry2, Translation2, Unit};
use serde::{Deserialize, Serialize};

use crate::config_error::ConfigError;
use crate::observation::Observation;
use crate::rule::RuleKind;

/// What the latest reading said about the scan, for the snapshots' headers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub(crate) struct ScanState {
    pub(crate) sweep_id: u32,
    pub(crate) direction: i8,
    pub(crate) mode: u8,
}

/// The engine's state, taken by [`crate::engine::Engine::capture`].
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct MapState {
    pub(crate) maps: MapperState,
    pub(crate) history: Vec<SavedObservation>,
    pub(crate) scan: Option<ScanState>,
    pub(crate) robot_pose: SavedPose,
    pub(crate) rejected_readings: u64,
    pub(crate) last_seq: Option<u64>,
}

impl MapState {
    /// Readings in the map since it was last cleared.
    pub fn readings_fused(&self) -> u64 {
        self.maps.readings_fused
    }

    /// `seq` of the last reading the engine took.
    pub fn last_seq(&self) -> Option<u64> {
        self.last_seq
    }
}

/// Both maps and what the [`crate::mapper::Mapper`] counts.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub(crate) struct MapperState {
    pub readings_fused: u64,
    pub last_pose: SavedPose,
    pub cells: SavedCells,
    /// Per cell, the bearing it was last heard occupied from, for a model that hears (empty for
    /// the others; see [`crate::grid::OccupancyGrid`]).
    pub heard: Vec<f32>,
    pub radar: SavedRadar,
}

/// A state that does not fit the settings it was saved with (a damaged or hand-made file whose
/// checksum happens to hold).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StateError {
    #[error("{what} has {found} values where the settings give {expected}")]
    Length {
        what: &'static str,
        expected: usize,
        found: usize,
    },
    #[error("the cells are a {found} rule's where the settings name {expected}")]
    Rule { expected: RuleKind, found: RuleKind },
    #[error(transparent)]
    Config(#[from] ConfigError),
}

/// `Ok` if a saved array has the length the settings give it.
pub(crate) fn check_len(
    what: &'static str,
    expected: usize,
    found: usize,
) -> Result<(), StateError> {
    if expected == found {
        Ok(())
    } else {
        Err(StateError::Length {
            what,
            expected,
            found,
        })
    }
}

/// The grid's cells, row-major, in the representation of the rule that fused them.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) enum SavedCells {
    Bayes(Vec<f32>),
    LogOdds(Vec<f32>),
    DempsterShafer(Vec<[f32; 2]>),
    Himm(Vec<u8>),
}

impl Default for SavedCells {
    /// No cells: an empty copy to capture into.
    fn default() -> Self {
        SavedCells::Bayes(Vec::new())
    }
}

impl SavedCells {
    pub(crate) fn rule_kind(&self) -> RuleKind {
        match self {
            SavedCells::Bayes(_) => RuleKind::Bayes,
            SavedCells::LogOdds(_) => RuleKind::LogOdds,
            SavedCells::DempsterShafer(_) => RuleKind::DempsterShafer,
            SavedCells::Himm(_) => RuleKind::Himm,
        }
    }
}

/// The radar array's contents and its bins (which follow the head, so they may differ from the
/// settings' bins; their count is the number of distances).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub(crate) struct SavedRadar {
    pub distances_m: Vec<f32>,
    pub current_angle_deg: Option<f32>,
    pub first_bin_deg: f32,
    pub bin_width_deg: f32,
}

/// A pose as nalgebra holds it (translation and unit complex), so it comes back bit for bit rather
/// than through an angle.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
pub(crate) struct SavedPose {
    x: f32,
    y: f32,
    cos: f32,
    sin: f32,
}

impl From<Isometry2<f32>> for SavedPose {
    fn from(pose: Isometry2<f32>) -> Self {
        Self {
            x: pose.translation.x,
            y: pose.translation.y,
            cos: pose.rotation.re,
            sin: pose.rotation.im,
        }
    }
}

impl From<SavedPose> for Isometry2<f32> {
    fn from(p: SavedPose) -> Self {
        // The components were a unit complex when saved; renormalising would change their bits.
        Isometry2::from_parts(
            Translation2::new(p.x, p.y),
            Unit::new_unchecked(Complex::new(p.cos, p.sin)),
        )
    }
}

/// An [`Observation`] kept for re-fusing.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub(crate) struct SavedObservation {
    pose: SavedPose,
    angle_rad: f32,
    range_m: Option<f32>,
    rejected_echo_m: Option<f32>,
    beam_half_angle_rad: f32,
    max_range_m: f32,
}

impl From<&Observation> for SavedObservation {
    fn from(o: &Observation) -> Self {
        Self {
            pose: o.pose.into(),
            angle_rad: o.angle_rad,
            range_m: o.range_m,
            rejected_echo_m: o.rejected_echo_m,
            beam_half_angle_rad: o.beam_half_angle_rad,
            max_range_m: o.max_range_m,
        }
    }
}

impl From<SavedObservation> for Observation {
    fn from(o: SavedObservation) -> Self {
        Self {
            pose: o.pose.into(),
            angle_rad: o.angle_rad,
            range_m: o.range_m,
            rejected_echo_m: o.rejected_echo_m,
            beam_half_angle_rad: o.beam_half_angle_rad,
            max_range_m: o.max_range_m,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector2;

    #[test]
    fn a_pose_comes_back_bit_for_bit() {
        for theta in [0.0f32, 0.3, -2.9, std::f32::consts::PI] {
            let pose = Isometry2::new(Vector2::new(0.37, -1.21), theta);
            let back: Isometry2<f32> = SavedPose::from(pose).into();
            assert_eq!(back.translation.vector, pose.translation.vector);
            assert_eq!(back.rotation.re.to_bits(), pose.rotation.re.to_bits());
            assert_eq!(back.rotation.im.to_bits(), pose.rotation.im.to_bits());
        }
    }
}
