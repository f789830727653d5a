"""A policy that observes ground-truth poses (world.observed_pose: ground_truth) deployed on the twin: its
observations are built from the motion-capture poses the runner hears, and a fleet without motion capture
is refused before anything moves."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.messages import convert as C
from pipeline.params import TrainConfig, world_config
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.ros.fleet import load_fleet
from pipeline.sim import make_world
from tests.integration.conftest import TINY_TRAIN, TINY_WORLD, write_fleet

pytestmark = pytest.mark.integration


def test_a_ground_truth_policy_observes_motion_capture_and_needs_it(tmp_path):
    scenario, world = make_world(world=world_config({**TINY_WORLD, "observed_pose": "ground_truth"}))
    cfg = from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), TINY_TRAIN), "<test>")
    trained = train(scenario, world, cfg, tmp_path / "run", progress=False)
    export_policy(trained.checkpoint, tmp_path / "policy", golden_observations(scenario, world, 8))
    runtime = PolicyRuntime(tmp_path / "policy")
    assert runtime.spec.mdp.observed_pose == "ground_truth"
    request = DeployRequest(episodes=1, seed=5, recording=tmp_path / "session.mcap", progress=False)

    blind = write_fleet(tmp_path / "blind.yaml", timing={"use_ground_truth": False})
    with pytest.raises(PolicyMismatch, match=r"observes the robots' ground-truth poses .* no motion capture"):
        deploy_policy(runtime, load_fleet(blind), str(blind), request)
    assert not (tmp_path / "session.mcap").exists()

    fleet = write_fleet(tmp_path / "fleet.yaml")
    results, _ = deploy_policy(runtime, load_fleet(fleet), str(fleet), request)
    assert len(results) == 1 and not results[0].aborted and results[0].steps >= 5
    layout = runtime.layout
    position = layout.slices["position"]
    truths: list[np.ndarray] = []
    matched = checked = 0
    for m in McapLog(tmp_path / "session.mcap").messages(["/robot_1/ground_truth", "/mrl/observation"]):
        if m.topic == "/robot_1/ground_truth":
            truths.append(C.planar_pose(m.msg.pose)[:2])
        elif m.msg.robot == "robot_1" and truths:
            seen = np.asarray(m.msg.values, dtype=np.float64)[position]
            # the observation's position is one of the last motion-capture poses heard before it
            recent = np.array(truths[-10:])
            matched += bool(np.abs(recent - seen).max(axis=1).min() < 1e-4)
            checked += 1
    assert checked >= 5 and matched == checked
