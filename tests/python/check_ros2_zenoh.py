#!/usr/bin/env python3
"""A zenoh peer that reads /map, /scan and /tf as a ROS 2 node with rmw_zenoh would.

Written from rmw_zenoh's design (docs/design.md of ros2/rmw_zenoh, Jazzy and later), not from the
bridge's code: it listens where rmw_zenoh's router would (`rmw_zenohd`, tcp/…:7447), computes each
topic's key `<domain>/<topic>/<DDS type>/<type hash>` with the type hash rosbags computes for
ROS 2 Jazzy (`Typestore.hash_rihs01`), subscribes to exactly those keys, and checks every sample:

- its attachment: sequence number (int64 LE, rising by one), source timestamp (int64 LE, ns, within
  a minute of now), the publisher's GID behind its length byte 16 (33 bytes, one GID a topic);
- its payload decodes with rosbags' Jazzy typestore (`deserialize_cdr`); the last map equals the
  map `sonar-export --format npy,pgm` wrote (size, resolution, origin, frame, every cell);
- the graph: the liveliness tokens under `@ros2_lv/<domain>/` name the node and a publisher (MP)
  of each topic with its type and hash, as `ros2 topic list` would find them.

It runs beside the pipeline from its start (scans and transforms are volatile, as in ROS 2: a
subscriber sees those published after it came). With --connected FILE it writes FILE once the
bridge's node token reaches it, so that the test sends readings only when the bridge's session has
found this peer (the bridge retries its connection, and on a loaded machine it may come after a
short scan is over). Once the file READY exists (the test writes it after the final map was
exported to MAP_STEM) it takes two more maps and checks the last.

Usage: check_ros2_zenoh.py LISTEN_ENDPOINT MAP_STEM READY [--connected FILE] [--domain 0]
       [--timeout 60]
Prints one summary line; exits 1 with the first mismatch.
"""

import argparse
import json
import struct
import sys
import threading
import time
from pathlib import Path

import zenoh
from rosbags.typesys import Stores, get_typestore

sys.path.insert(0, str(Path(__file__).parent))
from check_wellknown_mcap import Mismatch, check, close, load_map, occupancy  # noqa: E402

TOPICS = {
    "/map": "nav_msgs/msg/OccupancyGrid",
    "/scan": "sensor_msgs/msg/LaserScan",
    "/tf": "tf2_msgs/msg/TFMessage",
}


def dds_type(ros_type):
    """nav_msgs/msg/OccupancyGrid -> nav_msgs::msg::dds_::OccupancyGrid_"""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def key(domain, topic, ros_type, typestore):
    return f"{domain}/{topic.strip('/')}/{dds_type(ros_type)}/{typestore.hash_rihs01(ros_type)}"


def parse_attachment(raw):
    check(raw is not None, "a sample without an attachment")
    check(len(raw) == 33, f"attachment of {len(raw)} bytes, not 33")
    sequence, stamp = struct.unpack_from("<qq", raw, 0)
    check(raw[16] == 16, f"GID length byte {raw[16]}")
    return sequence, stamp, bytes(raw[17:])


def tokens_of(session, domain):
    """The liveliness tokens of the ROS 2 graph, as rmw_zenoh's graph cache reads them."""
    return [
        str(reply.ok.key_expr)
        for reply in session.liveliness().get(f"@ros2_lv/{domain}/**", timeout=10.0)
        if reply.ok is not None
    ]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("listen")
    parser.add_argument("map_stem")
    parser.add_argument("ready", help="a file that exists once MAP_STEM holds the final map")
    parser.add_argument("--connected", help="a file to write once the bridge's node token arrives")
    parser.add_argument("--domain", type=int, default=0)
    parser.add_argument("--timeout", type=float, default=60.0)
    args = parser.parse_args()
    typestore = get_typestore(Stores.ROS2_JAZZY)

    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("listen/endpoints", json.dumps([args.listen]))
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)

    lock = threading.Lock()
    samples = {topic: [] for topic in TOPICS}
    subscribers = []
    for topic, ros_type in TOPICS.items():

        def store(sample, topic=topic):
            attachment = sample.attachment.to_bytes() if sample.attachment is not None else None
            with lock:
                samples[topic].append((sample.payload.to_bytes(), attachment, time.time_ns()))

        subscribers.append(session.declare_subscriber(key(args.domain, topic, ros_type, typestore), store))

    deadline = time.monotonic() + args.timeout
    if args.connected:
        while not any(t.endswith("/NN/%/%/sonar_bridge") for t in tokens_of(session, args.domain)):
            check(time.monotonic() < deadline, f"no node token of the bridge within {args.timeout} s")
            time.sleep(0.1)
        Path(args.connected).write_text("")

    # The final map: two more after the export (the one kept back by the rate limit when the
    # pipeline stopped comes within a second, then it repeats each second).
    maps_before = None
    while time.monotonic() < deadline:
        with lock:
            if maps_before is None and Path(args.ready).exists():
                maps_before = len(samples["/map"])
            if maps_before is not None and len(samples["/map"]) >= maps_before + 2:
                break
        time.sleep(0.05)
    with lock:
        got = {topic: list(s) for topic, s in samples.items()}
    counts = {topic: len(s) for topic, s in got.items()}
    check(maps_before is not None, f"{args.ready} did not appear within {args.timeout} s")
    check(len(got["/map"]) >= maps_before + 2, f"no map after the export within {args.timeout} s: {counts}")
    check(counts["/scan"] and counts["/tf"], f"within {args.timeout} s: {counts}")

    gids = {}
    for topic, received in got.items():
        sequences = []
        for payload, attachment, arrived_ns in received:
            sequence, stamp, gid = parse_attachment(attachment)
            check(abs(stamp - arrived_ns) < 60e9, f"{topic}: source timestamp {stamp} far from now")
            gids.setdefault(topic, gid)
            check(gids[topic] == gid, f"{topic}: the GID changed")
            sequences.append(sequence)
            typestore.deserialize_cdr(payload, TOPICS[topic])
        check(sequences[0] >= 1, f"{topic}: sequence numbers start at {sequences[0]}")
        # rmw_zenoh's publishers (and the bridge, after them) drop a sample rather than block
        # when zenoh's queue is full (a loaded machine, a slow link); its subscribers count the
        # gaps as lost messages. So the numbers must rise, never repeat or go back, and the gaps
        # stay a minority of what was sent.
        check(
            all(a < b for a, b in zip(sequences, sequences[1:])),
            f"{topic}: sequence numbers {sequences[:5]}… do not rise",
        )
        sent = sequences[-1] - sequences[0] + 1
        check(
            2 * len(sequences) > sent,
            f"{topic}: {sent - len(sequences)} of {sent} samples lost",
        )
    check(len(set(gids.values())) == 3, "one GID for all topics")

    height, width, cells, resolution, ox, oy = load_map(args.map_stem)
    og = typestore.deserialize_cdr(got["/map"][-1][0], TOPICS["/map"])
    info = og.info
    check((info.width, info.height) == (width, height), "occupancy grid size")
    check(close(info.resolution, resolution), "occupancy grid resolution")
    check(close(info.origin.position.x, ox) and close(info.origin.position.y, oy), "origin")
    check(og.header.frame_id == "map", "occupancy grid frame")
    check(list(og.data) == [occupancy(c) for c in cells], "occupancy grid data differ from the map")
    known = sum(1 for v in og.data if v != -1)
    check(known > 0, "no observed cell")

    scan = typestore.deserialize_cdr(got["/scan"][-1][0], TOPICS["/scan"])
    check(scan.header.frame_id == "sonar", f"scan frame {scan.header.frame_id}")
    check(len(scan.ranges) > 0, "an empty scan")
    tf = typestore.deserialize_cdr(got["/tf"][-1][0], TOPICS["/tf"])
    frames = [(t.header.frame_id, t.child_frame_id) for t in tf.transforms]
    check(frames == [("map", "odom"), ("odom", "sonar")], f"transforms {frames}")

    # The graph, as rmw_zenoh's graph cache reads it.
    tokens = tokens_of(session, args.domain)
    check(any(t.endswith("/NN/%/%/sonar_bridge") for t in tokens), f"no node token in {tokens}")
    for topic, ros_type in TOPICS.items():
        middle = f"/MP/%/%/sonar_bridge/{topic.replace('/', '%')}/{dds_type(ros_type)}/{typestore.hash_rihs01(ros_type)}/"
        check(any(middle in t for t in tokens), f"no publisher token of {topic} in {tokens}")

    print(
        f"map {width}x{height} known {known} maps {counts['/map']} scans {counts['/scan']} "
        f"tfs {counts['/tf']} tokens {len(tokens)} scan_ranges {len(scan.ranges)}"
    )
    for s in subscribers:
        s.undeclare()
    session.close()


if __name__ == "__main__":
    try:
        main()
    except Mismatch as e:
        print(f"MISMATCH: {e}", file=sys.stderr)
        sys.exit(1)
