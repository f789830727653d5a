"""The pursuit task: a scripted evader that flees within the room, a judge that counts one robot's capture as
the team's, and the simulator's target body that lidars see and observations point at."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pipeline.core.errors import ScenarioError
from pipeline.core.evader import Evader
from pipeline.core.judge import EpisodeJudge, RewardWeights
from pipeline.core.scenario import box_clearance, load_scenario
from pipeline.params import world_config
from pipeline.policy.scripted import GoToGoalController
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim


@pytest.fixture(scope="module")
def pursuit():
    return load_scenario("pursuit")


def test_the_evader_flees_the_nearest_pursuer_and_stands_still_when_none_is_near(pursuit):
    evader = Evader(pursuit)
    start = evader.xy.copy()
    far = np.array([[0.5, 0.5], [0.5, 3.5], [0.6, 2.0]])  # all beyond flee_distance_m
    assert np.array_equal(evader.step(0.1, far), start)
    chaser = np.array([[start[0] - 1.0, start[1]], [0.5, 0.5], [0.5, 3.5]])
    after = evader.step(0.1, chaser)
    assert after[0] > start[0]  # away from the pursuer on its west
    assert np.hypot(*(after - start)) == pytest.approx(pursuit.target.speed_mps * 0.1, rel=1e-9)


def test_the_evader_stays_in_the_room_and_out_of_the_boxes_whatever_the_pursuers_do(pursuit):
    rng = np.random.default_rng(0)
    t, room = pursuit.target, pursuit.room
    keep = t.radius_m + t.clearance_m
    for _ in range(5):
        evader = Evader(pursuit)
        pursuers = rng.uniform([0.2, 0.2], [5.8, 3.8], size=(3, 2))
        for _ in range(400):
            # pursuers close in on it from wherever they are, with some wandering
            pursuers += 0.04 * (evader.xy - pursuers) / np.hypot(*(evader.xy - pursuers).T)[:, None]
            pursuers += rng.normal(0.0, 0.02, pursuers.shape)
            xy = evader.step(0.1, pursuers)
            assert room.x_min_m + keep - 1e-9 <= xy[0] <= room.x_max_m - keep + 1e-9
            assert room.y_min_m + keep - 1e-9 <= xy[1] <= room.y_max_m - keep + 1e-9
            assert all(box_clearance(box, xy[None])[0] >= keep - 1e-9 for box in pursuit.obstacles)


def test_one_robots_capture_is_the_teams(pursuit):
    judge = EpisodeJudge(pursuit, RewardWeights(), max_steps=100)
    pose = pursuit.starts.copy()
    judge.reset(pose)
    target = np.array([3.0, 2.0])
    judge.track(target)
    pose[1, :2] = target + np.array([pursuit.target.capture_distance_m + 0.01, 0.0])  # just outside
    step = judge.step(pose, pose)
    assert not step.reached.any() and not step.team_success
    pose[1, :2] = target + np.array([pursuit.target.capture_distance_m - 0.01, 0.0])
    step = judge.step(pose, pose)
    assert step.reached.all() and step.team_success and step.done.all()
    assert step.terms["team"].sum() == pytest.approx(3 * RewardWeights().team)


def test_the_simulator_moves_the_target_and_observations_point_at_it():
    scenario, world = make_world(world=world_config({"scenario": "pursuit", "observation": "rich", "max_steps": 350}))
    sim = MultiRobotSim(scenario, world)
    obs = sim.reset(3)
    target0 = sim.world.target_xy
    np.testing.assert_allclose(target0, (scenario.target.start.x_m, scenario.target.start.y_m))
    controller = GoToGoalController(world.layout(), world.codec())
    moved = False
    for _ in range(world.max_steps):
        step = sim.step(world.codec().encode(controller.commands(obs)))
        obs = step.obs
        target = sim.world.target_xy
        moved |= not np.allclose(target, target0)
        gid = sim.world.model.geom("target").id
        np.testing.assert_allclose(sim.world.data.geom_xpos[gid, :2], target, atol=1e-12)
        pose = sim.world.odometry.pose
        d = target - pose[:, :2]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        expected = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)
        np.testing.assert_allclose(obs[:, 4:6], expected, atol=1e-4)
        if step.judge.done.all() or step.judge.truncated:
            break
    assert moved and step.judge.team_success  # the scripted chase catches the default evader here
    truth = sim.world.truth[:, :2]
    assert np.hypot(*(truth - target).T).min() <= scenario.target.capture_distance_m + 0.05


def test_the_lidar_sees_the_target():
    scenario, world = make_world(world=world_config({"scenario": "pursuit", "observation": "rich"}))
    sim = MultiRobotSim(scenario, world)
    sim.reset(1)
    target = sim.world.target_xy
    pose = sim.world.truth.copy()
    pose[0] = (target[0] - 1.0, target[1], 0.0)  # robot_1 one metre west of the target, facing it
    sim.world.reset(1, pose)
    sim.world.evader.xy = target  # (reset put it back at its start, which is where it is)
    scan = sim.world.scan()
    assert scan[0, 0] == pytest.approx(1.0 - scenario.target.radius_m, abs=0.05)


def test_a_pursuit_scenario_is_checked(pursuit, tmp_path):
    too_close = dataclasses.replace(
        pursuit, target=dataclasses.replace(pursuit.target, start=dataclasses.replace(pursuit.target.start, x_m=1.4))
    )
    with pytest.raises(ScenarioError, match=r"robot_2 starts 0\.40 m from the target: caught before it moves"):
        too_close.validate()
    no_target = dataclasses.replace(pursuit, target=None)
    with pytest.raises(ScenarioError, match="robot_1, robot_2, robot_3 has no goal"):
        no_target.validate()
    assert math.isclose(float(pursuit.goals[2, 0]), pursuit.target.start.x_m)
