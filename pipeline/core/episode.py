"""Episode outcomes and their summary, shared by sim evaluation and deployment."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.core.stats import wilson_interval


@dataclass(frozen=True)
class EpisodeResult:
    """One episode; per-robot arrays are (n_robots,)."""

    episode: int
    seed: int
    steps: int
    reached: np.ndarray
    collided: np.ndarray
    time_to_goal_s: np.ndarray  # nan where the goal was not reached
    path_length_m: np.ndarray
    team_success: bool
    trajectory: np.ndarray  # (steps + 1, n_robots, 3) ground-truth poses
    aborted: bool = False
    abort_reason: str = ""

    @property
    def success(self) -> np.ndarray:
        return np.asarray(self.reached & ~self.collided)


def summarize(results: list[EpisodeResult], prefix: str = "eval") -> dict[str, float]:
    """Robot- and team-level success with 95 % Wilson intervals, collisions, time to goal.

    Aborted episodes (a robot went silent, the session was stopped) are counted but are not
    trials: the rates are over the finished episodes.
    """
    if not results:
        raise ValueError("no episodes to summarise")
    aborted = sum(r.aborted for r in results)
    finished = [r for r in results if not r.aborted]
    if not finished:
        return {f"{prefix}/episodes": float(len(results)), f"{prefix}/aborted_episodes": float(aborted)}
    results = finished
    success = np.stack([r.success for r in results])
    collided = np.stack([r.collided for r in results])
    team = np.array([r.team_success for r in results])
    times = np.concatenate([r.time_to_goal_s[r.success] for r in results])
    robot_k, robot_n = int(success.sum()), int(success.size)
    team_k, team_n = int(team.sum()), int(team.size)
    out = {
        "episodes": float(len(results) + aborted),
        "aborted_episodes": float(aborted),
        "robot_success": robot_k / robot_n,
        "robot_success_ci_low": wilson_interval(robot_k, robot_n)[0],
        "robot_success_ci_high": wilson_interval(robot_k, robot_n)[1],
        "team_success": team_k / team_n,
        "team_success_ci_low": wilson_interval(team_k, team_n)[0],
        "team_success_ci_high": wilson_interval(team_k, team_n)[1],
        "collision_rate": float(collided.mean()),
        "mean_time_to_goal_s": float(times.mean()) if times.size else float("nan"),
    }
    for i in range(success.shape[1]):
        out[f"robot_{i + 1}_success"] = float(success[:, i].mean())
    return {f"{prefix}/{k}": v for k, v in out.items()}
