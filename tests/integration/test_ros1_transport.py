"""Two real processes talk through a real ROS 1 master (Debian's rosmaster and rospy) with the ros1 transport.

The peer is the loopback tests' echo peer on the ros1 backend in a child interpreter; the types on the wire
are ROS 1 Noetic's (name, md5sum, definition), checked against Debian's own message packages.
"""

from __future__ import annotations

import importlib
import io
import os
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline.messages import convert
from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.ros import NetworkSettings, open_transport
from pipeline.ros.errors import TransportError
from pipeline.ros.ros1 import decode, encode, free_port, ros1_message_module, wire_type
from tests.integration.test_transport_loopback import (
    Inbox,
    assert_stream_is_exact,
    echo_peer,
    echo_spec,
    expected_odom,
    expected_scan,
    wait_until,
)
from tests.peers import ros1

pytestmark = pytest.mark.integration


@pytest.fixture
def ns() -> str:
    return f"robot_r{os.getpid()}_{time.monotonic_ns() % 100000}"


def test_wire_types_are_ros1_noeticss_own(ros1_master: str) -> None:
    """Name, md5sum and definition as Debian's ROS 1 message packages have them, so roscpp and rospy nodes connect."""
    debian = {
        T.LASER_SCAN: "sensor_msgs:LaserScan",
        T.ODOMETRY: "nav_msgs:Odometry",
        T.POSE_STAMPED: "geometry_msgs:PoseStamped",
        T.TWIST: "geometry_msgs:Twist",
        T.CLOCK: "rosgraph_msgs:Clock",
    }
    for typename, where in debian.items():
        package, _, name = where.partition(":")
        cls = getattr(ros1_message_module(package), name)
        wire = wire_type(typename)
        assert (wire.ros1_name, wire.md5sum) == (cls._type, cls._md5sum), typename
    # the bytes are ROS 1's: Debian's genpy class reads what the transport sends, and the other way round
    scan = expected_scan("robot_1", 7)
    theirs = ros1_message_module("sensor_msgs").LaserScan().deserialize(encode(scan, T.LASER_SCAN))
    assert theirs.header.frame_id == "robot_1/laser" and theirs.header.seq == 0
    np.testing.assert_array_equal(np.asarray(theirs.ranges, dtype=np.float32), scan.ranges)
    buff = io.BytesIO()
    theirs.serialize(buff)
    assert message_store().serialize(decode(buff.getvalue(), T.LASER_SCAN), T.LASER_SCAN) == message_store().serialize(
        scan, T.LASER_SCAN
    )


def test_two_processes_exchange_sensor_data_and_commands(ros1_master: str, ns: str) -> None:
    topics = T.robot_topics(ns)
    inbox = Inbox()
    env = {"ROS_MASTER_URI": ros1_master, "ROS_LOG_DIR": os.environ.get("ROS_LOG_DIR", "/tmp")}
    with (
        echo_peer("ros1", 0, ns, env=env),
        open_transport("ros1", NetworkSettings(master_uri=ros1_master)) as transport,
    ):
        transport.subscribe(topics["scan"], inbox)
        transport.subscribe(topics["odom"], inbox)
        transport.subscribe(echo_spec(ns), inbox)
        cmd_pub = transport.publisher(topics["cmd_vel"])
        for spec in (topics["scan"], topics["odom"], topics["cmd_vel"], echo_spec(ns)):
            assert transport.wait_for_match(spec, 1, 10.0), spec.name
            assert transport.matched_count(spec) == 1
        ping = convert.twist(-1.0, -1.0)
        wait_until(
            lambda: bool(inbox.messages(echo_spec(ns).name)) or cmd_pub.publish(ping) or False, 5.0, "the first echo"
        )
        sent = [convert.twist(0.01 * i, -0.02 * i) for i in range(20)]
        for cmd in sent:
            cmd_pub.publish(cmd)
            time.sleep(0.005)
        wait_until(lambda: sent[-1] in inbox.messages(echo_spec(ns).name), 5.0, "the echo of 20 commands")
        assert [m for m in inbox.messages(echo_spec(ns).name) if m != ping] == sent, "complete, exact, in order"
        wait_until(lambda: len(inbox.messages(topics["scan"].name)) >= 20, 5.0, "20 scans")
        wait_until(lambda: len(inbox.messages(topics["odom"].name)) >= 20, 5.0, "20 odometry messages")
        # every sample names its writer: the peer's node, which accept_only can lock
        sub = transport.subscribe(topics["odom"], lambda *_: None)
        assert transport.wait_for_match(topics["odom"], 1, 5.0) and len(sub.writers()) == 1
    assert_stream_is_exact(inbox.messages(topics["scan"].name), expected_scan, ns, T.LASER_SCAN)
    assert_stream_is_exact(inbox.messages(topics["odom"].name), expected_odom, ns, T.ODOMETRY)


def test_a_topic_of_another_type_on_the_master_is_refused(ros1_master: str, ns: str) -> None:
    rosgraph = importlib.import_module("rosgraph")
    master = rosgraph.Master("/mrl_test_other", master_uri=ros1_master)
    master.registerPublisher(f"/{ns}/scan", "std_msgs/String", "http://127.0.0.1:1/")
    with (
        open_transport("ros1", NetworkSettings(master_uri=ros1_master)) as transport,
        pytest.raises(TransportError) as err,
    ):
        transport.subscribe(T.robot_topics(ns)["scan"], lambda *_: None)
    assert f"/{ns}/scan" in str(err.value) and "std_msgs/String" in str(err.value)
    assert "sensor_msgs/LaserScan" in str(err.value)


def test_a_master_that_does_not_answer_is_named(ros1_master: str) -> None:
    port = free_port()
    uri = f"http://127.0.0.1:{port}"
    with pytest.raises(TransportError) as err:
        open_transport("ros1", NetworkSettings(master_uri=uri))
    assert uri in str(err.value) and "does not answer" in str(err.value) and f"roscore -p {port}" in str(err.value)


def test_a_second_master_in_one_process_is_refused(ros1_master: str, tmp_path: Path) -> None:
    with open_transport("ros1", NetworkSettings(master_uri=ros1_master)):
        pass
    with ros1.master(tmp_path / "second") as other, pytest.raises(TransportError, match="one node per process"):
        open_transport("ros1", NetworkSettings(master_uri=other))
