"""``mrl calibrate`` on a bag that holds nothing but a lidar's scans (a ROS 1 bag written with rosbags, as a driver
records it): the lidar's keys from the scans alone, the rest named, the bag's own SHA-256, a map that cannot be used
said so."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore

from tests.integration.test_mrl_command import mrl, refused

pytestmark = pytest.mark.integration

BEAMS, PERIOD_NS, STEP_M = 360, 125_000_000, 0.001


def scans_bag(dest: Path, seed: int = 5) -> Path:
    """8 s standing still, 10 s carried about, 8 s still again: ranges in 1 mm steps, noise 2 mm + 1 mm per metre,
    every 9th beam without a return (inf)."""
    store = get_typestore(Stores.ROS1_NOETIC)
    LaserScan = store.types["sensor_msgs/msg/LaserScan"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    rng = np.random.default_rng(seed)
    room = 2.0 + 1.2 * np.abs(np.sin(np.linspace(0.0, 2 * np.pi, BEAMS)))  # smooth walls
    with Writer(dest) as writer:
        conn = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
        for k in range(208):
            moving = 64 <= k < 144
            true = room + (0.03 * np.sin(k / 2.0) + 0.02 * rng.standard_normal(BEAMS) if moving else 0.0)
            r = np.round((true + rng.standard_normal(BEAMS) * (0.002 + 0.001 * true)) / STEP_M) * STEP_M
            r[::9] = np.inf
            t = 1_700_000_000 * 10**9 + k * PERIOD_NS
            msg = LaserScan(
                Header(k, Time(t // 10**9, t % 10**9), "laser"),
                -np.pi,
                np.pi - 2 * np.pi / BEAMS,
                2 * np.pi / BEAMS,
                0.0,
                0.125,
                0.12,
                12.0,
                r.astype(np.float32),
                np.zeros(0, dtype=np.float32),
            )
            writer.write(conn, t, store.serialize_ros1(msg, "sensor_msgs/msg/LaserScan"))
    return dest


def test_mrl_calibrate_reads_a_bag_of_scans_alone(tmp_path):
    bag = scans_bag(tmp_path / "lidar.bag")
    proc = mrl("calibrate", bag, "--map", tmp_path / "floor.yaml", "--out", tmp_path / "cal", timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert f"--map {tmp_path / 'floor.yaml'} not used" in proc.stdout  # said, not ignored in silence
    assert "calibrate: lidar.range_step_m 0.001 m" in proc.stdout
    assert "calibrate: lidar.bias_m unidentifiable: needs where the beams should end" in proc.stdout
    cal = yaml.safe_load((tmp_path / "cal" / "calibration.yaml").read_text())
    lidar = cal["uncertainty"]["lidar"]
    assert lidar["range_step_m"]["interval_95"][0] <= STEP_M <= lidar["range_step_m"]["interval_95"][1]
    assert lidar["rate_hz"]["interval_95"][0] <= 8.0 <= lidar["rate_hz"]["interval_95"][1]
    for key in ("noise_sigma_m", "noise_per_m"):
        assert lidar[key]["interval_95"][0] >= 0.0  # inside the key's domain
    assert set(cal["unidentified"]) >= {"lidar.bias_m", "lidar.mount_yaw_rad", "lidar.dropout_prob"}
    (recording,) = cal["source"]["recordings"]
    assert recording["path"] == str(bag)
    assert recording["sha256"] == hashlib.sha256(bag.read_bytes()).hexdigest()  # the user's bag, not a copy
    assert cal["source"]["poses"] == {"kind": "none"}
    report = (tmp_path / "cal" / "calibration.md").read_text()
    assert "scans alone: /scan, 208 scans of 360 beams" in report
    assert "2 still span(s) found from the scans alone" in report
    assert "beams without a return read inf" in report
    assert "world ?" not in report and "profile ``" not in report


def test_a_bag_of_scans_alone_is_not_pooled(tmp_path):
    bag = scans_bag(tmp_path / "a.bag")
    other = scans_bag(tmp_path / "b.bag", seed=6)
    line = refused(mrl("calibrate", bag, other, "--out", tmp_path / "cal"), "calibrate", str(bag), str(other))
    assert "holds scans alone" in line
    assert not (tmp_path / "cal").exists()
