"""Two real processes talk over loopback through the transport: values, matches, QoS rules, a killed peer.

The peer is :func:`run_echo_peer` in a child interpreter: it publishes LaserScan and Odometry
(best effort) built from a sequence number, and echoes every Twist it receives on
``/<ns>/cmd_vel`` (reliable) back on ``/<ns>/cmd_echo`` (reliable). Each test uses its own topic
namespace and domain id, so parallel runs on one host do not cross-talk. The same tests run on
every backend; the rclpy ones skip where rclpy is not installed.
"""

from __future__ import annotations

import itertools
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pipeline.core.scan import ScanGeometry
from pipeline.messages import convert
from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.ros import NetworkSettings, Transport, open_transport
from tests.domains import domain_id as run_domain_id

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
N_BEAMS = 360
PERIOD_NS = 10_000_000  # the peer publishes at 100 Hz
T0_NS = 1_700_000_000_000_000_000
GEOMETRY = ScanGeometry(
    n_beams=N_BEAMS,
    angle_min_rad=-math.pi,
    angle_increment_rad=2 * math.pi / N_BEAMS,
    range_min_m=0.05,
    range_max_m=8.0,
)
SHORT_LEASE = (
    '<CycloneDDS><Domain Id="any"><Discovery><LeaseDuration>1 s</LeaseDuration></Discovery></Domain></CycloneDDS>'
)
_runs = itertools.count()


def echo_spec(ns: str) -> T.TopicSpec:
    return T.TopicSpec(f"/{ns}/cmd_echo", T.TWIST, T.QOS_COMMAND, ns)


def expected_scan(ns: str, seq: int) -> Any:
    ranges = (0.05 + ((np.arange(N_BEAMS) + seq) % 700) * 0.01).astype(np.float32)
    return convert.laser_scan(T0_NS + seq * PERIOD_NS, f"{ns}/laser", ranges, GEOMETRY)


def expected_odom(ns: str, seq: int) -> Any:
    pose = np.array([0.001 * seq, -0.002 * seq, math.remainder(0.01 * seq, 2 * math.pi)])
    return convert.odometry(T0_NS + seq * PERIOD_NS, ns, pose, (0.1 + 1e-4 * seq, -0.05))


def sequence_number(msg: Any) -> int:
    return (convert.time_ns(msg.header.stamp) - T0_NS) // PERIOD_NS


def run_echo_peer(backend: str, domain_id: int, ns: str, limit_s: float = 30.0) -> None:
    """The child process: publish scans and odometry until stdin closes, echo every command."""
    topics = T.robot_topics(ns)
    stop = threading.Event()

    def watch_stdin() -> None:
        sys.stdin.read()
        stop.set()

    threading.Thread(target=watch_stdin, daemon=True).start()
    with open_transport(backend, NetworkSettings(domain_id=domain_id)) as transport:  # type: ignore[arg-type]
        scan_pub = transport.publisher(topics["scan"])
        odom_pub = transport.publisher(topics["odom"])
        echo_pub = transport.publisher(echo_spec(ns))
        transport.subscribe(topics["cmd_vel"], lambda _spec, msg, _t: echo_pub.publish(msg))
        print("READY", flush=True)
        end = time.monotonic() + limit_s
        for seq in itertools.count():
            if stop.is_set() or time.monotonic() > end:
                break
            scan_pub.publish(expected_scan(ns, seq))
            odom_pub.publish(expected_odom(ns, seq))
            time.sleep(PERIOD_NS / 1e9)


@contextmanager
def echo_peer(
    backend: str, domain_id: int, ns: str, env: dict[str, str] | None = None
) -> Iterator[subprocess.Popen[str]]:
    """Starts :func:`run_echo_peer` in a child interpreter and waits until its endpoints exist."""
    code = (
        "from tests.integration.test_transport_loopback import run_echo_peer; "
        f"run_echo_peer({backend!r}, {domain_id}, {ns!r})"
    )
    child_env = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    proc = subprocess.Popen(
        [sys.executable, "-c", code],
        cwd=ROOT,
        env=child_env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        ready: list[str] = []
        reader = threading.Thread(target=lambda: ready.append(proc.stdout.readline() if proc.stdout else ""))
        reader.start()
        reader.join(timeout=15.0)
        if not ready or ready[0].strip() != "READY":
            proc.kill()
            _, err = proc.communicate(timeout=5.0)
            pytest.fail(f"the {backend} echo peer did not start within 15 s; its stderr:\n{err}")
        yield proc
    finally:
        if proc.poll() is None:
            assert proc.stdin is not None
            proc.stdin.close()
            try:
                proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5.0)


@pytest.fixture(params=["dds", pytest.param("rclpy", marks=pytest.mark.ros2)])
def backend(request: pytest.FixtureRequest) -> str:
    if request.param == "rclpy":
        from pipeline.ros.rclpy_transport import rclpy_missing

        if rclpy_missing() is not None:
            pytest.skip(str(rclpy_missing()))
    return str(request.param)


@pytest.fixture
def domain_id() -> int:
    """A domain id of this run (40..99, this worker's share), different for every test."""
    return run_domain_id("loopback", os.getpid() + next(_runs))


@pytest.fixture
def ns() -> str:
    """A robot namespace used by this test only."""
    return f"robot_t{os.getpid()}_{next(_runs)}"


def wait_until(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.005)


def require_match(transport: Transport, spec: T.TopicSpec, count: int = 1, timeout_s: float = 5.0) -> None:
    if not transport.wait_for_match(spec, count, timeout_s):
        pytest.fail(
            f"{spec.name}: {transport.matched_count(spec)} remote endpoint(s) matched after {timeout_s} s, "
            f"expected {count} (discovery on loopback failed)"
        )


class Inbox:
    """Collects (msg, receive_time_ns) per topic from subscription callbacks."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.items: dict[str, list[tuple[Any, int]]] = {}

    def __call__(self, spec: T.TopicSpec, msg: Any, receive_time_ns: int) -> None:
        with self.lock:
            self.items.setdefault(spec.name, []).append((msg, receive_time_ns))

    def messages(self, name: str) -> list[Any]:
        with self.lock:
            return [m for m, _ in self.items.get(name, [])]


def assert_stream_is_exact(msgs: list[Any], build: Callable[[str, int], Any], ns: str, typename: str) -> None:
    store = message_store()
    seqs = [sequence_number(m) for m in msgs]
    assert seqs == sorted(set(seqs)), "samples arrive once each and in order"
    for msg, seq in zip(msgs, seqs, strict=True):
        assert msg is not None and type(msg) is store.cls(typename)
        assert store.serialize(msg, typename) == store.serialize(build(ns, seq), typename), f"sample {seq}"


def test_two_processes_exchange_sensor_data_and_commands(backend: str, domain_id: int, ns: str) -> None:
    topics = T.robot_topics(ns)
    inbox = Inbox()
    with (
        echo_peer(backend, domain_id, ns),
        open_transport(backend, NetworkSettings(domain_id=domain_id)) as transport,  # type: ignore[arg-type]
    ):
        transport.subscribe(topics["scan"], inbox)
        transport.subscribe(topics["odom"], inbox)
        transport.subscribe(echo_spec(ns), inbox)
        cmd_pub = transport.publisher(topics["cmd_vel"])
        for spec in (topics["scan"], topics["odom"], topics["cmd_vel"], echo_spec(ns)):
            require_match(transport, spec)
            assert transport.matched_count(spec) == 1

        # a reliable command reaches the peer once its reader knows our writer: ping until the echo
        ping = convert.twist(-1.0, -1.0)
        wait_until(
            lambda: bool(inbox.messages(echo_spec(ns).name)) or cmd_pub.publish(ping) or False,
            5.0,
            "the first command echo",
        )
        sent = [convert.twist(0.01 * i, -0.02 * i) for i in range(20)]
        for cmd in sent:  # paced like the emitter; a burst beyond the keep-last depth may drop old ones
            cmd_pub.publish(cmd)
            time.sleep(0.005)
        echo_name = echo_spec(ns).name
        wait_until(lambda: sent[-1] in inbox.messages(echo_name), 5.0, "the echo of 20 commands")
        echoed = [m for m in inbox.messages(echo_name) if m != ping]
        assert echoed == sent, "reliable commands arrive complete, exact and in order"

        wait_until(lambda: len(inbox.messages(topics["scan"].name)) >= 20, 5.0, "20 scans")
        wait_until(lambda: len(inbox.messages(topics["odom"].name)) >= 20, 5.0, "20 odometry messages")
    assert_stream_is_exact(inbox.messages(topics["scan"].name), expected_scan, ns, T.LASER_SCAN)
    assert_stream_is_exact(inbox.messages(topics["odom"].name), expected_odom, ns, T.ODOMETRY)
    assert inbox.messages(topics["scan"].name)[0].ranges.dtype == np.float32


def test_reliable_reader_does_not_match_a_best_effort_writer(backend: str, domain_id: int, ns: str) -> None:
    scan = T.robot_topics(ns)["scan"]
    reliable_scan = T.TopicSpec(scan.name, scan.typename, T.QOS_COMMAND, ns)
    best_effort_echo = T.TopicSpec(echo_spec(ns).name, T.TWIST, T.QOS_SENSOR, ns)
    matching, mismatched = Inbox(), Inbox()
    settings = NetworkSettings(domain_id=domain_id)
    with (
        echo_peer(backend, domain_id, ns),
        open_transport(backend, settings) as plain,  # type: ignore[arg-type]
        open_transport(backend, settings) as strict,  # type: ignore[arg-type]
    ):
        plain.subscribe(scan, matching)
        plain.subscribe(best_effort_echo, matching)
        strict.subscribe(reliable_scan, mismatched)
        # DDS request/offered rule: a best-effort reader matches a reliable writer...
        require_match(plain, scan)
        require_match(plain, best_effort_echo)
        # ...and a reliable reader never matches a best-effort writer, although the topic is live
        wait_until(lambda: len(matching.messages(scan.name)) >= 20, 5.0, "20 scans on the best-effort reader")
        assert not strict.wait_for_match(reliable_scan, 1, timeout_s=0.5)
        assert strict.matched_count(reliable_scan) == 0
        assert mismatched.messages(scan.name) == []


def test_killed_peer_delivers_no_invalid_samples(backend: str, domain_id: int, ns: str) -> None:
    topics = T.robot_topics(ns)
    inbox = Inbox()
    seen: list[Any] = []

    def record(spec: T.TopicSpec, msg: Any, receive_time_ns: int) -> None:
        seen.append(msg)
        inbox(spec, msg, receive_time_ns)

    # a short participant lease (Cyclone DDS) makes the survivor notice the death within about a second
    with (
        echo_peer(backend, domain_id, ns, env={"CYCLONEDDS_URI": SHORT_LEASE}) as peer,
        open_transport(backend, NetworkSettings(domain_id=domain_id)) as transport,  # type: ignore[arg-type]
    ):
        subs = [transport.subscribe(topics["scan"], record), transport.subscribe(topics["odom"], record)]
        require_match(transport, topics["scan"])
        require_match(transport, topics["odom"])
        wait_until(lambda: len(inbox.messages(topics["odom"].name)) >= 10, 5.0, "10 odometry messages")
        peer.send_signal(signal.SIGKILL)
        peer.wait(timeout=5.0)
        if backend == "dds" or os.environ.get("RMW_IMPLEMENTATION") == "rmw_cyclonedds_cpp":
            wait_until(lambda: transport.matched_count(topics["scan"]) == 0, 8.0, "the killed peer to be unmatched")
            wait_until(lambda: transport.matched_count(topics["odom"]) == 0, 2.0, "the killed peer to be unmatched")
        else:  # other RMWs keep their own lease (Fast DDS: 20 s); watch the first second after the kill
            time.sleep(1.0)
        time.sleep(0.2)  # let the receive thread take whatever the unmatching produced
        if backend == "dds":
            assert sum(s.dropped_invalid for s in subs) >= 1, "DDS announced the vanished writers"
        assert all(s.callback_errors == 0 for s in subs)
    assert all(msg is not None for msg in seen)
    assert_stream_is_exact(inbox.messages(topics["scan"].name), expected_scan, ns, T.LASER_SCAN)
    assert_stream_is_exact(inbox.messages(topics["odom"].name), expected_odom, ns, T.ODOMETRY)
