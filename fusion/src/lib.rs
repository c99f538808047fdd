//! Occupancy-grid fusion of sonar readings: the two maps of the paper (*Obstacle Detection and
//! Map Building with a Rotating Ultrasonic Range Sensor using Bayesian Combination*), its sensor
//! model and combination rule as written, and the alternatives we recommend instead.
//!
//! `docs/fusion.md` is the user-facing version of this page, with a worked example.
//!
//! # Two maps
//!
//! A [`Mapper`] feeds every reading ([`Observation`]) into both of the paper's maps:
//!
//! - the **basic method** (§III.A), [`RadarMap`]: the latest range per angle bin (by default one
//!   bin per reading centre of the sweep, −147° … 147° in 6° steps), drawn as arcs across the
//!   beam width; NaN for a bin never read, +∞ when its latest reading had no echo;
//! - the **probability method** (§III.B), [`OccupancyGrid`]: a square grid centred on the world
//!   origin (by default 400 × 400 cells of 2 cm, the sensor's ±4 m), each cell holding the fused
//!   state of the combination rule. A cell no reading has reached holds the rule's "unknown"
//!   sentinel, read as the prior 0.5 but kept apart from "observed, undecided" (`None` from
//!   [`OccupancyGrid::probability`], 255 in the snapshot encoding).
//!
//! A reading is fused in two steps: a **sensor model** turns it into the occupancy evidence it
//! carries for each cell of its cone, and a **combination rule** folds that evidence into each
//! cell's state. Both are chosen in [`FusionConfig`] (`[model]` and `[rule]` in a TOML file, with a
//! `kind`), independently of each other; [`Preset`] names the two ready-made combinations.
//!
//! # Sensor models ([`ModelConfig`])
//!
//! - [`PaperModel`], the paper's eqs. 1–3 (after Murphy, the paper's \[2\]): with
//!   s = ((R − r)/R + (β − |α|)/β) / 2, region I, within the tolerance p of the range d, gets
//!   P(s|H) = s · MaxOccupied (eq. 1); region II, in front of it, 1 − s (eq. 2); region III,
//!   beyond, nothing (eq. 3). With the prior 0.5, P(H|s) = P(s|H) (eq. 4), which is what the
//!   model returns. The paper gives neither p nor MaxOccupied; we take Murphy's 5 % and 0.98.
//! - [`LogOddsModel`], the inverse range-sensor model of *Probabilistic Robotics* (Table 9.2):
//!   p_occ = 0.7 within half an obstacle thickness (5 cm) of the range, p_free = 0.3 in front of
//!   it, uniformly across the cone. The textbook baseline, and the cheapest.
//! - [`SmoothModel`], after ROS `range_sensor_layer`: free evidence in front of the range and
//!   occupied evidence in a band d ± w around it (w = max(2.5 cm, 1 % of d)), each falling off
//!   smoothly with the angle off the axis (by default free evidence to zero at 7°, occupied at
//!   6°) and with range (a radial trust that halves at 3 m). It never raises occupancy in front of
//!   that band, nor lowers it within the band. Its free evidence at a cell that was heard
//!   occupied is weighted by the incidence at which the reading meets that reflector (the angle
//!   between the bearings it is seen from now and was heard from): full from the bearing it was heard from, none from 10° off it,
//!   since a specular board seen edge-on or at a slant is silent and its silence is no evidence
//!   that it is gone (`docs/fusion.md`, "Free space only where a reflector would have been heard").
//!
//! Why the recommended parameters ([`SmoothModel::default`], to which the recommended preset adds
//! echoes placed by region of constant depth, `docs/fusion.md`; `docs/results.md` has the evaluation
//! they come from, on the simulator; the angles and the incidence weighting were re-chosen on the
//! generated scene suite for issue 23, `docs/fusion.md`): a small or weak target is heard only
//! near the axis (a 5 cm post at 1 m within roughly ±10–15°, a thin board less), a wall across
//! much of the ±30° beam. Free evidence is therefore given only within ±7°, about where such a
//! target would have been heard: with free evidence over the whole cone, the readings aimed beside
//! a post cleared the post itself. Occupied evidence stays within ±6° and is weaker than free
//! evidence (+1 against −1.5 in log-odds on the axis): each reading claims its echo near its
//! axis, and the claims of readings aimed beside a small object are refuted by the neighbours that
//! heard past it. The band's 2.5 cm
//! covers the SRF05's quoted 3–4 cm accuracy. Far readings are the ones multipath spoils (a flat
//! surface beyond the specular cut-off returns phantom ranges of 2.5–3.4 m), hence the trust fading
//! from 3 m. With the log-odds rule's clamps (−2 and 3.5), no single reading decides a cell, and
//! contrary readings can always undo it.
//!
//! ## β and α: the paper's conventions, and where to change them
//!
//! - **β, full width or half width.** The paper calls β "the beam width" but tests membership
//!   with ±30°, and Murphy defines β as half the field of view. As the half-angle (30°), the
//!   term (β − |α|)/β runs from 1 on the axis to 0 at the cone's edge, like (R − r)/R from the
//!   sensor to the maximum range; as the full width (60°) it never falls below one half. We read
//!   β as the half-angle: [`BeamWidth::HalfAngle`], the default; `beam_width = "full-width"` in
//!   `[model]` selects the other reading ([`PaperModel::beam_width`]). Either way a cell belongs
//!   to the cone when |α| ≤ the beam's half-angle.
//! - **α, signed or absolute.** The paper defines α = a − θ (signed) and writes (β − α)/β. Taken
//!   literally the model is not symmetric about the beam axis: one edge of the cone gets
//!   (β + β)/β = 2 and probabilities leave [0, 1]. Murphy's model is symmetric; we use |α|
//!   ([`AlphaSign::Absolute`], the default) and keep the literal form as `alpha = "signed"`
//!   ([`PaperModel::alpha`]), its results clamped to [0, 1].
//!
//! ## The flaw of eq. 2, kept by the paper preset
//!
//! Eq. 2 gives P(s|H) = 1 − s in region II, in front of the echo. Wherever
//! (R − r)/R + (β − |α|)/β < 1, that is s < 1/2 — far from the sensor or near the cone's edge —
//! it gives **P(s|H) > 0.5: evidence of occupancy in front of the echo**, where the echo says
//! there is nothing. With R = 4 m and β = 30° that is every cell with |α| > 7.5° · (4 − r/m): from
//! 16.5° off the axis at r = 1.8 m, for instance. Repeated over a sweep and multiplied by eq. 6,
//! these values build phantom wedges of occupied cells along the edges of every cone. (Eq. 1 has
//! the mirror flaw: s < 1/2 makes region I, where the echo came from, evidence of free space.)
//! Reading β as the full width only moves the boundary (to |α| > 15° · (4 − r/m), beyond 2 m).
//!
//! [`Preset::Paper`] keeps both flaws, as the paper is written; [`Preset::Recommended`] uses the
//! [`SmoothModel`], which never raises occupancy in front of the range's band (unit-tested, as is
//! the presence of the wedges with the paper preset).
//!
//! # Combination rules ([`RuleConfig`]) and saturation
//!
//! - [`RuleConfig::Bayes`], the paper's eq. 6, P ← p·P / (p·P + (1 − p)(1 − P)), on f32
//!   probabilities exactly as written. It saturates: once rounding has taken a cell to exactly 0
//!   or 1 (eight readings of p = 0.9 reach 1 in f32), no later reading can move it, so the map
//!   never forgets a moved obstacle. Certain evidence against a certain cell is 0/0; the cell
//!   keeps its value.
//! - [`LogOddsRule`]: l ← clamp(l + l_reading, −2, 3.5) (OctoMap's probabilities 0.12 and 0.97).
//!   The same posterior as eq. 6 inside the clamps, but no cell ever becomes certain, so
//!   contrary evidence always brings it back; infinite evidence (a model's 0 or 1) lands on the
//!   clamps.
//! - [`RuleConfig::DempsterShafer`]: masses m(occupied), m(free) per cell (the rest is
//!   ignorance); a reading's p becomes the consonant masses max(0, 2p − 1) and max(0, 1 − 2p),
//!   combined by Dempster's rule and read out as the pignistic probability. It saturates like
//!   eq. 6: a mass that reaches 1 absorbs every later reading.
//! - [`HimmRule`] (Borenstein & Koren, named by the paper): a counter 0..=15 per cell, +3 where the
//!   evidence says occupied, −1 where it says free, only within ±3° of the beam axis; read out as
//!   count / 15. It cannot saturate for good (the counter is clamped, not absorbed), but a cell
//!   starts at 0 and needs three hits to read above one half.
//!
//! A rule consumes probabilities (Bayes, Dempster–Shafer) or log-odds (log-odds, HIMM); each
//! model answers in either, natively in its own, so the pairing costs a conversion per cell only
//! where the domains differ.
//!
//! # Readings without an echo
//!
//! An SRF05 that hears nothing (or reads at or beyond its maximum range) says "nothing up to R",
//! never an obstacle. With [`FusionConfig::clear_on_no_echo`] such a reading is fused as free
//! space up to the maximum range: every model's region in front of the range extended to R, with
//! no occupied part. Both presets ignore them, the paper's because the paper does, the recommended
//! one because a surface met beyond the specular cut-off (at grazing incidence) is silent, not
//! absent: in the evaluation (`docs/results.md`) clearing erased most of a wall. The paper's
//! model should not clear in any case: its eq. 2 near R is strong occupancy evidence off the axis.
//!
//! # Poses
//!
//! [`Observation::pose`] places the sensor's rotation axis in the world (the identity while the
//! robot stands still); the beam's world bearing is the pose's heading plus the sensor angle. The
//! grid stays fixed in the world, centred on the origin; a reading from anywhere updates the cells
//! of its cone that lie on the grid.
//!
//! # Fast kernel and reference
//!
//! [`Kernel::WholeGrid`] ([`mod@reference`]) is the paper's implementation (§III.B.2): arrays of
//! every cell's bearing and range from the sensor, an AngleInside mask rewritten over the whole
//! grid per reading, and the model and rule at every cell inside it. It is the yardstick.
//! [`Kernel::Cone`] ([`kernel`], the default) visits only the cells of the cone, narrowed to the
//! angles at which the rule updates and the model gives evidence (HIMM's ±3°, the smooth model's
//! profiles): per beam direction, the first and last column in each row around the sensor's cell
//! that the cone can hold wherever the sensor sits within its cell; branch-free inner loops over
//! contiguous rows, widened to whole vectors, that the compiler vectorises (with 256-bit vectors
//! where the CPU has AVX2 and 512-bit ones with AVX-512, detected at run time), each cell's range
//! and bearing computed in the loop, so a moving sensor keeps the fast path; for a sensor parked
//! at one position within a cell (16 readings in a row), a stencil of those ranges and bearings,
//! filled as readings visit its cells, loaded instead. Both kernels compute each cell's range and
//! bearing with the same function (a square root and an arctangent of our own that vectorises) and
//! update the same cells with the same values, to the last bit by construction: a property test
//! runs random readings (poses on and off the grid, parked and moving, every model and rule)
//! through both and compares the grids bit for bit, and a unit test runs stepper angles and
//! arbitrary ones through both and compares the grids and their encodings.
//! `docs/benchmarks.md` has the figures.
//!
//! # A moving robot, and the features beside the grid
//!
//! [`poses`] keeps the recent poses of `robot/pose` and places each reading at the pose
//! interpolated at its own stamp (bounded extrapolation when the pose stream lags; stale poses
//! counted). [`features`] groups the readings by sweep for the feature map of the
//! `sonar-features` crate (walls, corners, posts: `sonar/features`), each reading's pings brought
//! from the pose of its instant to the sweep's first reading's, and, with localisation on, matches
//! each sweep (taken still or on the move) against it to estimate the odometry's drift; only
//! sweeps taken still are merged into it. The engine then places the
//! readings that follow at that correction times the odometry's pose
//! ([`engine::Engine::set_correction`]).
//!
//! # Surviving a restart, and knowing what was missed
//!
//! [`engine::Engine::capture`] takes the engine's whole state ([`state`]: the cells in the rule's
//! own representation, the radar, the observations kept for re-fusing, poses, counters) and
//! [`engine::Engine::restore`] rebuilds an engine that goes on exactly as the saved one would
//! have. [`persist`] puts that state with its settings in a checksummed file, written atomically
//! (temporary file, fsync, rename, fsync of the directory) by a [`persist::Saver`] thread off the
//! readings loop, and at start restores it only if the settings are the same, else says why. The
//! process saves every few seconds and at shutdown: a crash loses at most the last period.
//!
//! [`status`] counts, for `sonar/fusion_status`, what the process received, fused, rejected and
//! published, and the readings that never reached it: gaps in the driver's sequence numbers,
//! which is how an overflowing subscriber buffer (iceoryx2 drops the oldest sample, silently)
//! shows.
//!
//! # Memory
//!
//! Per grid cell: 4 bytes (f32) for Bayes and log-odds, 8 for Dempster–Shafer, 1 for HIMM; a
//! 2048² grid of f32 is 16 MiB, and [`config::MAX_CELLS_PER_SIDE`] (4096) bounds the largest at
//! 128 MiB. The fast kernel's stencil (once a sensor parks) holds 8 bytes per cell of a square
//! twice the reach across, plus 16 bytes per row (about 1.3 MiB at 2 cm cells, 5.4 MiB at 1 cm,
//! for the 4.2 m reach of the paper's model), and per beam direction used one span pair (16
//! bytes) per row the cone crosses. The
//! whole-grid pass keeps 9 bytes per grid cell, allocated only when it is used. Nothing is
//! allocated per reading once the caches are warm. A process that saves its map keeps a second
//! copy of the state (cells and kept observations, about 33 bytes each) for the saver, reused
//! from one save to the next.

pub mod config;
mod config_error;
mod drawn;
mod encoding;
pub mod engine;
pub mod features;
pub mod file;
pub mod geometry;
pub mod grid;
mod hidden;
pub mod history;
pub mod kernel;
mod lines;
pub mod mapper;
pub mod model;
pub mod observation;
pub mod persist;
mod points;
pub mod poses;
pub mod radar;
pub mod reference;
mod regions;
pub mod rule;
mod sightlines;
pub mod state;
pub mod status;
#[cfg(test)]
mod test_strategies;

pub use config::{ConfigError, FusionConfig, GridConfig, Preset, SensorLimits, UnknownName};
pub use engine::SavedMap;
pub use features::{FeatureTracker, SweepOutcome};
pub use file::{FeaturesSection, FusionFile, FusionFileError, FusionSection, SlamSwitch};
pub use geometry::GridGeometry;
pub use grid::{CellCounts, EncodedVersion, OccupancyGrid};
pub use mapper::{Kernel, Mapper, Update};
pub use model::{
    AlphaSign, BeamWidth, EchoPlacement, LogOddsModel, ModelConfig, ModelKind, PaperModel,
    SmoothModel,
};
pub use observation::{Observation, ObservationError};
pub use persist::{LoadError, PersistConfig, Restore, SaveError, Saver};
pub use radar::{RadarConfig, RadarMap};
pub use rule::{HimmRule, LogOddsRule, RuleConfig, RuleKind};
pub use state::{MapState, StateError};
