"""Free-path distance to the goals and the heading of that path, used by the progress and heading terms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.core.geodesic import DistanceField, GoalFields
from pipeline.core.judge import EpisodeJudge, RewardWeights
from pipeline.core.scenario import load_scenario


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
