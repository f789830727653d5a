"""A robot driver stand-in written the way a ROS 2 driver is: an ordinary rclpy node on the RMW rclpy loads (Fast DDS
from the ros2 extra's wheels).

The node ``robot_driver`` publishes, in its namespace, ``scan`` (sensor_msgs LaserScan, sensor-data QoS: best
effort), ``odom`` (nav_msgs Odometry, reliable, as a base controller offers it) and ``ground_truth``
(geometry_msgs PoseStamped, standing for motion capture), and ``/tf`` (odom -> base_link) and ``/tf_static``
(base_link -> laser, transient local) with frames prefixed by the namespace; it subscribes to ``cmd_vel``
(geometry_msgs Twist, reliable) and drives a unicycle by the latest command until the command is older than the
``cmd_vel_timeout`` parameter (0.5 s), when it stops. Timers on the node's clock publish the scan, the odometry and
the ground truth; every header stamp is the node's clock. Names, types and QoS are those of
:mod:`pipeline.messages.topics` (odometry offered reliable, which the pipeline's best-effort reader matches).

The namespace is ``--ns NAME`` or ROS 2's own remapping ``--ros-args -r __ns:=/NAME``; the domain and discovery are
the environment's (``ROS_DOMAIN_ID``, ``ROS_AUTOMATIC_DISCOVERY_RANGE``), as for any ROS 2 node. The other flags,
stdout and the log are those of the C++ stand-ins (``tests/peers/common/robot_world.hpp``, ported in
``robot_world.py``): stdout announces ``ready <ns>`` once the endpoints exist; stdin takes the operator's
``reset`` (answered ``reset <n>``) and ``quit``; ``--log FILE`` gets one line per command received (at the time the
RMW received it, from the message info) and per scan published. A bad flag or a namespace that is not a ROS name is
refused in one line on stderr, exit code 2.
"""

from __future__ import annotations

import array
import itertools
import math
import re
import sys
import threading
import time
from dataclasses import replace
from typing import NoReturn, TextIO

import rclpy
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, TransformStamped, Twist
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from robot_world import FlagError, Unicycle, World, log_command, log_scan, scan_ranges, world_flag
from sensor_msgs.msg import LaserScan
from tf2_msgs.msg import TFMessage

from pipeline.messages import topics as T
from pipeline.messages.topics import QosProfile

PROGRAM = "mrl_rclpy_robot"
NODE_NAME = "robot_driver"
USAGE = (
    f"usage: {PROGRAM} [--ns NAME] --start X,Y,YAW --room XMIN,YMIN,XMAX,YMAX [--box CX,CY,HALF_X,HALF_Y,YAW]... "
    "[--beams N] [--scan-hz F] [--odom-hz F] [--truth-hz F] [--log FILE] [--ros-args ...]"
)
NAMESPACE_RULE = "tokens of letters, digits and '_' separated by '/', none starting with a digit"
_TOKENS = r"[A-Za-z_][A-Za-z0-9_]*(?:/[A-Za-z_][A-Za-z0-9_]*)*"
_NS_OPTION = re.compile(rf"^/?{_TOKENS}$")
_NS_REMAP = re.compile(rf"^/(?:{_TOKENS})?$")
_REMAP_NS = re.compile(r"^(?:[^:]+:)?__ns:=(.*)$")
ODOM_QOS = replace(T.QOS_SENSOR, reliability="reliable")
"""The odometry's offered QoS: reliable, as diff_drive_controller offers it; it matches the contract's best-effort
reader (pipeline.messages.topics.QOS_SENSOR)."""
TF_STATIC_QOS = QosProfile("reliable", "transient_local", 1)
"""/tf_static as tf2_ros' StaticTransformBroadcaster offers it."""
CMD_VEL_TIMEOUT_S = 0.5
CMD_VEL_DEPTH = 100
"""The node's queue of commands not yet taken (2 s at the runner's 50 Hz; the contract's reliable QoS): on a loaded
host a Python executor can stall for hundreds of ms, and a queue of 10 would drop commands the log must show."""


def refuse(why: str) -> NoReturn:
    """One line on stderr, exit code 2."""
    print(f"{PROGRAM}: {why}", file=sys.stderr, flush=True)
    raise SystemExit(2)


def split_ros_args(args: list[str]) -> tuple[list[str], list[str]]:
    """(this program's arguments, the ROS arguments: every ``--ros-args ... [--]`` block, markers included)."""
    ours: list[str] = []
    ros: list[str] = []
    inside = False
    for arg in args:
        if arg == "--ros-args":
            inside = True
            ros.append(arg)
        elif inside and arg == "--":
            inside = False
            ros.append(arg)
        else:
            (ros if inside else ours).append(arg)
    return ours, ros


def remapped_namespace(ros_args: list[str]) -> str | None:
    """The value of the last ``-r [node:]__ns:=VALUE`` among the ROS arguments; None if there is none."""
    found = None
    for flag, rule in itertools.pairwise(ros_args):
        if flag in ("-r", "--remap"):
            match = _REMAP_NS.match(rule)
            if match:
                found = match.group(1)
    return found


def parse(args: list[str]) -> tuple[World, list[str]]:
    """The world of this program's flags and the ROS arguments; a bad one is refused (:func:`refuse`)."""
    ours, ros = split_ros_args(args)
    world = World()
    if "-h" in ours or "--help" in ours:
        print(USAGE)
        raise SystemExit(0)
    if len(ours) % 2:
        refuse(f"{ours[-1]} needs a value; {USAGE}")
    for flag, value in zip(ours[::2], ours[1::2], strict=True):
        try:
            known = world_flag(world, flag, value)
        except FlagError as exc:
            refuse(str(exc))
        if not known:
            refuse(f"unknown option {flag}; {USAGE}")
    if world.ns is not None and not _NS_OPTION.match(world.ns):
        refuse(f"namespace {world.ns!r} (--ns) is not a valid ROS namespace: {NAMESPACE_RULE}, e.g. robot_1")
    remapped = remapped_namespace(ros)
    if remapped is not None and not _NS_REMAP.match(remapped):
        refuse(
            f"namespace {remapped!r} (__ns:=) is not a valid ROS namespace: '/' then {NAMESPACE_RULE}, e.g. /robot_1"
        )
    return world, ros


def ros_qos(qos: QosProfile) -> QoSProfile:
    """rclpy's QoS profile of a contract's QoS (keep last `depth`)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=qos.depth,
        reliability=ReliabilityPolicy.RELIABLE if qos.reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if qos.durability == "transient_local"
        else DurabilityPolicy.VOLATILE,
    )


def stamp(t_ns: int) -> Time:
    return Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)


class RobotDriver(Node):
    """One robot: its sensors published on timers, its base driven by ``cmd_vel``, the operator's resets.

    Everything but the operator's thread runs on the executor's thread; the operator hands its requests over through
    guard conditions."""

    def __init__(self, world: World, log: TextIO | None, done: Future) -> None:
        super().__init__(NODE_NAME, namespace=world.ns.strip("/") if world.ns else None)
        self.world = world
        self.log = log
        self.done = done
        self.namespace = self.get_namespace().strip("/")
        prefix = f"{self.namespace}/" if self.namespace else ""
        self.odom_frame, self.base_frame, self.laser_frame = (f"{prefix}{f}" for f in ("odom", "base_link", "laser"))
        timeout_s = self.declare_parameter("cmd_vel_timeout", CMD_VEL_TIMEOUT_S).value
        self.cmd_timeout_ns = round(float(timeout_s) * 1e9)

        # the contract's types and QoS (the same in every namespace); its relative names resolve to the contract's
        contract = T.robot_topics(self.namespace or "root")
        for key, cls in (("scan", LaserScan), ("odom", Odometry), ("ground_truth", PoseStamped), ("cmd_vel", Twist)):
            assert f"{cls.__module__.partition('.')[0]}/msg/{cls.__name__}" == contract[key].typename, key
            assert not self.namespace or self.resolve_topic_name(key) == contract[key].name, key
        self.scan_pub = self.create_publisher(LaserScan, "scan", ros_qos(contract["scan"].qos))
        self.odom_pub = self.create_publisher(Odometry, "odom", ros_qos(ODOM_QOS))
        self.truth_pub = self.create_publisher(PoseStamped, "ground_truth", ros_qos(contract["ground_truth"].qos))
        self.tf_pub = self.create_publisher(TFMessage, T.FLEET_TOPICS["tf"].name, ros_qos(T.FLEET_TOPICS["tf"].qos))
        self.tf_static_pub = self.create_publisher(TFMessage, "/tf_static", ros_qos(TF_STATIC_QOS))
        cmd_qos = replace(contract["cmd_vel"].qos, depth=CMD_VEL_DEPTH)
        self.create_subscription(Twist, "cmd_vel", self.on_cmd_vel, ros_qos(cmd_qos))

        self.body = Unicycle(world.x_m, world.y_m, world.yaw_rad)
        self.command = (0.0, 0.0)
        self.expires_ns = 0
        """Node-clock time the command in force times out at."""
        self.time_ns = self.now_ns()
        """Node-clock time the body has moved up to."""
        self.scan = LaserScan()
        self.scan.header.frame_id = self.laser_frame
        self.scan.angle_min = -math.pi
        self.scan.angle_increment = 2 * math.pi / world.beams
        self.scan.angle_max = -math.pi + 2 * math.pi / world.beams * (world.beams - 1)
        self.scan.scan_time = 1.0 / world.scan_hz
        self.scan.time_increment = 1.0 / world.scan_hz / world.beams
        self.scan.range_min = world.range_min_m
        self.scan.range_max = world.range_max_m

        self.resets_asked = 0
        self.resets_lock = threading.Lock()
        self.reset_guard = self.create_guard_condition(self.on_reset)
        self.quit_guard = self.create_guard_condition(self.on_quit)
        self.publish_static_transform()
        self.create_timer(1.0 / world.scan_hz, self.publish_scan)
        self.create_timer(1.0 / world.odom_hz, self.publish_odom)
        self.create_timer(1.0 / world.truth_hz, self.publish_truth)

    def now_ns(self) -> int:
        return int(self.get_clock().now().nanoseconds)

    # -- the base ---------------------------------------------------------------------------------------------------

    def advance(self, now_ns: int) -> None:
        """Moves the body up to `now_ns` by the command in force, and by none once it has timed out."""
        while self.time_ns < now_ns:
            fresh = self.time_ns < self.expires_ns
            end = min(now_ns, self.expires_ns) if fresh else now_ns
            v, w = self.command if fresh else (0.0, 0.0)
            self.body.move(self.world, v, w, (end - self.time_ns) / 1e9)
            self.time_ns = end

    def in_force(self, now_ns: int) -> tuple[float, float]:
        return self.command if now_ns < self.expires_ns else (0.0, 0.0)

    def on_cmd_vel(self, msg: Twist, info: dict[str, int]) -> None:
        """A command (with its message info): it moves the body from now on, until it times out."""
        received_ns = int(info.get("received_timestamp", 0)) or time.time_ns()  # when the RMW took it in
        now = self.now_ns()
        self.advance(now)
        self.command = (msg.linear.x, msg.angular.z)
        self.expires_ns = now + self.cmd_timeout_ns
        if self.log is not None:
            log_command(self.log, received_ns, msg.linear.x, msg.angular.z)

    # -- the sensors ------------------------------------------------------------------------------------------------

    def publish_scan(self) -> None:
        now = self.now_ns()
        self.advance(now)
        ranges = scan_ranges(self.world, self.body.x, self.body.y, self.body.th)
        self.scan.header.stamp = stamp(now)
        self.scan.ranges = array.array("f", ranges.tobytes())
        self.scan_pub.publish(self.scan)
        if self.log is not None:
            log_scan(self.log, self.scan.header.stamp.sec, self.scan.header.stamp.nanosec, ranges)

    def publish_odom(self) -> None:
        now = self.now_ns()
        self.advance(now)
        v, w = self.in_force(now)
        odom = Odometry()
        odom.header.stamp = stamp(now)
        odom.header.frame_id = self.odom_frame
        odom.child_frame_id = self.base_frame
        odom.pose.pose.position.x = self.body.ox
        odom.pose.pose.position.y = self.body.oy
        odom.pose.pose.orientation.z = math.sin(self.body.oth / 2)
        odom.pose.pose.orientation.w = math.cos(self.body.oth / 2)
        odom.twist.twist.linear.x = v
        odom.twist.twist.angular.z = w
        self.odom_pub.publish(odom)
        transform = TransformStamped(header=odom.header, child_frame_id=self.base_frame)
        transform.transform.translation.x = self.body.ox
        transform.transform.translation.y = self.body.oy
        transform.transform.rotation = odom.pose.pose.orientation
        self.tf_pub.publish(TFMessage(transforms=[transform]))

    def publish_truth(self) -> None:
        now = self.now_ns()
        self.advance(now)
        pose = PoseStamped()
        pose.header.stamp = stamp(now)
        pose.header.frame_id = "map"
        pose.pose.position.x = self.body.x
        pose.pose.position.y = self.body.y
        pose.pose.orientation.z = math.sin(self.body.th / 2)
        pose.pose.orientation.w = math.cos(self.body.th / 2)
        self.truth_pub.publish(pose)

    def publish_static_transform(self) -> None:
        """base_link -> laser: the scan is cast from the body's centre."""
        transform = TransformStamped(child_frame_id=self.laser_frame)
        transform.header.stamp = stamp(self.now_ns())
        transform.header.frame_id = self.base_frame
        transform.transform.rotation.w = 1.0
        self.tf_static_pub.publish(TFMessage(transforms=[transform]))

    # -- the operator -----------------------------------------------------------------------------------------------

    def operator(self, stdin: TextIO) -> None:
        """The operator's lines (its own thread): ``reset`` puts the robot back at its start, ``quit`` (or the end of
        stdin) ends the node."""
        for line in stdin:
            if line.strip() == "reset":
                with self.resets_lock:
                    self.resets_asked += 1
                self.reset_guard.trigger()
            elif line.strip() == "quit":
                break
        self.quit_guard.trigger()

    def on_reset(self) -> None:
        with self.resets_lock:
            number = self.resets_asked
        self.body = Unicycle(self.world.x_m, self.world.y_m, self.world.yaw_rad)
        self.command = (0.0, 0.0)
        self.expires_ns = 0
        self.time_ns = self.now_ns()
        print(f"reset {number}", flush=True)

    def on_quit(self) -> None:
        if not self.done.done():
            self.done.set_result(True)


def main(argv: list[str] | None = None) -> int:
    world, ros_args = parse(sys.argv[1:] if argv is None else argv)
    log = open(world.log, "w", encoding="ascii") if world.log else None  # noqa: SIM115 (closed at the end of main)
    try:
        rclpy.init(args=[PROGRAM, *ros_args])
    except Exception as exc:  # rcl refuses ROS arguments it cannot parse with an RCLError
        refuse(f"ROS arguments {' '.join(ros_args)!r} refused: {str(exc).splitlines()[0]}")
    try:
        done = Future()
        node = RobotDriver(world, log, done)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        threading.Thread(target=node.operator, args=(sys.stdin,), daemon=True).start()
        print(f"ready {node.namespace or '/'}", flush=True)
        executor.spin_until_future_complete(done)
        executor.shutdown()
        node.destroy_node()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()
        if log is not None:
            log.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
