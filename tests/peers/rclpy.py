"""A ROS 2 robot driver stand-in written as an ordinary rclpy node (``rclpy_robot/robot.py``), on the RMW rclpy loads
(Fast DDS from the ros2 extra's wheels).

:func:`driver` runs one per robot as a ROS 2 node is run: ``ROS_DOMAIN_ID`` and
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` in its environment, the interface packages the wheels lack (``tf2_msgs``)
on its paths as a sourced workspace puts them (:func:`pipeline.ros.ros2_interfaces.environment`), and its namespace
either by ``--ns`` or only by ROS 2's remapping ``--ros-args -r __ns:=/<ns>``; :func:`deploy_on_drivers` runs whole
episodes of a policy on three of them with the runner on ``dds`` (Cyclone) or ``rclpy`` (Fast DDS). See
:mod:`tests.peers.drivers`.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any, Literal

from pipeline.core.scenario import Scenario
from pipeline.ros import ros2_interfaces
from pipeline.ros.rclpy_transport import middleware_environment, rclpy_missing
from pipeline.ros.transport import NetworkSettings
from tests.peers import drivers
from tests.peers.drivers import DriverProcess

SOURCE = drivers.PEERS / "rclpy_robot"
ROBOT = SOURCE / "robot.py"
Transport = Literal["dds", "rclpy"]
Naming = Literal["option", "remap"]


def missing() -> str | None:
    """Why the stand-in cannot run here (None: it can): rclpy not importable, no RMW library, a distribution mix."""
    why = rclpy_missing()
    return None if why is None else f"the rclpy peer needs ROS 2's rclpy: {why}"


def environment(domain: int, log_dir: Path) -> dict[str, str]:
    """What a ROS 2 node of this host on `domain` runs with: the domain, loopback discovery (and what else the RMW
    needs to match Cyclone DDS, :func:`~pipeline.ros.rclpy_transport.middleware_environment`), the interface packages
    built from ``schemas/`` (``tf2_msgs``) where the installation lacks them, its logs under `log_dir`."""
    env = dict(os.environ)
    env.pop("ROS_LOCALHOST_ONLY", None)  # Jazzy's older switch; the discovery range says it
    prefix = ros2_interfaces.ensure_interfaces()
    if prefix is not None:
        env.update(ros2_interfaces.environment(prefix))
    env.update(middleware_environment(NetworkSettings(domain, loopback_only=True)))
    env.update(ROS_DOMAIN_ID=str(domain), ROS_LOG_DIR=str(log_dir), PYTHONUNBUFFERED="1")
    return env


def command(scenario: Scenario, index: int, namespace: str, log: Path, naming: Naming = "option") -> list[str]:
    """The node's command line for robot `index` of `scenario`: the shared world flags, its namespace by ``--ns``
    (`naming` option) or by remapping ``__ns`` only (remap)."""
    args = drivers.world_args(scenario, index, namespace, log)
    if naming == "remap":
        at = args.index("--ns")
        del args[at : at + 2]
        args += ["--ros-args", "-r", f"__ns:=/{namespace}"]
    return [sys.executable, str(ROBOT), *args]


def driver(
    domain: int, scenario: Scenario, index: int, namespace: str, log: Path, naming: Naming = "option"
) -> DriverProcess:
    """One rclpy robot node for robot `index` of `scenario` on `domain`, logging to `log`."""
    env = environment(domain, log.parent / "ros_log")
    return DriverProcess(command(scenario, index, namespace, log, naming), namespace, env)


def deploy_on_drivers(
    policy: Path,
    folder: Path,
    episodes: int,
    domain: int,
    transport: Transport = "dds",
    naming: Naming = "option",
    seed: int = 3,
) -> tuple[Path, dict[str, Path], list[Any]]:
    """Deploy `policy` on three rclpy robot nodes (target ``robots``, loopback, `domain`), the runner on `transport`."""
    from tests.integration.conftest import write_fleet

    fleet_file = write_fleet(folder / "fleet.yaml", target="robots", transport=transport, network={"domain_id": domain})
    return drivers.deploy_on_drivers(
        lambda scenario, i, ns, log: driver(domain, scenario, i, ns, log, naming),
        fleet_file,
        policy,
        folder,
        episodes,
        seed,
    )
