"""Calibration of recordings that cannot give every estimate: missing topics, no motion, another scenario."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from pipeline.calibration import (
    CalibrationError,
    CalibrationSettings,
    ScenarioMismatchError,
    calibrate,
    calibration_settings,
    write_calibration,
)
from pipeline.record import LogReadError, McapLog
from pipeline.record.errors import MissingTopicError
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


def test_without_ground_truth_or_scans_nothing_can_be_calibrated(tmp_path):
    """Poses come from motion capture or from localization in the map; a recording with neither is refused,
    naming what is missing, and asking for ground truth explicitly names the ground-truth topics."""
    no_truth = simulate_session(tmp_path / "no_truth.mcap", MILD_WORLD, episodes=1, steps=10, omit=["/ground_truth"])
    with pytest.raises(MissingTopicError, match=r"/robot_1/ground_truth, /robot_2/ground_truth, /robot_3/ground_truth"):
        calibrate(no_truth, CalibrationSettings(pose_source="ground_truth"))
    blind = simulate_session(tmp_path / "blind.mcap", MILD_WORLD, episodes=1, steps=10, omit=["/ground_truth", "/scan"])
    with pytest.raises(MissingTopicError, match=r"/robot_1/scan"):
        calibrate(blind)


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
    needs_driving = {
        "actuation.delay_s",
        "actuation.time_constant_s",
        "actuation.linear_gain",
        "actuation.angular_gain",
        "odometry.drift_per_m",
        "base.wheel_radius_left_m",
        "base.wheel_radius_right_m",
        "base.wheel_separation_m",
        "base.deadband_radps",
        "base.max_wheel_accel_radps2",
        "base.motor_time_constant_s",
        "base.friction",
    }
    unidentified = set(data["unidentified"])
    assert "robots must drive" in data["unidentified"]["base.deadband_radps"]
    assert "robots must drive" in data["unidentified"]["base.friction"]
    assert needs_driving <= unidentified
    # besides: what 5 s do not show (a clock's drift, bursts of losses, mixed pixels at the few depth edges seen,
    # scans lost beyond the other topics' losses), boxes no still robot sees, and the beams' angle errors (never)
    besides = ("clock.", "network.burst_len", "map.box_offsets_m[", "lidar.mixed_pixel_prob", "lidar.scan_drop_prob")
    assert all(k.startswith(besides) for k in unidentified - needs_driving - {"lidar.beam_angle_jitter_rad"})
    assert "grazing" in data["unidentified"]["lidar.beam_angle_jitter_rad"]
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


def rosbag2_copy(source: Path, folder: Path) -> Path:
    """What ``ros2 bag record -s mcap`` on the robots would give: a rosbag2 folder (metadata.yaml and
    an MCAP written by rosbags) with only the robots' standard topics, no session metadata, no
    episode events, no scenario."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    log = McapLog(source)
    kept = {t: ty for t, ty in log.topics().items() if t.count("/") == 2 and not t.startswith("/mrl/")}
    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {t: writer.add_connection(t, ty, typestore=typestore) for t, ty in sorted(kept.items())}
        for m in log.raw(list(kept)):
            writer.write(connections[m.topic], m.log_time_ns, m.data)
    (bag,) = folder.glob("*.mcap")
    return bag


def test_a_plain_rosbag2_recording_calibrates_with_the_scenario_given(tmp_path):
    ours = simulate_session(tmp_path / "ours.mcap", MILD_WORLD, episodes=2, steps=60)
    bag = rosbag2_copy(ours, tmp_path / "bag")
    bag_log = McapLog(bag)
    assert "session" not in bag_log.metadata() and "/mrl/episode" not in bag_log.topics()
    assert {"/robot_1/scan", "/robot_1/odom", "/robot_1/ground_truth", "/robot_1/cmd_vel"} <= set(bag_log.topics())
    with pytest.raises(CalibrationError, match="names no scenario"):
        calibrate(bag, CalibrationSettings(bootstrap=20))
    from_bag = calibrate(bag, CalibrationSettings(bootstrap=50, scenario="obstacles"))
    from_ours = calibrate(ours, CalibrationSettings(bootstrap=50))
    assert from_bag.values["lidar.beams"].value == 360
    assert from_bag.values["lidar.noise_sigma_m"].value == pytest.approx(0.02, rel=0.1)
    assert from_bag.values["actuation.linear_gain"].value == pytest.approx(0.95, rel=0.05)
    assert from_bag.values["odometry.drift_per_m"].ok
    # no /mrl/episode: the two episodes are found from the reset between them (the robots and their
    # odometry jump back to the starts), and the same data give nearly the same estimates
    assert from_bag.sources[0].episodes == 2 and from_bag.odometry is not None
    assert "2 episode(s) inferred from 1 reset(s)" in from_bag.odometry.notes[0]
    for key in ("lidar.noise_sigma_m", "lidar.bias_m", "actuation.linear_gain", "actuation.angular_gain"):
        assert from_bag.values[key].value == pytest.approx(from_ours.values[key].value, rel=0.05), key
