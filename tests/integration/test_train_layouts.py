"""Training and evaluation on random layouts: each training episode in a layout of its own, the same seed
the same weights to the bit, and evaluation on layouts drawn from seeds training never used."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch as th

from pipeline.core.layouts import draw_layout
from pipeline.learn.checkpoint import load_checkpoint
from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.learn.worlds import TRAIN_SEED_MIN
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig, world_config
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.sim import evaluate
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim
from tests.integration.conftest import TINY_TRAIN

pytestmark = pytest.mark.integration

WORLD = {"scenario": "obstacles_random", "observation": "rich", "max_steps": 25}


def test_training_on_random_layouts_is_deterministic_and_evaluates_on_held_out_layouts(tmp_path):
    scenario, world = make_world(world=world_config(WORLD))
    cfg = from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), {**TINY_TRAIN, "total_steps": 240}), "<test>")
    a = train(scenario, world, cfg, tmp_path / "a", progress=False)
    b = train(scenario, world, cfg, tmp_path / "b", progress=False)
    for wa, wb in zip(load_checkpoint(a.checkpoint).weights, load_checkpoint(b.checkpoint).weights, strict=True):
        assert all(th.equal(wa[k], wb[k]) for k in wa)

    with (tmp_path / "a" / "curve.csv").open() as f:
        seeds = [int(row["seed"]) for row in csv.DictReader(f)]
    assert len(seeds) >= 8 and min(seeds) >= TRAIN_SEED_MIN
    layouts = {draw_layout(scenario, s).starts.tobytes() for s in seeds}
    assert len(layouts) == len(set(seeds))  # a layout per training episode

    export_policy(a.checkpoint, tmp_path / "policy", golden_observations(scenario, world, 8))
    runtime = PolicyRuntime(tmp_path / "policy")
    sim = MultiRobotSim(scenario, world)
    results = evaluate(sim, runtime.actions, 4, seed=10_000, progress=False)
    assert [r.seed for r in results] == [10_000, 10_001, 10_002, 10_003]
    assert np.array_equal(sim.episode_layout.goals, draw_layout(scenario, 10_003).goals)
