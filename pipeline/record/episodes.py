"""Episodes of a session recording, read back from its ``/mrl/episode`` events: one reader for every tool.

:class:`~pipeline.record.session.SessionLog` writes the events; :func:`episode_windows` turns them
into :class:`EpisodeWindow` by one rule, in log-time order:

- a ``start`` opens an episode. Its seed is the event's ``seed`` field; where that is -1 (recordings
  made before the field existed read as -1 too), the ``seed=<n>`` its ``detail`` carried then
  (:func:`legacy_seed`); else unknown (None);
- an ``end`` of the open episode closes it: ``finished``;
- a team-level ``abort`` (empty robot) of the open episode closes it: ``aborted``, its detail the
  reason. A robot's ``abort`` adds ``"<robot>: <detail>"`` to the abort reasons and closes nothing;
- a ``start`` while an episode is open ends the open one at the new start's log time - 1: ``unfinished``;
- the episode still open where the file stops is ``unfinished``, without an end (``end_ns`` None);
- events of any other episode than the open one (its start is not in the file, or it is closed
  already) are ignored.

Which outcomes a tool uses is its choice, stated where it reads the windows: the analysis tables
keep every window (:mod:`pipeline.analysis.tables`), calibration leaves out the windows a new start
cut short (:mod:`pipeline.calibration.recording`), open-loop replay uses the finished ones
(:mod:`pipeline.analysis.replay`).

Times are log times: integer ns on the recording's clock (see :mod:`pipeline.record.session`).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Literal, NamedTuple

from pipeline.messages import topics as T
from pipeline.messages.convert import EVENT_NAMES, NO_SEED
from pipeline.record.errors import MissingTopicError, TopicTypeError
from pipeline.record.reader import McapLog

EPISODE_TOPIC = T.FLEET_TOPICS["episode"].name
"""``/mrl/episode``."""
Outcome = Literal["finished", "aborted", "unfinished"]
"""How an episode's window closed: by its ``end`` event, by a team-level ``abort``, or not at all."""
OUTCOMES: tuple[Outcome, ...] = ("finished", "aborted", "unfinished")
_LEGACY_SEED = re.compile(r"(?:^|[\s,;])seed=(-?\d+)")


class EventRow(NamedTuple):
    """One ``/mrl/episode`` event: log time (ns), episode, control step, robot ('' for team-level events),
    event name (``start``, ``goal``, ..., ``event_<code>`` for an unknown code), detail, seed (-1: none)."""

    t_ns: int
    episode: int
    step: int
    robot: str
    event: str
    detail: str
    seed: int = NO_SEED


@dataclass(frozen=True)
class EpisodeWindow:
    """One episode as its events delimit it (see the module's rule).

    `start_ns` and `end_ns` are the log times (ns) of its start and of the event that closed it;
    `end_ns` is the next start's log time - 1 when a new start cut it short, None when the file
    stops inside it. `end_step` is the control step of the closing event (None when unfinished),
    `end_detail` the detail of its ``end`` event ('' otherwise), `abort_reasons` the team abort's
    detail and ``"<robot>: <detail>"`` of robots' aborts, in order. `events` are the episode's
    events from its start to the one that closed it, in log-time order.
    """

    episode: int
    seed: int | None
    start_ns: int
    end_ns: int | None
    outcome: Outcome
    abort_reasons: tuple[str, ...] = ()
    end_detail: str = ""
    end_step: int | None = None
    events: tuple[EventRow, ...] = ()


def legacy_seed(detail: str) -> int | None:
    """The seed a start event's `detail` carried as ``seed=<n>`` before the ``seed`` field existed, else None."""
    found = _LEGACY_SEED.search(detail)
    return int(found.group(1)) if found else None


def start_seed(event: EventRow) -> int | None:
    """The seed of a start event: its ``seed`` field, else (-1) the legacy ``seed=<n>`` of its detail, else None."""
    return event.seed if event.seed >= 0 else legacy_seed(event.detail)


class _Open:
    """The episode being read: its start and the events so far."""

    def __init__(self, start: EventRow) -> None:
        self.start = start
        self.events: list[EventRow] = [start]
        self.reasons: list[str] = []

    def close(self, outcome: Outcome, end_ns: int | None, end: EventRow | None = None) -> EpisodeWindow:
        return EpisodeWindow(
            episode=self.start.episode,
            seed=start_seed(self.start),
            start_ns=self.start.t_ns,
            end_ns=end_ns,
            outcome=outcome,
            abort_reasons=tuple(self.reasons),
            end_detail=end.detail if end is not None and end.event == "end" else "",
            end_step=None if end is None else end.step,
            events=tuple(self.events),
        )


def episode_windows(events: Iterable[EventRow]) -> list[EpisodeWindow]:
    """The episodes of `events` (in log-time order, as a recording holds them) by the module's rule, in start order."""
    windows: list[EpisodeWindow] = []
    current: _Open | None = None
    for row in events:
        if row.event == "start":
            if current is not None:
                windows.append(current.close("unfinished", row.t_ns - 1))
            current = _Open(row)
            continue
        if current is None or row.episode != current.start.episode:
            continue  # an episode whose start is not in the file, or that is closed already
        current.events.append(row)
        if row.event == "end":
            windows.append(current.close("finished", row.t_ns, row))
            current = None
        elif row.event == "abort":
            current.reasons.append(f"{row.robot}: {row.detail}" if row.robot else row.detail)
            if not row.robot:
                windows.append(current.close("aborted", row.t_ns, row))
                current = None
    if current is not None:
        windows.append(current.close("unfinished", None))
    return windows


def recorded_events(log: McapLog) -> Iterator[EventRow]:
    """The ``/mrl/episode`` events of `log` in log-time order (recordings of any version of the type).

    Raises:
        MissingTopicError: the recording has no ``/mrl/episode``.
        TopicTypeError: it carries another type than ``mrl_msgs/msg/EpisodeEvent``.
    """
    where = str(log.path)
    found = log.topics().get(EPISODE_TOPIC)
    if found is None:
        raise MissingTopicError(where, [EPISODE_TOPIC], "the episodes")
    if found != T.EPISODE_EVENT:
        raise TopicTypeError(where, EPISODE_TOPIC, found, T.EPISODE_EVENT)
    for m in log.messages([EPISODE_TOPIC]):
        msg = m.msg
        code = int(msg.event)
        yield EventRow(
            t_ns=m.log_time_ns,
            episode=int(msg.episode),
            step=int(msg.step),
            robot=str(msg.robot),
            event=EVENT_NAMES.get(code, f"event_{code}"),
            detail=str(msg.detail),
            seed=int(getattr(msg, "seed", NO_SEED)),  # recordings made before the field lack it
        )


def read_episode_windows(log: McapLog) -> list[EpisodeWindow]:
    """The episodes of a recording (see :func:`episode_windows`); errors as :func:`recorded_events`."""
    return episode_windows(recorded_events(log))
