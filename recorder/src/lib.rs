//! Recording and replay of the sonar pipeline.
//!
//! - [`format`]: the recording file (MCAP, one channel per service, versioned), writer and reader.
//! - [`well_known`]: the channels Foxglove and ROS 2 tools draw, written beside them (by
//!   `sonar-record` and `sonar-export --mcap`).
//! - [`pace`]: when the replay publishes each message (real time, a factor, or as fast as a rate
//!   ceiling allows).
//!
//! The binaries `sonar-record` and `sonar-replay` do the I/O; `docs/recording.md` is the user
//! documentation and the format specification.

pub mod format;
pub mod pace;
pub mod ros2_bag;
pub mod well_known;

pub use format::{
    Entry, ExtraChannel, FeatureSnapshot, FormatError, Message, ReadOptions, Recording,
    RecordingWriter, Topic, read, read_file,
};
pub use pace::{Pacer, Speed};
pub use ros2_bag::Ros2Bag;
pub use well_known::WellKnownChannels;
