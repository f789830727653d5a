"""ROS 2's own client library beside the pipeline's Cyclone DDS: every type of the contract crosses both ways, bytes
equal, the pipeline's own mrl_msgs included (built from schemas/ with the installation's rosidl generators); and
what a ROS 2 tier refuses: no rclpy (named with the install command), a type without its type support.

Both transports are in this process on a domain of this test, so rclpy's Fast DDS and Cyclone DDS meet on loopback.
"""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.record import McapLog
from pipeline.ros import NetworkSettings, Transport, open_transport, ros2_interfaces
from pipeline.ros.rclpy_transport import rclpy_missing
from tests.integration.conftest import free_domain_id

pytestmark = [
    pytest.mark.integration,
    pytest.mark.ros2,
    pytest.mark.skipif(rclpy_missing() is not None, reason=str(rclpy_missing())),
]

ROOT = Path(__file__).resolve().parents[2]
GOLDEN = ROOT / "tests" / "golden" / "session.mcap"


def golden_samples() -> dict[str, Any]:
    """One recorded message per topic of the golden session (every type of the contract)."""
    samples: dict[str, Any] = {}
    for item in McapLog(GOLDEN).messages():
        samples.setdefault(item.topic, item.msg)
    return samples


def cross(sender: Transport, receiver: Transport, spec: T.TopicSpec, msg: Any, timeout_s: float = 10.0) -> bytes:
    """Publishes `msg` on `spec` from `sender` until `receiver` took one; the received message's CDR."""
    got: list[Any] = []
    sub = receiver.subscribe(spec, lambda _spec, m, _t: got.append(m))
    pub = sender.publisher(spec)
    try:
        assert sender.wait_for_match(spec, 1, timeout_s), f"{spec.name}: no match"
        deadline = time.monotonic() + timeout_s
        while not got and time.monotonic() < deadline:
            pub.publish(msg)  # best-effort topics may drop a sample while the match settles
            time.sleep(0.05)
        assert got, f"{spec.name}: nothing arrived within {timeout_s} s"
        return message_store().serialize(got[0], spec.typename)
    finally:
        pub.close()
        sub.close()


def test_every_contract_type_crosses_between_rclpy_and_cyclone_dds_bytes_equal():
    samples = golden_samples()
    specs = T.fleet_topics(["robot_1", "robot_2"])
    store = message_store()
    settings = NetworkSettings(domain_id=free_domain_id())
    checked = []
    with (
        open_transport("rclpy", settings) as ros2,
        open_transport("rclpy", settings) as other,
        open_transport("dds", settings) as dds,
    ):
        for name, msg in sorted(samples.items()):
            spec = specs[name]
            sent = store.serialize(msg, spec.typename)
            # the map's marker array goes to the recording and the live view, never over dds (cyclonedds cannot type
            # its byte fields): it crosses between two rclpy participants
            peer = other if name == "/mrl/map" else dds
            assert cross(ros2, peer, spec, msg) == sent, f"{name}: rclpy -> {'rclpy' if peer is other else 'dds'}"
            assert cross(peer, ros2, spec, msg) == sent, f"{name}: {'rclpy' if peer is other else 'dds'} -> rclpy"
            checked.append(spec.typename)
    assert {T.EPISODE_EVENT, T.OBSERVATION, T.ACTION, T.TIMING, T.RESET_REQUEST, T.TF_MESSAGE} <= set(checked)


def test_the_built_interface_packages_are_rosidl_packages_with_the_stores_type_hashes():
    """mrl_msgs and tf2_msgs import as rosidl-generated packages (not ROS 1's genpy) with their C type support, and
    rosidl's type description carries the RIHS01 hash the message store computes, the one the dds transport
    announces: Jazzy's nodes match the pipeline's endpoints on hash as well as on name."""
    ros2_interfaces.ensure_interfaces()
    from ament_index_python.packages import get_package_share_directory

    store = message_store()
    for typename in (T.EPISODE_EVENT, T.OBSERVATION, T.ACTION, T.TIMING, T.RESET_REQUEST, T.TF_MESSAGE):
        package, _, name = typename.partition("/msg/")
        cls = getattr(importlib.import_module(f"{package}.msg"), name)
        cls.__class__.__import_type_support__()
        assert cls.__class__._TYPE_SUPPORT is not None, typename
        described = json.loads((Path(get_package_share_directory(package)) / "msg" / f"{name}.json").read_text())
        hashes = {h["type_name"]: h["hash_string"] for h in described["type_hashes"]}
        assert hashes[typename] == store.rihs01(typename), typename


def _run(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)


def test_without_rclpy_the_transport_names_the_install_command():
    done = _run(
        "import sys\n"
        "sys.modules['rclpy'] = None\n"  # rclpy not importable, as in an environment without the extra
        "from pipeline.ros import NetworkSettings, open_transport\n"
        "from pipeline.ros.errors import BackendUnavailableError\n"
        "try:\n"
        "    open_transport('rclpy', NetworkSettings(domain_id=3))\n"
        "except BackendUnavailableError as exc:\n"
        "    print(exc)\n"
    )
    assert done.returncode == 0, done.stderr
    assert "transport 'rclpy'" in done.stdout and "pip install -e '.[ros2]'" in done.stdout, done.stdout
    assert "/opt/ros/jazzy/setup.bash" in done.stdout


def test_a_type_without_its_type_support_is_named_with_the_topic():
    done = _run(
        "import sys\n"
        "sys.modules['visualization_msgs'] = None\n"  # the installation lacks the package
        "from pipeline.messages import topics as T\n"
        "from pipeline.ros import NetworkSettings, open_transport\n"
        "from pipeline.ros.errors import TransportError\n"
        f"with open_transport('rclpy', NetworkSettings(domain_id={free_domain_id()})) as t:\n"
        "    try:\n"
        "        t.publisher(T.FLEET_TOPICS['map'])\n"
        "    except TransportError as exc:\n"
        "        print(exc)\n"
    )
    assert done.returncode == 0, done.stderr
    line = done.stdout.strip()
    assert "/mrl/map" in line and "visualization_msgs/msg/MarkerArray" in line and "ros-visualization-msgs" in line


@pytest.mark.parametrize("first", ["rospy", "rclpy"])
def test_one_process_holds_rospy_and_rclpy_with_their_own_message_packages(first):
    """ROS 1's rospy and ROS 2's rclpy in one interpreter, in either order: rospy keeps Debian's genpy classes,
    ``sys.modules`` keeps ROS 2's packages, and both transports send."""
    from pipeline.ros.ros1 import ros1_missing

    if ros1_missing() is not None:
        pytest.skip(str(ros1_missing()))
    code = f"""
import sys
from pipeline.ros import NetworkSettings, open_transport
from pipeline.ros.ros1 import _import_rospy, free_port, ros1_message_module
from pipeline.messages import convert, topics as T

def ros2_side():
    with open_transport("rclpy", NetworkSettings(domain_id={free_domain_id()})) as t:
        t.publisher(T.FLEET_TOPICS["clock"]).publish(convert.clock(5))
    import rosgraph_msgs.msg
    return hasattr(rosgraph_msgs.msg.Clock, "_TYPE_SUPPORT") or hasattr(type(rosgraph_msgs.msg.Clock), "_TYPE_SUPPORT")

def ros1_side():
    rospy = _import_rospy()
    log_class = sys.modules["rospy.impl.rosout"].Log
    return log_class._md5sum == ros1_message_module("rosgraph_msgs").Log._md5sum and hasattr(log_class, "_full_text")

order = [ros1_side, ros2_side] if "{first}" == "rospy" else [ros2_side, ros1_side]
print([f() for f in order])
import rosgraph_msgs.msg, std_msgs.msg
print("ros2" if hasattr(type(std_msgs.msg.Header), "_TYPE_SUPPORT") else "ros1", hasattr(rosgraph_msgs.msg, "Log"))
"""
    done = _run(code)
    assert done.returncode == 0, done.stderr
    both, after = done.stdout.splitlines()[-2:]
    assert both == "[True, True]" and after == "ros2 False", done.stdout


def test_the_stores_type_hashes_are_the_ones_this_ros2_installation_describes():
    """Every type of schemas/ and the graph's ParticipantEntitiesInfo: the RIHS01 hash the dds transport announces
    equals the one rosidl wrote into the installation's type description (a ``char`` field counts as uint8 there)."""
    prefix = ros2_interfaces.ensure_interfaces()
    folders = [Path(p) / "share" for p in ros2_interfaces.check_distribution().prefixes]
    folders += [prefix / "share"] if prefix is not None else []
    store = message_store()
    compared = []
    for typename in (*store.typenames, "rmw_dds_common/msg/ParticipantEntitiesInfo"):
        package, _, name = typename.partition("/msg/")
        found = [
            f / package / "msg" / f"{name}.json" for f in folders if (f / package / "msg" / f"{name}.json").is_file()
        ]
        if not found:
            continue  # a type this installation does not have (tf2_msgs' own are built: they are found)
        described = json.loads(found[0].read_text())
        hashes = {h["type_name"]: h["hash_string"] for h in described["type_hashes"]}
        assert hashes[typename] == store.rihs01(typename), typename
        compared.append(typename)
    assert {T.LASER_SCAN, T.ODOMETRY, T.TWIST, T.EPISODE_EVENT, "rmw_dds_common/msg/ParticipantEntitiesInfo"} <= set(
        compared
    )
