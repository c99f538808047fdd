//! The serial side of the sonar pipeline, as pure pieces the `sonar-driver` binary wires to a port
//! and to iceoryx2:
//!
//! - [`decoder`]: lines (our protocol or the hobby "Arduino radar" dialect) → [`Reading`]s;
//! - [`averaging`]: the policy that turns the four pings of a 6° group into one range;
//! - [`clock`]: the host time of a reading's instant, from the head's millisecond clock;
//! - [`sweeps`]: sweep ids continued across resets of the head.
//!
//! [`Reading`]: sonar_common::ipc::Reading

pub mod averaging;
pub mod clock;
pub mod decoder;
pub mod sweeps;
