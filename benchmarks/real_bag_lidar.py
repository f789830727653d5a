"""The lidar of a real robot's bag that holds nothing but scans: what calibration reads from the scans alone.

    python benchmarks/real_bag_lidar.py BAG [--topic /scan]

Reads the bag's LaserScan topic with rosbags (ROS 1 bag, rosbag2 folder or MCAP), finds the spans where the sensor
stood still from the scans themselves and estimates the range step, the noise and its growth with range (with their
trade-off), the beams' own spread, the no-return convention, the sweep's rate and wander
(:mod:`pipeline.calibration.scan_only`). Prints the bag's figures, one line per key and the notes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.scan_only import lidar_from_scans, read_scan_topic, scan_only_summary
from pipeline.errors import MrlError
from pipeline.record.bags import bag_sha256


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", type=Path)
    parser.add_argument("--topic", help="the LaserScan topic (default: the first)")
    args = parser.parse_args()
    if not args.bag.exists():
        print(f"real_bag_lidar: {args.bag} does not exist")
        return 2
    try:
        scans = read_scan_topic(args.bag, args.topic)
    except MrlError as e:
        print(f"real_bag_lidar: {e}")
        return 2
    ranges, stamps = scans.ranges, scans.stamps_ns
    digest = bag_sha256(args.bag)
    print(f"bag {args.bag.name} sha256 {digest[:16]}: {scans.topic}, {len(ranges)} scans of {ranges.shape[1]} beams "
          f"over {(stamps[-1] - stamps[0]) / 1e9:.1f} s, range {scans.range_min_m:g}-{scans.range_max_m:g} m, "
          f"increment {scans.angle_increment_rad:.6g} rad")  # fmt: skip
    fit = lidar_from_scans(
        ranges,
        stamps,
        scans.angle_min_rad,
        scans.angle_increment_rad,
        scans.range_min_m,
        scans.range_max_m,
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
