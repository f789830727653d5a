"""Replay of recorded sessions: action agreement of a policy on recorded observations, and open-loop
divergence of recorded commands in the simulator, on real recordings of a tiny policy."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.analysis.errors import ReplayError
from pipeline.analysis.replay import action_agreement, open_loop_divergence
from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import EvalSimConfig, TrainConfig, world_config
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.record.session import SessionLog, session_metadata
from pipeline.rollout.sim import evaluate_policy
from pipeline.sim import make_world
from tests.integration.conftest import TINY_TRAIN, TINY_WORLD

pytestmark = pytest.mark.integration

WORLD = {**TINY_WORLD, "max_steps": 60}


@pytest.fixture(scope="module")
def long_policy(tiny_policy: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny policy with 60-step episodes (its spec's world.max_steps edited), for longer recordings."""
    folder = tmp_path_factory.mktemp("long") / "policy"
    shutil.copytree(tiny_policy, folder)
    spec = json.loads((folder / "policy.json").read_text())
    spec["world"]["max_steps"] = WORLD["max_steps"]
    (folder / "policy.json").write_text(json.dumps(spec))
    return folder


@pytest.fixture(scope="module")
def recording(long_policy: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three episodes of the tiny policy in the simulated obstacles room, recorded."""
    scenario, world = make_world(world=world_config(WORLD))
    cfg = EvalSimConfig(episodes=3, seed=77, record=True)
    path = tmp_path_factory.mktemp("replay") / "session.mcap"
    evaluate_policy(scenario, world, PolicyRuntime(long_policy), cfg, path, progress=False)
    return path


def test_the_recording_policy_agrees_with_itself(tiny_policy, recording):
    result = action_agreement(recording, PolicyRuntime(tiny_policy))
    steps = sum(1 for _ in McapLog(recording).messages(["/mrl/action"])) // 3
    assert result.steps == steps > 0
    assert result.agreement == 1.0 and result.max_abs_diff <= 1e-5


def test_another_policy_disagrees(recording, tmp_path):
    scenario, world = make_world(world=world_config(WORLD))
    cfg = from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), {**TINY_TRAIN, "seed": 9}), "<test>")
    result = train(scenario, world, cfg, tmp_path / "run", progress=False)
    export_policy(result.checkpoint, tmp_path / "policy", golden_observations(scenario, world, 8))
    other = action_agreement(recording, PolicyRuntime(tmp_path / "policy"))
    assert other.agreement < 0.5 and other.max_abs_diff > 0.01


def test_open_loop_replay_in_the_recording_world_stays_on_the_recorded_path(recording):
    scenario, world = make_world(world=world_config(WORLD))
    same = open_loop_divergence(recording, scenario, world, horizon_s=4.0)
    assert same.episodes == 3
    assert np.all(np.isfinite(same.mean_error_m)) and same.times_s[-1] <= 4.0
    # weaker motors in the replay world: the robots fall behind their recorded paths
    weak_world = world_config({**WORLD, "actuation": {"linear_gain": 0.5, "angular_gain": 0.5}})
    weak = open_loop_divergence(recording, scenario, weak_world, horizon_s=4.0)
    # same world: the same physics, so only the sampling between recorded poses shows (mm)
    assert same.mean_error_m.max() < 0.005
    assert weak.mean_error_m.max() > 0.02 and weak.at(4.0) > 100 * same.at(4.0)


def test_recordings_that_cannot_be_replayed_are_named(tiny_policy, recording, tmp_path):
    empty_scenario, empty_world = make_world(world=world_config({**WORLD, "scenario": "empty"}))
    with pytest.raises(ReplayError, match=r"recorded in scenario 'obstacles', but the replay world is for 'empty'"):
        open_loop_divergence(recording, empty_scenario, empty_world)
    bare = tmp_path / "bare.mcap"
    robots = ("robot_1", "robot_2", "robot_3")
    with SessionLog(bare, robots, session_metadata("real", "obstacles", robots, 0.1)) as log:
        log.ground_truth(0, "robot_1", np.zeros(3))
    with pytest.raises(ReplayError, match=r"bare\.mcap: no /mrl/observation topic"):
        action_agreement(bare, PolicyRuntime(tiny_policy))
    scenario, world = make_world(world=world_config(WORLD))
    with pytest.raises(ReplayError, match=r"bare\.mcap: no /robot_1/cmd_vel topic"):
        open_loop_divergence(bare, scenario, world)
