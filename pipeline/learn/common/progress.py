"""Training progress: the convergence criterion and the per-episode learning curve."""

from __future__ import annotations

import csv
from collections import deque
from pathlib import Path
from typing import TextIO

import numpy as np

from pipeline.learn.common.worlds import EpisodeRecord


class ConvergenceTracker:
    """The paper's criterion: converged once every robot succeeded in more than `threshold` of the last `window`
    episodes (with 20 episodes and 0.8: at least 17 successes each).

    Episodes are counted in the order worlds finish them. `converged_at` is the 1-based index of
    the first episode at which the criterion holds (None until then).
    """

    def __init__(self, n_robots: int, window: int = 20, threshold: float = 0.8) -> None:
        self.window = window
        self.threshold = threshold
        self.history: deque[np.ndarray] = deque(maxlen=window)
        self.episodes = 0
        self.converged_at: int | None = None
        self.n_robots = n_robots

    def update(self, success: np.ndarray) -> bool:
        """Add one episode's per-robot success (n_robots,); True when the criterion holds now."""
        self.episodes += 1
        self.history.append(np.asarray(success, dtype=bool))
        holds = len(self.history) == self.window and bool((self.rates() > self.threshold + 1e-12).all())
        if holds and self.converged_at is None:
            self.converged_at = self.episodes
        return holds

    def rates(self) -> np.ndarray:
        """(n_robots,) success rate of each robot over the window so far."""
        if not self.history:
            return np.zeros(self.n_robots)
        return np.asarray(np.mean(np.stack(self.history), axis=0))


class LearningCurve:
    """Writes one CSV row per finished episode, for ``dvc plots`` and the report.

    Columns: episode, world_steps, world, seed, length, return_<robot>..., success_<robot>...,
    team_success, robot_success (mean over robots), robot_success_window (mean over the
    convergence window).
    """

    def __init__(self, path: Path, robots: tuple[str, ...]) -> None:
        self.path = path
        self.robots = robots
        path.parent.mkdir(parents=True, exist_ok=True)
        self._file: TextIO = path.open("w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._file)
        self._csv.writerow(
            ["episode", "world_steps", "world", "seed", "length"]
            + [f"return_{r}" for r in robots]
            + [f"success_{r}" for r in robots]
            + ["team_success", "robot_success", "robot_success_window"]
        )

    def add(self, episode: int, world_steps: int, record: EpisodeRecord, window_rate: float) -> None:
        success = record.success
        self._csv.writerow(
            [episode, world_steps, record.world, record.seed, record.steps]
            + [f"{r:.4f}" for r in record.returns]
            + [int(s) for s in success]
            + [int(record.team_success), f"{success.mean():.4f}", f"{window_rate:.4f}"]
        )

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()
