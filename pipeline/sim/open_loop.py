"""Recorded commands driven open loop through the simulator, against recorded poses.

:func:`open_loop_errors` puts each robot at its recorded pose, then steps the simulated world every
`tick_s` with the command each robot was last sent (held, as a base holds it), and measures after
each step how far each simulated robot is from where the recording has it. Replay against motion
capture (:mod:`pipeline.analysis.replay`) and against poses localized in a map
(:mod:`pipeline.calibration.map_replay`) share it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.sim.world import SimWorld


@dataclass(frozen=True)
class Track:
    """One robot's recorded stream: times (n,) int ns and values (n, k)."""

    t_ns: np.ndarray
    values: np.ndarray

    def last_at(self, t_ns: int) -> np.ndarray | None:
        """The value last recorded at or before `t_ns` (None before the first)."""
        j = int(np.searchsorted(self.t_ns, t_ns, side="right")) - 1
        return self.values[j] if j >= 0 else None

    def next_at(self, t_ns: int) -> np.ndarray | None:
        """The first value recorded at or after `t_ns` (None after the last)."""
        j = int(np.searchsorted(self.t_ns, t_ns))
        return self.values[j] if j < len(self.t_ns) else None


def open_loop_errors(
    sim: SimWorld,
    start: np.ndarray,
    commands: Sequence[Track],
    poses: Sequence[Track],
    t0_ns: int,
    end_ns: int,
    ticks: int,
    tick_s: float,
    blocked: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(ticks, robots) distance (m) from each simulated robot to its recorded pose after each step (NaN after
    `end_ns` or past the last recorded pose), and (robots,) whether each met a wall.

    `blocked(xy)` ((robots, 2) positions -> (robots,) bool) marks positions inside walls the simulated world does
    not hold (a building's map): a robot that reaches one stays where it last was free, as it would against the
    wall.

    Args:
        sim: the world to drive (reset here to `start`, (robots, 3) x, y, yaw).
        commands: per robot, the (v, w) commands as sent.
        poses: per robot, the recorded (x, y, ...) poses.
        t0_ns, end_ns: the recording's times of the first step and of the window's end.
    """
    sim.reset(0, start)
    tick_ns = round(tick_s * 1e9)
    err = np.full((ticks, len(poses)), np.nan)
    held = np.full((len(poses), 2), np.nan)
    free = np.asarray(start, dtype=np.float64)[:, :2].copy()
    for k in range(ticks):
        t = t0_ns + k * tick_ns
        if t > end_ns:
            break
        command = np.zeros((len(commands), 2))
        for i, track in enumerate(commands):
            last = track.last_at(t)
            if last is not None:
                command[i] = last
        sim.step(command)
        where = np.asarray(sim.truth[:, :2], dtype=np.float64).copy()
        if blocked is not None:
            hit = np.isnan(held[:, 0]) & np.asarray(blocked(where), dtype=bool)
            held[hit] = free[hit]
            stopped = ~np.isnan(held[:, 0])
            where[stopped] = held[stopped]
            free[~stopped] = where[~stopped]
        for i, track in enumerate(poses):
            recorded = track.next_at(t + tick_ns)
            if recorded is not None:
                err[k, i] = float(np.hypot(*(where[i] - recorded[:2])))
    return err, ~np.isnan(held[:, 0])
