//! Walls, corners and posts from the raw pings: regions of constant depth (Leonard &
//! Durrant-Whyte), classified with the echo model's physics, merged across sweeps into a feature
//! map, the walls assembled into partial planes.
//!
//! `docs/features.md` is the user-facing version of this page, with the numbers worked out and
//! the evaluation's figures. A pure library: plain data in, plain data out, no I/O.
//!
//! # Why features, next to the grid
//!
//! An occupancy grid spreads each reading's echo over the beam, so a 5 cm post 1 m away smears
//! over 20–50 cm and two posts closer than ≈ 55 cm merge: no ping aimed between them hears past
//! them. Yet the readings carry their four raw pings, one every 1.5°, and a target is heard by a
//! whole run of consecutive pings **at the same range**: the first echo comes from the part of the
//! target nearest the sensor (the wall's foot of the perpendicular, the corner's vertex, the
//! post's near face) wherever in the cone the target lies. That run is a *region of constant
//! depth* (RCD). It is as wide as the target's effective cone, and since the cone is symmetric
//! about the target, the target's bearing is the middle of the run, known to a fraction of a
//! step, not anywhere in the ±30° beam.
//!
//! # The pipeline
//!
//! 1. [`Sweep`]: the pings of one sweep at their own angles (ping j of a reading at
//!    centre + (j − 1.5)·1.5° in the direction of motion), sorted by bearing so both scan
//!    directions give the same sequence. No-echo and out-of-range pings have no range. A
//!    reading with one range per angle (a hobby sketch, a 360° head, a log) is one ping on its
//!    axis, at the step its head was driven at; a full circle has no scan end.
//! 2. [`rcd::extract`]: runs of constant depth within a few σ of the sensor's noise, measured
//!    online from the pings ([`noise`]), with short bursts of lost pings (one may read nearer)
//!    bridged, never a ping that heard farther (a gap); each end **natural** (the next ping heard
//!    farther or nothing: the cone's edge), **occluded** (nearer: hidden) or unknown (scan end,
//!    lost readings); runs at one range separated only by nearer pings joined (the wall behind a
//!    post). [`Rcd`]: range, centre, width, pings, ends, with uncertainties.
//! 3. [`classify()`]: the width against the cones the physics predicts at that range
//!    ([`physics`], from [`EchoPhysics`], the simulator's model with its defaults): a wall is
//!    heard over twice its specular cut-off (56°), a corner over its whole cone (60° when near), a
//!    reference 5 cm post over ±13.4° at 1 m. A region **wider than one point's cone but at most
//!    two** is two equal points, one half-cone in from each end: the union of two equal cones
//!    ends at each target's cone edge. Regions where a plane's line meets their range (inside
//!    them, or behind what hides them) are that plane's **corner**. [`Observation`]s in polar
//!    form.
//! 4. [`FeatureMap`]: observations placed with the sweep's pose, merged into the feature of their
//!    kind they match (Mahalanobis gate; Kalman refinement), else new; features aimed at but not
//!    heard fade and are removed; what one sweep heard and another from its place did not, and a
//!    point one place heard as wide as a wall (a post or a wall's foot), are withheld.
//!    Uncertainty in two parts: jitter averages out over sweeps, the bearing's
//!    quantisation (same ping angles every sweep) does not.
//! 5. [`segment`]: each plane as a segment from its feet to the corners on its line, or through
//!    occupied grid cells passed in as support points.
//! 6. [`FeatureMap::summaries`]: every feature as one flat record (kind, position, covariance,
//!    angle, confidence, times seen, segment), what a fixed-size publication record carries.
//!
//! ```
//! use nalgebra::Isometry2;
//! use sonar_features::{FeatureConfig, FeatureKind, FeatureMap, Ping, Sweep};
//! # fn main() -> Result<(), sonar_features::FeatureError> {
//! let cfg = FeatureConfig::default();
//! let mut map = FeatureMap::new(cfg)?;
//! // A 5 cm post 1 m ahead, heard within ±13.4° at its near face (0.975 m); from readings,
//! // `Sweep::from_readings(&one_sweep, &cfg)`.
//! let pings: Vec<Ping> = (0..40)
//!     .map(|i| {
//!         let bearing_deg = -29.25 + 1.5 * f64::from(i);
//!         Ping { bearing_deg, range_m: (bearing_deg.abs() <= 13.4).then_some(0.975) }
//!     })
//!     .collect();
//! map.update(&Sweep::from_pings(pings, 1.5)?, &Isometry2::identity());
//! let post = &map.summaries(&[])[0];
//! assert_eq!(post.kind, FeatureKind::Point);
//! assert!((post.x - 0.975).abs() < 0.001 && post.y.abs() < 0.001);
//! # Ok(())
//! # }
//! ```
//!
//! # What the readings allow, and what they do not
//!
//! - The bearing of a target is quantised by the stepper: each edge of its cone lies somewhere in
//!   a 1.5° step, so a centre is known to ±0.75° at worst (1.3 cm at 1 m), and the same error
//!   repeats in every sweep from the same place.
//! - From one place a single target's strength is unknown: a post twice as thick is heard over a
//!   wider cone, exactly like two reference posts close together. The reference target
//!   ([`EchoPhysics::point_radius_m`], the paper's 5 cm posts) decides; a thicker post is
//!   reported as two points a little apart.
//! - A wall is heard only at its foot: its extent needs corners, other viewpoints or the grid.
//! - A region cut by the end of the scan or hidden by a nearer target shows only part of its
//!   width; narrow ones are left unclassified rather than guessed.

pub mod calibrate;
pub mod classify;
pub mod config;
pub mod drift;
pub mod error;
pub mod feature;
pub mod geometry;
pub mod localize;
pub mod map;
pub mod noise;
pub mod odometry;
pub mod physics;
pub mod pings;
pub mod rcd;
pub mod segment;

pub use calibrate::{
    CalibrationError, RangeOffset, WallSighting, WallSightings, range_offset, wall_in_sweep,
};
pub use classify::{Class, Classification, CutRegions, Observation, classify, classify_with};
pub use config::{FeatureConfig, MergeConfig, SegmentConfig};
pub use drift::{DriftEstimate, DriftFilter};
pub use error::FeatureError;
pub use feature::{Feature, FeatureKind};
pub use geometry::{wrap_deg, wrap_rad};
pub use localize::{Needs, PoseFix, WallAhead};
pub use map::{FeatureMap, FeatureSummary, NearRegions, SweepReport};
pub use noise::{NoiseConfig, NoiseModel, PingPair};
pub use odometry::OdometryErrors;
pub use physics::{EchoPhysics, Reflector};
pub use pings::{Ping, Sweep};
pub use rcd::{End, Rcd};
pub use segment::{Segment, SegmentEnd};
