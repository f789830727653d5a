"""One episode's bookkeeping, the same in the simulated world and on a fleet.

The loops differ in where observations come from; what they count does not: the pose of every robot
at each control step (its start, then every step the episode reached: the samples of its path,
:func:`pipeline.core.episode.path_times_ns`), the time each robot reached its goal, path lengths,
the judge's events in the recording, and the episode's result.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pipeline.core.episode import EpisodeResult, path_lengths_m
from pipeline.core.judge import EpisodeJudge, JudgeStep
from pipeline.record.session import SessionLog


class EpisodeTally:
    """Counts one episode: `start` with the first poses, `stepped` with the poses at each later control step,
    `judged` after each judged step, `result` at the end."""

    def __init__(self, episode: int, seed: int, names: Sequence[str], control_period_s: float) -> None:
        self.episode = episode
        self.seed = seed
        self.names = tuple(names)
        self.control_period_s = control_period_s
        self.arrival = np.full(len(self.names), np.nan)
        self.poses: list[np.ndarray] = []
        self.last: JudgeStep | None = None

    def start(self, poses: np.ndarray) -> None:
        """The poses (n_robots, 3) the episode starts from, at control step 0 (ground truth where there is one)."""
        self.poses = [np.array(poses, dtype=float)]

    def stepped(self, poses: np.ndarray) -> None:
        """The poses (n_robots, 3) at the next control step (the path's next sample)."""
        self.poses.append(np.array(poses, dtype=float))

    @property
    def sampled_steps(self) -> int:
        """The control steps whose poses are counted after the start."""
        return len(self.poses) - 1

    def judged(self, judged: JudgeStep, steps: int) -> None:
        """After the judge's `steps`-th step: arrivals (at `steps` control periods)."""
        new = judged.reached & np.isnan(self.arrival)
        self.arrival[new] = steps * self.control_period_s
        self.last = judged

    def log_events(self, log: SessionLog | None, t_ns: int, step: int, judged: JudgeStep) -> None:
        """The judge's goal, collision, timeout and success events at `t_ns` (robot '' for team events)."""
        if log is None:
            return
        for robot, event in judged.events:
            log.event(t_ns, self.episode, step, event, "" if robot < 0 else self.names[robot])

    @property
    def team_success(self) -> bool:
        return bool(self.last.team_success) if self.last is not None else False

    def outcome(self, aborted: bool = False) -> str:
        """The detail of the episode's ``end`` event."""
        if aborted:
            return "aborted"
        return "team_success" if self.team_success else "incomplete"

    def result(
        self,
        judge: EpisodeJudge,
        aborted: bool = False,
        abort_reason: str = "",
        abort_kind: str = "",
        stale_s: np.ndarray | None = None,
    ) -> EpisodeResult:
        """The episode's result; an aborted one keeps the goals reached before the abort, and its team fails."""
        traj = np.stack(self.poses)
        return EpisodeResult(
            episode=self.episode,
            seed=self.seed,
            steps=judge.steps,
            reached=judge.reached.copy(),
            collided=judge.collided.copy(),
            time_to_goal_s=self.arrival.copy(),
            path_length_m=path_lengths_m(traj),
            team_success=self.team_success and not aborted,
            trajectory=traj,
            aborted=aborted,
            abort_reason=abort_reason,
            abort_kind=abort_kind if aborted else "",
            stale_s=np.zeros(len(self.names)) if stale_s is None else np.asarray(stale_s, dtype=float).copy(),
        )
