"""A session's result files and how they are put in place.

`write_metrics` (JSON for dvc metrics) and `write_episodes` (one CSV row per episode and robot)
describe the episodes of one recording. `SessionFolder` keeps them together with it: a session
is written into a staging folder inside its output folder and moved into place file by file only
when it holds data, so the recording, episodes.csv and metrics.json in an output folder always
come from the same session, and a session that fails before its first episode leaves the previous
one untouched.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import shutil
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.core.episode import ABORT_KINDS, EpisodeResult
from pipeline.record.errors import RecordError

STAGING = ".session.partial"
"""The staging folder inside an output folder (hidden from globs of results)."""


def write_metrics(path: Path, metrics: Mapping[str, float | None]) -> None:
    """JSON with NaN written as null (JSON has no NaN). The one writer of metrics.json; :func:`read_session_metrics`
    reads a session's back."""
    clean = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in metrics.items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(clean, indent=2, sort_keys=True) + "\n", encoding="utf-8")


@dataclass(frozen=True)
class Rate:
    """A success rate with its 95 % Wilson interval (NaN where no episode counts)."""

    value: float
    ci_low: float
    ci_high: float


@dataclass(frozen=True)
class SessionMetrics:
    """A session's metrics.json (:func:`pipeline.core.episode.summarize` under one world prefix: ``eval``, ``real``,
    ``scripted``), typed. Rates are over every episode; the ``*_completed`` ones over the episodes not aborted."""

    world: str
    episodes: int
    aborted_episodes: int
    aborted_by_kind: dict[str, int]
    robot_success: Rate
    team_success: Rate
    robot_success_completed: Rate
    team_success_completed: Rate
    collision_rate: float
    mean_time_to_goal_s: float
    robot_success_each: tuple[float, ...]
    """Per robot (robot_1, robot_2, ...), over every episode."""
    stale_s_each: tuple[float, ...]
    """Seconds each robot stood still for want of fresh data, summed over the session."""
    values: dict[str, float]
    """Every figure of the file under its full key (NaN for null), timing figures included."""

    def get(self, key: str) -> float:
        """The figure ``<world>/<key>`` (NaN when the file does not have it)."""
        return self.values.get(f"{self.world}/{key}", math.nan)


SESSION_METRICS_KEYS = ("episodes", "aborted_episodes", "robot_success", "team_success", "collision_rate")
"""The keys every session's metrics.json has under its world prefix (older files without the ``*_completed``
rates, stale seconds or abort kinds read with NaN and zeros there)."""


def session_metrics(flat: Mapping[str, Any], source: str, world: str | None = None) -> SessionMetrics:
    """:class:`SessionMetrics` of flat metrics (a metrics.json's object); RecordError naming `source` and the key."""
    if not isinstance(flat, Mapping):
        raise RecordError(source, "not a metrics file (expected a JSON object of <world>/<figure> numbers)")
    values: dict[str, float] = {}
    for key, value in flat.items():
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise RecordError(source, f"{key}: {value!r} is not a number or null")
        values[str(key)] = math.nan if value is None else float(value)
    if world is None:
        worlds = sorted({k.split("/")[0] for k in values if k.endswith("/robot_success")})
        if len(worlds) != 1:
            raise RecordError(source, f"expected the figures of one session (one <world>/robot_success): {worlds}")
        world = worlds[0]
    missing = [f"{world}/{k}" for k in SESSION_METRICS_KEYS if f"{world}/{k}" not in values]
    if missing:
        raise RecordError(source, f"{', '.join(missing)} missing: not the metrics of a session of {world!r}")

    def get(key: str, default: float = math.nan) -> float:
        return values.get(f"{world}/{key}", default)

    def rate(key: str) -> Rate:
        return Rate(get(key), get(f"{key}_ci_low"), get(f"{key}_ci_high"))

    def each(suffix: str) -> tuple[float, ...]:
        found = {}
        for key, value in values.items():
            name = key[len(world) + 1 :]
            if key.startswith(f"{world}/robot_") and name.endswith(suffix) and name[6 : -len(suffix)].isdigit():
                found[int(name[6 : -len(suffix)])] = value
        return tuple(found[i] for i in sorted(found))

    return SessionMetrics(
        world=world,
        episodes=int(get("episodes")),
        aborted_episodes=int(get("aborted_episodes")),
        aborted_by_kind={kind: int(get(f"aborted_{kind}", 0.0)) for kind in ABORT_KINDS},
        robot_success=rate("robot_success"),
        team_success=rate("team_success"),
        robot_success_completed=rate("robot_success_completed"),
        team_success_completed=rate("team_success_completed"),
        collision_rate=get("collision_rate"),
        mean_time_to_goal_s=get("mean_time_to_goal_s"),
        robot_success_each=each("_success"),
        stale_s_each=each("_stale_s"),
        values=values,
    )


def read_session_metrics(path: str | Path, world: str | None = None) -> SessionMetrics:
    """Read a session's metrics.json (eval_sim, scripted_eval, deploy); RecordError naming the file and the key."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RecordError(str(p), "missing: the session has not been run (or wrote no episode)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RecordError(str(p), f"unreadable or not JSON ({exc})") from exc
    return session_metrics(data, str(p), world)


EPISODES_CSV_COLUMNS = (
    "episode",
    "seed",
    "robot",
    "success",
    "reached",
    "collided",
    "aborted",
    "abort_kind",
    "abort_reason",
    "stale_s",
    "time_to_goal_s",
    "path_length_m",
    "steps",
    "team_success",
    "time_scale_asked",
    "time_scale_realized",
    "control_late_p95",
    "clock_kept",
)
"""The columns of every episodes.csv (sim evaluation, scripted evaluation, deployment), in order. success: the robot
reached its goal without colliding (before the abort, in an aborted episode); team_success: every robot did and the
episode was not aborted; stale_s: the seconds the robot stood still for want of fresh data; path_length_m: metres
along its poses at the episode's control steps (:func:`pipeline.core.episode.path_lengths_m`, which ``mrl episodes``
reads back from the recording the same way); time_scale_asked and time_scale_realized: the hardware twin's time
scale asked for and realized in the episode (empty without a twin); control_late_p95: how late the runner's control
steps woke, the 95th percentile as a share of the control period (empty in the simulator); clock_kept: 0 where the
twin fell behind its clock or the control steps woke late (the episode measures the host, not the policy)."""
EPISODES_CSV_BEFORE_CLOCK = EPISODES_CSV_COLUMNS[:-4]
"""The layout of episodes.csv files written before the twin's clock was recorded: read with the clock columns
empty and kept."""


def write_episodes(path: Path, results: list[EpisodeResult]) -> None:
    """One row per (episode, robot) with the columns of :data:`EPISODES_CSV_COLUMNS`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(EPISODES_CSV_COLUMNS)
        for r in results:
            stale = r.stale_per_robot_s
            for i in range(len(r.reached)):
                t = r.time_to_goal_s[i]
                out.writerow(
                    [
                        r.episode,
                        r.seed,
                        f"robot_{i + 1}",
                        int(r.success[i]),
                        int(r.reached[i]),
                        int(r.collided[i]),
                        int(r.aborted),
                        r.abort_kind,
                        r.abort_reason,
                        f"{stale[i]:.3f}",
                        "" if np.isnan(t) else f"{t:.3f}",
                        f"{r.path_length_m[i]:.4f}",
                        r.steps,
                        int(r.team),
                        "" if np.isnan(r.time_scale_asked) else f"{r.time_scale_asked:g}",
                        "" if np.isnan(r.time_scale_realized) else f"{r.time_scale_realized:.4f}",
                        "" if np.isnan(r.control_late_p95) else f"{r.control_late_p95:.4f}",
                        int(r.clock_kept),
                    ]
                )


EPISODES_CSV_TYPES = {
    "episode": int,
    "seed": int,
    "robot": str,
    "success": int,
    "reached": int,
    "collided": int,
    "aborted": int,
    "abort_kind": str,
    "abort_reason": str,
    "stale_s": float,
    "time_to_goal_s": float,
    "path_length_m": float,
    "steps": int,
    "team_success": int,
    "time_scale_asked": float,
    "time_scale_realized": float,
    "control_late_p95": float,
    "clock_kept": int,
}
"""The value type of each column of :data:`EPISODES_CSV_COLUMNS` (flags as 0 or 1; an empty time to goal: the robot
did not arrive)."""


def read_episodes_csv(path: str | Path) -> list[dict[str, Any]]:
    """The rows of an episodes.csv (sessions, ``mrl episodes --out``), typed; RecordError naming the file, the row
    and the column for another layout or a bad value (files of the earlier layout lack ``abort_kind`` and
    ``stale_s``: written before every episode counted, re-counted by benchmarks/recount.py; those written before the
    twin's clock was recorded are read with empty clock columns, kept)."""
    p = Path(path)
    try:
        with p.open(newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            header = tuple(reader.fieldnames or ())
            earlier = header == EPISODES_CSV_BEFORE_CLOCK
            if header != EPISODES_CSV_COLUMNS and not earlier:
                raise RecordError(
                    str(p), f"columns {list(header)}; an episodes.csv has {list(EPISODES_CSV_COLUMNS)}, in that order"
                )
            rows = []
            for line, raw in enumerate(reader, start=2):
                row: dict[str, Any] = {}
                for column, kind in EPISODES_CSV_TYPES.items():
                    text = raw.get(column, "1" if column == "clock_kept" else "") if earlier else raw[column]
                    try:
                        row[column] = math.nan if (kind is float and text == "") else kind(text)
                    except (TypeError, ValueError):
                        raise RecordError(str(p), f"line {line}, {column}: {text!r} is not {kind.__name__}") from None
                rows.append(row)
    except FileNotFoundError:
        raise RecordError(str(p), "missing: the session has not been run (or wrote no episode)") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise RecordError(str(p), f"unreadable ({exc})") from exc
    return rows


class SessionFolder:
    """The output folder of one session, written through a staging folder.

    ``staged(name)`` is where a file of the new session is written; ``publish()`` moves the previous
    session's files (those of `owned`) aside into ``previous-<time of its recording>`` and then every
    staged file into the folder, so the folder always holds one session, the latest, and no run removes
    or replaces a recording that an earlier run finished. A staging folder left by a killed run is kept
    under ``interrupted-<time>`` rather than reused. A session that never starts leaves the folder as it
    was (one it had to create is removed again).
    """

    def __init__(self, out_dir: str | Path, owned: Iterable[str] = ()) -> None:
        self.out_dir = Path(out_dir)
        self.staging = self.out_dir / STAGING
        self.owned = tuple(owned)
        self.kept_interrupted: Path | None = None
        self.kept_previous: Path | None = None
        self._created = False

    def kept(self) -> list[Path]:
        """The earlier sessions kept aside in the folder (``previous-*`` and ``interrupted-*``), oldest first."""
        if not self.out_dir.is_dir():
            return []
        found = [p for p in self.out_dir.iterdir() if p.is_dir() and p.name.startswith(("previous-", "interrupted-"))]
        return sorted(found, key=lambda p: p.stat().st_mtime)

    def open(self) -> SessionFolder:
        """Create the staging folder (keeping one left by a killed run)."""
        try:
            self._created = not self.out_dir.exists()
            if self.staging.exists():
                self.keep_as_interrupted()
            self.staging.mkdir(parents=True)
        except OSError as exc:
            raise RecordError(str(self.out_dir), f"cannot write the session's output folder ({exc.strerror})") from exc
        return self

    def keep_as_interrupted(self) -> Path:
        """Move the staging folder aside as ``interrupted-<time of its last change>``; returns its new path."""
        stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(self.staging.stat().st_mtime))
        target = self.out_dir / f"interrupted-{stamp}"
        n = 1
        while target.exists():
            n += 1
            target = self.out_dir / f"interrupted-{stamp}-{n}"
        self.staging.rename(target)
        self.kept_interrupted = target
        return target

    def staged(self, name: str) -> Path:
        return self.staging / name

    def _keep_previous(self) -> None:
        """Move the previous session's files into ``previous-<time of its recording>``."""
        present = [self.out_dir / name for name in self.owned if (self.out_dir / name).is_file()]
        if not present:
            return
        stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(max(p.stat().st_mtime for p in present)))
        target = self.out_dir / f"previous-{stamp}"
        n = 1
        while target.exists():
            n += 1
            target = self.out_dir / f"previous-{stamp}-{n}"
        target.mkdir()
        for path in present:
            os.replace(path, target / path.name)
        self.kept_previous = target

    def publish(self) -> list[Path]:
        """Keep the previous session aside, then move the staged files into the output folder; their final paths."""
        written = sorted(p.name for p in self.staging.iterdir() if p.is_file())
        self._keep_previous()
        out = []
        for name in written:
            target = self.out_dir / name
            os.replace(self.staging / name, target)
            out.append(target)
        shutil.rmtree(self.staging, ignore_errors=True)
        return out

    def discard(self) -> None:
        """Drop the staged files (nothing of the session is worth keeping); a folder created for them goes too."""
        shutil.rmtree(self.staging, ignore_errors=True)
        if self._created:
            with contextlib.suppress(OSError):
                self.out_dir.rmdir()  # only when empty
