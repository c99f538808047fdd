//! The well-known channels of an MCAP file: Foxglove's messages of the map, the sweeps, the
//! sensor's pose and the features, declared on a [`RecordingWriter`], and with a [`Ros2Bag`] ROS
//! 2's (`/map`, `/scan`, `/tf`) in that bag of their own; fed with the pipeline's own messages and
//! map snapshots (`sonar_wellknown` converts; `docs/foxglove.md`). One writer for every producer: `sonar-record` feeds it what it records,
//! `sonar-export --mcap` a recording's messages with the maps it fuses from them, or a live
//! snapshot.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use sonar_common::ipc::GridHeader;
/// What to write: ROS 2 too, and how often a map.
pub use sonar_wellknown::Options;
use sonar_wellknown::{Channel, Output, WellKnown};

use crate::format::{ExtraChannel, FormatError, Message, RecordingWriter};
use crate::ros2_bag::{BagChannel, Ros2Bag};

/// Where a well-known channel is written.
#[derive(Debug)]
enum Target {
    /// Foxglove's: beside the recording's own channels.
    Recording(ExtraChannel),
    /// ROS 2's: in the bag.
    Bag(BagChannel),
}

/// The converter and the channels it writes on.
#[derive(Debug)]
pub struct WellKnownChannels {
    converter: WellKnown,
    channels: BTreeMap<Channel, Target>,
    bag: Option<Ros2Bag>,
    written: u64,
}

impl WellKnownChannels {
    /// Declares Foxglove's channels on `writer` and, with `bag`, ROS 2's in it (`options.ros2`
    /// follows whether there is a bag).
    pub fn declare<W: Write + Seek>(
        writer: &mut RecordingWriter<W>,
        options: Options,
        mut bag: Option<Ros2Bag>,
    ) -> Result<Self, FormatError> {
        let converter = WellKnown::new(Options {
            ros2: bag.is_some(),
            ..options
        });
        let mut channels = BTreeMap::new();
        for channel in converter.channels() {
            let spec = channel.spec();
            let target = match bag.as_mut() {
                Some(bag) if Channel::ROS2.contains(&channel) => {
                    Target::Bag(bag.add_channel(spec.topic, &spec.schema_name, &spec.schema)?)
                }
                _ => Target::Recording(writer.add_channel(
                    spec.topic,
                    &spec.schema_name,
                    &spec.schema_encoding,
                    &spec.schema,
                    &spec.message_encoding,
                )?),
            };
            channels.insert(channel, target);
        }
        Ok(Self {
            converter,
            channels,
            bag,
            written: 0,
        })
    }

    /// Closes the bag's current chunk, as the recording's writer does its own.
    pub fn flush(&mut self) -> Result<(), FormatError> {
        self.bag.as_mut().map_or(Ok(()), Ros2Bag::flush)
    }

    /// One of the pipeline's messages (readings, poses and features give something; commands
    /// nothing; a correction of the odometry is the `map → odom` written with the sensor's next
    /// transform), received at `log_time_ns`.
    pub fn message<W: Write + Seek>(
        &mut self,
        writer: &mut RecordingWriter<W>,
        log_time_ns: u64,
        message: &Message,
    ) -> Result<(), FormatError> {
        let outputs = match message {
            Message::Reading(r) => self.converter.reading(r),
            Message::Pose(p) => self.converter.pose(p),
            Message::Features(f) => self.converter.features(&f.header, &f.records),
            Message::LocalizedPose(p) => {
                self.converter.localized_pose(p);
                Vec::new()
            }
            Message::SlamCorrection(c) => {
                self.converter.slam_correction(c);
                Vec::new()
            }
            Message::ScanCommand(_) | Message::FusionCommand(_) | Message::SweepEnd(_) => {
                Vec::new()
            }
        };
        self.write(writer, log_time_ns, outputs)
    }

    /// A correction of the odometry (map ← odom, `x`, `y` in metres, `theta` in radians) as of
    /// `stamp_ns`, from another source than a recorded message (an export's own localisation):
    /// the `map → odom` written with the sensor's next transform.
    pub fn correction(&mut self, stamp_ns: u64, x: f64, y: f64, theta: f64) {
        self.converter.correction(stamp_ns, x, y, theta);
    }

    /// A map snapshot (written at most once a grid period; the latest is kept for
    /// [`finish`](Self::finish)).
    pub fn grid<W: Write + Seek>(
        &mut self,
        writer: &mut RecordingWriter<W>,
        log_time_ns: u64,
        header: &GridHeader,
        cells: &[u8],
    ) -> Result<(), FormatError> {
        let outputs = self.converter.grid(header, cells);
        self.write(writer, log_time_ns, outputs)
    }

    /// The end: the map kept back and the scan of the sweep in progress, and the bag's end and
    /// metadata. Returns the number of well-known messages written in all.
    pub fn finish<W: Write + Seek>(
        mut self,
        writer: &mut RecordingWriter<W>,
        log_time_ns: u64,
    ) -> Result<u64, FormatError> {
        let outputs = self.converter.finish();
        self.write(writer, log_time_ns, outputs)?;
        if let Some(bag) = self.bag.take() {
            bag.finish()?;
        }
        Ok(self.written)
    }

    fn write<W: Write + Seek>(
        &mut self,
        writer: &mut RecordingWriter<W>,
        log_time_ns: u64,
        outputs: Vec<Output>,
    ) -> Result<(), FormatError> {
        for out in outputs {
            match (self.channels.get_mut(&out.channel), self.bag.as_mut()) {
                (Some(Target::Recording(channel)), _) => {
                    writer.write_extra(channel, log_time_ns, out.stamp_ns, &out.data)?
                }
                (Some(Target::Bag(channel)), Some(bag)) => {
                    bag.write(channel, log_time_ns, out.stamp_ns, &out.data)?
                }
                _ => continue,
            }
            self.written += 1;
        }
        Ok(())
    }
}
