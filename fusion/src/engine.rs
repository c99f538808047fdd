//! The fusion process's state, without its I/O: readings and commands in, snapshots out.
//!
//! The process (`src/main.rs`) only moves bytes between iceoryx2 and an [`Engine`]; everything it
//! decides — when a sweep has ended, what a command does, what a snapshot header says — lives here
//! so that it is tested without shared memory.
//!
//! The engine keeps the observations fused since the last clear (up to a bound), so that switching
//! the model, the rule or the preset re-fuses the same data: a user compares methods on one scan
//! instead of waiting for new sweeps.

use nalgebra::{Isometry2, Vector2};
use sonar_common::ipc::{
    FusionCommand, FusionCommandKind, GridHeader, LAYOUT_VERSION, Pose2D, RADAR_MAX_BINS, Radar,
    Reading, SlamCorrection, SweepEnd, preset_code, slam_state,
};

use crate::config::{ConfigError, FusionConfig, Preset};
use crate::grid::{CellCounts, EncodedVersion};
use crate::history::{History, Placement, Revised};
use crate::mapper::Mapper;
use crate::model::{ModelConfig, ModelKind};
use crate::observation::Observation;
use crate::poses::{PlacedPose, PoseError, PoseKind, PoseTrack};
use crate::rule::{RuleConfig, RuleKind};
use crate::state::{MapState, SavedObservation, ScanState, StateError};

/// A command the engine refuses; the maps are unchanged.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CommandError {
    #[error("unknown fusion command kind {0}")]
    UnknownKind(u32),
    #[error("unknown {what} code {code}")]
    UnknownCode { what: &'static str, code: u32 },
    #[error(transparent)]
    Config(#[from] ConfigError),
}

/// What a map file holds: the settings the map was built with, and the engine's state.
#[derive(Debug, Clone, Default)]
pub struct SavedMap {
    pub settings: FusionConfig,
    pub state: MapState,
}

/// Both maps, the observations behind them, and the scan state.
#[derive(Debug)]
pub struct Engine {
    mapper: Mapper,
    history: History,
    scan: Option<ScanState>,
    /// The robot's recent poses: each reading is placed at its own instant.
    poses: PoseTrack,
    /// Where the latest reading was placed.
    pose: Isometry2<f32>,
    /// Map ← odometry: what localisation found the poses of `robot/pose` to be off by.
    correction: Isometry2<f32>,
    /// Readings placed with a pose more than [`crate::poses::STALE_AFTER_NS`] old.
    stale_pose_readings: u64,
    /// Readings placed past the latest pose (within [`crate::poses::STALE_AFTER_NS`]).
    extrapolated_pose_readings: u64,
    /// Readings older than every pose kept, placed at the oldest.
    early_pose_readings: u64,
    rejected_readings: u64,
    last_seq: Option<u64>,
    /// The sweep of the latest reading fused, when it was closed on the head's word that it
    /// ended ([`Self::sweep_ended`]): its next sweep's first reading need not close it again.
    closed_sweep: Option<u32>,
    /// Bumped by every change of the state, so a saver knows whether there is anything new.
    revision: u64,
    /// The sensor's constant lateness, metres, taken off every reading's range
    /// ([`Self::set_range_offset`]).
    range_offset_m: f32,
}

/// What a sweep's end ([`SweepEnd`], the head's word through the driver) did to the engine.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SweepEndOutcome {
    /// Its last reading is still to be fused: offer the end again after it.
    Early,
    /// The sweep was closed; whether that changed the maps.
    Closed { changed: bool },
    /// Not the sweep the latest reading belongs to (fused past it, or another driver's): ignored.
    Stale,
}

impl Engine {
    /// Empty maps for `config`; up to `history_limit` observations are kept for re-fusing.
    pub fn new(config: FusionConfig, history_limit: usize) -> Result<Self, ConfigError> {
        Ok(Self {
            mapper: Mapper::new(config)?,
            history: History::new(history_limit),
            scan: None,
            poses: PoseTrack::new(Isometry2::identity()),
            pose: Isometry2::identity(),
            correction: Isometry2::identity(),
            stale_pose_readings: 0,
            extrapolated_pose_readings: 0,
            early_pose_readings: 0,
            rejected_readings: 0,
            last_seq: None,
            closed_sweep: None,
            revision: 0,
            range_offset_m: 0.0,
        })
    }

    /// The engine a saved state describes, under `config` (the settings it was saved with), with
    /// the latest `history_limit` of its kept observations.
    pub fn restore(
        config: FusionConfig,
        history_limit: usize,
        state: MapState,
    ) -> Result<Self, StateError> {
        let skip = state.history.len().saturating_sub(history_limit);
        let history = History::restored(
            history_limit,
            state.history.into_iter().skip(skip).map(Into::into),
        );
        let mut mapper = Mapper::restore(config, state.maps)?;
        mapper.remember_readings(history.observations());
        Ok(Self {
            mapper,
            history,
            scan: state.scan,
            poses: PoseTrack::new(state.robot_pose.into()),
            pose: state.robot_pose.into(),
            correction: Isometry2::identity(),
            stale_pose_readings: 0,
            extrapolated_pose_readings: 0,
            early_pose_readings: 0,
            rejected_readings: state.rejected_readings,
            last_seq: state.last_seq,
            closed_sweep: None,
            revision: 0,
            range_offset_m: 0.0,
        })
    }

    /// A copy of everything the engine holds, with its settings, for saving. A copy of the cells
    /// and nothing more (no encoding), so the process takes it between readings and writes it
    /// elsewhere.
    pub fn capture(&self) -> SavedMap {
        let mut map = SavedMap::default();
        self.capture_into(&mut map);
        map
    }

    /// [`Self::capture`] into an earlier copy, reusing its memory: for a large grid, a fresh
    /// copy's page faults cost more than the copying itself.
    pub fn capture_into(&self, map: &mut SavedMap) {
        map.settings = *self.mapper.config();
        let state = &mut map.state;
        self.mapper.save_into(&mut state.maps);
        state.history.clear();
        state
            .history
            .extend(self.history.observations().map(SavedObservation::from));
        state.scan = self.scan;
        state.robot_pose = self.poses.latest().into();
        state.rejected_readings = self.rejected_readings;
        state.last_seq = self.last_seq;
    }

    /// `seq` of the last reading taken by [`Self::fuse`], fused or refused.
    pub fn last_seq(&self) -> Option<u64> {
        self.last_seq
    }

    /// A number that changes whenever anything [`Self::capture`] copies does: equal revisions of
    /// one engine hold the same state, so a map saved at this revision needs no new save.
    pub fn revision(&self) -> u64 {
        self.revision
    }

    pub fn mapper(&self) -> &Mapper {
        &self.mapper
    }

    /// Readings the kernels refused (non-finite angle or range); they are logged by the process.
    pub fn rejected_readings(&self) -> u64 {
        self.rejected_readings
    }

    /// Where the latest reading was placed (the robot's pose at its instant).
    pub fn pose(&self) -> &Isometry2<f32> {
        &self.pose
    }

    /// Gaps in the pose stream (poses lost or not sent; estimated, see [`crate::poses`]).
    pub fn pose_gaps(&self) -> crate::poses::PoseGaps {
        self.poses.gaps()
    }

    /// Readings placed with a stale pose: the pose stream had stopped or lagged by more than
    /// [`crate::poses::STALE_AFTER_NS`].
    pub fn stale_pose_readings(&self) -> u64 {
        self.stale_pose_readings
    }

    /// Readings placed past the latest pose, at the robot's last velocity: the pose covering
    /// their instant had not arrived (and was not waited for, [`Self::awaits_pose`]).
    pub fn extrapolated_pose_readings(&self) -> u64 {
        self.extrapolated_pose_readings
    }

    /// Readings older than every pose kept, placed at the oldest: more than
    /// [`crate::poses::KEPT_POSES`] poses arrived while they waited in the buffer.
    pub fn early_pose_readings(&self) -> u64 {
        self.early_pose_readings
    }

    /// Whether a pose stream exists and no pose at or after `stamp_ns` has arrived yet: the one
    /// that places a reading of that instant by interpolation is still to come.
    pub fn awaits_pose(&self, stamp_ns: u64) -> bool {
        self.poses.awaits(stamp_ns)
    }

    /// Places every reading from now on at `correction` × its odometry pose: localisation's
    /// latest estimate of the odometry's drift (map ← odometry).
    pub fn set_correction(&mut self, correction: Isometry2<f32>) {
        self.correction = correction;
    }

    /// Takes one of sonar-slam's estimates (`sonar/slam_correction`): the correction of a new
    /// sweep places the readings from now on ([`Self::set_correction`]; fix or not, it is the
    /// SLAM's best estimate of map → odom), one that revises an earlier sweep does not. Returns
    /// the sweep and its correction for [`Self::revise`] (every message: the revisions move their
    /// sweeps, the others the sweep just fused), or `None`, changing nothing, when the correction
    /// is not finite.
    pub fn take_slam_correction(&mut self, c: &SlamCorrection) -> Option<(u32, Isometry2<f32>)> {
        let finite = [c.correction_x_m, c.correction_y_m, c.correction_theta_rad]
            .iter()
            .all(|v| v.is_finite());
        if !finite {
            return None;
        }
        let correction = Isometry2::new(
            Vector2::new(c.correction_x_m, c.correction_y_m),
            c.correction_theta_rad,
        );
        if c.state != slam_state::REVISED {
            self.set_correction(correction);
        }
        Some((c.sweep_id, correction))
    }

    /// Moves the kept readings of each sweep in `corrections` (sweep id, map ← odometry as now
    /// estimated; the SLAM's revisions) to where that correction places them, and starts
    /// rebuilding the maps from them if some moved by more than half a cell
    /// ([`crate::history`]); [`Self::rebuild_step`] carries it on.
    pub fn revise(&mut self, corrections: &[(u32, Isometry2<f32>)]) -> Revised {
        let config = *self.mapper.config();
        let tolerance = config.grid.resolution_m / 2.0;
        self.history.revise(corrections, tolerance, || {
            // The settings are the live maps', which were valid.
            Mapper::new(config).unwrap_or_else(|_| unreachable!("the live maps' settings"))
        })
    }

    /// Carries a rebuild on by up to `budget` readings; true when the rebuilt maps replaced
    /// the live ones.
    pub fn rebuild_step(&mut self, budget: usize) -> bool {
        let Some(mapper) = self.history.rebuild_step(budget) else {
            return false;
        };
        self.mapper = mapper;
        self.revision += 1;
        true
    }

    /// Whether the maps are being rebuilt after a revision.
    pub fn rebuilding(&self) -> bool {
        self.history.rebuilding()
    }

    /// Takes a pose of the robot (`robot/pose`); readings are placed at the pose interpolated at
    /// their own stamp ([`crate::poses`]). A non-finite or out-of-order pose is refused.
    pub fn set_pose(&mut self, pose: &Pose2D) -> Result<(), PoseError> {
        self.poses.push(*pose)?;
        self.revision += 1;
        Ok(())
    }

    /// Whether `reading` starts a new sweep after readings of another one: the moment to publish
    /// the finished sweep's maps, before this reading changes them.
    pub fn starts_new_sweep(&self, reading: &Reading) -> bool {
        self.scan.is_some_and(|s| s.sweep_id != reading.sweep_id)
    }

    /// Before fusing `reading`: when it starts a new sweep, closes the finished one
    /// ([`Self::close_region`]) unless its end closed it already ([`Self::sweep_ended`]).
    /// `Some(changed)` when it closed a sweep (the moment to publish that sweep's maps), `None`
    /// otherwise.
    pub fn close_finished_sweep(&mut self, reading: &Reading) -> Option<bool> {
        if !self.starts_new_sweep(reading) {
            // A reading after the end's word: the sweep goes on, and is closed again.
            self.closed_sweep = None;
            return None;
        }
        let closed = self.closed_sweep.take();
        (closed != self.scan.map(|s| s.sweep_id)).then(|| self.close_region())
    }

    /// The head reported sweep `end.sweep_id` ended after reading `end.last_seq`: once that reading
    /// is the latest fused, the sweep is closed now ([`Self::close_region`]), not when the next
    /// sweep's first reading comes (a quarter of a second later at the head's pace). The maps are
    /// the same either way, nothing being fused in between; what a recording or a live fusion
    /// without the word (a hobby head) closes on the next reading instead, this closes at once.
    pub fn sweep_ended(&mut self, end: &SweepEnd) -> SweepEndOutcome {
        match self.last_seq {
            Some(seq) if seq < end.last_seq => SweepEndOutcome::Early,
            Some(seq)
                if seq == end.last_seq
                    && self.scan.is_some_and(|s| s.sweep_id == end.sweep_id)
                    && self.closed_sweep != Some(end.sweep_id) =>
            {
                self.closed_sweep = Some(end.sweep_id);
                SweepEndOutcome::Closed {
                    changed: self.close_region(),
                }
            }
            _ => SweepEndOutcome::Stale,
        }
    }

    /// Places the evidence of the region of constant depth still open (with echoes placed by
    /// region; [`Mapper::close_region`]): at the end of a sweep, so that its maps are whole.
    /// Whether that changed the grid.
    pub fn close_region(&mut self) -> bool {
        let changed = self.mapper.close_region() > 0;
        if changed {
            self.revision += 1;
        }
        changed
    }

    /// Takes `offset_m`, the sensor's constant lateness (calibrated on a wall; negative for a
    /// sensor that reads short), off every reading's range fused from now on
    /// ([`Observation::calibrated`]): the fusion process gives it `[features] range_offset_m`,
    /// so the grid and the features place an echo at the same distance.
    pub fn set_range_offset(&mut self, offset_m: f32) {
        self.range_offset_m = offset_m;
    }

    /// Fuses `reading` at the current pose into both maps; `false` if the kernels refused it.
    pub fn fuse(&mut self, reading: &Reading) -> bool {
        let PlacedPose { pose, kind } = self.poses.at(reading.host_stamp_ns);
        self.poses.placed(reading.host_stamp_ns);
        match kind {
            PoseKind::Stale => self.stale_pose_readings += 1,
            PoseKind::Extrapolated => self.extrapolated_pose_readings += 1,
            PoseKind::Early => self.early_pose_readings += 1,
            PoseKind::Initial | PoseKind::Interpolated => {}
        }
        self.pose = self.correction * pose;
        let obs = Observation::from_reading(reading, self.pose).calibrated(self.range_offset_m);
        self.last_seq = Some(reading.seq);
        self.revision += 1;
        self.scan = Some(ScanState {
            sweep_id: reading.sweep_id,
            direction: reading.direction,
            mode: reading.mode,
        });
        if self.mapper.update(&obs).is_err() {
            self.rejected_readings += 1;
            return false;
        }
        self.history.push(
            obs,
            Some(Placement {
                sweep_id: reading.sweep_id,
                correction: self.correction,
            }),
        );
        true
    }

    /// Carries out a command from `sonar/fusion_commands`. Switching model, rule or preset keeps
    /// the grid's size and re-fuses the kept observations under the new configuration.
    pub fn apply(&mut self, command: &FusionCommand) -> Result<(), CommandError> {
        let kind = command
            .kind()
            .ok_or(CommandError::UnknownKind(command.kind))?;
        let current = *self.mapper.config();
        let unknown = |what| CommandError::UnknownCode {
            what,
            code: command.value,
        };
        let config = match kind {
            FusionCommandKind::Clear => {
                self.mapper.clear();
                self.history.clear();
                self.revision += 1;
                return Ok(());
            }
            FusionCommandKind::SetPreset => {
                let preset = Preset::from_code(command.value).ok_or_else(|| unknown("preset"))?;
                let mut config = current;
                config.use_preset(preset);
                config
            }
            FusionCommandKind::SetModel => {
                let kind = ModelKind::from_code(command.value).ok_or_else(|| unknown("model"))?;
                FusionConfig {
                    model: ModelConfig::default_for(kind),
                    ..current
                }
            }
            FusionCommandKind::SetRule => {
                let kind = RuleKind::from_code(command.value).ok_or_else(|| unknown("rule"))?;
                FusionConfig {
                    rule: RuleConfig::default_for(kind),
                    ..current
                }
            }
        };
        self.reconfigure(config)
    }

    /// Rebuilds the maps for `config` from the kept observations.
    fn reconfigure(&mut self, config: FusionConfig) -> Result<(), CommandError> {
        let mut mapper = Mapper::new(config)?;
        for obs in self.history.observations() {
            // Every kept observation was accepted once; the limits of the new configuration are
            // the same (grid and sensor are kept), so none is refused now.
            let _ = mapper.update(obs);
        }
        self.mapper = mapper;
        self.history.rebuilt_at_once();
        self.revision += 1;
        Ok(())
    }

    /// The header of a `sonar/grid` snapshot whose cells [`Self::encode_grid`] returned `counts` for.
    pub fn grid_header(&self, seq: u64, stamp_ns: u64, counts: CellCounts) -> GridHeader {
        let config = self.mapper.config();
        let geometry = self.mapper.grid().geometry();
        let side = geometry.cells_per_side() as u32;
        let origin = geometry.origin();
        let pose = self.mapper.last_pose();
        GridHeader {
            seq,
            stamp_ns,
            readings_fused: self.mapper.readings_fused(),
            layout_version: LAYOUT_VERSION,
            width: side,
            height: side,
            resolution_m: geometry.resolution(),
            origin_x_m: origin.x,
            origin_y_m: origin.y,
            pose_x_m: pose.translation.x,
            pose_y_m: pose.translation.y,
            pose_theta_rad: pose.rotation.angle(),
            model: config.model.kind().code(),
            rule: config.rule.kind().code(),
            preset: config
                .matching_preset()
                .map_or(preset_code::CUSTOM, Preset::code),
            sweep_id: self.scan.map_or(0, |s| s.sweep_id),
            occupied_cells: counts.occupied,
            free_cells: counts.free,
            unknown_cells: counts.unknown,
        }
    }

    /// Writes the grid's cells in the snapshot encoding into `out` (one byte per cell).
    ///
    /// # Panics
    /// If `out` does not hold one byte per cell: the caller sizes it from the grid.
    pub fn encode_grid(&mut self, out: &mut [u8]) -> CellCounts {
        self.mapper.grid_mut().encode_into(out)
    }

    /// Brings `out`, a copy of the grid's cells in the snapshot encoding as of `held` (`None`:
    /// unknown contents), up to date, copying only what changed since where the grid still knows
    /// it ([`crate::grid::OccupancyGrid::copy_changed_into`]); returns the counts and the version
    /// `out` now holds.
    ///
    /// # Panics
    /// If `out` does not hold one byte per cell: the caller sizes it from the grid.
    pub fn copy_grid_changes_into(
        &mut self,
        out: &mut [u8],
        held: Option<EncodedVersion>,
    ) -> (CellCounts, EncodedVersion) {
        self.mapper.grid_mut().copy_changed_into(out, held)
    }

    /// The version of the grid's cells as [`Self::encoded_grid`] returns them now.
    pub fn encoded_grid_version(&mut self) -> EncodedVersion {
        self.mapper.grid_mut().encoded_version()
    }

    /// The grid's cells in the snapshot encoding and their counts, as kept up to date while
    /// fusing ([`crate::grid::OccupancyGrid::encoded`]).
    pub fn encoded_grid(&mut self) -> (&[u8], CellCounts) {
        self.mapper.grid_mut().encoded()
    }

    /// The grid, for reads that bring its kept state up to date first
    /// ([`crate::grid::OccupancyGrid::confident_cells`], [`crate::grid::OccupancyGrid::encoded`]). Change the
    /// maps through [`Self::fuse`] and [`Self::apply`]: they keep the history and the revision.
    pub fn grid_mut(&mut self) -> &mut crate::grid::OccupancyGrid {
        self.mapper.grid_mut()
    }

    /// Cells per snapshot.
    pub fn grid_len(&self) -> usize {
        self.mapper.grid().geometry().len()
    }

    /// The basic method's array as a `sonar/radar` snapshot.
    pub fn radar(&self, seq: u64, stamp_ns: u64) -> Radar {
        let map = self.mapper.radar();
        let config = map.config();
        let sensor = self.mapper.config().sensor;
        let scan = self.scan.unwrap_or_default();
        let mut distances_m = [f32::NAN; RADAR_MAX_BINS];
        for (out, &d) in distances_m.iter_mut().zip(map.distances_m()) {
            *out = d;
        }
        Radar {
            seq,
            stamp_ns,
            layout_version: LAYOUT_VERSION,
            bin_count: config.bin_count,
            first_bin_deg: config.first_bin_deg,
            bin_width_deg: config.bin_width_deg,
            beam_half_angle_deg: sensor.beam_half_angle_deg,
            max_range_m: sensor.max_range_m,
            current_angle_deg: map.current_angle_deg().unwrap_or(f32::NAN),
            sweep_id: scan.sweep_id,
            direction: i32::from(scan.direction),
            mode: u32::from(scan.mode),
            distances_m,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Preset;
    use nalgebra::Point2;
    use sonar_common::ipc::{ScanMode, flags, model_code, rule_code};

    fn reading(sweep_id: u32, angle_deg: f32, distance_m: f32) -> Reading {
        Reading {
            layout_version: LAYOUT_VERSION,
            sweep_id,
            angle_deg,
            beam_half_angle_deg: 30.0,
            distance_m,
            min_range_m: 0.03,
            max_range_m: 4.0,
            direction: 1,
            mode: ScanMode::Full as u8,
            ..Reading::default()
        }
    }

    /// A wall 1.2 m away across two sweeps.
    fn sweeps() -> Vec<Reading> {
        let mut out = Vec::new();
        for sweep in 1..=2 {
            for k in 0..50 {
                let angle = -147.0 + 6.0 * k as f32;
                let d = 1.2 / angle.to_radians().cos().abs().max(0.3);
                let mut r = reading(sweep, angle, d.min(3.9));
                if k % 7 == 0 {
                    r.flags = flags::NO_ECHO;
                }
                out.push(r);
            }
        }
        out
    }

    fn encoded(engine: &mut Engine) -> Vec<u8> {
        let mut cells = vec![0; engine.grid_len()];
        engine.encode_grid(&mut cells);
        cells
    }

    /// Where the grid holds its most likely cell on the x axis (0.5–1.5 m), after readings
    /// straight ahead that heard `distance_m`, with the sensor's range offset `offset_m`.
    fn wall_on_the_axis(distance_m: f32, offset_m: f32) -> f32 {
        let mut engine = Engine::new(FusionConfig::preset(Preset::Paper), 10).unwrap();
        engine.set_range_offset(offset_m);
        for seq in 0..4 {
            assert!(engine.fuse(&Reading {
                seq,
                ..reading(1, 0.0, distance_m)
            }));
        }
        let grid = engine.mapper().grid();
        let geometry = grid.geometry();
        let (_, y) = geometry.cell_at(Point2::origin()).unwrap();
        let (from, _) = geometry.cell_at(Point2::new(0.5, 0.0)).unwrap();
        let (to, _) = geometry.cell_at(Point2::new(1.5, 0.0)).unwrap();
        let best = (from..=to)
            .max_by(|&a, &b| {
                let p = |x| grid.probability(x, y).unwrap_or(0.0);
                p(a).total_cmp(&p(b))
            })
            .unwrap();
        geometry.cell_centre(best, y).x
    }

    /// A sensor that reads 4 cm short, calibrated as such (`[features] range_offset_m = -0.04`),
    /// has its echoes placed where a sensor that reads true would place them, 4 cm farther (two
    /// cells), as the features place them.
    #[test]
    fn a_calibrated_range_offset_moves_the_grid_s_echoes_by_it() {
        let short = wall_on_the_axis(1.0, 0.0);
        let calibrated = wall_on_the_axis(1.0, -0.04);
        assert_eq!(calibrated, wall_on_the_axis(1.04, 0.0));
        assert!(
            (calibrated - short - 0.04).abs() < 0.001,
            "calibrated wall at {calibrated} m, uncalibrated at {short} m"
        );
    }

    #[test]
    fn a_new_sweep_is_announced_before_its_first_reading_is_fused() {
        let mut engine = Engine::new(FusionConfig::default(), 100).unwrap();
        let r1 = reading(1, 0.0, 1.0);
        assert!(!engine.starts_new_sweep(&r1), "nothing fused yet");
        engine.fuse(&r1);
        assert!(!engine.starts_new_sweep(&reading(1, 6.0, 1.0)));
        assert!(engine.starts_new_sweep(&reading(2, 6.0, 1.0)));
    }

    /// A sweep closed on the head's word that it ended is closed once, where the next sweep's
    /// first reading would have closed it: the same maps, and the last sweep whole without a
    /// next reading.
    #[test]
    fn a_sweep_closed_on_its_end_makes_the_maps_of_one_closed_by_the_next_sweep() {
        let mut on_end = Engine::new(FusionConfig::default(), 1000).unwrap();
        let mut on_next = Engine::new(FusionConfig::default(), 1000).unwrap();
        let readings: Vec<Reading> = sweeps()
            .into_iter()
            .enumerate()
            .map(|(seq, r)| Reading {
                seq: seq as u64,
                ..r
            })
            .collect();
        let end_of = |sweep_id: u32| SweepEnd {
            sweep_id,
            last_seq: 50 * u64::from(sweep_id) - 1,
            ..SweepEnd::default()
        };
        for r in &readings {
            let closed = on_end.close_finished_sweep(r);
            assert_eq!(closed, None, "reading {}: closed on its end already", r.seq);
            if r.seq == 49 {
                assert_eq!(on_end.sweep_ended(&end_of(1)), SweepEndOutcome::Early);
            }
            on_end.fuse(r);
            if r.seq == 49 {
                assert_eq!(
                    on_end.sweep_ended(&end_of(1)),
                    SweepEndOutcome::Closed { changed: true }
                );
                assert_eq!(on_end.sweep_ended(&end_of(1)), SweepEndOutcome::Stale);
            }
            let closed = on_next.close_finished_sweep(r);
            assert_eq!(closed.is_some(), r.seq == 50, "reading {}", r.seq);
            on_next.fuse(r);
            if r.seq == 50 {
                assert_eq!(encoded(&mut on_end), encoded(&mut on_next));
            }
        }
        assert_eq!(on_end.sweep_ended(&end_of(1)), SweepEndOutcome::Stale);
        assert!(matches!(
            on_end.sweep_ended(&end_of(2)),
            SweepEndOutcome::Closed { .. }
        ));
        on_next.close_region();
        assert_eq!(encoded(&mut on_end), encoded(&mut on_next));
    }

    /// A new sweep's SLAM correction places the next reading; a revision or a correction that is
    /// not finite does not.
    #[test]
    fn a_new_sweep_s_slam_correction_places_the_readings_and_a_revision_does_not() {
        let mut engine = Engine::new(FusionConfig::default(), 100).unwrap();
        let estimate = |sweep_id, state, x| SlamCorrection {
            layout_version: LAYOUT_VERSION,
            sweep_id,
            state,
            correction_x_m: x,
            ..SlamCorrection::default()
        };
        let placed_x = |engine: &mut Engine| {
            engine.fuse(&reading(3, 0.0, 1.0));
            engine.pose().translation.x
        };
        let revised = engine.take_slam_correction(&estimate(1, slam_state::REVISED, 0.7));
        assert_eq!(
            revised.map(|(sweep, c)| (sweep, c.translation.x)),
            Some((1, 0.7))
        );
        assert_eq!(placed_x(&mut engine), 0.0);
        assert!(
            engine
                .take_slam_correction(&estimate(2, slam_state::FIX, f32::NAN))
                .is_none()
        );
        assert_eq!(placed_x(&mut engine), 0.0);
        let new = engine.take_slam_correction(&estimate(2, slam_state::UNCERTAIN, 0.5));
        assert_eq!(new.map(|(sweep, _)| sweep), Some(2));
        assert_eq!(placed_x(&mut engine), 0.5);
    }

    #[test]
    fn switching_the_preset_refuses_the_kept_readings() {
        let readings = sweeps();
        let mut live = Engine::new(FusionConfig::default(), 1000).unwrap();
        for r in &readings {
            live.fuse(r);
        }
        live.apply(&FusionCommand::new(
            FusionCommandKind::SetPreset,
            preset_code::PAPER,
        ))
        .unwrap();

        let mut fresh = Engine::new(FusionConfig::preset(Preset::Paper), 1000).unwrap();
        for r in &readings {
            fresh.fuse(r);
        }
        assert_eq!(encoded(&mut live), encoded(&mut fresh));
        let h = live.grid_header(1, 0, CellCounts::default());
        assert_eq!(h.preset, preset_code::PAPER);
        assert_eq!(h.model, model_code::PAPER);
        assert_eq!(h.rule, rule_code::BAYES);
        assert_eq!(h.readings_fused, readings.len() as u64);
    }

    /// The SLAM revises sweep 1, placed before its correction was known: the maps rebuilt in
    /// steps equal maps fused with that correction from the start.
    #[test]
    fn a_revised_sweep_is_fused_again_where_its_correction_places_it() {
        let readings = sweeps();
        let correction = Isometry2::new(nalgebra::Vector2::new(0.3, -0.2), 0.1);
        let mut live = Engine::new(FusionConfig::default(), 1000).unwrap();
        for r in &readings {
            if r.sweep_id == 2 {
                live.set_correction(correction);
            }
            live.fuse(r);
        }
        let mut right = Engine::new(FusionConfig::default(), 1000).unwrap();
        right.set_correction(correction);
        for r in &readings {
            // As the process does, and the rebuild after it: a sweep's last region of constant
            // depth is placed when the next sweep begins.
            right.close_finished_sweep(r);
            right.fuse(r);
        }
        assert_ne!(encoded(&mut live), encoded(&mut right));
        assert_eq!(live.revise(&[(1, correction)]), Revised::Rebuilding(50));
        let before = encoded(&mut live);
        let mut steps = 0;
        while !live.rebuild_step(32) {
            steps += 1;
            // The live maps stay as they were until the rebuilt ones replace them.
            assert_eq!(encoded(&mut live), before);
        }
        assert_eq!(steps, 3, "100 readings in steps of 32");
        assert!(!live.rebuilding());
        assert_eq!(encoded(&mut live), encoded(&mut right));
        assert_eq!(live.revise(&[(1, correction)]), Revised::Unmoved);
    }

    #[test]
    fn a_bounded_history_keeps_the_latest_readings() {
        let readings = sweeps();
        let mut engine = Engine::new(FusionConfig::default(), 50).unwrap();
        for r in &readings {
            engine.fuse(r);
        }
        engine
            .apply(&FusionCommand::new(
                FusionCommandKind::SetRule,
                rule_code::HIMM,
            ))
            .unwrap();
        let mut expected = Engine::new(
            FusionConfig {
                rule: RuleConfig::default_for(RuleKind::Himm),
                ..FusionConfig::default()
            },
            50,
        )
        .unwrap();
        for r in &readings[50..] {
            expected.fuse(r);
        }
        assert_eq!(encoded(&mut engine), encoded(&mut expected));
        let h = engine.grid_header(1, 0, CellCounts::default());
        assert_eq!(h.preset, preset_code::CUSTOM);
        assert_eq!(h.rule, rule_code::HIMM);
    }

    #[test]
    fn clear_forgets_maps_and_history() {
        let mut engine = Engine::new(FusionConfig::default(), 1000).unwrap();
        for r in &sweeps() {
            engine.fuse(r);
        }
        let before = encoded(&mut engine);
        assert!(before.iter().any(|&c| c != sonar_common::ipc::CELL_UNKNOWN));
        engine
            .apply(&FusionCommand::new(FusionCommandKind::Clear, 0))
            .unwrap();
        assert!(
            encoded(&mut engine)
                .iter()
                .all(|&c| c == sonar_common::ipc::CELL_UNKNOWN)
        );
        assert!(engine.radar(1, 0).distances_m.iter().all(|d| d.is_nan()));
        // With the history gone, a switch re-fuses nothing.
        engine
            .apply(&FusionCommand::new(
                FusionCommandKind::SetModel,
                model_code::LOG_ODDS,
            ))
            .unwrap();
        assert!(
            encoded(&mut engine)
                .iter()
                .all(|&c| c == sonar_common::ipc::CELL_UNKNOWN)
        );
    }

    #[test]
    fn bad_commands_change_nothing() {
        let mut engine = Engine::new(FusionConfig::default(), 1000).unwrap();
        for r in &sweeps() {
            engine.fuse(r);
        }
        let before = encoded(&mut engine);
        for (cmd, expected) in [
            (
                FusionCommand { kind: 99, value: 0 },
                CommandError::UnknownKind(99),
            ),
            (
                FusionCommand::new(FusionCommandKind::SetModel, 42),
                CommandError::UnknownCode {
                    what: "model",
                    code: 42,
                },
            ),
            (
                FusionCommand::new(FusionCommandKind::SetPreset, preset_code::CUSTOM),
                CommandError::UnknownCode {
                    what: "preset",
                    code: preset_code::CUSTOM,
                },
            ),
        ] {
            assert_eq!(engine.apply(&cmd), Err(expected));
        }
        assert_eq!(encoded(&mut engine), before);
    }

    #[test]
    fn readings_are_placed_at_the_pose_of_their_instant_and_bad_poses_are_refused() {
        let mut engine = Engine::new(FusionConfig::default(), 10).unwrap();
        let at = |stamp_ns, x_m| Pose2D {
            stamp_ns,
            x_m,
            y_m: -0.25,
            theta_rad: 0.3,
            ..Pose2D::default()
        };
        engine.set_pose(&at(1_000_000_000, 0.5)).unwrap();
        engine.set_pose(&at(1_200_000_000, 0.7)).unwrap();
        assert_eq!(
            engine.set_pose(&Pose2D {
                x_m: f32::NAN,
                ..at(1_300_000_000, 0.0)
            }),
            Err(PoseError::NotFinite)
        );
        let mut r = reading(1, 0.0, 1.0);
        r.host_stamp_ns = 1_100_000_000;
        engine.fuse(&r);
        let h = engine.grid_header(1, 0, CellCounts::default());
        assert!(
            (h.pose_x_m - 0.6).abs() < 1e-6 && h.pose_y_m == -0.25,
            "{h:?}"
        );
        assert!((h.pose_theta_rad - 0.3).abs() < 1e-6);
        assert_eq!(engine.stale_pose_readings(), 0);
        // A second after the latest pose: held there, and counted.
        r.host_stamp_ns = 2_200_000_000;
        engine.fuse(&r);
        assert_eq!(engine.pose().translation.x, 0.7);
        assert_eq!(engine.stale_pose_readings(), 1);
    }

    #[test]
    fn the_radar_snapshot_carries_the_latest_distance_per_bin() {
        let mut engine = Engine::new(FusionConfig::default(), 10).unwrap();
        engine.fuse(&reading(1, 3.0, 1.5));
        let mut no_echo = reading(1, 9.0, 0.0);
        no_echo.flags = flags::NO_ECHO;
        engine.fuse(&no_echo);
        let radar = engine.radar(7, 0);
        assert_eq!(radar.bin_count, 60);
        let bin = |deg: f32| ((deg - radar.first_bin_deg) / radar.bin_width_deg).round() as usize;
        assert_eq!(radar.distances_m[bin(3.0)], 1.5);
        assert_eq!(radar.distances_m[bin(9.0)], f32::INFINITY);
        assert!(radar.distances_m[bin(-3.0)].is_nan());
        assert_eq!(radar.current_angle_deg, 9.0);
        assert_eq!((radar.seq, radar.sweep_id, radar.direction), (7, 1, 1));
    }
}
