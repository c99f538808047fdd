//! `sonar-eval`: the paper's four scenes (Figs. 8–11) run through the pipeline's real code and
//! measured against the scenes' ground truth; the figures behind `docs/results.md`.
//!
//! # Design
//!
//! The evaluation runs the pipeline minus its transport, in one process and deterministically
//! ([`pipeline`]):
//!
//! 1. the simulator's library (`sonar-sim`) plays the device: [`sonar_sim::NativeDevice`] around
//!    the firmware state machine and the echo model, seeded, on its virtual clock, writing the
//!    protocol's lines;
//! 2. the driver's library (`sonar-driver`) reads them: the line framer, the [`Decoder`] with the
//!    driver's default ping policy (dominant cluster of the four pings), after the same handshake
//!    (`HELLO`, adopt the device's geometry, then the scan command: local scans for the corner and
//!    obstacle scenes, a full scan for the room, as in the paper);
//! 3. the fusion library (`sonar-fusion`) builds the maps from the driver's readings through
//!    [`Observation::from_reading`] into a [`Mapper`] per preset (`paper` and `recommended`); the
//!    basic method is the mapper's radar array drawn by `RadarMap::rasterise_into` across the
//!    reading's beam (±30°), the probability method its grid.
//!
//! Only the pseudo-terminal, the wall-clock pacing and iceoryx2 are left out, so a run depends on
//! the scene, the scan, the number of complete sweeps and the seed alone, and repeats bit for bit.
//!
//! [`metrics`] turns a map and the scene's truth into figures (a post's apparent width across the
//! ray, whether the gap between two posts shows, how close the occupied cells lie to the true walls
//! and how much of the visible walls they cover), each defined there and unit-tested on synthetic
//! grids. [`image`] draws the paper-style pictures (basic | probability | actual setup, one row per
//! preset). [`report`] runs the scenes and the two-post spacing sweep and writes the Markdown
//! tables; the `sonar-eval` binary wires it to a command line.
//!
//! [`Decoder`]: sonar_driver::decoder::Decoder
//! [`Observation::from_reading`]: sonar_fusion::Observation::from_reading
//! [`Mapper`]: sonar_fusion::Mapper

pub mod calibration;
pub mod feature_report;
pub mod features;
pub mod image;
pub mod landmarks;
pub mod metrics;
pub mod motion;
pub mod pipeline;
pub mod report;
pub mod scenegen;
pub mod slam;
pub mod suite;
