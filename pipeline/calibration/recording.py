"""Reading a session recording into the arrays calibration needs, on one clock.

Per robot namespace ``ns``: ``/<ns>/ground_truth`` (PoseStamped), ``/<ns>/scan`` (LaserScan),
``/<ns>/odom`` (Odometry) and ``/<ns>/cmd_vel`` (Twist, logged when sent); ``/mrl/episode``
delimits episodes when present: the windows of :mod:`pipeline.record.episodes` that ended (finished
or aborted) and the one the file stops inside, cut at the last message read. A window that a new
start cut short is left out: the reset before that start lies somewhere inside it, unmarked.

A recording without ``/mrl/episode`` (a plain ``ros2 bag record``) has its episodes inferred from
the data: a reset puts the robots back at their starts and restarts their odometry, which shows
as a jump of the ground-truth and odometry poses that no motion could produce between two
messages (see :func:`pose_jumps`); jumps on at least `RESET_MIN_STREAMS` streams within
`RESET_CLUSTER_S` of each other are one reset (see :func:`reset_boundaries`). A single stream's
jump is not: a motion-capture glitch, or one robot's odometry restarting (which the odometry
estimate handles by not comparing across it). A reset that moves no robot by `RESET_MIN_JUMP_M`
nor turns one by `RESET_MIN_TURN_RAD` cannot be seen, and its two episodes stay one.

Times: everything is put on the recorder's clock (MCAP log time, int ns). Commands are logged
when sent, so their log time is used as is. Sensor messages carry the sender's stamp, which is
when the data were true; each sensor topic's stamps are moved onto the recorder's clock by the
smallest delivery delay observed on it (the 2nd percentile of log time minus stamp), i.e. the
quickest messages are taken to have arrived without delay. This also maps robot or
motion-capture clocks that are not synchronised with the recorder.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from tqdm import tqdm

from pipeline.calibration.errors import CalibrationError, ScenarioMismatchError
from pipeline.calibration.options import Part
from pipeline.core.scenario import Scenario, load_scenario
from pipeline.core.timebase import NS_PER_S
from pipeline.errors import MrlError
from pipeline.mappings import to_mapping
from pipeline.messages.convert import quaternion_yaw
from pipeline.record import McapLog
from pipeline.record import episodes as recorded_episodes
from pipeline.record.errors import MissingTopicError
from pipeline.record.session import SessionInfo, session_info

OFFSET_QUANTILE = 2.0
"""Percentile of (log time - stamp) taken as a sensor topic's clock offset (the quickest deliveries)."""
OUTLIER_S = 10.0
"""Messages whose (log time - stamp) lies this far from the topic's median are not used (a clock not yet running)."""

RESET_MIN_JUMP_M = 0.2
"""A pose that moved at least this far from the previous message's..."""
RESET_MIN_SPEED_MPS = 1.0
"""...at an implied speed of at least this (twice the ~0.5 m/s top speed of the robots this pipeline targets) jumped."""
RESET_MIN_TURN_RAD = 0.5
"""So did one whose heading changed by at least this..."""
RESET_MIN_YAW_RATE_RADPS = 4.0
"""...at an implied yaw rate of at least this."""
RESET_CLUSTER_S = 0.5
"""Jumps on different streams within this time of the first are one reset."""
RESET_MIN_STREAMS = 2
"""A reset shows on at least this many streams (robot and topic: ground truth or odometry)."""

PoseSourceKind = Literal["ground_truth", "scans"]

TOPICS_FOR: dict[Part, tuple[str, ...]] = {
    "lidar": ("ground_truth", "scan"),
    "actuation": ("ground_truth", "cmd_vel"),
    "odometry": ("ground_truth", "odom"),
    "network": ("ground_truth",),
}
"""Per-robot topics (``/<ns>/<kind>``) each part of the calibration needs."""


@dataclass(frozen=True)
class MessageTimes:
    """Times of one sensor topic's messages (n,), int ns: on the recorder's clock, stamped, and received."""

    t_ns: np.ndarray
    stamp_ns: np.ndarray
    log_ns: np.ndarray
    offset_ns: int


@dataclass(frozen=True)
class PoseSeries:
    """Planar poses (n, 3) x, y (m), yaw (rad) with their times; `velocity` (n, 2) v (m/s), w (rad/s) if sent."""

    time: MessageTimes
    pose: np.ndarray
    velocity: np.ndarray | None = None


@dataclass(frozen=True)
class ScanSeries:
    """Scans: ranges (n, beams) in metres as sent; beam k of scan i points at angle_min[i] + k angle_increment[i]."""

    time: MessageTimes
    ranges: np.ndarray
    angle_min_rad: np.ndarray
    angle_increment_rad: np.ndarray
    range_min_m: np.ndarray
    range_max_m: np.ndarray

    @property
    def beams(self) -> int:
        return int(self.ranges.shape[1])


@dataclass(frozen=True)
class CommandSeries:
    """Velocity commands as sent: `t_ns` (n,) send times, `v` (n,) m/s, `w` (n,) rad/s."""

    t_ns: np.ndarray
    v: np.ndarray
    w: np.ndarray


@dataclass(frozen=True)
class RobotData:
    """One robot's recorded streams (None where the recording lacks the topic)."""

    name: str
    truth: PoseSeries | None
    scans: ScanSeries | None
    odom: PoseSeries | None
    commands: CommandSeries | None
    lidar_mount: tuple[float, float, float] | None = None
    """The laser's pose (x, y, yaw) on the base from the recording's ``/tf_static``, when it has one."""


@dataclass(frozen=True)
class EpisodeTimes:
    """One episode: recorder-clock times (ns) of its start event and of its end (the event that closed it, else
    the last message read), and its seed if recorded."""

    episode: int
    start_ns: int
    end_ns: int
    seed: int | None = None


@dataclass(frozen=True)
class SessionData:
    """A recording as calibration reads it.

    `has_episode_topic` is False when the episodes were inferred from the data (see the module's
    description); `notes` then say how.
    """

    path: Path
    session: SessionInfo
    scenario: Scenario
    robots: tuple[RobotData, ...]
    episodes: tuple[EpisodeTimes, ...]
    has_episode_topic: bool
    notes: tuple[str, ...] = ()
    followed_clock: tuple[np.ndarray, np.ndarray] | None = None
    """(values, log times) int ns of the ``/clock`` messages the recorder followed (a time-scaled fleet), else None."""
    pose_source: PoseSourceKind = "ground_truth"
    """Where the robots' poses (`truth`) come from: motion capture, or scans and odometry (localized by the caller)."""
    salvage: str = ""
    """What salvaging a damaged file lost, in words; '' for a file read as written."""

    @property
    def kind(self) -> str:
        """What the recording is of: ``sim`` (the simulator), ``twin`` (the hardware twin) or ``real`` (robots, or a
        bag recorded elsewhere)."""
        if self.session.world == "sim":
            return "sim"
        return "twin" if self.session.fields.get("target") == "twin" else "real"

    @property
    def windows(self) -> list[tuple[int, int]]:
        return [(e.start_ns, e.end_ns) for e in self.episodes]


def _robots(log: McapLog, session: SessionInfo) -> tuple[str, ...]:
    if session.robots:
        return session.robots
    topics = log.topics()
    found = sorted({t.split("/")[1] for t in topics if t.count("/") == 2 and t.endswith("/ground_truth")})
    if not found:
        found = sorted({t.split("/")[1] for t in topics if t.count("/") == 2 and t.endswith("/scan")})
    return tuple(found)


def recorded_scenario(
    log: McapLog, expected: str | Path | Scenario | None, fallback: Scenario | None = None
) -> Scenario:
    """The scenario of a recording (its ``scenario`` document, else the bundled one its session names).

    With `expected`, a recording of another scenario raises ScenarioMismatchError; a recording that
    names no scenario uses `expected`, else `fallback` (the stand-in of a map given without a scenario).
    """
    where = str(log.path)
    try:
        recorded = session_info(log.metadata()).load_scenario()
    except (MrlError, ValueError, TypeError) as exc:
        raise CalibrationError(where, f"the recorded scenario cannot be loaded: {exc}") from exc
    wanted: Scenario | None = None
    if expected is not None:
        try:
            wanted = load_scenario(expected)
        except MrlError as exc:
            raise CalibrationError(where, f"the scenario asked for cannot be loaded: {exc}") from exc
    if recorded is None:
        if wanted is None and fallback is not None:
            return fallback
        if wanted is None:
            raise CalibrationError(
                where, "the recording names no scenario (no 'scenario' metadata); pass the scenario it was made in"
            )
        return wanted
    if recorded.layouts is not None:
        raise CalibrationError(
            where,
            f"scenario {recorded.name!r} draws a layout per episode; calibration fits the lidar and the map against "
            "one layout and cannot use this recording yet (record a scenario without layouts ranges)",
        )
    if wanted is not None:
        if recorded.name != wanted.name:
            raise ScenarioMismatchError(where, recorded.name, wanted.name)
        if to_mapping(recorded) != to_mapping(wanted):
            raise CalibrationError(
                where, f"the recording's scenario {recorded.name!r} differs from the scenario of that name asked for"
            )
    return recorded


def _stamped(log_ns: list[int], stamp_ns: list[int], windows: Sequence[tuple[int, int]]) -> MessageTimes:
    log = np.asarray(log_ns, dtype=np.int64)
    stamp = np.asarray(stamp_ns, dtype=np.int64)
    if len(log) == 0:
        return MessageTimes(log, stamp, log, 0)
    delay = log - stamp
    good = np.abs(delay - np.median(delay)) < OUTLIER_S * NS_PER_S
    inside = np.zeros(len(log), dtype=bool)
    for start, end in windows:
        inside |= (log >= start) & (log <= end)
    use = good & inside if (good & inside).sum() >= 10 else good
    offset = int(np.percentile(delay[use], OFFSET_QUANTILE))
    return MessageTimes(stamp + offset, stamp, log, offset)


def _episodes(windows: Sequence[recorded_episodes.EpisodeWindow], last_ns: int, where: str) -> list[EpisodeTimes]:
    """The recorded windows calibration uses (see the module's description); the one the file stops inside ends at
    `last_ns`, the last log time read."""
    out = [
        EpisodeTimes(w.episode, w.start_ns, max(w.start_ns, last_ns) if w.end_ns is None else w.end_ns, w.seed)
        for w in windows
        if w.outcome != "unfinished" or w.end_ns is None
    ]
    if not out:
        raise CalibrationError(
            where, "topic /mrl/episode holds no episode to calibrate with: the next start cut every one short"
        )
    return out


@dataclass(frozen=True)
class PoseJump:
    """A discontinuity of one stream (e.g. ``/robot_1/odom``): the times (int ns) of the poses before and after it."""

    stream: str
    before_ns: int
    after_ns: int


def pose_jumps(t_ns: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Indices i of poses (n, 3) (x m, y m, yaw rad) at sorted times `t_ns` (n,) that no motion reaches from pose i - 1.

    A jump moves by at least RESET_MIN_JUMP_M at RESET_MIN_SPEED_MPS or more, or turns by at least
    RESET_MIN_TURN_RAD at RESET_MIN_YAW_RATE_RADPS or more (so a long gap in the messages is not a jump).
    """
    if len(t_ns) < 2:
        return np.zeros(0, dtype=np.int64)
    dt = np.maximum(np.diff(np.asarray(t_ns, dtype=np.int64)) / NS_PER_S, 1e-9)
    step = np.hypot(np.diff(pose[:, 0]), np.diff(pose[:, 1]))
    turn = np.abs(np.angle(np.exp(1j * np.diff(pose[:, 2]))))
    moved = (step >= RESET_MIN_JUMP_M) & (step >= RESET_MIN_SPEED_MPS * dt)
    turned = (turn >= RESET_MIN_TURN_RAD) & (turn >= RESET_MIN_YAW_RATE_RADPS * dt)
    return np.flatnonzero(moved | turned) + 1


def reset_boundaries(jumps: Sequence[PoseJump]) -> list[tuple[int, int]]:
    """(end_ns, start_ns) of each reset among `jumps`: the last time before it and the first after it.

    Jumps within RESET_CLUSTER_S of a cluster's first one join it; a cluster with jumps on at least
    RESET_MIN_STREAMS streams is a reset. It happened after the latest pose before a jump and no
    later than the earliest pose after one. Where the streams' clocks disagree so that these
    overlap, the episode before ends at the earliest pose before a jump and the next starts at the
    latest pose after one, so that neither holds a pose from the other side.
    """
    ordered = sorted(jumps, key=lambda j: j.after_ns)
    out: list[tuple[int, int]] = []
    i = 0
    while i < len(ordered):
        first = ordered[i].after_ns
        k = i
        while k < len(ordered) and ordered[k].after_ns - first <= RESET_CLUSTER_S * NS_PER_S:
            k += 1
        cluster = ordered[i:k]
        if len({j.stream for j in cluster}) >= RESET_MIN_STREAMS:
            end = max(j.before_ns for j in cluster)
            start = min(j.after_ns for j in cluster)
            if end >= start:
                end = min(j.before_ns for j in cluster)
                start = max(end + 1, max(j.after_ns for j in cluster))
            out.append((end, start))
        i = k
    return out


def infer_episodes(streams: dict[str, PoseSeries], first_ns: int, last_ns: int) -> list[EpisodeTimes]:
    """Episodes from `first_ns` to `last_ns` split at the resets seen on `streams` (topic -> poses)."""
    jumps = [
        PoseJump(topic, int(series.time.t_ns[i - 1]), int(series.time.t_ns[i]))
        for topic, series in streams.items()
        for i in pose_jumps(series.time.t_ns, series.pose)
    ]
    starts = [first_ns]
    ends: list[int] = []
    for end, start in reset_boundaries(jumps):
        if starts[-1] < end and start < last_ns:
            ends.append(end)
            starts.append(start)
    ends.append(last_ns)
    return [EpisodeTimes(k, a, b) for k, (a, b) in enumerate(zip(starts, ends, strict=True))]


def topics_for(part: Part, pose_source: PoseSourceKind) -> tuple[str, ...]:
    """The per-robot topic kinds `part` needs when the poses come from `pose_source`."""
    kinds = TOPICS_FOR[part]
    if pose_source == "scans":
        swapped = [("scan", "odom") if kind == "ground_truth" else (kind,) for kind in kinds]
        kinds = tuple(dict.fromkeys(k for group in swapped for k in group))
    return kinds


def read_session(
    path: str | Path,
    parts: Sequence[Part],
    scenario: str | Path | Scenario | None = None,
    pose_source: PoseSourceKind | Literal["auto"] = "auto",
    fallback: Scenario | None = None,
) -> SessionData:
    """The streams of a recording needed for `parts`; MissingTopicError names every topic that is absent.

    `pose_source` says where the robots' poses come from: ``ground_truth`` (``/<ns>/ground_truth``,
    motion capture), ``scans`` (localization from ``/<ns>/scan`` and ``/<ns>/odom`` against a map,
    done by the caller), or ``auto``: ground truth where every robot has it, else scans. `fallback` is the
    scenario of a recording that names none when `scenario` is not given either.

    A session recording of this project must hold as many robots as its scenario; a bag recorded elsewhere may
    hold fewer or more (one robot of a fleet, in the scenario's room).
    """
    p = Path(path)
    where = str(p)
    log = McapLog(p)
    session = session_info(log.metadata())
    scen = recorded_scenario(log, scenario, fallback)
    robots = _robots(log, session)
    if not robots:
        raise MissingTopicError(
            where, ["/<robot>/ground_truth", "/<robot>/scan"], "every estimate (the robots' poses, from motion capture "
            "or from their scans)"
        )  # fmt: skip
    topics = log.topics()
    if pose_source == "auto":
        pose_source = "ground_truth" if all(f"/{ns}/ground_truth" in topics for ns in robots) else "scans"
    _check_topics(where, topics, robots, parts, pose_source)
    if session.robots and len(robots) != scen.n_robots:
        raise CalibrationError(
            where, f"the recording has {len(robots)} robots, scenario {scen.name!r} has {scen.n_robots}"
        )
    has_episodes = recorded_episodes.EPISODE_TOPIC in topics
    recorded = recorded_episodes.read_episode_windows(log) if has_episodes else []
    if has_episodes and not recorded:
        raise CalibrationError(where, "topic /mrl/episode holds no start event: the recording has no episode")
    kinds = sorted({kind for part in parts for kind in topics_for(part, pose_source)})
    wanted = [f"/{ns}/{kind}" for ns in robots for kind in kinds]
    if not has_episodes:  # poses that show the resets
        wanted += [f"/{ns}/{kind}" for ns in robots for kind in ("ground_truth", "odom")]
        wanted = list(dict.fromkeys(t for t in wanted if t in topics))
    raw, frames = _read_streams(log, wanted)
    notes: tuple[str, ...] = ()
    if has_episodes:
        last_ns = max((max(b["log"]) for b in raw.values() if b["log"]), default=0)
        last_ns = max([last_ns, *(e.t_ns for w in recorded for e in w.events)])
        episodes = _episodes(recorded, last_ns, where)
    else:
        episodes, notes = _inferred_episodes(raw, p)
    windows = [(e.start_ns, e.end_ns) for e in episodes]
    robot_data = []
    for ns in robots:
        robot_data.append(
            RobotData(
                ns,
                truth=_poses(raw.get(f"/{ns}/ground_truth"), windows),
                scans=_scans(raw.get(f"/{ns}/scan"), windows, where, f"/{ns}/scan"),
                odom=_poses(raw.get(f"/{ns}/odom"), windows) if "odom" in kinds else None,
                commands=_commands(raw.get(f"/{ns}/cmd_vel")),
            )
        )
    followed = _followed_clock(log) if session.clock == "ros_clock" and CLOCK_TOPIC in topics else None
    if TF_STATIC_TOPIC in topics:
        statics = _static_transforms(log)
        robot_data = [replace(r, lidar_mount=lidar_mount(statics, r.name, frames.get(r.name, ""))) for r in robot_data]
    return SessionData(
        p,
        session,
        scen,
        tuple(robot_data),
        tuple(episodes),
        has_episodes,
        notes,
        followed,
        pose_source,
        log.salvage_note,
    )


def _check_topics(
    where: str, topics: dict[str, str], robots: Sequence[str], parts: Sequence[Part], pose_source: PoseSourceKind
) -> None:
    """MissingTopicError naming every per-robot topic that a requested part needs and the recording lacks."""
    needed: dict[str, list[str]] = {}
    for part in parts:
        for kind in topics_for(part, pose_source):
            for ns in robots:
                topic = f"/{ns}/{kind}"
                if topic not in topics:
                    needed.setdefault(topic, []).append(part)
    if needed:
        uses = sorted({part for parts_ in needed.values() for part in parts_})
        raise MissingTopicError(where, sorted(needed), "the " + ", ".join(uses) + " calibration")


def _read_streams(log: McapLog, wanted: list[str]) -> tuple[dict[str, dict[str, list[Any]]], dict[str, str]]:
    """Log times, stamps and the fields calibration uses of every message on `wanted` topics; the scans' frame per
    robot."""
    raw: dict[str, dict[str, list[Any]]] = {t: {"log": [], "stamp": [], "data": []} for t in wanted}
    frames: dict[str, str] = {}
    counts = log.message_counts() if sys.stderr.isatty() else {}
    messages = tqdm(
        log.messages(wanted, skip_undecodable=True),
        total=sum(counts.get(t, 0) for t in wanted) or None,
        desc=f"reading {log.path.stem}",
        unit="msg",
        unit_scale=True,
        disable=None,  # a bar on a terminal only
        leave=False,
        mininterval=0.5,
    )
    for m in messages:
        bucket = raw[m.topic]
        bucket["log"].append(m.log_time_ns)
        kind = m.topic.rsplit("/", 1)[1]
        msg = m.msg
        if kind == "cmd_vel":
            bucket["stamp"].append(m.log_time_ns)
            bucket["data"].append((float(msg.linear.x), float(msg.angular.z)))
            continue
        bucket["stamp"].append(int(msg.header.stamp.sec) * NS_PER_S + int(msg.header.stamp.nanosec))
        if kind == "ground_truth":
            q = msg.pose
            bucket["data"].append((q.position.x, q.position.y, quaternion_yaw(q.orientation)))
        elif kind == "odom":
            q = msg.pose.pose
            tw = msg.twist.twist
            bucket["data"].append(
                (q.position.x, q.position.y, quaternion_yaw(q.orientation), float(tw.linear.x), float(tw.angular.z))
            )
        else:
            frames.setdefault(m.topic.split("/")[1], str(msg.header.frame_id))
            bucket["data"].append(
                (
                    np.asarray(msg.ranges, dtype=np.float64),
                    float(msg.angle_min),
                    float(msg.angle_increment),
                    float(msg.range_min),
                    float(msg.range_max),
                )
            )
    return raw, frames


def _inferred_episodes(raw: dict[str, dict[str, list[Any]]], path: Path) -> tuple[list[EpisodeTimes], tuple[str, ...]]:
    """Episodes of a recording without /mrl/episode, from the resets its poses show, and the note that says so."""
    where = str(path)
    all_log = [t for b in raw.values() for t in b["log"]]
    if not all_log:
        raise CalibrationError(where, "the recording holds no messages on the robots' topics")
    first_ns, last_ns = int(min(all_log)), int(max(all_log))
    whole = [(first_ns, last_ns)]
    poses = {
        t: _poses(b, whole) for t, b in raw.items() if t.endswith(("/ground_truth", "/odom")) and len(b["log"]) >= 2
    }
    episodes = infer_episodes({t: s for t, s in poses.items() if s is not None}, first_ns, last_ns)
    notes = (
        f"{path.name}: no /mrl/episode; {len(episodes)} episode(s) inferred from "
        f"{len(episodes) - 1} reset(s) (simultaneous jumps of the robots' ground-truth or odometry poses)",
    )
    return episodes, notes


CLOCK_TOPIC = "/clock"
TF_STATIC_TOPIC = "/tf_static"
BASE_FRAMES = ("base_link", "base_footprint")
"""Frames a robot description puts the base at (the lidar's mounting is taken relative to one of them)."""


def _static_transforms(log: McapLog) -> dict[str, tuple[str, tuple[float, float, float]]]:
    """Child frame -> (parent frame, planar x, y, yaw) of every transform on ``/tf_static`` (leading '/' dropped)."""
    out: dict[str, tuple[str, tuple[float, float, float]]] = {}
    for m in log.messages([TF_STATIC_TOPIC], skip_undecodable=True):
        for tr in getattr(m.msg, "transforms", []):
            t = tr.transform
            yaw = quaternion_yaw(t.rotation)
            child = str(tr.child_frame_id).lstrip("/")
            out[child] = (str(tr.header.frame_id).lstrip("/"), (float(t.translation.x), float(t.translation.y), yaw))
    return out


def lidar_mount(
    statics: dict[str, tuple[str, tuple[float, float, float]]], robot: str, scan_frame: str
) -> tuple[float, float, float] | None:
    """The laser's pose on robot `robot`'s base: the static transform from its base frame (``base_link`` or
    ``base_footprint``, with or without the robot's namespace) to the frame its scans are stamped in."""
    frame = scan_frame.lstrip("/")
    found = statics.get(frame)
    if not frame or found is None:
        return None
    parent, pose = found
    bases = {b for base in BASE_FRAMES for b in (base, f"{robot}/{base}")}
    return pose if parent in bases else None


def _followed_clock(log: McapLog) -> tuple[np.ndarray, np.ndarray]:
    """Values and log times (int ns) of the recorded ``/clock`` messages, by log time."""
    values, logs = [], []
    for m in log.messages([CLOCK_TOPIC], skip_undecodable=True):
        values.append(int(m.msg.clock.sec) * NS_PER_S + int(m.msg.clock.nanosec))
        logs.append(m.log_time_ns)
    v, t = np.asarray(values, dtype=np.int64), np.asarray(logs, dtype=np.int64)
    order = np.argsort(t, kind="stable")
    return v[order], t[order]


def _poses(bucket: dict[str, list[Any]] | None, windows: Sequence[tuple[int, int]]) -> PoseSeries | None:
    if bucket is None:
        return None
    data = np.asarray(bucket["data"], dtype=np.float64).reshape(len(bucket["data"]), -1)
    time = _stamped(bucket["log"], bucket["stamp"], windows)
    order = np.argsort(time.t_ns, kind="stable")
    time = MessageTimes(time.t_ns[order], time.stamp_ns[order], time.log_ns[order], time.offset_ns)
    data = data[order]
    velocity = data[:, 3:5] if data.shape[1] >= 5 else None
    return PoseSeries(time, data[:, :3], velocity)


def _scans(
    bucket: dict[str, list[Any]] | None, windows: Sequence[tuple[int, int]], where: str, topic: str
) -> ScanSeries | None:
    if bucket is None:
        return None
    rows = bucket["data"]
    if not rows:
        return ScanSeries(_stamped([], [], windows), np.zeros((0, 0)), *(np.zeros(0) for _ in range(4)))
    counts = np.array([len(r[0]) for r in rows])
    beams = int(np.bincount(counts).argmax())
    keep = counts == beams
    if beams == 0:
        raise CalibrationError(where, f"topic {topic}: the scans hold no ranges")
    time = _stamped(
        [t for t, k in zip(bucket["log"], keep, strict=True) if k],
        [t for t, k in zip(bucket["stamp"], keep, strict=True) if k],
        windows,
    )
    kept = [r for r, k in zip(rows, keep, strict=True) if k]
    order = np.argsort(time.t_ns, kind="stable")
    ranges = np.stack([kept[i][0] for i in order])
    cols = np.array([[kept[i][j] for j in range(1, 5)] for i in order], dtype=np.float64)
    time = MessageTimes(time.t_ns[order], time.stamp_ns[order], time.log_ns[order], time.offset_ns)
    return ScanSeries(time, ranges, cols[:, 0], cols[:, 1], cols[:, 2], cols[:, 3])


def _commands(bucket: dict[str, list[Any]] | None) -> CommandSeries | None:
    if bucket is None:
        return None
    t = np.asarray(bucket["log"], dtype=np.int64)
    vw = np.asarray(bucket["data"], dtype=np.float64).reshape(len(t), 2)
    order = np.argsort(t, kind="stable")
    return CommandSeries(t[order], vw[order, 0], vw[order, 1])
