"""Calibration of recordings that cannot give every estimate: missing topics, no motion, another scenario."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from pipeline.calibration import (
    CalibrationSettings,
    MissingTopicError,
    ScenarioMismatchError,
    calibrate,
    calibration_settings,
    write_calibration,
)
from pipeline.record import LogReadError
from tests.calibration_helpers import simulate_session

pytestmark = pytest.mark.integration

MILD_WORLD = {
    "lidar": {"noise_sigma_m": 0.02, "dropout_prob": 0.01, "bias_m": 0.01, "mount_yaw_rad": 0.01},
    "actuation": {"delay_s": 0.05, "time_constant_s": 0.15, "linear_gain": 0.95, "angular_gain": 0.9},
    "odometry": {"drift_per_m": 0.04},
}


def test_a_recording_without_a_needed_topic_names_it(tmp_path):
    path = simulate_session(tmp_path / "no_cmd.mcap", MILD_WORLD, episodes=1, steps=10, omit=["/robot_2/cmd_vel"])
    with pytest.raises(MissingTopicError) as err:
        calibrate(path)
    text = str(err.value)
    assert str(path) in text and "/robot_2/cmd_vel" in text and "actuation calibration" in text
    # the parts that do not need it still run
    lidar_only = calibrate(path, calibration_settings({"parts": ["lidar", "odometry"]}))
    assert "actuation.delay_s" not in lidar_only.values and "lidar.noise_sigma_m" in lidar_only.values


def test_without_ground_truth_nothing_can_be_calibrated(tmp_path):
    path = simulate_session(tmp_path / "no_truth.mcap", MILD_WORLD, episodes=1, steps=10, omit=["/ground_truth"])
    with pytest.raises(MissingTopicError, match=r"/robot_1/ground_truth, /robot_2/ground_truth, /robot_3/ground_truth"):
        calibrate(path)


def test_robots_standing_still_leave_actuation_and_odometry_unidentifiable(tmp_path):
    path = simulate_session(tmp_path / "still.mcap", MILD_WORLD, episodes=2, steps=25, mode="still")
    result = calibrate(path, CalibrationSettings(bootstrap=50))
    for key in ("delay_s", "time_constant_s", "linear_gain", "angular_gain"):
        est = result.values[f"actuation.{key}"]
        assert est.status == "unidentifiable"
        assert est.reason == "no linear commands above 0.05 m/s; no turning commands above 0.05 rad/s"
    drift = result.values["odometry.drift_per_m"]
    assert drift.status == "unidentifiable" and "robots must drive" in drift.reason
    # standing still is what the lidar estimates need
    assert result.values["lidar.noise_sigma_m"].ok
    assert result.values["lidar.noise_sigma_m"].value == pytest.approx(0.02, rel=0.1)
    data = yaml.safe_load(write_calibration(result, tmp_path / "out").read_text())
    assert "actuation" not in data["world"] and "odometry" not in data["world"]
    assert set(data["unidentified"]) == {
        "actuation.delay_s",
        "actuation.time_constant_s",
        "actuation.linear_gain",
        "actuation.angular_gain",
        "odometry.drift_per_m",
    }
    assert data["world"]["lidar"]["sim_beams"] == 360


def test_a_recording_from_another_scenario_is_refused(tmp_path):
    empty = simulate_session(tmp_path / "empty.mcap", MILD_WORLD, episodes=1, steps=5, scenario="empty")
    with pytest.raises(ScenarioMismatchError) as err:
        calibrate(empty, calibration_settings({"scenario": "obstacles"}))
    text = str(err.value)
    assert str(empty) in text and "'empty'" in text and "'obstacles'" in text
    obstacles = simulate_session(tmp_path / "obstacles.mcap", MILD_WORLD, episodes=1, steps=5)
    with pytest.raises(ScenarioMismatchError, match=r"made in scenario 'empty'"):
        calibrate([obstacles, empty])


def test_a_file_that_is_not_a_recording_is_named(tmp_path):
    bad = tmp_path / "notes.mcap"
    bad.write_text("not an MCAP file")
    with pytest.raises(LogReadError, match=str(bad)):
        calibrate(bad)
    with pytest.raises(LogReadError, match="no such file"):
        calibrate(Path(tmp_path / "missing.mcap"))
