//! Map files from `sonar/grid` snapshots: what a user keeps of a mapping run.
//!
//! Every writer takes a [`Map`], the snapshot's [`GridHeader`] and its cells exactly as published
//! (`width × height` bytes, row 0 at the lowest y, `round(p · 254)`, 255 = never observed; see
//! `docs/ipc.md`), so the live consumer, the offline export and the viewer share one code path.
//!
//! - [`colour`]: the colour code of the maps (blue free → pale even odds → red occupied, dark grey
//!   unknown), shared with the terminal viewer.
//! - [`canvas`]: an RGB picture and its PNG encoding, shared with the evaluation's figures.
//! - [`picture`]: PNG, one pixel per cell, highest y on top, optionally with a legend strip (scale
//!   bar and colour ramp).
//! - [`ros`]: a ROS `map_server` map, trinary PGM + YAML.
//! - [`table`]: the probabilities as CSV and as a NumPy `.npy` array (`float32`, NaN = unknown).
//! - [`output`]: formats, file names, and writing files so that no half-written map is ever seen.
//! - [`features`]: the walls, corners and posts of a `sonar/features` snapshot as CSV and JSON.
//! - [`settings`]: names of the model, rule and preset codes of a snapshot header.
//! - [`viewport`]: which cells each pixel of a picture of the map shows (the viewer's zoom and
//!   pan; the PNG's one pixel per cell).
//! - [`overlay`]: the pixels showing the walls, corners and posts over the map, drawn by the
//!   viewer as glyphs and by the PNG (`sonar-export --features`) as marks.
//!
//! `docs/export.md` documents the formats and their conventions for users.

pub mod canvas;
pub mod colour;
pub mod features;
mod font;
pub mod map;
pub mod output;
pub mod overlay;
pub mod picture;
pub mod ros;
pub mod settings;
pub mod table;
pub mod viewport;

pub use features::{FeatureFormat, write_features};
pub use map::{Map, MapError};
pub use output::{Format, write_map};
pub use picture::PngOptions;
pub use ros::Thresholds;
