"""A private ROS 1 master for the ROS 1 tier: Debian's ``rosmaster`` on a free loopback port.

:func:`missing` says why the tier cannot run here (rospy or rosmaster absent); :func:`master` is
:func:`pipeline.ros.ros1.private_master`. rospy allows one node per process, bound to one master: a test
process uses one master for all its ROS 1 tests (the session fixture ``ros1_master``).
"""

from __future__ import annotations

import shutil

from pipeline.ros.ros1 import private_master as master
from pipeline.ros.ros1 import ros1_missing
from pipeline.ros.ros1 import ros_environment as environment

__all__ = ["environment", "master", "missing"]


def missing() -> str | None:
    """Why the ROS 1 tier cannot run here (None: it can)."""
    why = ros1_missing()
    if why is None and shutil.which("rosmaster") is None:
        why = "rosmaster is not installed (apt-get install ros-core python3-rospy)"
    return None if why is None else f"{why} (.ci/run installs Debian's ROS 1)"
