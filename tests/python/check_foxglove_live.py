#!/usr/bin/env python3
"""A Foxglove WebSocket client for the test of sonar-foxglove.

Connects with the `foxglove.sdk.v1` subprotocol (the Python `websockets` package) — the one the
`foxglove` crate 0.30 serves (it refuses the older `foxglove.websocket.v1` with HTTP 400) and in
which channel advertisements carry their schemas inline — reads the
server's advertisements, checks that the four well-known channels are there with their protobuf
schemas, subscribes to the map, decodes the first foxglove.Grid it receives with the schema the
server advertised (`mcap-protobuf-support` builds the decoder from the FileDescriptorSet) and prints
one line: `channels <n> grid <columns>x<rows> cell <m> known <cells observed> frame <id>`.
Exits 1 on a missing channel, a wrong schema or no map within the timeout.
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
}
SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # server → client binary opcode


def fail(what):
    print(f"mismatch: {what}", file=sys.stderr)
    sys.exit(1)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("url")
    parser.add_argument("--timeout", type=float, default=30.0)
    args = parser.parse_args()

    deadline = time.monotonic() + args.timeout
    channels = {}
    # proxy=None: a proxy from the environment cannot reach a server on loopback.
    with connect(
        args.url, subprotocols=[SUBPROTOCOL], open_timeout=args.timeout, proxy=None
    ) as ws:
        if ws.subprotocol != SUBPROTOCOL:
            fail(f"subprotocol {ws.subprotocol!r}")
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
            known = sum(grid.data[i * grid.cell_stride + alpha] != 0 for i in range(grid.column_count * rows))
            print(
                f"channels {len(channels)} grid {grid.column_count}x{rows} "
                f"cell {grid.cell_size.x:.4f} known {known} frame {grid.frame_id}"
            )
            return
    missing = [t for t in EXPECTED if t not in channels]
    fail(f"missing channels {missing}" if missing else "no map within the timeout")


if __name__ == "__main__":
    main()
