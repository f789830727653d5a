"""The episode judge: goal, collision and timeout decisions and the reward with its terms.

One judge serves sim, twin and robots. It prefers a ground-truth pose (sim truth, the twin's
ground_truth topic, motion capture) and the known map; without ground truth it falls back to
odometry for the goal and to the lidar for collisions (closest valid range below the robot
radius plus a margin).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Literal

import numpy as np

from pipeline.core.geodesic import DistanceField, GoalFields
from pipeline.core.scenario import Scenario, box_table, boxes_clearance
from pipeline.mappings import setting

ProgressDistance = Literal["geodesic", "euclidean"]

REWARD_TERMS: tuple[str, ...] = ("progress", "heading", "goal", "team", "collision", "step", "proximity")


@dataclass(frozen=True)
class RewardWeights:
    """Named reward weights: progress per metre toward the own goal, bonuses and penalties."""

    progress_per_m: float = 10.0
    heading_per_rad: float = 0.0
    """Per radian that the heading turned toward the direction of the path to the goal (0 turns it off)."""
    goal: float = 10.0
    team: float = 10.0
    collision: float = -10.0
    step: float = 0.0
    proximity: float = setting(0.0, le=0.0, optional=True)
    """Per step while a robot's body is closer than `proximity_m` to a wall, box or robot: this much at
    contact, falling linearly to 0 at `proximity_m` (0 turns it off)."""
    proximity_m: float = setting(0.3, gt=0.0, le=2.0, optional=True)
    path_clearance_m: float = setting(0.0, ge=0.0, le=1.0, optional=True)
    """The free path that progress and heading follow keeps this much clearance (m) from walls and boxes
    beyond the robot's radius, where the room allows (0: paths graze them)."""


@dataclass(frozen=True)
class JudgeStep:
    """The judgement of one control step; arrays are (n_robots,)."""

    reward: np.ndarray
    terms: dict[str, np.ndarray]
    reached: np.ndarray
    collided: np.ndarray
    done: np.ndarray
    active: np.ndarray
    truncated: bool
    team_success: bool
    events: list[tuple[int, str]] = field(default_factory=list)

    def robot_terms(self, i: int) -> dict[str, float]:
        """Robot i's reward terms as floats; they sum exactly to float(reward[i])."""
        return {name: float(v[i]) for name, v in self.terms.items()}


class EpisodeJudge:
    """Judges each control step of an episode against a scenario's goals and map."""

    def __init__(
        self,
        scenario: Scenario,
        weights: RewardWeights,
        max_steps: int,
        collision_margin_m: float = 0.02,
        distance: ProgressDistance = "euclidean",
    ) -> None:
        """`distance` measures progress toward the goal: straight-line, or along the free path ("geodesic")."""
        self.distance = distance
        self.weights = weights
        self.max_steps = max_steps
        self.margin_m = collision_margin_m
        self.use_layout(scenario)
        n = scenario.n_robots
        self.reached = np.zeros(n, dtype=bool)
        self.collided = np.zeros(n, dtype=bool)
        self.steps = 0
        self.team_success = False
        self._prev_dist = np.zeros(n)
        self._prev_heading_err = np.zeros(n)

    def use_layout(self, scenario: Scenario) -> None:
        """Judge against `scenario`'s goals and map from the next episode on (the same robots; another layout)."""
        self.scenario = scenario
        # a moving target's free-path field would change every step: a pursuit measures progress straight
        geodesic = self.distance == "geodesic" and not scenario.pursuit
        self._fields = goal_fields(scenario, self.weights.path_clearance_m) if geodesic else None
        self.goals = scenario.goals
        self.capture_m = scenario.target.capture_distance_m if scenario.target is not None else None
        self.half_goal_m = scenario.goal_size_m / 2
        self.radius_m = scenario.radii  # (n_robots,) each robot's body
        self._radii = self.radius_m.tolist()
        self._pairs = np.triu_indices(scenario.n_robots, k=1)  # every two robots once
        self._reach = self.radius_m[self._pairs[0]] + self.radius_m[self._pairs[1]]
        self._boxes = box_table(scenario.obstacles)  # the clearance to every box in one pass

    def track(self, target_xy: np.ndarray) -> None:
        """A pursuit's target is now at `target_xy` (2,): every robot's goal from the next judgement on."""
        self.goals = np.tile(np.asarray(target_xy, dtype=np.float64)[:2], (self.scenario.n_robots, 1))

    @property
    def done(self) -> np.ndarray:
        """(n_robots,) robots whose episode is over (at goal or collided)."""
        return self.reached | self.collided

    def reset(self, pose: np.ndarray) -> None:
        """Start an episode at `pose` (n_robots, 3) (truth if known, else odometry)."""
        self.reached[:] = False
        self.collided[:] = False
        self.steps = 0
        self.team_success = False
        self._prev_dist = self.goal_distance(pose)
        self._prev_heading_err = self.heading_error(pose)

    def path_direction(self, pose: np.ndarray) -> np.ndarray:
        """(n_robots,) heading (rad) toward each robot's goal: along the free path, or straight at it."""
        xy = np.asarray(pose)[:, :2]
        if self._fields is not None:
            return self._fields.direction(xy)
        d = self.goals - xy
        return np.asarray(np.arctan2(d[:, 1], d[:, 0]))

    def path_point(self, pose: np.ndarray, ahead_m: float) -> np.ndarray:
        """(n_robots, 2) the point `ahead_m` along each robot's way to its goal: on the free path, or straight at
        the goal; the goal itself where it is nearer."""
        xy = np.asarray(pose, dtype=np.float64)[:, :2]
        if self._fields is not None:
            return self._fields.ahead(xy, self.goals, ahead_m)
        d = self.goals - xy
        gap = np.hypot(d[:, 0], d[:, 1])
        return np.asarray(xy + d * np.minimum(1.0, ahead_m / np.maximum(gap, 1e-9))[:, None])

    def heading_error(self, pose: np.ndarray) -> np.ndarray:
        """(n_robots,) |heading - path direction| in [0, pi] (rad)."""
        err = np.asarray(pose)[:, 2] - self.path_direction(pose)
        return np.asarray(np.abs(np.angle(np.exp(1j * err))))

    def goal_distance(self, pose: np.ndarray) -> np.ndarray:
        """(n_robots,) distance (m) from each robot to its goal centre, straight or along the free path."""
        xy = np.asarray(pose)[:, :2]
        if self._fields is not None:
            return self._fields.distance(xy)
        d = xy - self.goals
        return np.asarray(np.hypot(d[:, 0], d[:, 1]))

    def in_goal(self, pose: np.ndarray) -> np.ndarray:
        """(n_robots,) robot centres inside their own goal squares (in a pursuit: within capture distance of the
        target)."""
        if self.capture_m is not None:
            d = np.asarray(pose)[:, :2] - self.goals
            return np.asarray(np.hypot(d[:, 0], d[:, 1]) <= self.capture_m)
        d = np.abs(np.asarray(pose)[:, :2] - self.goals)
        return np.asarray((d[:, 0] <= self.half_goal_m) & (d[:, 1] <= self.half_goal_m))

    def clearance(self, pose: np.ndarray) -> np.ndarray:
        """(n_robots,) free distance (m) between each robot's body and the nearest wall, box or robot.

        A handful of robots is read in Python floats (numpy's per-call cost would be most of the work): the walls'
        and the robots' differences, the minima and the radii taken off are the same operations as on arrays, in
        the same order, so the same numbers to the bit; the boxes' distances and the robots' from each other are
        one numpy call each (its hypot), NaN propagates through the minima as numpy's would."""
        xy = np.asarray(pose, dtype=np.float64)[:, :2]
        room = self.scenario.room
        radii = self._radii
        gap = [
            _least(_least(x - room.x_min_m, room.x_max_m - x), _least(y - room.y_min_m, room.y_max_m - y)) - r
            for (x, y), r in zip(xy.tolist(), radii, strict=True)
        ]
        if len(self._boxes):
            nearest_box = boxes_clearance(self._boxes, xy).min(axis=1).tolist()
            gap = [_least(g, b - r) for g, b, r in zip(gap, nearest_box, radii, strict=True)]
        if len(gap) > 1:
            first, second = self._pairs
            apart = np.hypot(xy[first, 0] - xy[second, 0], xy[first, 1] - xy[second, 1]) - self._reach
            nearest = [math.inf] * len(gap)
            for i, j, d in zip(first.tolist(), second.tolist(), apart.tolist(), strict=True):
                nearest[i], nearest[j] = _least(nearest[i], d), _least(nearest[j], d)
            gap = [_least(g, d) for g, d in zip(gap, nearest, strict=True)]
        return np.array(gap)

    def step(
        self, odom_pose: np.ndarray, truth_pose: np.ndarray | None = None, ranges: np.ndarray | None = None
    ) -> JudgeStep:
        """Judge the step that just ended.

        odom_pose, truth_pose: (n_robots, 3) x, y (m), yaw (rad); ranges: (n_robots, n_beams) m,
        used for collisions only when no truth pose is given.

        The terms are formed robot by robot in Python floats: each is the product, difference or choice it is on
        arrays, and the reward their sum in :data:`REWARD_TERMS`' order from 0, so the same numbers to the bit.
        """
        was_done = self.done
        active = (~was_done).tolist()
        n = len(active)
        pose = truth_pose if truth_pose is not None else odom_pose
        self.steps += 1
        if truth_pose is not None:
            gap = self.clearance(truth_pose).tolist()
        elif ranges is not None:
            gap = (np.asarray(ranges).min(axis=1) - self.radius_m).tolist()
        else:
            gap = [math.inf] * n
        hit = [g < self.margin_m for g in gap]
        arrived = self.in_goal(pose).tolist()
        new_collided = [a and h for a, h in zip(active, hit, strict=True)]
        new_reached = [a and g and not h for a, g, h in zip(active, arrived, hit, strict=True)]
        if self.capture_m is not None and any(new_reached):  # one robot's capture is the whole team's
            new_reached = [a and not h for a, h in zip(active, hit, strict=True)]
        dist = self.goal_distance(pose)
        w = self.weights
        heading_err = self.heading_error(pose) if w.heading_per_rad else np.zeros(n)
        prev_dist, prev_heading = self._prev_dist.tolist(), self._prev_heading_err.tolist()
        closeness = _closeness(np.array(gap), w.proximity_m).tolist() if w.proximity else None
        progress = [w.progress_per_m * (p - d) for p, d in zip(prev_dist, dist.tolist(), strict=True)]
        turned = [w.heading_per_rad * (p - e) for p, e in zip(prev_heading, heading_err.tolist(), strict=True)]
        terms = {
            "progress": [v if a else 0.0 for a, v in zip(active, progress, strict=True)],
            "heading": [v if a else 0.0 for a, v in zip(active, turned, strict=True)],
            "goal": [w.goal if r else 0.0 for r in new_reached],
            "team": [0.0] * n,
            "collision": [w.collision if c else 0.0 for c in new_collided],
            "step": [w.step if a else 0.0 for a in active],
            "proximity": [w.proximity * c if a else 0.0 for a, c in zip(active, closeness, strict=True)]
            if closeness is not None
            else [0.0] * n,
        }
        keep = np.array(active)
        self._prev_dist = np.where(keep, dist, self._prev_dist)
        self._prev_heading_err = np.where(keep, heading_err, self._prev_heading_err)
        self.reached |= np.array(new_reached)
        self.collided |= np.array(new_collided)
        events = [(i, "collision") for i, c in enumerate(new_collided) if c]
        events += [(i, "goal") for i, r in enumerate(new_reached) if r]
        if not self.team_success and self.reached.all():
            self.team_success = True
            terms["team"] = [w.team] * n
            events.append((-1, "success"))
        done = self.done
        truncated = bool(self.steps >= self.max_steps and not done.all())
        if truncated:
            events += [(int(i), "timeout") for i in np.flatnonzero(~done)]
        reward = [0.0] * n
        for name in REWARD_TERMS:
            reward = [r + t for r, t in zip(reward, terms[name], strict=True)]
        return JudgeStep(
            reward=np.array(reward),
            terms={name: np.array(values, dtype=np.float64) for name, values in terms.items()},
            reached=self.reached.copy(),
            collided=self.collided.copy(),
            done=done,
            active=keep,
            truncated=truncated,
            team_success=self.team_success,
            events=events,
        )


def _least(a: float, b: float) -> float:
    """np.minimum of two floats: NaN where either is NaN (Python's min keeps its first argument then)."""
    return a if a < b or a != a else b


def _closeness(gap: np.ndarray, within_m: float) -> np.ndarray:
    """1 at contact falling linearly to 0 at `within_m` of free space (0 where the gap is unknown)."""
    known = np.nan_to_num(np.asarray(gap, dtype=np.float64), nan=np.inf)
    return np.asarray(np.clip(1.0 - known / within_m, 0.0, 1.0))


@lru_cache(maxsize=16)
def goal_fields(scenario: Scenario, margin_m: float = 0.0) -> GoalFields:
    """The free-path distance fields of every robot's goal, paths keeping `margin_m` beyond each robot's
    radius where they can (cached: scenarios are immutable; the last few layouts, so that an episode's
    layout drawn and checked for reachability is not computed again)."""
    return GoalFields(
        [
            DistanceField(scenario, goal, radius_m=float(r), margin_m=margin_m)
            for goal, r in zip(scenario.goals, scenario.radii, strict=True)
        ]
    )
