"""Calibration on twin recordings like a real robot's bag: one robot, still for 10 s, then driving, under a minute.

A TurtleBot 4's bag (a 720-beam lidar of the RPLIDAR class at 7.7 Hz, ranges in 2 mm steps, noise of 2-5 mm rising
with range, a quarter of the beams without a return, standing still for its first 10 s, then driving) is what
these recordings imitate: --recordings reality profiles (seeds --seed, --seed + 1, ...) of that lidar, with noise,
growth, mixed pixels, per-beam noise, sweep wander and scan losses drawn from the ranges below, each played by the
twin for one episode of a one-robot fleet (a tiny one-robot policy gives the deployment its interface; the robot
stands still for --still-s, then the scripted go-to-goal controller drives it). Each recording is calibrated (lidar
and network) and every lidar key the profile has is scored: the interval holds the truth or not.

Prints one line per recording and key, then per key the intervals that held the truth; the last line
``held=<k>/<n> share=<k/n>``. Rows go to --out (CSV); --keep DIR keeps the profiles and recordings.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline.calibration import calibrate
from pipeline.calibration.options import CalibrationSettings
from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig, world_config
from pipeline.policy.excitation import StillThenDrive
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.ros.fleet import load_fleet
from pipeline.sim import make_world

WORLD = {"scenario": "obstacles", "observation": "rich", "n_robots": 1, "max_steps": 400}
"""One robot in the reference room; an episode of at most 40 s."""
TRAIN = {"algorithm": "sac", "mode": "shared", "total_steps": 200, "n_envs": 1, "net_arch": [16, 16],
         "batch_size": 16, "buffer_size": 2000, "learning_starts": 40, "checkpoint_every_episodes": 5}  # fmt: skip
"""A tiny policy: it gives the deployment the robot's interface; the scripted controller drives."""
RANGES = {
    "noise_sigma_m": (0.001, 0.0025),
    "noise_per_m": (0.0003, 0.0008),
    "mixed_pixel_prob": (0.0, 0.3),
    "beam_noise_spread": (0.0, 0.3),
    "rate_wander": (0.0, 0.02),
    "scan_drop_prob": (0.0, 0.01),
}
"""Drawn per recording (uniform); noise 2-5 mm over the room's ranges as the bag's."""
SCORED = (
    "lidar.noise_sigma_m",
    "lidar.noise_per_m",
    "lidar.range_step_m",
    "lidar.dropout_prob",
    "lidar.bias_m",
    "lidar.rate_hz",
    "lidar.rate_wander",
    "lidar.mixed_pixel_prob",
    "lidar.beam_noise_spread",
    "lidar.scan_drop_prob",
    "lidar.mount_yaw_rad",
)
TIMING = {"tick_period_s": 0.02, "command_validity_s": 0.12, "discovery_timeout_s": 20.0, "reset_timeout_s": 20.0,
          "scan_stale_s": 0.5, "odom_stale_s": 0.3, "truth_stale_s": 0.3, "outage_limit_s": 5.0,
          "use_ground_truth": True}  # fmt: skip
COLUMNS = ["recording", "key", "truth", "status", "value", "low", "high", "held"]


def profile(seed: int) -> dict[str, Any]:
    """A TurtleBot-4-like reality profile (a mild base and link; the lidar as the bag's) drawn with `seed`."""
    rng = np.random.default_rng(seed)
    drawn = {k: float(f"{rng.uniform(lo, hi):.6g}") for k, (lo, hi) in RANGES.items()}
    lidar = {"beams": 720, "rate_hz": 7.7, "dropout_prob": 0.25, "bias_m": 0.005, "mount_yaw_rad": 0.0,
             "motion_distortion": True, "range_step_m": 0.002, "no_return": "inf", **drawn}  # fmt: skip
    return {
        "lidar": lidar,
        "actuation": {"delay_s": 0.05, "time_constant_s": 0.1, "linear_gain": 1.0, "angular_gain": 1.0},
        "odometry": {"rate_hz": 20.0, "drift_per_m": 0.01},
        "network": {"loss_prob": 0.0, "jitter_s": 0.002},
    }


def fleet_file(path: Path, domain: int) -> Path:
    fleet = {
        "target": "twin",
        "transport": "dds",
        "scenario": "obstacles",
        "network": {"domain_id": domain, "loopback_only": True, "peers": []},
        "robots": [{"name": "robot_1", "namespace": "robot_1", "v_max_mps": 0.4, "w_max_radps": 0.2}],
        "twin": {"profile": "mild", "time_scale": 1.0, "seed": 0},
        "timing": TIMING,
    }
    path.write_text(yaml.safe_dump(fleet), encoding="utf-8")
    return path


def tiny_policy(folder: Path) -> Path:
    scenario, world = make_world(world=world_config(WORLD))
    cfg = from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), TRAIN), "<lidar_like_real>")
    result = train(scenario, world, cfg, folder / "run", progress=False)
    export_policy(result.checkpoint, folder / "policy", golden_observations(scenario, world, 8))
    return folder / "policy"


def scored(recording: Path, truth: dict[str, Any], index: int) -> list[dict[str, object]]:
    cal = calibrate(recording, CalibrationSettings(parts=("lidar", "network"), bootstrap=200, seed=index))
    rows: list[dict[str, object]] = []
    for key in SCORED:
        est = cal.values.get(key)
        value = truth["lidar"].get(key.split(".", 1)[1])
        if est is None or value is None:
            continue
        row: dict[str, object] = {"recording": index, "key": key, "truth": value, "status": est.status}
        if est.ok and est.interval is not None:
            lo, hi = est.interval
            row.update(value=est.value, low=lo, high=hi, held=int(lo <= float(value) <= hi))
        rows.append(row)
    found = cal.lidar.no_return if cal.lidar is not None else None
    rows.append({"recording": index, "key": "lidar.no_return", "truth": "inf", "status": "category",
                 "value": found, "held": int(found == "inf")})  # fmt: skip
    if cal.lidar is not None:
        for note in cal.lidar.notes:
            print(f"  {note}", file=sys.stderr)
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=int, default=6)
    parser.add_argument("--seed", type=int, default=700)
    parser.add_argument("--still-s", type=float, default=10.0)
    parser.add_argument("--time-scale", type=float, default=1.0)
    parser.add_argument("--domain-id", type=int, default=77, help="the DDS domain the twin and the deployment use")
    parser.add_argument("--out", type=Path, default=Path("logs/benchmarks/lidar_like_real.csv"))
    parser.add_argument("--keep", type=Path, help="keep the profiles and recordings in this folder")
    args = parser.parse_args()
    if not 0 < args.domain_id < 233:
        print(f"lidar_like_real: --domain-id {args.domain_id}: a DDS domain id in 1..232")
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, object]] = []
    folder = nullcontext(str(args.keep)) if args.keep is not None else tempfile.TemporaryDirectory()
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
    with folder as tmp, tempfile.TemporaryDirectory() as work, args.out.open("w", newline="") as f:
        print("training the tiny one-robot policy (its interface only)", file=sys.stderr, flush=True)
        runtime = PolicyRuntime(tiny_policy(Path(work)))
        fleet_path = fleet_file(Path(work) / "one_robot.yaml", args.domain_id)
        fleet = load_fleet(str(fleet_path))
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        for k in range(args.recordings):
            seed = args.seed + k
            truth = profile(seed)
            path = Path(tmp) / f"turtle_{seed}.yaml"
            path.write_text(yaml.safe_dump(truth), encoding="utf-8")
            recording = Path(tmp) / f"turtle_{seed}.mcap"
            start = time.perf_counter()
            request = DeployRequest(
                episodes=1, seed=seed, recording=recording, time_scale=args.time_scale, profile=str(path),
                progress=False,
            )  # fmt: skip
            driver: Any = StillThenDrive(runtime, args.still_s)  # the policy's interface, the drive's commands
            deploy_policy(driver, fleet, str(fleet_path), request)
            for row in scored(recording, truth, seed):
                rows.append(row)
                writer.writerow(row)
                shown = "-" if "low" not in row else f"[{float(row['low']):.4g}, {float(row['high']):.4g}]"  # type: ignore[arg-type]
                print(f"{seed} {row['key']:26s} truth {row['truth']!s:10s} {row['status']:14s} {shown}", flush=True)
            f.flush()
            print(f"recording {k + 1}/{args.recordings} done in {time.perf_counter() - start:.0f} s", file=sys.stderr)
    summary(rows)
    return 0


def summary(rows: list[dict[str, object]]) -> None:
    held_all = tried = 0
    for key in [*SCORED, "lidar.no_return"]:
        mine = [r for r in rows if r["key"] == key]
        if not mine:
            continue
        judged = [r for r in mine if "held" in r]
        held = sum(int(r["held"]) for r in judged)  # type: ignore[call-overload]
        print(f"{key:26s} identified {len(judged)}/{len(mine)}  held the truth {held}/{len(judged)}")
        if key != "lidar.no_return":
            held_all += held
            tried += len(judged)
    share = held_all / tried if tried else math.nan
    print(f"held={held_all}/{tried} share={share:.2f}")


if __name__ == "__main__":
    sys.exit(main())
