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

import yaml

from pipeline.calibration.calibrate import calibrate, split_key
from pipeline.calibration.options import PARTS, CalibrationSettings
from pipeline.errors import MrlError
from pipeline.twin.profile import load_profile, profile_path

IDEAL = {"range_step_m": 0.0, "beam_noise_spread": 0.0, "mixed_pixel_prob": 0.0, "rate_wander": 0.0}
"""Lidar keys a profile may leave out, at the value an ideal sensor has."""
IDEAL_OPTIONAL = {"noise_per_m": 0.0, "scan_drop_prob": 0.0, "mount_xy_m": [0.0, 0.0], "beam_angle_jitter_rad": 0.0}


def truth_of(mapping: dict[str, Any], key: str) -> float | None:
    """The profile's value of the estimate key (``map.box_offsets_m[1][0]``...); None where it has no number."""
    group, name, index = split_key(key)
    section = mapping.get(group, {}) or {}
    value: Any = section.get(name)
    if value is None and group == "lidar":
        value = IDEAL.get(name, IDEAL_OPTIONAL.get(name))
    if value is None and group == "map":
        value = 0.0 if name == "wall_offset_m" else []
    for k in index:
        value = value[k] if isinstance(value, list) and len(value) > k else (0.0 if group == "map" else None)
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("profile", help="a profile name (lab, harsh, ...) or a profile YAML file")
    parser.add_argument("--parts", nargs="+", choices=PARTS, default=["lidar"])
    parser.add_argument("--bootstrap", type=int, default=200)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    try:
        load_profile(args.profile)  # a clear error for a profile that is not one
        mapping = yaml.safe_load(profile_path(args.profile).read_text(encoding="utf-8"))
        cal = calibrate(args.recording, CalibrationSettings(bootstrap=args.bootstrap, parts=tuple(args.parts)))
    except MrlError as exc:
        print(f"profile_truth: {exc}")
        return 2
    rows = []
    for key, est in cal.values.items():
        if not key.startswith(("lidar.", "map.")):
            continue
        truth = truth_of(mapping, key)
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
