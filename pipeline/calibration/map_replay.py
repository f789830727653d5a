"""Fidelity on real data without motion capture: a bag's commands open loop in the simulator, against its path
localized in the building's map.

:func:`map_replay` reads the recordings as calibration does with ``--map`` (each robot localized from its scans
and odometry in the map_server map), cuts every robot's localized path into windows of the longest horizon (one
every `every_s` seconds at most), and drives each simulator of `worlds` (the nominal one, a calibrated one) open
loop from the window's first localized pose with the commands as sent
(:func:`pipeline.sim.open_loop.open_loop_errors`) in the map's stand-in room, with the map's walls: a simulated
robot whose body reaches one stays where it was last free, as it would against the wall (the windows where that
happened are counted). A window starts where every robot has stood still (commanded zero) for a second, just
before it moves again: the simulator starts at rest. The drift at each horizon (5, 10, 30 s by default) is the
distance from the simulated robot to the localized path then: its mean and 90th percentile over the windows, per
simulator. The localized path has the localization's own error (a few centimetres where the scans match the map),
a floor under every drift.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pipeline.calibration.calibrate import localized_recordings
from pipeline.calibration.errors import CalibrationError
from pipeline.calibration.localize import OccupancyMap
from pipeline.calibration.recording import RobotData, SessionData
from pipeline.params import RandomizeConfig, WorldConfig, world_config
from pipeline.sim.open_loop import Track, open_loop_errors
from pipeline.sim.world import SimWorld

TICK_S = 0.02
HORIZONS_S = (5.0, 10.0, 30.0)
REST_S = 1.0
"""A window starts where every robot has been commanded to stand still this long: the simulator starts at rest, so
a window started in motion would measure the start, not the drive."""
MAX_GAP_S = 1.0
"""A window whose localized path has a gap longer than this (localization lost, a pause in recording) is left out."""


@dataclass(frozen=True)
class Drift:
    """One simulator's open-loop drift from the localized path: per horizon (s), mean and p90 (m) over windows."""

    world: str
    mean_m: dict[float, float]
    p90_m: dict[float, float]
    walls: int
    """Windows in which a simulated robot reached a wall of the map (and stayed there, as against the wall)."""
    first_tick_m: float
    """Mean distance after the first step (one tick): the offset between the localized path and the replay's
    start that no simulator removes (localization's error and timing), the floor under every drift."""


@dataclass(frozen=True)
class MapReplay:
    windows: int
    """Windows replayed (every robot's together)."""
    window_s: float
    drifts: tuple[Drift, ...]
    localization: str
    """Where the recorded path comes from, in words."""

    def lines(self) -> list[str]:
        """A markdown table: horizon by simulator, mean (p90)."""
        head = "| horizon | " + " | ".join(f"{d.world} simulator, mean (p90)" for d in self.drifts) + " |"
        out = [head, "|---" * (len(self.drifts) + 1) + "|"]
        first = " | ".join(f"{d.first_tick_m:.3f} m" for d in self.drifts)
        out.append(f"| {TICK_S:g} s (the path's own offset) | {first} |")
        walls = " | ".join(f"{d.walls} of {self.windows} windows" for d in self.drifts)
        out.append(f"| a simulated robot met a wall of the map | {walls} |")
        for h in sorted(self.drifts[0].mean_m):
            cells = " | ".join(f"{d.mean_m[h]:.3f} m ({d.p90_m[h]:.3f} m)" for d in self.drifts)
            out.append(f"| {h:g} s | {cells} |")
        return out


def map_replay(
    recordings: Sequence[str | Path],
    map_file: str | Path,
    worlds: Mapping[str, WorldConfig],
    horizons_s: Sequence[float] = HORIZONS_S,
    every_s: float | None = None,
    max_windows: int = 60,
    initial_pose: Sequence[float] = (),
    progress: Callable[[str], None] | None = None,
) -> MapReplay:
    """Each simulator of `worlds` driven open loop with the recordings' commands, against their localized path.

    Raises:
        CalibrationError: nothing to replay (no window of the longest horizon with a localized path and commands).
    """
    window_s = max(horizons_s)
    ticks = round(window_s / TICK_S)
    step = every_s if every_s is not None else window_s

    def nothing(where: str) -> CalibrationError:
        return CalibrationError(
            where,
            f"no {window_s:g} s stretch of path with commands to replay that starts with every robot standing still "
            f"for {REST_S:g} s (commanded zero, or sent nothing for {COMMAND_TIMEOUT_S:g} s: the driver stops; the "
            f"simulator starts at rest; gaps in the path over {MAX_GAP_S:g} s break a stretch); a shorter "
            "--horizon-s may find one",
        )

    def has_window(data: SessionData) -> None:
        """Before the long localization: a window's start exists in the commands (the path is checked after)."""
        commands = command_tracks(data.robots)
        if commands is None:
            raise nothing(str(data.path))
        last = max(int(t[-1]) for t in _stream_times(data.robots))
        if not any(t0 + int(window_s * 1e9) <= last for t0 in rest_starts(commands).tolist()):
            raise nothing(str(data.path))

    began = time.perf_counter()

    def stage(what: str) -> None:
        if progress is not None:
            progress(f"{what} ({time.perf_counter() - began:.0f} s)")

    def checked(data: SessionData) -> None:
        has_window(data)
        if data.pose_source == "scans":
            stage(f"localizing {len(data.robots)} robot(s) of {data.path} in {Path(map_file).name}")

    stage(f"reading {len(recordings)} recording(s)")
    sessions, scenario = localized_recordings(
        recordings, map_file, initial_pose=initial_pose, before_localizing=checked
    )
    cases: list[tuple[np.ndarray, list[Track], list[Track], int, int]] = []
    for data in sessions:
        robots = [r for r in data.robots if r.truth is not None]
        commands = command_tracks(data.robots)
        if len(robots) != len(data.robots) or commands is None:
            continue
        poses = [Track(r.truth.time.t_ns, r.truth.pose) for r in robots]  # type: ignore[union-attr]
        first = max(int(p.t_ns[0]) for p in poses)
        last = min(int(p.t_ns[-1]) for p in poses)
        tick_ns = round(TICK_S * 1e9)
        next_ns = first  # a window starts where the robots stop standing still at or after this
        for t0 in rest_starts(commands).tolist():
            if t0 + tick_ns < next_ns:
                continue
            end = t0 + int(window_s * 1e9)
            if end > last or len(cases) >= max_windows:
                break
            if all(_continuous(p, t0, end) for p in poses):
                start = np.stack([p.next_at(t0) for p in poses])  # type: ignore[misc]
                cases.append((start, commands, poses, t0, end))
            next_ns = t0 + int(step * 1e9)
    if not cases:
        raise nothing(str(recordings[0]))
    floor = OccupancyMap.from_map_server(map_file)
    radii = np.asarray(scenario.radii, dtype=np.float64)

    def blocked(xy: np.ndarray) -> np.ndarray:
        """Robots whose body overlaps a wall of the map (the simulator's stand-in room has none inside)."""
        return np.asarray(floor.distance_only(xy) < radii[: len(xy)])

    drifts = []
    for name, world in worlds.items():
        stage(f"{len(cases)} windows of {window_s:g} s in the {name} simulator")
        sim = SimWorld(scenario, _replay_world(world))
        runs = [open_loop_errors(sim, start, c, p, t0, end, ticks, TICK_S, blocked) for start, c, p, t0, end in cases]
        errors = np.stack([e for e, _ in runs])  # (windows, ticks, robots)
        walls = sum(int(hit.any()) for _, hit in runs)
        mean, p90 = {}, {}
        for h in horizons_s:
            k = min(round(h / TICK_S) - 1, ticks - 1)
            at = errors[:, k, :].ravel()
            at = at[np.isfinite(at)]
            mean[h] = float(at.mean()) if at.size else math.nan
            p90[h] = float(np.percentile(at, 90)) if at.size else math.nan
        offset = errors[:, 0, :].ravel()
        drifts.append(
            Drift(name, mean, p90, walls, float(np.nanmean(offset)) if np.isfinite(offset).any() else math.nan)
        )
    where = "localized in " + Path(map_file).name + " from scans and odometry"
    if all(d.pose_source != "scans" for d in sessions):
        where = "motion capture"
    return MapReplay(len(cases), window_s, tuple(drifts), where)


COMMAND_TIMEOUT_S = 0.5
"""A robot's driver stops it when no command came for this long (the twin's and ROS base drivers' rule): a silence
longer than this is a command to stand still, from the timeout on."""


def _stream_times(robots: Sequence[RobotData]) -> list[np.ndarray]:
    """The recording's time lines (ns) of each robot's streams that have messages."""
    out = []
    for r in robots:
        for series in (r.truth, r.odom, r.scans):
            if series is not None and len(series.time.t_ns):
                out.append(series.time.t_ns)
        if r.commands is not None and len(r.commands.t_ns):
            out.append(r.commands.t_ns)
    return out


def command_tracks(robots: Sequence[RobotData]) -> list[Track] | None:
    """Each robot's commands as its driver applied them: a zero from the recording's start until the first
    command and wherever none came for `COMMAND_TIMEOUT_S` (from the timeout on); None where a robot sent none."""
    times = _stream_times(robots)
    if not times or any(r.commands is None or len(r.commands.t_ns) == 0 for r in robots):
        return None
    begin = min(int(t[0]) for t in times)
    timeout_ns = round(COMMAND_TIMEOUT_S * 1e9)
    out = []
    for r in robots:
        cmd = r.commands
        if cmd is None:
            return None
        t = np.asarray(cmd.t_ns, dtype=np.int64)
        values = np.stack([cmd.v, cmd.w], axis=1).astype(np.float64)
        stops = t[np.flatnonzero(np.diff(t) > timeout_ns)] + timeout_ns  # silences: the driver stops at timeout
        stops = np.r_[stops, t[-1] + timeout_ns]
        lead = np.array([begin], dtype=np.int64) if t[0] - begin > timeout_ns else np.zeros(0, dtype=np.int64)
        all_t = np.r_[lead, t, stops]
        all_v = np.r_[np.zeros((len(lead), 2)), values, np.zeros((len(stops), 2))]
        order = np.argsort(all_t, kind="stable")
        out.append(Track(all_t[order], all_v[order]))
    return out


def rest_starts(commands: Sequence[Track]) -> np.ndarray:
    """The times, in order, at which every robot has been commanded (0, 0) for `REST_S` and moves again: one tick
    before the end of each robot's standing still, where a window starts (int ns)."""
    rest_ns = int(REST_S * 1e9)
    ends: list[np.ndarray] = []
    for track in commands:
        still = np.all(track.values == 0.0, axis=1)
        # runs of standing still: [first zero command, first moving command after it)
        edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
        stop = np.minimum(edges[1::2], len(track.t_ns) - 1)
        begin, end = track.t_ns[edges[0::2]], track.t_ns[stop]
        ends.append(end[end - begin >= rest_ns])
    common = [t for t in ends[0] if all(np.any(np.abs(other - t) <= rest_ns // 2) for other in ends[1:])]
    return np.asarray(common, dtype=np.int64) - round(TICK_S * 1e9)


def _continuous(track: Track, t0: int, end: int) -> bool:
    inside = track.t_ns[(track.t_ns >= t0) & (track.t_ns <= end)]
    if len(inside) < 2:
        return False
    gaps = np.diff(np.r_[t0, inside, end]) / 1e9
    return bool(gaps.max() <= MAX_GAP_S)


def _replay_world(world: WorldConfig) -> WorldConfig:
    """The world's own values, not a randomized draw (replay asks how far the point estimates carry), stepped at
    the replay's tick for as long as a window lasts."""
    return world_config(
        {"control_period_s": TICK_S, "max_steps": 100_000, "lidar": {"noise_sigma_m": 0.0}},
        base=replace(world, randomize=RandomizeConfig()),
    )
