"""Weight selection by periodic deterministic evaluation: the best evaluation's weights are kept,
evaluations leave training bit for bit unchanged, and the checkpoint holds what was chosen."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import torch as th

from pipeline.errors import ConfigError
from pipeline.learn.checkpoint import load_checkpoint
from pipeline.learn.selection import SELECTION_FILE, Selector
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import SelectionConfig, TrainConfig, load_params, world_config
from pipeline.policy.scripted import GoToGoalController
from pipeline.sim import make_world
from tests.integration.conftest import TINY_TRAIN

pytestmark = pytest.mark.integration

WORLD = {"scenario": "empty", "observation": "rich", "max_steps": 120}


class Holder:
    """Stands in for a learner's model: what the selector copies is `policy.state_dict()`."""

    def __init__(self, value: float) -> None:
        self.policy = th.nn.Linear(2, 1)
        with th.no_grad():
            self.policy.weight.fill_(value)
            self.policy.bias.fill_(value)


def rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def test_the_selector_keeps_the_weights_of_the_best_evaluation(tmp_path):
    scenario, world = make_world(world=world_config(WORLD))
    selector = Selector(SelectionConfig(keep="best", every_steps=100, episodes=3, seed=11), scenario, world, tmp_path)
    scripted = GoToGoalController(world.layout(), world.codec())

    def stand_still(obs: np.ndarray) -> np.ndarray:
        return np.tile(world.codec().encode(np.zeros((1, 2))), (len(obs), 1))

    assert not selector.due(99) and selector.due(100)
    first = selector.offer(100, stand_still, [Holder(1.0)])
    assert first.robot_success == 0.0 and selector.best == first
    good = selector.offer(200, scripted, [Holder(2.0)])
    assert good.robot_success > 0.5 and selector.best == good
    selector.offer(300, stand_still, [Holder(3.0)])
    assert selector.best == good and not selector.due(399) and selector.due(400)
    selector.close()
    assert selector.best_state is not None
    assert float(selector.best_state[0]["weight"][0, 0]) == 2.0  # a copy, taken when it was the best
    table = rows(tmp_path / SELECTION_FILE)
    assert [r["world_steps"] for r in table] == ["100", "200", "300"]
    assert [r["kept"] for r in table] == ["1", "1", "0"]
    assert float(table[1]["robot_success"]) == pytest.approx(good.robot_success, abs=1e-4)


def tiny_cfg(**selection: object) -> TrainConfig:
    changes = {**TINY_TRAIN, "total_steps": 240, "selection": selection}
    return from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), changes), "<test>")


def test_evaluations_do_not_change_training_and_best_weights_are_exported(tmp_path):
    scenario, world = make_world(world=world_config({**WORLD, "max_steps": 30}))
    plain = train(scenario, world, tiny_cfg(), tmp_path / "plain", progress=False)
    watched = train(
        scenario, world, tiny_cfg(keep="last", every_steps=60, episodes=2), tmp_path / "last", progress=False
    )
    a, b = load_checkpoint(plain.checkpoint), load_checkpoint(watched.checkpoint)
    for wa, wb in zip(a.weights, b.weights, strict=True):
        assert all(th.equal(wa[k], wb[k]) for k in wa)  # bit for bit: evaluation touched no training state
    assert watched.selected_at_steps is None and b.record.selection is not None and b.record.selection.keep == "last"
    assert [r["world_steps"] for r in rows(tmp_path / "last" / SELECTION_FILE)] == ["60", "120", "180", "240"]

    best = train(scenario, world, tiny_cfg(keep="best", every_steps=60, episodes=2), tmp_path / "best", progress=False)
    table = rows(tmp_path / "best" / SELECTION_FILE)
    keys = [(float(r["robot_success"]), float(r["team_success"]), int(r["world_steps"])) for r in table]
    winner = max(keys)
    assert best.selected_at_steps == winner[2] and best.selected_robot_success == pytest.approx(winner[0], abs=1e-4)
    record = load_checkpoint(best.checkpoint).record
    assert record.selection is not None and record.selection.best_at_steps == winner[2] and record.world_steps == 240
    assert best.metrics()["train/selected_at_steps"] == float(winner[2])


def test_keep_best_needs_evaluations(params_data, write_params):
    params_data["train"]["selection"].update({"keep": "best", "every_steps": 0, "episodes": 5, "seed": 1})
    with pytest.raises(ConfigError, match=r"train\.selection\.every_steps = 0.*keep 'best'"):
        load_params(write_params(params_data))


def at_goal_world(tmp_path: Path):  # type: ignore[no-untyped-def]
    """A room whose robots start on their goals: every evaluation and every training episode succeeds at once."""
    room = tmp_path / "at_goal.yaml"
    room.write_text(
        "name: at_goal\n"
        "room: {x_min_m: 0.0, x_max_m: 6.0, y_min_m: 0.0, y_max_m: 4.0, wall_thickness_m: 0.1, wall_height_m: 0.5}\n"
        "robot: {radius_m: 0.165, height_m: 0.2, mass_kg: 5.0, wheel_separation_m: 0.281, wheel_diameter_m: 0.068}\n"
        "goal_size_m: 0.4\n"
        "robots:\n"
        "  - {start: {x_m: 1.0, y_m: 1.0, yaw_rad: 0.0}, goal: {x_m: 1.0, y_m: 1.0}}\n"
        "  - {start: {x_m: 4.0, y_m: 2.0, yaw_rad: 0.0}, goal: {x_m: 4.0, y_m: 2.0}}\n"
        "obstacles: []\n",
        encoding="utf-8",
    )
    return make_world(world=world_config({**WORLD, "scenario": str(room), "max_steps": 30}))


def test_training_stops_at_the_first_evaluation_that_reaches_stop_at_success(tmp_path):
    # the first evaluation scores 1.0 and training stops there
    scenario, world = at_goal_world(tmp_path)
    stopped = train(
        scenario, world, tiny_cfg(keep="best", every_steps=60, episodes=2, stop_at_success=1.0), tmp_path / "stop"
    )
    assert stopped.world_steps == 60 and stopped.selected_robot_success == 1.0
    assert [r["world_steps"] for r in rows(tmp_path / "stop" / SELECTION_FILE)] == ["60"]
    assert load_checkpoint(stopped.checkpoint).record.world_steps == 60

    # in the reference room an untrained policy never reaches its goals: the whole budget is trained
    scenario, world = make_world(world=world_config({**WORLD, "max_steps": 30}))
    whole = train(
        scenario, world, tiny_cfg(keep="best", every_steps=60, episodes=2, stop_at_success=1.0), tmp_path / "whole"
    )
    assert whole.world_steps == 240 and len(rows(tmp_path / "whole" / SELECTION_FILE)) == 4


def test_stop_after_convergence_waits_for_the_training_criterion(tmp_path):
    scenario, world = at_goal_world(tmp_path)
    selection = {"keep": "best", "every_steps": 60, "episodes": 2, "stop_at_success": 1.0}
    selection["stop_after_convergence"] = True

    def run(window: int, name: str):  # type: ignore[no-untyped-def]
        cfg = from_mapping(
            TrainConfig,
            merge(to_mapping(tiny_cfg(**selection)), {"convergence": {"window_episodes": window}}),
            "<test>",
        )
        return train(scenario, world, cfg, tmp_path / name, progress=False)

    # a window the training episodes fill before the first evaluation: the criterion holds, the first evaluation stops
    early = run(2, "early")
    assert early.converged_at_episode is not None and early.world_steps == 60
    # a window longer than the budget's episodes: the criterion never holds, so perfect evaluations do not stop it
    whole = run(10_000, "whole")
    assert whole.converged_at_episode is None and whole.world_steps == 240
    assert [float(r["robot_success"]) for r in rows(tmp_path / "whole" / SELECTION_FILE)] == [1.0] * 4


def test_stop_after_convergence_needs_stop_at_success(params_data, write_params):
    params_data["train"]["selection"].update({"keep": "last", "every_steps": 10, "stop_after_convergence": True})
    with pytest.raises(ConfigError, match=r"train\.selection\.stop_after_convergence = True.*stop_at_success"):
        load_params(write_params(params_data))


def test_stop_at_success_needs_evaluations(params_data, write_params):
    selection = {"keep": "last", "every_steps": 0, "episodes": 5, "seed": 1, "stop_at_success": 0.9}
    params_data["train"]["selection"].update(selection)
    with pytest.raises(ConfigError, match=r"train\.selection\.every_steps = 0.*stop_at_success"):
        load_params(write_params(params_data))
