"""The deploy runner (rospy) driving three robot drivers written against Debian's roscpp, through a real master.

The drivers are C++ programs compiled here with CMake against libroscpp-dev and the standard message
packages (``tests/peers/roscpp_robot``): the first ROS peer no one here wrote the middleware of. The tier
skips where those packages are absent (``.ci/run`` installs them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.record import McapLog
from tests.peers import drivers, roscpp

pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(roscpp.missing() is not None, reason=str(roscpp.missing())),
]


@pytest.fixture(scope="module")
def driver_binary() -> Path:
    return roscpp.build()


def test_the_runner_drives_roscpp_robots_through_whole_episodes(ros1_master, driver_binary, tiny_policy, tmp_path):
    recording, logs, results = roscpp.deploy_on_drivers(driver_binary, ros1_master, tiny_policy, tmp_path, episodes=2)
    assert len(results) == 2 and not any(r.aborted for r in results)
    assert all(r.steps >= 1 for r in results)
    log = McapLog(recording)
    assert log.metadata()["session"]["transport"] == "ros1"
    episode_times = [m.log_time_ns for m in log.messages(["/mrl/episode"])]
    first, last = min(episode_times), max(episode_times)
    for ns in drivers.NAMESPACES:
        driver = drivers.read_log(logs[ns])
        sent = [(m.log_time_ns, m.msg.linear.x, m.msg.angular.z) for m in log.messages([f"/{ns}/cmd_vel"])]
        got = drivers.delivery(sent, driver)
        # commands sent before the driver's subscriber connected never reach it; from the first one received on,
        # TCPROS delivers every command, values bit for bit
        assert got.matched, ns
        in_episodes = [s for s in sent if first <= s[0] <= last]
        assert sent.index(in_episodes[0]) >= got.first_matched, f"{ns}: a command sent during an episode was lost"
        assert any(v != 0.0 for _, v, _ in in_episodes), f"{ns}: the policy never moved the robot"
        delays = np.array(got.delays_s())
        assert delays.min() > -0.002, ns
        assert np.quantile(delays, 0.99) < 0.12, ns
        # every scan the runner recorded decodes to the ranges the driver published (float32, bit for bit)
        recorded = list(log.messages([f"/{ns}/scan"]))
        assert len(recorded) >= 0.8 * len([k for k in driver.scans if first <= k[0] * 10**9 + k[1] <= last])
        for m in recorded:
            key = (m.msg.header.stamp.sec, m.msg.header.stamp.nanosec)
            assert key in driver.scans, f"{ns}: a scan the driver never published"
            np.testing.assert_array_equal(m.msg.ranges, np.array(driver.scans[key], dtype=np.float32))
            assert m.msg.header.frame_id == f"{ns}/laser" and len(m.msg.ranges) == drivers.BEAMS
    truth = [m.msg.pose.position for m in log.messages(["/robot_1/ground_truth"])]
    assert len({(round(p.x, 3), round(p.y, 3)) for p in truth}) > 10
