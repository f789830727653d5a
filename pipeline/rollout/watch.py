"""The deploy runner's rules for data that goes stale, and for odometry that counts from anywhere.

A robot whose scan, odometry or ground truth is stale stands still (zero commands) until its data is
fresh again, while the others drive on; one that stays stale for the fleet's outage limit aborts the
episode. Each stale interval is an event of the recording (``stale`` when it begins, ``fresh`` when it
ends) and its length is added to the robot's stale seconds. The robots' odometry is rebased at each
episode's start so that it begins at the scenario's start poses, as in simulation.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.core.timebase import NS_PER_S


@dataclass(frozen=True)
class StaleChange:
    """What one control step changed: robots that went stale (name -> why), came back (name -> seconds stale),
    and have been blind past the outage limit (name -> why)."""

    began: dict[str, str]
    ended: dict[str, float]
    outage: dict[str, str]


class StalenessWatch:
    """Since when each robot has been stale without a break, its stale seconds in the episode, who is blind too long."""

    def __init__(self, outage_ns: int, robots: Sequence[str] = ()) -> None:
        self.outage_ns = outage_ns
        self.robots = tuple(robots)
        self.since: dict[str, int] = {}
        self._total_ns: dict[str, int] = dict.fromkeys(self.robots, 0)

    def reset(self) -> None:
        self.since.clear()
        self._total_ns = dict.fromkeys(self.robots, 0)

    def update(self, t_ns: int, stale: Mapping[str, str]) -> StaleChange:
        """Take the stale robots at `t_ns` (name -> why)."""
        ended: dict[str, float] = {}
        for name in [n for n in self.since if n not in stale]:
            span = t_ns - self.since.pop(name)
            self._total_ns[name] = self._total_ns.get(name, 0) + span
            ended[name] = span / NS_PER_S
        began = {name: why for name, why in stale.items() if name not in self.since}
        for name in began:
            self.since[name] = t_ns
        outage = {name: why for name, why in stale.items() if t_ns - self.since[name] >= self.outage_ns}
        return StaleChange(began, ended, outage)

    def stale_s(self, t_ns: int) -> np.ndarray:
        """(n_robots,) seconds each robot has been stale in this episode up to `t_ns` (open intervals included)."""
        return np.array(
            [
                (self._total_ns.get(r, 0) + (t_ns - self.since[r] if r in self.since else 0)) / NS_PER_S
                for r in self.robots
            ]
        )


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
