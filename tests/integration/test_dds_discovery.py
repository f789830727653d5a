"""What the DDS transport announces on the network, how it leaves, and that it never hangs an exiting process."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading
import time
from typing import Any

import numpy as np
import pytest
from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription
from cyclonedds.core import Policy

from pipeline.messages import convert
from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.ros import NetworkSettings, open_transport
from pipeline.ros.dds import DdsTransport, parse_type_hash
from tests.integration.test_transport_loopback import ROOT, echo_peer, require_match, wait_until

pytestmark = pytest.mark.integration

_counter = iter(range(10**6))


@pytest.fixture
def domain_id() -> int:
    """A domain id of this run (40..99), different for every test."""
    return 40 + (os.getpid() * 7 + next(_counter)) % 60


@pytest.fixture
def ns() -> str:
    return f"robot_d{os.getpid()}_{next(_counter)}"


def remote_endpoints(transport: DdsTransport, builtin_topic: Any, topic_name: str) -> list[Any]:
    """Discovered endpoints of other participants on DDS topic `topic_name`."""
    reader = BuiltinDataReader(transport.participant, builtin_topic)
    own = transport.participant.guid
    return [
        e
        for e in reader.read(N=1000)
        if e.sample_info.valid_data and e.topic_name == topic_name and e.participant_key != own
    ]


def test_peer_endpoints_announce_ros_names_type_hash_and_xcdr1(domain_id: int, ns: str) -> None:
    topics = T.robot_topics(ns)
    with (
        echo_peer("dds", domain_id, ns),
        open_transport("dds", NetworkSettings(domain_id=domain_id)) as transport,
    ):
        assert isinstance(transport, DdsTransport)
        transport.subscribe(topics["scan"], lambda *_: None)
        transport.publisher(topics["cmd_vel"])
        require_match(transport, topics["scan"])
        require_match(transport, topics["cmd_vel"])
        found = {
            "writer": remote_endpoints(transport, BuiltinTopicDcpsPublication, "rt" + topics["scan"].name),
            "reader": remote_endpoints(transport, BuiltinTopicDcpsSubscription, "rt" + topics["cmd_vel"].name),
        }
    for kind, typename in (("writer", T.LASER_SCAN), ("reader", T.TWIST)):
        assert len(found[kind]) == 1, f"one remote {kind}"
        endpoint = found[kind][0]
        assert endpoint.type_name == message_store().dds_type_name(typename)
        user_data = endpoint.qos[Policy.Userdata].data
        assert user_data == f"typehash={message_store().rihs01(typename)};".encode()
        assert parse_type_hash(user_data) == message_store().rihs01(typename)
        assert endpoint.qos[Policy.DataRepresentation] == Policy.DataRepresentation(use_cdrv0_representation=True)
    assert found["writer"][0].qos[Policy.Reliability] == Policy.Reliability.BestEffort
    assert isinstance(found["reader"][0].qos[Policy.Reliability], Policy.Reliability.Reliable)


def test_closing_withdraws_endpoints_at_once(domain_id: int, ns: str) -> None:
    spec = T.robot_topics(ns)["cmd_vel"]
    settings = NetworkSettings(domain_id=domain_id)
    got: list[Any] = []
    with open_transport("dds", settings) as robot, open_transport("dds", settings) as planner:
        sub = robot.subscribe(spec, lambda _s, msg, _t: got.append(msg))
        pub = planner.publisher(spec)
        require_match(robot, spec)
        require_match(planner, spec)
        pub.publish(convert.twist(0.3, 0.1))
        wait_until(lambda: len(got) == 1, 2.0, "one command")
        pub.close()
        wait_until(lambda: robot.matched_count(spec) == 0, 1.0, "the closed writer to be unmatched")
        pub = planner.publisher(spec)
        require_match(robot, spec)
        planner.close()
        wait_until(lambda: robot.matched_count(spec) == 0, 1.0, "the closed transport to be unmatched")
    assert got == [convert.twist(0.3, 0.1)]
    assert sub.received == 1 and sub.callback_errors == 0


def test_open_transport_does_not_hang_interpreter_exit(domain_id: int, ns: str) -> None:
    code = textwrap.dedent(
        f"""
        from pipeline.messages import convert, topics as T
        from pipeline.ros import NetworkSettings, open_transport
        t = open_transport("dds", NetworkSettings(domain_id={domain_id}))
        spec = T.robot_topics({ns!r})["cmd_vel"]
        t.subscribe(spec, lambda *_: None)
        t.publisher(spec).publish(convert.twist(0.1, 0.0))
        print("LEAVING", flush=True)
        """
    )
    done = subprocess.run(  # a hanging exit fails by the timeout
        [sys.executable, "-c", code],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=20.0,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "LEAVING"


def test_a_receiver_that_stalls_loses_no_sensor_samples(domain_id: int, ns: str) -> None:
    """Odometry (best effort, depth 5 offered) while the receiving callback blocks for half a second: the reader
    keeps what arrives meanwhile (its own depth is READER_MIN_DEPTH), as a recorder must; with the writer's
    depth it kept the last 5 and lost the rest without a trace."""
    spec = T.robot_topics(ns)["odom"]
    settings = NetworkSettings(domain_id=domain_id)
    got: list[int] = []
    release = threading.Event()

    def slow(_spec: Any, msg: Any, _t: int) -> None:
        if not got:
            release.wait(5.0)  # the receive thread stalls on the first sample
        got.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)

    with open_transport("dds", settings) as planner, open_transport("dds", settings) as robot:
        planner.subscribe(spec, slow)
        pub = robot.publisher(spec)
        require_match(planner, spec)
        require_match(robot, spec)
        sent = []
        for k in range(60):
            stamp = 1_000_000_000 + k * 20_000_000
            pub.publish(convert.odometry(stamp, ns, np.array([0.01 * k, 0.0, 0.0]), (0.1, 0.0)))
            sent.append(stamp)
            time.sleep(0.005)
        time.sleep(0.2)
        release.set()
        wait_until(lambda: len(got) == len(sent), 3.0, "every odometry sample")
    assert got == sent
