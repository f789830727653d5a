"""Session recordings as polars tables: episodes (one row per episode and robot), topics, poses.

A :class:`Recording` opens one MCAP file of the session layout (:mod:`pipeline.record.session`),
reads the topics an analysis asks for in one pass over the file, and decodes each topic column-wise
(:mod:`pipeline.analysis.decode`). Episodes are the windows that :mod:`pipeline.record.episodes` reads
from the ``/mrl/episode`` events (a ``start`` opens one, an ``end`` or a team-level ``abort`` closes
it), every outcome of them: an episode that is never closed (the recorder was killed, or a new start
came first) or that saw any ``abort`` counts as aborted. A salvaged file (no summary, read
up to its last complete chunk) is analysed like any other: the reader's TruncatedLogWarning is
raised as usual and :attr:`Recording.salvaged` and the ``salvaged`` column say so.

Times: ``t_ns`` is a message's log time (the session clock: simulated ns in sim, the deploy
clock's ns on the fleet), ``stamp_ns`` the sender's header stamp. Positions are metres in the
frame of the topic (``map`` for ground truth, ``<ns>/odom`` for odometry), yaw in radians.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
import polars as pl
from tqdm import tqdm

from pipeline.analysis.decode import Decoded, Ragged, Strings, concat, decode
from pipeline.analysis.errors import AnalysisError
from pipeline.analysis.layouts import DECODABLE
from pipeline.core.episode import path_lengths_m, path_times_ns
from pipeline.core.scenario import Scenario
from pipeline.core.timebase import CONTROL_LATE_LIMIT, NS_PER_S
from pipeline.errors import MrlError
from pipeline.messages import topics as T
from pipeline.messages.convert import EVENT_NAMES, NO_SEED
from pipeline.record import McapLog
from pipeline.record.episodes import EPISODE_TOPIC as EPISODE_TOPIC  # re-exported: mrl and benchmarks use it
from pipeline.record.episodes import EpisodeWindow, EventRow, episode_windows
from pipeline.record.errors import MissingTopicError, TopicTypeError
from pipeline.record.session import CONTROL_TIMING_META, TWIN_TIMING_META, SessionInfo, session_info

PoseKind = Literal["ground_truth", "odom"]
POSE_TYPES: dict[str, str] = {"ground_truth": T.POSE_STAMPED, "odom": T.ODOMETRY}
_ROBOT_TOPIC = re.compile(r"^/([^/]+)/(scan|odom|ground_truth|cmd_vel)$")
_INT64_MAX = np.iinfo(np.int64).max
DECODE_BATCH = 16384
"""Messages of one topic decoded together while a file is read (bounds the raw bytes held in memory)."""

EPISODES_SCHEMA: dict[str, Any] = {
    "world": pl.String,
    "scenario": pl.String,
    "policy": pl.String,
    "policy_digest": pl.String,
    "profile": pl.String,
    "session": pl.String,
    "path": pl.String,
    "episode": pl.Int64,
    "seed": pl.Int64,
    "robot": pl.String,
    "success": pl.Boolean,
    "reached": pl.Boolean,
    "collided": pl.Boolean,
    "timeout": pl.Boolean,
    "aborted": pl.Boolean,
    "time_to_goal_s": pl.Float64,
    "time_to_goal_clock_s": pl.Float64,
    "path_length_m": pl.Float64,
    "path_source": pl.String,
    "steps": pl.Int64,
    "team_success": pl.Boolean,
    "end": pl.String,
    "abort_reason": pl.String,
    "abort_kind": pl.String,
    "stale_s": pl.Float64,
    "time_scale_asked": pl.Float64,
    "time_scale_realized": pl.Float64,
    "control_late_p95": pl.Float64,
    "clock_kept": pl.Boolean,
    "start_ns": pl.Int64,
    "end_ns": pl.Int64,
    "salvaged": pl.Boolean,
}
"""Columns of :func:`episodes_table`, in order."""


@dataclass(frozen=True)
class _Episode:
    """What the tables read from one episode window (log times in ns)."""

    window: EpisodeWindow
    aborted: bool  # not finished, any abort event, or an end 'aborted'
    abort_reason: str
    end: str  # the end event's detail; 'aborted' after a team abort; '' when unfinished
    team_success: bool  # a team-level success or an end 'team_success', and not aborted
    max_step: int
    robot_events: Mapping[str, Mapping[str, tuple[int, int]]]  # robot -> event -> (t, step) of its first
    abort_kind: str  # outage | fault | clash | interrupted | cut_off; '' when not aborted
    stale_s: Mapping[str, float]  # robot -> seconds between its stale and fresh events (to the end when open)


def _abort_kind(w: EpisodeWindow, aborted: bool) -> str:
    """Why an episode was aborted, from its events (see :data:`pipeline.core.episode.ABORT_KINDS`)."""
    if not aborted:
        return ""
    aborts = [e for e in w.events if e.event == "abort"]
    if w.outcome == "unfinished" and not aborts:
        return "cut_off"
    if any(e.robot for e in aborts):
        return "outage"
    details = " ".join(e.detail for e in aborts)
    if "interrupted" in details:
        return "interrupted"
    if "DDS domain" in details or "foreign" in details:
        return "clash"
    return "fault"


def _stale_seconds(w: EpisodeWindow) -> dict[str, float]:
    """Per robot, the seconds from each ``stale`` event to the next ``fresh`` one (or to the episode's end)."""
    since: dict[str, int] = {}
    total: dict[str, float] = {}
    last_t = w.start_ns
    for e in w.events:
        last_t = max(last_t, e.t_ns)
        if e.event == "stale" and e.robot:
            since.setdefault(e.robot, e.t_ns)
        elif e.event == "fresh" and e.robot in since:
            total[e.robot] = total.get(e.robot, 0.0) + (e.t_ns - since.pop(e.robot)) / NS_PER_S
    end = w.end_ns if w.end_ns is not None else last_t
    for robot, t in since.items():
        total[robot] = total.get(robot, 0.0) + (end - t) / NS_PER_S
    return total


def _episode(w: EpisodeWindow) -> _Episode:
    reasons = list(w.abort_reasons)
    if w.outcome == "unfinished":
        why = "the recording stops inside the episode" if w.end_ns is None else "the next episode started"
        reasons.append(f"no end event ({why})")
    aborted = w.outcome != "finished" or bool(w.abort_reasons) or w.end_detail == "aborted"
    team = w.end_detail == "team_success" or any(e.event == "success" and not e.robot for e in w.events)
    robot_events: dict[str, dict[str, tuple[int, int]]] = {}
    for e in w.events:
        if e.robot and e.event not in ("abort", "stale", "fresh"):
            robot_events.setdefault(e.robot, {}).setdefault(e.event, (e.t_ns, e.step))
    end = {"finished": w.end_detail, "aborted": "aborted", "unfinished": ""}[w.outcome]
    max_step = max(e.step for e in w.events)
    return _Episode(
        w,
        aborted,
        "; ".join(reasons),
        end,
        team and not aborted,
        max_step,
        robot_events,
        _abort_kind(w, aborted),
        _stale_seconds(w),
    )


class Recording:
    """One session recording opened for analysis; decoded topics are cached.

    Args:
        source: the MCAP file (or an open :class:`~pipeline.record.McapLog`).
        session: the name in the ``session`` column; the file's stem by default.
        progress: show a bar of the messages read (on a terminal, on stderr) while topics are decoded.

    Raises:
        LogReadError: the file is missing, not MCAP or damaged beyond salvage (from the reader).
    """

    def __init__(
        self, source: str | os.PathLike[str] | McapLog, session: str | None = None, progress: bool = False
    ) -> None:
        self.log = source if isinstance(source, McapLog) else McapLog(source)
        self.progress = progress
        self.path = self.log.path
        self.where = str(self.path)
        self.session = session if session is not None else self.path.stem
        self._topics = self.log.topics()
        self._metadata = self.log.metadata()
        self._schemas = self.log.schemas()
        self.info = self._session_info()
        self._decoded: dict[str, tuple[np.ndarray, np.ndarray, Decoded]] = {}
        self._frames: dict[str, pl.DataFrame] = {}
        self._windows: list[_Episode] | None = None
        self._table: pl.DataFrame | None = None

    # -- file facts --------------------------------------------------------------------------

    @property
    def salvaged(self) -> bool:
        """True when the file had no summary and was read up to its last complete chunk."""
        return self.log.salvaged

    @property
    def robots(self) -> tuple[str, ...]:
        return self.info.robots

    def topics(self) -> dict[str, str]:
        """``{topic: message type}`` of the file."""
        return dict(self._topics)

    def document(self, name: str) -> str | None:
        """The text of a metadata document (``params``, ``scenario``, ``world``, ``policy``), if recorded."""
        record = self._metadata.get(name)
        return None if record is None else record.get("text")

    def scenario(self) -> Scenario:
        """The scenario of the session: the recorded ``scenario`` document, else the bundled one it names."""
        try:
            scenario = self.info.load_scenario()
        except (MrlError, ValueError, TypeError) as exc:
            raise AnalysisError(self.where, f"the recorded scenario cannot be loaded: {exc}") from exc
        if scenario is not None:
            return scenario
        raise AnalysisError(self.where, "the recording names no scenario (no 'scenario' metadata)")

    def _twin_timing(self) -> dict[int, tuple[float, float, bool]]:
        """Per episode, (time scale asked, realized, kept) from the ``twin_timing`` record of a deployment on the
        hardware twin; empty for other recordings (and those made before the record)."""
        out = {}
        for key, text in self._metadata.get(TWIN_TIMING_META, {}).items():
            try:
                record = json.loads(text)
                out[int(key)] = (
                    float(record["time_scale_asked"]),
                    float(record["time_scale_realized"]),
                    bool(record["kept"]),
                )
            except (ValueError, KeyError, TypeError) as exc:
                raise AnalysisError(self.where, f"the {TWIN_TIMING_META} record of episode {key!r}: {exc}") from exc
        return out

    def _control_timing(self) -> dict[int, float]:
        """Per episode, how late the runner's control steps woke (the ``control_timing`` record of a deployment)."""
        try:
            return {int(k): float(v) for k, v in self._metadata.get(CONTROL_TIMING_META, {}).items()}
        except ValueError as exc:
            raise AnalysisError(self.where, f"the {CONTROL_TIMING_META} record: {exc}") from exc

    def _session_info(self) -> SessionInfo:
        info = session_info(self._metadata)
        if info.robots:
            return info
        found = {m.group(1) for topic in self._topics if (m := _ROBOT_TOPIC.match(topic))}
        return replace(info, robots=tuple(sorted(found)))

    # -- reading -----------------------------------------------------------------------------

    def robot_topics(self, *kinds: str) -> list[str]:
        """The topics ``/<robot>/<kind>`` of every robot for each of `kinds` (e.g. "odom") in the file."""
        return [f"/{r}/{k}" for k in kinds for r in self.robots if f"/{r}/{k}" in self._topics]

    def require(self, topics: Sequence[str], needed_for: str) -> None:
        """Raise MissingTopicError unless the file has at least one of `topics`."""
        if not any(t in self._topics for t in topics):
            raise MissingTopicError(self.where, topics, needed_for, any_of=True)

    def load(self, topics: Iterable[str]) -> None:
        """Read and decode `topics` (those present and not cached yet) in one pass over the file.

        Every frame reads the topics it needs on first use; loading the topics of several frames
        first reads the file once for all of them.
        """
        wanted = [t for t in dict.fromkeys(topics) if t in self._topics and t not in self._decoded]
        for topic in wanted:
            if self._topics[topic] not in DECODABLE:
                raise AnalysisError(
                    self.where, f"topic {topic} carries {self._topics[topic]}, which has no column decoder"
                )
        if not wanted:
            return
        pending: dict[str, tuple[list[int], list[int], list[bytes]]] = {t: ([], [], []) for t in wanted}
        parts: dict[str, list[tuple[np.ndarray, np.ndarray, Decoded]]] = {t: [] for t in wanted}

        def flush(topic: str) -> None:
            log_ns, pub_ns, datas = pending[topic]
            t_ns = np.array(log_ns, dtype=np.int64)
            where = f"{self.where}: topic {topic}"
            decoded = decode(self._topics[topic], datas, where=where, log_times_ns=t_ns, schema=self._schemas[topic])
            parts[topic].append((t_ns, np.array(pub_ns, dtype=np.int64), decoded))
            pending[topic] = ([], [], [])

        batch = DECODE_BATCH
        counts = self.log.message_counts() if self.progress else {}
        with tqdm(
            total=sum(counts.get(t, 0) for t in wanted) or None,
            desc=f"reading {self.path.stem}",
            unit="msg",
            unit_scale=True,
            disable=None if self.progress else True,  # a bar on a terminal only
            leave=False,
        ) as bar:
            for topic, _, log_ns, pub_ns, _, data in self.log.raw(wanted):
                times, stamps, datas = pending[topic]
                times.append(log_ns)
                stamps.append(pub_ns)
                datas.append(data)
                if len(datas) >= batch:
                    flush(topic)
                    bar.update(batch)
        for topic in wanted:
            if pending[topic][2] or not parts[topic]:
                flush(topic)
            chunks = parts.pop(topic)
            t_all = np.concatenate([c[0] for c in chunks])
            pub_all = np.concatenate([c[1] for c in chunks])
            self._decoded[topic] = (t_all, pub_all, concat([c[2] for c in chunks]))

    def topic_frame(self, topic: str) -> pl.DataFrame:
        """One row per message of `topic`, flat columns (see :func:`topic_frame`)."""
        frame = self._frames.get(topic)
        if frame is not None:
            return frame
        self.require([topic], f"a frame of {topic}")
        self.load([topic])
        t_ns, pub_ns, decoded = self._decoded[topic]
        frame = _flat_frame(t_ns, pub_ns, decoded)
        self._frames[topic] = frame
        return frame

    def _expect_type(self, topic: str, typename: str) -> None:
        found = self._topics.get(topic)
        if found is not None and found != typename:
            raise TopicTypeError(self.where, topic, found, typename)

    # -- episodes ----------------------------------------------------------------------------

    def events(self) -> pl.DataFrame:
        """``/mrl/episode`` as a frame: t_ns, episode, step, robot ('' for team events), event (name), detail."""
        self.require([EPISODE_TOPIC], "the episodes")
        self._expect_type(EPISODE_TOPIC, T.EPISODE_EVENT)
        frame = self.topic_frame(EPISODE_TOPIC)
        names = pl.Series([EVENT_NAMES.get(code, f"event_{code}") for code in range(256)], dtype=pl.String)
        codes = frame["event"].cast(pl.Int64).to_numpy()
        return frame.select(
            pl.col("t_ns"),
            pl.col("episode").cast(pl.Int64),
            pl.col("step").cast(pl.Int64),
            pl.col("robot"),
            names.gather(codes).alias("event"),
            pl.col("detail"),
        )

    def _event_rows(self) -> Iterator[EventRow]:
        """The events with their seeds (-1 where the recording's definition has no seed field)."""
        events = self.events()
        raw = self.topic_frame(EPISODE_TOPIC)
        seed = raw["seed"] if "seed" in raw.columns else pl.Series([NO_SEED] * raw.height)
        for row in events.with_columns(seed.cast(pl.Int64).alias("seed")).iter_rows():
            yield EventRow(*row)

    def _episode_windows(self) -> list[_Episode]:
        """Every episode window of the file (:func:`~pipeline.record.episodes.episode_windows`), any outcome."""
        if self._windows is None:
            self._windows = [_episode(w) for w in episode_windows(self._event_rows())]
        return self._windows

    def episodes(self) -> pl.DataFrame:
        """One row per episode: episode, seed, start_ns, end_ns (null when the file stops inside it),
        steps (of the end or abort event; null if neither), end (the end event's detail), aborted,
        abort_reason, team_success."""
        rows = [
            {
                "episode": e.window.episode,
                "seed": e.window.seed,
                "start_ns": e.window.start_ns,
                "end_ns": e.window.end_ns,
                "steps": e.window.end_step,
                "end": e.end,
                "aborted": e.aborted,
                "abort_reason": e.abort_reason,
                "team_success": e.team_success,
            }
            for e in self._episode_windows()
        ]
        schema = {
            "episode": pl.Int64,
            "seed": pl.Int64,
            "start_ns": pl.Int64,
            "end_ns": pl.Int64,
            "steps": pl.Int64,
            "end": pl.String,
            "aborted": pl.Boolean,
            "abort_reason": pl.String,
            "team_success": pl.Boolean,
        }
        return pl.DataFrame(rows, schema=schema)

    def _window_index(self, t_ns: np.ndarray) -> np.ndarray:
        """(n,) index of the episode window holding each log time, -1 outside every episode."""
        windows = self._episode_windows()
        if not windows or not len(t_ns):
            return np.full(len(t_ns), -1, dtype=np.int64)
        starts = np.array([e.window.start_ns for e in windows], dtype=np.int64)
        ends = np.array([_INT64_MAX if e.window.end_ns is None else e.window.end_ns for e in windows], dtype=np.int64)
        idx = np.searchsorted(starts, t_ns, side="right") - 1
        inside = (idx >= 0) & (t_ns <= ends[np.maximum(idx, 0)])
        return np.where(inside, idx, -1).astype(np.int64)

    # -- poses -------------------------------------------------------------------------------

    def pose_topics(self, kind: PoseKind) -> dict[str, str]:
        """``{robot: topic}`` of the pose topics of `kind` present in the file."""
        if kind not in POSE_TYPES:
            raise AnalysisError(self.where, f"pose kind {kind!r} is not one of {sorted(POSE_TYPES)}")
        return {r: f"/{r}/{kind}" for r in self.robots if f"/{r}/{kind}" in self._topics}

    def poses(self, kind: PoseKind = "ground_truth") -> pl.DataFrame:
        """Poses of every robot: robot, episode (null between episodes), t_ns, stamp_ns, x_m, y_m, yaw_rad
        (odometry adds v_mps, w_radps), sorted by robot then log time."""
        topics = self.pose_topics(kind)
        wanted = [f"/{r}/{kind}" for r in self.robots]
        missing = [t for t in wanted if t not in topics.values()]
        if missing or not wanted:
            raise MissingTopicError(self.where, missing or [f"/<robot>/{kind}"], f"{kind} poses of every robot")
        for topic in topics.values():
            self._expect_type(topic, POSE_TYPES[kind])
        return self._poses(topics, kind)

    def _poses(self, topics: dict[str, str], kind: PoseKind) -> pl.DataFrame:
        has_events = EPISODE_TOPIC in self._topics
        self.load([*topics.values(), *([EPISODE_TOPIC] if has_events else [])])
        windows = self._episode_windows() if has_events else []
        numbers = np.array([e.window.episode for e in windows], dtype=np.int64)
        columns = ["t_ns", "stamp_ns", "x_m", "y_m", "yaw_rad"] + (["v_mps", "w_radps"] if kind == "odom" else [])
        parts = []
        for robot, topic in topics.items():
            frame = self.topic_frame(topic)
            idx = self._window_index(frame["t_ns"].to_numpy()) if has_events else np.full(frame.height, -1)
            episode = pl.Series("episode", numbers[np.maximum(idx, 0)] if len(numbers) else idx, dtype=pl.Int64)
            episode = episode.scatter(np.flatnonzero(idx < 0), None) if (idx < 0).any() else episode
            parts.append(frame.select(columns).with_columns(pl.lit(robot, dtype=pl.String).alias("robot"), episode))
        out = pl.concat(parts) if parts else pl.DataFrame()
        return out.select(["robot", "episode", *columns])

    # -- the episodes table ------------------------------------------------------------------

    def episodes_table(self) -> pl.DataFrame:
        """One row per (episode, robot); columns :data:`EPISODES_SCHEMA` (see :func:`episodes_table`)."""
        if self._table is None:
            self._table = self._episodes_table()
        return self._table

    def _episodes_table(self) -> pl.DataFrame:
        self.require([EPISODE_TOPIC], "the episodes table")
        sources: dict[str, tuple[str, str]] = {}
        for robot in self.robots:
            gt, odom = f"/{robot}/ground_truth", f"/{robot}/odom"
            if gt in self._topics:
                self._expect_type(gt, T.POSE_STAMPED)
                sources[robot] = ("ground_truth", gt)
            elif odom in self._topics:
                self._expect_type(odom, T.ODOMETRY)
                sources[robot] = ("odom", odom)
            else:
                raise MissingTopicError(self.where, [gt, odom], f"the path length of {robot}", any_of=True)
        self.load([EPISODE_TOPIC, *(topic for _, topic in sources.values())])
        # a ground-truth channel without messages (e.g. cut off by a crash) falls back to odometry
        for robot, (kind, topic) in list(sources.items()):
            odom = f"/{robot}/odom"
            if kind == "ground_truth" and not len(self._decoded[topic][0]) and odom in self._topics:
                self._expect_type(odom, T.ODOMETRY)
                self.load([odom])
                sources[robot] = ("odom", odom)
        windows = self._episode_windows()
        period = self.info.control_period_s
        period_ns = round(period * NS_PER_S) if period else None
        tracks: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        last_t: dict[str, np.ndarray] = {}
        for robot, (_, topic) in sources.items():
            frame = self.topic_frame(topic)
            t_ns = frame["t_ns"].to_numpy()
            tracks[robot] = (t_ns, frame.select("x_m", "y_m").to_numpy())
            last_t[robot] = _last_times(t_ns, self._window_index(t_ns), len(windows))
        steps_of: list[int] = []
        for k, e in enumerate(windows):
            w = e.window
            steps = w.end_step
            if steps is None:
                latest = max((int(last_t[r][k]) for r in self.robots if last_t[r][k] >= 0), default=w.start_ns)
                by_time = (latest - w.start_ns) // period_ns if period_ns else 0
                steps = max(e.max_step, int(by_time))
            steps_of.append(steps)
        lengths = {
            robot: _path_lengths(t_ns, xy, [e.window for e in windows], steps_of, period_ns)
            for robot, (t_ns, xy) in tracks.items()
        }
        info = self.info
        timing = self._twin_timing()
        control = self._control_timing()
        rows: list[tuple[Any, ...]] = []
        for k, e in enumerate(windows):
            w = e.window
            steps = steps_of[k]
            asked, realized, twin_kept = timing.get(w.episode, (None, None, True))
            late = control.get(w.episode)
            clock_kept = twin_kept and (late is None or late <= CONTROL_LATE_LIMIT)
            for robot in self.robots:
                events = e.robot_events.get(robot, {})
                goal = events.get("goal")
                reached = goal is not None
                collided = "collision" in events
                if goal is None:
                    ttg: float | None = None
                    ttg_clock: float | None = None
                else:
                    ttg_clock = (goal[0] - w.start_ns) / NS_PER_S
                    ttg = goal[1] * period if period else ttg_clock
                rows.append(
                    (
                        info.world,
                        info.scenario,
                        info.policy,
                        info.policy_digest,
                        info.profile,
                        self.session,
                        self.where,
                        w.episode,
                        w.seed,
                        robot,
                        reached and not collided,
                        reached,
                        collided,
                        "timeout" in events,
                        e.aborted,
                        ttg,
                        ttg_clock,
                        float(lengths[robot][k]),
                        sources[robot][0],
                        steps,
                        e.team_success,
                        e.end,
                        e.abort_reason,
                        e.abort_kind,
                        e.stale_s.get(robot, 0.0),
                        asked,
                        realized,
                        late,
                        clock_kept,
                        w.start_ns,
                        w.end_ns,
                        self.salvaged,
                    )
                )
        return pl.DataFrame(rows, schema=EPISODES_SCHEMA, orient="row")


def _last_times(t_ns: np.ndarray, window: np.ndarray, n_windows: int) -> np.ndarray:
    """(n_windows,) the log time of the last pose inside each window (-1 where a window has none)."""
    last = np.full(n_windows, -1, dtype=np.int64)
    inside = window >= 0
    if inside.any():
        np.maximum.at(last, window[inside], t_ns[inside])
    return last


def _path_lengths(
    t_ns: np.ndarray, xy: np.ndarray, windows: Sequence[EpisodeWindow], steps: Sequence[int], period_ns: int | None
) -> np.ndarray:
    """(n_windows,) one robot's path length (m) in each episode, as the episode's own result counts it
    (:func:`~pipeline.core.episode.path_lengths_m`): through its newest pose logged at or before each control step's
    time (:func:`~pipeline.core.episode.path_times_ns`; logged = received, on a fleet), never one logged before the
    previous episode ended (a pose from before the reset starts no path). Poses `xy` (n, 2) at log times `t_ns` (n,).
    Without a control period (a recording without session metadata), every pose logged inside the episode is a step.
    """
    order = np.argsort(t_ns, kind="stable")  # a salvaged file is read in file order
    t_ns, xy = t_ns[order], xy[order]
    out = np.zeros(len(windows))
    floor = 0  # index of the first pose logged after the previous episode's end
    for k, w in enumerate(windows):
        if period_ns:
            times = path_times_ns(w.start_ns, period_ns, steps[k], w.end_ns)
        else:
            end = _INT64_MAX if w.end_ns is None else w.end_ns
            times = t_ns[(t_ns >= w.start_ns) & (t_ns <= end)]
        newest = np.searchsorted(t_ns, times, side="right") - 1
        samples = np.full((len(times), 1, 2), np.nan)
        known = newest >= floor
        samples[known, 0] = xy[newest[known]]
        out[k] = path_lengths_m(samples)[0]
        if w.end_ns is not None:
            floor = int(np.searchsorted(t_ns, w.end_ns, side="right"))
    return out


def _yaw(qx: np.ndarray, qy: np.ndarray, qz: np.ndarray, qw: np.ndarray) -> np.ndarray:
    """Yaw (rad) in [-pi, pi] of quaternions."""
    return np.asarray(np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz)))


def _series(name: str, column: np.ndarray | Strings | Ragged) -> pl.Series:
    if isinstance(column, Strings):
        return pl.Series(name, list(column.values), dtype=pl.String).gather(column.codes)
    if isinstance(column, Ragged):
        inner = pl.Series(values=column.values).dtype
        return pl.Series(name, column.tolist(), dtype=pl.List(inner))
    return pl.Series(name, column)


_RENAMES: dict[str, dict[str, str]] = {
    T.POSE_STAMPED: {"x": "x_m", "y": "y_m", "z": "z_m"},
    T.ODOMETRY: {"x": "x_m", "y": "y_m", "z": "z_m", "linear_x": "v_mps", "angular_z": "w_radps"},
    T.TWIST: {
        "linear_x": "v_mps",
        "angular_z": "w_radps",
        "linear_y": "linear_y_mps",
        "linear_z": "linear_z_mps",
        "angular_x": "angular_x_radps",
        "angular_y": "angular_y_radps",
    },
    T.LASER_SCAN: {
        "angle_min": "angle_min_rad",
        "angle_max": "angle_max_rad",
        "angle_increment": "angle_increment_rad",
        "time_increment": "time_increment_s",
        "scan_time": "scan_time_s",
        "range_min": "range_min_m",
        "range_max": "range_max_m",
        "ranges": "ranges_m",
    },
}
_DROPPED: dict[str, frozenset[str]] = {
    T.POSE_STAMPED: frozenset({"qx", "qy", "qz", "qw"}),
    T.ODOMETRY: frozenset({"qx", "qy", "qz", "qw", "linear_y", "linear_z", "angular_x", "angular_y"}),
}


def _flat_frame(t_ns: np.ndarray, pub_ns: np.ndarray, decoded: Decoded) -> pl.DataFrame:
    typename = decoded.typename
    cols = decoded.columns
    renames = _RENAMES.get(typename, {})
    dropped = _DROPPED.get(typename, frozenset())
    series = [pl.Series("t_ns", t_ns, dtype=pl.Int64), pl.Series("publish_ns", pub_ns, dtype=pl.Int64)]
    for name, column in cols.items():
        if name in dropped:
            continue
        if name == "intensities" and _empty_sequences(column):
            continue
        series.append(_series(renames.get(name, name), column))
        if name == "z" and "qw" in cols:
            qx, qy, qz, qw = (np.asarray(cols[q]) for q in ("qx", "qy", "qz", "qw"))
            series.append(pl.Series("yaw_rad", _yaw(qx, qy, qz, qw)))
    return pl.DataFrame(series)


def _empty_sequences(column: np.ndarray | Strings | Ragged) -> bool:
    if isinstance(column, Ragged):
        return len(column.values) == 0
    return isinstance(column, np.ndarray) and column.ndim == 2 and column.shape[1] == 0


# -- module-level entry points -----------------------------------------------------------------

Source = str | os.PathLike[str] | McapLog | Recording
"""A recording to analyse: a path, an open McapLog, or a Recording (whose decoded topics are reused)."""


def open_recording(source: Source) -> Recording:
    """`source` as a :class:`Recording` (itself if it already is one)."""
    return source if isinstance(source, Recording) else Recording(source)


def episodes_table(source: Source) -> pl.DataFrame:
    """One row per (episode, robot) of a session recording.

    Columns (:data:`EPISODES_SCHEMA`): session facts (world, scenario, policy, policy_digest,
    profile, session = file stem, path), episode, seed (the start event's seed; in recordings made before
    its seed field, the ``seed=<n>`` of its detail), robot,
    success (reached its goal without colliding), reached, collided, timeout, aborted (the episode
    saw an abort event, ended ``aborted``, or has no end event), time_to_goal_s (the goal event's
    control step x control period; null if not reached), time_to_goal_clock_s (log time from start
    to goal), path_length_m (along the robot's ground-truth poses at the episode's control steps, as the
    episode's own result counts it: :func:`pipeline.core.episode.path_lengths_m`; over odometry where the robot
    has no ground truth, as ``path_source`` says), steps (control steps of the end or
    abort event; without either, estimated from the last pose), team_success (all robots reached
    their goals and the episode was not aborted), end (the end event's detail, ``aborted`` after a
    team-level abort, empty when the file stops inside the episode), abort_reason, abort_kind (outage,
    fault, clash, interrupted, or cut_off for a file that stops inside the episode), stale_s (seconds between
    the robot's ``stale`` and ``fresh`` events), time_scale_asked, time_scale_realized (how the hardware twin kept its
    clock in the episode, from the deployment's ``twin_timing`` record), control_late_p95 (how late the runner's
    control steps woke, from its ``control_timing`` record) and clock_kept (both within their limits; null, null,
    null and true without the records), start_ns and end_ns (log times; end_ns null when the file
    stops inside the episode), salvaged.

    Raises:
        MissingTopicError: no ``/mrl/episode``, or a robot with neither ground truth nor odometry.
        LogReadError: the file cannot be read (from the reader).
    """
    return open_recording(source).episodes_table()


def topic_frame(source: Source, topic: str) -> pl.DataFrame:
    """One row per message of `topic`: t_ns (log time), publish_ns, stamp_ns (header) and the fields.

    Poses: frame_id, x_m, y_m, z_m, yaw_rad (odometry adds child_frame_id, v_mps, w_radps and
    linear_z...); Twist: v_mps, w_radps and the other four components; LaserScan: frame_id, the
    angle (rad), time (s) and range (m) fields, ``ranges_m`` as an Array(Float32, beams) column (a
    List column when the beam count changes), ``intensities`` when recorded; other decodable types
    (:data:`~pipeline.analysis.layouts.DECODABLE`) keep their field names.
    """
    return open_recording(source).topic_frame(topic)


def poses_frame(source: Source, kind: PoseKind = "ground_truth") -> pl.DataFrame:
    """Poses of every robot with robot and episode columns (see :meth:`Recording.poses`)."""
    return open_recording(source).poses(kind)


def events_frame(source: Source) -> pl.DataFrame:
    """The ``/mrl/episode`` events (see :meth:`Recording.events`)."""
    return open_recording(source).events()


def episodes_tables(sources: Iterable[Source]) -> pl.DataFrame:
    """The episodes tables of several recordings, concatenated."""
    tables = [episodes_table(s) for s in sources]
    return pl.concat(tables) if tables else pl.DataFrame(schema=EPISODES_SCHEMA)
