"""The deploy runner (rospy) driving three robot drivers written against Debian's roscpp, through a real master.

The drivers are C++ programs compiled here with CMake against libroscpp-dev and the standard message
packages (``tests/peers/roscpp_robot``): the first ROS peer no one here wrote the middleware of. The tier
skips where those packages are absent (``.ci/run`` installs them).
"""

from __future__ import annotations

from pathlib import Path

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
    assert McapLog(recording).metadata()["session"]["transport"] == "ros1"
    drivers.check_whole_episodes(recording, logs, results, episodes=2)
