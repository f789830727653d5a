"""Training and evaluation on random layouts: each training episode in a layout of its own, the same seed
the same weights to the bit, and evaluation on layouts drawn from seeds training never used."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch as th

from pipeline.core.layouts import draw_layout
from pipeline.learn.checkpoint import load_checkpoint
from pipeline.learn.common.worlds import TRAIN_SEED_MIN
from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig, world_config
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.rollout.sim import evaluate
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim
from tests.integration.conftest import TINY_TRAIN

pytestmark = pytest.mark.integration

MRL = Path(sys.executable).parent / "mrl"
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

    # the installed command evaluates in the scenario's own layout on request, recording each episode's map
    for layouts, expected in (("fixed", [scenario, scenario]), ("random", [draw_layout(scenario, s) for s in (7, 8)])):
        out = tmp_path / f"eval_{layouts}"
        proc = subprocess.run(
            [str(MRL), "eval", "--policy", str(tmp_path / "policy"), "--episodes", "2", "--seed", "7",
             "--layouts", layouts, "--out", str(out)],
            capture_output=True, text=True, timeout=300, check=False,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        maps = [m.msg for m in McapLog(out / "session.mcap").messages(["/mrl/map"])]
        for msg, layout in zip(maps, expected, strict=True):
            goals = [(mk.pose.position.x, mk.pose.position.y) for mk in msg.markers if mk.ns == "goals"]
            np.testing.assert_allclose(goals, layout.goals, atol=1e-9)


def test_the_twin_and_the_runner_play_each_episode_in_the_layout_drawn_from_its_seed(tmp_path):
    """Deployment on the twin of a scenario with layouts ranges: both sides draw the layout from the episode's
    seed; the twin places its robots and boxes there, the runner judges and records it."""
    from pipeline.calibration import calibrate
    from pipeline.calibration.errors import CalibrationError
    from pipeline.policy.errors import PolicyMismatch
    from pipeline.rollout.deployment import DeployRequest, deploy_policy
    from pipeline.ros.fleet import load_fleet
    from tests.integration.conftest import write_fleet

    scenario, world = make_world(world=world_config({**WORLD, "max_steps": 20}))
    cfg = from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), TINY_TRAIN), "<test>")
    trained = train(scenario, world, cfg, tmp_path / "run", progress=False)
    export_policy(trained.checkpoint, tmp_path / "policy", golden_observations(scenario, world, 8))
    fleet_file = write_fleet(tmp_path / "fleet.yaml", scenario="obstacles_random")
    request = DeployRequest(episodes=2, seed=5, recording=tmp_path / "session.mcap", progress=False)
    results, _ = deploy_policy(PolicyRuntime(tmp_path / "policy"), load_fleet(fleet_file), str(fleet_file), request)
    assert [r.seed for r in results] == [5, 6] and not any(r.aborted for r in results)

    log = McapLog(tmp_path / "session.mcap")
    maps = [m for m in log.messages(["/mrl/map"])]
    assert len(maps) == 2
    truth = [(m.log_time_ns, m.msg) for m in log.messages(["/robot_1/ground_truth"])]
    for episode, map_msg in enumerate(maps):
        layout = draw_layout(scenario, 5 + episode)
        boxes = [mk for mk in map_msg.msg.markers if mk.ns == "boxes"]
        recorded = [(mk.pose.position.x, mk.pose.position.y) for mk in boxes]
        np.testing.assert_allclose(recorded, [(b.x_m, b.y_m) for b in layout.obstacles], atol=1e-9)
        goals = [mk for mk in map_msg.msg.markers if mk.ns == "goals"]
        np.testing.assert_allclose([(g.pose.position.x, g.pose.position.y) for g in goals], layout.goals, atol=1e-9)
        # the twin's motion capture shows robot_1 at the layout's start when the episode begins
        first = next(msg for t, msg in truth if t >= map_msg.log_time_ns)
        at = np.array([first.pose.position.x, first.pose.position.y])
        assert np.hypot(*(at - layout.starts[0, :2])) < 0.05

    # a policy trained on drawn layouts drives another draw of the same room and robots (boxes on the robots'
    # way): the twin and the runner play that draw's layout
    runtime = PolicyRuntime(tmp_path / "policy")
    in_way = make_world(world=world_config({**WORLD, "scenario": "obstacles_random_in_way"}))[0]
    seed = next(s for s in range(100) if draw_layout(in_way, s).obstacles != draw_layout(scenario, s).obstacles)
    other = write_fleet(tmp_path / "in_way.yaml", scenario="obstacles_random_in_way")
    again = DeployRequest(episodes=1, seed=seed, recording=tmp_path / "in_way.mcap", progress=False)
    (result,), _ = deploy_policy(runtime, load_fleet(other), str(other), again)
    assert result.seed == seed and not result.aborted
    (map_msg,) = [m.msg for m in McapLog(tmp_path / "in_way.mcap").messages(["/mrl/map"])]
    boxes = [(mk.pose.position.x, mk.pose.position.y) for mk in map_msg.markers if mk.ns == "boxes"]
    np.testing.assert_allclose(boxes, [(b.x_m, b.y_m) for b in draw_layout(in_way, seed).obstacles], atol=1e-9)
    # ... but not a room with other obstacles, refused before anything is recorded
    empty = write_fleet(tmp_path / "empty.yaml", scenario="empty")
    refused = DeployRequest(episodes=1, seed=0, recording=tmp_path / "empty.mcap", progress=False)
    with pytest.raises(PolicyMismatch, match=r"trained in scenario 'obstacles_random'.*'empty' \(other obstacles"):
        deploy_policy(runtime, load_fleet(empty), str(empty), refused)
    assert not (tmp_path / "empty.mcap").exists()

    # calibration fits one layout: a recording of layouts drawn per episode is refused, saying why
    with pytest.raises(CalibrationError, match=r"draws a layout per episode.*cannot use this recording yet"):
        calibrate(tmp_path / "session.mcap")


def test_a_sweep_trial_on_random_layouts_also_scores_the_scenarios_own_layout(tmp_path):
    from pipeline.bench.trials import Trial, base_mapping, run_trial
    from pipeline.params import load_params

    tiny = {
        "world": {"max_steps": 25},
        "train": {**TINY_TRAIN, "total_steps": 160, "selection": {"keep": "last", "every_steps": 0}},
    }
    base = merge(base_mapping(load_params()), tiny)
    row = run_trial(Trial("sac", "shared", "obstacles_random", 0), base, tmp_path / "trial", 3, say=lambda _: None)
    assert row["eval_episodes"] == 3 and 0.0 <= row["robot_success"] <= 1.0
    assert (row["time_to_goal_s"] is None) == (row["robot_success"] == 0.0)
    assert row["fixed_layout_robot_success"] is not None and 0.0 <= row["fixed_layout_robot_success"] <= 1.0
    plain = run_trial(Trial("sac", "shared", "obstacles", 0), base, tmp_path / "plain", 2, say=lambda _: None)
    assert plain["fixed_layout_robot_success"] is None
