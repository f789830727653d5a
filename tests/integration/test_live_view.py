"""The live view: a deployment served to a Foxglove WebSocket client while it runs (foxglove-sdk's server)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.messages.store import message_store
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.record.live import LiveView
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.ros.fleet import load_fleet
from tests.integration.conftest import write_fleet
from tests.peers.foxglove_client import Client

pytestmark = pytest.mark.integration

WANTED = ("/robot_1/scan", "/robot_1/cmd_vel")


def test_a_client_receives_the_scan_and_cmd_vel_of_a_running_deployment(tiny_policy, tmp_path: Path):
    fleet_file = write_fleet(tmp_path / "fleet.yaml")
    request = DeployRequest(episodes=3, seed=5, recording=tmp_path / "session.mcap", progress=False)
    store = message_store()
    with LiveView(port=0) as live:
        client = Client(live.url, WANTED)
        results, _ = deploy_policy(
            PolicyRuntime(tiny_policy), load_fleet(fleet_file), str(fleet_file), request, live=live
        )
        client.thread.join(timeout=30)
    assert client.error is None, client.error
    assert len(results) == 3 and live.failures == 0
    scan_ch, cmd_ch = (client.channels[t] for t in WANTED)
    assert scan_ch["schemaName"] == "sensor_msgs/msg/LaserScan" and scan_ch["encoding"] == "cdr"
    assert scan_ch["schemaEncoding"] == "ros2msg" and "float32[] ranges" in scan_ch["schema"]
    assert cmd_ch["schemaName"] == "geometry_msgs/msg/Twist"
    # log times on the twin's clock can repeat (two scans read within one tick of /clock): every recorded message
    # at a log time is a candidate, and the live one must be one of them
    recorded: dict[str, dict[int, list]] = {topic: {} for topic in WANTED}
    for topic in WANTED:
        for m in McapLog(tmp_path / "session.mcap").messages([topic]):
            recorded[topic].setdefault(m.log_time_ns, []).append(m)
    for topic in WANTED:
        got = client.received[topic]
        assert len(got) == client.limit, topic
        for log_time, data in got:
            # the live message is a recorded one: same log time, same decoded content
            candidates = recorded[topic][log_time]
            live_msg = store.deserialize(data, candidates[0].typename)
            if topic.endswith("scan"):
                assert len(live_msg.ranges) == 360
                assert any(np.array_equal(live_msg.ranges, m.msg.ranges) for m in candidates), log_time
            else:
                sent = (live_msg.linear.x, live_msg.angular.z)
                assert any(sent == (m.msg.linear.x, m.msg.angular.z) for m in candidates), log_time
