#!/usr/bin/env python3
"""Print the sonar readings published on `sonar/readings`, from Python, with the PyPI `iceoryx2`
package and nothing from this repository but the layout in docs/ipc.md.

    pip install "iceoryx2==0.10.*"
    python3 examples/python/print_readings.py [--count N] [--prefix P --root DIR]

The prefix and root default to SONAR_IOX_PREFIX / SONAR_IOX_ROOT like the Rust processes do; without
them, iceoryx2's defaults apply, as for the driver.
"""
import argparse
import ctypes
import os
import sys

import iceoryx2 as iox2


class Reading(ctypes.Structure):
    """sonar::ReadingV1, 104 bytes, see docs/ipc.md."""

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("host_stamp_ns", ctypes.c_uint64),
        ("layout_version", ctypes.c_uint32),
        ("device_seq", ctypes.c_uint32),
        ("device_time_ms", ctypes.c_uint32),
        ("sweep_id", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("angle_deg", ctypes.c_float),
        ("beam_half_angle_deg", ctypes.c_float),
        ("tof_us", ctypes.c_float),
        ("distance_m", ctypes.c_float),
        ("speed_of_sound_mps", ctypes.c_float),
        ("min_range_m", ctypes.c_float),
        ("max_range_m", ctypes.c_float),
        ("echo_us", ctypes.c_uint32 * 8),
        ("direction", ctypes.c_int8),
        ("mode", ctypes.c_uint8),
        ("ping_count", ctypes.c_uint8),
        ("pings_used", ctypes.c_uint8),
        ("reserved", ctypes.c_uint8 * 4),
    ]

    @staticmethod
    def type_name() -> str:
        return "sonar::ReadingV1"  # must equal the Rust #[type_name]


NO_ECHO, OUT_OF_RANGE = 1, 2


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=0, help="stop after N readings (0: run until Ctrl-C)")
    parser.add_argument("--iox-prefix", "--prefix", dest="prefix", default=os.environ.get("SONAR_IOX_PREFIX"),
                        help="the pipeline's iceoryx2 prefix, as the Rust programs' --iox-prefix [env SONAR_IOX_PREFIX]")
    parser.add_argument("--iox-root", "--root", dest="root", default=os.environ.get("SONAR_IOX_ROOT"),
                        help="the pipeline's iceoryx2 root directory, as the Rust programs' --iox-root [env SONAR_IOX_ROOT]")
    args = parser.parse_args()
    assert ctypes.sizeof(Reading) == 104, "layout drifted from docs/ipc.md"

    cfg = iox2.config.default()
    if args.prefix:
        cfg.global_cfg.prefix = iox2.FileName.new(args.prefix)
    if args.root:
        cfg.global_cfg.root_path = iox2.Path.new(args.root.rstrip("/") + "/")
    node = iox2.NodeBuilder.new().name(iox2.NodeName.new("py-readings")).config(cfg).create(iox2.ServiceType.Ipc)
    name = iox2.ServiceName.new("sonar/readings")
    # open() (not open_or_create) checks only the type, so the driver's QoS need not be repeated here.
    service = node.service_builder(name).publish_subscribe(Reading).open()
    subscriber = service.subscriber_builder().create()
    listener = node.service_builder(name).event().open().listener_builder().create()
    waitset = iox2.WaitSetBuilder.new().create(iox2.ServiceType.Ipc)
    guard = waitset.attach_notification(listener)
    print("subscribed to sonar/readings", flush=True)

    seen = 0
    while args.count == 0 or seen < args.count:
        _, result = waitset.wait_and_process()
        if result in (iox2.WaitSetRunResult.Interrupt, iox2.WaitSetRunResult.TerminationRequest):
            break
        listener.try_wait()  # consume the wake-ups, else the wait returns at once again
        while (sample := subscriber.receive()) is not None:
            r = sample.payload().contents
            if r.flags & NO_ECHO:
                rng = "no echo"
            elif r.flags & OUT_OF_RANGE:
                rng = "out of range"
            else:
                rng = f"{r.distance_m:.3f} m"
            print(f"reading {r.seq} sweep {r.sweep_id} angle {r.angle_deg:.2f} {rng}", flush=True)
            sample.delete()  # hand the sample back now, not at garbage collection
            seen += 1
    del guard
    return 0


if __name__ == "__main__":
    sys.exit(main())
