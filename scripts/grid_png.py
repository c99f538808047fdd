#!/usr/bin/env python3
"""Renders the last foxglove.Grid of an MCAP file to a PNG with its own RGBA fields (the colours
Foxglove's 3D panel shows), top row = highest y; transparent (never observed) cells dark grey.
Decoded with `mcap` + `mcap-protobuf-support`; no other packages.

Usage: scripts/grid_png.py RECORDING.mcap OUT.png [--topic /foxglove/map]
"""
import argparse
import struct
import zlib

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("recording")
parser.add_argument("png")
parser.add_argument("--topic", default="/foxglove/map")
args = parser.parse_args()
grid = None
with open(args.recording, "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    for _, _, _, grid in reader.iter_decoded_messages(topics=[args.topic]):
        pass
if grid is None:
    raise SystemExit(f"no message on {args.topic}")
off = {fl.name: fl.offset for fl in grid.fields}
w, h = grid.column_count, len(grid.data) // grid.row_stride
rows = []
for y in reversed(range(h)):
    row = bytearray(b"\x00")
    for x in range(w):
        i = y * grid.row_stride + x * grid.cell_stride
        if grid.data[i + off["alpha"]] == 0:
            row += b"\x30\x30\x30"
        else:
            row += bytes(grid.data[i + off[c]] for c in ("red", "green", "blue"))
    rows.append(bytes(row))
chunk = lambda t, d: struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
png += chunk(b"IDAT", zlib.compress(b"".join(rows), 9)) + chunk(b"IEND", b"")
open(args.png, "wb").write(png)
print(f"{args.png}: {w}x{h}")
