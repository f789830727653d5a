"""train.imitation: PPO's warm start from the scripted controller, in real worlds with tiny budgets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th

from pipeline.errors import ConfigError
from pipeline.learn.checkpoint import load_checkpoint
from pipeline.learn.common.modes import StreamMap
from pipeline.learn.common.worlds import VecWorlds
from pipeline.learn.export import export_policy
from pipeline.learn.imitation import demonstrate, discounted_returns, imitate
from pipeline.learn.learners import build_learners
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, read_yaml, to_mapping
from pipeline.params import Params, TrainConfig, world_config
from pipeline.policy.runtime import PolicyRuntime
from pipeline.policy.scripted import GoToGoalController
from pipeline.sim import make_world
from tests.integration.test_train_export import golden_from_sim, tiny_config, world_for

pytestmark = pytest.mark.integration


def test_discounted_returns_stop_at_each_episode_end_and_are_unknown_past_the_last():
    # one stream: an episode of 3 steps (ends at t=2), the robot inactive at t=3 (finished, others drive on),
    # then a new episode cut off by the end of the arrays
    reward = np.array([[1.0], [2.0], [10.0], [0.0], [4.0], [5.0]])
    active = np.array([[1], [1], [1], [0], [1], [1]], dtype=bool)
    ended = np.array([[0], [0], [1], [0], [0], [0]], dtype=bool)
    returns, known = discounted_returns(reward, active, ended, gamma=0.5)
    assert returns[:3, 0].tolist() == [1 + 0.5 * (2 + 0.5 * 10), 2 + 0.5 * 10, 10.0]
    assert known[:, 0].tolist() == [True, True, True, False, False, False]
    assert returns[3, 0] == 0.0


@pytest.mark.parametrize("mode", ["independent", "shared", "centralized"])
@pytest.mark.parametrize("kind", ["continuous", "discrete"])
def test_learner_actions_are_the_inverse_of_world_actions(mode: str, kind: str) -> None:
    scenario, world = make_world(
        world=world_config({"scenario": "obstacles", "observation": "rich", "actions": {"kind": kind}})
    )
    with VecWorlds(scenario, world, 3, seed=0) as worlds:
        streams = StreamMap(mode, worlds)  # type: ignore[arg-type]
        rng = np.random.default_rng(0)
        if kind == "continuous":
            actions = rng.uniform(-1, 1, size=(3, scenario.n_robots, 2)).astype(np.float32)
        else:
            actions = rng.integers(0, worlds.codec.n_discrete, size=(3, scenario.n_robots))
        per_learner = streams.learner_actions(actions)
        assert len(per_learner) == streams.n_learners
        np.testing.assert_array_equal(streams.world_actions(per_learner), actions)


@pytest.mark.parametrize("mode", ["shared", "independent", "centralized"])
def test_the_imitated_policy_drives_like_the_controller_and_its_values_follow_the_returns(mode: str) -> None:
    scenario, world = world_for("ppo", n_robots=3, max_steps=40)
    cfg = tiny_config(
        algorithm="ppo", mode=mode, learning_rate=1e-3, imitation={"steps": 600, "epochs": 60, "log_std": -1.5}
    )
    with VecWorlds(scenario, world, 2, seed=4, start_xy_m=0.3) as worlds:
        streams = StreamMap(mode, worlds)  # type: ignore[arg-type]
        learners = build_learners(
            cfg, streams.observation_space, streams.action_space, streams.n_streams, streams.n_learners
        )
        demos, steps, episodes = demonstrate(worlds, streams, 600, cfg.gamma)
        assert steps == 600 and episodes >= 10 and len(demos) == streams.n_learners
        for learner, demo in zip(learners, demos, strict=True):
            assert len(demo.obs) == len(demo.actions) == len(demo.returns) > 50
            policy = learner.model.policy
            obs = th.as_tensor(demo.obs)

            def errors() -> tuple[float, float]:
                with th.no_grad():
                    mean = policy.get_distribution(obs).distribution.mean.numpy()  # noqa: B023
                    values = policy.predict_values(obs).numpy().ravel()  # noqa: B023
                return float(np.mean((mean - demo.actions) ** 2)), float(np.mean((values - demo.returns) ** 2))  # noqa: B023

            action_before, value_before = errors()
            action_loss, value_loss = imitate(learner.model, demo, cfg, seed=0)
            action_after, value_after = errors()
            assert action_after < 0.25 * action_before
            # the values explain much of the returns' spread: more than their mean alone would
            assert value_after < 0.5 * float(np.var(demo.returns)) < value_before
            assert action_loss == pytest.approx(action_after, rel=0.5) and value_loss < value_before
            np.testing.assert_allclose(policy.log_std.detach().numpy(), -1.5)


def test_a_warm_started_training_reports_it_and_repeats_to_the_bit(tmp_path: Path) -> None:
    scenario, world = world_for("ppo")
    selection = {"keep": "best", "every_steps": 120, "episodes": 2}
    cfg = tiny_config(algorithm="ppo", mode="shared", imitation={"steps": 200, "epochs": 3}, selection=selection)
    a = train(scenario, world, cfg, tmp_path / "a", progress=False)
    b = train(scenario, world, cfg, tmp_path / "b", progress=False)
    plain_cfg = tiny_config(algorithm="ppo", mode="shared", selection=selection)
    plain = train(scenario, world, plain_cfg, tmp_path / "c", progress=False)
    assert a.digest == b.digest != plain.digest
    assert a.world_steps == plain.world_steps == cfg.total_steps  # the demonstration is not in the budget
    metrics = a.metrics()
    assert metrics["train/imitation_world_steps"] == 200.0 and metrics["train/imitation_samples"] > 0
    state = load_checkpoint(tmp_path / "a" / "checkpoint").record
    assert state.imitation is not None and state.imitation.world_steps == 200
    assert "train/imitation_world_steps" not in plain.metrics()
    # the imitated weights are evaluated before PPO's first step, and compete for export
    evaluated = [line.split(",")[0] for line in (tmp_path / "a" / "selection.csv").read_text().splitlines()[1:]]
    assert evaluated[0] == "0" and "0" not in [
        line.split(",")[0] for line in (tmp_path / "c" / "selection.csv").read_text().splitlines()[1:]
    ]


def test_with_no_ppo_budget_the_imitated_policy_alone_is_evaluated_and_kept(tmp_path: Path) -> None:
    """`total_steps: 0` with imitation: the imitated weights are the training's result (no PPO update), evaluated
    like any and exported from the checkpoint, the same as a training with a budget exports before its first
    update."""
    scenario, world = world_for("ppo")
    selection = {"keep": "best", "every_steps": 120, "episodes": 2}
    imitation = {"steps": 200, "epochs": 3}
    alone = tiny_config(algorithm="ppo", mode="shared", imitation=imitation, selection=selection, total_steps=0)
    result = train(scenario, world, alone, tmp_path / "a", progress=False)
    assert result.world_steps == 0 and result.episodes == 0 and result.selected_at_steps == 0
    rows = (tmp_path / "a" / "selection.csv").read_text().splitlines()[1:]
    assert [row.split(",")[0] for row in rows] == ["0"]
    state = load_checkpoint(tmp_path / "a" / "checkpoint").record
    assert state.world_steps == 0 and state.imitation is not None and state.imitation.world_steps == 200
    assert not state.interrupted
    golden = golden_from_sim(scenario, world)
    export_policy(result.checkpoint, tmp_path / "policy", golden, tolerance=1e-5)
    assert PolicyRuntime(tmp_path / "policy").actions(golden[0]).shape == (scenario.n_robots, 2)
    # the same imitation followed by PPO changes the weights; the imitation alone is what it started from
    longer = tiny_config(
        algorithm="ppo", mode="shared", imitation=imitation, selection={**selection, "keep": "last"}, total_steps=240
    )
    trained = train(scenario, world, longer, tmp_path / "b", progress=False)
    assert trained.digest != result.digest
    assert train(scenario, world, alone, tmp_path / "c", progress=False).digest == result.digest
    with pytest.raises(ConfigError, match=r"total_steps.*0 with imitation\.steps > 0"):
        tiny_config(algorithm="ppo", total_steps=0)


def test_imitation_is_refused_where_it_cannot_run() -> None:
    with pytest.raises(ConfigError, match=r"imitation\.steps.*0 with algorithm sac \(ppo only\)"):
        tiny_config(algorithm="sac", imitation={"steps": 100})
    params = read_yaml(Path(__file__).resolve().parents[2] / "params.yaml")
    bad = merge(params, {"train": {"algorithm": "ppo", "imitation": {"steps": 100}}, "world": {"observation": "paper"}})
    with pytest.raises(
        ConfigError, match=r"world\.observation.*'rich', 'rich_limits' or 'rich_memory' with train\.imitation\.steps"
    ):
        from_mapping(Params, bad, "<test>")
    with pytest.raises(ConfigError, match=r"imitation\.log_std"):
        from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), {"imitation": {"log_std": 3.0}}), "<test>")


def test_in_a_dagger_round_the_driver_steers_and_the_controller_only_labels() -> None:
    scenario, world = world_for("ppo", n_robots=3, max_steps=30)
    with VecWorlds(scenario, world, 2, seed=5, start_xy_m=0.3) as worlds:
        streams = StreamMap("shared", worlds)

        def stand_still(per_learner: list[np.ndarray]) -> list[np.ndarray]:
            # decoded to (0, 0): the middle of the action range
            return [np.zeros((len(o), 2), dtype=np.float32) for o in per_learner]

        (demo,), steps, episodes = demonstrate(worlds, streams, 120, gamma=0.99, driver=stand_still)
    assert steps == 120 and episodes == 4  # 2 worlds, 30-step episodes nobody ends early
    position = world.layout().slices["position"]
    # nobody moved: every sample of a robot's episode shows it where it started (lockstep steps 0-29 are the
    # first episodes, 30-59 the second; 6 streams per step) ...
    xy = demo.obs[:, position].reshape(60, 2 * scenario.n_robots, 2)
    for first in (0, 30):
        np.testing.assert_allclose(xy[first : first + 30], np.broadcast_to(xy[first], (30, 6, 2)), atol=1e-3)
    assert not np.allclose(xy[0], xy[30], atol=1e-2)  # the second episodes start elsewhere
    # ... while the labels are what the controller would have done there
    controller = GoToGoalController(world.layout(), worlds.codec)
    np.testing.assert_array_equal(demo.actions, controller(demo.obs))
    assert np.abs(demo.actions).max() > 0.5


def test_dagger_rounds_add_samples_from_the_students_driving_and_repeat_to_the_bit(tmp_path: Path) -> None:
    scenario, world = world_for("ppo")
    imitation = {"steps": 120, "epochs": 2, "rounds": 3}
    cfg = tiny_config(algorithm="ppo", mode="shared", imitation=imitation)
    a = train(scenario, world, cfg, tmp_path / "a", progress=False)
    b = train(scenario, world, cfg, tmp_path / "b", progress=False)
    one = train(
        scenario,
        world,
        tiny_config(algorithm="ppo", mode="shared", imitation={**imitation, "rounds": 1}),
        tmp_path / "c",
        progress=False,
    )
    assert a.digest == b.digest != one.digest
    assert a.metrics()["train/imitation_world_steps"] == 360.0 and one.metrics()["train/imitation_world_steps"] == 120.0
    assert a.metrics()["train/imitation_samples"] > 2 * one.metrics()["train/imitation_samples"]
