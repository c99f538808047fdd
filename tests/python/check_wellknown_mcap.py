#!/usr/bin/env python3
"""Checks the well-known channels of a sonar-record or sonar-export --mcap file with independent decoders.

Reads the MCAP file with the `mcap` package and decodes Foxglove's protobuf messages with
`mcap-protobuf-support` (from the schemas in the file); with `--ros2`, the ROS 2 bag beside it
(FILE_ros2/) is opened with `rosbags` (an independent ROS 2 bag reader: the directory, and its MCAP
file alone, which must have profile ros2), every message deserialised with the typestores of ROS 2
Humble and Jazzy, and the bag round-tripped through `rosbags-convert` (ROS 2 → ROS 1 → ROS 2) with
its maps unchanged; then compares them with what the pipeline itself says:

- the last foxglove.Grid (and nav_msgs/msg/OccupancyGrid) against the map exported by
  `sonar-export --format npy,pgm` (values, size, resolution, origin);
- every foxglove.LaserScan (and sensor_msgs/msg/LaserScan) against the recording's own
  `sonar/readings` channel (or that of `--readings-from`, the recording a `sonar-export --mcap`
  file was made from), decoded from the byte layout of docs/recording.md: one scan per sweep
  (none for a live export's snapshot, which has no readings);
- every reading's beam (foxglove.SceneUpdate on /foxglove/beam, at most one each 100 ms of the
  readings' stamps) against its reading: a cone from the sensor, its arc at the reading's range (the
  maximum range without an echo) and spanning its bearing ± half-angle;
- that transforms and the features' scene are there.

Usage: check_wellknown_mcap.py FILE.mcap MAP_STEM [--ros2] [--readings-from RECORDING.mcap]
(MAP_STEM.npy and MAP_STEM.yaml as sonar-export writes them). Prints one summary line; exits 1
with the first mismatch.
"""

import argparse
import math
import re
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import Stores, get_typestore

READING = struct.Struct("<QQ5I7f8IbBBB4s")  # sonar::ReadingV1, 104 bytes
NO_ECHO, OUT_OF_RANGE = 1, 2
CELL_UNKNOWN = 255


class Mismatch(Exception):
    pass


def check(ok, what):
    if not ok:
        raise Mismatch(what)


def close(a, b, tol=1e-6):
    return abs(a - b) <= tol


def load_map(stem):
    """(height, width, cells as bytes 0..254/255, resolution, origin x, origin y)."""
    with open(stem + ".npy", "rb") as f:
        raw = f.read()
    check(raw[:8] == b"\x93NUMPY\x01\x00", "not an NPY 1.0 file")
    (hlen,) = struct.unpack_from("<H", raw, 8)
    header = raw[10 : 10 + hlen].decode()
    shape = re.search(r"'shape': \((\d+), (\d+)\)", header)
    height, width = int(shape.group(1)), int(shape.group(2))
    values = struct.unpack_from(f"<{height * width}f", raw, 10 + hlen)
    # The NPY holds p = byte / 254 (NaN never observed): the byte comes back exactly.
    cells = bytes(CELL_UNKNOWN if math.isnan(p) else round(p * 254) for p in values)
    yaml = open(stem + ".yaml").read()
    resolution = float(re.search(r"^resolution: (\S+)", yaml, re.M).group(1))
    origin = re.search(r"^origin: \[(\S+), (\S+), ", yaml, re.M)
    return height, width, cells, resolution, float(origin.group(1)), float(origin.group(2))


def occupancy(cell):
    """The ROS convention the channels use: -1 unknown, else percent rounded half up."""
    return -1 if cell == CELL_UNKNOWN else (cell * 100 + 127) // 254


def sweeps_of(readings):
    """Readings grouped by sweep, in recorded order (a sweep ends when the next begins)."""
    sweeps = []
    for r in readings:
        if not sweeps or sweeps[-1][0]["sweep_id"] != r["sweep_id"]:
            sweeps.append([])
        sweeps[-1].append(r)
    return sweeps


def check_scan(scan, sweep, start, end, ranges, what):
    """The readings of `sweep` lie on the scan's bearings with their ranges."""
    n = len(ranges)
    step = (end - start) / (n - 1) if n > 1 else 0.0
    filled = set()
    for r in sweep:
        a = math.radians(r["angle_deg"])
        i = round((a - start) / step) if step else 0
        check(0 <= i < n, f"{what}: reading at {r['angle_deg']}° outside the scan")
        check(
            close(start + i * step, a, 1e-4),
            f"{what}: bearing {start + i * step} rad for a reading at {a} rad",
        )
        if r["flags"] & (NO_ECHO | OUT_OF_RANGE):
            check(math.isinf(ranges[i]), f"{what}: a reading without echo is not +inf")
        else:
            check(
                close(ranges[i], r["distance_m"], 1e-6),
                f"{what}: range {ranges[i]} for a reading of {r['distance_m']} m",
            )
        filled.add(i)
    for i, v in enumerate(ranges):
        if i not in filled:
            check(math.isnan(v), f"{what}: bin {i} has {v} but no reading")


ROS2_TYPES = {
    "/map": "nav_msgs/msg/OccupancyGrid",
    "/scan": "sensor_msgs/msg/LaserScan",
    "/tf": "tf2_msgs/msg/TFMessage",
}


def read_bag(path, typestore):
    """Every message of the ROS 2 bag (or bare MCAP file) at `path`, deserialised, by topic."""
    messages = {}
    with Rosbag2Reader(path) as reader:
        topics = sorted(conn.topic for conn in reader.connections)
        check(topics == sorted(ROS2_TYPES), f"{path}: topics {topics}")
        for conn in reader.connections:
            check(conn.msgtype == ROS2_TYPES.get(conn.topic), f"{conn.topic}: type {conn.msgtype}")
        for conn, _, raw in reader.messages():
            messages.setdefault(conn.topic, []).append(typestore.deserialize_cdr(raw, conn.msgtype))
    return messages


def check_ros2_bag(bag, expected, geometry, sweeps):
    """The bag beside a file: rosbags opens it (and its MCAP file alone), both distributions'
    types decode every message, the last map is the exported map, one scan per sweep, and
    rosbags-convert carries it to ROS 1 and back unchanged. Returns the summary's words."""
    width, height, resolution, ox, oy = geometry
    check((bag / "metadata.yaml").is_file(), f"no ROS 2 bag at {bag}")
    files = sorted(bag.glob("*.mcap"))
    check(len(files) == 1, f"{len(files)} MCAP files in {bag}")
    decoded = None
    for store in (Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY):
        typestore = get_typestore(store)
        for path in (bag, files[0]):
            got = read_bag(path, typestore)
            # A live snapshot's export has a map and a transform but no sweep, so no scan.
            check({"/map", "/tf"} <= set(got), f"{path}: messages on {sorted(got)}")
            decoded = decoded or got
    og = decoded["/map"][-1]
    info = og.info
    check((info.width, info.height) == (width, height), "occupancy grid size")
    check(close(info.resolution, resolution), "occupancy grid resolution")
    check(close(info.origin.position.x, ox) and close(info.origin.position.y, oy), "origin")
    check(close(info.origin.orientation.w, 1.0), "origin orientation")
    check(og.header.frame_id == "map", "occupancy grid frame")
    check(list(og.data) == expected, "occupancy grid data differ from the map")
    ros_scans = decoded.get("/scan", [])
    check(len(ros_scans) == len(sweeps), f"{len(ros_scans)} ROS scans for {len(sweeps)} sweeps")
    for k, (scan, sweep) in enumerate(zip(ros_scans, sweeps)):
        n = len(scan.ranges)
        check(
            n == 1 or close(scan.angle_min + (n - 1) * scan.angle_increment, scan.angle_max, 1e-5),
            f"ROS scan {k}: angle_max",
        )
        check_scan(scan, sweep, scan.angle_min, scan.angle_max, list(scan.ranges), f"ROS scan {k}")
    frames = [(t.header.frame_id, t.child_frame_id) for t in decoded["/tf"][0].transforms]
    check(frames == [("map", "odom"), ("odom", "sonar")], f"ROS transform frames {frames}")

    # ROS 2 → ROS 1 → ROS 2 with rosbags-convert: the same maps come back.
    convert = Path(sys.executable).with_name("rosbags-convert")
    with tempfile.TemporaryDirectory() as tmp:
        ros1, back = Path(tmp) / "bag.bag", Path(tmp) / "back"
        for src, dst, extra in ((bag, ros1, []), (ros1, back, ["--dst-typestore", "ros2_humble"])):
            done = subprocess.run(
                [str(convert), "--src", str(src), "--dst", str(dst), *extra],
                capture_output=True, text=True,
            )
            check(done.returncode == 0, f"rosbags-convert {src} -> {dst}: {done.stderr}")
        with AnyReader([back], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            maps = [
                reader.deserialize(raw, conn.msgtype)
                for conn, _, raw in reader.messages()
                if conn.topic == "/map"
            ]
        check(len(maps) == len(decoded["/map"]), f"{len(maps)} maps after the round trip")
        check(list(maps[-1].data) == expected, "the round trip changed the map")
    return f"ros2_maps {len(decoded['/map'])} ros2_scans {len(ros_scans)}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("map_stem")
    parser.add_argument("--ros2", action="store_true", help="expect and check the ROS 2 channels")
    parser.add_argument("--readings-from", help="the recording whose readings the scans show")
    args = parser.parse_args()

    height, width, cells, resolution, ox, oy = load_map(args.map_stem)
    expected = [occupancy(c) for c in cells]

    readings = []
    with open(args.readings_from or args.recording, "rb") as f:
        for _, _, message in make_reader(f).iter_messages(topics=["sonar/readings"]):
            f_ = READING.unpack(message.data)
            readings.append(
                {
                    "stamp_ns": f_[1],
                    "sweep_id": f_[5],
                    "flags": f_[6],
                    "angle_deg": f_[7],
                    "half_angle_deg": f_[8],
                    "distance_m": f_[10],
                    "max_range_m": f_[13],
                }
            )
    decoded = {}
    with open(args.recording, "rb") as f:
        reader = make_reader(f, decoder_factories=[ProtobufDecoderFactory()])
        schemas = {c.topic: reader.get_summary().schemas[c.schema_id] for c in reader.get_summary().channels.values()}
        topics = ["/foxglove/map", "/foxglove/scan", "/foxglove/tf", "/foxglove/features", "/foxglove/beam"]
        # ROS 2's channels are in the bag of their own, never beside these.
        check(not {"/map", "/scan", "/tf"} & set(schemas), "ROS 2 channels in the Foxglove file")
        for _, channel, _, msg in reader.iter_decoded_messages(topics=topics):
            decoded.setdefault(channel.topic, []).append(msg)

    check(schemas["/foxglove/map"].name == "foxglove.Grid", "grid schema")
    check(schemas["/foxglove/map"].encoding == "protobuf", "grid schema encoding")
    for topic in topics:
        # The scans and beams are counted against the readings below.
        if not topic.endswith("/scan") and topic != "/foxglove/beam":
            check(decoded.get(topic), f"no message on {topic}")

    # The map: the last Grid is the map the pipeline ended with.
    grid = decoded["/foxglove/map"][-1]
    rows = len(grid.data) // grid.row_stride
    check((grid.column_count, rows) == (width, height), f"grid {grid.column_count}×{rows}")
    check(grid.cell_stride == 5 and grid.row_stride == 5 * width, "grid strides")
    check(close(grid.cell_size.x, resolution) and close(grid.cell_size.y, resolution), "cell size")
    check(close(grid.pose.position.x, ox) and close(grid.pose.position.y, oy), "grid origin")
    check(grid.frame_id == "map", "grid frame")
    fields = {f.name: f.offset for f in grid.fields}
    occ = fields["occupancy"]
    # One copy: protobuf hands out a new bytes object at each access of the field.
    data = grid.data
    values = [struct.unpack_from("b", data, i * 5 + occ)[0] for i in range(width * height)]
    bad = [i for i in range(width * height) if values[i] != expected[i]]
    check(not bad, f"{len(bad)} grid cells differ from the map, first {bad[:1]}")
    alpha = fields["alpha"]
    check(
        all((data[i * 5 + alpha] == 0) == (cells[i] == CELL_UNKNOWN) for i in range(width * height)),
        "unknown cells are not exactly the transparent ones",
    )
    known = sum(c != CELL_UNKNOWN for c in cells)
    check(known > 0, "the map has observed cells")

    # The scans: one per sweep, each holding its sweep's readings.
    sweeps = sweeps_of(readings)
    scans = decoded.get("/foxglove/scan", [])
    check(len(scans) == len(sweeps), f"{len(scans)} scans for {len(sweeps)} sweeps")
    for k, (scan, sweep) in enumerate(zip(scans, sweeps)):
        check(scan.frame_id == "sonar", "scan frame")
        check_scan(scan, sweep, scan.start_angle, scan.end_angle, list(scan.ranges), f"scan {k}")

    beams = decoded.get("/foxglove/beam", [])
    check(bool(beams) == bool(readings), f"{len(beams)} beams for {len(readings)} readings")
    by_stamp = {r["stamp_ns"]: r for r in readings}
    last = None
    for k, beam in enumerate(beams):
        check(len(beam.entities) == 1, f"beam {k}: one entity")
        e = beam.entities[0]
        check((e.id, e.frame_id) == ("beam", "sonar"), f"beam {k}: entity {e.id} in {e.frame_id}")
        stamp = e.timestamp.seconds * 1_000_000_000 + e.timestamp.nanos
        r = by_stamp.get(stamp)
        check(r is not None, f"beam {k}: no reading stamped {stamp}")
        check(last is None or stamp < last or stamp - last >= 100_000_000, f"beam {k}: too soon")
        last = stamp
        silent = r["flags"] & (NO_ECHO | OUT_OF_RANGE)
        reach = r["max_range_m"] if silent else r["distance_m"]
        outline = e.lines[0].points
        check(close(outline[0].x, 0) and close(outline[0].y, 0), f"beam {k}: not from the sensor")
        arc = outline[1:-1]
        check(
            all(close(math.hypot(p.x, p.y), reach, 1e-4) for p in arc),
            f"beam {k}: arc not at {reach} m",
        )
        edges = [math.atan2(p.y, p.x) for p in (arc[0], arc[-1])]
        centre, half = math.radians(r["angle_deg"]), math.radians(r["half_angle_deg"])
        for edge, want in zip(edges, (centre - half, centre + half)):
            turn = (edge - want + math.pi) % (2 * math.pi) - math.pi
            check(abs(turn) < 1e-4, f"beam {k}: edge at {edge} rad instead of {want}")

    frames = [(t.parent_frame_id, t.child_frame_id) for t in decoded["/foxglove/tf"][:2]]
    check(frames == [("map", "odom"), ("odom", "sonar")], f"transform frames {frames}")
    walls = sum(len(e.lines) for e in decoded["/foxglove/features"][-1].entities)
    summary = (
        f"grid {width}x{height} res {resolution} cells {width * height} known {known} "
        f"scans {len(scans)} readings {len(readings)} transforms {len(decoded['/foxglove/tf'])} "
        f"wall_lines {walls} beams {len(beams)}"
    )

    if args.ros2:
        recording = Path(args.recording)
        bag = recording.with_name(recording.stem + "_ros2")
        summary += " " + check_ros2_bag(bag, expected, (width, height, resolution, ox, oy), sweeps)

    print(summary)


if __name__ == "__main__":
    try:
        main()
    except Mismatch as e:
        print(f"mismatch: {e}", file=sys.stderr)
        sys.exit(1)
