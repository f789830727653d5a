"""A ROS 1 robot driver stand-in on roscpp, built with CMake against Debian's libroscpp-dev and message packages.

:func:`build` compiles ``roscpp_robot/robot.cpp`` once per source digest (kept under the user's cache
folder); :func:`driver` runs one per robot on a master (``ROS_MASTER_URI``); see :mod:`tests.peers.drivers`.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from pipeline.core.scenario import Scenario
from tests.peers import drivers, ros1
from tests.peers.drivers import DriverProcess

SOURCE = drivers.PEERS / "roscpp_robot"
HEADERS = {
    "libroscpp-dev": Path("/usr/include/ros/ros.h"),
    "libsensor-msgs-dev": Path("/usr/include/sensor_msgs/LaserScan.h"),
    "libnav-msgs-dev": Path("/usr/include/nav_msgs/Odometry.h"),
    "libgeometry-msgs-dev": Path("/usr/include/geometry_msgs/PoseStamped.h"),
}


def missing() -> str | None:
    """Why the stand-in cannot be built or run here (None: it can)."""
    absent = [tool for tool in ("cmake", "g++", "pkg-config") if shutil.which(tool) is None]
    absent += [package for package, header in HEADERS.items() if not header.exists()]
    if absent:
        return f"the roscpp peer needs Debian's {', '.join(absent)} (apt-get install {' '.join(absent)})"
    return ros1.missing()


def cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mrl" / "roscpp_robot"


def build(root: Path | None = None) -> Path:
    """The driver's executable, built on first use for these sources."""
    out = (root or cache_root()) / drivers.source_digest(SOURCE, drivers.COMMON)
    binary = out / "build" / "mrl_roscpp_robot"
    if binary.exists():
        return binary
    out.mkdir(parents=True, exist_ok=True)
    drivers.run(["cmake", "-S", str(SOURCE), "-B", str(out / "build")], out)
    drivers.run(["cmake", "--build", str(out / "build"), "-j", "2"], out)
    return binary


def driver(binary: Path, master_uri: str, scenario: Scenario, index: int, namespace: str, log: Path) -> DriverProcess:
    """One roscpp driver for robot `index` of `scenario` on the master `master_uri`, logging to `log`."""
    env = ros1.environment(master_uri, log.parent / "ros_home")
    return DriverProcess([str(binary), *drivers.world_args(scenario, index, namespace, log)], namespace, env)


def deploy_on_drivers(
    binary: Path, master_uri: str, policy: Path, folder: Path, episodes: int, seed: int = 3
) -> tuple[Path, dict[str, Path], list[Any]]:
    """Deploy `policy` on three roscpp drivers (a fleet file with transport ros1, target ``robots``)."""
    from tests.integration.conftest import write_fleet

    fleet_file = write_fleet(
        folder / "fleet.yaml", target="robots", transport="ros1", network={"master_uri": master_uri}
    )
    return drivers.deploy_on_drivers(
        lambda scenario, i, ns, log: driver(binary, master_uri, scenario, i, ns, log),
        fleet_file,
        policy,
        folder,
        episodes,
        seed,
    )
