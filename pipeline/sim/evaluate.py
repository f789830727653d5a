"""Run episodes of a policy in the simulated world and summarise robot- and team-level success."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from pipeline.analysis.stats import wilson_interval
from pipeline.sim.env import MultiRobotSim

Policy = Callable[[np.ndarray], np.ndarray]
"""Maps observations (n_robots, obs_size) to actions for the action codec."""


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

    @property
    def success(self) -> np.ndarray:
        return np.asarray(self.reached & ~self.collided)


def run_episode(sim: MultiRobotSim, policy: Policy, seed: int, episode: int = 0) -> EpisodeResult:
    """One episode of `policy` from reset(seed) to the end (all done or the step limit)."""
    obs = sim.reset(seed)
    n = sim.n
    poses = [sim.world.truth.copy()]
    arrival = np.full(n, np.nan)
    while True:
        result = sim.step(policy(obs))
        obs = result.obs
        poses.append(sim.world.truth.copy())
        judged = result.judge
        new = judged.reached & np.isnan(arrival)
        arrival[new] = sim.judge.steps * sim.world_config.control_period_s
        if judged.done.all() or judged.truncated:
            break
    traj = np.array(poses)
    steps_xy = np.diff(traj[:, :, :2], axis=0)
    return EpisodeResult(
        episode=episode,
        seed=seed,
        steps=sim.judge.steps,
        reached=judged.reached.copy(),
        collided=judged.collided.copy(),
        time_to_goal_s=arrival,
        path_length_m=np.hypot(steps_xy[..., 0], steps_xy[..., 1]).sum(axis=0),
        team_success=judged.team_success,
        trajectory=traj,
    )


def evaluate(
    sim: MultiRobotSim, policy: Policy, episodes: int, seed: int, progress: bool = True
) -> list[EpisodeResult]:
    """`episodes` episodes with seeds seed, seed+1, ...; shows a progress bar when `progress`."""
    results = []
    bar = tqdm(range(episodes), desc="eval", unit="ep", disable=not progress)
    for k in bar:
        results.append(run_episode(sim, policy, seed + k, k))
        robot = np.mean([r.success.mean() for r in results])
        bar.set_postfix(robot_success=f"{robot:.2f}")
    return results


def summarize(results: list[EpisodeResult], prefix: str = "eval") -> dict[str, float]:
    """Robot- and team-level success with 95 % Wilson intervals, collisions, time to goal."""
    if not results:
        raise ValueError("no episodes to summarise")
    success = np.stack([r.success for r in results])
    collided = np.stack([r.collided for r in results])
    team = np.array([r.team_success for r in results])
    times = np.concatenate([r.time_to_goal_s[r.success] for r in results])
    robot_k, robot_n = int(success.sum()), int(success.size)
    team_k, team_n = int(team.sum()), int(team.size)
    out = {
        "episodes": float(len(results)),
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
