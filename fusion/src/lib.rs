//! Occupancy-grid fusion of sonar readings (draft docs).

pub mod config;
pub mod engine;
pub mod geometry;
pub mod grid;
pub mod kernel;
pub mod mapper;
pub mod model;
pub mod observation;
pub mod radar;
pub mod reference;
pub mod rule;

pub use config::{ConfigError, FusionConfig, GridConfig, Preset, SensorLimits, UnknownName};
pub use geometry::GridGeometry;
pub use grid::{CellCounts, OccupancyGrid};
pub use mapper::{Kernel, Mapper, Update};
pub use model::{
    AlphaSign, BeamWidth, LogOddsModel, ModelConfig, ModelKind, PaperModel, SmoothModel,
};
pub use observation::{Observation, ObservationError};
pub use radar::{RadarConfig, RadarMap};
pub use rule::{HimmRule, LogOddsRule, RuleConfig, RuleKind};
