"""Calibration without motion capture against calibration with it, on one twin recording.

Calibrates `--recording` (a deployment on the twin, default the lab loop's nominal round) three
times: from its ground truth; with ``/<ns>/ground_truth`` ignored, each robot localized from its
scans and odometry in the scenario's map; and localized in the same room written as a ROS
map_server occupancy grid. Prints, per key, the profile's truth (``--profile``), each estimate
with its 95 % interval, and the relative difference of each localized estimate from the ground-truth
one; then the localization's match score and the matches' own standard deviations. Last line:
``within_15pct=<keys within 15 % of the ground-truth value>/<keys identified both ways> ...``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import yaml
from calibration_coverage import truth_of

from pipeline.calibration import CalibrationSettings, calibrate
from pipeline.calibration.localize import OccupancyMap
from pipeline.core.scenario import load_scenario
from pipeline.twin.profile import profile_path

ROOT = Path(__file__).resolve().parents[1]

ABS_MARGIN = {"lidar.noise_sigma_m": 0.002, "map.": 0.004, "clock.offset_s": 0.012, "network.jitter_s": 0.003}
"""Absolute margins where a value near zero makes 15 % meaningless (as the twin tests use)."""


def margin(key: str) -> float:
    return next((m for prefix, m in ABS_MARGIN.items() if key.startswith(prefix)), 0.0)


def fmt(est) -> str:
    if not est.ok or est.value is None:
        return f"{'unidentifiable':>26s}"
    lo, hi = est.interval or (float("nan"), float("nan"))
    return f"{est.value:9.4g} [{lo:7.4g},{hi:7.4g}]"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path("logs/benchmarks/sim2real/lab/real/nominal/session.mcap")
    parser.add_argument("--recording", type=Path, default=default)
    parser.add_argument("--profile", default="lab", help="the twin's profile (bundled name or YAML) for the truth")
    parser.add_argument("--bootstrap", type=int, default=100)
    args = parser.parse_args()
    truth = yaml.safe_load(profile_path(args.profile).read_text())
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.monotonic()
        runs["ground truth"] = calibrate(args.recording, CalibrationSettings(bootstrap=args.bootstrap))
        t1 = time.monotonic()
        runs["scans, scenario map"] = calibrate(
            args.recording, CalibrationSettings(bootstrap=args.bootstrap, pose_source="scans")
        )
        t2 = time.monotonic()
        scenario = runs["ground truth"].scenario
        floor = OccupancyMap.from_scenario(load_scenario(scenario)).write_map_server(Path(tmp) / "floor.yaml")
        runs["scans, map_server map"] = calibrate(
            args.recording, CalibrationSettings(bootstrap=args.bootstrap, pose_source="scans", map_file=str(floor))
        )
    print(f"calibration took {t1 - t0:.0f} s with ground truth, {t2 - t1:.0f} s localized")
    names = list(runs)
    print(f"{'key':28s} {'truth':>9s} " + " ".join(f"{n:>26s}" for n in names) + "  rel diff (scenario, map_server)")
    within = both = 0
    reference = runs["ground truth"]
    for key, est in reference.values.items():
        t = truth_of(truth, key)
        row = f"{key:28s} {'' if t is None else f'{t:9.4g}':>9s} " + " ".join(fmt(runs[n].values[key]) for n in names)
        diffs = []
        for n in names[1:]:
            other = runs[n].values[key]
            if est.ok and other.ok and est.value is not None and other.value is not None:
                d = abs(other.value - est.value)
                diffs.append(f"{d / abs(est.value):6.3f}" if est.value else f"{d:6.3g}")
                both += 1
                within += d <= 0.15 * abs(est.value) + margin(key)
            else:
                diffs.append("     -")
        print(row + "  " + " ".join(diffs))
    for n in names[1:]:
        src = runs[n].pose_source
        print(f"{n}: match score {src.median_score:.3f}; per robot (score, std x/y mm, yaw mrad):")
        for r in src.robots:
            sx, sy, syaw = r.median_std
            stds = f"{1e3 * sx:.1f}/{1e3 * sy:.1f}, {1e3 * syaw:.1f}"
            print(f"  {r.robot}: {r.median_score:.3f}, {stds}; starts {r.starts[:2]}")
    print(f"within_15pct={within}/{both} (keys identified with and without ground truth, both maps)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
