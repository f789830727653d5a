"""Behaviour every transport backend shares: refusals with clear errors, closing, in-process delivery.

Runs on the 'dds' backend everywhere, on 'ros1' where Debian's ROS 1 is installed (a private rosmaster for the
session) and on 'rclpy' where a ROS 2 installation provides it.
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from pipeline.messages import convert
from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.ros import NetworkSettings, Transport, TransportError, open_transport
from tests.domains import domain_id as run_domain_id

_domains = itertools.count()


@pytest.fixture(params=["dds", "ros1", pytest.param("rclpy", marks=pytest.mark.ros2)])
def transport(request: pytest.FixtureRequest) -> Iterator[Transport]:
    if request.param == "rclpy":
        from pipeline.ros.rclpy_transport import rclpy_missing

        if rclpy_missing() is not None:
            pytest.skip(str(rclpy_missing()))
    master = request.getfixturevalue("ros1_master") if request.param == "ros1" else ""
    domain_id = run_domain_id("contract", os.getpid() + next(_domains))
    with open_transport(request.param, NetworkSettings(domain_id=domain_id, master_uri=master)) as t:
        yield t


def wait_for(condition: Any, timeout_s: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


def test_publishing_another_type_names_topic_and_expected_type(transport: Transport) -> None:
    pub = transport.publisher(T.robot_topics("robot_1")["cmd_vel"])
    with pytest.raises(TransportError, match="/robot_1/cmd_vel: expected a geometry_msgs/msg/Twist message, got str"):
        pub.publish("forward")
    with pytest.raises(TransportError, match="Twist message, got geometry_msgs__msg__Vector3"):
        pub.publish(message_store().new("geometry_msgs/msg/Vector3", x=1.0, y=0.0, z=0.0))


def test_field_values_that_do_not_fit_are_refused_with_the_topic(transport: Transport) -> None:
    odom_pub = transport.publisher(T.robot_topics("robot_1")["odom"])
    odom = convert.odometry(1_000_000_000, "robot_1", np.array([1.0, 2.0, 0.5]))
    odom.pose.covariance = np.zeros(35)
    with pytest.raises(TransportError, match=r"/robot_1/odom: .*covariance"):
        odom_pub.publish(odom)
    twist_pub = transport.publisher(T.robot_topics("robot_1")["cmd_vel"])
    bad = convert.twist(0.1, 0.0)
    bad.linear.x = "fast"
    with pytest.raises(TransportError, match="/robot_1/cmd_vel: "):
        twist_pub.publish(bad)


def test_closed_endpoints_refuse_use_and_close_twice(transport: Transport) -> None:
    spec = T.robot_topics("robot_1")["cmd_vel"]
    pub = transport.publisher(spec)
    sub = transport.subscribe(spec, lambda *_: None)
    for endpoint in (pub, sub, pub, sub):
        endpoint.close()
    assert pub.closed and sub.closed
    with pytest.raises(TransportError, match="/robot_1/cmd_vel: cannot publish: the publisher is closed"):
        pub.publish(convert.twist(0.0, 0.0))
    with pytest.raises(TransportError, match="/robot_1/cmd_vel: this transport has no publisher or subscription"):
        transport.matched_count(spec)
    transport.close()
    transport.close()
    assert transport.closed
    with pytest.raises(TransportError, match="transport is closed"):
        transport.publisher(spec)


def test_subscribe_needs_a_callable_and_a_valid_topic(transport: Transport) -> None:
    with pytest.raises(TransportError, match="callback must be callable"):
        transport.subscribe(T.robot_topics("robot_1")["scan"], "print")  # type: ignore[arg-type]
    with pytest.raises(TransportError, match="fully qualified ROS 2 name"):
        transport.publisher(T.TopicSpec("scan", T.LASER_SCAN, T.QOS_SENSOR))


def test_in_process_delivery_on_the_transport_thread_with_wall_clock_receive_times(transport: Transport) -> None:
    spec = T.robot_topics("robot_1")["cmd_vel"]
    got: list[tuple[Any, int, str]] = []
    pub = transport.publisher(spec)
    sub = transport.subscribe(spec, lambda _s, msg, t_ns: got.append((msg, t_ns, threading.current_thread().name)))
    assert transport.matched_count(spec) == 0, "own endpoints are not remote matches"
    assert not transport.wait_for_match(spec, 1, timeout_s=0.05)
    before_ns = time.time_ns()
    assert wait_for(lambda: got or pub.publish(convert.twist(0.2, -0.1)) or False), "no local delivery within 2 s"
    msg, receive_ns, thread_name = got[0]
    assert msg == convert.twist(0.2, -0.1)
    assert before_ns <= receive_ns <= time.time_ns()
    assert thread_name != threading.main_thread().name
    assert sub.received >= 1 and sub.callback_errors == 0


def test_a_raising_callback_is_counted_and_delivery_goes_on(transport: Transport) -> None:
    spec = T.robot_topics("robot_1")["cmd_vel"]
    got: list[Any] = []

    def flaky(_spec: T.TopicSpec, msg: Any, _t: int) -> None:
        got.append(msg)
        if len(got) == 1:
            raise RuntimeError("first one fails")

    pub = transport.publisher(spec)
    sub = transport.subscribe(spec, flaky)
    assert wait_for(lambda: len(got) >= 2 or pub.publish(convert.twist(0.1, 0.0)) or False)
    assert sub.callback_errors == 1
