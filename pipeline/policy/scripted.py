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


def front_beams(n_beams: int, half_angle_rad: float = math.radians(35)) -> np.ndarray:
    """(n_beams,) which of a layout's beams (evenly around, the first straight ahead) look within `half_angle_rad`
    of straight ahead."""
    angles = 2 * math.pi * np.arange(n_beams) / n_beams
    return np.asarray(np.abs(np.angle(np.exp(1j * angles))) <= half_angle_rad)


def range_ahead(ranges: np.ndarray, front: np.ndarray) -> np.ndarray:
    """(n,) the nearest return among the `front` beams of each robot's ranges (n, n_beams) (inf without one)."""
    return np.asarray(np.where(front[None], ranges, np.inf).min(axis=1))


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
        self._front = front_beams(layout.n_beams)

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
        front = range_ahead(ranges, self._front)
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


class PathFollowingController:
    """A teacher that is told where its free path goes: it steers at the point `ahead_m` along the path to its
    goal (a bearing from the map, :meth:`pipeline.sim.env.MultiRobotSim.path_bearing`), through the lidar's
    free directions.

    Among directions around the robot it picks the one nearest that bearing whose corridor of half-width
    `half_width_m` is free of lidar returns up to `ahead_m` (the goal's distance where nearer), turning right
    rather than left by `right_bias` rad when it must leave the path (so two robots that meet head-on pass each
    other); it drives there forward or, for a direction behind it, in reverse, with pure-pursuit curvature,
    slowing for returns in its way. Told where the other robots are (`others`), it keeps the `ahead_m` corridor
    clear of their bodies (`others_radius_m`) and checks the lidar only up to `near_m`: the path already keeps
    clear of walls and boxes, and a corridor to a point around a box's corner would clip the corner and stall
    the robot there. It needs the bearing, which only the simulator knows: training's imitation uses it as a
    teacher (``train.imitation.teacher: path``); it is not a policy for deployment.
    """

    def __init__(
        self,
        layout: ObservationLayout,
        codec: ActionCodec,
        ahead_m: float = 1.0,
        half_width_m: float = 0.22,
        right_bias: float = 0.3,
        n_directions: int = 72,
        near_m: float = 0.6,
        others_radius_m: float = 0.25,
    ) -> None:
        if not layout.has_goal:
            raise ValueError(
                f"the path-following controller needs the 'rich' observation layout (goal), got {layout.name!r}"
            )
        if codec.kind != "continuous":
            raise ValueError("the path-following controller drives continuous actions (reverse included)")
        self.codec = codec
        self.ahead_m = ahead_m
        self.half_width_m = half_width_m
        self.right_bias = right_bias
        self.near_m = near_m
        self.others_radius_m = others_radius_m
        self._slices = layout.slices
        n = layout.n_beams
        # a sector's return may lie anywhere across its sector: its centre and both edges stand for it
        half = math.pi / n
        self._point_angles = (2 * math.pi * np.arange(n) / n)[:, None] + np.array([-0.95, 0.0, 0.95])[None] * half
        self._directions = np.linspace(-math.pi, math.pi, n_directions, endpoint=False)

    def commands(self, obs: np.ndarray, bearing: np.ndarray, others: np.ndarray | None = None) -> np.ndarray:
        """(n_robots, 2) (v m/s, w rad/s) for observations (n_robots, layout.size), path bearings (n_robots,) and,
        optionally, the other robots' positions in each robot's frame (n_robots, n_robots - 1, 2)."""
        goal = obs[:, self._slices["goal_in_robot"]].astype(np.float64)
        ranges = obs[:, self._slices["ranges"]].astype(np.float64)
        m = len(obs)
        dist = np.hypot(goal[:, 0], goal[:, 1])
        # near the goal, straight at it (the path's last cells are coarse)
        phi = np.where(dist < 0.5, np.arctan2(goal[:, 1], goal[:, 0]), np.asarray(bearing, dtype=np.float64))
        cand = np.concatenate([phi[:, None], np.broadcast_to(self._directions, (m, len(self._directions)))], axis=1)
        px = (ranges[:, :, None] * np.cos(self._point_angles)[None]).reshape(m, -1)
        py = (ranges[:, :, None] * np.sin(self._point_angles)[None]).reshape(m, -1)
        ux, uy = np.cos(cand)[:, :, None], np.sin(cand)[:, :, None]
        along = ux * px[:, None] + uy * py[:, None]
        across = np.abs(-uy * px[:, None] + ux * py[:, None])
        reach = np.minimum(dist, self.ahead_m if others is None else self.near_m)[:, None, None]
        blocked = ((along > -0.05) & (along < reach) & (across < self.half_width_m)).any(axis=2)
        if others is not None:
            o = np.asarray(others, dtype=np.float64).reshape(m, -1, 2)
            o_along = ux * o[:, None, :, 0] + uy * o[:, None, :, 1]
            o_across = np.abs(-uy * o[:, None, :, 0] + ux * o[:, None, :, 1])
            o_reach = np.minimum(dist, self.ahead_m)[:, None, None] + self.others_radius_m
            body = self.half_width_m + self.others_radius_m
            blocked |= ((o_along > -0.05) & (o_along < o_reach) & (o_across < body)).any(axis=2)
        dev = np.angle(np.exp(1j * (cand - phi[:, None])))
        cost = np.abs(dev) + self.right_bias * (dev > 0.05) + 10.0 * blocked
        best = cost.argmin(axis=1)
        theta = cand[np.arange(m), best]
        forward = np.abs(theta) <= math.pi / 2 + 0.3
        alpha = np.where(forward, theta, np.angle(np.exp(1j * (theta - math.pi))))
        kappa = 2 * np.sin(alpha) / np.clip(np.minimum(dist, self.ahead_m), 0.05, None)
        v_max, w_max = self.codec.v_max_mps, self.codec.w_max_radps
        v = np.minimum(v_max, w_max / np.maximum(np.abs(kappa), 1e-9))
        # far off the driving direction: turn on the spot first
        v *= np.clip((math.radians(70) - np.abs(alpha)) / math.radians(25), 0.0, 1.0)
        ahead = np.where(forward, 1.0, -1.0)[:, None] * px
        free = np.where((ahead > 0) & (np.abs(py) < self.half_width_m), ahead, np.inf).min(axis=1)
        v *= np.clip((free - 0.2) / 0.35, 0.0, 1.0)
        v = np.where(blocked.all(axis=1), 0.0, v)
        w = np.clip(kappa * v, -w_max, w_max)
        w = np.where(v < 0.05, np.sign(alpha) * w_max, w)
        return np.stack([np.where(forward, v, -v), w], axis=1)

    def __call__(self, obs: np.ndarray, bearing: np.ndarray, others: np.ndarray | None = None) -> np.ndarray:
        """Actions for the codec: (n, 2) in [-1, 1]."""
        return np.asarray(self.codec.encode(self.commands(obs, bearing, others)))
