"""A Fast DDS robot driver stand-in, built from the pipeline's IDL with Debian's fastddsgen and libfastrtps-dev.

:func:`build` generates the IDL of the robot's message types (:func:`pipeline.ros.idl_text.idl_document`),
runs ``fastddsgen`` on it and compiles ``fastdds_robot/robot.cpp`` with CMake, once per source
digest (the binary is kept under the user's cache folder). :func:`driver` runs one per robot with the
QoS and type hash of each ROS 2 topic from :mod:`pipeline.messages.topics` (see :mod:`tests.peers.drivers`).
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path
from typing import Any

from pipeline.core.scenario import Scenario
from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.messages.topics import TopicSpec
from pipeline.ros.idl_text import idl_document
from tests.peers import drivers
from tests.peers.drivers import BEAMS, NAMESPACES, DriverProcess, delivery, read_log

__all__ = ["BEAMS", "NAMESPACES", "build", "delivery", "deploy_on_drivers", "driver", "missing", "read_log"]

SOURCE = drivers.PEERS / "fastdds_robot"
TYPES = (T.LASER_SCAN, T.ODOMETRY, T.POSE_STAMPED, T.TWIST)
HEADERS = Path("/usr/include/fastdds/dds/domain/DomainParticipant.hpp")


def missing() -> str | None:
    """Why the stand-in cannot be built here (None: it can)."""
    absent = [tool for tool in ("fastddsgen", "cmake", "g++") if shutil.which(tool) is None]
    if not HEADERS.exists():
        absent.append("libfastrtps-dev")
    if absent:
        return (
            f"the Fast DDS peer needs Debian's {', '.join(absent)} "
            "(apt-get install libfastrtps-dev fastddsgen cmake g++)"
        )
    return None


def cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mrl" / "fastdds_robot"


def build(root: Path | None = None) -> Path:
    """The driver's executable, built on first use for this IDL and these sources."""
    idl = idl_document(TYPES)
    # Debian's Fast DDS 2.9, not the ROS 2 wheels' (fastcdr 2) that CMake would find through the venv's bin/ on PATH
    ignore = f"-DCMAKE_IGNORE_PREFIX_PATH={sys.prefix}"
    out = (root or cache_root()) / drivers.source_digest(SOURCE, drivers.COMMON, extra=idl.encode() + ignore.encode())
    binary = out / "build" / "mrl_fastdds_robot"
    if binary.exists():
        return binary
    gen = out / "generated"
    gen.mkdir(parents=True, exist_ok=True)
    (gen / "ros2_types.idl").write_text(idl, encoding="utf-8")
    drivers.run(["fastddsgen", "-replace", "-d", str(gen), str(gen / "ros2_types.idl")], out)
    drivers.run(["cmake", "-S", str(SOURCE), "-B", str(out / "build"), f"-DGENERATED_DIR={gen}", ignore], out)
    drivers.run(["cmake", "--build", str(out / "build"), "-j", "2"], out)
    return binary


def qos_arg(spec: TopicSpec) -> str:
    q = spec.qos
    return f"{q.reliability},{q.durability},{q.depth},{message_store().rihs01(spec.typename)}"


def driver(binary: Path, domain: int, scenario: Scenario, index: int, namespace: str, log: Path) -> DriverProcess:
    """One Fast DDS driver for robot `index` of `scenario` on `domain`, logging to `log`."""
    topics = T.robot_topics(namespace)
    cmd = [
        str(binary),
        "--domain", str(domain),
        *drivers.world_args(scenario, index, namespace, log),
        "--qos-scan", qos_arg(topics["scan"]),
        "--qos-odom", qos_arg(topics["odom"]),
        "--qos-truth", qos_arg(topics["ground_truth"]),
        "--qos-cmd", qos_arg(topics["cmd_vel"]),
    ]  # fmt: skip
    return DriverProcess(cmd, namespace)


def deploy_on_drivers(
    binary: Path, policy: Path, folder: Path, episodes: int, domain: int, seed: int = 3
) -> tuple[Path, dict[str, Path], list[Any]]:
    """Deploy `policy` on three Fast DDS drivers (target ``robots``, loopback, `domain`)."""
    from tests.integration.conftest import write_fleet

    fleet_file = write_fleet(folder / "fleet.yaml", target="robots", network={"domain_id": domain})
    return drivers.deploy_on_drivers(
        lambda scenario, i, ns, log: driver(binary, domain, scenario, i, ns, log),
        fleet_file,
        policy,
        folder,
        episodes,
        seed,
    )
