"""Real learning (minutes): the default PPO configuration learns the reference task."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.core.episode import summarize
from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig, load_params, world_config
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.sim import evaluate
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


def test_default_ppo_learns_the_empty_room(tmp_path):
    params = load_params(ROOT / "params.yaml")
    scenario, world = make_world(world=world_config({"scenario": "empty"}, base=params.world))
    cfg = from_mapping(TrainConfig, merge(to_mapping(params.train), {"total_steps": 150_000}), "<slow test>")
    result = train(scenario, world, cfg, tmp_path / "run", progress=False)
    export_policy(result.checkpoint, tmp_path / "policy", golden_observations(scenario, world, 16))
    runtime = PolicyRuntime(tmp_path / "policy")
    metrics = summarize(evaluate(MultiRobotSim(scenario, world), runtime.actions, 50, 10_000, progress=False))
    assert metrics["eval/robot_success"] >= 0.8, metrics
