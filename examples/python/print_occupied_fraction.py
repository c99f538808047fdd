#!/usr/bin/env python3
"""Print the occupied fraction of the sonar map on `sonar/grid`, from Python, with the PyPI
`iceoryx2` package and nothing from this repository but the layout in docs/ipc.md.

    pip install "iceoryx2==0.10.*"
    python3 examples/python/print_occupied_fraction.py [--count N] [--min-readings N] [--prefix P --root DIR]

For every snapshot it prints `occupied fraction <x> seq <seq> readings <n>`, where x is the share of
occupied cells (p > 0.5) among the observed ones (p > 0.5 or p < 0.5; never-observed cells are left
out). It counts the cells itself from the payload and checks them against the counts in the header,
so a layout that drifted from the documentation shows as an error, not as wrong numbers.

The prefix and root default to SONAR_IOX_PREFIX / SONAR_IOX_ROOT like the Rust processes do; without
them, iceoryx2's defaults apply, as for the fusion engine.
"""
import argparse
import ctypes
import os
import sys

import iceoryx2 as iox2


class GridHeader(ctypes.Structure):
    """sonar::GridHeaderV1, 88 bytes, alignment 8, see docs/ipc.md."""

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("readings_fused", ctypes.c_uint64),
        ("layout_version", ctypes.c_uint32),
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("resolution_m", ctypes.c_float),
        ("origin_x_m", ctypes.c_float),
        ("origin_y_m", ctypes.c_float),
        ("pose_x_m", ctypes.c_float),
        ("pose_y_m", ctypes.c_float),
        ("pose_theta_rad", ctypes.c_float),
        ("model", ctypes.c_uint32),
        ("rule", ctypes.c_uint32),
        ("preset", ctypes.c_uint32),
        ("sweep_id", ctypes.c_uint32),
        ("occupied_cells", ctypes.c_uint32),
        ("free_cells", ctypes.c_uint32),
        ("unknown_cells", ctypes.c_uint32),
    ]

    @staticmethod
    def type_name() -> str:
        return "sonar::GridHeaderV1"  # must equal the Rust #[type_name]


LAYOUT_VERSION = 1
# Cell bytes: round(p * 254); 127 is p = 0.5 (neither), 255 never observed.
OCCUPIED = bytes(range(128, 255))
FREE = bytes(range(0, 127))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=0, help="stop after N snapshots printed (0: run until Ctrl-C)")
    parser.add_argument("--min-readings", type=int, default=0, help="skip snapshots with fewer readings fused")
    parser.add_argument("--iox-prefix", "--prefix", dest="prefix", default=os.environ.get("SONAR_IOX_PREFIX"),
                        help="the pipeline's iceoryx2 prefix, as the Rust programs' --iox-prefix [env SONAR_IOX_PREFIX]")
    parser.add_argument("--iox-root", "--root", dest="root", default=os.environ.get("SONAR_IOX_ROOT"),
                        help="the pipeline's iceoryx2 root directory, as the Rust programs' --iox-root [env SONAR_IOX_ROOT]")
    args = parser.parse_args()
    assert ctypes.sizeof(GridHeader) == 88 and ctypes.alignment(GridHeader) == 8, "layout drifted from docs/ipc.md"

    cfg = iox2.config.default()
    if args.prefix:
        cfg.global_cfg.prefix = iox2.FileName.new(args.prefix)
    if args.root:
        cfg.global_cfg.root_path = iox2.Path.new(args.root.rstrip("/") + "/")
    node = iox2.NodeBuilder.new().name(iox2.NodeName.new("py-occupied")).config(cfg).create(iox2.ServiceType.Ipc)
    name = iox2.ServiceName.new("sonar/grid")
    # A slice of u8 with a user header; open() checks only the types, not the fusion engine's QoS.
    service = node.service_builder(name).publish_subscribe(iox2.Slice[ctypes.c_uint8]).user_header(GridHeader).open()
    subscriber = service.subscriber_builder().create()
    listener = node.service_builder(name).event().open().listener_builder().create()
    waitset = iox2.WaitSetBuilder.new().create(iox2.ServiceType.Ipc)
    guard = waitset.attach_notification(listener)
    print("subscribed to sonar/grid", flush=True)

    printed = 0
    while args.count == 0 or printed < args.count:
        _, result = waitset.wait_and_process()
        if result in (iox2.WaitSetRunResult.Interrupt, iox2.WaitSetRunResult.TerminationRequest):
            break
        listener.try_wait()  # consume the wake-ups, else the wait returns at once again
        while (sample := subscriber.receive()) is not None:
            h = sample.user_header().contents
            # One copy out of shared memory; then hand the sample back at once.
            cells = bytes(sample.payload().as_memory_view())
            header = (h.seq, h.readings_fused, h.layout_version, h.width, h.height,
                      h.occupied_cells, h.free_cells, h.unknown_cells)
            sample.delete()
            seq, readings, version, width, height, occupied_hdr, free_hdr, unknown_hdr = header
            if version != LAYOUT_VERSION or len(cells) != width * height:
                print(f"snapshot {seq}: layout {version}, {len(cells)} cells for {width} x {height}", file=sys.stderr)
                return 1
            if readings < args.min_readings or (args.count and printed >= args.count):
                continue
            # Deleting the bytes of one class leaves the others: the difference counts them (in C).
            occupied = len(cells) - len(cells.translate(None, OCCUPIED))
            free = len(cells) - len(cells.translate(None, FREE))
            even, unknown = cells.count(127), cells.count(255)
            # The header counts p > 0.5 and p < 0.5 before rounding: a cell of byte 127 may be in either.
            consistent = (unknown == unknown_hdr and occupied <= occupied_hdr <= occupied + even
                          and free <= free_hdr <= free + even)
            if not consistent:
                print(f"snapshot {seq}: cells say {occupied} occupied / {free} free / {unknown} unknown, header "
                      f"says {occupied_hdr} / {free_hdr} / {unknown_hdr}: layout drifted from docs/ipc.md",
                      file=sys.stderr)
                return 1
            fraction = occupied / (occupied + free) if occupied + free else 0.0
            print(f"occupied fraction {fraction:.4f} seq {seq} readings {readings}", flush=True)
            printed += 1
    del guard
    return 0


if __name__ == "__main__":
    sys.exit(main())
