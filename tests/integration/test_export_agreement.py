"""Export checks what reaches a robot: the commands after decoding agree within a share of the limits, so float32
round-off of a correct graph never fails, for many draws of weights of every policy kind; a graph with a layer
or an order wrong still fails."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch as th

from pipeline.learn import export as export_module
from pipeline.learn.checkpoint import load_checkpoint, save_checkpoint
from pipeline.learn.export import COMMAND_TOLERANCE, export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig, world_config
from pipeline.policy.errors import PolicyError
from pipeline.policy.networks import ActionNetwork, Dense
from pipeline.sim import make_world

pytestmark = pytest.mark.integration

CASES = {
    "sac_actor": ({"algorithm": "sac", "mode": "independent"}, "continuous"),
    "ppo_actor": ({"algorithm": "ppo", "mode": "shared"}, "continuous"),
    "ppo_actor_centralized": ({"algorithm": "ppo", "mode": "centralized"}, "continuous"),
    "dqn_dueling": ({"algorithm": "dqn", "mode": "shared"}, "discrete"),
    "dqn": ({"algorithm": "dqn", "mode": "shared", "dqn": {"dueling": False}}, "discrete"),
}
TINY = {
    "total_steps": 120,
    "n_envs": 2,
    "net_arch": [32, 32],
    "batch_size": 16,
    "buffer_size": 1000,
    "learning_starts": 40,
    "checkpoint_every_episodes": 5,
    "ppo": {"n_steps": 32, "minibatch_size": 32, "n_epochs": 1},
}


@pytest.fixture(scope="module", params=sorted(CASES))
def trained(request, tmp_path_factory):
    """A checkpoint of the case's policy kind, its world and golden observations."""
    settings, kind = CASES[request.param]
    root = tmp_path_factory.mktemp(request.param)
    scenario, world = make_world(
        world=world_config({"scenario": "obstacles", "observation": "rich", "max_steps": 30, "actions": {"kind": kind}})
    )
    cfg = from_mapping(TrainConfig, merge(merge(to_mapping(TrainConfig()), TINY), settings), "<test>")
    result = train(scenario, world, cfg, root / "run", progress=False)
    return result.checkpoint, golden_observations(scenario, world, 16), root


def redrawn(checkpoint: Path, folder: Path, seed: int) -> Path:
    """The checkpoint with its weights drawn anew (large: raw outputs of several units, where float32 rounds)."""
    ckpt = load_checkpoint(checkpoint)
    rng = np.random.default_rng(seed)
    weights = [
        {
            k: th.from_numpy((rng.normal(0.0, 1.5, tuple(v.shape)) * (1 + v.abs().mean().item())).astype(np.float32))
            if v.dtype.is_floating_point
            else v
            for k, v in w.items()
        }
        for w in ckpt.weights
    ]
    save_checkpoint(folder, ckpt.record, weights)
    return folder


def test_many_draws_of_weights_export_without_a_false_alarm(trained):
    checkpoint, golden, root = trained
    worst = 0.0
    for seed in range(8):
        result = export_policy(redrawn(checkpoint, root / f"w{seed}", seed), root / f"p{seed}", golden)
        worst = max(worst, result.max_abs_diff)
    assert worst <= COMMAND_TOLERANCE


def _swapped_outputs(net: ActionNetwork) -> ActionNetwork:
    return dataclasses.replace(net, out=Dense(net.out.weight[::-1].copy(), net.out.bias[::-1].copy()))


def _permuted_hidden(net: ActionNetwork) -> ActionNetwork:
    first = net.hidden[0]
    wrong = Dense(first.weight[::-1].copy(), first.bias[::-1].copy())  # its units, not the next layer's inputs
    return dataclasses.replace(net, hidden=(wrong, *net.hidden[1:]))


@pytest.mark.parametrize("plant", [_swapped_outputs, _permuted_hidden])
def test_a_graph_with_a_layer_or_an_order_wrong_is_refused(trained, monkeypatch, plant):
    checkpoint, golden, root = trained
    real_graph = export_module.policy_graph

    def planted(networks, *args, **kwargs):
        return real_graph([plant(n) for n in networks], *args, **kwargs)

    monkeypatch.setattr(export_module, "policy_graph", planted)
    with pytest.raises(PolicyError, match=r"differ|different"):
        export_policy(checkpoint, root / f"planted_{plant.__name__}", golden)
    assert not (root / f"planted_{plant.__name__}").exists()  # nothing written
