//! A ROS 2 bag: the ROS 2 channels (`/map`, `/scan`, `/tf` in CDR) in a directory of their own,
//! as `ros2 bag record` leaves one: `metadata.yaml` and one MCAP file of profile `ros2`.
//!
//! Why apart from the recording: rosbag2 and `rosbags` read an MCAP file only when its profile is
//! `ros2` and every channel is `cdr` with a `ros2msg` schema; a recording also holds its own
//! channels and Foxglove's protobuf ones, so a file with all of them was refused by both
//! ("Profile is not ros2").
//!
//! The metadata is rosbag2's version 5 (what Humble writes; Iron and Jazzy read it too): the
//! topics with their types, `cdr`, the QoS profiles a player offers (`/map` reliable and transient
//! local, as `map_server` publishes it, so a late RViz still gets the map; `/scan` best effort,
//! as sensor data; `/tf` reliable), message counts, start and duration. `metadata.yaml` is written
//! at [`Ros2Bag::finish`]: a recorder killed before leaves the MCAP file without it, which
//! `ros2 bag reindex` rebuilds.

use std::collections::BTreeMap;
use std::fs::{self, File};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use mcap::WriteOptions;

use crate::format::{FormatError, write_numbered};

/// Message encoding of every channel of the bag.
const MESSAGE_ENCODING: &str = "cdr";
/// Schema encoding of every channel of the bag.
const SCHEMA_ENCODING: &str = "ros2msg";
/// The metadata version written (Humble's).
const METADATA_VERSION: u32 = 5;
/// Chunks of about this size, closed and written whole.
const CHUNK_SIZE: u64 = 256 * 1024;

/// The QoS a player of a topic offers, in rosbag2's YAML (`rmw_qos_profile_t` numbers: history 1
/// keep last; reliability 1 reliable, 2 best effort; durability 1 transient local, 2 volatile;
/// liveliness 1 automatic; "infinite" durations as rosbag2 writes them).
fn qos_yaml(topic: &str) -> String {
    let (reliability, durability, depth) = match topic {
        "/map" => (1, 1, 1),
        "/scan" => (2, 2, 5),
        _ => (1, 2, 100),
    };
    let infinite = "\n    sec: 2147483647\n    nsec: 4294967295";
    format!(
        "- history: 1\n  depth: {depth}\n  reliability: {reliability}\n  durability: {durability}\n  \
         deadline:{infinite}\n  lifespan:{infinite}\n  liveliness: 1\n  \
         liveliness_lease_duration:{infinite}\n  avoid_ros_namespace_conventions: false\n"
    )
}

/// A channel of a [`Ros2Bag`].
#[derive(Debug)]
pub struct BagChannel {
    id: u16,
    index: usize,
    sequence: u32,
}

#[derive(Debug)]
struct Topic {
    name: String,
    msg_type: String,
    messages: u64,
}

/// A ROS 2 bag being written (see the module docs).
pub struct Ros2Bag {
    dir: PathBuf,
    file_name: String,
    mcap: mcap::Writer<BufWriter<File>>,
    topics: Vec<Topic>,
    first_ns: Option<u64>,
    last_ns: u64,
}

impl std::fmt::Debug for Ros2Bag {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ros2Bag")
            .field("dir", &self.dir)
            .field("topics", &self.topics)
            .finish_non_exhaustive()
    }
}

impl Ros2Bag {
    /// The bag directory that goes with a recording or export `file`: `run.mcap` → `run_ros2/`.
    pub fn dir_beside(file: &Path) -> PathBuf {
        let stem = file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "sonar".to_owned());
        file.with_file_name(format!("{stem}_ros2"))
    }

    /// Creates the bag directory `dir` (refusing one that exists unless `overwrite`, which
    /// replaces the bag's own two files) and its MCAP file.
    pub fn create(dir: &Path, overwrite: bool) -> Result<Self, FormatError> {
        let io = |source| FormatError::Io {
            path: dir.to_owned(),
            source,
        };
        let name = dir
            .file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "sonar_ros2".to_owned());
        let file_name = format!("{name}_0.mcap");
        if dir.exists() && !overwrite {
            return Err(io(std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                "the ROS 2 bag directory exists already",
            )));
        }
        fs::create_dir_all(dir).map_err(io)?;
        let path = dir.join(&file_name);
        let file = File::create(&path).map_err(|source| FormatError::Io {
            path: path.clone(),
            source,
        })?;
        let mcap = WriteOptions::new()
            .profile("ros2")
            .compression(None)
            .chunk_size(Some(CHUNK_SIZE))
            .disable_seeking(true)
            .library(format!(
                "sonar-recorder {} (mcap {})",
                env!("CARGO_PKG_VERSION"),
                mcap::VERSION
            ))
            .create(BufWriter::new(file))
            .map_err(FormatError::Write)?;
        Ok(Self {
            dir: dir.to_owned(),
            file_name,
            mcap,
            topics: Vec::new(),
            first_ns: None,
            last_ns: 0,
        })
    }

    /// The bag's directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Declares `topic` of ROS 2 type `msg_type` (`nav_msgs/msg/OccupancyGrid`) with its
    /// `ros2msg` definition.
    pub fn add_channel(
        &mut self,
        topic: &str,
        msg_type: &str,
        definition: &[u8],
    ) -> Result<BagChannel, FormatError> {
        let schema = self
            .mcap
            .add_schema(msg_type, SCHEMA_ENCODING, definition)
            .map_err(FormatError::Write)?;
        let metadata = BTreeMap::from([("offered_qos_profiles".to_owned(), qos_yaml(topic))]);
        let id = self
            .mcap
            .add_channel(schema, topic, MESSAGE_ENCODING, &metadata)
            .map_err(FormatError::Write)?;
        self.topics.push(Topic {
            name: topic.to_owned(),
            msg_type: msg_type.to_owned(),
            messages: 0,
        });
        Ok(BagChannel {
            id,
            index: self.topics.len() - 1,
            sequence: 0,
        })
    }

    /// Appends a CDR message; `log_time_ns` is the bag's time of it (what `ros2 bag play` paces
    /// by), `publish_time_ns` the stamp of what it shows.
    pub fn write(
        &mut self,
        channel: &mut BagChannel,
        log_time_ns: u64,
        publish_time_ns: u64,
        data: &[u8],
    ) -> Result<(), FormatError> {
        write_numbered(
            &mut self.mcap,
            channel.id,
            &mut channel.sequence,
            log_time_ns,
            publish_time_ns,
            data,
        )?;
        self.topics[channel.index].messages += 1;
        self.first_ns = Some(self.first_ns.map_or(log_time_ns, |t| t.min(log_time_ns)));
        self.last_ns = self.last_ns.max(log_time_ns);
        Ok(())
    }

    /// Closes the current chunk and hands it to the file.
    pub fn flush(&mut self) -> Result<(), FormatError> {
        self.mcap.flush().map_err(FormatError::Write)
    }

    /// Writes the MCAP file's end and `metadata.yaml`; returns the messages written.
    pub fn finish(mut self) -> Result<u64, FormatError> {
        self.mcap.finish().map_err(FormatError::Write)?;
        let yaml = self.metadata_yaml();
        let file = self
            .mcap
            .into_inner()
            .into_inner()
            .map_err(|e| FormatError::Write(mcap::McapError::Io(e.into_error())))?;
        file.sync_all()
            .map_err(|e| FormatError::Write(mcap::McapError::Io(e)))?;
        let path = self.dir.join("metadata.yaml");
        let mut out = File::create(&path).map_err(|source| FormatError::Io {
            path: path.clone(),
            source,
        })?;
        out.write_all(yaml.as_bytes())
            .and_then(|()| out.sync_all())
            .map_err(|source| FormatError::Io { path, source })?;
        Ok(self.topics.iter().map(|t| t.messages).sum())
    }

    /// rosbag2's `metadata.yaml` (version [`METADATA_VERSION`]) of what was written.
    fn metadata_yaml(&self) -> String {
        let start = self.first_ns.unwrap_or(0);
        let duration = self.last_ns.saturating_sub(start);
        let total: u64 = self.topics.iter().map(|t| t.messages).sum();
        let mut topics = String::new();
        for t in &self.topics {
            // The QoS profiles are a YAML document inside a double-quoted YAML string, its line
            // breaks escaped, as rosbag2 writes them.
            let qos = qos_yaml(&t.name).replace('"', "\\\"").replace('\n', "\\n");
            topics.push_str(&format!(
                "    - topic_metadata:\n        name: {}\n        type: {}\n        \
                 serialization_format: cdr\n        offered_qos_profiles: \"{}\"\n      \
                 message_count: {}\n",
                t.name, t.msg_type, qos, t.messages
            ));
        }
        format!(
            "rosbag2_bagfile_information:\n  version: {METADATA_VERSION}\n  storage_identifier: \
             mcap\n  duration:\n    nanoseconds: {duration}\n  starting_time:\n    \
             nanoseconds_since_epoch: {start}\n  message_count: {total}\n  \
             topics_with_message_count:\n{topics}  compression_format: \"\"\n  \
             compression_mode: \"\"\n  relative_file_paths:\n    - {file}\n  files:\n    - path: \
             {file}\n      starting_time:\n        nanoseconds_since_epoch: {start}\n      \
             duration:\n        nanoseconds: {duration}\n      message_count: {total}\n",
            file = self.file_name
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bag_directory_goes_beside_the_recording() {
        assert_eq!(
            Ros2Bag::dir_beside(Path::new("/data/run.mcap")),
            PathBuf::from("/data/run_ros2")
        );
        assert_eq!(
            Ros2Bag::dir_beside(Path::new("room")),
            PathBuf::from("room_ros2")
        );
    }

    #[test]
    fn a_bag_holds_its_messages_and_says_so_in_its_metadata() {
        let dir = std::env::temp_dir().join(format!("sonar_bag_{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        let mut bag = Ros2Bag::create(&dir, false).unwrap();
        let mut map = bag
            .add_channel("/map", "nav_msgs/msg/OccupancyGrid", b"int8[] data\n")
            .unwrap();
        for k in 0..3u64 {
            bag.write(&mut map, 1_000 + k, 1_000 + k, &[0, 1, 0, 0])
                .unwrap();
        }
        assert!(
            Ros2Bag::create(&dir, false).is_err(),
            "an existing bag is kept"
        );
        assert_eq!(bag.finish().unwrap(), 3);
        let yaml = fs::read_to_string(dir.join("metadata.yaml")).unwrap();
        for line in [
            "version: 5",
            "storage_identifier: mcap",
            "nanoseconds: 2",
            "nanoseconds_since_epoch: 1000",
            "name: /map",
            "type: nav_msgs/msg/OccupancyGrid",
            "message_count: 3",
            &format!("- {}_0.mcap", dir.file_name().unwrap().to_string_lossy()),
        ] {
            assert!(yaml.contains(line), "{line:?} missing in\n{yaml}");
        }
        let file = fs::read(dir.join(format!(
            "{}_0.mcap",
            dir.file_name().unwrap().to_string_lossy()
        )))
        .unwrap();
        // The header record (magic, opcode 1, length, profile string) names the profile rosbag2
        // and rosbags require.
        assert_eq!(file[8], 0x01);
        assert_eq!(&file[17..25], b"\x04\0\0\0ros2");
        let _ = fs::remove_dir_all(&dir);
    }
}
