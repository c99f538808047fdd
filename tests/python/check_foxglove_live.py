#!/usr/bin/env python3
"""A Foxglove WebSocket client for the test of sonar-foxglove.

Connects once for each `--subprotocol` given (the Python `websockets` package), offering exactly
that one — `foxglove.websocket.v1`, the ws-protocol's name that Lichtblick and older Foxglove offer,
or `foxglove.sdk.v1`, the `foxglove` crate's name for the same wire format; both carry the schemas
inline in the advertisements — and checks the server agreed to it. Then reads the server's
advertisements, checks that the well-known channels are there with their protobuf schemas,
subscribes to the map, decodes the first foxglove.Grid it receives with the schema the server
advertised (`mcap-protobuf-support` builds the decoder from the FileDescriptorSet) and prints one
line per connection:
`<subprotocol> channels <n> grid <columns>x<rows> cell <m> known <cells observed> frame <id>`.
Exits 1 on a refused subprotocol, a missing channel, a wrong schema or no map within the timeout.
"""

import argparse
import base64
import json
import struct
import sys
import time

from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory
from websockets.sync.client import connect

EXPECTED = {
    "/foxglove/map": "foxglove.Grid",
    "/foxglove/scan": "foxglove.LaserScan",
    "/foxglove/tf": "foxglove.FrameTransform",
    "/foxglove/features": "foxglove.SceneUpdate",
    "/foxglove/beam": "foxglove.SceneUpdate",
}
MESSAGE_DATA = 0x01  # server → client binary opcode


def fail(what):
    print(f"mismatch: {what}", file=sys.stderr)
    sys.exit(1)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("url")
    parser.add_argument("--subprotocol", action="append", required=True)
    parser.add_argument("--timeout", type=float, default=30.0)
    args = parser.parse_args()
    for subprotocol in args.subprotocol:
        print(subprotocol, check_connection(args.url, subprotocol, args.timeout), flush=True)


def check_connection(url, subprotocol, timeout):
    """The summary of one connection offering only `subprotocol`."""
    deadline = time.monotonic() + timeout
    channels = {}
    # proxy=None: a proxy from the environment cannot reach a server on loopback.
    with connect(url, subprotocols=[subprotocol], open_timeout=timeout, proxy=None) as ws:
        if ws.subprotocol != subprotocol:
            fail(f"subprotocol {ws.subprotocol!r} instead of {subprotocol}")
        subscribed = False
        while time.monotonic() < deadline:
            try:
                message = ws.recv(timeout=max(0.1, deadline - time.monotonic()))
            except TimeoutError:
                break
            if isinstance(message, str):
                op = json.loads(message)
                if op.get("op") == "advertise":
                    for ch in op["channels"]:
                        channels[ch["topic"]] = ch
                if not subscribed and all(t in channels for t in EXPECTED):
                    for topic, schema_name in EXPECTED.items():
                        ch = channels[topic]
                        if ch["schemaName"] != schema_name or ch["encoding"] != "protobuf":
                            fail(f"{topic}: {ch['schemaName']} ({ch['encoding']})")
                        if ch.get("schemaEncoding", "protobuf") != "protobuf":
                            fail(f"{topic}: schema encoding {ch.get('schemaEncoding')}")
                    grid = channels["/foxglove/map"]
                    ws.send(
                        json.dumps(
                            {"op": "subscribe", "subscriptions": [{"id": 1, "channelId": grid["id"]}]}
                        )
                    )
                    subscribed = True
                continue
            if message[0] != MESSAGE_DATA:
                continue
            (subscription,) = struct.unpack_from("<I", message, 1)
            if subscription != 1:
                continue
            grid_channel = channels["/foxglove/map"]
            schema = Schema(
                id=1,
                name=grid_channel["schemaName"],
                encoding="protobuf",
                data=base64.b64decode(grid_channel["schema"]),
            )
            decode = DecoderFactory().decoder_for("protobuf", schema)
            grid = decode(message[1 + 4 + 8 :])
            rows = len(grid.data) // grid.row_stride
            alpha = {f.name: f.offset for f in grid.fields}["alpha"]
            # One copy: protobuf hands out a new bytes object at each access of the field.
            data = grid.data
            known = sum(data[i * grid.cell_stride + alpha] != 0 for i in range(grid.column_count * rows))
            return (
                f"channels {len(channels)} grid {grid.column_count}x{rows} "
                f"cell {grid.cell_size.x:.4f} known {known} frame {grid.frame_id}"
            )
    missing = [t for t in EXPECTED if t not in channels]
    fail(f"missing channels {missing}" if missing else "no map within the timeout")


if __name__ == "__main__":
    main()
