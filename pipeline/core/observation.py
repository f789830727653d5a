"""Observation layouts: named, sliced vectors built the same way in sim, on the twin and on robots.

``paper``: x, y (odometry, m) then N ranges (m): 17 values for 15 beams, as the original.
``rich``: x, y, cos(yaw), sin(yaw) (odometry), the own goal's centre in the robot frame
(forward, left, m), then N ranges (m). Shared networks need it: it tells robots apart.
``rich_limits``: ``rich`` with the robot's own speed limits and body radius (v_max m/s, w_max rad/s,
radius m) before the ranges: one shared network for a mixed fleet.
``rich_memory``: ``rich`` with the command the robot was given at the previous control step (v, w as fractions
of its own limits; zero at an episode's start) before the ranges: one step of memory. The builder is told
every command given (:meth:`ObservationBuilder.remember`), by the simulator and the deploy runner alike.

The builder (:class:`ObservationBuilder`) is the one path from raw sensor data to observations, used by
sim, twin and robots. A world hands over each robot's LaserScan-shaped ranges with their geometry and its odometry
pose; the builder reduces the scans to the policy's beams, builds the layout's vector, and clips
it to the observation bounds of the scenario's room. Nothing else builds observations.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from pipeline.core.scan import Reduction, ScanGeometry, reduce_scan
from pipeline.core.scenario import Scenario

LayoutName = Literal["paper", "rich", "rich_limits", "rich_memory"]
ObservedPose = Literal["odometry", "ground_truth"]
"""Where an observation's pose comes from: wheel odometry, or ground truth (motion capture, the simulator)."""
LAYOUTS: tuple[LayoutName, ...] = ("paper", "rich", "rich_limits", "rich_memory")

_FIELDS: dict[str, tuple[tuple[str, int], ...]] = {
    "paper": (("position", 2),),
    "rich": (("position", 2), ("heading", 2), ("goal_in_robot", 2)),
    "rich_limits": (("position", 2), ("heading", 2), ("goal_in_robot", 2), ("limits", 3)),
    "rich_memory": (("position", 2), ("heading", 2), ("goal_in_robot", 2), ("previous_command", 2)),
}
LIMITS_HIGH = (10.0, 50.0, 2.0)
"""Upper bounds of the limits field (v_max m/s, w_max rad/s, radius m), as the scenario's keys allow."""


@dataclass(frozen=True)
class ObservationLayout:
    """A named observation layout for `n_beams` lidar ranges."""

    name: LayoutName
    n_beams: int

    def __post_init__(self) -> None:
        if self.name not in _FIELDS:
            raise ValueError(f"unknown observation layout {self.name!r}; allowed: {', '.join(LAYOUTS)}")

    @property
    def fields(self) -> tuple[tuple[str, int], ...]:
        """(name, size) pairs in vector order."""
        return (*_FIELDS[self.name], ("ranges", self.n_beams))

    @property
    def size(self) -> int:
        return sum(n for _, n in self.fields)

    @property
    def slices(self) -> dict[str, slice]:
        """Field name -> slice of the observation vector."""
        out, start = {}, 0
        for name, n in self.fields:
            out[name] = slice(start, start + n)
            start += n
        return out

    @property
    def names(self) -> tuple[str, ...]:
        """One name per element, e.g. ('x_m', 'y_m', 'range_0_m', ...)."""
        per_field = {
            "position": ("x_m", "y_m"),
            "heading": ("cos_yaw", "sin_yaw"),
            "goal_in_robot": ("goal_forward_m", "goal_left_m"),
            "limits": ("v_max_mps", "w_max_radps", "radius_m"),
            "previous_command": ("previous_v_frac", "previous_w_frac"),
            "ranges": tuple(f"range_{k}_m" for k in range(self.n_beams)),
        }
        return tuple(n for name, _ in self.fields for n in per_field[name])

    def bounds(
        self,
        x_lim_m: tuple[float, float],
        y_lim_m: tuple[float, float],
        range_min_m: float,
        range_max_m: float,
        margin_m: float = 1.0,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) float32 vectors of the observation space for a room's limits."""
        span = float(np.hypot(x_lim_m[1] - x_lim_m[0], y_lim_m[1] - y_lim_m[0])) + 2 * margin_m
        per_field = {
            "position": (
                [x_lim_m[0] - margin_m, y_lim_m[0] - margin_m],
                [x_lim_m[1] + margin_m, y_lim_m[1] + margin_m],
            ),
            "heading": ([-1.0, -1.0], [1.0, 1.0]),
            "goal_in_robot": ([-span, -span], [span, span]),
            "limits": ([0.0, 0.0, 0.0], list(LIMITS_HIGH)),
            "previous_command": ([-1.0, -1.0], [1.0, 1.0]),
            "ranges": ([range_min_m] * self.n_beams, [range_max_m] * self.n_beams),
        }
        low = np.concatenate([per_field[n][0] for n, _ in self.fields]).astype(np.float32)
        high = np.concatenate([per_field[n][1] for n, _ in self.fields]).astype(np.float32)
        return low, high

    @property
    def has_memory(self) -> bool:
        """Whether it carries the previous command (the builder then needs every command it gives)."""
        return self.name == "rich_memory"

    @property
    def has_goal(self) -> bool:
        """Whether the robot's goal is in it (every layout but the paper's)."""
        return self.name != "paper"

    def build(
        self,
        odom_pose: np.ndarray,
        ranges: np.ndarray,
        goals: np.ndarray,
        limits: np.ndarray | None = None,
        previous: np.ndarray | None = None,
    ) -> np.ndarray:
        """Observations (n_robots, size) float32.

        odom_pose: (n_robots, 3) x, y (m), yaw (rad) from odometry.
        ranges: (n_robots, n_beams) reduced lidar ranges (m).
        goals: (n_robots, 2) goal centres (m).
        limits: (n_robots, 3) v_max (m/s), w_max (rad/s), body radius (m) (``rich_limits`` only).
        previous: (n_robots, 2) the previous command, v and w as fractions of the robot's limits (``rich_memory`` only).
        """
        pose = np.asarray(odom_pose, dtype=np.float64)
        r = np.asarray(ranges, dtype=np.float64)
        if r.shape != (pose.shape[0], self.n_beams):
            raise ValueError(f"ranges have shape {r.shape}, the layout needs ({pose.shape[0]}, {self.n_beams})")
        parts = [pose[:, :2]]
        if self.has_goal:
            c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
            d = np.asarray(goals, dtype=np.float64) - pose[:, :2]
            parts += [
                np.stack([c, s], axis=1),
                np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1),
            ]
        if self.name == "rich_limits":
            if limits is None or np.shape(limits) != (pose.shape[0], 3):
                raise ValueError(f"the rich_limits layout needs limits of shape ({pose.shape[0]}, 3)")
            parts.append(np.asarray(limits, dtype=np.float64))
        if self.name == "rich_memory":
            if previous is None or np.shape(previous) != (pose.shape[0], 2):
                raise ValueError(f"the rich_memory layout needs previous commands of shape ({pose.shape[0]}, 2)")
            parts.append(np.asarray(previous, dtype=np.float64))
        parts.append(r)
        return np.concatenate(parts, axis=1).astype(np.float32)


@dataclass(frozen=True)
class Observed:
    """Reduced ranges (n_robots, n_beams) in metres and observations (n_robots, layout.size) float32."""

    ranges: np.ndarray
    obs: np.ndarray


class ObservationBuilder:
    """Builds observations of `layout` for the robots of `scenario` (goals, room bounds)."""

    def __init__(
        self,
        scenario: Scenario,
        layout: ObservationLayout,
        range_min_m: float,
        range_max_m: float,
        reduction: Reduction = "sector_min",
    ) -> None:
        self.scenario = scenario
        self.goals = scenario.goals
        """(n_robots, 2) the goals the observation points at: the layout's, or a pursuit's moving target."""
        self.limits: np.ndarray | None = None
        """(n_robots, 3) v_max, w_max, radius of each robot, for the ``rich_limits`` layout (set by the MDP)."""
        self.previous = np.zeros((scenario.n_robots, 2))
        """(n_robots, 2) the last command given, as fractions of each robot's limits (``rich_memory``; see
        :meth:`forget`, :meth:`remember`)."""
        self.layout = layout
        self.range_min_m = range_min_m
        self.range_max_m = range_max_m
        self.reduction: Reduction = reduction
        room = scenario.room
        self.low, self.high = layout.bounds(
            (room.x_min_m, room.x_max_m), (room.y_min_m, room.y_max_m), range_min_m, range_max_m
        )

    def use_layout(self, scenario: Scenario) -> None:
        """Observe against `scenario`'s goals (another layout of the same room and robots)."""
        self.scenario = scenario
        self.goals = scenario.goals

    def forget(self) -> None:
        """An episode starts: no command was given yet."""
        self.previous = np.zeros((self.scenario.n_robots, 2))

    def remember(self, commands: np.ndarray) -> None:
        """The commands (n_robots, 2) v (m/s), w (rad/s) just given to the robots, for the next observation."""
        if not self.layout.has_memory:
            return
        if self.limits is None:
            raise ValueError("the rich_memory layout needs the robots' limits to scale their commands")
        cmd = np.asarray(commands, dtype=np.float64)
        self.previous = np.clip(cmd / self.limits[:, :2], -1.0, 1.0)

    def reduce(
        self, scans: np.ndarray | Sequence[np.ndarray], geometry: ScanGeometry | Sequence[ScanGeometry]
    ) -> np.ndarray:
        """(n_robots, n_beams) policy ranges from every robot's scan; one geometry for all or one per robot."""
        n = self.layout.n_beams
        if isinstance(geometry, ScanGeometry):
            return reduce_scan(
                np.asarray(scans), geometry, n, self.range_min_m, self.range_max_m, self.reduction
            ).reshape(-1, n)
        return np.stack(
            [
                reduce_scan(np.asarray(s), g, n, self.range_min_m, self.range_max_m, self.reduction)
                for s, g in zip(scans, geometry, strict=True)
            ]
        )

    def build(
        self,
        scans: np.ndarray | Sequence[np.ndarray],
        geometry: ScanGeometry | Sequence[ScanGeometry],
        odom_pose: np.ndarray,
    ) -> Observed:
        """Observations from scans and odometry poses (n_robots, 3) x, y (m), yaw (rad)."""
        ranges = self.reduce(scans, geometry)
        obs = self.layout.build(odom_pose, ranges, self.goals, self.limits, self.previous)
        return Observed(ranges=ranges, obs=np.minimum(np.maximum(obs, self.low), self.high))
