//! Sonar SLAM: the robot's poses (one per sweep) and the landmarks its sonar sees — walls,
//! corners and posts from the features crate — estimated together in one factor graph, with the
//! odometry's systematic errors as variables of the same graph, data association gated by the
//! joint covariance, loop closure by re-association against the landmark map, and a published
//! covariance that says "no fix" when the information is missing.
//!
//! After Leonard & Durrant-Whyte (landmarks from regions of constant depth) and Tardós et al.
//! 2002 ("Robust mapping and localization in indoor environments using sonar data": landmarks in
//! the state, joint compatibility, a map consistent over loops). [`Slam`] takes odometry and
//! readings and returns a [`SweepEstimate`] per sweep; [`estimator`] describes one sweep's steps,
//! [`graph`] the factor graph and its solver, [`odometry`] the odometry's error model.
//!
//! # Why the graph is solved by hand-written Gauss–Newton on nalgebra(-sparse)
//!
//! The issue asks for a maintained crate chosen by measurement. Measured on this machine
//! (2 cores shared with other builds, each crate alone in a fresh project with its own target
//! directory, `cargo build` debug, December 2026):
//!
//! | crate | version | crates built | debug build from clean | nalgebra | robust kernels | covariance |
//! |---|---|---|---|---|---|---|
//! | tiny-solver | 0.18.8 | 117 (faer, rayon, num-dual) | 145 s | 0.34 | Huber, Cauchy, … | none exposed |
//! | factrs | 0.3.0 | 99 (faer, statrs, num-dual) | 193 s | 0.34 | Huber, Cauchy, … | none exposed |
//! | apex-solver | 1.5.0 | 305 (faer 0.24, clap, chrono, tracing-subscriber, camera models) | 480 s | 0.33 | 15 kernels | full matrix, blocks and block pairs |
//! | nalgebra (already in the workspace) and nalgebra-sparse 0.12 | 0.35 | 1 new (nalgebra-sparse) | – | 0.35 | written here (Huber) | any block of H⁻¹ |
//!
//! What decided it:
//! - **The joint covariance.** Joint-compatibility data association needs the covariance of the
//!   current pose *and every landmark together*, cross-covariances included, at every sweep.
//!   tiny-solver and factrs expose no covariance (no such function in their sources); with them
//!   the normal matrix would have to be rebuilt outside the crate. apex-solver does compute it
//!   (`linalg::covariance`: the full matrix, a block, a pair of blocks), so this alone does not
//!   rule it out; its weight does (below).
//! - **A second linear-algebra stack.** All three pull faer and an older nalgebra (0.33/0.34)
//!   than the workspace's 0.35: two copies of nalgebra, with conversions at every boundary, and
//!   (tiny-solver, apex-solver) rayon's thread pool in a process meant to share 2 cores with the
//!   driver and the fusion; apex-solver also brings a command-line parser, chrono and a tracing
//!   subscriber into a library: 305 crates and 8 minutes of build for a few hundred unknowns.
//! - **Size.** A tour of hundreds of sweeps and tens of landmarks is a state of a few hundred to
//!   a few thousand numbers, nearly all of H empty: a sparse Cholesky factorisation in the
//!   order the graph knows (variables by their last use, [`graph`]) is all the sparse machinery
//!   it needs. nalgebra-sparse (dimforge's, on the workspace's nalgebra 0.35, no new stack)
//!   factors it; a dense factorisation had cost the cube of the tour (1.8 s a sweep at 600 sweeps,
//!   docs/benchmarks.md). Should tours grow to many thousands of sweeps, the choice should be
//!   measured again (apex-solver or factrs with a marginals solver of our own, or a window of
//!   recent poses).
//!
//! Not measured: the three crates on our pose graph itself (time ran out after the build
//! measurements); the decision rests on the build and API facts above.
//!
//! The solver here: Gauss–Newton with Levenberg damping when a step would raise the cost, a
//! Huber kernel on every landmark factor, numerical Jacobians (each factor is written once, as
//! its residual; the odometry's steps are re-corrected only when the errors that correct them
//! move), covariances from the undamped normal matrix at the solution.

pub mod error;
pub mod estimator;
pub mod graph;
pub mod message;
pub mod odometry;
pub mod section;

pub use error::SlamError;
pub use estimator::{
    FixState, Landmark, Slam, SlamConfig, SweepEstimate, SweepPose, chi2_quantile,
};
pub use graph::LandmarkKind;
pub use section::SlamSection;
