"""Numbers <-> messages: the one place that knows how poses, scans and commands sit in ROS 2 types.

Times are integer nanoseconds (``*_ns``) since the clock's epoch (Unix time on robots and the
twin at 1x, simulated time otherwise); poses are planar (x m, y m, yaw rad) in the ``map`` frame
(ground truth) or ``odom`` frame (odometry); frames of robot ``ns`` are ``<ns>/base_link``,
``<ns>/odom`` and ``<ns>/laser``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from pipeline.core.scan import ScanGeometry
from pipeline.core.timebase import NS_PER_S
from pipeline.messages import topics as T
from pipeline.messages.errors import MessageError
from pipeline.messages.store import MessageStore, message_store

_ZERO36 = np.zeros(36, dtype=np.float64)
_INT64_MAX = 2**63 - 1


def _store(store: MessageStore | None) -> MessageStore:
    return store if store is not None else message_store()


def stamp(t_ns: int, store: MessageStore | None = None) -> Any:
    """builtin_interfaces/Time of `t_ns` (floor to whole seconds, nanoseconds >= 0)."""
    sec, nanosec = divmod(int(t_ns), NS_PER_S)
    return _store(store).new("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)


def time_ns(t: Any) -> int:
    """Nanoseconds of a builtin_interfaces/Time."""
    return int(t.sec) * NS_PER_S + int(t.nanosec)


def header(t_ns: int, frame_id: str, store: MessageStore | None = None) -> Any:
    return _store(store).new("std_msgs/msg/Header", stamp=stamp(t_ns, store), frame_id=frame_id)


def yaw_quaternion(yaw_rad: float, store: MessageStore | None = None) -> Any:
    half = 0.5 * float(yaw_rad)
    return _store(store).new("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))


def quaternion_yaw(q: Any) -> float:
    """Yaw (rad) of a quaternion, in [-pi, pi]."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _pose(x_m: float, y_m: float, yaw_rad: float, store: MessageStore) -> Any:
    point = store.new("geometry_msgs/msg/Point", x=float(x_m), y=float(y_m), z=0.0)
    return store.new("geometry_msgs/msg/Pose", position=point, orientation=yaw_quaternion(yaw_rad, store))


def _vector(x: float, y: float, z: float, store: MessageStore) -> Any:
    return store.new("geometry_msgs/msg/Vector3", x=float(x), y=float(y), z=float(z))


def laser_scan(
    t_ns: int,
    frame_id: str,
    ranges_m: np.ndarray,
    geometry: ScanGeometry,
    scan_time_s: float = 0.1,
    store: MessageStore | None = None,
    time_increment_s: float | None = None,
) -> Any:
    """sensor_msgs/LaserScan of `ranges_m` (n_beams,) laid out as `geometry`; beams `time_increment_s` apart
    (by default spread evenly over `scan_time_s`; 0 for a scan taken at one instant)."""
    s = _store(store)
    n = geometry.n_beams
    return s.new(
        T.LASER_SCAN,
        header=header(t_ns, frame_id, s),
        angle_min=float(geometry.angle_min_rad),
        angle_max=float(geometry.angle_min_rad + geometry.angle_increment_rad * (n - 1)),
        angle_increment=float(geometry.angle_increment_rad),
        time_increment=float(scan_time_s / n if time_increment_s is None else time_increment_s),
        scan_time=float(scan_time_s),
        range_min=float(geometry.range_min_m),
        range_max=float(geometry.range_max_m),
        ranges=np.asarray(ranges_m, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def scan_geometry(msg: Any) -> ScanGeometry:
    """The angular layout and valid range of a LaserScan."""
    return ScanGeometry(
        n_beams=len(msg.ranges),
        angle_min_rad=float(msg.angle_min),
        angle_increment_rad=float(msg.angle_increment),
        range_min_m=float(msg.range_min),
        range_max_m=float(msg.range_max),
    )


def odometry(
    t_ns: int,
    ns: str,
    pose: np.ndarray,
    velocity: tuple[float, float] = (0.0, 0.0),
    store: MessageStore | None = None,
) -> Any:
    """nav_msgs/Odometry of robot `ns`: `pose` (x, y, yaw) in ``<ns>/odom``, body velocity (v m/s, w rad/s)."""
    s = _store(store)
    twist = s.new(T.TWIST, linear=_vector(velocity[0], 0.0, 0.0, s), angular=_vector(0.0, 0.0, velocity[1], s))
    return s.new(
        T.ODOMETRY,
        header=header(t_ns, f"{ns}/odom", s),
        child_frame_id=f"{ns}/base_link",
        pose=s.new(
            "geometry_msgs/msg/PoseWithCovariance",
            pose=_pose(float(pose[0]), float(pose[1]), float(pose[2]), s),
            covariance=_ZERO36.copy(),
        ),
        twist=s.new("geometry_msgs/msg/TwistWithCovariance", twist=twist, covariance=_ZERO36.copy()),
    )


def pose_stamped(t_ns: int, frame_id: str, pose: np.ndarray, store: MessageStore | None = None) -> Any:
    """geometry_msgs/PoseStamped of planar `pose` (x, y, yaw)."""
    s = _store(store)
    return s.new(
        T.POSE_STAMPED, header=header(t_ns, frame_id, s), pose=_pose(float(pose[0]), float(pose[1]), float(pose[2]), s)
    )


def planar_pose(pose: Any) -> np.ndarray:
    """(3,) x, y (m), yaw (rad) of a geometry_msgs/Pose."""
    return np.array([pose.position.x, pose.position.y, quaternion_yaw(pose.orientation)])


def twist(linear_mps: float, angular_radps: float, store: MessageStore | None = None) -> Any:
    """geometry_msgs/Twist of a planar command."""
    s = _store(store)
    return s.new(T.TWIST, linear=_vector(linear_mps, 0.0, 0.0, s), angular=_vector(0.0, 0.0, angular_radps, s))


def twist_command(msg: Any) -> tuple[float, float]:
    """(v m/s, w rad/s) of a Twist."""
    return float(msg.linear.x), float(msg.angular.z)


def tf_message(t_ns: int, transforms: list[tuple[str, str, np.ndarray]], store: MessageStore | None = None) -> Any:
    """tf2_msgs/TFMessage of planar transforms (parent frame, child frame, (x, y, yaw))."""
    s = _store(store)
    items = []
    for parent, child, pose in transforms:
        q = yaw_quaternion(float(pose[2]), s)
        tr = s.new("geometry_msgs/msg/Transform", translation=_vector(pose[0], pose[1], 0.0, s), rotation=q)
        head = header(t_ns, parent, s)
        items.append(s.new("geometry_msgs/msg/TransformStamped", header=head, child_frame_id=child, transform=tr))
    return s.new(T.TF_MESSAGE, transforms=items)


def clock(t_ns: int, store: MessageStore | None = None) -> Any:
    s = _store(store)
    return s.new(T.CLOCK, clock=stamp(t_ns, s))


def observation(
    t_ns: int, episode: int, step: int, robot: str, layout: str, values: np.ndarray, store: MessageStore | None = None
) -> Any:
    s = _store(store)
    return s.new(
        T.OBSERVATION,
        header=header(t_ns, robot, s),
        episode=int(episode),
        step=int(step),
        robot=robot,
        layout=layout,
        values=np.asarray(values, dtype=np.float32),
    )


def action(
    t_ns: int,
    episode: int,
    step: int,
    robot: str,
    policy_output: np.ndarray,
    command: tuple[float, float],
    store: MessageStore | None = None,
) -> Any:
    s = _store(store)
    return s.new(
        T.ACTION,
        header=header(t_ns, robot, s),
        episode=int(episode),
        step=int(step),
        robot=robot,
        policy_output=np.atleast_1d(np.asarray(policy_output, dtype=np.float32)),
        linear_mps=float(command[0]),
        angular_radps=float(command[1]),
    )


EVENT_CODES: dict[str, int] = {
    "start": 0,
    "goal": 1,
    "collision": 2,
    "timeout": 3,
    "success": 4,
    "abort": 5,
    "end": 6,
    "stale": 7,
    "fresh": 8,
}
EVENT_NAMES: dict[int, str] = {v: k for k, v in EVENT_CODES.items()}


NO_SEED = -1
"""The ``seed`` of an EpisodeEvent that is not a start, or whose episode's seed is unknown."""


def episode_event(
    t_ns: int,
    episode: int,
    step: int,
    event: str,
    robot: str = "",
    detail: str = "",
    store: MessageStore | None = None,
    seed: int = NO_SEED,
) -> Any:
    """mrl_msgs/EpisodeEvent; `event` is one of EVENT_CODES, `robot` empty for team-level events.

    `seed` is the episode's seed on ``start`` events (>= 0), NO_SEED on the others and when unknown.
    """
    seed = int(seed)
    if not NO_SEED <= seed <= _INT64_MAX:
        raise MessageError(T.EPISODE_EVENT, f"seed {seed} is out of range (0 to 2**63 - 1, or {NO_SEED}: none)")
    s = _store(store)
    return s.new(
        T.EPISODE_EVENT,
        header=header(t_ns, robot or "fleet", s),
        episode=int(episode),
        step=int(step),
        robot=robot,
        event=EVENT_CODES[event],
        detail=detail,
        seed=seed,
    )


TIMING_CODES: dict[str, int] = {"send": 0, "receive": 1, "tick": 2, "control": 3, "stale": 4}
TIMING_NAMES: dict[int, str] = {v: k for k, v in TIMING_CODES.items()}


def timing(
    t_ns: int,
    kind: str,
    robot: str,
    topic: str,
    source_stamp_ns: int,
    seq: int,
    tick: int,
    store: MessageStore | None = None,
) -> Any:
    """mrl_msgs/Timing of one send, receive, emitter tick or control step at local time `t_ns`."""
    s = _store(store)
    return s.new(
        T.TIMING,
        header=header(t_ns, robot or "fleet", s),
        kind=TIMING_CODES[kind],
        robot=robot,
        topic=topic,
        source_stamp_ns=int(source_stamp_ns),
        local_ns=int(t_ns),
        seq=int(seq),
        tick=int(tick),
    )


def reset_request(t_ns: int, episode: int, seed: int, done: bool, store: MessageStore | None = None) -> Any:
    s = _store(store)
    return s.new(T.RESET_REQUEST, header=header(t_ns, "fleet", s), episode=int(episode), seed=int(seed), done=done)


def _color(rgba: tuple[float, float, float, float], store: MessageStore) -> Any:
    r, g, b, a = (float(np.float32(c)) for c in rgba)  # float32 on the wire: keep exactly what is sent
    return store.new("std_msgs/msg/ColorRGBA", r=r, g=g, b=b, a=a)


ROBOT_RGBA: tuple[tuple[float, float, float, float], ...] = (
    (0.85, 0.2, 0.2, 1.0),
    (0.2, 0.45, 0.85, 1.0),
    (0.2, 0.7, 0.3, 1.0),
    (0.85, 0.6, 0.1, 1.0),
    (0.6, 0.3, 0.8, 1.0),
    (0.1, 0.7, 0.7, 1.0),
)


def map_markers(t_ns: int, scenario: Any, truth_frames: Sequence[str] = (), store: MessageStore | None = None) -> Any:
    """visualization_msgs/MarkerArray of a scenario in ``map``: walls, boxes, goal squares, and robot bodies.

    A robot body is a cylinder fixed to its frame in `truth_frames` (e.g. ``robot_1/ground_truth``),
    so it follows the robot wherever that frame is published.
    """
    s = _store(store)
    zero = s.new("builtin_interfaces/msg/Duration", sec=0, nanosec=0)
    image = s.new("sensor_msgs/msg/CompressedImage", header=header(t_ns, "", s), format="", data=np.zeros(0, np.uint8))
    mesh = s.new("visualization_msgs/msg/MeshFile", filename="", data=np.zeros(0, np.uint8))
    markers: list[Any] = []

    def marker(
        ns: str,
        kind: int,
        frame: str,
        pose: np.ndarray,
        size: tuple[float, float, float],
        z: float,
        rgba: tuple[float, float, float, float],
        locked: bool = False,
    ) -> None:
        p = _pose(float(pose[0]), float(pose[1]), float(pose[2]), s)
        p.position.z = z
        markers.append(
            s.new(
                "visualization_msgs/msg/Marker",
                header=header(t_ns, frame, s),
                ns=ns,
                id=len(markers),
                type=kind,
                action=0,
                pose=p,
                scale=_vector(*size, s),
                color=_color(rgba, s),
                lifetime=zero,
                frame_locked=locked,
                points=[],
                colors=[],
                texture_resource="",
                texture=image,
                uv_coordinates=[],
                text="",
                mesh_resource="",
                mesh_file=mesh,
                mesh_use_embedded_materials=False,
            )
        )

    room = scenario.room
    t, h = room.wall_thickness_m, room.wall_height_m
    cx, cy = (room.x_min_m + room.x_max_m) / 2, (room.y_min_m + room.y_max_m) / 2
    lx, ly = room.x_max_m - room.x_min_m + 2 * t, room.y_max_m - room.y_min_m + 2 * t
    grey = (0.5, 0.5, 0.5, 1.0)
    for x, y, sx, sy in (
        (cx, room.y_min_m - t / 2, lx, t),
        (cx, room.y_max_m + t / 2, lx, t),
        (room.x_min_m - t / 2, cy, t, ly),
        (room.x_max_m + t / 2, cy, t, ly),
    ):
        marker("walls", 1, "map", np.array([x, y, 0.0]), (sx, sy, h), h / 2, grey)
    for box in scenario.obstacles:
        pose = np.array([box.x_m, box.y_m, box.yaw_rad])
        marker(
            "boxes", 1, "map", pose, (box.size_x_m, box.size_y_m, box.height_m), box.height_m / 2, (0.9, 0.5, 0.1, 1.0)
        )
    g = scenario.goal_size_m
    for i, (gx, gy) in enumerate(scenario.goals):
        r, gg, b, _ = ROBOT_RGBA[i % len(ROBOT_RGBA)]
        marker("goals", 1, "map", np.array([gx, gy, 0.0]), (g, g, 0.01), 0.005, (r, gg, b, 0.4))
    for i, frame in enumerate(truth_frames):
        shape = scenario.shapes[i] if i < scenario.n_robots else scenario.robot
        radius, height = shape.radius_m, shape.height_m
        marker(
            "robots",
            3,
            frame,
            np.zeros(3),
            (2 * radius, 2 * radius, height),
            height / 2,
            ROBOT_RGBA[i % len(ROBOT_RGBA)],
            True,
        )
    return s.new("visualization_msgs/msg/MarkerArray", markers=markers)
