"""Calibration at building scale: peak memory and time of calibrating a long bag in a large map_server map.

Generates a building (corridors on a 20 m grid, rooms off them with doors, clutter in the rooms, outer walls) as a
map_server map of --size x --size metres at --resolution, drives one robot with a 720-beam lidar around its
corridors for --minutes (a scripted path: pure pursuit of the corridor loop, a 2 s stop every 20 s, through a drive
with a delay, a lag and a gain of its own; scans cast in the map with Gaussian noise; odometry with a scale error;
no ground truth, no episode events: a bag as a robot records it), writes it as a plain MCAP and calibrates it with
``--map`` in a child process (the robot localized in the map from its scans and odometry). Printed: the map's cells
and faces, the bag's duration and size, the calibration's peak memory (the child's maximum resident set) and wall
time, and their ratios to the limits (2 GiB; the bag's duration); then the lidar and drive estimates beside the
values the bag was made with; then the bag's commands open loop in the nominal and in the calibrated simulator
against the localized path (``mrl replay BAG --map``): the drift at 5, 10 and 30 s. Last line:
``peak_mib=<..> limit_ratio=<peak / 2 GiB> wall_s=<..> duration_ratio=<wall / bag>``.

    python benchmarks/calibration_scale.py                       # 60 x 60 m at 0.05 m, 10 minutes
    python benchmarks/calibration_scale.py --size 20 --minutes 1 # the slow test's size
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.calibration.localize import OccupancyMap
from pipeline.calibration.map_replay import MapReplay, map_replay
from pipeline.core.scan import ScanGeometry
from pipeline.messages import convert as C
from pipeline.messages.topics import robot_topics
from pipeline.params import calibrated_world, world_config
from pipeline.record.writer import McapRecorder

ROOT = Path(__file__).resolve().parents[1]

MEMORY_LIMIT_MIB = 2048
BEAMS = 720
SCAN_HZ = 7.7
RANGE_MAX_M = 12.0
NOISE_M = 0.01
DRIVE = {"delay_s": 0.08, "time_constant_s": 0.15, "linear_gain": 0.95, "angular_gain": 0.9}
"""The drive the bag is made with (the truth the estimates are printed beside)."""
ODOMETRY_SCALE = 1.02
CORRIDOR_M = 2.4
ROOM_M = 5.0
DOOR_M = 1.0


def building(size_m: float, resolution_m: float, seed: int) -> tuple[OccupancyMap, list[tuple[float, float]]]:
    """The occupancy grid and the corridor loop's corners (m) the robot drives around."""
    n = round(size_m / resolution_m)
    xs = (np.arange(n) + 0.5) * resolution_m
    gx, gy = np.meshgrid(xs, xs)
    rng = np.random.default_rng(seed)
    spacing = 10.0 if size_m <= 30 else 20.0
    lines = np.arange(spacing / 2, size_m - spacing / 4, spacing)  # corridor centre lines, both axes
    half = CORRIDOR_M / 2
    in_corridor = np.zeros((n, n), bool)
    for c in lines:
        in_corridor |= np.abs(gx - c) < half
        in_corridor |= np.abs(gy - c) < half
    wall = 0.15
    occupied = (gx < wall) | (gy < wall) | (gx > size_m - wall) | (gy > size_m - wall)
    # corridor walls, with a door into each room; room walls perpendicular to the corridors every ROOM_M
    for c in lines:
        for side in (-1, 1):
            edge = c + side * (half + wall / 2)
            for axis_g, other_g in ((gy, gx), (gx, gy)):
                along = np.abs(axis_g - edge) < wall / 2
                door = np.abs(np.mod(other_g, ROOM_M) - ROOM_M / 2) < DOOR_M / 2
                occupied |= along & ~door & ~in_corridor
    for k in np.arange(ROOM_M, size_m, ROOM_M):
        occupied |= ((np.abs(gx - k) < wall / 2) | (np.abs(gy - k) < wall / 2)) & ~in_corridor
    # clutter: boxes in the rooms
    for _ in range(int(size_m * size_m / 40)):
        cx, cy = rng.uniform(1.0, size_m - 1.0, 2)
        w, h = rng.uniform(0.3, 0.9, 2)
        box = (np.abs(gx - cx) < w / 2) & (np.abs(gy - cy) < h / 2)
        if not (box & in_corridor).any():
            occupied |= box
    occupied &= ~(in_corridor & (gx > wall) & (gy > wall) & (gx < size_m - wall) & (gy < size_m - wall))
    # a mapped building's speckle: single cells marked occupied beside the walls (each adds four faces), as a
    # SLAM-built map_server map has them
    near_wall = np.argwhere(~occupied & ~in_corridor)
    for r, c in near_wall[
        rng.choice(len(near_wall), size=min(len(near_wall), int(3 * size_m * size_m)), replace=False)
    ]:
        occupied[r, c] = True
    lo, hi = float(lines[0]), float(lines[-1])
    corners = [(lo, lo), (hi, lo), (hi, hi), (lo, hi)]
    return OccupancyMap(occupied, resolution_m, (0.0, 0.0, 0.0), "generated building"), corners


def drive(corners: list[tuple[float, float]], seconds: float) -> dict[str, np.ndarray]:
    """Pure pursuit around the corridor loop: commands at 20 Hz through the drive's delay, lag and gains; the true
    pose at 100 Hz."""
    h = 0.01
    steps = round(seconds / h)
    pose = np.array([corners[0][0], corners[0][1], 0.0])
    vel = np.zeros(2)
    target = 1
    cmd = np.zeros(2)
    delay = round(DRIVE["delay_s"] / h)
    queue = [np.zeros(2)] * (delay + 1)
    a = math.exp(-h / DRIVE["time_constant_s"])
    gains = np.array([DRIVE["linear_gain"], DRIVE["angular_gain"]])
    t_out, pose_out, vel_out, cmd_t, cmd_out = [], [], [], [], []
    for i in range(steps):
        if i % 5 == 0:  # a new command every 50 ms
            gx, gy = corners[target]
            if math.hypot(gx - pose[0], gy - pose[1]) < 0.6:
                target = (target + 1) % len(corners)
                gx, gy = corners[target]
            error = math.atan2(gy - pose[1], gx - pose[0]) - pose[2]
            error = math.atan2(math.sin(error), math.cos(error))
            cmd = np.array([0.4 * max(math.cos(error), 0.0) ** 4 + 0.05, float(np.clip(2.0 * error, -0.6, 0.6))])
            if (i * h) % 20.0 < 2.0:  # a stop of 2 s every 20 s: the lidar's noise shows standing still
                cmd = np.zeros(2)
            cmd_t.append(i * h)
            cmd_out.append(cmd.copy())
        queue.append(cmd.copy())
        acting = queue.pop(0)
        vel = a * vel + (1 - a) * gains * acting
        pose = pose + h * np.array([vel[0] * math.cos(pose[2]), vel[0] * math.sin(pose[2]), vel[1]])
        t_out.append(i * h)
        pose_out.append(pose.copy())
        vel_out.append(vel.copy())
    return {
        "t": np.array(t_out),
        "pose": np.array(pose_out),
        "vel": np.array(vel_out),
        "cmd_t": np.array(cmd_t),
        "cmd": np.array(cmd_out),
    }


def write_bag(path: Path, floor: OccupancyMap, run: dict[str, np.ndarray], seed: int) -> float:
    """The plain MCAP: /robot_1/scan, /odom, /cmd_vel (no ground truth, no session metadata); its duration (s)."""
    rng = np.random.default_rng(seed)
    geometry = floor.geometry(0.2)
    ns = "robot_1"
    t0 = 1_700_000_000 * 10**9
    angles = -math.pi + np.arange(BEAMS) * (2 * math.pi / BEAMS)
    scan_geometry = ScanGeometry(BEAMS, -math.pi, 2 * math.pi / BEAMS, 0.12, RANGE_MAX_M)
    t, pose = run["t"], run["pose"]
    with McapRecorder(path, {spec.name: spec for spec in robot_topics(ns).values()}, overwrite=True) as rec:
        odom_pose = pose[0].copy()
        for k, (tc, c) in enumerate(zip(run["cmd_t"], run["cmd"], strict=True)):
            stamp = t0 + round(tc * 1e9)
            rec.write(f"/{ns}/cmd_vel", C.twist(float(c[0]), float(c[1])), stamp)
            i = min(round(tc / 0.01), len(t) - 1)
            if k:  # odometry: the true motion since the last message, read with a scale error
                j = min(round(run["cmd_t"][k - 1] / 0.01), len(t) - 1)
                step = pose[i] - pose[j]
                dist = math.hypot(step[0], step[1]) * ODOMETRY_SCALE
                heading = odom_pose[2] + step[2] / 2
                odom_pose = odom_pose + np.array([dist * math.cos(heading), dist * math.sin(heading), step[2]])
            velocity = (float(run["vel"][i, 0]), float(run["vel"][i, 1]))
            rec.write(f"/{ns}/odom", C.odometry(stamp, ns, odom_pose, velocity), stamp)
        scan_times = np.arange(0.0, t[-1], 1.0 / SCAN_HZ)
        batch = 200
        for lo in range(0, len(scan_times), batch):
            times = scan_times[lo : lo + batch]
            idx = np.minimum(np.round(times / 0.01).astype(int), len(t) - 1)
            origins = pose[idx, None, :2]
            hits = geometry.cast(origins, pose[idx, 2, None] + angles[None, :])
            ranges = hits.range_m + rng.normal(0.0, NOISE_M, hits.range_m.shape)
            ranges = np.where(hits.range_m <= RANGE_MAX_M, ranges, np.inf)
            for k, tk in enumerate(times):
                stamp = t0 + round(tk * 1e9)
                msg = C.laser_scan(stamp, f"{ns}/laser", ranges[k], scan_geometry, 1.0 / SCAN_HZ, time_increment_s=0.0)
                rec.write(f"/{ns}/scan", msg, stamp)
    return float(t[-1])


CHILD = """
import json, resource, sys, time
from pathlib import Path
from pipeline.calibration import CalibrationSettings, calibrate, write_calibration
start = time.perf_counter()
settings = CalibrationSettings(
    parts=("lidar", "actuation", "odometry"), pose_source="scans", map_file=sys.argv[2],
    initial_pose=[float(v) for v in sys.argv[3].split(",")], bootstrap=50,
)
cal = calibrate(sys.argv[1], settings)
wall = time.perf_counter() - start
keys = ("lidar.noise_sigma_m", "lidar.beams", "lidar.rate_hz", "actuation.linear_gain", "actuation.angular_gain")
values = {k: [cal.values[k].value, cal.values[k].interval, cal.values[k].reason] for k in keys if k in cal.values}
for k, v in cal.effective.items():
    values[f"effective.{k}"] = [v.estimate.value, v.estimate.interval, v.estimate.reason]
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
write_calibration(cal, Path(sys.argv[4]))
print(json.dumps({"wall_s": wall, "peak_mib": peak, "score": cal.pose_source.median_score, "values": values}))
"""


def replay(bag: Path, map_yaml: Path, calibration: Path, start: np.ndarray) -> MapReplay:
    """The bag's commands open loop in the nominal and the calibrated simulator against its localized path."""
    nominal = world_config({})
    worlds = {"nominal": nominal, "calibrated": calibrated_world(nominal, calibration)}
    return map_replay([bag], map_yaml, worlds, initial_pose=[float(v) for v in start])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=float, default=60.0, help="the building's side (m)")
    parser.add_argument("--resolution", type=float, default=0.05, help="the map's cell (m)")
    parser.add_argument("--minutes", type=float, default=10.0, help="the bag's length")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--keep", type=Path, default=None, help="keep the map and the bag in this folder")
    args = parser.parse_args(argv)
    if args.size < 20:
        parser.error(f"--size {args.size:g}: the building needs at least 20 m (two corridors 10 m apart)")
    if not 0 < args.resolution <= 0.5:
        parser.error(f"--resolution {args.resolution:g}: a map cell of more than 0 and at most 0.5 m")
    if not args.minutes > 0:
        parser.error(f"--minutes {args.minutes:g}: the bag must last more than 0 minutes")
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        started = time.perf_counter()
        floor, corners = building(args.size, args.resolution, args.seed)
        map_yaml = floor.write_map_server(folder / "building.yaml")
        faces = len(floor.geometry(0.2).a)
        print(f"map: {floor.occupied.shape[1]} x {floor.occupied.shape[0]} cells at {args.resolution} m, {faces} faces")
        run = drive(corners, args.minutes * 60.0)
        bag = folder / "building.mcap"
        duration = write_bag(bag, floor, run, args.seed)
        print(
            f"bag: {duration:.0f} s, {bag.stat().st_size / 2**20:.0f} MiB, {len(run['cmd'])} commands, "
            f"{int(duration * SCAN_HZ)} scans of {BEAMS} beams (made in {time.perf_counter() - started:.0f} s)",
            flush=True,
        )
        start = ",".join(f"{v:.3f}" for v in run["pose"][0])
        child = subprocess.run(
            [sys.executable, "-c", CHILD, str(bag), str(map_yaml), start, str(folder / "calibration")],
            capture_output=True,
            text=True,
            cwd=ROOT,
            check=False,
        )
        if child.returncode != 0:
            print(child.stderr[-3000:])
            return 1
        result = json.loads(child.stdout.strip().splitlines()[-1])
        replayed = replay(bag, map_yaml, folder / "calibration" / "calibration.yaml", run["pose"][0])
    print(f"localization: median match score {result['score']:.2f}")
    truth = {
        "lidar.noise_sigma_m": NOISE_M,
        "lidar.beams": BEAMS,
        "lidar.rate_hz": SCAN_HZ,
        "actuation.linear_gain": DRIVE["linear_gain"],
        "actuation.angular_gain": DRIVE["angular_gain"],
        "effective.drive_delay_s": DRIVE["delay_s"],
        "effective.drive_lag_s": DRIVE["time_constant_s"],
        "effective.drive_response_s": DRIVE["delay_s"] + DRIVE["time_constant_s"],
    }
    for key, (value, interval, reason) in result["values"].items():
        if value is None:
            print(f"  {key:28s} unidentifiable: {reason}")
            continue
        within = "" if interval is None else ("  covered" if interval[0] <= truth[key] <= interval[1] else "  missed")
        shown = "" if interval is None else f" [{interval[0]:.4g}, {interval[1]:.4g}]"
        print(f"  {key:28s} {value:.4g}{shown}  made with {truth[key]:.4g}{within}")
    print(
        f"open-loop replay against the localized path ({replayed.windows} windows of {replayed.window_s:g} s), "
        "mean (p90) distance:"
    )
    for line in replayed.lines():
        print(f"  {line}")
    peak, wall = result["peak_mib"], result["wall_s"]
    print(
        f"calibration: peak memory {peak:.0f} MiB (limit {MEMORY_LIMIT_MIB}), {wall:.0f} s for a {duration:.0f} s bag"
    )
    print(
        f"peak_mib={peak:.0f} limit_ratio={peak / MEMORY_LIMIT_MIB:.2f} wall_s={wall:.0f} "
        f"duration_ratio={wall / duration:.2f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
