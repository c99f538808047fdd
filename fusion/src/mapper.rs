//! The engine a fusion process drives: one configuration, its probability grid and radar array.

use std::collections::VecDeque;
use std::fmt;

use nalgebra::{Isometry2, Vector2};

use crate::config::{ConfigError, FusionConfig};
use crate::drawn::DrawnStretches;
use crate::geometry::GridGeometry;
use crate::geometry::{Boxes, incidence, sector_box, wrap_angle};
use crate::grid::{Above, OccupancyGrid, SquaresAbove, with_layer};
use crate::hidden::{self, Hiding, Sight};
use crate::kernel::ConeCache;
use crate::lines::{self, Echo, Lines, Patch, Stretch};
use crate::model::{CellEvidence, ModelConfig, SmoothModel, with_model};
use crate::observation::{Beam, Observation, ObservationError};
use crate::points::{self, Points};
use crate::radar::RadarMap;
use crate::reference::PaperArrays;
use crate::regions::{DepthTolerance, End, Heard, LobeWidth, Region, RegionTracker};
use crate::sightlines::{Lobe, Sightline, Sightlines};
use crate::state::{MapperState, StateError};

/// One-ended and cut regions kept for the sweep's end at most: more than a 360° sweep at 1.5° holds.
const DEFERRED_REGIONS: usize = 256;
/// With `region_weak_echo_withdrawn`: the weak echoes kept to be taken back, the latest this many
/// (a 300° sweep at 1.5° has 200 readings; this holds the weak echoes of many sweeps), those
/// looking at the same cells kept together ([`WeakEchoes`]).
const WEAK_ECHOES_KEPT: usize = 4096;
/// With `region_weak_echo_withdrawn`: a weak echo is taken back for a cell in front of it only
/// when that cell is more than a few weak echoes (0.3 each) would make it: a wall placed by a
/// region or a stretch. With any occupied cell (p > 0.5), on the suite's tune split `srf05` lost
/// 0.03 of recall at 8 viewpoints and 0.01 from one (docs/fusion.md).
const WITHDRAW_ABOVE: f32 = 0.9;
/// … and only when that cell was heard from a bearing this far off the weak echo's axis: the
/// SRF05's specular cut-off, beyond which the wall could not have answered the reading.
const WITHDRAW_INCIDENCE_DEG: f32 = 28.0;

/// With `region_stretch_withdrawn_at_feet`: a drawn stretch is taken back this far each side of
/// a refuting reading's foot, metres (about the spot a wall square to the reading would have
/// answered from) …
const REFUTED_AROUND_FOOT_M: f32 = 0.1;
/// … and what is left of it drawn again in parts at least this long, metres.
const SHORTEST_PART_M: f32 = 0.05;

/// Stretches of wall are drawn in pieces at most this long, metres.
const STRETCH_PIECE_M: f32 = 1.0;
/// With `region_corner_walls_seen`: the viewpoints kept to see walls drawn on from, the latest
/// this many, each at least [`VIEWPOINTS_APART_M`] from the others.
const VIEWPOINTS_KEPT: usize = 32;
const VIEWPOINTS_APART_M: f32 = 0.25;

/// A box (lower and upper corners, world metres) holding the axis from `position` along `axis`
/// to `range`, and `margin` round it.
fn axis_box(
    position: Vector2<f32>,
    axis: f32,
    range: f32,
    margin: f32,
) -> (Vector2<f32>, Vector2<f32>) {
    let end = position + Vector2::new(axis.cos(), axis.sin()) * range;
    let margin = Vector2::repeat(margin);
    (position.inf(&end) - margin, position.sup(&end) + margin)
}

/// Every number from 0 to `last`, once each, the nearest to `last / 2` first.
fn from_the_middle(last: usize) -> impl Iterator<Item = usize> {
    let middle = last / 2;
    (0..=last - middle).flat_map(move |d| {
        let below = (d > 0).then(|| middle.checked_sub(d)).flatten();
        std::iter::once(middle + d).chain(below)
    })
}

/// Which kernel fuses a reading into the grid. Both give the same grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Kernel {
    /// Only the cells of the cone (see [`crate::kernel`]).
    #[default]
    Cone,
    /// The paper's pass over the whole grid (see [`crate::reference`]): for tests and benchmarks.
    WholeGrid,
}

/// What one reading changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Update {
    /// The radar bin it went into, if a bin covers its angle.
    pub radar_bin: Option<usize>,
    /// Grid cells it updated.
    pub cells_updated: usize,
}

/// Both of the paper's maps, fed reading by reading.
pub struct Mapper {
    config: FusionConfig,
    grid: OccupancyGrid,
    /// Occupied (p > 0.5) and [`WITHDRAW_ABOVE`] as thresholds on the grid's cell keys: the walks
    /// along readings' axes test thousands of cells a sweep without a probability each.
    above_half: Above,
    above_withdraw: Above,
    radar: RadarMap,
    cones: ConeCache,
    paper_arrays: PaperArrays,
    readings: u64,
    pose: Isometry2<f32>,
    /// With echoes placed by region: the tolerance of a region's depth, and the open region.
    regions: Option<Regions>,
    /// With `region_weak_echo_explained`: the boxes (lower and upper corners, world metres) of
    /// the walls drawn since the weak echoes were last looked at, where a weak echo looked at
    /// before can have become explained ([`Mapper::withdraw_weak_echoes`]).
    walls_drawn: Boxes,
}

/// With echoes placed by region: the tracker, and the readings of the open region, whose free
/// evidence waits for it to close, since only the readings of a whole region may clear space.
#[derive(Debug)]
struct Regions {
    tolerance: DepthTolerance,
    tracker: RegionTracker,
    waiting: Vec<Beam>,
    /// The patches placed, for the walls between them ([`crate::lines`]).
    lines: Lines,
    /// With `region_points`: the whole regions' patches drawn, to tell points from walls.
    points: Points,
    /// With `region_corner_walls_seen`: where whole regions were heard from, the latest
    /// [`VIEWPOINTS_KEPT`], each at least [`VIEWPOINTS_APART_M`] from the others.
    viewpoints: VecDeque<Vector2<f32>>,
    stretches: Vec<Stretch>,
    /// The lobe's half-width by range, learnt from the whole regions.
    lobe: LobeWidth,
    /// With a stretch's foot check on: the latest readings with an echo, which may refute a
    /// stretch of wall ([`crate::sightlines`]).
    sightlines: Sightlines,
    /// With a stretch's foot check on: the stretches of that kind drawn, newest last, at most
    /// [`crate::drawn::KEPT`], each taken back if a later reading refutes it.
    drawn: DrawnStretches,
    /// With `region_one_end`: the sweep's one-ended regions, placed at its end, each with its
    /// readings (with `region_one_end_free`, else none).
    one_ended: Vec<(Region, Vec<Beam>)>,
    /// With `region_corners`: the sweep's regions cut short on both sides, placed at its end.
    cut: Vec<Region>,
    /// With `region_weak_echo_withdrawn`: the weak echoes placed and not yet taken back.
    weak: WeakEchoes,
    /// Whether a region, a corner or a stretch placed occupied evidence since the weak echoes
    /// were last looked at: only such walls can withdraw one ([`WITHDRAW_ABOVE`]).
    walls_placed: bool,
    /// With `region_hidden_unknown`: where the sensor stood and what it heard, to tell the cells
    /// no viewpoint could have heard.
    hiding: Option<Hiding>,
    /// The region closed last: what cut short the next one's start, if it did.
    previous: Option<Region>,
    /// With `region_small_cutters_free`: the readings of a region cut short on both sides, the
    /// first cutter small, waiting for the region after it (the second cutter) to close.
    between: Option<Between>,
}

/// The grid as [`Hiding::hidden_cells`] sees it.
struct GridSight<'a> {
    grid: &'a OccupancyGrid,
    hiding_above: Above,
    model: &'a SmoothModel,
}

impl Sight for GridSight<'_> {
    fn hides(&self, index: usize) -> bool {
        let n = self.grid.geometry().cells_per_side();
        self.grid.is_above(index % n, index / n, self.hiding_above)
    }

    fn own_normal(&self, index: usize) -> Option<Vector2<f32>> {
        let n = self.grid.geometry().cells_per_side();
        self.grid
            .heard_from(index % n, index / n)
            .map(|bearing| Vector2::new(bearing.cos(), bearing.sin()))
    }

    fn near_line(&self, distance: f32) -> f32 {
        2.0 * self.model.band(distance)
    }
}

/// With `region_weak_echo_withdrawn`: the weak echoes placed and not yet taken back, those that
/// look at the same cells for a wall in front of them ([`Mapper::slanted_wall_in_front`]) kept
/// together, so that each such set is looked at once. A head standing still places the same weak
/// echoes sweep after sweep: kept apart, every sweep's end that placed a wall looked at all of
/// them again, up to 4096 (issue 29).
#[derive(Debug, Default)]
struct WeakEchoes {
    /// Oldest first, at most [`WEAK_ECHOES_KEPT`].
    kept: VecDeque<LookedAtTogether>,
    /// Whether some weak echo was kept since they were last looked at for withdrawal.
    unchecked: bool,
}

/// Weak echoes from one sensor position along one axis, as far in front of their echoes: the
/// same cells in front of them, so the same answer to whether a wall lies there.
#[derive(Debug)]
struct LookedAtTogether {
    /// How many cells in front of their echoes are looked at ([`Mapper::cells_in_front`]).
    steps: usize,
    /// Each beam once, oldest first, at most [`SAME_WEAK_ECHOES_KEPT`].
    placed: VecDeque<Placed>,
}

/// A weak echo's beam, and how many readings placed it: all of them, and those not yet looked at
/// for withdrawal.
#[derive(Debug)]
struct Placed {
    beam: Beam,
    heard: u32,
    unchecked: u32,
}

/// Distinct beams kept in one [`LookedAtTogether`]: a head standing still hears one range, or a
/// few within its noise, again and again.
const SAME_WEAK_ECHOES_KEPT: usize = 64;

impl WeakEchoes {
    /// Keeps the weak echo of `beam`, looking at `steps` cells in front of its echo: with those
    /// from its sensor position along its axis looking at as many, counting one more hearing of
    /// the same beam; else as the newest, the oldest forgotten first.
    fn keep(&mut self, beam: Beam, steps: usize) {
        self.unchecked = true;
        let same_cells = self.kept.iter().rposition(|kept| {
            let first = &kept.placed[0].beam;
            kept.steps == steps && first.position == beam.position && first.axis == beam.axis
        });
        let index = match same_cells {
            Some(index) => index,
            None => {
                if self.kept.len() >= WEAK_ECHOES_KEPT {
                    self.kept.pop_front();
                }
                self.kept.push_back(LookedAtTogether {
                    steps,
                    placed: VecDeque::new(),
                });
                self.kept.len() - 1
            }
        };
        let together = &mut self.kept[index];
        if let Some(same) = together.placed.iter_mut().find(|p| p.beam == beam) {
            same.heard = same.heard.saturating_add(1);
            same.unchecked = same.unchecked.saturating_add(1);
            return;
        }
        if together.placed.len() >= SAME_WEAK_ECHOES_KEPT {
            together.placed.pop_front();
        }
        together.placed.push_back(Placed {
            beam,
            heard: 1,
            unchecked: 1,
        });
    }
}

/// Which stretches of wall [`Lines`] wrote: those between two patches of one wall, or those
/// from a patch on to where its wall ends ([`Lines::join_ends`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stretches {
    BetweenFeet,
    ToEnds,
}

/// A region cut short on both sides whose free evidence waits for its second cutter.
#[derive(Debug)]
struct Between {
    region: Region,
    readings: Vec<Beam>,
}

impl Regions {
    /// Keeps `stretch`, just drawn and checked against every reading kept, to be taken back if
    /// a later reading refutes it ([`DrawnStretches::keep`]).
    fn keep_drawn(&mut self, stretch: Stretch) {
        self.drawn.keep(stretch, self.sightlines.pushed());
    }

    /// Whether `region` is a small reflector's ([`Region::is_small`]), measured against the
    /// lobe over which the sensor hears a wall met squarely: the widest learnt
    /// ([`LobeWidth::widest`]), else the sensor's beam half-angle `beam` less half a reading step.
    fn is_small(&self, region: &Region, beam: f32) -> bool {
        region.is_small(
            self.lobe
                .widest()
                .unwrap_or_else(|| region.prior_lobe(beam)),
        )
    }

    /// The lobe's half-width at `region`'s range: learnt from the whole regions there, else the
    /// sensor's beam half-angle `beam` less half a reading step.
    fn lobe_of(&self, region: &Region, beam: f32) -> f32 {
        self.lobe
            .at(region.range)
            .unwrap_or_else(|| region.prior_lobe(beam))
    }
}

impl fmt::Debug for Mapper {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Mapper")
            .field("config", &self.config)
            .field("readings", &self.readings)
            .field("pose", &self.pose)
            .finish_non_exhaustive()
    }
}

impl Mapper {
    /// Empty maps for `config`, once it validates.
    pub fn new(config: FusionConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        let geometry = GridGeometry::centred_at(
            config.grid.cells as usize,
            config.grid.resolution_m,
            Vector2::new(config.grid.centre_x_m, config.grid.centre_y_m),
        );
        let grid = OccupancyGrid::new(geometry, &config.rule, config.model.hears());
        Ok(Self {
            above_half: grid.above(0.5),
            above_withdraw: grid.above(WITHDRAW_ABOVE),
            grid,
            radar: RadarMap::new(config.radar)?,
            cones: ConeCache::new(&config),
            paper_arrays: PaperArrays::default(),
            readings: 0,
            pose: Isometry2::identity(),
            walls_drawn: Boxes::default(),
            regions: match &config.model {
                ModelConfig::Smooth(m) => m.regions().map(|tolerance| Regions {
                    tolerance,
                    tracker: RegionTracker::default(),
                    waiting: Vec::new(),
                    lines: Lines::new(m.region_lines_through_feet),
                    points: Points::default(),
                    viewpoints: VecDeque::new(),
                    stretches: Vec::new(),
                    lobe: LobeWidth::default(),
                    sightlines: Sightlines::default(),
                    drawn: DrawnStretches::default(),
                    one_ended: Vec::new(),
                    cut: Vec::new(),
                    weak: WeakEchoes::default(),
                    walls_placed: false,
                    hiding: m.region_hidden_unknown.then(|| Hiding::new(&geometry)),
                    previous: None,
                    between: None,
                }),
                _ => None,
            },
            config,
        })
    }

    pub fn config(&self) -> &FusionConfig {
        &self.config
    }

    /// The probability method's grid.
    pub fn grid(&self) -> &OccupancyGrid {
        &self.grid
    }

    /// The grid, to bring its snapshot encoding up to date ([`OccupancyGrid::encoded`]).
    pub fn grid_mut(&mut self) -> &mut OccupancyGrid {
        &mut self.grid
    }

    /// The basic method's array.
    pub fn radar(&self) -> &RadarMap {
        &self.radar
    }

    /// Readings fused since the maps were last cleared.
    pub fn readings_fused(&self) -> u64 {
        self.readings
    }

    /// Sensor pose of the last reading fused.
    pub fn last_pose(&self) -> Isometry2<f32> {
        self.pose
    }

    /// Fuses one reading into both maps with the fast kernel.
    pub fn update(&mut self, obs: &Observation) -> Result<Update, ObservationError> {
        self.update_with(obs, Kernel::Cone)
    }

    /// Fuses one reading into both maps with the chosen kernel.
    pub fn update_with(
        &mut self,
        obs: &Observation,
        kernel: Kernel,
    ) -> Result<Update, ObservationError> {
        let beam = Beam::new(
            obs,
            self.config.sensor.limits(),
            self.config.clear_on_no_echo,
        )?;
        let radar_bin = self.radar.record(obs);
        self.readings += 1;
        self.pose = obs.pose;
        let mut cells_updated = 0;
        if let Some(mut regions) = self.regions.take() {
            self.note_for_hiding(&mut regions, obs, beam.as_ref());
            let heard = Heard {
                position: obs.pose.translation.vector,
                axis: wrap_angle(obs.pose.rotation.angle() + obs.angle_rad),
                range: beam.and_then(|b| b.echo),
                rejected: obs.rejected_echo_m,
            };
            if let ModelConfig::Smooth(model) = self.config.model
                && (model.region_stretch_foot_check || model.region_corner_walls_foot_check)
                && let Some(range) = heard.range
            {
                regions.sightlines.push(Sightline {
                    position: heard.position,
                    axis: heard.axis,
                    range,
                });
            }
            // A region this reading closes is placed first: it lies before this reading.
            if let Some(region) = regions.tracker.push(&heard, &regions.tolerance) {
                cells_updated += self.close(&mut regions, &region, kernel);
            }
            // A reading with an echo waits for its region to close.
            let waits = beam.filter(|b| b.echo.is_some());
            regions.waiting.extend(waits);
            self.regions = Some(regions);
            if waits.is_some() {
                return Ok(Update {
                    radar_bin,
                    cells_updated,
                });
            }
        }
        if let Some(beam) = beam {
            cells_updated += self.fuse_beam(&beam, kernel);
        }
        Ok(Update {
            radar_bin,
            cells_updated,
        })
    }

    /// With `region_hidden_unknown`: notes where `obs` was taken from and, if its `beam` has an
    /// echo, what it heard.
    fn note_for_hiding(&self, regions: &mut Regions, obs: &Observation, beam: Option<&Beam>) {
        if let (Some(hiding), ModelConfig::Smooth(model)) = (&mut regions.hiding, self.config.model)
        {
            let echo = beam
                .and_then(|b| b.echo)
                .map(|range| (range, model.band(range)));
            hiding.note_reading(
                self.grid.geometry(),
                obs.pose.translation.vector,
                wrap_angle(obs.pose.rotation.angle() + obs.angle_rad),
                echo,
            );
        }
    }

    /// Notes the readings behind a restored map (those kept of them) as if fused, without fusing
    /// them: with `region_hidden_unknown`, where the sensor stood and what it heard, so that the
    /// next look hides nothing those readings saw.
    pub(crate) fn remember_readings<'a>(
        &mut self,
        observations: impl Iterator<Item = &'a Observation>,
    ) {
        let Some(mut regions) = self.regions.take() else {
            return;
        };
        if regions.hiding.is_some() {
            for obs in observations {
                // The maps' own readings, which were placed: a beam that does not build now did
                // not then either.
                let beam = Beam::new(
                    obs,
                    self.config.sensor.limits(),
                    self.config.clear_on_no_echo,
                )
                .ok()
                .flatten();
                self.note_for_hiding(&mut regions, obs, beam.as_ref());
            }
        }
        self.regions = Some(regions);
    }

    /// Fuses one reading's beam with the model's evidence.
    fn fuse_beam(&mut self, beam: &Beam, kernel: Kernel) -> usize {
        let model = self.config.model;
        with_model!(&model, m => self.apply(beam, &m.reading(beam), kernel))
    }

    /// Fuses `evidence` seen along `beam` with the chosen kernel.
    fn apply<E: CellEvidence>(&mut self, beam: &Beam, evidence: &E, kernel: Kernel) -> usize {
        let (geometry, store, heard) = self.grid.parts_mut();
        let (cones, arrays) = (&mut self.cones, &mut self.paper_arrays);
        with_layer!(store, layer => match kernel {
            Kernel::Cone => cones.update(layer, heard, geometry, beam, evidence),
            Kernel::WholeGrid => arrays.update(layer, heard, geometry, beam, evidence),
        })
    }

    /// Places a closed region, if whole, and the free evidence of the readings waiting for it
    /// (with `region_masked_free`, of a region cut short on both sides, up to the nearer of the
    /// echoes that cut it);
    /// they are forgotten either way. A one-ended region (`region_one_end`) and one cut short on
    /// both sides (`region_corners`) wait for the sweep's end, when the lobe has been learnt from
    /// the whole sweep and the walls beside a corner placed ([`Self::close_region`]).
    fn close(&mut self, regions: &mut Regions, region: &Region, kernel: Kernel) -> usize {
        let ModelConfig::Smooth(model) = self.config.model else {
            return 0;
        };
        regions.lobe.learn(region);
        let mut cells = 0;
        // This region cut short the one waiting before it on its far side: if it too is a small
        // reflector's, that one's readings passed beside two.
        if let Some(between) = regions.between.take() {
            let beam = self.config.sensor.limits().half_angle;
            let beside_small = regions.is_small(region, beam);
            cells += self.clear_masked(
                regions.tolerance,
                &between.region,
                &between.readings,
                beside_small,
                kernel,
            );
        }
        if model.region_corner_walls {
            regions.lines.hear(Echo {
                sensor: region.position,
                axis: region.axis,
                half_width: region.half_width,
                range: region.range,
                tolerance: model.depth_and_band(regions.tolerance, region.range),
                whole: region.is_whole(),
                masked: region.ends == [End::Occluded; 2],
            });
        }
        if region.is_whole() {
            let half_angle = model.region_patch_half_angle(region.half_width, region.range);
            cells += self.place_region(regions, region, region.axis, half_angle, kernel);
            for beam in &regions.waiting {
                cells += self.fuse_beam(beam, kernel);
            }
        } else {
            // The readings of a region not whole may have heard something off their axes.
            if model.region_weak_echo_log_odds > 0.0 {
                cells += self.place_weak_echoes(regions, region, &model, kernel);
            }
            if model.region_masked_free && region.ends == [End::Occluded; 2] {
                let beam = self.config.sensor.limits().half_angle;
                let first_small = regions
                    .previous
                    .is_some_and(|previous| regions.is_small(&previous, beam));
                if model.region_small_cutters_free && first_small {
                    // Its second cutter is the region the next reading opened.
                    regions.between = Some(Between {
                        region: *region,
                        readings: regions.waiting.clone(),
                    });
                } else {
                    cells += self.clear_masked(
                        regions.tolerance,
                        region,
                        &regions.waiting,
                        false,
                        kernel,
                    );
                }
            }
            if model.region_one_end && region.is_one_ended() {
                let readings = if model.region_one_end_free {
                    regions.waiting.clone()
                } else {
                    Vec::new()
                };
                regions.one_ended.push((*region, readings));
            } else if model.region_corners && !region.ends.contains(&End::Natural) {
                regions.cut.push(*region);
            }
        }
        regions.waiting.clear();
        regions.previous = Some(*region);
        // A head whose sweeps are never told apart still places them, a sweep's worth at a time.
        if regions.one_ended.len() + regions.cut.len() >= DEFERRED_REGIONS {
            cells += self.place_one_ended(regions, kernel);
            cells += self.place_corners(regions, kernel);
        }
        cells
    }

    /// Clears the axes of `readings`, the readings of `region`, cut short on both sides
    /// (`region_masked_free`): up to the nearer of the echoes that cut it less its depth
    /// tolerance, or, when both cutters are small reflectors' (`beside_small`,
    /// `region_small_cutters_free`), up to each reading's own range less its tolerance; the
    /// model's band comes off either, as for any echo.
    fn clear_masked(
        &mut self,
        tolerance: DepthTolerance,
        region: &Region,
        readings: &[Beam],
        beside_small: bool,
        kernel: Kernel,
    ) -> usize {
        let masking = region.masking_range();
        let mut cells = 0;
        for beam in readings {
            let Some(reach) = (if beside_small { beam.echo } else { masking }) else {
                continue;
            };
            let cleared = Beam {
                echo: Some(reach - tolerance.at(reach)),
                ..*beam
            };
            cells += self.fuse_beam(&cleared, kernel);
        }
        cells
    }

    /// Places the weak echoes of `region`'s readings (a region not whole): each on its own axis,
    /// unless the grid already holds an occupied cell in front of it on that axis (what the axis
    /// met would have answered nearer); with `region_weak_echo_at_reflector`, those of a region
    /// heard to stop on one side and cut short by a nearer echo on the other on the bearing its
    /// reflector was heard from ([`Region::cut_short_axis`]), which no reading's axis met.
    fn place_weak_echoes(
        &mut self,
        regions: &mut Regions,
        region: &Region,
        model: &SmoothModel,
        kernel: Kernel,
    ) -> usize {
        // Only with a lobe learnt at some range: the sensor's configured beam is no measure of
        // where its echoes fade.
        let reflector = model
            .region_weak_echo_at_reflector
            .then(|| regions.lobe.at(region.range))
            .flatten()
            .and_then(|lobe| region.cut_short_axis(lobe));
        let mut cells = 0;
        for beam in &regions.waiting {
            let beam = reflector.map_or(*beam, |axis| Beam { axis, ..*beam });
            if reflector.is_some() || !self.occupied_in_front(model, &beam) {
                let echo = model.weak_echo(&beam, model.region_weak_echo_log_odds);
                cells += self.apply(&beam, &echo, kernel);
                if model.region_weak_echo_withdrawn {
                    regions.weak.keep(beam, self.steps_in_front(model, &beam));
                }
            }
        }
        cells
    }

    /// Places the one-ended regions of the sweep one lobe half-width in from their natural ends
    /// (the lobe learnt at their range, else the sensor's beam half-angle), on a patch half a
    /// lobe wide each side.
    fn place_one_ended(&mut self, regions: &mut Regions, kernel: Kernel) -> usize {
        let ModelConfig::Smooth(model) = self.config.model else {
            return 0;
        };
        let beam = self.config.sensor.limits().half_angle;
        let mut cells = 0;
        for (region, readings) in std::mem::take(&mut regions.one_ended) {
            let lobe = regions.lobe_of(&region, beam);
            if let Some(placed) = region.one_ended_axis(lobe) {
                // Half the lobe each side: the foot is known to a reading's step at best, and
                // on the suite's tune split a patch as wide as the lobe cost `srf05` 0.06 of
                // precision at 8 viewpoints for no recall (docs/fusion.md). A quarter when it
                // lies beyond the readings: none of them tells where the wall goes on.
                let share = if placed.reached { 0.5 } else { 0.25 };
                let half_angle = model.region_patch_half_angle(share * lobe, region.range);
                cells += self.place_region(regions, &region, placed.axis, half_angle, kernel);
                // Placed, its readings heard that reflector as a whole region's do theirs.
                for beam in &readings {
                    cells += self.fuse_beam(beam, kernel);
                }
            }
        }
        cells
    }

    /// With echoes placed by region (`echo_placement = "region"`), places the open region's
    /// evidence now instead of when the next reading closes it: at the end of a sweep, or before
    /// the map is read when no more readings follow. Returns the cells it updated.
    pub fn close_region(&mut self) -> usize {
        let Some(mut regions) = self.regions.take() else {
            return 0;
        };
        let mut cells = match regions.tracker.close() {
            Some(region) => self.close(&mut regions, &region, Kernel::Cone),
            None => 0,
        };
        cells += self.place_one_ended(&mut regions, Kernel::Cone);
        cells += self.place_corners(&mut regions, Kernel::Cone);
        cells += self.redraw_corner_points(&mut regions, Kernel::Cone);
        if let ModelConfig::Smooth(model) = self.config.model
            && model.region_corner_walls
        {
            let viewpoints = &regions.viewpoints;
            let seen = |sensor: Vector2<f32>, stretch: &Stretch, out: &mut Vec<Stretch>| {
                if model.region_corner_walls_seen {
                    self.seen_parts(&model, sensor, viewpoints, stretch, out);
                } else {
                    out.push(*stretch);
                }
            };
            regions.lines.join_ends(
                model.region_corner_walls_confirmed,
                seen,
                &mut regions.stretches,
            );
            regions.walls_placed |= !regions.stretches.is_empty();
            cells += self.place_stretches(&model, &mut regions, Stretches::ToEnds, Kernel::Cone);
        }
        cells += self.withdraw_refuted_stretches(&mut regions, Kernel::Cone);
        cells += self.withdraw_weak_echoes(&mut regions, Kernel::Cone);
        cells += self.forget_hidden(&mut regions);
        self.regions = Some(regions);
        cells
    }

    /// With `region_hidden_unknown`, when a look is due ([`Hiding::due`]): sets the occupied
    /// cells no viewpoint could have heard back to unknown ([`crate::hidden`]). Returns how many.
    fn forget_hidden(&mut self, regions: &mut Regions) -> usize {
        let (ModelConfig::Smooth(model), Some(hiding)) = (self.config.model, &mut regions.hiding)
        else {
            return 0;
        };
        if !hiding.due(self.readings) {
            return 0;
        }
        let mut occupied = Vec::new();
        self.grid.occupied_cells_into(&mut occupied);
        let sight = GridSight {
            grid: &self.grid,
            hiding_above: self.grid.above(hidden::HIDING_ABOVE),
            model: &model,
        };
        let mut out = Vec::new();
        hiding.hidden_cells(
            self.grid.geometry(),
            self.config.sensor.limits().max_range,
            model.region_hidden_behind_walls,
            &occupied,
            &sight,
            &mut out,
        );
        self.grid.forget_cells(&out);
        out.len()
    }

    /// Takes back the weak echoes with an occupied cell on their axis in front of them: a wall
    /// drawn since that the axis would have met first, so the echo came from off the axis, behind
    /// it. Their log-odds are subtracted; the bearing their cells remember stays.
    fn withdraw_weak_echoes(&mut self, regions: &mut Regions, kernel: Kernel) -> usize {
        let ModelConfig::Smooth(model) = self.config.model else {
            return 0;
        };
        // A cell above WITHDRAW_ABOVE is more than weak echoes make: unless a wall was placed
        // since the last look, only the weak echoes added since can find one in front of them
        // (a head whose sweeps are never told apart ends a sweep every reading or two).
        let all = std::mem::take(&mut regions.walls_placed);
        let unchecked = std::mem::take(&mut regions.weak.unchecked);
        if !all && !unchecked {
            return 0;
        }
        let mut cells = 0;
        // The lobe within which a reflector may have answered: the widest learnt, else the beam.
        let lobe = regions
            .lobe
            .widest_learnt()
            .unwrap_or(self.config.sensor.limits().half_angle);
        let tolerance = regions.tolerance;
        let walls_drawn = std::mem::take(&mut self.walls_drawn);
        let cell = self.grid.geometry().resolution();
        // Taken when first needed, and again after a withdrawal has changed the grid.
        let mut squares: Option<SquaresAbove> = None;
        regions.weak.kept.retain_mut(|together| {
            let looked_at = |p: &Placed| if all { p.heard } else { p.unchecked };
            let beam = &together.placed[0].beam;
            let new = together.placed.iter().any(|p| p.unchecked > 0);
            let drawn_in = |area| walls_drawn.any_meets(area);
            // A set looked at before can have become withdrawable only where a wall was drawn
            // since (a cell above WITHDRAW_ABOVE is a drawn wall's, readings placed by region
            // carrying no occupied evidence, or eight weak echoes' stacked, left out here); the
            // scans of its lobe and of its axis are the costly part (a moving robot keeps
            // thousands). The walls drawn are noted only with `region_weak_echo_explained`.
            let explainable = || {
                new || beam.echo.is_some_and(|range| {
                    let depth = model.depth_and_band(tolerance, range);
                    drawn_in(sector_box(beam.position, beam.axis, range, lobe, depth))
                })
            };
            let slanted_in_front_possible = || {
                new || !model.region_weak_echo_explained
                    || beam.echo.is_none_or(|range| {
                        drawn_in(axis_box(beam.position, beam.axis, range, cell))
                    })
            };
            let mut slanted_in_front = || {
                let squares = squares
                    .get_or_insert_with(|| SquaresAbove::new(&self.grid, self.above_withdraw));
                self.slanted_wall_in_front(&model, beam, squares)
            };
            let withdrawn = together.placed.iter().any(|p| looked_at(p) > 0)
                && ((slanted_in_front_possible() && slanted_in_front())
                    || (model.region_weak_echo_explained
                        && explainable()
                        && self.explained_off_axis(&model, lobe, tolerance, beam)));
            if withdrawn {
                squares = None;
            }
            for placed in &mut together.placed {
                if withdrawn {
                    // Log-odds add: one weak echo as strong as its hearings stands for them.
                    let hearings = looked_at(placed);
                    if hearings > 0 {
                        let log_odds = model.region_weak_echo_log_odds * hearings as f32;
                        let echo = model.weak_echo(&placed.beam, -log_odds);
                        cells += self.apply(&placed.beam, &echo, kernel);
                        placed.heard -= hearings;
                    }
                }
                placed.unchecked = 0;
            }
            together.placed.retain(|p| p.heard > 0);
            !together.placed.is_empty()
        });
        cells
    }

    /// Places the sweep's regions cut short on both sides, narrower than the lobe, where two
    /// walls heard so far meet at their middle bearing and range (within the occupied band and the
    /// regions' depth tolerance): a corner masked by its walls' nearer feet, placed as a point.
    fn place_corners(&mut self, regions: &mut Regions, kernel: Kernel) -> usize {
        let ModelConfig::Smooth(model) = self.config.model else {
            return 0;
        };
        let beam = self.config.sensor.limits().half_angle;
        let mut cells = 0;
        for region in std::mem::take(&mut regions.cut) {
            let lobe = regions.lobe_of(&region, beam);
            let point =
                region.position + Vector2::new(region.axis.cos(), region.axis.sin()) * region.range;
            let tolerance = model.depth_and_band(regions.tolerance, region.range);
            if region.is_cut_and_narrow(lobe) && regions.lines.corner_at(point, tolerance) {
                // A point: a cell wide.
                let half_angle = (self.grid.geometry().resolution() / region.range).atan();
                let point = points::Drawn {
                    position: region.position,
                    axis: region.axis,
                    range: region.range,
                    half_angle,
                    readings: region.readings as f32,
                    point: true,
                    step: region.turn.abs(),
                };
                cells += self.fuse_patch(&model, &point, 1.0, kernel);
                regions.walls_placed = true;
            }
        }
        cells
    }

    /// Fuses a closed region's occupied evidence: a straight patch square to its reflector's
    /// bearing `axis` at its range, `half_angle` wide each side; then the stretches of wall between
    /// it and the patches other viewpoints placed on its line.
    fn place_region(
        &mut self,
        regions: &mut Regions,
        region: &Region,
        axis: f32,
        half_angle: f32,
        kernel: Kernel,
    ) -> usize {
        let ModelConfig::Smooth(model) = self.config.model else {
            return 0;
        };
        let drawn = points::Drawn {
            position: region.position,
            axis,
            range: region.range,
            half_angle,
            readings: region.readings as f32,
            point: false,
            step: region.turn.abs(),
        };
        let found = if model.region_points {
            let tolerance = model.depth_and_band(regions.tolerance, region.range);
            regions.points.add(drawn, tolerance)
        } else {
            points::Found::default()
        };
        let mut cells = 0;
        for kept in &found.became_points {
            cells += self.redraw_as_point(&model, regions, kept, kernel);
        }
        regions.walls_placed = true;
        if found.point {
            return cells + self.fuse_patch(&model, &self.as_point(&drawn), 1.0, kernel);
        }
        cells += self.fuse_patch(&model, &drawn, 1.0, kernel);
        if model.region_corner_walls_seen
            && !regions
                .viewpoints
                .iter()
                .any(|v| (v - region.position).norm() < VIEWPOINTS_APART_M)
        {
            if regions.viewpoints.len() >= VIEWPOINTS_KEPT {
                regions.viewpoints.pop_front();
            }
            regions.viewpoints.push_back(region.position);
        }
        let patch = Patch::new(region.position, axis, region.range, half_angle);
        // A region not whole is placed only when one-ended (`place_one_ended`).
        let patch = if region.is_whole() {
            patch
        } else {
            patch.needing_confirmation()
        };
        regions.lines.add(patch, &mut regions.stretches);
        cells + self.place_stretches(&model, regions, Stretches::BetweenFeet, kernel)
    }

    /// With `region_corner_points`: draws again as points the whole regions' patches drawn since
    /// the last sweep's end whose reflectors lie where two other walls heard meet, taking their
    /// patches back and forgetting them as walls.
    fn redraw_corner_points(&mut self, regions: &mut Regions, kernel: Kernel) -> usize {
        let ModelConfig::Smooth(model) = self.config.model else {
            return 0;
        };
        if !(model.region_corner_points && model.region_points && model.region_corner_walls) {
            return 0;
        }
        let tolerance = regions.tolerance;
        let lines = &regions.lines;
        let corners = regions.points.corners(|d| {
            let within = model.depth_and_band(tolerance, d.range);
            lines.corner_of_others_at(d.reflector(), within, d.position, d.axis)
        });
        corners
            .iter()
            .map(|kept| self.redraw_as_point(&model, regions, kept, kernel))
            .sum()
    }

    /// Takes back `kept`, a whole region's patch as drawn, draws it as a point and forgets it
    /// as a wall to follow.
    fn redraw_as_point(
        &mut self,
        model: &SmoothModel,
        regions: &mut Regions,
        kept: &points::Drawn,
        kernel: Kernel,
    ) -> usize {
        let tolerance = model.depth_and_band(regions.tolerance, kept.range);
        regions
            .lines
            .forget(kept.position, kept.axis, kept.range, tolerance);
        self.fuse_patch(model, kept, -1.0, kernel)
            + self.fuse_patch(model, &self.as_point(kept), 1.0, kernel)
    }

    /// `patch` drawn as a point: a cell wide.
    fn as_point(&self, patch: &points::Drawn) -> points::Drawn {
        points::Drawn {
            half_angle: (self.grid.geometry().resolution() / patch.range).atan(),
            ..*patch
        }
    }

    /// Fuses a region's occupied evidence on a straight patch square to `axis` at its range,
    /// `half_angle` wide each side, as strong as its readings' together: with one reading's
    /// strength, a patch did not outweigh the free evidence other readings put on its cells (on
    /// the suite's `tune` split, a fifth to a third of the misses on squarely faced surfaces were
    /// cells a patch had covered; docs/fusion.md).
    fn fuse_patch(
        &mut self,
        model: &SmoothModel,
        patch: &points::Drawn,
        sign: f32,
        kernel: Kernel,
    ) -> usize {
        let points::Drawn {
            position,
            axis,
            range,
            half_angle,
            readings,
            ..
        } = *patch;
        let beam = Beam {
            position,
            axis,
            half_angle: model.max_half_angle(),
            max_range: self.config.sensor.limits().max_range,
            echo: Some(range),
        };
        if sign > 0.0 && model.region_weak_echo_explained {
            // The patch is straight: its box is its ends'.
            let ends = Patch::new(position, axis, range, half_angle).ends;
            self.note_wall_drawn(&ends, model.band(range));
        }
        let evidence = model.region_echo(axis, range, half_angle, sign * readings);
        self.apply(&beam, &evidence, kernel)
    }

    /// Notes the box around `points`, widened by `margin`, as holding a wall drawn
    /// ([`Self::walls_drawn`]).
    fn note_wall_drawn(&mut self, points: &[Vector2<f32>], margin: f32) {
        let margin = Vector2::repeat(margin);
        let lower = points
            .iter()
            .fold(Vector2::repeat(f32::INFINITY), |m, p| m.inf(p));
        let upper = points
            .iter()
            .fold(Vector2::repeat(f32::NEG_INFINITY), |m, p| m.sup(p));
        self.walls_drawn.push((lower - margin, upper + margin));
    }

    /// Fuses the stretches of wall [`Lines`] last wrote (of the kind `kind`), those readings did
    /// not see through: with the kind's foot check on, those no reading refutes
    /// ([`Self::refuted_at`]), kept to be taken back if a later one does
    /// ([`Self::withdraw_refuted_stretches`]); else those along which the grid holds no three
    /// free cells in a row ([`Self::seen_through`]). With the foot check, stretches that lie on
    /// one line and overlap are checked and drawn as the pieces of their union
    /// ([`lines::Overlapping`]): a stretch is refused if a reading's foot lies on it, and each
    /// piece drawn counts the readings of the stretches not refused that cover it.
    fn place_stretches(
        &mut self,
        model: &SmoothModel,
        regions: &mut Regions,
        kind: Stretches,
        kernel: Kernel,
    ) -> usize {
        let foot_check = match kind {
            Stretches::BetweenFeet => model.region_stretch_foot_check,
            Stretches::ToEnds => model.region_corner_walls_foot_check,
        };
        let stretches = std::mem::take(&mut regions.stretches);
        let mut cells = 0;
        if foot_check {
            for group in lines::overlapping(&stretches) {
                let (a, b) = group.ends();
                let mut feet: Vec<f32> = self.refuted_at(model, regions, a, b, 0).collect();
                feet.sort_by(f32::total_cmp);
                let unrefuted = |from: f32, to: f32| {
                    let first = feet.partition_point(|&t| t < from);
                    feet.get(first).is_none_or(|&t| t > to)
                };
                for piece in group.pieces(unrefuted) {
                    cells += self.place_stretch(model, &piece, 1.0, kernel);
                    // Piece by piece: a wall drawn on past where it ends is wrong only there.
                    for part in piece.pieces(STRETCH_PIECE_M) {
                        regions.keep_drawn(part);
                    }
                }
            }
        } else {
            for stretch in &stretches {
                if !self.seen_through(stretch) {
                    cells += self.place_stretch(model, stretch, 1.0, kernel);
                }
            }
        }
        regions.stretches = stretches;
        cells
    }

    /// Takes back the stretches drawn that a reading since refutes ([`Self::refuted_at`]): the
    /// readings of viewpoints that came later, which would have heard the wall at their foot on
    /// it. A stretch is a guess no reading heard; without this it stayed drawn whatever the
    /// robot heard after it (on the suite, walls drawn across rooms from the first viewpoints).
    fn withdraw_refuted_stretches(&mut self, regions: &mut Regions, kernel: Kernel) -> usize {
        let ModelConfig::Smooth(model) = self.config.model else {
            return 0;
        };
        let now = regions.sightlines.pushed();
        let mut drawn = std::mem::take(&mut regions.drawn);
        let mut cells = 0;
        let mut kept_parts = Vec::new();
        drawn.retain_mut(|d| {
            if d.unchecked_from == now {
                return true;
            }
            let (a, b) = (d.stretch.a, d.stretch.b);
            let mut refuting = self
                .refuted_at(&model, regions, a, b, d.unchecked_from)
                .peekable();
            if refuting.peek().is_none() {
                d.unchecked_from = now;
                return true;
            }
            // Where the refuting feet lie is wanted only to draw the rest again.
            let feet: Vec<Vector2<f32>> = if model.region_stretch_withdrawn_at_feet {
                refuting.map(|t| a + (b - a) * t).collect()
            } else {
                drop(refuting);
                Vec::new()
            };
            cells += self.place_stretch(&model, &d.stretch, -1.0, kernel);
            if model.region_stretch_withdrawn_at_feet {
                // Drawn again but where the readings' feet refute it.
                for part in d
                    .stretch
                    .without(&feet, REFUTED_AROUND_FOOT_M, SHORTEST_PART_M)
                {
                    cells += self.place_stretch(&model, &part, 1.0, kernel);
                    kept_parts.push(part);
                }
            }
            false
        });
        drawn.push_unchecked(kept_parts, now);
        regions.drawn = drawn;
        cells
    }

    /// How many grid steps lie in front of something at `range`, up to two of its bands short
    /// of it (its own cells may be drawn already).
    fn steps_short_of(&self, model: &SmoothModel, range: f32) -> usize {
        let step = self.grid.geometry().resolution();
        ((range - 2.0 * model.band(range)) / step).floor().max(0.0) as usize
    }

    /// How many cells [`Self::cells_in_front`] looks at: a cell's width apart on `beam`'s axis up
    /// to two bands short of its echo.
    fn steps_in_front(&self, model: &SmoothModel, beam: &Beam) -> usize {
        beam.echo
            .map_or(0, |range| self.steps_short_of(model, range))
    }

    /// The `steps` cells a grid step apart from `from` along the unit vector `direction`,
    /// nearest first (those off the grid left out).
    fn cells_along(
        &self,
        from: Vector2<f32>,
        direction: Vector2<f32>,
        steps: usize,
    ) -> impl Iterator<Item = (usize, usize)> + '_ {
        let geometry = self.grid.geometry();
        let step = geometry.resolution();
        (1..=steps)
            .filter_map(move |k| geometry.cell_at((from + direction * (k as f32 * step)).into()))
    }

    /// The cells on `beam`'s axis in front of its echo's band, nearest first, one per grid step
    /// (none without an echo).
    fn cells_in_front(
        &self,
        model: &SmoothModel,
        beam: &Beam,
    ) -> impl Iterator<Item = (usize, usize)> + '_ {
        let direction = Vector2::new(beam.axis.cos(), beam.axis.sin());
        self.cells_along(beam.position, direction, self.steps_in_front(model, beam))
    }

    /// Whether the grid holds an occupied cell (p > 0.5) on `beam`'s axis in front of its echo's
    /// band.
    fn occupied_in_front(&self, model: &SmoothModel, beam: &Beam) -> bool {
        self.cells_in_front(model, beam)
            .any(|(x, y)| self.grid.is_above(x, y, self.above_half))
    }

    /// Writes into `out` the parts of `stretch`, a wall drawn on from a patch heard from
    /// `sensor`, that `sensor` or one of `viewpoints` sees, as far as the grid shows (looked at
    /// every two grid steps): within the sensor's reach, with no wall (p > [`WITHDRAW_ABOVE`])
    /// between, leaving out the cells within two bands of the stretch's own line (a sight line
    /// that meets the wall at a slant runs near it). No viewpoint could have heard the rest: a
    /// wall followed on behind another wall is a guess nothing can check or refute.
    fn seen_parts(
        &self,
        model: &SmoothModel,
        sensor: Vector2<f32>,
        viewpoints: &VecDeque<Vector2<f32>>,
        stretch: &Stretch,
        out: &mut Vec<Stretch>,
    ) {
        let geometry = self.grid.geometry();
        let reach = self.config.sensor.limits().max_range;
        let step = 2.0 * geometry.resolution();
        let length = (stretch.b - stretch.a).norm();
        if length <= step {
            out.push(*stretch);
            return;
        }
        let along = (stretch.b - stretch.a) / length;
        let normal = Vector2::new(-along.y, along.x);
        let samples = (length / step).ceil() as usize;
        let at = |k: usize| stretch.a + along * (k as f32 * step).min(length);
        let seen_from = |from: Vector2<f32>, point: Vector2<f32>| {
            let distance = (point - from).norm();
            let near_line = 2.0 * model.band(distance);
            let direction = (point - from) / distance;
            distance <= reach
                && !self
                    .cells_along(from, direction, self.steps_short_of(model, distance))
                    .any(|(x, y)| {
                        let centre: Vector2<f32> = geometry.cell_centre(x, y).coords;
                        normal.dot(&(centre - stretch.a)).abs() > near_line
                            && self.grid.is_above(x, y, self.above_withdraw)
                    })
        };
        let seen = |k: usize| {
            let point = at(k);
            seen_from(sensor, point) || viewpoints.iter().any(|&v| seen_from(v, point))
        };
        // Runs of seen samples, each drawn from its first sample to its last.
        let mut first_seen = None;
        for k in 0..=samples {
            match (seen(k), first_seen) {
                (true, None) => first_seen = Some(k),
                (false, Some(first)) => {
                    if k - 1 > first {
                        out.push(Stretch {
                            a: at(first),
                            b: at(k - 1),
                            ..*stretch
                        });
                    }
                    first_seen = None;
                }
                _ => {}
            }
        }
        if let Some(first) = first_seen.filter(|&first| first < samples) {
            out.push(Stretch {
                a: at(first),
                b: at(samples),
                ..*stretch
            });
        }
    }

    /// Whether a wall drawn (a cell above [`WITHDRAW_ABOVE`]) within `lobe` of `beam`'s axis at
    /// its echo's range (within the depth tolerance and band) explains the echo, and no such wall
    /// runs through the echo on the axis: the reading heard that wall at its foot, off its axis,
    /// so what its weak echo drew on the axis lies in front of that wall or beyond its end. Each
    /// wall cell stands for the line through it square to the bearing it was heard from.
    fn explained_off_axis(
        &self,
        model: &SmoothModel,
        lobe: f32,
        tolerance: DepthTolerance,
        beam: &Beam,
    ) -> bool {
        let Some(range) = beam.echo else {
            return false;
        };
        let depth = model.depth_and_band(tolerance, range);
        let geometry = self.grid.geometry();
        // Apart by at most a band (a wall drawn is two bands thick, so every one crossing the
        // sector is met) and at most two grid steps.
        let step = (2.0 * geometry.resolution()).min(model.band(range));
        let axis = Vector2::new(beam.axis.cos(), beam.axis.sin());
        // The annulus sector at the echo's range, sampled both ways.
        let arcs = (2.0 * depth / step).ceil() as usize;
        let rays = (2.0 * lobe * (range + depth) / step).ceil() as usize;
        let mut off_line = false;
        // From the axis outwards: the answer does not depend on the order, and the search ends
        // at the first wall cell whose line crosses the axis at the echo (the echo is then that
        // wall's own), which mostly lies near the axis.
        for j in from_the_middle(rays) {
            let bearing = beam.axis - lobe + 2.0 * lobe * j as f32 / rays.max(1) as f32;
            let direction = Vector2::new(bearing.cos(), bearing.sin());
            for i in 0..=arcs {
                let r = range - depth + 2.0 * depth * i as f32 / arcs.max(1) as f32;
                let Some((x, y)) = geometry.cell_at((beam.position + direction * r).into()) else {
                    continue;
                };
                // Most cells hold no wall: that test first, the cell's own place after.
                if !self.grid.is_above(x, y, self.above_withdraw) {
                    continue;
                }
                let to_cell = geometry.cell_centre(x, y).coords - beam.position;
                let cell_bearing = to_cell.y.atan2(to_cell.x);
                if (to_cell.norm() - range).abs() > depth
                    || wrap_angle(cell_bearing - beam.axis).abs() > lobe
                {
                    continue;
                }
                let heard = self.grid.heard_from(x, y).unwrap_or(cell_bearing);
                let normal = Vector2::new(heard.cos(), heard.sin());
                // Where the axis meets the wall's line, as a range along it.
                let across = normal.dot(&axis);
                let meets = (across.abs() > f32::EPSILON).then(|| normal.dot(&to_cell) / across);
                if meets.is_some_and(|t| (t - range).abs() <= depth) {
                    return false;
                }
                off_line = true;
            }
        }
        off_line
    }

    /// Whether the grid holds a cell on `beam`'s axis in front of its echo's band that is occupied
    /// (p > [`WITHDRAW_ABOVE`]) and was heard from a bearing at least [`WITHDRAW_INCIDENCE_DEG`]
    /// off the axis: a wall the axis meets at a slant, which could not answer the reading.
    /// `squares`: what is known of the grid's squares above [`WITHDRAW_ABOVE`] as it is now.
    fn slanted_wall_in_front(
        &self,
        model: &SmoothModel,
        beam: &Beam,
        squares: &mut SquaresAbove,
    ) -> bool {
        let min_incidence = WITHDRAW_INCIDENCE_DEG.to_radians();
        let grid = &self.grid;
        let direction = Vector2::new(beam.axis.cos(), beam.axis.sin());
        let steps = self.steps_in_front(model, beam);
        squares.any_along(grid, beam.position, direction, steps, |x, y| {
            grid.is_above(x, y, self.above_withdraw)
                && grid
                    .heard_from(x, y)
                    .is_none_or(|h| incidence(beam.axis, h) >= min_incidence)
        })
    }

    /// Where the readings that refute the wall from `a` to `b` have their feet on it, as
    /// fractions of the way from `a` to `b` ([`Sightlines::refuted_at`], those kept from number
    /// `since` on): readings whose lobe (learnt at that range) held the foot of their sensor's
    /// perpendicular on the wall, with no occupied cell between them, and that heard their first
    /// echo farther than the foot by more than the depth tolerance and band: a flat wall there
    /// would have answered them at the foot.
    fn refuted_at<'a>(
        &'a self,
        model: &'a SmoothModel,
        regions: &'a Regions,
        a: Vector2<f32>,
        b: Vector2<f32>,
        since: u64,
    ) -> impl Iterator<Item = f32> + 'a {
        let unhidden = |from: Vector2<f32>, foot: Vector2<f32>| {
            let distance = (foot - from).norm();
            let direction = (foot - from) / distance;
            self.cells_along(from, direction, self.steps_short_of(model, distance))
                .all(|(x, y)| !self.grid.is_above(x, y, self.above_half))
        };
        regions.sightlines.refuted_at(
            since,
            a,
            b,
            Lobe {
                at: |distance| regions.lobe.at(distance),
                widest: regions.lobe.widest_learnt(),
            },
            |range| model.depth_and_band(regions.tolerance, range),
            unhidden,
        )
    }

    /// Whether readings saw through `stretch`: three cells in a row along it that the grid holds
    /// free (p < 0.3), a doorway or the gap between two walls in line.
    fn seen_through(&self, stretch: &Stretch) -> bool {
        let grid = &self.grid;
        let step = grid.geometry().resolution();
        let length = (stretch.b - stretch.a).norm();
        let steps = (length / step).ceil() as usize;
        let mut free_run = 0;
        for k in 0..=steps {
            let p = stretch.a + (stretch.b - stretch.a) * (k as f32 / steps.max(1) as f32);
            let free = grid
                .geometry()
                .cell_at(p.into())
                .and_then(|(x, y)| grid.probability(x, y))
                .is_some_and(|p| p < 0.3);
            free_run = if free { free_run + 1 } else { 0 };
            if free_run >= 3 {
                return true;
            }
        }
        false
    }

    /// Fuses a stretch of wall as the patch a sensor square to its middle would have heard, far
    /// enough back that the whole stretch lies within the widest patch's angle; `sign` −1 takes
    /// it back.
    fn place_stretch(
        &mut self,
        model: &SmoothModel,
        stretch: &Stretch,
        sign: f32,
        kernel: Kernel,
    ) -> usize {
        // In pieces short enough that each lies within the widest patch's angle from no farther
        // than 3 m: a longer one would be cut at that angle.
        stretch
            .pieces(STRETCH_PIECE_M)
            .map(|piece| self.place_piece(model, &piece, sign, kernel))
            .sum()
    }

    /// Fuses a piece of a stretch ([`Self::place_stretch`]).
    fn place_piece(
        &mut self,
        model: &SmoothModel,
        stretch: &Stretch,
        sign: f32,
        kernel: Kernel,
    ) -> usize {
        if sign > 0.0 && model.region_weak_echo_explained {
            // The profile reaches past the piece's ends (1.5 times its angle, below).
            let reach = 0.5 * (stretch.b - stretch.a).norm() + model.band(3.0);
            self.note_wall_drawn(&[stretch.a, stretch.b], reach);
        }
        let half_length = 0.5 * (stretch.b - stretch.a).norm();
        let widest = model.region_half_angle_deg.to_radians();
        let distance = (half_length / widest.tan()).clamp(0.5, 3.0);
        let normal = Vector2::new(stretch.facing.cos(), stretch.facing.sin());
        let middle = 0.5 * (stretch.a + stretch.b);
        let cut = (half_length / distance).atan();
        let beam = Beam {
            position: middle - normal * distance,
            axis: stretch.facing,
            half_angle: cut,
            max_range: self.config.sensor.limits().max_range,
            echo: Some(distance),
        };
        // The profile reaches past the stretch's ends, so that they get more than a trace.
        // A stretch was not heard: it counts as a reading for each pair of hearings that drew it.
        let evidence = model.region_echo(
            stretch.facing,
            distance,
            1.5 * cut,
            sign * stretch.readings as f32,
        );
        self.apply(&beam, &evidence, kernel)
    }

    /// Copies both maps and the counters into `out`, for saving (into its allocations).
    pub(crate) fn save_into(&self, out: &mut MapperState) {
        out.readings_fused = self.readings;
        out.last_pose = self.pose.into();
        self.grid.save_cells_into(&mut out.cells);
        self.grid.save_heard_into(&mut out.heard);
        self.radar.save_into(&mut out.radar);
    }

    /// The maps of `config` holding a saved state, if it fits `config`.
    pub(crate) fn restore(config: FusionConfig, saved: MapperState) -> Result<Self, StateError> {
        let mut mapper = Self::new(config)?;
        mapper.grid.restore_cells(saved.cells)?;
        mapper.grid.restore_heard(saved.heard)?;
        mapper.radar.restore(saved.radar)?;
        mapper.readings = saved.readings_fused;
        mapper.pose = saved.last_pose.into();
        Ok(mapper)
    }

    /// Forgets everything: the grid back to the prior, the radar empty. The kernels' caches stay.
    pub fn clear(&mut self) {
        self.grid.clear();
        self.radar.clear();
        self.readings = 0;
        self.walls_drawn.clear();
        if let Some(regions) = &mut self.regions {
            regions.tracker = RegionTracker::default();
            regions.waiting.clear();
            regions.lines.clear();
            regions.points.clear();
            regions.viewpoints.clear();
            regions.sightlines.clear();
            regions.drawn.clear();
            regions.one_ended.clear();
            regions.cut.clear();
            regions.weak = WeakEchoes::default();
            regions.walls_placed = false;
            if let Some(hiding) = &mut regions.hiding {
                hiding.clear();
            }
            regions.previous = None;
            regions.between = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{GridConfig, Preset};
    use crate::model::{AlphaSign, BeamWidth, ModelConfig, ModelKind, PaperModel};
    use crate::rule::{RuleConfig, RuleKind};
    use nalgebra::{Point2, Vector2};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use sonar_common::sensor::SensorConfig;

    const DEG: f32 = std::f32::consts::PI / 180.0;

    fn reading(angle_deg: f32, range_m: Option<f32>) -> Observation {
        Observation {
            pose: Isometry2::identity(),
            angle_rad: angle_deg * DEG,
            range_m,
            rejected_echo_m: None,
            beam_half_angle_rad: 30.0 * DEG,
            max_range_m: 4.0,
        }
    }

    /// A mapper placing echoes by region, with `model`'s other settings.
    fn region_mapper(model: crate::model::SmoothModel) -> Mapper {
        Mapper::new(FusionConfig {
            model: ModelConfig::Smooth(crate::model::SmoothModel {
                echo_placement: crate::model::EchoPlacement::Region,
                ..model
            }),
            ..FusionConfig::default()
        })
        .unwrap()
    }

    /// A mapper placing echoes by region with `model`, after `observations` and its last
    /// region closed.
    fn region_scan(model: crate::model::SmoothModel, observations: &[Observation]) -> Mapper {
        let mut m = region_mapper(model);
        for obs in observations {
            m.update(obs).unwrap();
        }
        m.close_region();
        m
    }

    /// Every probability of the grid, `None` for unknown cells.
    fn cells(m: &Mapper) -> Vec<Option<f32>> {
        let n = m.grid().geometry().cells_per_side();
        (0..n)
            .flat_map(|y| (0..n).map(move |x| (x, y)))
            .map(|(x, y)| m.grid().probability(x, y))
            .collect()
    }

    /// The stepper's angles (reading centres and ping positions) and arbitrary ones.
    fn random_angle_deg(rng: &mut ChaCha8Rng, centres: &[f32]) -> f32 {
        let centre = centres[rng.random_range(0..centres.len())];
        match rng.random_range(0..3) {
            0 => centre,
            1 => centre + [-2.25, -0.75, 0.75, 2.25][rng.random_range(0..4)],
            _ => rng.random_range(-180.0..180.0),
        }
    }

    /// Random readings: 20 at the origin, then parked elsewhere long enough for the stencil to
    /// move there, then moving at every reading, 60 after the origin in all.
    fn random_observations(seed: u64) -> Vec<Observation> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let centres = SensorConfig::default().reading_centres_deg();
        let parked = Isometry2::new(Vector2::new(0.37, -0.21), 0.4);
        (0..80)
            .map(|i| {
                let pose = if i < 20 {
                    Isometry2::identity()
                } else if i < 20 + REBUILD + 10 {
                    parked
                } else {
                    Isometry2::new(
                        Vector2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)),
                        rng.random_range(-3.2..3.2),
                    )
                };
                Observation {
                    pose,
                    angle_rad: random_angle_deg(&mut rng, &centres) * DEG,
                    range_m: rng.random_bool(0.85).then(|| rng.random_range(0.05..4.3)),
                    rejected_echo_m: None,
                    beam_half_angle_rad: rng.random_range(10.0..40.0) * DEG,
                    max_range_m: 4.0,
                }
            })
            .collect()
    }

    /// Sweeps in which runs of readings hear the same range between readings with no echo, so
    /// that regions of constant depth form: from the origin, from a parked position long enough
    /// for the stencil to move there, and from a new pose at every reading.
    fn region_observations(seed: u64) -> Vec<Observation> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let parked = Isometry2::new(Vector2::new(0.37, -0.21), 0.4);
        let mut range = None;
        (0..3 * 51)
            .map(|i| {
                let pose = match i / 51 {
                    0 => Isometry2::identity(),
                    1 => parked,
                    _ => Isometry2::new(
                        Vector2::new(rng.random_range(-0.01..0.01), rng.random_range(-0.01..0.01)),
                        rng.random_range(-0.01..0.01),
                    ),
                };
                if i % 5 == 0 {
                    range = rng.random_bool(0.8).then(|| rng.random_range(0.3..4.3));
                }
                Observation {
                    pose,
                    angle_rad: (-150.0 + 6.0 * (i % 51) as f32) * DEG,
                    range_m: if i % 5 == 4 { None } else { range },
                    rejected_echo_m: None,
                    beam_half_angle_rad: 30.0 * DEG,
                    max_range_m: 4.0,
                }
            })
            .collect()
    }

    #[test]
    fn fast_kernel_equals_the_whole_grid_pass_for_every_model_and_rule() {
        // Every model with its defaults, and the paper's model with its other conventions for β
        // and α (the signed α is asymmetric and clamped, so the spans must not assume symmetry).
        let models = ModelKind::ALL
            .map(ModelConfig::default_for)
            .into_iter()
            .chain([
                ModelConfig::Paper(PaperModel {
                    beam_width: BeamWidth::FullWidth,
                    ..Default::default()
                }),
                ModelConfig::Paper(PaperModel {
                    alpha: AlphaSign::Signed,
                    ..Default::default()
                }),
                ModelConfig::Smooth(crate::model::SmoothModel {
                    echo_placement: crate::model::EchoPlacement::Region,
                    ..Default::default()
                }),
            ]);
        for (seed, model) in models.enumerate() {
            for rule in RuleKind::ALL {
                for clear_on_no_echo in [false, true] {
                    // 3 m of grid each side, less than the 4 m range: the cone is clipped. Every
                    // other model on a grid whose centre is off the origin by fractions of a cell.
                    let (centre_x_m, centre_y_m) = if seed % 2 == 1 {
                        (0.37, -0.613)
                    } else {
                        (0.0, 0.0)
                    };
                    let config = FusionConfig {
                        grid: GridConfig {
                            cells: 120,
                            resolution_m: 0.05,
                            centre_x_m,
                            centre_y_m,
                        },
                        model,
                        rule: RuleConfig::default_for(rule),
                        clear_on_no_echo,
                        ..FusionConfig::default()
                    };
                    let mut fast = Mapper::new(config).unwrap();
                    let mut reference = Mapper::new(config).unwrap();
                    // The snapshot bytes and counts, brought up to date from the runs the fast
                    // kernel fused since the last time (overlapping, many readings' worth) and
                    // anew after each whole-grid pass, as if encoded afresh.
                    let check = |m: &mut Mapper| {
                        let expected = crate::grid::reference_encoding(m.grid());
                        let (bytes, counts) = m.grid_mut().encoded();
                        assert!(
                            (bytes, counts) == (&expected.0[..], expected.1),
                            "{model:?} {rule}"
                        );
                    };
                    let observations = match model {
                        ModelConfig::Smooth(m) if m.regions().is_some() => {
                            region_observations(seed as u64)
                        }
                        _ => random_observations(seed as u64),
                    };
                    for (i, obs) in observations.into_iter().enumerate() {
                        let a = fast.update_with(&obs, Kernel::Cone).unwrap();
                        let b = reference.update_with(&obs, Kernel::WholeGrid).unwrap();
                        assert_eq!(a, b, "{model:?} {rule} {obs:?}");
                        // Now and then, as snapshots come, and at the end.
                        if i % 7 == 6 {
                            check(&mut fast);
                            check(&mut reference);
                        }
                    }
                    check(&mut fast);
                    check(&mut reference);
                    let (a, b) = (cells(&fast), cells(&reference));
                    assert!(a.iter().any(|c| c.is_some()));
                    for (i, (a, b)) in a.iter().zip(&b).enumerate() {
                        match (a, b) {
                            (Some(a), Some(b)) => {
                                assert!((a - b).abs() <= 1e-6, "{model:?} {rule} cell {i}: {a} {b}")
                            }
                            _ => assert_eq!(a, b, "{model:?} {rule} cell {i}"),
                        }
                    }
                }
            }
        }
    }
    const REBUILD: usize = crate::kernel::PARKED_AFTER as usize;

    /// FNV-1a over the bits of every cell of the grid: a fingerprint of the whole map.
    fn fingerprint(m: &Mapper) -> u64 {
        cells(m)
            .iter()
            .flat_map(|c| c.map_or(u32::MAX, f32::to_bits).to_le_bytes())
            .fold(0xcbf2_9ce4_8422_2325, |h, b| {
                (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
            })
    }

    /// The paper preset is the paper as written: its map of fixed readings from five poses (with
    /// both kernels) is the very one it gave before the recommended model learnt where a cell was
    /// heard from (fingerprint taken on commit cef130e, before that change; taken again when the
    /// kernels' arctangent became our own, issue 29: the paper scenes' tables of `sonar-eval`
    /// were the same to the last digit before and after).
    #[test]
    fn the_paper_preset_map_is_unchanged_bit_for_bit() {
        let config = FusionConfig {
            grid: GridConfig {
                cells: 150,
                ..GridConfig::default()
            },
            ..FusionConfig::preset(Preset::Paper)
        };
        let mut rng = ChaCha8Rng::seed_from_u64(23);
        let centres = SensorConfig::default().reading_centres_deg();
        let poses = [
            (0.0, 0.0, 0.0),
            (0.5, 0.3, 1.0),
            (-0.7, 0.2, -2.0),
            (0.1, -0.9, 2.5),
            (0.33, 0.71, 0.2),
        ];
        let mut maps = [Kernel::Cone, Kernel::WholeGrid].map(|k| (k, Mapper::new(config).unwrap()));
        for (x, y, heading) in poses {
            let pose = Isometry2::new(Vector2::new(x, y), heading);
            for &centre in &centres {
                let obs = Observation {
                    pose,
                    range_m: rng.random_bool(0.9).then(|| rng.random_range(0.1..4.2)),
                    ..reading(centre, None)
                };
                for (kernel, m) in &mut maps {
                    m.update_with(&obs, *kernel).unwrap();
                }
            }
        }
        for (kernel, m) in &maps {
            assert_eq!(fingerprint(m), PAPER_FINGERPRINT, "{kernel:?}");
        }
    }
    const PAPER_FINGERPRINT: u64 = 15_339_024_908_047_804_659;

    #[test]
    fn every_model_and_rule_is_symmetric_about_the_beam_axis() {
        for model in ModelKind::ALL {
            for rule in RuleKind::ALL {
                for (axis_deg, mirror_x) in [(0.0, false), (90.0, true), (-90.0, true)] {
                    let config = FusionConfig {
                        model: ModelConfig::default_for(model),
                        rule: RuleConfig::default_for(rule),
                        ..FusionConfig::default()
                    };
                    let mut m = Mapper::new(config).unwrap();
                    m.update(&reading(axis_deg, Some(2.0))).unwrap();
                    m.update(&reading(axis_deg, Some(1.3))).unwrap();
                    let n = m.grid().geometry().cells_per_side();
                    for y in 0..n {
                        for x in 0..n {
                            let (mx, my) = if mirror_x {
                                (n - 1 - x, y)
                            } else {
                                (x, n - 1 - y)
                            };
                            // Exact about the x axis; within rounding of π/2 about the y axis
                            // (a bearing's last bit moves the smooth model's steep 7° free
                            // profile by about 1e-6).
                            let (a, b) = (m.grid().probability(x, y), m.grid().probability(mx, my));
                            assert_eq!(a.is_some(), b.is_some(), "{model} {rule} ({x}, {y})");
                            let (a, b) = (a.unwrap_or(0.0), b.unwrap_or(0.0));
                            assert!(
                                (a - b).abs() <= 4e-6,
                                "{model} {rule} axis {axis_deg}: ({x}, {y}) {a} {b}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn paper_preset_by_hand() {
        let mut m = Mapper::new(FusionConfig::preset(Preset::Paper)).unwrap();
        // The default grid: 2 cm cells, the sensor at the corner of cells 199 and 200, so cell
        // (300, 200) has its centre at (2.01, 0.01): r = 2.010025 m, a = 0.285051°.
        m.update(&reading(0.0, Some(2.0))).unwrap();
        // Region I (1.9 ≤ r ≤ 2.1): s = ((4 − r)/4 + (30 − 0.285051)/30)/2 = 0.743996;
        // eq. 1: 0.98·s = 0.729116; eq. 4: P(H|s) = P(s|H); eq. 6 from the prior 0.5: the same.
        let p = m.grid().probability(300, 200).unwrap();
        assert!((p - 0.729_116).abs() < 1e-5, "{p}");
        // Region II, cell (250, 200) at (1.01, 0.01): r = 1.010050, a = 0.567266°;
        // eq. 2: 1 − ((4 − r)/4 + (30 − a)/30)/2 = 0.135711.
        let q = m.grid().probability(250, 200).unwrap();
        assert!((q - 0.135_711).abs() < 1e-5, "{q}");
        // Region III: untouched.
        assert_eq!(m.grid().probability(310, 200), None);
        // A second reading at 6°, also 2.0 m: α = 5.714949° for the first cell, P(s|H) = 0.640428;
        // eq. 6: 0.729116·0.640428 / (0.729116·0.640428 + 0.270884·0.359572) = 0.827408.
        m.update(&reading(6.0, Some(2.0))).unwrap();
        let p = m.grid().probability(300, 200).unwrap();
        assert!((p - 0.827_408).abs() < 1e-5, "{p}");
        // And for the second: P(s|H) = 0.216802; eq. 6 gives 0.041655.
        let q = m.grid().probability(250, 200).unwrap();
        assert!((q - 0.041_655).abs() < 1e-5, "{q}");
    }

    /// Occupied cells (p > 0.5) closer to the sensor than `range` − `margin`, after one reading
    /// along the x axis.
    fn occupied_in_front(preset: Preset, range: f32, margin: f32) -> usize {
        let mut m = Mapper::new(FusionConfig::preset(preset)).unwrap();
        m.update(&reading(0.0, Some(range))).unwrap();
        let g = m.grid().geometry();
        let n = g.cells_per_side();
        (0..n)
            .flat_map(|y| (0..n).map(move |x| (x, y)))
            .filter(|&(x, y)| {
                g.cell_centre(x, y).coords.norm() < range - margin
                    && m.grid().probability(x, y).is_some_and(|p| p > 0.5)
            })
            .count()
    }

    #[test]
    fn the_paper_paints_wedges_in_front_of_the_echo_and_the_recommended_model_does_not() {
        // Eq. 2 gives P > 0.5 where (R − r)/R + (β − |α|)/β < 1: at 3.5 m, from about 2 m on
        // near the cone's edges.
        assert!(occupied_in_front(Preset::Paper, 3.5, 3.5 * 0.05) > 100);
        // The recommended model's occupied band is centred on the range (half-width
        // max(2.5 cm, 1 % of it)); nothing in front of the band.
        for range in [0.5, 2.0, 3.5] {
            let band = crate::model::SmoothModel::default().band(range);
            assert_eq!(occupied_in_front(Preset::Recommended, range, band), 0);
        }
    }

    /// Readings from `(x, y)` at world bearings `from_deg..=to_deg` every 1.5°, each with the
    /// range `range(bearing°)`, repeated `sweeps` times.
    fn sweep(
        at: (f32, f32),
        (from_deg, to_deg): (f32, f32),
        sweeps: usize,
        range: impl Fn(f32) -> Option<f32>,
    ) -> Vec<Observation> {
        let steps = ((to_deg - from_deg) / 1.5).round() as usize;
        let one: Vec<Observation> = (0..=steps)
            .map(|i| from_deg + i as f32 * 1.5)
            .map(|a| Observation {
                pose: Isometry2::new(Vector2::new(at.0, at.1), 0.0),
                ..reading(a, range(a))
            })
            .collect();
        one.repeat(sweeps)
    }

    /// A thin board across x = 1 m, |y| ≤ 0.3 m, heard square from the origin, then passed along
    /// and beside by readings from two other positions that hear a wall at y = 1.5 m beyond it,
    /// and, if `taken_away`, swept again from the origin hearing the wall at x = 3 m (the board
    /// was taken away). Returns the mapper and, per 2 cm row of the board's middle (|y| ≤ 0.14 m),
    /// the highest occupancy within 3 cm of x = 1 m.
    fn board_scene(model: crate::model::SmoothModel, taken_away: bool) -> (Mapper, Vec<f32>) {
        let mut m = Mapper::new(FusionConfig {
            model: ModelConfig::Smooth(model),
            ..FusionConfig::default()
        })
        .unwrap();
        // Square from the origin: every beam whose lobe (±15°) holds the board's foot hears it at
        // its perpendicular distance; the others hear the far wall at x = 3 m.
        let square = sweep((0.0, 0.0), (-30.0, 30.0), 2, |a| {
            Some(if a.abs() <= 15.0 { 1.0 } else { 3.0 })
        });
        // Edge-on from (1, −1.5): the beams along the board hear the wall at y = 1.5 m; beside it,
        // from (1.3, −1.5), the same.
        let along = sweep((1.0, -1.5), (75.0, 105.0), 3, |_| Some(3.0));
        let beside = sweep((1.3, -1.5), (75.0, 105.0), 3, |_| Some(3.0));
        let mut all: Vec<Observation> = [square, along, beside].concat();
        if taken_away {
            all.extend(sweep((0.0, 0.0), (-30.0, 30.0), 3, |_| Some(3.0)));
        }
        for obs in &all {
            m.update(obs).unwrap();
        }
        let g = *m.grid().geometry();
        let rows = (-7..=7)
            .map(|i| {
                let y = i as f32 * 0.02 + 0.01;
                (-1..=1)
                    .filter_map(|j| {
                        let p = nalgebra::Point2::new(1.0 + j as f32 * 0.02 + 0.01, y);
                        let (cx, cy) = g.cell_at(p)?;
                        m.grid().probability(cx, cy)
                    })
                    .fold(0.0f32, f32::max)
            })
            .collect();
        (m, rows)
    }

    /// The occupied cells of one sweep from the origin over a wall along x = 1.5 m, heard at its
    /// perpendicular distance by every reading within 27° of the perpendicular (the foot in the
    /// lobe) and by no other: (x, y) of each cell centre.
    fn wall_heard_off_its_perpendicular(placement: crate::model::EchoPlacement) -> Vec<(f32, f32)> {
        let mut m = Mapper::new(FusionConfig {
            model: ModelConfig::Smooth(crate::model::SmoothModel {
                echo_placement: placement,
                ..Default::default()
            }),
            ..FusionConfig::default()
        })
        .unwrap();
        // Reading centres every 6°, as the driver publishes them.
        for k in -10..=10 {
            let a = 6.0 * k as f32;
            m.update(&reading(a, (a.abs() <= 27.0).then_some(1.5)))
                .unwrap();
        }
        m.close_region();
        let g = *m.grid().geometry();
        let n = g.cells_per_side();
        (0..n)
            .flat_map(|y| (0..n).map(move |x| (x, y)))
            .filter(|&(x, y)| m.grid().probability(x, y).is_some_and(|p| p > 0.5))
            .map(|(x, y)| {
                let c = g.cell_centre(x, y);
                (c.x, c.y)
            })
            .collect()
    }

    /// Sweeps from `at` over ±40° about the bearing of `target`, whose readings within ±15° of it
    /// hear `range(bearing)`, the others nothing; the region closed after.
    fn hear_around(m: &mut Mapper, at: (f32, f32), target: (f32, f32), range: impl Fn(f32) -> f32) {
        let to = (target.1 - at.1).atan2(target.0 - at.0).to_degrees();
        let readings = sweep(at, (to - 40.0, to + 40.0), 2, |a| {
            ((a - to).abs() <= 15.0).then(|| range(a))
        });
        for obs in &readings {
            m.update(obs).unwrap();
        }
        m.close_region();
    }

    /// The range to the wall along x = `x` from `at` at bearing `deg`, if it lies ahead.
    fn to_wall_at_x(at: (f32, f32), x: f32, deg: f32) -> Option<f32> {
        let c = (deg * DEG).cos();
        let range = (x - at.0) / c;
        (range > 0.0 && range < 4.0).then_some(range)
    }

    #[test]
    fn a_restored_map_keeps_what_its_readings_saw_from_the_other_side_of_a_wall() {
        // From the origin: a wall along x = 1 ahead and one along x = −1 behind, each heard
        // square over ±15° (nothing heard beyond, ±25°), four times.
        let a = (0.0, 0.0);
        let square = |at: (f32, f32), x: f32, facing: f32| {
            move |deg: f32| {
                ((deg - facing).abs() <= 15.0)
                    .then(|| to_wall_at_x(at, x, deg))
                    .flatten()
            }
        };
        let mut heard_from_a = sweep(a, (-25.0, 25.0), 4, square(a, 1.0, 0.0));
        heard_from_a.extend(sweep(a, (155.0, 205.0), 4, square(a, -1.0, 180.0)));
        let preset = FusionConfig::preset(Preset::Recommended);
        let ModelConfig::Smooth(model) = preset.model else {
            panic!("the recommended preset's model is the smooth one");
        };
        let config = FusionConfig {
            model: ModelConfig::Smooth(crate::model::SmoothModel {
                region_hidden_unknown: true,
                ..model
            }),
            ..preset
        };
        let mut live = Mapper::new(config).unwrap();
        for obs in &heard_from_a {
            live.update(obs).unwrap();
        }
        live.close_region();
        assert!(probability_at(&live, -1.0, 0.0).is_some_and(|p| p > 0.9));
        let mut saved = MapperState::default();
        live.save_into(&mut saved);

        // Restored, then sweeps from x = 2, which hear the wall along x = 1 from its other side:
        // the wall behind the origin lies behind it as seen from there.
        let b = (2.0, 0.0);
        let from_b = sweep(b, (155.0, 205.0), 4, square(b, 1.0, 180.0));
        let after = |remembered: bool| {
            let mut m = Mapper::restore(config, saved.clone()).unwrap();
            if remembered {
                m.remember_readings(heard_from_a.iter());
            }
            for obs in &from_b {
                m.update(obs).unwrap();
            }
            m.close_region();
            probability_at(&m, -1.0, 0.0)
        };
        assert!(
            after(true).is_some_and(|p| p > 0.9),
            "the wall behind the origin, seen from it, stays"
        );
        assert_eq!(
            after(false),
            None,
            "not told where its readings were taken, the map hides it from x = 2"
        );
    }

    #[test]
    fn a_post_heard_whole_from_two_bearings_is_drawn_as_a_point_and_a_wall_stays_a_wall() {
        let model = |points: bool| crate::model::SmoothModel {
            region_points: points,
            ..crate::model::SmoothModel::default()
        };
        let occupied =
            |m: &Mapper, x: f32, y: f32| probability_at(m, x, y).is_some_and(|p| p > 0.5);
        let post = (1.5, 0.0);
        let distance = |from: (f32, f32)| (post.0 - from.0).hypot(post.1 - from.1);
        for points in [false, true] {
            let mut m = region_mapper(model(points));
            hear_around(&mut m, (0.0, 0.0), post, |_| distance((0.0, 0.0)));
            // One viewpoint: a patch across the bearing, as a wall's foot would give.
            assert!(
                occupied(&m, 1.51, 0.01) && occupied(&m, 1.51, 0.21),
                "{points}"
            );
            hear_around(&mut m, (0.5, -1.0), post, |_| distance((0.5, -1.0)));
            assert!(occupied(&m, 1.51, 0.01), "{points}");
            // From 45° round, the same spot: a point, the first patch's flank taken back.
            assert_eq!(occupied(&m, 1.51, 0.21), !points);
        }
        // A wall along x = 2 heard from (0, 0) and (0, 1): each viewpoint at its own foot, along
        // one bearing; its patches stay as wide.
        let mut m = region_mapper(model(true));
        for y in [0.0, 1.0] {
            hear_around(&mut m, (0.0, y), (2.0, y), |a| 2.0 / a.to_radians().cos());
        }
        for y in [-0.19, 0.21, 0.81, 1.21] {
            assert!(occupied(&m, 2.01, y), "{y}");
        }
    }

    #[test]
    fn a_wall_drawn_on_is_drawn_only_where_some_viewpoint_sees_it() {
        let model = crate::model::SmoothModel {
            echo_placement: crate::model::EchoPlacement::Region,
            ..crate::model::SmoothModel::default()
        };
        let mut m = region_mapper(model);
        // A wall along x = 1 from y = −0.3 to 0.3, between the sensor at the origin and a wall
        // along x = 2 followed on from y = −1 to 1.
        let near = Stretch {
            a: Vector2::new(1.0, -0.3),
            b: Vector2::new(1.0, 0.3),
            facing: 0.0,
            readings: 5,
        };
        m.place_stretch(&model, &near, 1.0, Kernel::Cone);
        assert!(probability_at(&m, 1.01, 0.01).is_some_and(|p| p > 0.9));
        let far = Stretch {
            a: Vector2::new(2.0, -1.0),
            b: Vector2::new(2.0, 1.0),
            facing: 0.0,
            readings: 1,
        };
        let seen = |viewpoints: &[Vector2<f32>]| {
            let mut out = Vec::new();
            let viewpoints: VecDeque<Vector2<f32>> = viewpoints.iter().copied().collect();
            m.seen_parts(&model, Vector2::zeros(), &viewpoints, &far, &mut out);
            out.iter().map(|s| (s.a.y, s.b.y)).collect::<Vec<_>>()
        };
        // From the origin the near wall hides the far one where |y| < 0.6 and a little more.
        let parts = seen(&[]);
        assert_eq!(parts.len(), 2, "{parts:?}");
        assert!((parts[0].0 + 1.0).abs() < 1e-6 && (-0.72..-0.6).contains(&parts[0].1));
        assert!((0.6..0.72).contains(&parts[1].0) && (parts[1].1 - 1.0).abs() < 1e-6);
        // A viewpoint between the walls sees it all.
        assert_eq!(seen(&[Vector2::new(1.5, 0.0)]), vec![(-1.0, 1.0)]);
    }

    #[test]
    fn a_region_puts_a_wall_where_it_is_and_single_readings_draw_an_arc_in_front_of_it() {
        use crate::model::EchoPlacement;
        let arc = wall_heard_off_its_perpendicular(EchoPlacement::Reading);
        let patch = wall_heard_off_its_perpendicular(EchoPlacement::Region);
        let in_front = |cells: &[(f32, f32)]| cells.iter().filter(|c| c.0 < 1.44).count();
        // Each reading puts its echo on its own axis: at 24° off the perpendicular, 13 cm in front.
        assert!(in_front(&arc) > 10, "{arc:?}");
        // The region's patch lies on the wall (band ± 2.5 cm and a cell), along it both ways.
        assert!(!patch.is_empty());
        assert_eq!(in_front(&patch), 0, "{patch:?}");
        assert!(patch.iter().all(|c| (c.0 - 1.5).abs() <= 0.05), "{patch:?}");
        assert!(patch.iter().any(|c| c.1 > 0.4) && patch.iter().any(|c| c.1 < -0.4));
    }

    #[test]
    fn a_region_outweighs_the_free_evidence_its_cells_had_as_all_its_readings_together() {
        let mut m = region_mapper(crate::model::SmoothModel::default());
        let sweep = |m: &mut Mapper, range: f32, half_deg: f32| {
            for k in -10..=10 {
                let a = 6.0 * k as f32;
                m.update(&reading(a, (a.abs() <= half_deg).then_some(range)))
                    .unwrap();
            }
            m.close_region();
        };
        // Two sweeps hear 2.5 m past where the board will stand (their whole region clears the
        // space in front of it, down to the rule's lower clamp on the axis) …
        sweep(&mut m, 2.5, 27.0);
        sweep(&mut m, 2.5, 27.0);
        let g = *m.grid().geometry();
        let (x, y) = g.cell_at(Vector2::new(1.5, 0.0).into()).unwrap();
        let cleared = m.grid().probability(x, y).unwrap();
        assert!(cleared < 0.15, "{cleared}");
        // … then five readings hear it at 1.5 m: their patch counts as all five (+4 at that
        // range's trust), where one reading's (+0.8) left the cell free at −1.2.
        sweep(&mut m, 1.5, 12.0);
        let heard = m.grid().probability(x, y).unwrap();
        assert!(heard > 0.8, "{heard}");
    }

    /// The occupied cells of a local scan from the origin of a corner on the x axis between two
    /// walls 0.85 m away square to ±`facing_deg` (at (1.2, 0) for 45°): each wall heard from the
    /// scan's limit (±57°) to ±21°, the corner between (a region cut short by both walls' nearer
    /// echoes), one sweep each way.
    fn corner_local_scan(
        region_one_end: bool,
        region_corners: bool,
        region_corner_walls: bool,
        facing_deg: f32,
    ) -> Vec<(f32, f32)> {
        let mut m = region_mapper(crate::model::SmoothModel {
            region_one_end,
            region_corners,
            region_corner_walls,
            ..Default::default()
        });
        let corner = 0.85 / facing_deg.to_radians().cos();
        let range = |a: f32| Some(if a.abs() >= 21.0 { 0.85 } else { corner });
        for k in (-10..=10).chain((-10..=10).rev()) {
            let a = 3.0 + 6.0 * k as f32;
            if a.abs() < 60.0 {
                m.update(&reading(a, range(a))).unwrap();
            }
        }
        m.close_region();
        let g = *m.grid().geometry();
        let n = g.cells_per_side();
        (0..n)
            .flat_map(|y| (0..n).map(move |x| (x, y)))
            .filter(|&(x, y)| m.grid().probability(x, y).is_some_and(|p| p > 0.5))
            .map(|(x, y)| {
                let c = g.cell_centre(x, y);
                (c.x, c.y)
            })
            .collect()
    }

    #[test]
    fn a_local_scan_of_a_corner_draws_its_walls_and_the_corner_where_they_meet() {
        // Only whole regions are placed: nothing (both walls run to the scan's limits, the corner
        // is masked on both sides).
        assert!(corner_local_scan(false, false, false, 45.0).is_empty());
        let cells = corner_local_scan(true, false, false, 45.0);
        // Every cell on one of the two walls (band ± 2.5 cm and a cell), and both walls drawn.
        let wall = |c: &(f32, f32), side: f32| {
            let normal = (-45f32 * side).to_radians();
            (c.0 * normal.cos() + c.1 * normal.sin() - 0.85).abs()
        };
        assert!(
            cells
                .iter()
                .all(|c| wall(c, 1.0).min(wall(c, -1.0)) <= 0.05),
            "{cells:?}"
        );
        for side in [1.0, -1.0] {
            let on = cells
                .iter()
                .filter(|c| wall(c, side) <= 0.05 && c.1 * side < 0.0);
            assert!(on.count() > 10, "{side}: {cells:?}");
        }
        // The corner between them: where the two walls meet, at the range its region heard.
        let near_corner = |cells: &[(f32, f32)]| {
            cells
                .iter()
                .filter(|c| (c.0 - 1.2).hypot(c.1) <= 0.05)
                .count()
        };
        assert_eq!(near_corner(&cells), 0);
        let with_corner = corner_local_scan(true, true, false, 45.0);
        assert!(near_corner(&with_corner) > 0, "{with_corner:?}");
        assert!(with_corner.len() <= cells.len() + 6, "a point, not a patch");
        // The walls drawn from their patches to the corner the region between them heard. Each
        // patch is a one-ended region's, followed on from one place only to a corner heard
        // between the walls' feet, as this one is (its region cut short on both sides). Square
        // to ±48°, where the walls' ends at ±21° put them before the lobe is learnt (the beam's
        // 30° less half a step): the stretch between each patch's end and the corner is drawn,
        // on the walls, and nothing beyond the corner.
        let (before, joined) = (
            corner_local_scan(true, false, false, 48.0),
            corner_local_scan(true, false, true, 48.0),
        );
        let wall = |c: &(f32, f32), side: f32| {
            let normal = (-48f32 * side).to_radians();
            (c.0 * normal.cos() + c.1 * normal.sin() - 0.85).abs()
        };
        let corner_x = 0.85 / 48f32.to_radians().cos();
        assert!(
            joined
                .iter()
                .all(|c| wall(c, 1.0).min(wall(c, -1.0)) <= 0.05 && c.0 <= corner_x + 0.05),
            "{joined:?}"
        );
        let before_corner = |cells: &[(f32, f32)], side: f32| {
            cells
                .iter()
                .filter(|c| wall(c, side) <= 0.05 && (c.0 - corner_x + 0.15).abs() <= 0.05)
                .count()
        };
        for side in [1.0, -1.0] {
            assert_eq!(before_corner(&before, side), 0, "{side}: {before:?}");
            assert!(before_corner(&joined, side) > 2, "{side}: {joined:?}");
        }
        assert!(
            joined.iter().any(|c| (c.0 - corner_x).hypot(c.1) <= 0.05),
            "{joined:?}"
        );
    }

    #[test]
    fn a_one_ended_region_short_of_the_lobe_is_placed_beyond_its_readings() {
        let occupied =
            |m: &Mapper, x: f32, y: f32| probability_at(m, x, y).is_some_and(|p| p > 0.5);
        // The wall x = 1, its foot at 0°, heard within the lobe (±27°); the sweep starts at 10°,
        // so the region runs from its limit to its natural end at 27°, 17° wide.
        let m = region_scan(
            crate::model::SmoothModel {
                region_one_end: true,
                ..Default::default()
            },
            &sweep((0.0, 0.0), (10.0, 60.0), 1, |a| (a <= 27.0).then_some(1.0)),
        );
        // Before any whole region the lobe is the beam's 30° less half a step: the foot a lobe in
        // from 27°, at −2.25°, beyond the first reading; its patch a quarter lobe each side.
        assert!(occupied(&m, 1.01, -0.03));
        assert!(!occupied(&m, 1.01, 0.2));
        assert!(!occupied(&m, 1.01, -0.25));
    }

    #[test]
    fn a_far_wall_is_drawn_no_farther_along_than_its_half_width_in_metres() {
        // The wall x = 3 heard square from the origin within ±27°: its region 54° wide, its
        // patch 18° each side (0.97 m at 3 m) by the angle alone.
        let wall = sweep((0.0, 0.0), (-60.0, 60.0), 1, |a| {
            (a.abs() <= 27.0).then_some(3.0)
        });
        let scan = |half_width_m: f32| {
            let model = crate::model::SmoothModel {
                region_half_width_m: half_width_m,
                ..Default::default()
            };
            region_scan(model, &wall)
        };
        let occupied = |m: &Mapper, y: f32| probability_at(m, 3.01, y).is_some_and(|p| p > 0.5);
        let angle_alone = scan(0.0);
        assert!(occupied(&angle_alone, 0.3) && occupied(&angle_alone, 0.8));
        let metres = scan(0.5);
        assert!(occupied(&metres, 0.3) && occupied(&metres, -0.3));
        assert!(!occupied(&metres, 0.6) && !occupied(&metres, -0.6));
    }

    #[test]
    fn a_region_cut_short_by_nearer_echoes_clears_up_to_them_when_asked() {
        // Two posts at 1 m, heard whole on either side; the reading between them, along +x,
        // hears the wall behind at 2 m, its region cut short on both sides.
        let readings = [
            (-36.0, None),
            (-24.0, Some(1.0)),
            (-12.0, Some(1.0)),
            (0.0, Some(2.0)),
            (12.0, Some(1.0)),
            (24.0, Some(1.0)),
            (36.0, None),
        ]
        .map(|(a, r)| reading(a, r));
        let scan = |masked_free: bool| {
            let model = crate::model::SmoothModel {
                region_masked_free: masked_free,
                ..Default::default()
            };
            region_scan(model, &readings)
        };
        let at = |m: &Mapper, x: f32| {
            let g = *m.grid().geometry();
            let (cx, cy) = g.cell_at(nalgebra::Point2::new(x, 0.01)).unwrap();
            m.grid().probability(cx, cy)
        };
        // Without the option the gap is never observed: the posts' readings are 12° off.
        let off = scan(false);
        assert_eq!(at(&off, 0.5), None);
        let on = scan(true);
        assert!(at(&on, 0.5).is_some_and(|p| p < 0.5), "{:?}", at(&on, 0.5));
        // Free only in front of the posts' range less its tolerance (4 cm) and band (2.5 cm);
        // nothing at the wall, whose region is not placed.
        assert_eq!(at(&on, 0.97), None);
        assert_eq!(at(&on, 2.0), None);
    }

    /// A wall along x = 2 m heard square from (0, 0) and from (0, 1.6) (the foot in a ±9° lobe),
    /// after readings from (1.2, −0.6) crossed it at 62–66° of incidence near y = 1 m, silent
    /// there, and heard something at 3 m beyond it; with `doorway`, readings from (0.5, 1.1)
    /// square to it there heard 3.5 m through it. Returns the occupancy at (2, 0.45), on the
    /// stretch between the two patches and out of the other readings' cones (`None`: unknown).
    /// Where a doorway's readings come: none, between the two feet's sweeps, after both.
    #[derive(Clone, Copy, PartialEq)]
    enum Doorway {
        None,
        Between,
        Last,
    }

    fn stretch_after_slanted_readings(foot_check: bool, doorway: Doorway) -> Option<f32> {
        stretch_after_slanted_readings_at(foot_check, false, doorway, 0.45)
    }

    /// [`stretch_after_slanted_readings`], with `region_stretch_withdrawn_at_feet` as `at_feet`,
    /// the occupancy at (2, `y`).
    fn stretch_after_slanted_readings_at(
        foot_check: bool,
        at_feet: bool,
        doorway: Doorway,
        y: f32,
    ) -> Option<f32> {
        let mut m = region_mapper(crate::model::SmoothModel {
            region_stretch_foot_check: foot_check,
            region_stretch_withdrawn_at_feet: at_feet,
            ..Default::default()
        });
        let wall = |a: f32| (a.abs() <= 9.0).then_some(2.0);
        let mut sweeps = vec![
            sweep((1.2, -0.6), (40.0, 80.0), 1, |a| {
                (62.0..=66.0).contains(&a).then_some(3.0)
            }),
            sweep((0.0, 0.0), (-30.0, 30.0), 1, wall),
        ];
        let doorway_sweep = || {
            sweep((0.5, 1.1), (-30.0, 30.0), 1, |a| {
                (a.abs() <= 9.0).then_some(3.5)
            })
        };
        if doorway == Doorway::Between {
            sweeps.push(doorway_sweep());
        }
        sweeps.push(sweep((0.0, 1.6), (-30.0, 30.0), 1, wall));
        if doorway == Doorway::Last {
            sweeps.push(doorway_sweep());
        }
        for one in &sweeps {
            for obs in one {
                m.update(obs).unwrap();
            }
            m.close_region();
        }
        let (x, y) = m.grid().geometry().cell_at(Point2::new(2.0, y))?;
        m.grid().probability(x, y)
    }

    #[test]
    fn a_wall_between_two_feet_is_refused_by_a_reading_that_should_have_heard_it_not_by_slanted_ones()
     {
        // The grid's free cells near y = 1 m refuse the whole stretch: the slanted readings
        // cleared them.
        assert!(stretch_after_slanted_readings(false, Doorway::None).is_none_or(|p| p < 0.5));
        // No reading's lobe held a foot on the stretch: drawn.
        assert!(stretch_after_slanted_readings(true, Doorway::None).is_some_and(|p| p > 0.5));
        // The readings from (0.5, 1.1) had its foot on their axes and heard 1.5 m beyond it.
        assert!(stretch_after_slanted_readings(true, Doorway::Between).is_none_or(|p| p < 0.5));
    }

    #[test]
    fn a_wall_drawn_between_two_feet_is_taken_back_when_a_later_reading_refutes_it() {
        // The doorway's readings come after the stretch was drawn: it is taken back at the
        // sweep's end, its cell back to what it was without it.
        let before = stretch_after_slanted_readings(false, Doorway::None);
        let after = stretch_after_slanted_readings(true, Doorway::Last);
        assert!(after.is_none_or(|p| p <= 0.5), "{after:?}");
        let (before, after) = (before.unwrap_or(0.5), after.unwrap_or(0.5));
        assert!((before - after).abs() < 0.05, "{before} against {after}");
    }

    #[test]
    fn a_wall_drawn_between_two_feet_is_taken_back_only_around_the_refuting_foot_when_asked() {
        let at = |at_feet: bool, y: f32| {
            stretch_after_slanted_readings_at(true, at_feet, Doorway::Last, y).unwrap_or(0.5)
        };
        // The doorway's readings refute the stretch at their foot, (2, 1.1): taken back there
        // either way.
        assert!(at(false, 1.1) <= 0.5 && at(true, 1.1) <= 0.5);
        // 0.65 m from that foot: taken back with the whole piece, or kept (as strong as drawn
        // but for the fade at the ends of the part drawn again).
        assert!(at(false, 0.45) <= 0.5, "{}", at(false, 0.45));
        let drawn = stretch_after_slanted_readings_at(true, false, Doorway::None, 0.45);
        let kept = at(true, 0.45);
        assert!(kept > 0.5, "{kept}");
        assert!(
            drawn.is_some_and(|p| (p - kept).abs() < 0.05),
            "{drawn:?} against {kept}"
        );
    }

    #[test]
    fn a_region_between_two_small_reflectors_clears_up_to_its_own_range_when_asked() {
        // Two reflectors at 1 m, `side` readings each (6° apart), either side of five readings
        // that hear a wall at 2 m along +x; nothing heard beyond them.
        let scan = |side: i32, small_cutters: bool| {
            let mut m = region_mapper(crate::model::SmoothModel {
                region_masked_free: true,
                region_small_cutters_free: small_cutters,
                ..Default::default()
            });
            let edge = 12 + 6 * side;
            for a in (-edge - 6..=edge + 6).step_by(6) {
                let range = match a.abs() {
                    a if a <= 12 => Some(2.0),
                    a if a <= edge => Some(1.0),
                    _ => None,
                };
                m.update(&reading(a as f32, range)).unwrap();
            }
            m.close_region();
            m
        };
        let at = |m: &Mapper, x: f32| {
            let g = *m.grid().geometry();
            let (cx, cy) = g.cell_at(nalgebra::Point2::new(x, 0.01)).unwrap();
            m.grid().probability(cx, cy)
        };
        let free = |p: Option<f32>| p.is_some_and(|p| p < 0.5);
        // Two posts (three readings each, ±6°, less than half the beam's 27° lobe): the gap
        // readings clear through the posts' range to their own less its tolerance (6 cm) and
        // band (2.5 cm); the wall itself, whose region is not placed, stays unknown.
        let posts = scan(3, true);
        assert!(
            free(at(&posts, 1.0)) && free(at(&posts, 1.85)),
            "{:?}",
            at(&posts, 1.0)
        );
        assert_eq!(at(&posts, 2.0), None);
        // Without the option, only up to the posts' range less tolerance and band.
        let ninth = scan(3, false);
        assert!(free(at(&ninth, 0.5)));
        assert_eq!(at(&ninth, 1.0), None);
        // Two walls' feet (eight readings each, ±21°): the axes may have crossed either wall at a
        // slant, so only up to the nearer echo, as without the option.
        let walls = scan(8, true);
        assert!(free(at(&walls, 0.5)));
        assert_eq!(at(&walls, 1.0), None);
    }

    #[test]
    fn weak_echoes_show_what_a_standing_scan_heard_where_no_region_is_placed() {
        let with = |weak: f32| {
            region_mapper(crate::model::SmoothModel {
                region_weak_echo_log_odds: weak,
                ..Default::default()
            })
        };
        let at = |m: &Mapper, x: f32| {
            let g = *m.grid().geometry();
            let (cx, cy) = g.cell_at(nalgebra::Point2::new(x, 0.01)).unwrap();
            m.grid().probability(cx, cy)
        };
        // A wall heard at 1 m from the scan's one limit to the other: no natural end, no region
        // placed.
        let wall = |m: &mut Mapper| {
            for k in -5..=5 {
                m.update(&reading(6.0 * k as f32, Some(1.0))).unwrap();
            }
            m.close_region();
        };
        let mut off = with(0.0);
        wall(&mut off);
        assert_eq!(at(&off, 1.0), None);
        let mut on = with(0.3);
        wall(&mut on);
        assert!(at(&on, 1.0).is_some_and(|p| p > 0.5), "{:?}", at(&on, 1.0));
        // Nothing in front of the echo: no free evidence.
        assert_eq!(at(&on, 0.5), None);
        // Behind a board heard whole at 0.5 m, what the axis met would have answered nearer: the
        // echo from beyond it is not drawn.
        let mut behind = with(0.3);
        for (a, r) in [(-18.0, None), (-12.0, Some(0.5)), (-6.0, Some(0.5))]
            .into_iter()
            .chain([
                (0.0, Some(0.5)),
                (6.0, Some(0.5)),
                (12.0, Some(0.5)),
                (18.0, None),
            ])
        {
            behind.update(&reading(a, r)).unwrap();
        }
        behind.close_region();
        assert!(at(&behind, 0.5).is_some_and(|p| p > 0.5));
        wall(&mut behind);
        assert!(
            at(&behind, 1.0).is_none_or(|p| p <= 0.5),
            "{:?}",
            at(&behind, 1.0)
        );
    }

    #[test]
    fn a_weak_echo_drawn_as_a_point_claims_nothing_across_its_axis() {
        // One reading at 0° hearing 1 m, alone in its sweep: its region has no natural end, so
        // only a weak echo is drawn, on the axis y = 0 at x = 1 m.
        let heard = |half_width_m: f32| {
            let mut m = region_mapper(crate::model::SmoothModel {
                region_weak_echo_log_odds: 0.3,
                region_weak_echo_half_width_m: half_width_m,
                ..Default::default()
            });
            m.update(&reading(0.0, Some(1.0))).unwrap();
            m.close_region();
            let g = *m.grid().geometry();
            // The cell centres beside the axis (cell edges lie on multiples of 2 cm): 1 cm off
            // it (0.6° at 1 m) and 5 cm off it (2.9°, within the occupied profile's 6°).
            [0.01, 0.05].map(|y| {
                let (cx, cy) = g.cell_at(nalgebra::Point2::new(1.01, y)).unwrap();
                m.grid().probability(cx, cy).is_some_and(|p| p > 0.5)
            })
        };
        // Across the occupied profile, an arc: 5 cm off the axis is drawn too.
        assert_eq!(heard(0.0), [true, true]);
        // A point a cell (2 cm) wide: the axis's cells only.
        assert_eq!(heard(0.02), [true, false]);
    }

    #[test]
    fn a_wall_heard_beside_a_post_has_its_weak_echo_where_its_reflector_lies() {
        // From the origin, readings every 1.5°, two sweeps: a thin post at 0.9 m heard within ±15°
        // (a whole region, which teaches the lobe: ±15°), the wall along x = 1.2 behind it heard
        // at its perpendicular 1.2 m from 16.5° to 19.5° on either side, farther beyond. The
        // wall's foot lies behind the post; those readings heard it at their lobe's edge: the
        // reading at 21° did not, so the wall's reflector lies less than 15° from 21°, and every
        // reading of the region heard it, within 15° of 19.5°: between 4.5° and 6°.
        let heard = |at_reflector: bool| {
            let mut m = region_mapper(crate::model::SmoothModel {
                region_weak_echo_log_odds: 0.3,
                region_weak_echo_half_width_m: 0.02,
                region_weak_echo_at_reflector: at_reflector,
                ..Default::default()
            });
            for obs in sweep((0.0, 0.0), (-39.0, 39.0), 2, |deg: f32| {
                Some(match deg.abs() {
                    a if a <= 15.0 => 0.9,
                    a if a <= 20.0 => 1.2,
                    _ => 1.5,
                })
            }) {
                m.update(&obs).unwrap();
            }
            m.close_region();
            let occupied = |deg: f32| {
                let (s, c) = (deg * DEG).sin_cos();
                probability_at(&m, 1.2 * c, 1.2 * s).is_some_and(|p| p > 0.5)
            };
            // On the reflector's bearing, 0.6 cm in front of the wall; on the readings' axes,
            // 6–7 cm in front of it.
            [5.25, -5.25, 18.0, -18.0].map(occupied)
        };
        // The first sweep heard the wall at −16.5° to −19.5° before the post taught it the lobe:
        // those weak echoes are on their axes.
        assert_eq!(heard(true), [true, true, false, true]);
        assert_eq!(heard(false), [false, false, true, true]);
    }

    /// From the origin, an echo at 1 m heard from one limit of the scan to the other: no region,
    /// a weak echo on each of its 11 axes, among them (1, 0) on the axis along +x.
    fn hear_far_echo_across_the_scan(m: &mut Mapper) {
        for k in -5..=5 {
            m.update(&reading(6.0 * k as f32, Some(1.0))).unwrap();
        }
        m.close_region();
    }

    /// A board lying along the +x axis, x in [0.3, 0.7] on y = 0, heard whole from (0.5, -0.5)
    /// looking along +y: the axis meets it edge-on (90° from the bearing it was heard from), so
    /// it could not have answered [`hear_far_echo_across_the_scan`]'s reading along +x; that
    /// echo came from beside the axis.
    fn hear_board_across_the_x_axis(m: &mut Mapper) {
        let below = Isometry2::new(Vector2::new(0.5, -0.5), std::f32::consts::FRAC_PI_2);
        for (a, r) in [
            (-24.0, None),
            (-18.0, Some(0.5)),
            (-12.0, Some(0.5)),
            (-6.0, Some(0.5)),
            (0.0, Some(0.5)),
            (6.0, Some(0.5)),
            (12.0, Some(0.5)),
            (18.0, Some(0.5)),
            (24.0, None),
        ] {
            m.update(&Observation {
                pose: below,
                ..reading(a, r)
            })
            .unwrap();
        }
        m.close_region();
    }

    /// The probability of the cell holding (x, y).
    fn probability_at(m: &Mapper, x: f32, y: f32) -> Option<f32> {
        let g = *m.grid().geometry();
        let (cx, cy) = g.cell_at(nalgebra::Point2::new(x, y)).unwrap();
        m.grid().probability(cx, cy)
    }

    #[test]
    fn a_weak_echo_is_taken_back_once_a_wall_its_axis_meets_at_a_slant_is_drawn_in_front() {
        let far = hear_far_echo_across_the_scan;
        let board = hear_board_across_the_x_axis;
        let mapper = |withdrawn: bool, board_first: bool| {
            let mut m = region_mapper(crate::model::SmoothModel {
                region_weak_echo_log_odds: 0.3,
                region_weak_echo_withdrawn: withdrawn,
                ..Default::default()
            });
            if board_first {
                board(&mut m);
                far(&mut m);
            } else {
                far(&mut m);
                board(&mut m);
            }
            m
        };
        let at = probability_at;
        let kept = mapper(false, false);
        assert!(at(&kept, 0.5, 0.0).is_some_and(|p| p > 0.75));
        assert!(at(&kept, 1.0, 0.0).is_some_and(|p| p > 0.55));
        // The wall drawn after the weak echoes, in a sweep of its own, takes them back at its
        // end; drawn before them, it keeps the one behind it from being put at all.
        for board_first in [false, true] {
            let taken_back = mapper(true, board_first);
            assert!(at(&taken_back, 0.5, 0.0).is_some_and(|p| p > 0.75));
            // Back to about the prior: the weak echo (0.3, p = 0.57) is gone, what the
            // neighbouring axes' echoes put at the edge of their footprint (6° off) stays.
            let behind = at(&taken_back, 1.0, 0.0);
            assert!(
                behind.is_some_and(|p| p < 0.52),
                "{board_first}: {behind:?}"
            );
            // An axis the board does not cross keeps its weak echo.
            let beside = at(
                &taken_back,
                1.0 * (30.0 * DEG).cos(),
                1.0 * (30.0 * DEG).sin(),
            );
            assert!(beside.is_some_and(|p| p > 0.5), "{board_first}: {beside:?}");
        }
    }

    #[test]
    fn from_the_middle_gives_every_number_once_nearest_the_middle_first() {
        for last in 0..40 {
            let order: Vec<usize> = from_the_middle(last).collect();
            let mut sorted = order.clone();
            sorted.sort_unstable();
            assert_eq!(sorted, (0..=last).collect::<Vec<_>>(), "{last}: {order:?}");
            let off = |j: usize| j.abs_diff(last / 2);
            assert!(
                order.windows(2).all(|w| off(w[0]) <= off(w[1])),
                "{order:?}"
            );
        }
        assert_eq!(from_the_middle(4).collect::<Vec<_>>(), [2, 3, 1, 4, 0]);
        assert_eq!(from_the_middle(3).collect::<Vec<_>>(), [1, 2, 0, 3]);
    }

    #[test]
    fn a_sector_box_holds_its_whole_sector() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..200 {
            let position = Vector2::new(rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0));
            let axis: f32 = rng.random_range(-3.1..3.1);
            let range: f32 = rng.random_range(0.05..4.0);
            let lobe: f32 = rng.random_range(0.05..0.8);
            let depth: f32 = rng.random_range(0.0..0.3);
            let (lower, upper) = sector_box(position, axis, range, lobe, depth);
            for _ in 0..50 {
                let r = (range + rng.random_range(-depth..=depth)).max(0.0);
                let bearing = axis + rng.random_range(-lobe..=lobe);
                let p = position + Vector2::new(bearing.cos(), bearing.sin()) * r;
                let inside = (lower.x - 1e-4..=upper.x + 1e-4).contains(&p.x)
                    && (lower.y - 1e-4..=upper.y + 1e-4).contains(&p.y);
                assert!(inside, "{p:?} outside {lower:?}..{upper:?}");
            }
        }
    }

    /// A wall square to the +x axis at x = 1 m, heard whole from the origin: readings −18°…18°
    /// answered at its foot, 1 m away, none at ±24° (its lobe's edges).
    fn hear_wall_square_to_the_x_axis(m: &mut Mapper) {
        for k in -4i32..=4 {
            let heard = k.abs() < 4;
            m.update(&reading(6.0 * k as f32, heard.then_some(1.0)))
                .unwrap();
        }
        m.close_region();
    }

    #[test]
    fn a_weak_echo_a_wall_in_its_lobe_explains_is_taken_back_unless_it_lies_on_that_wall() {
        // Weak echoes at 1 m on the axes −30°…30° (a region the scan's ends cut), then the wall
        // at x = 1 m heard whole from the same place: it answers any reading whose lobe holds
        // its foot at 1 m, so those echoes may all be its. Along an axis more than about 20° off
        // the wall's perpendicular the wall lies farther than 1 m plus the depth tolerance and
        // band (6.5 cm here): that axis's weak echo was drawn in front of the wall.
        let mapper = |explained: bool| {
            let mut m = region_mapper(crate::model::SmoothModel {
                region_weak_echo_log_odds: 0.3,
                region_weak_echo_withdrawn: true,
                region_weak_echo_explained: explained,
                ..Default::default()
            });
            hear_far_echo_across_the_scan(&mut m);
            hear_wall_square_to_the_x_axis(&mut m);
            m
        };
        let kept_axes = |m: &Mapper| {
            let mut axes: Vec<i32> = m
                .regions
                .as_ref()
                .unwrap()
                .weak
                .kept
                .iter()
                .map(|k| (k.placed[0].beam.axis / DEG).round() as i32)
                .collect();
            axes.sort_unstable();
            axes
        };
        let (without, with) = (mapper(false), mapper(true));
        assert_eq!(
            kept_axes(&without),
            (-5..=5).map(|k| 6 * k).collect::<Vec<_>>()
        );
        assert_eq!(kept_axes(&with), vec![-18, -12, -6, 0, 6, 12, 18]);
        // The echo on the 30° axis, in front of the wall, is gone; without the check it stays
        // (0.3, p = 0.57).
        let (x, y) = ((30.0 * DEG).cos(), (30.0 * DEG).sin());
        let kept = probability_at(&without, x, y);
        assert!(kept.is_some_and(|p| p > 0.55), "{kept:?}");
        let gone = probability_at(&with, x, y);
        assert!(gone.is_some_and(|p| p < 0.51), "{gone:?}");
    }

    #[test]
    fn weak_echoes_heard_a_thousand_times_from_one_place_are_kept_once_and_still_taken_back() {
        let mut m = region_mapper(crate::model::SmoothModel {
            region_weak_echo_log_odds: 0.3,
            region_weak_echo_withdrawn: true,
            ..Default::default()
        });
        for _ in 0..1000 {
            hear_far_echo_across_the_scan(&mut m);
        }
        // How many sets of weak echoes are kept, and the hearings of the one along +x.
        let kept = |m: &Mapper| {
            let weak = &m.regions.as_ref().unwrap().weak.kept;
            let along_x = weak
                .iter()
                .find(|k| k.placed[0].beam.axis.abs() < 1e-3)
                .map(|k| (k.placed.len(), k.placed[0].heard));
            (weak.len(), along_x)
        };
        // One kept per axis, counting its 1000 hearings, not 1000 copies of each (4096 kept).
        assert_eq!(kept(&m), (11, Some((1, 1000))));
        assert!(probability_at(&m, 1.0, 0.0).is_some_and(|p| p > 0.9));
        hear_board_across_the_x_axis(&mut m);
        // The one along +x is taken back with all its hearings: the cell behind the board falls
        // below the prior (the log-odds clamp held the 1000 hearings at 0.97), …
        assert_eq!(kept(&m), (10, None));
        let behind = probability_at(&m, 1.0, 0.0);
        assert!(behind.is_some_and(|p| p < 0.5), "{behind:?}");
        // … an axis the board does not cross keeps its weak echo.
        let beside = probability_at(&m, 1.0 * (30.0 * DEG).cos(), 1.0 * (30.0 * DEG).sin());
        assert!(beside.is_some_and(|p| p > 0.9), "{beside:?}");
    }

    #[test]
    fn a_placed_one_ended_region_clears_in_front_of_it_with_region_one_end_free() {
        // A wall 1 m ahead heard from the sweep's start (nothing known before it) over 48°, then
        // not: one-ended, as a servo head's side wall heard up to its limit is.
        let probability_half_way = |free: bool| {
            let mut m = region_mapper(crate::model::SmoothModel {
                region_one_end: true,
                region_one_end_free: free,
                ..Default::default()
            });
            for k in 0..10 {
                let a = -27.0 + 6.0 * k as f32;
                m.update(&reading(a, (k < 9).then_some(1.0))).unwrap();
            }
            m.close_region();
            let geometry = m.grid().geometry();
            let (x, y) = geometry
                .cell_at(Point2::new(
                    0.5 * (-15.0 * DEG).cos(),
                    0.5 * (-15.0 * DEG).sin(),
                ))
                .unwrap();
            let wall = cells(&m).iter().any(|p| p.is_some_and(|p| p > 0.5));
            (m.grid().probability(x, y), wall)
        };
        let (without, wall) = probability_half_way(false);
        assert!(wall, "the region is placed");
        assert_eq!(without, None, "its readings clear nothing");
        let (with, wall) = probability_half_way(true);
        assert!(wall, "the region is placed");
        assert!(with.is_some_and(|p| p < 0.5), "{with:?}");
    }

    #[test]
    fn one_ended_regions_are_placed_even_if_no_sweep_ever_ends() {
        let mut m = region_mapper(crate::model::SmoothModel {
            region_one_end: true,
            ..Default::default()
        });
        // Runs of readings 30° apart (a gap: nothing known before each), 54° of echo at 1 m and
        // then none: one-ended regions, and no end of a sweep.
        for run in 0..1000 {
            let start = -170.0 + 90.0 * (run % 4) as f32;
            for k in 0..10 {
                let a = start + 6.0 * k as f32;
                m.update(&reading(a, (k < 9).then_some(1.0))).unwrap();
            }
        }
        let deferred = m.regions.as_ref().map(|r| r.one_ended.len());
        assert!(
            deferred.is_some_and(|n| n < DEFERRED_REGIONS),
            "{deferred:?}"
        );
        assert!(cells(&m).iter().any(|p| p.is_some_and(|p| p > 0.5)));
    }

    #[test]
    fn a_board_passed_edge_on_or_beside_survives_and_empty_space_is_still_cleared() {
        // The weighting by incidence, with each reading's echo on its own axis: here the sweeps
        // from the two other positions hear one range end to end, a region with no natural end,
        // which placed by region would give no evidence at all.
        let recommended = crate::model::SmoothModel {
            echo_placement: crate::model::EchoPlacement::Reading,
            ..Default::default()
        };
        let (m, rows) = board_scene(recommended, false);
        assert!(rows.iter().all(|&p| p > 0.5), "{rows:?}");
        // Without the weighting by incidence (every cell takes full free evidence, as the smooth
        // model did before), the same readings erase the board.
        let deaf = crate::model::SmoothModel {
            incidence_full_deg: 90.0,
            incidence_none_deg: 180.0,
            ..recommended
        };
        let (_, erased) = board_scene(deaf, false);
        assert!(erased.iter().all(|&p| p < 0.5), "{erased:?}");
        // Space no reading heard occupied is cleared: between the board and the edge-on sensor.
        let g = *m.grid().geometry();
        for y in [-1.0f32, -0.6, -0.35] {
            let (cx, cy) = g.cell_at(nalgebra::Point2::new(1.01, y)).unwrap();
            let p = m.grid().probability(cx, cy).unwrap();
            assert!(p < 0.2, "({}, {y}): {p}", 1.01);
        }
        // A board taken away is cleared by readings that would have heard it: from where it was
        // heard.
        let (_, gone) = board_scene(recommended, true);
        assert!(gone.iter().all(|&p| p < 0.5), "{gone:?}");
    }

    /// A restored map remembers where its cells were heard from: it fuses on like the original
    /// (without the bearings, the edge-on readings below would erase the board in the copy only).
    #[test]
    fn a_restored_map_keeps_the_bearings_its_cells_were_heard_from() {
        let (mut original, _) = board_scene(crate::model::SmoothModel::default(), false);
        let mut saved = MapperState::default();
        original.save_into(&mut saved);
        assert_eq!(saved.heard.len(), original.grid().geometry().len());
        assert!(saved.heard.iter().any(|h| !h.is_nan()));
        let mut restored = Mapper::restore(*original.config(), saved.clone()).unwrap();
        for obs in sweep((1.0, -1.5), (75.0, 105.0), 3, |_| Some(3.0)) {
            original.update(&obs).unwrap();
            restored.update(&obs).unwrap();
        }
        assert_eq!(fingerprint(&original), fingerprint(&restored));
        // Bearings the settings have no room for are refused.
        let deaf = FusionConfig {
            model: ModelConfig::default_for(ModelKind::Paper),
            ..*original.config()
        };
        assert!(matches!(
            Mapper::restore(deaf, saved),
            Err(StateError::Length {
                what: "the heard bearings",
                ..
            })
        ));
    }

    #[test]
    fn no_echo_clears_up_to_max_range_and_marks_nothing() {
        let mut paper = Mapper::new(FusionConfig::preset(Preset::Paper)).unwrap();
        let u = paper.update(&reading(33.0, None)).unwrap();
        assert_eq!(u.cells_updated, 0);
        assert_eq!(u.radar_bin, Some(30));
        assert_eq!(paper.readings_fused(), 1);

        let mut m = Mapper::new(FusionConfig {
            clear_on_no_echo: true,
            ..FusionConfig::default()
        })
        .unwrap();
        for obs in [reading(33.0, None), reading(-33.0, Some(4.0))] {
            let u = m.update(&obs).unwrap();
            assert!(u.cells_updated > 1000);
        }
        assert_eq!(m.radar().distances_m()[30], f32::INFINITY);
        let g = *m.grid().geometry();
        let mut bytes = vec![0; g.len()];
        let counts = m.grid_mut().encode_into(&mut bytes);
        assert_eq!(counts.occupied, 0);
        assert!(counts.free > 1000);
        for y in 0..g.cells_per_side() {
            for x in 0..g.cells_per_side() {
                if g.cell_centre(x, y).coords.norm() > 4.0 {
                    assert_eq!(m.grid().probability(x, y), None);
                }
            }
        }
        m.clear();
        assert_eq!(m.readings_fused(), 0);
        assert_eq!(m.grid().probability(250, 250), None);
        assert!(m.radar().distances_m().iter().all(|d| d.is_nan()));
    }

    #[test]
    fn readings_are_fused_at_the_robot_pose() {
        // One reading: with the echo on its own axis (placed by region, one reading with nothing
        // beside it is no whole region).
        let mut m = Mapper::new(FusionConfig {
            model: ModelConfig::Smooth(crate::model::SmoothModel {
                echo_placement: crate::model::EchoPlacement::Reading,
                ..Default::default()
            }),
            ..FusionConfig::default()
        })
        .unwrap();
        // The robot 1 m along y, heading along y; the sensor's 0° looks along the world's y.
        let pose = Isometry2::new(Vector2::new(0.0, 1.0), 90.0 * DEG);
        let obs = Observation {
            pose,
            ..reading(0.0, Some(1.5))
        };
        m.update(&obs).unwrap();
        assert_eq!(m.last_pose(), pose);
        let g = *m.grid().geometry();
        let at = |x: f32, y: f32| {
            let (cx, cy) = g.cell_at(nalgebra::Point2::new(x, y)).unwrap();
            m.grid().probability(cx, cy)
        };
        assert!(at(0.01, 2.51).unwrap() > 0.5);
        assert!(at(0.01, 1.51).unwrap() < 0.5);
        assert_eq!(at(2.51, 0.01), None);
    }

    #[test]
    fn invalid_observations_change_nothing() {
        let mut m = Mapper::new(FusionConfig::default()).unwrap();
        let bad = Observation {
            angle_rad: f32::NAN,
            ..reading(0.0, Some(1.0))
        };
        assert_eq!(
            m.update(&bad),
            Err(ObservationError::NotFinite("angle_rad"))
        );
        assert_eq!(m.readings_fused(), 0);
        assert!(m.radar().current_angle_deg().is_none());
    }
}
