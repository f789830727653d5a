"""Topic names, message types and QoS of the ROS 2 contract, shared by transports and the recorder.

Per robot namespace ``ns`` (robot -> us unless noted):
``/<ns>/scan`` LaserScan, ``/<ns>/odom`` Odometry, ``/<ns>/ground_truth`` PoseStamped,
``/<ns>/cmd_vel`` Twist (us -> robot). Fleet-wide: ``/tf``, ``/clock``, the reset handshake
``/mrl/reset`` (us -> fleet) and ``/mrl/reset_done`` (fleet -> us), and the recorded-only
``/mrl/observation``, ``/mrl/action``, ``/mrl/episode``, ``/mrl/timing`` and ``/mrl/map`` (the room as markers).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

import yaml

Reliability = Literal["reliable", "best_effort"]
Durability = Literal["volatile", "transient_local"]

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TWIST = "geometry_msgs/msg/Twist"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
CLOCK = "rosgraph_msgs/msg/Clock"
OBSERVATION = "mrl_msgs/msg/Observation"
ACTION = "mrl_msgs/msg/Action"
EPISODE_EVENT = "mrl_msgs/msg/EpisodeEvent"
TIMING = "mrl_msgs/msg/Timing"
RESET_REQUEST = "mrl_msgs/msg/ResetRequest"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"


@dataclass(frozen=True)
class QosProfile:
    """The QoS a topic is offered with (history is always keep-last `depth`)."""

    reliability: Reliability
    durability: Durability
    depth: int

    def rosbag2_yaml(self) -> str:
        """The ``offered_qos_profiles`` text rosbag2 (Jazzy, metadata version 9) stores per channel."""
        profile = {
            "history": "keep_last",
            "depth": self.depth,
            "reliability": self.reliability,
            "durability": self.durability,
            "deadline": {"sec": 0, "nsec": 0},
            "lifespan": {"sec": 0, "nsec": 0},
            "liveliness": "automatic",
            "liveliness_lease_duration": {"sec": 0, "nsec": 0},
            "avoid_ros_namespace_conventions": False,
        }
        return str(yaml.safe_dump([profile], sort_keys=False))


QOS_SENSOR = QosProfile("best_effort", "volatile", 5)
"""Sensor data (scan, odom, ground truth, clock): best effort, like rclpy's sensor-data profile."""
QOS_COMMAND = QosProfile("reliable", "volatile", 10)
"""Commands (cmd_vel) and the reset handshake: reliable."""
QOS_EVENT = QosProfile("reliable", "volatile", 100)
"""/tf and the pipeline's own recorded topics: reliable with a deep queue."""


@dataclass(frozen=True)
class TopicSpec:
    """One topic: its ROS 2 name, message type, QoS, and the robot it belongs to ('' if fleet-wide)."""

    name: str
    typename: str
    qos: QosProfile
    robot: str = ""

    @property
    def dds_name(self) -> str:
        """The DDS topic name ROS 2 uses: ``rt`` + the ROS name."""
        return "rt" + self.name


def robot_topics(ns: str) -> dict[str, TopicSpec]:
    """The four topics of robot namespace `ns`, keyed scan, odom, ground_truth, cmd_vel."""
    return {
        "scan": TopicSpec(f"/{ns}/scan", LASER_SCAN, QOS_SENSOR, ns),
        "odom": TopicSpec(f"/{ns}/odom", ODOMETRY, QOS_SENSOR, ns),
        "ground_truth": TopicSpec(f"/{ns}/ground_truth", POSE_STAMPED, QOS_SENSOR, ns),
        "cmd_vel": TopicSpec(f"/{ns}/cmd_vel", TWIST, QOS_COMMAND, ns),
    }


TARGET_TRUTH = TopicSpec("/target/ground_truth", POSE_STAMPED, QOS_SENSOR, "target")
"""A pursuit's target pose from motion capture (the twin publishes it as a robot of its own would)."""

FLEET_TOPICS: dict[str, TopicSpec] = {
    "tf": TopicSpec("/tf", TF_MESSAGE, QOS_EVENT),
    "clock": TopicSpec("/clock", CLOCK, QOS_SENSOR),
    "reset": TopicSpec("/mrl/reset", RESET_REQUEST, QOS_COMMAND),
    "reset_done": TopicSpec("/mrl/reset_done", RESET_REQUEST, QOS_COMMAND),
    "observation": TopicSpec("/mrl/observation", OBSERVATION, QOS_EVENT),
    "action": TopicSpec("/mrl/action", ACTION, QOS_EVENT),
    "episode": TopicSpec("/mrl/episode", EPISODE_EVENT, QOS_EVENT),
    "timing": TopicSpec("/mrl/timing", TIMING, QOS_EVENT),
    "map": TopicSpec("/mrl/map", MARKER_ARRAY, QosProfile("reliable", "transient_local", 1)),
}


def fleet_topics(namespaces: Iterable[str]) -> dict[str, TopicSpec]:
    """Every topic of a fleet keyed by ROS topic name: per-robot topics, then fleet-wide ones."""
    out: dict[str, TopicSpec] = {}
    for ns in namespaces:
        out.update({spec.name: spec for spec in robot_topics(ns).values()})
    out.update({spec.name: spec for spec in FLEET_TOPICS.values()})
    return out
