#!/usr/bin/env python3
"""Print the walls, corners and posts published on `sonar/features`, from Python, with the PyPI
`iceoryx2` package and nothing from this repository but the layout in docs/ipc.md.

    pip install "iceoryx2==0.10.*"
    python3 examples/python/print_features.py [--count N] [--prefix P --root DIR]

For every snapshot (the fusion engine publishes one after each sweep and after a clear) it prints

    snapshot <seq> sweeps <n> features <count> left_out <n>

and then one line per feature, the most confident first:

    feature <id> <point|corner|plane> x <m> y <m> cov <xx> <xy> <yy> angle <deg> sigma <deg|-> confidence <c> seen <n> segment <ax> <ay> <bx> <by>|- <confirmed|tentative>

where `-` is an absent value (NaN in the record: a post has no segment and no angle sigma), and
`tentative` a feature heard from one place only (it may be a phantom; `confirmed`: from two or
more). A new
subscriber gets the current features with the next snapshot, at the end of the sweep in progress.

The prefix and root default to SONAR_IOX_PREFIX / SONAR_IOX_ROOT like the Rust processes do; without
them, iceoryx2's defaults apply, as for the fusion engine.
"""
import argparse
import ctypes
import math
import os
import sys

import iceoryx2 as iox2


class FeaturesHeader(ctypes.Structure):
    """sonar::FeaturesHeaderV1, 56 bytes, alignment 8, see docs/ipc.md."""

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_uint64),
        ("sweeps", ctypes.c_uint64),
        ("layout_version", ctypes.c_uint32),
        ("feature_count", ctypes.c_uint32),
        ("last_sweep_id", ctypes.c_uint32),
        ("last_sweep_rcds", ctypes.c_uint32),
        ("last_sweep_refined", ctypes.c_uint32),
        ("last_sweep_added", ctypes.c_uint32),
        ("last_sweep_removed", ctypes.c_uint32),
        ("features_left_out", ctypes.c_uint32),
    ]

    @staticmethod
    def type_name() -> str:
        return "sonar::FeaturesHeaderV1"  # must equal the Rust #[type_name]


class FeatureRecord(ctypes.Structure):
    """sonar::FeatureRecordV2, 80 bytes, alignment 8, see docs/ipc.md."""

    _fields_ = [
        ("id", ctypes.c_uint64),
        ("kind", ctypes.c_uint32),
        ("times_seen", ctypes.c_uint32),
        ("x_m", ctypes.c_float),
        ("y_m", ctypes.c_float),
        ("cov_xx", ctypes.c_float),
        ("cov_xy", ctypes.c_float),
        ("cov_yy", ctypes.c_float),
        ("angle_deg", ctypes.c_float),
        ("angle_sigma_deg", ctypes.c_float),
        ("confidence", ctypes.c_float),
        ("segment_ax_m", ctypes.c_float),
        ("segment_ay_m", ctypes.c_float),
        ("segment_bx_m", ctypes.c_float),
        ("segment_by_m", ctypes.c_float),
        ("last_seen_sweep", ctypes.c_uint64),
        ("flags", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
    ]

    @staticmethod
    def type_name() -> str:
        return "sonar::FeatureRecordV2"  # must equal the Rust #[type_name]


LAYOUT_VERSION = 1
KINDS = {1: "point", 2: "corner", 3: "plane"}
CONFIRMED = 1  # the flags bit: heard from two places or more


def number(x: float, digits: int) -> str:
    """A value with `digits` decimals, `-` when absent (NaN)."""
    return "-" if math.isnan(x) else f"{x:.{digits}f}"


def describe(r: FeatureRecord) -> str:
    segment = (r.segment_ax_m, r.segment_ay_m, r.segment_bx_m, r.segment_by_m)
    ends = "-" if any(math.isnan(v) for v in segment) else " ".join(f"{v:.3f}" for v in segment)
    return (f"feature {r.id} {KINDS.get(r.kind, str(r.kind))} x {r.x_m:.3f} y {r.y_m:.3f} "
            f"cov {r.cov_xx:.3g} {r.cov_xy:.3g} {r.cov_yy:.3g} angle {r.angle_deg:.1f} "
            f"sigma {number(r.angle_sigma_deg, 2)} confidence {r.confidence:.3f} seen {r.times_seen} "
            f"segment {ends} {'confirmed' if r.flags & CONFIRMED else 'tentative'}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=0, help="stop after N snapshots (0: run until Ctrl-C)")
    parser.add_argument("--iox-prefix", "--prefix", dest="prefix", default=os.environ.get("SONAR_IOX_PREFIX"),
                        help="the pipeline's iceoryx2 prefix, as the Rust programs' --iox-prefix [env SONAR_IOX_PREFIX]")
    parser.add_argument("--iox-root", "--root", dest="root", default=os.environ.get("SONAR_IOX_ROOT"),
                        help="the pipeline's iceoryx2 root directory, as the Rust programs' --iox-root [env SONAR_IOX_ROOT]")
    args = parser.parse_args()
    assert ctypes.sizeof(FeaturesHeader) == 56 and ctypes.alignment(FeaturesHeader) == 8, \
        "layout drifted from docs/ipc.md"
    assert ctypes.sizeof(FeatureRecord) == 80 and ctypes.alignment(FeatureRecord) == 8, \
        "layout drifted from docs/ipc.md"

    cfg = iox2.config.default()
    if args.prefix:
        cfg.global_cfg.prefix = iox2.FileName.new(args.prefix)
    if args.root:
        cfg.global_cfg.root_path = iox2.Path.new(args.root.rstrip("/") + "/")
    node = iox2.NodeBuilder.new().name(iox2.NodeName.new("py-features")).config(cfg).create(iox2.ServiceType.Ipc)
    name = iox2.ServiceName.new("sonar/features")
    # A slice of records with a user header; open() checks only the types, not the fusion engine's QoS.
    service = node.service_builder(name).publish_subscribe(iox2.Slice[FeatureRecord]).user_header(FeaturesHeader).open()
    subscriber = service.subscriber_builder().create()
    listener = node.service_builder(name).event().open().listener_builder().create()
    waitset = iox2.WaitSetBuilder.new().create(iox2.ServiceType.Ipc)
    guard = waitset.attach_notification(listener)
    print("subscribed to sonar/features", flush=True)

    printed = 0
    while args.count == 0 or printed < args.count:
        _, result = waitset.wait_and_process()
        if result in (iox2.WaitSetRunResult.Interrupt, iox2.WaitSetRunResult.TerminationRequest):
            break
        listener.try_wait()  # consume the wake-ups, else the wait returns at once again
        while (sample := subscriber.receive()) is not None:
            h = sample.user_header().contents
            seq, sweeps, version, count, left_out = (h.seq, h.sweeps, h.layout_version, h.feature_count,
                                                     h.features_left_out)
            payload = sample.payload()
            # The payload holds feature_count records. The iceoryx2 0.10 Python binding gives the
            # length of a slice of a structure in bytes, not records (a u8 slice, as the grid's,
            # hides the difference): accept either, and nothing else.
            if version != LAYOUT_VERSION or payload.len() not in (count, count * ctypes.sizeof(FeatureRecord)):
                print(f"snapshot {seq}: layout {version}, a payload of {payload.len()} for feature_count {count}",
                      file=sys.stderr)
                return 1
            # Copy the records out of shared memory; then hand the sample back at once.
            records = [FeatureRecord.from_buffer_copy(payload[i]) for i in range(count)]
            sample.delete()
            if args.count and printed >= args.count:
                continue
            lines = [f"snapshot {seq} sweeps {sweeps} features {count} left_out {left_out}"]
            lines += [describe(r) for r in records]
            print("\n".join(lines), flush=True)
            printed += 1
    del guard
    return 0


if __name__ == "__main__":
    sys.exit(main())
