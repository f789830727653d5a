"""A policy observing its previous command (``rich_memory``) in the simulator and on the twin: each recorded
observation carries the command recorded one step before it, over the robot's limits (zero at the start), so
the deploy runner gives the network the memory it was trained with."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig, world_config
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.record.session import SessionLog, session_metadata
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.rollout.sim import evaluate
from pipeline.ros.fleet import load_fleet
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim
from tests.integration.conftest import TINY_TRAIN, TINY_WORLD, write_fleet

pytestmark = pytest.mark.integration


def _memory_against_commands(recording: Path, runtime: PolicyRuntime) -> int:
    """Checks every recorded observation's previous command against the command recorded a step earlier;
    returns how many steps after the first were checked."""
    s = runtime.layout.slices["previous_command"]
    limits = runtime.codec.limits(3)
    index = {f"robot_{i}": i - 1 for i in (1, 2, 3)}
    seen: dict[tuple[int, str], dict[int, np.ndarray]] = defaultdict(dict)
    given: dict[tuple[int, str], dict[int, np.ndarray]] = defaultdict(dict)
    for m in McapLog(recording).messages(["/mrl/observation", "/mrl/action"]):
        key = (m.msg.episode, m.msg.robot)
        if m.topic == "/mrl/observation":
            assert m.msg.layout == "rich_memory"
            seen[key][m.msg.step] = np.asarray(m.msg.values, dtype=np.float64)[s]
        else:
            given[key][m.msg.step] = np.array([m.msg.linear_mps, m.msg.angular_radps]) / limits[index[m.msg.robot]]
    checked = 0
    for key, steps in seen.items():
        np.testing.assert_array_equal(steps[0], 0.0)
        for step, memory in steps.items():
            if step > 0:
                np.testing.assert_allclose(memory, np.clip(given[key][step - 1], -1, 1), atol=1e-6, err_msg=str(key))
                checked += 1
    moved = [np.abs(m).max() for steps in seen.values() for k, m in steps.items() if k > 0]
    assert max(moved) > 0.005  # the policy commanded something: the check is not of zeros alone
    return checked


@pytest.fixture(scope="module")
def memory_policy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("memory_policy")
    scenario, world = make_world(world=world_config({**TINY_WORLD, "observation": "rich_memory"}))
    cfg = from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), TINY_TRAIN), "<test>")
    trained = train(scenario, world, cfg, root / "run", progress=False)
    export_policy(trained.checkpoint, root / "policy", golden_observations(scenario, world, 8))
    return root / "policy"


def test_the_simulator_records_the_previous_command_in_each_observation(memory_policy, tmp_path):
    runtime = PolicyRuntime(memory_policy)
    assert runtime.layout.name == "rich_memory" and runtime.layout.size == 23
    scenario, world = runtime.spec.scenario, runtime.spec.world
    session = session_metadata("sim", scenario.name, scenario.robot_names, 0.1, runtime.document)
    with SessionLog(tmp_path / "s.mcap", scenario.robot_names, session) as log:
        evaluate(MultiRobotSim(scenario, world), runtime.actions, 2, 0, False, log, runtime.layout.name)
    assert _memory_against_commands(tmp_path / "s.mcap", runtime) >= 40


def test_the_deploy_runner_gives_the_policy_its_previous_command_on_the_twin(memory_policy, tmp_path):
    runtime = PolicyRuntime(memory_policy)
    fleet = write_fleet(tmp_path / "fleet.yaml")
    request = DeployRequest(episodes=2, seed=5, recording=tmp_path / "session.mcap", progress=False)
    results, _ = deploy_policy(runtime, load_fleet(fleet), str(fleet), request)
    assert len(results) == 2 and not any(r.aborted for r in results)
    assert _memory_against_commands(tmp_path / "session.mcap", runtime) >= 20
