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
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from pipeline.core.episode import EpisodeResult
from pipeline.record.errors import RecordError

STAGING = ".session.partial"
"""The staging folder inside an output folder (hidden from globs of results)."""


def write_metrics(path: Path, metrics: dict[str, float]) -> None:
    """JSON with NaN written as null (JSON has no NaN)."""
    clean = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in metrics.items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(clean, indent=2, sort_keys=True) + "\n", encoding="utf-8")


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
)
"""The columns of every episodes.csv (sim evaluation, scripted evaluation, deployment), in order. success: the robot
reached its goal without colliding (before the abort, in an aborted episode); team_success: every robot did and the
episode was not aborted; stale_s: the seconds the robot stood still for want of fresh data."""


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
                    ]
                )


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
