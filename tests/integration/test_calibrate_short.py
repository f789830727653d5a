"""Calibration never fails on what the data cannot show: three episodes of a barely trained policy on the twin give a
complete calibration file (each key identified or unidentified with its reason), that training reads."""

from __future__ import annotations

import pytest
import yaml

from pipeline.calibration import calibrate, write_calibration
from pipeline.calibration.keys import PROFILE_KEYS
from pipeline.params import WorldConfig, calibrated_world
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.deployment import DeployRequest, deploy_session
from pipeline.ros.fleet import load_fleet
from tests.integration.conftest import write_fleet

pytestmark = pytest.mark.integration


@pytest.mark.parametrize("profile", ["mild", "lab"])
def test_three_short_episodes_of_a_poor_policy_calibrate_to_a_complete_file(tiny_policy, tmp_path, profile):
    fleet_file = write_fleet(tmp_path / "fleet.yaml", twin={"profile": profile, "time_scale": 2.0})
    out = tmp_path / "real"
    request = DeployRequest(episodes=3, seed=3, recording=out / "session.mcap", progress=False)
    deploy_session(PolicyRuntime(tiny_policy), load_fleet(fleet_file), str(fleet_file), request, out)
    calibration = calibrate(out / "session.mcap")
    path = write_calibration(calibration, tmp_path / "calibration")
    data = yaml.safe_load(path.read_text())
    for group in ("lidar", "actuation", "odometry", "network"):
        for key in PROFILE_KEYS[group]:
            entry = data["uncertainty"][group][key]
            assert entry["status"] in ("ok", "weak", "unidentifiable")
            if entry["status"] == "weak":  # identified, with an interval wider than its value: said so
                assert "wider than its value" in entry["reason"] and entry["interval_95"][0] >= 0
            if entry["status"] == "unidentifiable":
                assert entry["reason"] and data["unidentified"][f"{group}.{key}"] == entry["reason"]
    calibrated_world(WorldConfig(), path)  # a valid simulator for training


def test_a_twin_and_a_sim_recording_are_not_pooled_unless_asked(tiny_policy, tmp_path):
    import hashlib

    from pipeline.calibration import calibration_settings
    from pipeline.calibration.errors import CalibrationError
    from pipeline.params import EvalSimConfig
    from pipeline.rollout.sim import evaluate_session
    from pipeline.sim import make_world

    runtime = PolicyRuntime(tiny_policy)
    fleet_file = write_fleet(tmp_path / "fleet.yaml")
    twin = tmp_path / "twin"
    request = DeployRequest(episodes=2, seed=3, recording=twin / "session.mcap", progress=False)
    deploy_session(runtime, load_fleet(fleet_file), str(fleet_file), request, twin)
    scenario, world = make_world(world=runtime.spec.world)
    evaluate_session(scenario, world, runtime, EvalSimConfig(episodes=2), tmp_path / "sim", progress=False)
    both = [twin / "session.mcap", tmp_path / "sim" / "session.mcap"]
    parts = {"parts": ["lidar", "network"]}
    with pytest.raises(CalibrationError) as err:
        calibrate(both, calibration_settings(parts))
    text = str(err.value)
    assert "a sim recording" in text and "twin recording" in text and "--pool" in text
    pooled = calibrate(both, calibration_settings({**parts, "pool": True}))
    assert [s.kind for s in pooled.sources] == ["twin", "sim"]
    assert pooled.sources[0].sha256 == hashlib.sha256(both[0].read_bytes()).hexdigest()
    data = yaml.safe_load(write_calibration(pooled, tmp_path / "cal", report=False).read_text())
    assert [r["kind"] for r in data["source"]["recordings"]] == ["twin", "sim"]
    assert all(r["salvaged"] == "" and len(r["sha256"]) == 64 for r in data["source"]["recordings"])
