"""The pursuit task's scripted evader: the target the robots chase.

Each control step it moves away from the pursuers closer than `flee_distance_m` (the sum of their unit
directions weighted by their closeness, so the nearest counts most), pushed off walls and boxes closer
than a body radius plus `clearance_m` plus one step, at up to `speed_mps`; without a pursuer in range it
stands still. A step that would end closer than its radius plus clearance to a wall is cut at that
distance, one into a box is not taken: it slides along the box or stops there, as a cornered animal
does. It moves holonomically (a quadruped steps sideways as readily as forward). The simulator moves its
body to each new position; the hardware twin publishes it as a robot of its own.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.core.scenario import Scenario, box_clearance

REPULSION_GAIN = 1.5
"""Weight of a wall or box at contact, relative to a pursuer at distance 0 (falls off linearly to 0)."""


class Evader:
    """The target of a pursuit scenario: its position (2,) and one scripted step per control period."""

    def __init__(self, scenario: Scenario) -> None:
        if scenario.target is None:
            raise ValueError(f"scenario {scenario.name!r} has no target")
        self.scenario = scenario
        self.target = scenario.target
        self.xy = np.array([self.target.start.x_m, self.target.start.y_m])
        self.velocity = np.zeros(2)

    def reset(self, layout: Scenario | None = None) -> None:
        """Back to the target's start, at rest; with `layout` (an episode's layout drawn from this scenario) at
        its start, keeping off its boxes."""
        if layout is not None:
            if layout.target is None:
                raise ValueError(f"layout {layout.name!r} has no target")
            self.scenario, self.target = layout, layout.target
        self.xy = np.array([self.target.start.x_m, self.target.start.y_m])
        self.velocity = np.zeros(2)

    def _keep(self) -> float:
        return self.target.radius_m + self.target.clearance_m

    def _clear_of_boxes(self, xy: np.ndarray) -> bool:
        p = xy[None, :]
        return all(box_clearance(box, p)[0] >= self._keep() for box in self.scenario.obstacles)

    def step(self, dt_s: float, pursuers_xy: np.ndarray) -> np.ndarray:
        """Move for `dt_s` seconds given the pursuers' positions (n, 2); returns the new position."""
        t, room = self.target, self.scenario.room
        reach = t.speed_mps * dt_s
        away = np.zeros(2)
        d = self.xy - np.asarray(pursuers_xy, dtype=float)[:, :2]
        dist = np.hypot(d[:, 0], d[:, 1])
        close = dist < t.flee_distance_m
        if not close.any() or reach <= 0:
            self.velocity = np.zeros(2)
            return self.xy.copy()
        for vec, r in zip(d[close], dist[close], strict=True):
            away += (vec / max(r, 1e-9)) * (1.0 - r / t.flee_distance_m)
        margin = self._keep() + 3 * reach
        x, y = self.xy
        for gap, normal in (
            (x - room.x_min_m, (1.0, 0.0)),
            (room.x_max_m - x, (-1.0, 0.0)),
            (y - room.y_min_m, (0.0, 1.0)),
            (room.y_max_m - y, (0.0, -1.0)),
        ):
            if gap < margin + 0.5:
                away += REPULSION_GAIN * np.array(normal) * (1.0 - max(gap - self._keep(), 0.0) / (margin + 0.5))
        for box in self.scenario.obstacles:
            gap = float(box_clearance(box, self.xy[None, :])[0])
            if gap < margin + 0.5:
                normal = self.xy - np.array([box.x_m, box.y_m])
                normal /= max(float(np.hypot(*normal)), 1e-9)
                away += REPULSION_GAIN * normal * (1.0 - max(gap - self._keep(), 0.0) / (margin + 0.5))
        norm = float(np.hypot(*away))
        if norm < 1e-9:
            self.velocity = np.zeros(2)
            return self.xy.copy()
        move = away / norm * reach
        keep = self._keep()
        for candidate in (move, np.array([move[0], 0.0]), np.array([0.0, move[1]])):  # straight, else slide
            nxt = self.xy + candidate
            nxt[0] = min(max(nxt[0], room.x_min_m + keep), room.x_max_m - keep)
            nxt[1] = min(max(nxt[1], room.y_min_m + keep), room.y_max_m - keep)
            if self._clear_of_boxes(nxt):
                self.velocity = (nxt - self.xy) / dt_s
                self.xy = nxt
                return self.xy.copy()
        self.velocity = np.zeros(2)
        return self.xy.copy()

    @property
    def heading_rad(self) -> float:
        """Direction of its last move (0 when it stood still)."""
        return math.atan2(self.velocity[1], self.velocity[0]) if self.velocity.any() else 0.0
