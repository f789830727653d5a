"""A recording like a real robot's bag, made by the twin and calibrated: one robot with a TurtleBot-4-like lidar
(720 beams in 2 mm steps, a quarter without a return, noise rising with range, mixed pixels, per-beam noise, a
wandering sweep) stands still, then drives; the lidar's keys come back with intervals inside their domains that hold
the truth, and the simulator takes what calibration found."""

from __future__ import annotations

import pytest
from lidar_like_real import fleet_file, profile, tiny_policy

from pipeline.calibration import CalibrationSettings, calibrate, write_calibration
from pipeline.calibration.keys import split_key
from pipeline.core.reality import profile_bounds
from pipeline.params import WorldConfig, calibrated_world
from pipeline.policy.excitation import StillThenDrive
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.ros.fleet import load_fleet
from tests.integration.conftest import free_domain_id

pytestmark = pytest.mark.integration


def test_a_turtlebot_like_recording_calibrates_inside_the_domains_and_holds_the_truth(tmp_path):
    import yaml

    runtime = PolicyRuntime(tiny_policy(tmp_path / "policy"))
    fleet_path = fleet_file(tmp_path / "one_robot.yaml", free_domain_id())
    truth = profile(703)
    profile_path = tmp_path / "turtle.yaml"
    profile_path.write_text(yaml.safe_dump(truth), encoding="utf-8")
    recording = tmp_path / "turtle.mcap"
    request = DeployRequest(episodes=1, seed=3, recording=recording, time_scale=2.0, profile=str(profile_path),
                            progress=False)  # fmt: skip
    deploy_policy(StillThenDrive(runtime, 6.0), load_fleet(str(fleet_path)), str(fleet_path), request)
    result = calibrate(recording, CalibrationSettings(parts=("lidar", "network"), bootstrap=100, seed=1))
    lidar = truth["lidar"]
    assert result.lidar is not None and result.lidar.spans >= 1 and result.lidar.no_return == "inf"
    held = []
    for key in ("noise_sigma_m", "noise_per_m", "range_step_m", "dropout_prob", "rate_wander", "mixed_pixel_prob"):
        est = result.values[f"lidar.{key}"]
        assert est.ok and est.interval is not None, (key, est)
        assert 0.0 <= est.interval[0] < est.interval[1], (key, est)
        held.append(est.interval[0] <= lidar[key] <= est.interval[1])
    assert sum(held) >= 5, held  # 95 % intervals: one of six may miss
    for key, est in result.values.items():  # every interval inside its key's domain, never of zero width
        if not est.ok or est.interval is None or key == "lidar.beams":
            continue
        group, name, _ = split_key(key)
        low, high = profile_bounds(f"{group}.{name}")
        assert low <= est.interval[0] < est.interval[1] <= high, (key, est)
    assert any("steps of 2 mm" in note for note in result.lidar.notes)
    written = write_calibration(result, tmp_path / "cal")
    (trade,) = yaml.safe_load(written.read_text())["trade_offs"]
    at_m, _ = result.lidar.noise_at_range
    lo, hi = trade["determined"]["interval_95"]
    assert trade["correlation"] < 0 and lo <= lidar["noise_sigma_m"] + lidar["noise_per_m"] * at_m <= hi
    world = calibrated_world(WorldConfig(), written)
    assert world.lidar.range_step_m == pytest.approx(0.002, rel=0.01) and world.lidar.no_return == "inf"
    mixed = result.values["lidar.mixed_pixel_prob"]  # applied where ok; a weak one is left out (REAL_LIDAR_KEYS)
    assert world.lidar.sim_beams == 720 and world.lidar.mixed_pixel_prob == pytest.approx(
        mixed.value if mixed.status == "ok" else 0.0, rel=1e-5
    )
    if mixed.status == "ok":
        assert world.lidar.mixed_pixel_prob == pytest.approx(lidar["mixed_pixel_prob"], abs=0.1)
