"""world.observed_pose: observations built from wheel odometry (the paper's) or from ground truth (a localized
robot); part of the policy's MDP, so a world that differs is told apart."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.errors import ConfigError
from pipeline.mdp import MdpDefinition
from pipeline.params import world_config
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim

DRIFTY = {"scenario": "empty", "observation": "rich", "odometry": {"drift_per_m": 0.2}}


def _drive(observed_pose: str) -> tuple[np.ndarray, MultiRobotSim]:
    scenario, world = make_world(world=world_config({**DRIFTY, "observed_pose": observed_pose}))
    sim = MultiRobotSim(scenario, world)
    obs = sim.reset(3)
    for _ in range(30):  # forward and turning: odometry drifts away from the truth
        obs = sim.step(np.tile([0.8, 0.6], (scenario.n_robots, 1))).obs
    return obs, sim


@pytest.mark.parametrize("observed_pose", ["odometry", "ground_truth"])
def test_the_observation_takes_its_pose_from_the_chosen_source(observed_pose):
    obs, sim = _drive(observed_pose)
    position = sim.layout.slices["position"]
    heading = sim.layout.slices["heading"]
    truth, odom = sim.world.truth, sim.world.odometry.pose
    assert np.abs(truth[:, :2] - odom[:, :2]).max() > 0.01  # the two sources differ by now
    source = truth if observed_pose == "ground_truth" else odom
    np.testing.assert_allclose(obs[:, position], source[:, :2], atol=1e-5)
    np.testing.assert_allclose(
        obs[:, heading], np.column_stack([np.cos(source[:, 2]), np.sin(source[:, 2])]), atol=1e-5
    )
    # the goal vector is seen from the same pose
    goal = sim.layout.slices["goal_in_robot"]
    d = sim.judge.goals - source[:, :2]
    forward = np.cos(source[:, 2]) * d[:, 0] + np.sin(source[:, 2]) * d[:, 1]
    np.testing.assert_allclose(obs[:, goal][:, 0], forward, atol=1e-4)


def test_the_pose_source_is_part_of_the_mdp_and_checked():
    odometry = MdpDefinition.of(world_config(DRIFTY))
    truth = MdpDefinition.of(world_config({**DRIFTY, "observed_pose": "ground_truth"}))
    assert odometry.observed_pose == "odometry"  # the default: the paper's wheel odometry
    assert odometry.differences(truth, reward=False) == ["world.observed_pose 'odometry' vs 'ground_truth'"]
    with pytest.raises(ConfigError) as err:
        world_config({**DRIFTY, "observed_pose": "mocap"})
    assert "observed_pose = 'mocap'" in str(err.value) and "ground_truth" in str(err.value)
