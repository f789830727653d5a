"""A scripted go-to-goal controller with reactive obstacle avoidance: the baseline policy.

It reads the `rich` observation layout (heading and the goal in the robot frame) through the
layout's slice map and returns actions for the action codec, so it runs wherever a learned
policy runs: in sim, on the twin, on robots.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.core.actions import ActionCodec
from pipeline.core.observation import ObservationLayout


class GoToGoalController:
    """Steers each robot toward its goal, bending away from lidar returns closer than `influence_m`."""

    def __init__(
        self, layout: ObservationLayout, codec: ActionCodec, influence_m: float = 0.7, heading_gain: float = 1.5
    ) -> None:
        if not layout.has_goal:
            raise ValueError(
                f"the scripted controller needs the 'rich' observation layout (heading and goal), got {layout.name!r}"
            )
        self.layout = layout
        self.codec = codec
        self.influence_m = influence_m
        self.heading_gain = heading_gain
        self._slices = layout.slices
        angles = 2 * math.pi * np.arange(layout.n_beams) / layout.n_beams
        self._dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        self._front = np.abs(np.angle(np.exp(1j * angles))) <= math.radians(35)

    def commands(self, obs: np.ndarray) -> np.ndarray:
        """(n_robots, 2) (v m/s, w rad/s) for observations (n_robots, layout.size)."""
        goal = obs[:, self._slices["goal_in_robot"]].astype(np.float64)
        ranges = obs[:, self._slices["ranges"]].astype(np.float64)
        dist = np.hypot(goal[:, 0], goal[:, 1])
        attract = goal / np.maximum(dist, 1e-6)[:, None]
        push = np.clip((self.influence_m - ranges) / self.influence_m, 0.0, 1.0)
        repulse = -(push[:, :, None] * self._dirs[None]).sum(axis=1)
        # near the goal the obstacle field must not push the robot out of its square
        weight = np.clip(dist / 0.6, 0.0, 1.0)[:, None]
        want = attract + 1.2 * weight * repulse
        err = np.arctan2(want[:, 1], want[:, 0])
        front = np.where(self._front[None], ranges, np.inf).min(axis=1)
        v = self.codec.v_max_mps * np.clip(np.cos(err), 0.0, 1.0) ** 4
        v *= np.clip(dist / 0.4, 0.25, 1.0) * np.clip((front - 0.22) / 0.4, 0.0, 1.0)
        w = np.clip(self.heading_gain * err, -self.codec.w_max_radps, self.codec.w_max_radps)
        return np.stack([v, w], axis=1)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Actions for the codec: (n, 2) in [-1, 1] (continuous) or (n,) indices (discrete)."""
        cmd = self.commands(obs)
        if self.codec.kind == "continuous":
            return self.codec.encode(cmd)
        table = self.codec.table
        # nearest discrete command, comparing turn rate first, then speed
        cost = (
            np.abs(table[None, :, 1] - cmd[:, None, 1]) / self.codec.w_max_radps
            + 0.5 * np.abs(table[None, :, 0] - cmd[:, None, 0]) / self.codec.v_max_mps
        )
        return np.asarray(cost.argmin(axis=1))
