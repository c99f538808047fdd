//! The well-known channels of an MCAP file: Foxglove's (and, with `ros2`, ROS 2's) messages of the
//! map, the sweeps, the sensor's pose and the features, declared on a [`RecordingWriter`] and fed
//! with the pipeline's own messages and map snapshots (`sonar_wellknown` converts;
//! `docs/foxglove.md`). One writer for every producer: `sonar-record` feeds it what it records,
//! `sonar-export --mcap` a recording's messages with the maps it fuses from them, or a live
//! snapshot.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use sonar_common::ipc::GridHeader;
/// What to write: ROS 2 too, and how often a map.
pub use sonar_wellknown::Options;
use sonar_wellknown::{Channel, Output, WellKnown};

use crate::format::{ExtraChannel, FormatError, Message, RecordingWriter};

/// The converter and the channels it writes on.
#[derive(Debug)]
pub struct WellKnownChannels {
    converter: WellKnown,
    channels: BTreeMap<Channel, ExtraChannel>,
    written: u64,
}

impl WellKnownChannels {
    /// Declares the channels `options` ask for on `writer`.
    pub fn declare<W: Write + Seek>(
        writer: &mut RecordingWriter<W>,
        options: Options,
    ) -> Result<Self, FormatError> {
        let converter = WellKnown::new(options);
        let mut channels = BTreeMap::new();
        for channel in converter.channels() {
            let spec = channel.spec();
            let extra = writer.add_channel(
                spec.topic,
                &spec.schema_name,
                &spec.schema_encoding,
                &spec.schema,
                &spec.message_encoding,
            )?;
            channels.insert(channel, extra);
        }
        Ok(Self {
            converter,
            channels,
            written: 0,
        })
    }

    /// One of the pipeline's messages (readings, poses and features give something; commands
    /// nothing), received at `log_time_ns`.
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
            Message::ScanCommand(_) | Message::FusionCommand(_) => Vec::new(),
        };
        self.write(writer, log_time_ns, outputs)
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

    /// The end: the map kept back and the scan of the sweep in progress. Returns the number of
    /// well-known messages written in all.
    pub fn finish<W: Write + Seek>(
        mut self,
        writer: &mut RecordingWriter<W>,
        log_time_ns: u64,
    ) -> Result<u64, FormatError> {
        let outputs = self.converter.finish();
        self.write(writer, log_time_ns, outputs)?;
        Ok(self.written)
    }

    fn write<W: Write + Seek>(
        &mut self,
        writer: &mut RecordingWriter<W>,
        log_time_ns: u64,
        outputs: Vec<Output>,
    ) -> Result<(), FormatError> {
        for out in outputs {
            if let Some(channel) = self.channels.get_mut(&out.channel) {
                writer.write_extra(channel, log_time_ns, out.stamp_ns, &out.data)?;
                self.written += 1;
            }
        }
        Ok(())
    }
}
