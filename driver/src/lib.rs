//! The serial side of the sonar pipeline, as pure pieces the `sonar-driver` binary wires to a port
//! and to iceoryx2:
//!
//! - [`decoder`]: lines (our protocol or the hobby "Arduino radar" dialect) → [`Reading`]s;
//! - [`averaging`]: the policy that turns the four pings of a 6° group into one range;
//! - [`sweeps`]: sweep ids continued across resets of the head.
//!
//! [`Reading`]: sonar_common::ipc::Reading

pub mod averaging;
pub mod decoder;
pub mod sweeps;
