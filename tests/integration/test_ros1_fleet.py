"""A ROS 1 fleet: the deploy runner and the hardware twin as two rospy nodes on a real master (Debian's ROS 1)."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.messages.convert import EVENT_NAMES
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.ros.fleet import load_fleet
from tests.integration.conftest import write_fleet

pytestmark = pytest.mark.integration

SIM_LAYOUT = {"/tf", "/mrl/observation", "/mrl/action", "/mrl/episode"} | {
    f"/robot_{i}/{t}" for i in (1, 2, 3) for t in ("scan", "odom", "ground_truth", "cmd_vel")
}


def ros1_fleet(path: Path, master_uri: str, **changes: object) -> Path:
    return write_fleet(path, transport="ros1", network={"master_uri": master_uri}, **changes)


def test_the_twin_plays_a_ros1_fleet_through_whole_episodes(ros1_master, tiny_policy, tmp_path):
    fleet_file = ros1_fleet(tmp_path / "fleet.yaml", ros1_master)
    request = DeployRequest(episodes=2, seed=5, recording=tmp_path / "session.mcap", progress=False)
    results, profile = deploy_policy(PolicyRuntime(tiny_policy), load_fleet(fleet_file), str(fleet_file), request)
    assert profile == "mild" and len(results) == 2
    assert all(r.steps >= 1 and not r.aborted for r in results)
    log = McapLog(tmp_path / "session.mcap")
    counts = log.message_counts()
    assert set(counts) >= SIM_LAYOUT and counts["/mrl/reset"] == 2 and counts["/clock"] > 0
    session = log.metadata()["session"]
    assert session["target"] == "twin" and session["transport"] == "ros1"
    names = [EVENT_NAMES[m.msg.event] for m in log.messages(["/mrl/episode"])]
    assert names.count("start") == 2 and names.count("end") == 2
    assert counts["/mrl/observation"] == counts["/mrl/action"] == 3 * sum(r.steps for r in results)
    assert len(next(iter(log.messages(["/robot_1/scan"]))).msg.ranges) == 360
