"""eval_sim's output folder: one clock per recording spanning the session, results beside the recording they
describe, a bag folder that rosbags opens, and a policy refused in a world whose actions decode otherwise."""

from __future__ import annotations

import json

import pytest
from rosbags.rosbag2 import Reader

from pipeline.core.timebase import NS_PER_S
from pipeline.params import EvalSimConfig, world_config
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.record.results import STAGING
from pipeline.rollout.sim import EPISODE_GAP_NS, evaluate_session
from pipeline.sim import make_world
from tests.integration.conftest import TINY_WORLD

pytestmark = pytest.mark.integration


def test_a_sim_recording_spans_exactly_its_episodes_and_opens_as_a_bag(tiny_policy, tmp_path):
    scenario, world = make_world(world=world_config(TINY_WORLD))
    cfg = EvalSimConfig(episodes=3, seed=7, out_dir=str(tmp_path))
    results, metrics = evaluate_session(scenario, world, PolicyRuntime(tiny_policy), cfg, tmp_path, progress=False)
    assert {p.name for p in tmp_path.iterdir()} == {
        "session.mcap",
        "metadata.yaml",
        "episodes.csv",
        "metrics.json",
        "paths.png",
    }
    log = McapLog(tmp_path / "session.mcap")
    session = log.metadata()["session"]
    assert (session["clock"], session["clock_epoch"]) == ("sim", "session")
    times = [m.log_time_ns for m in log.raw()]
    period = round(world.control_period_s * NS_PER_S)
    expected = sum(r.steps for r in results) * period + (len(results) - 1) * EPISODE_GAP_NS
    assert (min(times), max(times)) == (0, expected)
    with Reader(tmp_path) as bag:
        assert (bag.start_time, bag.duration) == (0, expected + 1)  # rosbags counts the last nanosecond in
        assert bag.message_count == len(times) == sum(1 for _ in bag.messages())
    assert json.loads((tmp_path / "metrics.json").read_text())["eval/episodes"] == 3 == metrics["eval/episodes"]


def test_a_world_with_other_action_limits_is_refused_before_anything_is_written(tiny_policy, tmp_path):
    scenario, world = make_world(world=world_config({**TINY_WORLD, "actions": {"v_max_mps": 0.3}}))
    cfg = EvalSimConfig(episodes=1, out_dir=str(tmp_path))
    (tmp_path / "metrics.json").write_text("{}")
    with pytest.raises(PolicyMismatch) as err:
        evaluate_session(scenario, world, PolicyRuntime(tiny_policy), cfg, tmp_path, progress=False)
    assert "world.actions.v_max_mps 0.4 vs 0.3" in str(err.value) and "policy.json" in str(err.value)
    assert {p.name for p in tmp_path.iterdir()} == {"metrics.json"}
    assert not (tmp_path / STAGING).exists()
