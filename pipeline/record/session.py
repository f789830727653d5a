"""The session layout: one MCAP per evaluation or deployment session, the same for sim and real.

Per robot namespace ``ns``: ``/<ns>/scan``, ``/<ns>/odom``, ``/<ns>/ground_truth`` (as
received, or as simulated) and ``/<ns>/cmd_vel`` (as sent). Fleet-wide: ``/tf`` (``map`` ->
``<ns>/odom`` -> ``<ns>/base_link`` -> ``<ns>/laser``, and ``map`` -> ``<ns>/ground_truth``),
``/mrl/map`` (walls, boxes, goals and robot bodies as markers, at every episode start), ``/mrl/observation`` and
``/mrl/action`` (one message per robot and control step), ``/mrl/episode`` (start, goal,
collision, timeout, success, abort, end; a start carries its episode's seed; read back as episodes
by :mod:`pipeline.record.episodes`), ``/mrl/timing`` (deployments: every send, receive,
emitter tick and control step), ``/clock`` when the fleet's time is scaled.

Metadata records: ``session`` (world sim|real, scenario, robots, profile, policy digest and
name, control period), ``params``, ``scenario``, ``policy`` (the exported policy's JSON) and
``versions``. Log times are the session clock's nanoseconds: simulated time in sim (continuing
across episodes), the deploy clock on the fleet. Header stamps are the sender's.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pipeline.core.scan import ScanGeometry
from pipeline.core.scenario import Scenario, load_scenario
from pipeline.messages import convert as C
from pipeline.messages import fleet_topics, message_store
from pipeline.messages.topics import TopicSpec
from pipeline.record.writer import DEFAULT_CHUNK_SIZE, McapRecorder, versions_metadata

World = Literal["sim", "real"]
SESSION_META = "session"
CONTROL_TIMING_META = "control_timing"
"""A deployment: per episode (its number as the key), how late the runner's control steps woke, the 95th percentile
as a share of the control period (``repr`` of a float)."""
TWIN_TIMING_META = "twin_timing"
"""A deployment on the hardware twin: per episode (its number as the key), how the twin kept its clock, as JSON
(``time_scale_asked``, ``time_scale_realized``, ``jumped_s``, ``lag_max_s``, ``kept``)."""
_IDENTITY = np.zeros(3)


def session_metadata(
    world: World,
    scenario: str,
    robots: Sequence[str],
    control_period_s: float,
    policy: Mapping[str, Any] | None = None,
    profile: str = "",
    extra: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """The ``session`` metadata record (strings only, as MCAP requires)."""
    out = {
        "world": world,
        "scenario": scenario,
        "robots": ",".join(robots),
        "control_period_s": repr(float(control_period_s)),
        "profile": profile,
        "policy_digest": "" if policy is None else str(policy.get("onnx", {}).get("sha256", "")),
        "policy": "" if policy is None else f"{policy.get('algorithm', '')}/{policy.get('mode', '')}",
        "training_digest": "" if policy is None else str(policy.get("training", {}).get("digest", "")),
    }
    out.update(extra or {})
    return out


@dataclass(frozen=True)
class SessionInfo:
    """The ``session`` metadata record of a recording, read back by :func:`read_session_info` (empty strings and
    None where the file does not say: a bag recorded by other tools has no such record)."""

    recorded: bool
    """The file has a ``session`` record (a session recording of this pipeline)."""
    world: str
    scenario: str
    """The scenario's name as the session names it ('' when none)."""
    scenario_text: str
    """The recorded ``scenario`` document (JSON text), '' when none."""
    robots: tuple[str, ...]
    """The robots in fleet order, as recorded (empty when the file does not name them)."""
    control_period_s: float | None
    profile: str
    policy: str
    policy_digest: str
    training_digest: str
    clock: str
    """sim | wall | ros_clock (see :func:`clock_metadata`), '' when not recorded."""
    fields: dict[str, str]
    """Every key of the record as written."""

    def load_scenario(self) -> Scenario | None:
        """The recorded scenario document, else the bundled scenario the session names, else None; MrlError,
        ValueError or TypeError when what is recorded cannot be loaded."""
        if self.scenario_text:
            return load_scenario(json.loads(self.scenario_text))
        if self.scenario:
            return load_scenario(self.scenario)
        return None

    def scenario_name(self) -> str:
        """The scenario the recording names: its scenario document's name, else the session's, else ''."""
        if self.scenario_text:
            try:
                return str(json.loads(self.scenario_text).get("name", "")) or "(a scenario document)"
            except (ValueError, AttributeError):
                return "(an unreadable scenario document)"
        return self.scenario


def session_info(metadata: Mapping[str, Mapping[str, str]]) -> SessionInfo:
    """:class:`SessionInfo` of a recording's metadata records (``McapLog.metadata()``)."""
    meta = dict(metadata.get(SESSION_META, {}))
    try:
        period: float | None = float(meta["control_period_s"])
    except (KeyError, ValueError):
        period = None
    if period is not None and not (math.isfinite(period) and period > 0):
        period = None
    return SessionInfo(
        recorded=SESSION_META in metadata,
        world=meta.get("world", ""),
        scenario=meta.get("scenario", ""),
        scenario_text=metadata.get("scenario", {}).get("text", ""),
        robots=tuple(r for r in meta.get("robots", "").split(",") if r),
        control_period_s=period,
        profile=meta.get("profile", ""),
        policy=meta.get("policy", ""),
        policy_digest=meta.get("policy_digest", ""),
        training_digest=meta.get("training_digest", ""),
        clock=meta.get("clock", ""),
        fields=meta,
    )


def clock_metadata(time_scale: float | None) -> dict[str, str]:
    """What the recording's log times are, for the ``session`` record: one clock per recording.

    `time_scale` None: simulated time (eval_sim), 0 ns at the first episode's start, running on across
    episodes; 1: Unix time of the deploying host; otherwise the twin's ``/clock`` (Unix time at its
    start, then `time_scale` times faster than wall time); messages that arrive before the first
    ``/clock`` are not recorded.
    """
    if time_scale is None:
        return {"clock": "sim", "clock_epoch": "session", "clock_rate": "1"}
    if time_scale == 1.0:
        return {"clock": "wall", "clock_epoch": "unix", "clock_rate": "1"}
    return {"clock": "ros_clock", "clock_epoch": "unix", "clock_rate": repr(float(time_scale))}


class SessionLog:
    """Writes one session in the shared layout; `robots` are the robots' namespaces in fleet order."""

    def __init__(
        self,
        path: str | Path,
        robots: Sequence[str],
        session: Mapping[str, str],
        documents: Mapping[str, str] | None = None,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        overwrite: bool = True,
    ) -> None:
        self.robots = tuple(robots)
        self._announce: Callable[[Any], None] | None = None
        self.unannounced = 0
        """Episode events the network publisher refused (the recording has them all)."""
        self.store = message_store()
        self.topics = fleet_topics(self.robots)
        self.store.prepare(spec.typename for spec in self.topics.values())
        metadata: dict[str, dict[str, str]] = {SESSION_META: dict(session), "versions": versions_metadata()}
        for name, text in (documents or {}).items():
            metadata[name] = {"text": text}
        self.recorder = McapRecorder(
            path, self.topics, self.store, chunk_size=chunk_size, metadata=metadata, overwrite=overwrite
        )
        self.path = self.recorder.path

    # -- robots' topics --------------------------------------------------------------------

    def scan(self, t_ns: int, ns: str, ranges: np.ndarray, geometry: ScanGeometry, stamp_ns: int | None = None) -> None:
        stamp = t_ns if stamp_ns is None else stamp_ns
        msg = C.laser_scan(stamp, f"{ns}/laser", ranges, geometry, store=self.store)
        self.recorder.write(f"/{ns}/scan", msg, t_ns, stamp)

    def odom(
        self,
        t_ns: int,
        ns: str,
        pose: np.ndarray,
        velocity: tuple[float, float] = (0.0, 0.0),
        stamp_ns: int | None = None,
    ) -> None:
        stamp = t_ns if stamp_ns is None else stamp_ns
        self.recorder.write(f"/{ns}/odom", C.odometry(stamp, ns, pose, velocity, store=self.store), t_ns, stamp)

    def ground_truth(self, t_ns: int, ns: str, pose: np.ndarray, stamp_ns: int | None = None) -> None:
        stamp = t_ns if stamp_ns is None else stamp_ns
        self.recorder.write(f"/{ns}/ground_truth", C.pose_stamped(stamp, "map", pose, store=self.store), t_ns, stamp)

    def cmd_vel(self, t_ns: int, ns: str, v_mps: float, w_radps: float) -> None:
        self.recorder.write(f"/{ns}/cmd_vel", C.twist(v_mps, w_radps, store=self.store), t_ns)

    def raw(self, topic: str, data: bytes, t_ns: int, stamp_ns: int | None = None) -> None:
        """A message exactly as it arrived (CDR), logged at local time `t_ns`."""
        self.recorder.write_cdr(topic, data, t_ns, stamp_ns)

    def message(self, topic: str | TopicSpec, msg: Any, t_ns: int, stamp_ns: int | None = None) -> None:
        """A received message object, logged at local time `t_ns` (a TopicSpec for a topic beyond the fleet's)."""
        self.recorder.write(topic, msg, t_ns, stamp_ns)

    def tf(
        self,
        t_ns: int,
        odom_poses: np.ndarray,
        truth_poses: np.ndarray | None = None,
        mount_yaw_rad: Sequence[float] | None = None,
    ) -> None:
        """One /tf message: map -> ns/odom (identity), ns/odom -> ns/base_link (odometry), base_link -> laser,
        and map -> ns/ground_truth when true poses are known."""
        transforms: list[tuple[str, str, np.ndarray]] = []
        for i, ns in enumerate(self.robots):
            if truth_poses is not None:
                transforms.append(("map", f"{ns}/ground_truth", truth_poses[i]))
            laser = _IDENTITY if mount_yaw_rad is None else np.array([0.0, 0.0, mount_yaw_rad[i]])
            transforms += [
                ("map", f"{ns}/odom", _IDENTITY),
                (f"{ns}/odom", f"{ns}/base_link", odom_poses[i]),
                (f"{ns}/base_link", f"{ns}/laser", laser),
            ]
        self.recorder.write("/tf", C.tf_message(t_ns, transforms, store=self.store), t_ns)

    def map(self, t_ns: int, scenario: Any) -> None:
        """/mrl/map: the scenario's walls, boxes and goals, and a body for each robot on its ground-truth frame."""
        frames = [f"{ns}/ground_truth" for ns in self.robots]
        self.recorder.write("/mrl/map", C.map_markers(t_ns, scenario, frames, store=self.store), t_ns)

    def clock(self, t_ns: int) -> None:
        self.recorder.write("/clock", C.clock(t_ns, store=self.store), t_ns)

    # -- the pipeline's own topics ---------------------------------------------------------

    def observation(self, t_ns: int, episode: int, step: int, ns: str, layout: str, values: np.ndarray) -> None:
        msg = C.observation(t_ns, episode, step, ns, layout, values, store=self.store)
        self.recorder.write("/mrl/observation", msg, t_ns)

    def action(
        self, t_ns: int, episode: int, step: int, ns: str, output: np.ndarray, command: tuple[float, float]
    ) -> None:
        msg = C.action(t_ns, episode, step, ns, output, command, store=self.store)
        self.recorder.write("/mrl/action", msg, t_ns)

    def event(
        self,
        t_ns: int,
        episode: int,
        step: int,
        event: str,
        robot: str = "",
        detail: str = "",
        seed: int = C.NO_SEED,
    ) -> None:
        """One ``/mrl/episode`` event; `seed` (>= 0) belongs on ``start`` events (see :meth:`start_episode`).

        Also sent on the network where :meth:`announce_events` gave a publisher."""
        msg = C.episode_event(t_ns, episode, step, event, robot, detail, store=self.store, seed=seed)
        self.recorder.write("/mrl/episode", msg, t_ns)
        if self._announce is not None:
            try:
                self._announce(msg)
            except Exception:  # the network's failure; the recording has the event
                self.unannounced += 1

    def announce_events(self, send: Callable[[Any], None]) -> None:
        """Hand every episode event to `send` too (a ``/mrl/episode`` publisher's), so a recorder of the network
        (``rosbag record``, ``ros2 bag record``) has the episodes; events it refuses are counted in
        :attr:`unannounced`."""
        self._announce = send

    def start_episode(self, t_ns: int, episode: int, seed: int) -> None:
        """The ``start`` event of `episode`, which runs from the seed `seed` (>= 0), carried in its ``seed`` field.

        Readers: :func:`pipeline.record.episodes.episode_windows`.
        """
        self.event(t_ns, episode, 0, "start", seed=seed)

    def timing(self, t_ns: int, kind: str, robot: str, topic: str, source_stamp_ns: int, seq: int, tick: int) -> None:
        msg = C.timing(t_ns, kind, robot, topic, source_stamp_ns, seq, tick, store=self.store)
        self.recorder.write("/mrl/timing", msg, t_ns)

    def add_metadata(self, name: str, mapping: Mapping[str, str]) -> None:
        self.recorder.add_metadata(name, mapping)

    def flush(self) -> None:
        self.recorder.flush()

    def close(self) -> None:
        self.recorder.close()

    def __enter__(self) -> SessionLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def dumps(data: Any) -> str:
    """JSON text for a metadata document."""
    return json.dumps(data, indent=1, sort_keys=True, default=str)
