"""The lidar of a real robot's bag that holds nothing but scans: what calibration reads from the scans alone.

    python benchmarks/real_bag_lidar.py BAG [--topic /scan]

Reads the bag's LaserScan topic with rosbags (ROS 1 bag, rosbag2 folder or MCAP), finds the spans where the sensor
stood still from the scans themselves and estimates the range step, the noise and its growth with range (with their
trade-off), the beams' own spread, the no-return convention, the sweep's rate and wander
(:mod:`pipeline.calibration.scan_only`). Prints the bag's figures, one line per key and the notes.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.scan_only import lidar_from_scans, scan_only_summary

LASER_SCAN = "sensor_msgs/msg/LaserScan"


def read_scans(path: Path, topic: str | None) -> tuple[str, np.ndarray, np.ndarray, object]:
    """(topic, (n, beams) ranges, (n,) header stamps ns, the first message) of one LaserScan topic."""
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
        scans = [c for c in reader.connections if c.msgtype == LASER_SCAN and (topic is None or c.topic == topic)]
        if not scans:
            found = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
            raise SystemExit(f"real_bag_lidar: {path} has no LaserScan topic{f' {topic}' if topic else ''}: {found}")
        chosen = scans[0].topic
        ranges, stamps, first = [], [], None
        for conn, _, raw in reader.messages(connections=[c for c in scans if c.topic == chosen]):
            msg = reader.deserialize(raw, conn.msgtype)
            first = first or msg
            if len(msg.ranges) != len(first.ranges):
                continue
            ranges.append(np.asarray(msg.ranges, dtype=np.float64))
            stamps.append(int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec))
    return chosen, np.array(ranges), np.array(stamps, dtype=np.int64), first


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", type=Path)
    parser.add_argument("--topic", help="the LaserScan topic (default: the first)")
    args = parser.parse_args()
    if not args.bag.exists():
        print(f"real_bag_lidar: {args.bag} does not exist")
        return 2
    topic, ranges, stamps, first = read_scans(args.bag, args.topic)
    digest = hashlib.sha256(args.bag.read_bytes()).hexdigest() if args.bag.is_file() else "-"
    print(f"bag {args.bag.name} sha256 {digest[:16]}: {topic}, {len(ranges)} scans of {ranges.shape[1]} beams over "
          f"{(stamps[-1] - stamps[0]) / 1e9:.1f} s, range {first.range_min:g}-{first.range_max:g} m, "  # type: ignore[attr-defined]
          f"increment {first.angle_increment:.6g} rad")  # type: ignore[attr-defined]  # fmt: skip
    fit = lidar_from_scans(
        ranges,
        stamps,
        float(first.angle_min),  # type: ignore[attr-defined]
        float(first.angle_increment),  # type: ignore[attr-defined]
        float(first.range_min),  # type: ignore[attr-defined]
        float(first.range_max),  # type: ignore[attr-defined]
        CalibrationSettings(bootstrap=200),
    )
    for key, est in scan_only_summary(fit):
        if not est.ok:
            print(f"{key:26s} unidentifiable: {est.reason}")
            continue
        lo, hi = est.interval or (float("nan"), float("nan"))
        print(f"{key:26s} {est.value:.6g} {est.unit:8s} [{lo:.6g}, {hi:.6g}] {est.status}")
    print(f"{'lidar.no_return':26s} {fit.no_return}")
    for note in fit.notes:
        print(f"- {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
