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

Otherwise it is drawn again; after `tries` draws the scenario is refused, naming the reason most draws
failed for.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter

import numpy as np

from pipeline.core.errors import ScenarioError
from pipeline.core.scenario import Box, LayoutRanges, Point2D, Pose2D, RobotSpec, Scenario, box_clearance, box_corners

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


def _draw_once(scenario: Scenario, ranges: LayoutRanges, rng: np.random.Generator) -> tuple[Scenario | None, str]:
    room = scenario.room
    r = float(scenario.radii.max())  # every body kept as clear as the largest
    c = ranges.clearance_m
    half = scenario.goal_size_m / 2
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
            corners = box_corners(moved)
            if (
                corners[:, 0].min() < room.x_min_m + c
                or corners[:, 0].max() > room.x_max_m - c
                or corners[:, 1].min() < room.y_min_m + c
                or corners[:, 1].max() > room.y_max_m - c
            ):
                return None, "a box reached within clearance_m of a wall"
            if any(_box_gap(moved, other) < c for other in boxes):
                return None, "two boxes came within clearance_m of each other"
            boxes.append(moved)
    goals = []
    for _ in scenario.robots:
        g = np.array([_uniform(rng, ranges.goal_x_m), _uniform(rng, ranges.goal_y_m)])
        if (
            g[0] - half < room.x_min_m
            or g[0] + half > room.x_max_m
            or g[1] - half < room.y_min_m
            or g[1] + half > room.y_max_m
        ):
            return None, "a goal square reached outside the room"
        if _wall_gap(scenario, g) < r + c or any(box_clearance(b, g[None])[0] < r + c for b in boxes):
            return None, "a goal centre came within a robot radius plus clearance_m of a wall or box"
        goals.append(g)
    starts: list[np.ndarray] = []
    for i, _ in enumerate(scenario.robots):
        s = np.array(
            [_uniform(rng, ranges.start_x_m), _uniform(rng, ranges.start_y_m), _uniform(rng, ranges.start_yaw_rad)]
        )
        xy = s[:2]
        if _wall_gap(scenario, xy) < r + c or any(box_clearance(b, xy[None])[0] < r + c for b in boxes):
            return None, "a start came within a robot radius plus clearance_m of a wall or box"
        if any(math.hypot(*(xy - o[:2])) < 2 * r + c for o in starts):
            return None, "two starts came within two robot radii plus clearance_m"
        if any(abs(xy[0] - g[0]) < half + r + c and abs(xy[1] - g[1]) < half + r + c for g in goals):
            return None, "a start came within a robot radius plus clearance_m of a goal square"
        if math.hypot(*(xy - goals[i])) < ranges.min_goal_distance_m:
            return None, "a goal lay closer than min_goal_distance_m to its robot's start"
        starts.append(s)
    robots = tuple(
        RobotSpec(Pose2D(float(s[0]), float(s[1]), float(s[2])), Point2D(float(g[0]), float(g[1])))
        for s, g in zip(starts, goals, strict=True)
    )
    layout = dataclasses.replace(scenario, robots=robots, obstacles=tuple(boxes))
    try:
        layout.validate()
    except ScenarioError as exc:
        return None, exc.problem
    if not _reachable(layout):
        return None, "a goal could not be reached from its robot's start along free space"
    return layout, ""


def _reachable(layout: Scenario) -> bool:
    from pipeline.core.judge import goal_fields  # the judge's fields, cached for the episode that uses them

    distances = goal_fields(layout).distance(layout.starts[:, :2])
    return bool(np.all(np.isfinite(distances)))
