"""The deploy runner's rules for data that goes stale, and for odometry that counts from anywhere.

A robot whose scan, odometry or ground truth is stale stands still (zero commands) until its data is
fresh again; one that stays stale for `abort_after_ns` aborts the episode. The robots' odometry is
rebased at each episode's start so that it begins at the scenario's start poses, as in simulation.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np


class StalenessWatch:
    """Since when each robot has been stale without a break; which have been stale too long."""

    def __init__(self, abort_after_ns: int) -> None:
        self.abort_after_ns = abort_after_ns
        self.since: dict[str, int] = {}

    def reset(self) -> None:
        self.since.clear()

    def update(self, t_ns: int, stale: Mapping[str, str]) -> dict[str, str]:
        """Take the stale robots at `t_ns` (name -> why); return those stale for `abort_after_ns` or longer."""
        for name in [n for n in self.since if n not in stale]:
            del self.since[name]
        for name in stale:
            self.since.setdefault(name, t_ns)
        return {name: why for name, why in stale.items() if t_ns - self.since[name] >= self.abort_after_ns}


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Planar pose composition a (+) b for (n, 3) arrays of (x, y, yaw)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.stack(
        [
            a[:, 0] + c * b[:, 0] - s * b[:, 1],
            a[:, 1] + s * b[:, 0] + c * b[:, 1],
            np.angle(np.exp(1j * (a[:, 2] + b[:, 2]))),
        ],
        axis=1,
    )


def inverse(a: np.ndarray) -> np.ndarray:
    """The planar pose inverse of (n, 3) poses: compose(a, inverse(a)) is the identity."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.stack([-c * a[:, 0] - s * a[:, 1], s * a[:, 0] - c * a[:, 1], -a[:, 2]], axis=1)


class OdometryFrame:
    """Maps each robot's odometry into the map frame, rebased so that an episode starts at the known starts."""

    def __init__(self, n_robots: int) -> None:
        self.origin = np.zeros((n_robots, 3))

    def rebase(self, starts: np.ndarray, odometry: np.ndarray) -> None:
        """From now on, the odometry poses `odometry` (n, 3) read as the map poses `starts` (n, 3)."""
        self.origin = compose(np.asarray(starts, dtype=float), inverse(np.asarray(odometry, dtype=float)))

    def to_map(self, odometry: np.ndarray) -> np.ndarray:
        return compose(self.origin, np.asarray(odometry, dtype=float))
