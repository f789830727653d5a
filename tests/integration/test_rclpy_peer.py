"""The deploy runner (on Cyclone DDS or on rclpy) driving three robot drivers written as ordinary ROS 2 nodes in rclpy
(``tests/peers/rclpy_robot``, Fast DDS from the ros2 extra's wheels), over real discovery on loopback; and what a
ROS 2 tool sees of the runner through rclpy's graph API.

The tier skips where rclpy is not importable (``tests/peers/rclpy.missing``).
"""

from __future__ import annotations

import math
import os
import shutil
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

from pipeline.core.scenario import load_scenario
from pipeline.messages import convert as C
from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.messages.topics import QosProfile, TopicSpec
from pipeline.record import McapLog
from pipeline.ros import ros2_interfaces
from pipeline.ros.rclpy_transport import middleware_variables
from pipeline.ros.transport import NetworkSettings, open_transport
from tests.integration.conftest import free_domain_id
from tests.peers import drivers
from tests.peers import rclpy as peer

pytestmark = [
    pytest.mark.integration,
    pytest.mark.ros2,
    pytest.mark.skipif(peer.missing() is not None, reason=str(peer.missing())),
]

NAMESPACES = drivers.NAMESPACES


@pytest.mark.alone  # three rclpy nodes beside a second worker's test delay some commands past their validity
@pytest.mark.parametrize(
    ("transport", "naming"),
    [("dds", "option"), ("rclpy", "remap")],
    ids=["runner-on-cyclone-nodes-namespaced", "runner-on-rclpy-nodes-remapped"],
)
def test_the_runner_drives_rclpy_robot_nodes_through_whole_episodes(transport, naming, tiny_policy, tmp_path):
    recording, logs, results = peer.deploy_on_drivers(
        tiny_policy, tmp_path, episodes=2, domain=free_domain_id(), transport=transport, naming=naming
    )
    assert McapLog(recording).metadata()["session"]["transport"] == transport
    drivers.check_whole_episodes(recording, logs, results, episodes=2)


# -- what a ROS 2 tool sees ------------------------------------------------------------------------------------------


@contextmanager
def observer(domain: int) -> Iterator[Any]:
    """An rclpy node of its own context in `domain`, started with the middleware settings the robots have."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    context = Context()
    with middleware_variables(NetworkSettings(domain, loopback_only=True)):
        rclpy.init(context=context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node("graph_observer", context=context)
    try:
        yield node
    finally:
        node.destroy_node()
        context.try_shutdown()


def poll(what: Callable[[], Any], ready: Callable[[Any], bool], timeout_s: float) -> Any:
    """`what()` once `ready` holds of it, or its last value after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    value = what()
    while not ready(value) and time.monotonic() < deadline:
        time.sleep(0.1)
        value = what()
    return value


@pytest.mark.parametrize("transport", ["dds", "rclpy"])
def test_ros2_graph_shows_the_runner_endpoints_with_their_types_and_qos(transport, tiny_policy, tmp_path):
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    domain = free_domain_id()
    deployed: dict[str, Any] = {}
    # Jazzy's graph ties the Cyclone participant's endpoints to the node it announces; Kilted's (Fast DDS 3) lists that
    # node but leaves its endpoints unnamed, though their GUIDs are the ones announced
    ties_endpoints = transport == "rclpy" or ros2_interfaces.check_distribution().distribution == "jazzy"

    def deploy() -> None:
        try:
            deployed["out"] = peer.deploy_on_drivers(tiny_policy, tmp_path, 1, domain, transport, "option")
        except BaseException as exc:  # handed to the test's thread
            deployed["error"] = exc

    with observer(domain) as node:
        thread = threading.Thread(target=deploy, daemon=True)
        thread.start()

        def graph() -> tuple[dict[str, list[Any]], dict[str, list[Any]], list[tuple[str, str]]]:
            """(the runner's endpoints by topic, the robots' cmd_vel subscriptions, the nodes) as the graph has them."""
            runner, robots = {}, {}
            for ns in NAMESPACES:
                runner[f"/{ns}/cmd_vel"] = node.get_publishers_info_by_topic(f"/{ns}/cmd_vel")
                for topic in ("scan", "odom", "ground_truth"):
                    runner[f"/{ns}/{topic}"] = node.get_subscriptions_info_by_topic(f"/{ns}/{topic}")
                robots[ns] = node.get_subscriptions_info_by_topic(f"/{ns}/cmd_vel")
            return runner, robots, node.get_node_names_and_namespaces()

        def complete(found: tuple[dict[str, list[Any]], dict[str, list[Any]], list[tuple[str, str]]]) -> bool:
            runner, robots, _ = found
            # an endpoint is tied to its node once that node's participant has announced it (ros_discovery_info)
            named = [e.node_name for subs in robots.values() for e in subs]
            if ties_endpoints:
                named += [e.node_name for ends in runner.values() for e in ends]
            return all(runner.values()) and all(robots.values()) and not any(n.startswith("_") for n in named)

        seen, robots, nodes = poll(graph, complete, 60.0)
        thread.join(timeout=180.0)
    assert not thread.is_alive(), "the deployment did not end"
    if "error" in deployed:
        raise deployed["error"]
    assert not deployed["out"][2][0].aborted

    expected = {"cmd_vel": (T.TWIST, "reliable"), "scan": (T.LASER_SCAN, "best_effort")}
    expected |= {"odom": (T.ODOMETRY, "best_effort"), "ground_truth": (T.POSE_STAMPED, "best_effort")}
    runner_nodes = set()
    for topic, endpoints in seen.items():
        typename, reliability = expected[topic.rsplit("/", 1)[1]]
        assert len(endpoints) == 1, (topic, endpoints)  # the runner's only: the robots publish these, or take cmd_vel
        found = endpoints[0]
        assert found.topic_type == typename, topic
        assert str(found.topic_type_hash) == message_store().rihs01(typename), topic
        wanted = ReliabilityPolicy.RELIABLE if reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT
        assert found.qos_profile.reliability == wanted, topic
        assert found.qos_profile.durability == DurabilityPolicy.VOLATILE, topic
        runner_nodes.add((found.node_name, found.node_namespace))
    assert len(runner_nodes) == 1
    runner = runner_nodes.pop()
    for ns, subs in robots.items():  # the robot nodes' side of cmd_vel: reliable, so every command is delivered
        assert [(s.node_name, s.node_namespace) for s in subs] == [("robot_driver", f"/{ns}")]
        assert subs[0].qos_profile.reliability == ReliabilityPolicy.RELIABLE
    assert {(n, ns) for n, ns in nodes} >= {("robot_driver", f"/{ns}") for ns in NAMESPACES}
    # the runner is a ROS 2 node of this process on either transport: rclpy's own, or the node the Cyclone DDS
    # participant announces on ros_discovery_info as every RMW does
    assert any(n.startswith(f"mrl_transport_{os.getpid()}_") and ns == "/" for n, ns in nodes), nodes
    if ties_endpoints:
        assert runner[0].startswith(f"mrl_transport_{os.getpid()}_") and runner[1] == "/"
        assert runner in nodes
    else:  # Kilted's graph lists the Cyclone participant's node but does not tie its endpoints to it (see the docs)
        assert runner[0] == "_CREATED_BY_BARE_DDS_APP_"


# -- the node as a ROS 2 driver --------------------------------------------------------------------------------------

TF_STATIC = TopicSpec("/tf_static", T.TF_MESSAGE, QosProfile("reliable", "transient_local", 1))


@pytest.mark.parametrize("naming", ["option", "remap"])
def test_the_node_publishes_its_frames_stamps_on_its_clock_and_stops_when_commands_stop(naming, tmp_path):
    domain = free_domain_id()
    scenario = load_scenario("obstacles", 3)
    robot = peer.driver(domain, scenario, 0, "robot_1", tmp_path / "robot_1.log", naming)
    topics = T.robot_topics("robot_1")
    heard: dict[str, list[tuple[Any, int]]] = {"odom": [], "scan": [], "tf": [], "tf_static": []}

    def keep(key: str) -> Callable[[TopicSpec, Any, int], None]:
        return lambda spec, msg, receive_ns: heard[key].append((msg, receive_ns))

    robot.start()
    try:
        with open_transport("rclpy", NetworkSettings(domain)) as net:
            subs = [net.subscribe(topics[k], keep(k)) for k in ("odom", "scan")]
            subs.append(net.subscribe(T.FLEET_TOPICS["tf"], keep("tf")))
            time.sleep(1.0)  # /tf_static is transient local: a late subscriber still gets the laser's frame
            subs.append(net.subscribe(TF_STATIC, keep("tf_static")))
            cmd = net.publisher(topics["cmd_vel"])
            assert net.wait_for_match(topics["cmd_vel"], 1, 15.0)
            assert poll(lambda: len(heard["tf_static"]), bool, 10.0) == 1
            for _ in range(25):  # 0.5 s of driving, then silence
                cmd.publish(C.twist(0.3, 0.2))
                time.sleep(0.02)
            last_command_ns = time.time_ns()
            time.sleep(1.5)
            for sub in subs:
                sub.close()
    finally:
        robot.stop()

    ((static, _),) = heard["tf_static"]
    assert [(t.header.frame_id, t.child_frame_id) for t in static.transforms] == [
        ("robot_1/base_link", "robot_1/laser")
    ]
    assert {(t.header.frame_id, t.child_frame_id) for m, _ in heard["tf"] for t in m.transforms} == {
        ("robot_1/odom", "robot_1/base_link")
    }
    for key in ("odom", "scan"):  # stamped on the node's clock (system time here) when published
        lags = [(receive_ns - C.time_ns(m.header.stamp)) / 1e9 for m, receive_ns in heard[key]]
        assert heard[key] and min(lags) >= 0.0 and max(lags) < 0.5, key
    assert {m.header.frame_id for m, _ in heard["scan"]} == {"robot_1/laser"}
    odom = [(C.time_ns(m.header.stamp), m.twist.twist.linear.x, m.pose.pose.position.x) for m, _ in heard["odom"]]
    driving = [o for o in odom if o[0] < last_command_ns]
    stopped = [o for o in odom if o[0] > last_command_ns + 0.5e9 + 0.05e9]
    assert any(v == 0.3 for _, v, _ in driving), "the commanded velocity never reached the odometry"
    assert stopped and all(v == 0.0 for _, v, _ in stopped), "the robot went on after its commands stopped"
    assert len({x for _, _, x in stopped}) == 1, "the robot moved after its command timed out"
    assert max(x for _, _, x in odom) > 0.1


def _run_robot(folder: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = peer.environment(free_domain_id(), folder / "ros_log")
    return subprocess.run(
        [sys.executable, str(peer.ROBOT), "--start", "1,1,0", *args],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env=env,
        stdin=subprocess.DEVNULL,
    )


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--ns", "robot-1"], "'robot-1' (--ns)"),
        (["--ns", "1robot"], "'1robot' (--ns)"),
        (["--ros-args", "-r", "__ns:=/robot_1/"], "'/robot_1/' (__ns:=)"),
        (["--ros-args", "-r", "__ns:=robot_1"], "'robot_1' (__ns:=)"),
    ],
)
def test_a_namespace_that_is_not_a_ros_name_is_refused_in_one_line(args, named, tmp_path):
    done = _run_robot(tmp_path, *args)
    assert done.returncode == 2, done.stdout + done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert named in lines[0] and "letters, digits and '_'" in lines[0], lines[0]
    assert "ready" not in done.stdout


# -- the world is the C++ stand-ins' ---------------------------------------------------------------------------------


@pytest.mark.skipif(shutil.which("g++") is None, reason="comparing with robot_world.hpp needs g++")
def test_the_python_world_is_robot_world_hpp_bit_for_bit(tmp_path):
    """The same scans and poses, to the bit, as the C++ stand-ins' ray casting and unicycle."""
    source = tmp_path / "world.cpp"
    source.write_text(
        '#include "robot_world.hpp"\n'
        "int main(int argc, char** argv) {\n"
        "  robot_world::World w; std::string bad;\n"
        "  for (int i = 1; i + 1 < argc; i += 2) robot_world::world_flag(w, argv[i], argv[i + 1], bad);\n"
        "  robot_world::Unicycle body{w.x, w.y, w.yaw};\n"
        "  for (int k = 0; k < 4; ++k) {\n"
        '    for (float r : robot_world::scan_ranges(w, body.x, body.y, body.th)) std::printf("%a ", (double)r);\n'
        "    for (int s = 0; s < 400; ++s) body.step(w, 0.4, 0.3 * (k - 1), 0.005);\n"
        '    std::printf("\\n%a %a %a %a %a %a\\n", body.x, body.y, body.th, body.ox, body.oy, body.oth);\n'
        "  }\n"
        "}\n"
    )
    binary = tmp_path / "world"
    drivers.run(["g++", "-O2", "-std=c++17", f"-I{drivers.COMMON}", str(source), "-o", str(binary)], tmp_path)
    sys.path.insert(0, str(peer.SOURCE))
    try:
        from robot_world import Unicycle, World, scan_ranges, world_flag
    finally:
        sys.path.remove(str(peer.SOURCE))
    scenario = load_scenario("obstacles", 3)
    for index in range(3):
        args = drivers.world_args(scenario, index, NAMESPACES[index], tmp_path / "unused.log")
        lines = subprocess.run([str(binary), *args], capture_output=True, text=True, check=True).stdout.splitlines()
        world = World()
        for flag, value in zip(args[::2], args[1::2], strict=True):
            assert world_flag(world, flag, value)
        body = Unicycle(world.x_m, world.y_m, world.yaw_rad)
        for k in range(4):
            theirs = np.array([math.inf if r == "inf" else float.fromhex(r) for r in lines[2 * k].split()], np.float32)
            ours = scan_ranges(world, body.x, body.y, body.th)
            assert ours.dtype == np.float32 and ours.tobytes() == theirs.tobytes(), (index, k)
            for _ in range(400):
                body.step(world, 0.4, 0.3 * (k - 1), 0.005)
            pose = [float.fromhex(p) for p in lines[2 * k + 1].split()]
            assert [body.x, body.y, body.th, body.ox, body.oy, body.oth] == pose, (index, k)
