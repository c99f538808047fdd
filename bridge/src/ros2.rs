//! `/map`, `/scan` and `/tf` for ROS 2 over zenoh, as `rmw_zenoh` carries a ROS 2 topic, so a ROS 2
//! machine whose middleware is `rmw_zenoh_cpp` (`RMW_IMPLEMENTATION=rmw_zenoh_cpp`) receives them
//! from a robot without ROS (`sonar-bridge --mode ros2`, `docs/bridge.md`).
//!
//! The layout follows `rmw_zenoh`'s design (its `docs/design.md`, as of the Jazzy, Kilted and
//! Rolling releases that run on zenoh 1.x):
//!
//! - **Data key**: `<domain_id>/<topic without its leading slash>/<DDS type name>/<type hash>`,
//!   e.g. `0/map/nav_msgs::msg::dds_::OccupancyGrid_/RIHS01_8d34…`; the type hash is REP 2011's
//!   `RIHS01_` hash of the type's description (the same in Jazzy and Kilted for these three types).
//!   Humble's `rmw_zenoh` puts `TypeHashNotSupported` there instead and is not served.
//! - **Payload**: the message in CDR with its 4-byte encapsulation header (`sonar_wellknown::ros2`).
//! - **Attachment** of every sample, as zenoh's serializer writes it (`zenoh-ext`): the sequence
//!   number (int64 LE, from 1), the source timestamp (int64 LE, ns since the epoch), the
//!   publisher's 16-byte GID behind its length (one byte, 16): 33 bytes.
//! - **Graph** (what `ros2 topic list`/`ros2 node list` show): liveliness tokens
//!   `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>[/<topic>/<type>/<hash>/<qos>]`,
//!   names with `/` written `%` and an empty enclave or namespace `%`, the QoS as the difference
//!   from ROS 2's default profile. The GID is the XXH3-128 hash of the publisher's token (low 64
//!   bits first, little endian), as `rmw_zenoh` makes it.

use sonar_wellknown::Channel;

/// The ROS 2 node these topics belong to (`ros2 node list` shows `/sonar_bridge`).
pub const NODE_NAME: &str = "sonar_bridge";
/// The admin space of `rmw_zenoh`'s liveliness tokens.
const ADMIN_SPACE: &str = "@ros2_lv";
/// The attachment: sequence number, source timestamp, length byte, GID.
pub const ATTACHMENT_LEN: usize = 8 + 8 + 1 + GID_LEN;
/// `RMW_GID_STORAGE_SIZE`.
pub const GID_LEN: usize = 16;

/// A ROS 2 topic this bridge publishes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Topic {
    pub channel: Channel,
    /// The ROS 2 type, `package/msg/Type`.
    pub ros_type: &'static str,
    /// `RIHS01_` and the SHA-256 of the type's description (REP 2011), as `ros2 topic info -v`
    /// shows it; computed for Jazzy and Kilted with `rosbags` (`Typestore.hash_rihs01`), which
    /// the test recomputes independently.
    pub type_hash: &'static str,
    /// The QoS offered, in the token's notation (see [`qos`]).
    pub qos: Qos,
    /// Its entity id within the node (the node is 0).
    pub entity_id: u32,
}

/// The parts of a ROS 2 QoS profile the token carries that differ here from the default.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    pub reliable: bool,
    pub transient_local: bool,
    pub depth: u32,
}

/// The three topics: the map as `map_server` offers it (reliable, transient local, a late
/// subscriber's `rmw_zenoh` asks for the last one), the scans as sensor data (best effort, depth
/// 5), the transforms as `tf2` does (reliable, volatile, depth 100).
pub const TOPICS: [Topic; 3] = [
    Topic {
        channel: Channel::Ros2Map,
        ros_type: "nav_msgs/msg/OccupancyGrid",
        type_hash: "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
        qos: Qos {
            reliable: true,
            transient_local: true,
            depth: 1,
        },
        entity_id: 1,
    },
    Topic {
        channel: Channel::Ros2Scan,
        ros_type: "sensor_msgs/msg/LaserScan",
        type_hash: "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828",
        qos: Qos {
            reliable: false,
            transient_local: false,
            depth: 5,
        },
        entity_id: 2,
    },
    Topic {
        channel: Channel::Ros2Transform,
        ros_type: "tf2_msgs/msg/TFMessage",
        type_hash: "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
        qos: Qos {
            reliable: true,
            transient_local: false,
            depth: 100,
        },
        entity_id: 3,
    },
];

impl Topic {
    /// The topic this carries, as ROS 2 names it (`/map`).
    pub fn name(&self) -> &'static str {
        self.channel.topic()
    }

    /// The DDS name of its type: `nav_msgs::msg::dds_::OccupancyGrid_`.
    pub fn dds_type(&self) -> String {
        let mut parts: Vec<&str> = self.ros_type.split('/').collect();
        let name = parts.pop().unwrap_or_default();
        format!("{}::dds_::{name}_", parts.join("::"))
    }

    /// The zenoh key its samples go to.
    pub fn key(&self, domain: u32) -> String {
        format!(
            "{domain}/{}/{}/{}",
            self.name().trim_matches('/'),
            self.dds_type(),
            self.type_hash
        )
    }

    /// The liveliness token of its publisher in session `zid`.
    pub fn token(&self, domain: u32, zid: &str) -> String {
        format!(
            "{ADMIN_SPACE}/{domain}/{zid}/0/{}/MP/%/%/{NODE_NAME}/{}/{}/{}/{}",
            self.entity_id,
            mangle(self.name()),
            self.dds_type(),
            self.type_hash,
            qos(self.qos)
        )
    }
}

/// The liveliness token of the node in session `zid`.
pub fn node_token(domain: u32, zid: &str) -> String {
    format!("{ADMIN_SPACE}/{domain}/{zid}/0/0/NN/%/%/{NODE_NAME}")
}

/// A name in a token: `/` written `%`, empty as `%`.
fn mangle(name: &str) -> String {
    if name.is_empty() {
        "%".into()
    } else {
        name.replace('/', "%")
    }
}

/// The token's QoS: `<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan
/// s>,<ns>:<liveliness>,<lease s>,<ns>`, each field empty where it equals ROS 2's default profile
/// (reliable, volatile, keep last 10, the rest unset); reliability 2 is best effort, durability 1
/// transient local (`rmw_qos_*_policy_e`).
pub fn qos(q: Qos) -> String {
    let reliability = if q.reliable { "" } else { "2" };
    let durability = if q.transient_local { "1" } else { "" };
    let depth = if q.depth == 10 {
        String::new()
    } else {
        q.depth.to_string()
    };
    format!("{reliability}:{durability}:,{depth}:,:,:,,")
}

/// The GID of the entity whose liveliness token is `token`.
pub fn gid(token: &str) -> [u8; GID_LEN] {
    xxhash_rust::xxh3::xxh3_128(token.as_bytes()).to_le_bytes()
}

/// A sample's attachment.
pub fn attachment(sequence: i64, source_stamp_ns: i64, gid: &[u8; GID_LEN]) -> Vec<u8> {
    let mut out = Vec::with_capacity(ATTACHMENT_LEN);
    out.extend_from_slice(&sequence.to_le_bytes());
    out.extend_from_slice(&source_stamp_ns.to_le_bytes());
    out.push(GID_LEN as u8);
    out.extend_from_slice(gid);
    out
}

/// The topic that carries a well-known channel, if it is a ROS 2 one.
pub fn topic_of(channel: Channel) -> Option<&'static Topic> {
    TOPICS.iter().find(|t| t.channel == channel)
}

#[cfg(test)]
mod tests {
    use super::*;

    const ZID: &str = "aac3178e146ba6f1fc6e6a4085e77f21";

    #[test]
    fn keys_are_domain_topic_dds_type_and_hash() {
        let map = topic_of(Channel::Ros2Map).map(|t| t.key(0));
        assert_eq!(
            map.as_deref(),
            Some(
                "0/map/nav_msgs::msg::dds_::OccupancyGrid_/\
                 RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7"
            )
        );
        assert_eq!(
            TOPICS[2].key(7),
            format!(
                "7/tf/tf2_msgs::msg::dds_::TFMessage_/{}",
                TOPICS[2].type_hash
            )
        );
        assert!(topic_of(Channel::FoxgloveMap).is_none());
    }

    #[test]
    fn tokens_and_qos_follow_the_design_s_examples() {
        assert_eq!(
            node_token(0, ZID),
            format!("@ros2_lv/0/{ZID}/0/0/NN/%/%/sonar_bridge")
        );
        // The design's talker: only its depth (7) differs from the default.
        let talker = Qos {
            reliable: true,
            transient_local: false,
            depth: 7,
        };
        assert_eq!(qos(talker), "::,7:,:,:,,");
        assert_eq!(qos(TOPICS[0].qos), ":1:,1:,:,:,,");
        assert_eq!(qos(TOPICS[1].qos), "2::,5:,:,:,,");
        assert_eq!(
            TOPICS[1].token(0, ZID),
            format!(
                "@ros2_lv/0/{ZID}/0/2/MP/%/%/sonar_bridge/%scan/sensor_msgs::msg::dds_::LaserScan_/{}/2::,5:,:,:,,",
                TOPICS[1].type_hash
            )
        );
    }

    #[test]
    fn an_attachment_is_two_int64_and_a_sized_gid() {
        let gid = gid("@ros2_lv/0/x/0/1/MP/%/%/n/%map/t/h/::,:,:,:,,");
        let a = attachment(3, 1_700_000_000_000_000_000, &gid);
        assert_eq!(a.len(), ATTACHMENT_LEN);
        assert_eq!(a[..8], 3i64.to_le_bytes());
        assert_eq!(a[8..16], 1_700_000_000_000_000_000i64.to_le_bytes());
        assert_eq!(a[16], 16);
        assert_eq!(a[17..], gid);
        // XXH3-128 of the empty input (its reference value), low half first.
        assert_eq!(
            super::gid(""),
            0x99aa06d3014798d86001c324468d497fu128.to_le_bytes()
        );
    }
}
