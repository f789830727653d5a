"""Mixed fleets: robots with bodies and speed limits of their own in one scenario, simulated, judged, decoded
and observed per robot."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.core.actions import ActionCodec
from pipeline.core.errors import ScenarioError
from pipeline.core.scenario import Pose2D, load_scenario
from pipeline.params import world_config
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim

WORLD = {"scenario": "mixed", "observation": "rich_limits", "actions": {"v_max_mps": 0.4, "w_max_radps": 0.2}}


def test_each_robot_keeps_its_own_body_and_limits():
    mixed = load_scenario("mixed")
    assert mixed.mixed and not load_scenario("obstacles").mixed
    np.testing.assert_array_equal(mixed.radii, [0.165, 0.165, 0.25])
    np.testing.assert_array_equal(mixed.speed_limits(0.4, 0.2), [[0.4, 0.2], [0.4, 0.2], [0.3, 0.4]])
    # two starts 0.4 m apart fit two SPARKs (0.33 m) but not a SPARK beside the larger base (0.415 m)
    moved = dataclasses.replace(
        mixed.robots[2], start=Pose2D(mixed.robots[1].start.x_m, mixed.robots[1].start.y_m + 0.4, 0.0)
    )
    with pytest.raises(ScenarioError, match=r"robot_2 and robot_3 start 0\.400 m apart, closer than their two radii"):
        dataclasses.replace(mixed, robots=(*mixed.robots[:2], moved)).validate()


def test_actions_scale_to_each_robots_own_limits():
    codec = ActionCodec("continuous", 0.4, 0.2, robot_limits=((0.4, 0.2), (0.3, 0.4)))
    cmd = codec.decode(np.array([[1.0, -1.0], [1.0, -1.0]]))
    np.testing.assert_allclose(cmd, [[0.4, -0.2], [0.3, -0.4]])
    np.testing.assert_allclose(codec.encode(cmd), [[1.0, -1.0], [1.0, -1.0]])
    discrete = ActionCodec("discrete", 0.4, 0.2, robot_limits=((0.4, 0.2), (0.12, 0.1)))
    np.testing.assert_allclose(discrete.decode(np.array([0, 1])), [[0.15, 0.0], [0.1, 0.1]])  # forward; left cut


def test_the_simulator_and_judge_use_each_robots_body_and_the_observation_carries_its_limits():
    scenario, world = make_world(world=world_config(WORLD))
    sim = MultiRobotSim(scenario, world)
    obs = sim.reset(2)
    model = sim.world.model
    assert model.geom("robot_3_body").size[0] == pytest.approx(0.25)
    assert model.geom("robot_1_body").size[0] == pytest.approx(0.165)
    limits = obs[:, sim.layout.slices["limits"]]
    np.testing.assert_allclose(limits, [[0.4, 0.2, 0.165], [0.4, 0.2, 0.165], [0.3, 0.4, 0.25]], atol=1e-6)
    # full actions drive each robot at its own limit
    sim.step(np.ones((3, 2), dtype=np.float32))
    np.testing.assert_allclose(sim.last_cmd, [[0.4, 0.2], [0.4, 0.2], [0.3, 0.4]])
    # the judge's clearance counts the larger body: 0.2 m from a wall is free for a SPARK, a hit for the base
    pose = scenario.starts.copy()
    pose[0, :2] = (0.2 + 0.0, 2.0)
    pose[2, :2] = (5.8, 2.0)
    clear = sim.judge.clearance(pose)
    assert clear[0] == pytest.approx(0.2 - 0.165) and clear[2] == pytest.approx(0.2 - 0.25)
