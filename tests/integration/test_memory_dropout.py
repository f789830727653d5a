"""train.imitation.memory_dropout: fits of a ``rich_memory`` student that show the previous command as zero in
a share of the samples, so that a student at rest acts on what it sees instead of repeating its last command."""

from __future__ import annotations

from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch as th

from pipeline.core.observation import ObservationLayout
from pipeline.errors import ConfigError
from pipeline.learn.imitation import Demonstration, drop_memory, imitate
from pipeline.learn.learners import build_learners
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, read_yaml
from pipeline.params import Params, world_config
from pipeline.sim import make_world
from tests.integration.test_train_export import tiny_config

pytestmark = pytest.mark.integration

LAYOUT = ObservationLayout("rich_memory", 15)
MEMORY = LAYOUT.slices["previous_command"]


def test_only_the_previous_command_of_the_drawn_robots_is_zeroed():
    rng = np.random.default_rng(0)
    obs = th.as_tensor(rng.uniform(0.1, 1.0, size=(4000, 3 * LAYOUT.size)), dtype=th.float32)  # 3 robots side by side
    out = drop_memory(obs, MEMORY, LAYOUT.size, 0.3, th.Generator().manual_seed(1))
    blocks, before = out.reshape(4000, 3, LAYOUT.size).numpy(), obs.reshape(4000, 3, LAYOUT.size).numpy()
    dropped = (blocks[:, :, MEMORY] == 0).all(axis=2)
    # both fields of a robot go together; nothing else changes; the input is left alone
    assert ((blocks[:, :, MEMORY] == 0).any(axis=2) == dropped).all()
    np.testing.assert_array_equal(blocks[~dropped], before[~dropped])
    np.testing.assert_array_equal(np.delete(blocks, [6, 7], axis=2), np.delete(before, [6, 7], axis=2))
    assert (before[:, :, MEMORY] != 0).all()
    # the share, per robot and independently of the other robots (binomial sd of 4000 draws: 0.007)
    assert dropped.mean(axis=0) == pytest.approx([0.3, 0.3, 0.3], abs=0.03)
    assert (dropped[:, 0] & dropped[:, 1]).mean() == pytest.approx(0.09, abs=0.02)
    # the same generator state draws the same samples, to the bit; no share keeps everything
    again = drop_memory(obs, MEMORY, LAYOUT.size, 0.3, th.Generator().manual_seed(1))
    assert th.equal(out, again)
    assert th.equal(drop_memory(obs, MEMORY, LAYOUT.size, 0.0, th.Generator().manual_seed(1)), obs)


def _copycat_demo(n: int, seed: int) -> Demonstration:
    """A smooth teacher: its action depends on the goal alone, and the previous command it gave is its action
    with a little noise, so that repeating that command fits every sample."""
    rng = np.random.default_rng(seed)
    obs = rng.uniform(-1.0, 1.0, size=(n, LAYOUT.size)).astype(np.float32)
    goal = obs[:, LAYOUT.slices["goal_in_robot"]]
    actions = np.stack([np.sin(3.0 * goal[:, 0] * goal[:, 1]), np.cos(2.0 * goal[:, 0]) - goal[:, 1] ** 2], axis=1)
    actions = np.clip(actions, -1.0, 1.0).astype(np.float32)
    obs[:, MEMORY] = actions + rng.normal(0.0, 0.02, size=actions.shape).astype(np.float32)
    return Demonstration(obs=obs, actions=actions, returns=np.zeros(n, dtype=np.float32))


def _at_rest_error(memory_dropout: float, demo: Demonstration, test: Demonstration) -> tuple[float, float]:
    cfg = tiny_config(
        algorithm="ppo",
        mode="shared",
        learning_rate=1e-3,
        net_arch=[64, 64],
        imitation={"steps": 100, "epochs": 25, "memory_dropout": memory_dropout},
    )
    space = gymnasium.spaces.Box(-1.0, 1.0, shape=(LAYOUT.size,), dtype=np.float32)
    (learner,) = build_learners(cfg, space, gymnasium.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32), 1, 1)
    imitate(learner.model, demo, cfg, seed=0, memory=(MEMORY, LAYOUT.size))  # type: ignore[arg-type]
    policy = learner.model.policy

    def error(obs: np.ndarray) -> float:
        with th.no_grad():
            mean = policy.get_distribution(th.as_tensor(obs)).distribution.mean.numpy()
        return float(np.mean((mean - test.actions) ** 2))

    at_rest = test.obs.copy()
    at_rest[:, MEMORY] = 0.0
    return error(test.obs), error(at_rest)


def test_a_student_fitted_with_memory_dropout_acts_on_what_it_sees_when_at_rest():
    demo, test = _copycat_demo(2000, seed=0), _copycat_demo(1000, seed=1)
    copy_moving, copy_at_rest = _at_rest_error(0.0, demo, test)
    drop_moving, drop_at_rest = _at_rest_error(0.5, demo, test)
    spread = float(np.mean((test.actions - test.actions.mean(axis=0)) ** 2))
    # without dropout the student repeats its last command: fine while it moves, lost at rest
    assert copy_moving < 0.02 * spread
    assert copy_at_rest > 0.3 * spread
    # with dropout it still follows while moving and, at rest, does what the teacher would
    assert drop_moving < 0.1 * spread
    assert drop_at_rest < 0.2 * copy_at_rest


def test_memory_dropout_is_refused_without_the_memory_layout_or_outside_its_range():
    params = read_yaml(Path(__file__).resolve().parents[2] / "params.yaml")
    imitation = {"steps": 100, "teacher": "path", "memory_dropout": 0.5}
    bad = merge(params, {"train": {"algorithm": "ppo", "imitation": imitation}, "world": {"observation": "rich"}})
    with pytest.raises(
        ConfigError, match=r"train\.imitation\.memory_dropout.*0 with world\.observation 'rich' \('rich_memory' only"
    ):
        from_mapping(Params, bad, "<test>")
    good = merge(bad, {"world": {"observation": "rich_memory"}})
    assert from_mapping(Params, good, "<test>").train.imitation.memory_dropout == 0.5
    for share in (1.0, -0.1):
        with pytest.raises(ConfigError, match=r"imitation\.memory_dropout"):
            tiny_config(algorithm="ppo", imitation={"steps": 100, "memory_dropout": share})


def test_a_training_with_memory_dropout_repeats_to_the_bit_and_differs_from_one_without(tmp_path: Path):
    scenario, world = make_world(
        world=world_config({"scenario": "obstacles", "n_robots": 2, "observation": "rich_memory", "max_steps": 60})
    )
    imitation = {"steps": 160, "epochs": 3, "rounds": 2, "memory_dropout": 0.5}
    cfg = tiny_config(algorithm="ppo", mode="shared", imitation=imitation, total_steps=0)
    a = train(scenario, world, cfg, tmp_path / "a", progress=False)
    b = train(scenario, world, cfg, tmp_path / "b", progress=False)
    plain = tiny_config(algorithm="ppo", mode="shared", imitation={**imitation, "memory_dropout": 0.0}, total_steps=0)
    c = train(scenario, world, plain, tmp_path / "c", progress=False)
    assert a.digest == b.digest != c.digest
    assert a.metrics()["train/imitation_samples"] > 0
