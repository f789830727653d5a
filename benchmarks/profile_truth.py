"""One recording's lidar and map calibration against the reality profile it was recorded on.

    python benchmarks/profile_truth.py RECORDING PROFILE [--parts lidar] [--out CSV]

RECORDING is a session (MCAP) of the twin playing PROFILE (a profile name such as ``lab`` or a YAML file); the
recording is calibrated (only --parts) and every estimated lidar and map key is set beside the profile's value (a key
the profile leaves out at its ideal value: no range step, no mixed pixels, boxes and walls where the map says).
Printed per key: status, value, 95 % interval, the truth and whether the interval holds it; last line
``covered=<k>/<n> weak=<w> unidentifiable=<u>`` over the keys with a truth. Rows go to --out (CSV).

The loop's own recordings (``dvc repro``'s deployments on the lab twin, or two loops side by side on lab and harsh:
benchmarks/two_loops.py) are what this scores: the coverage benchmark's drawn realities in one recording each.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path
from typing import Any

from calibration_coverage import truth_of

from pipeline.calibration.calibrate import calibrate
from pipeline.calibration.options import PARTS, CalibrationSettings
from pipeline.errors import MrlError
from pipeline.mappings import to_mapping
from pipeline.twin.profile import load_profile


def truth_in(mapping: dict[str, Any], key: str) -> float | None:
    """The profile's value of the estimate key (:func:`calibration_coverage.truth_of` on the profile with its
    defaults); a box the profile does not move stands where the map says."""
    if key.startswith("map.box_offsets_m[") and int(key[len("map.box_offsets_m[")]) >= len(
        mapping["map"]["box_offsets_m"]
    ):
        return 0.0
    return truth_of(mapping, key)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("profile", help="a profile name (lab, harsh, ...) or a profile YAML file")
    parser.add_argument("--parts", nargs="+", choices=PARTS, default=["lidar"])
    parser.add_argument("--bootstrap", type=int, default=200)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    try:
        _, profile = load_profile(args.profile)
        mapping = to_mapping(profile)
        cal = calibrate(args.recording, CalibrationSettings(bootstrap=args.bootstrap, parts=tuple(args.parts)))
    except MrlError as exc:
        print(f"profile_truth: {exc}")
        return 2
    rows = []
    for key, est in cal.values.items():
        if not key.startswith(("lidar.", "map.")):
            continue
        truth = truth_in(mapping, key)
        lo, hi = est.interval if est.interval is not None else (math.nan, math.nan)
        held = "" if truth is None or est.interval is None else int(lo <= truth <= hi)
        rows.append({"key": key, "status": est.status, "value": est.value, "low": lo, "high": hi, "truth": truth,
                     "held": held})  # fmt: skip
        shown = f"{est.value:.6g} [{lo:.6g}, {hi:.6g}]" if est.interval is not None else (est.reason or "-")
        mark = {1: "  ", 0: "X ", "": "  "}[held]
        print(f"{mark}{key:30s} {est.status:15s} {shown}  truth {truth}")
    judged = [r for r in rows if r["held"] != ""]
    weak = sum(r["status"] == "weak" for r in rows)
    unidentifiable = sum(r["status"] == "unidentifiable" for r in rows)
    if args.out is not None:
        with args.out.open("w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else ["key"])
            writer.writeheader()
            writer.writerows(rows)
    print(f"covered={sum(int(r['held']) for r in judged)}/{len(judged)} weak={weak} unidentifiable={unidentifiable}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
