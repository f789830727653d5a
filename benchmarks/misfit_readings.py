"""Where the twin leaves calibration's models: the readings behind the widened jitter and odometry intervals.

For each kept coverage recording (``python benchmarks/calibration_coverage.py --keep DIR`` leaves
``drawn_<seed>.mcap``, its profile ``drawn_<seed>.yaml`` and the link's deliveries ``drawn_<seed>.link.npz``):

- per sensor kind (odometry, scans, ground truth), for two robots' messages of one tick: the jitter the pair rule
  reads at the link (hand-over times) and in the recording (log times), the share of pairs handed on / logged within
  0.1 ms of each other, and the jitter the 0.5, 0.75 and 0.9 quantiles of the recorded differences' size read;
- the odometry's per-episode errors (scale, yaw scale, heading drift about the unequal wheels' arc): their mean and
  spread over the robot-episodes, beside the profile's drift and the systematic errors its wheels predict;
- the drive: the recorded forward speed against the profile's drive replayed under the commands as the twin's
  driver took them, on calibration's contact-free stretches above 0.1 m/s (the slope through the origin), and the
  linear gain each reads;
- what the recording says about the floor.

Usage: ``python benchmarks/misfit_readings.py --keep DIR --seeds 100 106``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import yaml
from calibration_coverage import drive_replayed, drive_truths, realized_jitter

from pipeline.calibration import calibrate
from pipeline.calibration.keys import arc_per_m
from pipeline.calibration.network import SHAPE_QUANTILES, pair_rule
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.recording import read_session
from pipeline.calibration.streams import network_streams
from pipeline.core.scenario import SPARK_WHEEL_RADIUS_M, SPARK_WHEEL_SEPARATION_M

CLOSE_NS = 100_000


def jitter_lines(recording: Path) -> list[str]:
    data = read_session(recording, ["network", "odometry", "lidar"])
    streams = network_streams("recording", data)
    with np.load(recording.with_suffix(".link.npz")) as link:
        topics, stamps, handed = link["topic"], link["stamp_ns"], link["handed_ns"]
    lines = []
    for kind in ("odom", "scan", "ground_truth"):
        mine = [s for s in streams if s.topic.endswith(kind)]
        if len(mine) < 2:
            continue
        a, b = mine[0], mine[1]
        common, ia, ib = np.intersect1d(a.stamp_ns, b.stamp_ns, return_indices=True)
        logged = (a.log_ns[ia] - a.stamp_ns[ia]) - (b.log_ns[ib] - b.stamp_ns[ib])
        sent = []
        for s in (a, b):
            name = s.topic.split(" ", 1)[1]
            sel = topics == name
            sent.append(dict(zip(stamps[sel].tolist(), (handed[sel] - stamps[sel]).tolist(), strict=True)))
        keys = sorted(set(sent[0]) & set(sent[1]))
        at_link = np.array([sent[0][k] - sent[1][k] for k in keys], dtype=float)
        q = np.asarray(SHAPE_QUANTILES)
        readings = np.quantile(np.abs(logged) / 1e9, q) / (1 - np.sqrt(1 - q))
        lines.append(
            f"  {kind:12s} pair rule at the link {pair_rule(at_link / 1e9) * 1e3:5.1f} ms, in the recording "
            f"{pair_rule(logged / 1e9) * 1e3:5.1f} ms; within 0.1 ms: link {np.mean(np.abs(at_link) < CLOSE_NS):.3f},"
            f" recording {np.mean(np.abs(logged) < CLOSE_NS):.3f} ({len(common)} pairs); quantiles "
            + ", ".join(f"{x:.2f}" for x in q)
            + " read "
            + ", ".join(f"{r * 1e3:.1f}" for r in readings)
            + " ms"
        )
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", type=Path, required=True)
    parser.add_argument("--seeds", type=int, nargs="+", required=True)
    args = parser.parse_args()
    for seed in args.seeds:
        recording = args.keep / f"drawn_{seed}.mcap"
        profile = yaml.safe_load((args.keep / f"drawn_{seed}.yaml").read_text(encoding="utf-8"))
        deliveries = recording.with_suffix(".link.npz")
        if not recording.is_file() or not deliveries.is_file():
            print(f"misfit_readings: {recording} or its .link.npz is missing")
            return 2
        cal = calibrate(recording, CalibrationSettings(bootstrap=200, seed=seed))
        jitter = cal.values["network.jitter_s"]
        print(
            f"profile {seed}: jitter profile {profile['network']['jitter_s'] * 1e3:.1f} ms, realized at the link "
            f"{(realized_jitter(deliveries) or float('nan')) * 1e3:.1f} ms, calibrated {jitter.value * 1e3:.1f} ms "
            f"[{jitter.interval[0] * 1e3:.1f}, {jitter.interval[1] * 1e3:.1f}]"
        )
        for line in jitter_lines(recording):
            print(line)
        base = profile["base"]
        r = (base["wheel_radius_left_m"] + base["wheel_radius_right_m"]) / 2
        scale = SPARK_WHEEL_RADIUS_M / r - 1
        yaw_scale = SPARK_WHEEL_RADIUS_M / r * base["wheel_separation_m"] / SPARK_WHEEL_SEPARATION_M - 1
        drift = cal.values["odometry.drift_per_m"]
        print(
            f"  odometry: profile drift {profile['odometry']['drift_per_m']:.4f}; its wheels predict a scale error "
            f"{scale:+.4f} and a yaw-scale error {yaw_scale:+.4f}; calibrated {drift.value:.4f} "
            f"[{drift.interval[0]:.4f}, {drift.interval[1]:.4f}]"
        )
        arc = arc_per_m(cal.values) or 0.0
        if cal.odometry is not None:
            for name in ("scale_error", "yaw_scale_error", "heading_drift_per_m"):
                v = np.array([getattr(e, name) for e in cal.odometry.episodes if getattr(e, name) is not None])
                if name == "heading_drift_per_m":
                    v = v + arc
                print(f"    {name:20s} mean {np.mean(v):+.4f} sd {np.std(v, ddof=1):.4f} over {len(v)} robot-episodes")
        settings = CalibrationSettings(bootstrap=200, seed=seed)
        record, replay = drive_replayed(recording, args.keep / f"drawn_{seed}.yaml", settings, deliveries)
        recorded, replayed = [], []
        for track in record.tracks:
            velocity, contact = replay[track.robot].at(track.t_ns)
            recorded.append(track.achieved[~contact, 0])
            replayed.append(velocity[~contact, 0])
        a, r = np.concatenate(recorded), np.concatenate(replayed)
        fast = np.abs(r) > 0.1
        slope = float(np.sum(a[fast] * r[fast]) / np.sum(r[fast] ** 2))
        truths = drive_truths(recording, args.keep / f"drawn_{seed}.yaml", settings, replayed=(record, replay))
        gain = cal.values["actuation.linear_gain"]
        print(
            f"  drive: recorded / replayed forward speed {slope:.4f} over {int(fast.sum())} samples; linear gain "
            f"{gain.value:.4f} [{gain.interval[0]:.4f}, {gain.interval[1]:.4f}] from the recording, "
            f"{truths['actuation.linear_gain']:.4f} from the replay"
        )
        print(f"  floor (friction {base['friction']:.2f}): {cal.values['base.friction'].reason}")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
