from __future__ import annotations

import numpy as np
import pytest

from pipeline.core.judge import REWARD_TERMS, EpisodeJudge, RewardWeights
from pipeline.core.scenario import load_scenario

WEIGHTS = RewardWeights(progress_per_m=1.5, goal=1.0, team=10.0, collision=-1.0, step=-0.01)


@pytest.fixture
def judge() -> EpisodeJudge:
    j = EpisodeJudge(load_scenario("obstacles"), WEIGHTS, max_steps=350, collision_margin_m=0.02)
    j.reset(j.scenario.starts)
    return j


def test_goal_square_membership(judge):
    pose = judge.scenario.starts.copy()
    pose[0, :2] = (4.5 + 0.199, 0.5 - 0.199)
    pose[1, :2] = (1.0 + 0.201, 2.0)
    assert judge.in_goal(pose).tolist() == [True, False, False]


def test_progress_term_and_exact_sum(judge):
    pose = judge.scenario.starts.copy()
    before = judge.goal_distance(pose)
    pose[0, 0] += 0.1
    step = judge.step(pose, truth_pose=pose)
    after = judge.goal_distance(pose)
    np.testing.assert_allclose(step.terms["progress"], 1.5 * (before - after))
    assert set(step.terms) == set(REWARD_TERMS)
    for i in range(3):
        terms = step.robot_terms(i)
        assert sum(terms.values()) == float(step.reward[i])


def test_collisions_with_wall_box_and_robot(judge):
    pose = judge.scenario.starts.copy()
    pose[0, :2] = (2.5 - 0.15 - 0.165 + 0.01, 1.0)  # touching box 0
    pose[1, :2] = (5.9, 2.0)  # 0.1 m from the east wall: body through it
    step = judge.step(pose, truth_pose=pose)
    assert step.collided.tolist() == [True, True, False]
    assert step.terms["collision"].tolist() == [-1.0, -1.0, 0.0]
    assert step.done.tolist() == [True, True, False]
    assert (0, "collision") in step.events and (1, "collision") in step.events
    # robots that are done earn nothing more and do not collide again
    again = judge.step(pose, truth_pose=pose)
    assert again.reward[:2].tolist() == [0.0, 0.0]
    assert again.terms["collision"][:2].tolist() == [0.0, 0.0]


def test_robot_robot_collision():
    scenario = load_scenario("empty")
    j = EpisodeJudge(scenario, WEIGHTS, 350)
    pose = scenario.starts.copy()
    j.reset(pose)
    pose[0, :2] = (3.0, 2.0)
    pose[1, :2] = (3.0 + 0.32, 2.0)
    assert j.step(pose, truth_pose=pose).collided.tolist() == [True, True, False]


def test_lidar_fallback_without_ground_truth(judge):
    pose = judge.scenario.starts.copy()
    ranges = np.full((3, 15), 2.0)
    ranges[2, 7] = 0.17  # closer than radius + margin
    step = judge.step(pose, truth_pose=None, ranges=ranges)
    assert step.collided.tolist() == [False, False, True]


def test_team_bonus_when_all_reach_and_success(judge):
    pose = judge.scenario.starts.copy()
    pose[:, :2] = judge.scenario.goals
    step = judge.step(pose, truth_pose=pose)
    assert step.reached.all() and step.team_success
    assert step.terms["team"].tolist() == [10.0] * 3
    assert step.terms["goal"].tolist() == [1.0] * 3
    assert (-1, "success") in step.events
    assert not step.truncated


def test_timeout_truncates_at_max_steps():
    scenario = load_scenario("empty")
    j = EpisodeJudge(scenario, WEIGHTS, max_steps=3)
    pose = scenario.starts.copy()
    j.reset(pose)
    flags = [j.step(pose, truth_pose=pose).truncated for _ in range(3)]
    assert flags == [False, False, True]


def test_collision_beats_goal_in_the_same_step(judge):
    pose = judge.scenario.starts.copy()
    pose[0, :2] = judge.scenario.goals[0]  # inside its goal square ...
    pose[1, :2] = judge.scenario.goals[0] + (0.0, 0.32)  # ... with robot_2 touching it
    step = judge.step(pose, truth_pose=pose)
    assert judge.in_goal(pose)[0]
    assert step.collided[0] and not step.reached[0]


def test_proximity_term_grows_linearly_to_contact():
    weights = RewardWeights(proximity=-1.0, proximity_m=0.3)
    judge = EpisodeJudge(load_scenario("obstacles"), weights, max_steps=350, collision_margin_m=0.02)
    pose = judge.scenario.starts.copy()
    judge.reset(pose)
    radius = judge.scenario.robot.radius_m
    pose[0, :2] = (1.0, radius + 0.15)  # robot_1 0.15 m from the bottom wall: half way in
    pose[1, :2] = (4.0, 2.0)  # robot_2 in the open (the nearest box is 0.85 m off)
    pose[2, :2] = (1.0, 4.0 - radius - 0.3)  # robot_3 just at the edge
    step = judge.step(pose, truth_pose=pose)
    np.testing.assert_allclose(step.terms["proximity"], [-0.5, 0.0, 0.0], atol=1e-9)
    assert not step.collided.any()
    # without ground truth the gap comes from the closest lidar return, as for collisions
    lidar = EpisodeJudge(load_scenario("obstacles"), weights, max_steps=350, collision_margin_m=0.02)
    lidar.reset(judge.scenario.starts)
    ranges = np.full((3, 15), 4.0)
    ranges[1, 3] = radius + 0.06
    step = lidar.step(judge.scenario.starts, ranges=ranges)
    np.testing.assert_allclose(step.terms["proximity"], [0.0, -0.8, 0.0], atol=1e-9)
    # a robot whose scan has no valid return is not penalized (nor is its reward nan)
    blank = EpisodeJudge(load_scenario("obstacles"), weights, max_steps=350, collision_margin_m=0.02)
    blank.reset(judge.scenario.starts)
    unknown = np.full((3, 15), 4.0)
    unknown[0] = np.nan
    quiet = blank.step(judge.scenario.starts, ranges=unknown)
    assert np.isfinite(quiet.reward).all() and quiet.terms["proximity"][0] == 0.0
    # off by default; the terms still sum to the reward
    assert RewardWeights().proximity == 0.0
    assert float(step.reward[1]) == pytest.approx(sum(step.robot_terms(1).values()))


@pytest.mark.parametrize("name", ["obstacles", "ten"])
def test_the_clearance_to_every_box_at_once_is_each_box_s_distance_bit_for_bit(name):
    """The judge takes the clearance to all boxes in one pass; it equals the walls', each box's (box_clearance) and
    the other robots' distances taken one at a time, to the last bit, at 2000 random poses in and around the room."""
    from pipeline.core.scenario import box_clearance

    scenario = load_scenario(name)
    judge = EpisodeJudge(scenario, RewardWeights(), max_steps=10)
    rng = np.random.default_rng(0)
    room, radius = scenario.room, judge.radius_m
    for _ in range(2000):
        n = scenario.n_robots
        xy = np.column_stack(
            [
                rng.uniform(room.x_min_m - 0.5, room.x_max_m + 0.5, n),
                rng.uniform(room.y_min_m - 0.5, room.y_max_m + 0.5, n),
            ]
        )
        gap = np.minimum.reduce([xy[:, 0] - room.x_min_m, room.x_max_m - xy[:, 0], xy[:, 1] - room.y_min_m,
                                 room.y_max_m - xy[:, 1]]) - radius  # fmt: skip
        for box in scenario.obstacles:
            gap = np.minimum(gap, box_clearance(box, xy) - radius)
        dist = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) - (radius[:, None] + radius[None, :])
        np.fill_diagonal(dist, np.inf)
        gap = np.minimum(gap, dist.min(axis=1))
        pose = np.column_stack([xy, rng.uniform(-3, 3, n)])
        assert np.array_equal(judge.clearance(pose), gap)
