"""Training worlds stepped by worker processes: the same transitions, to the bit, as in the trainer's process."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
import torch as th

from pipeline.learn.checkpoint import load_checkpoint
from pipeline.learn.common.worlds import VecWorlds
from pipeline.learn.errors import WorldWorkerError
from pipeline.learn.trainer import train
from pipeline.params import world_config
from pipeline.sim import make_world

from .test_train_export import tiny_config, world_for

pytestmark = pytest.mark.integration


def _rollout(workers: int, steps: int) -> list:
    scenario, world = make_world(world=world_config({"scenario": "obstacles", "max_steps": 12}))
    rng = np.random.default_rng(4)
    out = []
    with VecWorlds(scenario, world, 5, seed=11, start_xy_m=0.3, start_yaw_rad=0.6, workers=workers) as worlds:
        out.append(worlds.reset())
        for _ in range(steps):
            out.append(worlds.step(rng.uniform(-1, 1, size=(5, scenario.n_robots, 2)).astype(np.float32)))
    return out


def test_worker_processes_give_the_same_transitions_to_the_bit() -> None:
    one, three = _rollout(1, 40), _rollout(3, 40)
    assert np.array_equal(one[0], three[0])
    ended = 0
    for a, b in zip(one[1:], three[1:], strict=True):
        for f in fields(a):
            x, y = getattr(a, f.name), getattr(b, f.name)
            if f.name == "finished":
                assert [(r.world, r.seed, r.steps) for r in x] == [(r.world, r.seed, r.steps) for r in y]
                for r, s in zip(x, y, strict=True):
                    assert r.returns.tobytes() == s.returns.tobytes()
                    assert np.array_equal(r.success, s.success) and r.team_success == s.team_success
                ended += len(x)
            else:
                assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), f.name
    assert ended >= 10  # episodes of 12 steps: every world restarted several times within the 40 steps


def test_training_with_world_workers_learns_the_same_weights(tmp_path: Path) -> None:
    scenario, world = world_for("ppo")
    a = train(scenario, world, tiny_config(algorithm="ppo", mode="shared"), tmp_path / "a", progress=False)
    b = train(
        scenario, world, tiny_config(algorithm="ppo", mode="shared", world_workers=2), tmp_path / "b", progress=False
    )
    assert (tmp_path / "a" / "curve.csv").read_bytes() == (tmp_path / "b" / "curve.csv").read_bytes()
    wa, wb = load_checkpoint(a.checkpoint).weights, load_checkpoint(b.checkpoint).weights
    assert len(wa) == len(wb) == 1
    assert wa[0].keys() == wb[0].keys()
    assert all(th.equal(wa[0][k], wb[0][k]) for k in wa[0])


def test_a_failing_worker_reports_its_traceback() -> None:
    scenario, world = make_world(world=world_config({"scenario": "empty"}))
    with VecWorlds(scenario, world, 2, seed=0, workers=2) as worlds:
        worlds.reset()
        with pytest.raises(WorldWorkerError, match=r"training world worker \(pid \d+\) failed: Traceback"):
            worlds.step(np.zeros((2, scenario.n_robots, 5), dtype=np.float32))


@pytest.mark.parametrize("algorithm", ["sac", "dqn"])
def test_overlapped_training_is_deterministic_and_takes_the_same_gradient_steps(tmp_path: Path, algorithm) -> None:
    """Collection and gradient steps overlapped (the worlds in their process): the same seed gives the same weights
    to the bit; the gradient steps see data one step older than without overlap, so the weights differ from those."""
    scenario, world = world_for(algorithm)
    runs = {}
    for name, overlap in (("a", True), ("b", True), ("sync", False)):
        cfg = tiny_config(algorithm=algorithm, overlap=overlap)
        runs[name] = train(scenario, world, cfg, tmp_path / name, progress=False)
    weights = {k: load_checkpoint(r.checkpoint).weights for k, r in runs.items()}
    assert (tmp_path / "a" / "curve.csv").read_bytes() == (tmp_path / "b" / "curve.csv").read_bytes()
    for wa, wb in zip(weights["a"], weights["b"], strict=True):
        assert wa.keys() == wb.keys() and all(th.equal(wa[k], wb[k]) for k in wa)
    # the one-step lag shows in the weights, never in the transitions collected before updates begin
    assert any(not th.equal(wa[k], ws[k]) for wa, ws in zip(weights["a"], weights["sync"], strict=True) for k in wa)


def test_overlap_is_refused_where_the_algorithm_has_nothing_to_overlap() -> None:
    from pipeline.errors import ConfigError

    with pytest.raises(ConfigError, match=r"overlap = True: .*false with algorithm ppo in mode centralized"):
        tiny_config(algorithm="ppo", mode="centralized", overlap=True)
