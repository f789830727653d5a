"""Free-path distance to the goals and the heading of that path, used by the progress and heading terms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.core.geodesic import DistanceField, GoalFields
from pipeline.core.judge import EpisodeJudge, RewardWeights
from pipeline.core.scenario import box_clearance, load_scenario
from pipeline.mappings import to_mapping


@pytest.fixture(scope="module")
def obstacles():
    return load_scenario("obstacles")


def test_open_space_distance_is_nearly_straight(obstacles):
    field = DistanceField(obstacles, obstacles.goals[1])  # robot_2: nothing between its start and goal
    pts = np.array([[4.0, 2.0], [3.0, 2.5], [2.0, 1.8], [1.5, 2.0]])
    straight = np.hypot(*(pts - obstacles.goals[1]).T)
    # a 16-connected grid: within 3 % of the straight line at any angle
    np.testing.assert_allclose(field(pts), straight, rtol=0.03)


def test_boxes_make_the_path_longer_than_the_straight_line(obstacles):
    field = DistanceField(obstacles, obstacles.goals[0])  # robot_1: a box on the straight line
    behind = np.array([[1.9, 1.0]])
    straight = float(np.hypot(*(behind[0] - obstacles.goals[0])))
    assert field(behind)[0] > straight + 0.1
    # below the box is shorter than above it for a goal at y = 0.5
    assert field(np.array([[2.5, 0.5]]))[0] < field(np.array([[2.5, 1.5]]))[0]


def test_path_direction_points_at_the_goal_in_open_space_and_around_boxes(obstacles):
    field = DistanceField(obstacles, obstacles.goals[1])
    heading = field.direction(np.array([[4.0, 2.0]]))[0]
    assert abs(np.angle(np.exp(1j * (heading - math.pi)))) < 0.05  # due west
    behind_box = DistanceField(obstacles, obstacles.goals[0]).direction(np.array([[2.0, 1.0]]))[0]
    assert -math.pi / 2 < behind_box < -0.2  # away from the straight line, down and around the box


def testgoal_fields_equal_each_robots_own_field(obstacles):
    fields = [DistanceField(obstacles, g) for g in obstacles.goals]
    joint = GoalFields(fields)
    rng = np.random.default_rng(0)
    pts = rng.uniform([0.2, 0.2], [5.8, 3.8], size=(3, 2))
    np.testing.assert_array_equal(joint.distance(pts), [f(pts[i : i + 1])[0] for i, f in enumerate(fields)])
    np.testing.assert_array_equal(joint.direction(pts), [f.direction(pts[i : i + 1])[0] for i, f in enumerate(fields)])


def test_the_judges_per_robot_reading_is_the_vectorised_one_to_the_bit(obstacles):
    """The fields read robot by robot in Python floats (the judge's step) give the vectorised reading's numbers
    exactly: inside the room, on the grid's lines, outside it (clamped), inside the boxes."""
    joint = GoalFields([DistanceField(obstacles, g) for g in obstacles.goals])
    rng = np.random.default_rng(5)
    pts = rng.uniform(-1.0, 7.0, size=(3000, 3, 2))
    pts[::5] = np.round(pts[::5] / joint.resolution_m) * joint.resolution_m  # on the grid's lines
    pts[1::5] = rng.uniform([0.2, 0.2], [5.8, 3.8], size=(len(pts[1::5]), 3, 2))
    for p in pts:
        np.testing.assert_array_equal(joint.distance(p), joint.distance_arrays(p))
        np.testing.assert_array_equal(joint.direction(p), joint.direction_arrays(p))
    assert len({joint.distance(p)[0] for p in pts}) > 2000  # the points meet many different cells


def test_heading_term_rewards_turning_toward_the_path(obstacles):
    judge = EpisodeJudge(obstacles, RewardWeights(progress_per_m=0.0, heading_per_rad=2.0), 350, 0.02, "geodesic")
    pose = obstacles.starts.copy()
    judge.reset(pose)
    before = judge.heading_error(pose)
    turned = pose.copy()
    turned[:, 2] = judge.path_direction(pose)  # face the path exactly
    step = judge.step(turned, turned)
    np.testing.assert_allclose(step.terms["heading"], 2.0 * before, atol=1e-9)
    assert sum(step.robot_terms(0).values()) == float(step.reward[0])


def _min_clearance_along_path(scenario, field, start, radius, steps=300, step_m=0.02):
    """Follow the field's path direction from `start`; the smallest gap (m) between the body and a box."""
    p, gap = np.array(start, dtype=float), np.inf
    for _ in range(steps):
        heading = field.direction(p[None])[0]
        p = p + step_m * np.array([math.cos(heading), math.sin(heading)])
        gap = min(gap, min(float(box_clearance(b, p[None])[0]) for b in scenario.obstacles) - radius)
        if field(p[None])[0] < 0.1:
            break
    return gap, field(p[None])[0]


def test_path_clearance_keeps_the_path_off_the_box(obstacles):
    # robot_1's path runs past the box at (2.5, 1.0): the plain map's path grazes it, the inflated one keeps clear
    radius = obstacles.robot.radius_m
    plain = DistanceField(obstacles, obstacles.goals[0])
    kept = DistanceField(obstacles, obstacles.goals[0], margin_m=0.15)
    gap_plain, end_plain = _min_clearance_along_path(obstacles, plain, (1.9, 1.0), radius)
    gap_kept, end_kept = _min_clearance_along_path(obstacles, kept, (1.9, 1.0), radius)
    assert end_plain < 0.1 and end_kept < 0.1  # both paths arrive
    assert gap_plain < 0.05
    assert gap_kept > gap_plain + 0.05
    # in open space the inflated map's distances stay the plain ones
    far = np.array([[4.0, 0.5], [4.3, 0.5]])
    np.testing.assert_allclose(kept(far), plain(far), atol=1e-9)


def _wall_with_gap(gap_m):
    """The empty 6 x 4 m room with one robot, cut by a box from the top wall down to `gap_m` above the bottom."""
    height = 4.0 - gap_m
    data = to_mapping(load_scenario("empty"))
    data["robots"] = [{"start": {"x_m": 1.0, "y_m": 2.0, "yaw_rad": 0.0}, "goal": {"x_m": 5.0, "y_m": 2.0}}]
    box = {"kind": "box", "x_m": 3.0, "y_m": gap_m + height / 2, "size_x_m": 0.3, "size_y_m": height}
    data["obstacles"] = [{**box, "height_m": 0.4, "yaw_rad": 0.0}]
    return load_scenario(data)


def test_path_clearance_falls_back_where_the_inflated_map_cuts_the_goal_off():
    # a 0.5 m gap: the robot (0.33 m across) passes, a path 0.15 m clear of both sides (0.63 m) does not
    narrow = _wall_with_gap(0.5)
    plain = DistanceField(narrow, narrow.goals[0])
    kept = DistanceField(narrow, narrow.goals[0], margin_m=0.15)
    start = narrow.starts[:, :2]
    assert np.isfinite(kept(start)).all()
    np.testing.assert_array_equal(kept.values, plain.values)
    # a 1.2 m gap leaves room for the margin: the inflated map is used, and its path is no shorter
    wide = _wall_with_gap(1.2)
    plain_w = DistanceField(wide, wide.goals[0])
    kept_w = DistanceField(wide, wide.goals[0], margin_m=0.15)
    assert not np.array_equal(kept_w.values, plain_w.values)
    assert kept_w(wide.starts[:, :2])[0] >= plain_w(wide.starts[:, :2])[0] - 1e-9


def test_judge_follows_the_inflated_path_when_asked(obstacles):
    plain = EpisodeJudge(obstacles, RewardWeights(), 350, 0.02, "geodesic")
    kept = EpisodeJudge(obstacles, RewardWeights(path_clearance_m=0.15), 350, 0.02, "geodesic")
    near_box = np.array([[2.1, 0.75, 0.0], [4.0, 2.0, math.pi], [1.0, 3.0, 0.0]])
    expected = DistanceField(obstacles, obstacles.goals[0], margin_m=0.15).direction(near_box[:1, :2])[0]
    assert kept.path_direction(near_box)[0] == pytest.approx(expected)
    assert kept.path_direction(near_box)[0] != pytest.approx(plain.path_direction(near_box)[0], abs=1e-3)
