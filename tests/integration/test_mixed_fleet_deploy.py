"""A mixed fleet end to end: a shared policy trained with each robot's limits in its observation, exported
with them, deployed on the twin (each chassis its own size), and refused by robot name where the fleet file
gives a robot other limits."""

from __future__ import annotations

import pytest

from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig, world_config
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.ros.fleet import load_fleet
from pipeline.sim import make_world
from tests.integration.conftest import TINY_TRAIN, write_fleet

pytestmark = pytest.mark.integration

ROBOTS = [
    {"name": "robot_1", "namespace": "robot_1", "v_max_mps": 0.4, "w_max_radps": 0.2},
    {"name": "robot_2", "namespace": "robot_2", "v_max_mps": 0.4, "w_max_radps": 0.2},
    {"name": "robot_3", "namespace": "robot_3", "v_max_mps": 0.3, "w_max_radps": 0.4},
]


def test_a_mixed_fleet_deploys_with_its_limits_and_a_mismatch_is_refused_by_name(tmp_path):
    world = world_config({"scenario": "mixed", "observation": "rich_limits", "max_steps": 20})
    scenario, world = make_world(world=world)
    cfg = from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), TINY_TRAIN), "<test>")
    trained = train(scenario, world, cfg, tmp_path / "run", progress=False)
    export_policy(trained.checkpoint, tmp_path / "policy", golden_observations(scenario, world, 8))
    runtime = PolicyRuntime(tmp_path / "policy")
    assert runtime.codec.robot_limits == ((0.4, 0.2), (0.4, 0.2), (0.3, 0.4))  # from policy.json's scenario

    fleet_file = write_fleet(tmp_path / "fleet.yaml", scenario="mixed", robots=ROBOTS)
    request = DeployRequest(episodes=2, seed=5, recording=tmp_path / "session.mcap", progress=False)
    results, _ = deploy_policy(runtime, load_fleet(fleet_file), str(fleet_file), request)
    assert len(results) == 2 and not any(r.aborted for r in results)

    other = [dict(r) for r in ROBOTS]
    other[2]["w_max_radps"] = 0.3
    bad = write_fleet(tmp_path / "bad.yaml", scenario="mixed", robots=other)
    with pytest.raises(PolicyMismatch) as err:
        deploy_policy(runtime, load_fleet(bad), str(bad), request)
    text = str(err.value)
    assert "it commands robot_3 up to 0.3 m/s and 0.4 rad/s" in text and "robot_1" not in text

    # a faster robot_3 than trained would see wrong limits in its observation: refused too, by name
    faster = [dict(r) for r in ROBOTS]
    faster[2]["w_max_radps"] = 0.5
    quick = write_fleet(tmp_path / "quick.yaml", scenario="mixed", robots=faster)
    with pytest.raises(PolicyMismatch, match=r"robot_3 was trained with limits 0\.3 m/s and 0\.4 rad/s"):
        deploy_policy(runtime, load_fleet(quick), str(quick), request)
