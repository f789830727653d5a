"""Random layouts: another arrangement of a scenario's starts, goals and boxes for every episode.

A scenario with ``layouts`` ranges (:class:`~pipeline.core.scenario.LayoutRanges`) draws each episode's
layout from them with a generator seeded by the episode's seed alone, so the simulator, the twin and a
deployment's judge that know the seed draw the same layout, bit for bit, without sending it. A draw is
kept when the layout is one the team can succeed in:

- boxes inside the room, `clearance_m` from its walls and from each other;
- each goal square inside the room, its centre a robot radius plus `clearance_m` from walls and boxes,
  goal squares apart as :meth:`Scenario.validate` requires;
- each start a robot radius plus `clearance_m` from walls, boxes, the other starts (two radii) and every
  goal square, and at least `min_goal_distance_m` (straight line) from its own goal;
- every goal reachable from its robot's start along free space (the free-path distance field is finite).

In a pursuit scenario (one with a ``target``) the goal ranges draw the target's start instead of goals: it
keeps the target's radius plus its `clearance_m` from walls and boxes, each robot's start keeps
`min_goal_distance_m` (and more than the capture distance) from it, and the target is reachable from every
start; boxes are not moved onto the robots' way there (`box_in_way_share` is for goals).

Otherwise it is drawn again; after `tries` draws the scenario is refused, naming the reason most draws
failed for.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter

import numpy as np

from pipeline.core.errors import ScenarioError
from pipeline.core.scenario import (
    Box,
    LayoutRanges,
    Point2D,
    Pose2D,
    RobotSpec,
    Scenario,
    Target,
    box_clearance,
    box_corners,
)

LAYOUT_STREAM = 0x1A70
"""Second word of the layout generator's seed, so layouts do not share draws with the noise of the same seed."""
EDGE_POINTS = 9
"""Points per box edge checked against another box (boxes that cross without a corner inside each other)."""


def draw_layout(scenario: Scenario, seed: int) -> Scenario:
    """The layout of the episode with this seed: `scenario` with starts, goals and boxes drawn from its
    ranges (the scenario itself when it has none). Raises ScenarioError when no draw is valid."""
    ranges = scenario.layouts
    if ranges is None:
        return scenario
    rng = np.random.default_rng([int(seed) % 2**63, LAYOUT_STREAM])
    reasons: Counter[str] = Counter()
    for _ in range(ranges.tries):
        layout, reason = _draw_once(scenario, ranges, rng)
        if layout is not None:
            return layout
        reasons[reason] += 1
    reason, count = reasons.most_common(1)[0]
    raise ScenarioError(
        scenario.name,
        f"no valid layout in {ranges.tries} draws from its layouts ranges; {count} of them failed because {reason} "
        "(widen the ranges, lower clearance_m or min_goal_distance_m, or raise tries)",
    )


def _uniform(rng: np.random.Generator, span: tuple[float, ...]) -> float:
    return float(rng.uniform(span[0], span[1]))


def _edge_points(box: Box) -> np.ndarray:
    corners = box_corners(box)
    t = np.linspace(0.0, 1.0, EDGE_POINTS)[:, None]
    return np.concatenate([corners[k] + t * (corners[(k + 1) % 4] - corners[k]) for k in range(4)])


def _box_gap(a: Box, b: Box) -> float:
    """Free distance between two boxes (0 when they touch or overlap)."""
    gap = min(float(box_clearance(a, _edge_points(b)).min()), float(box_clearance(b, _edge_points(a)).min()))
    centre_inside = (
        box_clearance(a, np.array([[b.x_m, b.y_m]]))[0] == 0 or box_clearance(b, np.array([[a.x_m, a.y_m]]))[0] == 0
    )
    return 0.0 if centre_inside else gap


def _wall_gap(scenario: Scenario, xy: np.ndarray) -> float:
    room = scenario.room
    return float(min(xy[0] - room.x_min_m, room.x_max_m - xy[0], xy[1] - room.y_min_m, room.y_max_m - xy[1]))


def _box_problem(scenario: Scenario, box: Box, others: list[Box], c: float) -> str:
    """Why `box` may not stand there among `others` ('' when it may)."""
    room = scenario.room
    corners = box_corners(box)
    if (
        corners[:, 0].min() < room.x_min_m + c
        or corners[:, 0].max() > room.x_max_m - c
        or corners[:, 1].min() < room.y_min_m + c
        or corners[:, 1].max() > room.y_max_m - c
    ):
        return "a box reached within clearance_m of a wall"
    if any(_box_gap(box, other) < c for other in others):
        return "two boxes came within clearance_m of each other"
    return ""


def _goal_problem(scenario: Scenario, g: np.ndarray, boxes: list[Box], r: float, c: float) -> str:
    room = scenario.room
    half = scenario.goal_size_m / 2
    if (
        g[0] - half < room.x_min_m
        or g[0] + half > room.x_max_m
        or g[1] - half < room.y_min_m
        or g[1] + half > room.y_max_m
    ):
        return "a goal square reached outside the room"
    if _wall_gap(scenario, g) < r + c or any(box_clearance(b, g[None])[0] < r + c for b in boxes):
        return "a goal centre came within a robot radius plus clearance_m of a wall or box"
    return ""


def _start_problem(
    scenario: Scenario,
    ranges: LayoutRanges,
    s: np.ndarray,
    goal: np.ndarray,
    starts: list[np.ndarray],
    goals: list[np.ndarray],
    boxes: list[Box],
    r: float,
) -> str:
    c = ranges.clearance_m
    half = scenario.goal_size_m / 2
    xy = s[:2]
    problem = _start_clear(scenario, xy, starts, boxes, r, c)
    if problem:
        return problem
    if any(abs(xy[0] - g[0]) < half + r + c and abs(xy[1] - g[1]) < half + r + c for g in goals):
        return "a start came within a robot radius plus clearance_m of a goal square"
    if math.hypot(*(xy - goal)) < ranges.min_goal_distance_m:
        return "a goal lay closer than min_goal_distance_m to its robot's start"
    return ""


def _start_clear(
    scenario: Scenario, xy: np.ndarray, starts: list[np.ndarray], boxes: list[Box], r: float, c: float
) -> str:
    """Why a robot may not start at `xy` among walls, `boxes` and the other `starts` ('' when it may)."""
    if _wall_gap(scenario, xy) < r + c or any(box_clearance(b, xy[None])[0] < r + c for b in boxes):
        return "a start came within a robot radius plus clearance_m of a wall or box"
    if any(math.hypot(*(xy - o[:2])) < 2 * r + c for o in starts):
        return "two starts came within two robot radii plus clearance_m"
    return ""


def _kept(layout: Scenario, unreachable: str) -> tuple[Scenario | None, str]:
    """`layout` when it is a valid scenario whose goals its robots can reach, else None and why not."""
    try:
        layout.validate()
    except ScenarioError as exc:
        return None, exc.problem
    if not _reachable(layout):
        return None, unreachable
    return layout, ""


def _draw_once(scenario: Scenario, ranges: LayoutRanges, rng: np.random.Generator) -> tuple[Scenario | None, str]:
    r = float(scenario.radii.max())  # every body kept as clear as the largest
    c = ranges.clearance_m
    boxes = list(scenario.obstacles)
    if ranges.move_boxes:
        boxes = []
        for box in scenario.obstacles:
            moved = dataclasses.replace(
                box,
                x_m=_uniform(rng, ranges.box_x_m),
                y_m=_uniform(rng, ranges.box_y_m),
                yaw_rad=_uniform(rng, ranges.box_yaw_rad),
            )
            problem = _box_problem(scenario, moved, boxes, c)
            if problem:
                return None, problem
            boxes.append(moved)
    if scenario.target is not None:
        return _draw_pursuit(scenario, scenario.target, ranges, rng, boxes)
    goals = []
    for _ in scenario.robots:
        g = np.array([_uniform(rng, ranges.goal_x_m), _uniform(rng, ranges.goal_y_m)])
        problem = _goal_problem(scenario, g, boxes, r, c)
        if problem:
            return None, problem
        goals.append(g)
    starts: list[np.ndarray] = []
    for i, _ in enumerate(scenario.robots):
        s = np.array(
            [_uniform(rng, ranges.start_x_m), _uniform(rng, ranges.start_y_m), _uniform(rng, ranges.start_yaw_rad)]
        )
        problem = _start_problem(scenario, ranges, s, goals[i], starts, goals, boxes, r)
        if problem:
            return None, problem
        starts.append(s)
    if ranges.move_boxes and ranges.box_in_way_share > 0:
        boxes, problem = _boxes_in_the_way(scenario, ranges, rng, boxes, starts, goals)
        if problem:
            return None, problem
    robots = tuple(
        RobotSpec(Pose2D(float(s[0]), float(s[1]), float(s[2])), Point2D(float(g[0]), float(g[1])))
        for s, g in zip(starts, goals, strict=True)
    )
    layout = dataclasses.replace(scenario, robots=robots, obstacles=tuple(boxes))
    return _kept(layout, "a goal could not be reached from its robot's start along free space")


def _draw_pursuit(
    scenario: Scenario, target: Target, ranges: LayoutRanges, rng: np.random.Generator, boxes: list[Box]
) -> tuple[Scenario | None, str]:
    """The rest of a pursuit's draw, after the boxes: the target's start, then the robots' starts."""
    r = float(scenario.radii.max())
    c = ranges.clearance_m
    keep = target.radius_m + target.clearance_m
    t = np.array([_uniform(rng, ranges.goal_x_m), _uniform(rng, ranges.goal_y_m)])
    if _wall_gap(scenario, t) < keep or any(box_clearance(b, t[None])[0] < keep for b in boxes):
        return None, "the target's start came within its radius plus its clearance_m of a wall or box"
    starts: list[np.ndarray] = []
    for _ in scenario.robots:
        s = np.array(
            [_uniform(rng, ranges.start_x_m), _uniform(rng, ranges.start_y_m), _uniform(rng, ranges.start_yaw_rad)]
        )
        xy = s[:2]
        problem = _start_clear(scenario, xy, starts, boxes, r, c)
        if problem:
            return None, problem
        gap = math.hypot(*(xy - t))
        if gap < ranges.min_goal_distance_m or gap <= target.capture_distance_m:
            return None, "a start lay closer than min_goal_distance_m (or the capture distance) to the target's start"
        starts.append(s)
    robots = tuple(
        dataclasses.replace(spec, start=Pose2D(float(s[0]), float(s[1]), float(s[2])))
        for spec, s in zip(scenario.robots, starts, strict=True)
    )
    moved = dataclasses.replace(target, start=Point2D(float(t[0]), float(t[1])))
    layout = dataclasses.replace(scenario, robots=robots, obstacles=tuple(boxes), target=moved)
    return _kept(layout, "the target could not be reached from a robot's start along free space")


def _boxes_in_the_way(
    scenario: Scenario,
    ranges: LayoutRanges,
    rng: np.random.Generator,
    boxes: list[Box],
    starts: list[np.ndarray],
    goals: list[np.ndarray],
) -> tuple[list[Box], str]:
    """Each box, with probability `box_in_way_share`, moved onto a robot's straight way: between 35 % and 65 %
    of the segment from its start to its goal, up to `box_in_way_offset_m` to either side (the draws are taken
    after the rest of the layout, so a share of 0 leaves every layout as it was)."""
    r = float(scenario.radii.max())
    c = ranges.clearance_m
    placed: list[Box] = []
    for box in boxes:
        if rng.uniform() >= ranges.box_in_way_share:
            placed.append(box)
            continue
        i = int(rng.integers(len(starts)))
        t = float(rng.uniform(0.35, 0.65))
        side = float(rng.uniform(-ranges.box_in_way_offset_m, ranges.box_in_way_offset_m))
        a, b = starts[i][:2], goals[i]
        along = (b - a) / max(float(np.hypot(*(b - a))), 1e-9)
        centre = a + t * (b - a) + side * np.array([-along[1], along[0]])
        placed.append(dataclasses.replace(box, x_m=float(centre[0]), y_m=float(centre[1])))
    for k, box in enumerate(placed):
        problem = _box_problem(scenario, box, placed[:k], c)
        if problem:
            return placed, problem
    for g in goals:
        problem = _goal_problem(scenario, g, placed, r, c)
        if problem:
            return placed, problem
    for i, s in enumerate(starts):
        problem = _start_problem(scenario, ranges, s, goals[i], starts[:i], goals, placed, r)
        if problem:
            return placed, problem
    return placed, ""


def _reachable(layout: Scenario) -> bool:
    from pipeline.core.judge import goal_fields  # the judge's fields, cached for the episode that uses them

    distances = goal_fields(layout).distance(layout.starts[:, :2])
    return bool(np.all(np.isfinite(distances)))
