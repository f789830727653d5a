"""A ROS 1 fleet: the deploy runner and the hardware twin as two rospy nodes on a real master (Debian's ROS 1)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import polars as pl
import pytest
import yaml

from pipeline.messages.convert import EVENT_NAMES
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.ros.fleet import load_fleet
from tests.integration.conftest import check_twin_fleet_plays_two_episodes, write_fleet
from tests.integration.test_mrl_command import MRL, mrl
from tests.peers import ros1

pytestmark = pytest.mark.integration


def ros1_fleet(path: Path, master_uri: str, **changes: object) -> Path:
    return write_fleet(path, transport="ros1", network={"master_uri": master_uri}, **changes)


def test_the_twin_plays_a_ros1_fleet_through_whole_episodes(ros1_master, tiny_policy, tmp_path):
    fleet_file = ros1_fleet(tmp_path / "fleet.yaml", ros1_master)
    check_twin_fleet_plays_two_episodes(tiny_policy, fleet_file, tmp_path, "ros1")


def test_rosbag_record_of_a_ros1_deployment_reads_as_the_session_recording(ros1_master, tiny_policy, tmp_path):
    """Debian's ``rosbag record`` (not this project's recorder) records the fleet's topics; ``mrl info``,
    ``mrl episodes`` and ``mrl calibrate`` read the ROS 1 .bag, and its episodes are the session's."""
    home = tmp_path / "ros_home"
    topics = ["/mrl/episode", "/clock"] + [f"/robot_{i}/{t}" for i in (1, 2, 3) for t in ("scan", "odom", "cmd_vel")]
    topics += [f"/robot_{i}/ground_truth" for i in (1, 2, 3)]
    bag = tmp_path / "deploy.bag"
    recorder = subprocess.Popen(
        ["rosbag", "record", "--output-name", str(bag), *topics],
        env=ros1.environment(ros1_master, home),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        time.sleep(1.0)  # rosbag subscribes to the named topics before they exist
        fleet_file = ros1_fleet(tmp_path / "fleet.yaml", ros1_master)
        request = DeployRequest(episodes=3, seed=5, recording=tmp_path / "session.mcap", progress=False)
        results, _ = deploy_policy(PolicyRuntime(tiny_policy), load_fleet(fleet_file), str(fleet_file), request)
        time.sleep(0.5)
    finally:
        recorder.send_signal(signal.SIGINT)
        output = recorder.communicate(timeout=30)[0]
    assert len(results) == 3 and bag.is_file(), output
    info = mrl("info", bag)
    assert info.returncode == 0, info.stderr
    assert "robots: robot_1, robot_2, robot_3 (3)" in info.stdout and "/mrl/episode" in info.stdout
    columns = ["episode", "seed", "robot", "success", "reached", "collided", "aborted", "steps"]
    tables = []
    for source in (bag, tmp_path / "session.mcap"):
        out = tmp_path / f"{source.stem}.csv"
        done = mrl("episodes", source, "--out", out)
        assert done.returncode == 0, done.stderr
        tables.append(pl.read_csv(out).select(columns).sort("episode", "robot"))
    assert tables[0].height == 9 and tables[0].equals(tables[1])
    calibrated = mrl("calibrate", bag, "--scenario", "obstacles", "--out", tmp_path / "cal", "--parts", "lidar,network")
    assert calibrated.returncode == 0, calibrated.stderr
    written = yaml.safe_load((tmp_path / "cal" / "calibration.yaml").read_text())
    # the twin's scans at their rate, read from the bag's robot stamps (the mild profile's lidar runs at 10 Hz)
    assert written["scenario"] == "obstacles" and written["profile"]["lidar"]["beams"] == 360
    assert abs(written["profile"]["lidar"]["rate_hz"] - 10.0) < 0.1


def test_mrl_deploy_on_the_bundled_ros1_twin_fleet_brings_its_own_master(tiny_policy, tmp_path):
    """``twin_ros1`` names no master: the deployment starts one of its own for the run (and stops it)."""
    from pipeline.ros.ros1 import ros1_missing

    if ros1_missing() is not None:
        pytest.skip(str(ros1_missing()))
    env = {k: v for k, v in os.environ.items() if k != "ROS_MASTER_URI"}
    done = subprocess.run(
        [str(MRL), "deploy", "--policy", str(tiny_policy), "--fleet", "twin_ros1", "--episodes", "2",
         "--time-scale", "1", "--out", str(tmp_path / "out")],
        env=env, capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    log = McapLog(tmp_path / "out" / "session.mcap")
    assert log.metadata()["session"]["transport"] == "ros1"
    names = [EVENT_NAMES[m.msg.event] for m in log.messages(["/mrl/episode"])]
    assert names.count("start") == 2 and names.count("end") == 2
