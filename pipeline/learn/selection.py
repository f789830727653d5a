"""Choosing the weights training hands to export: periodic deterministic evaluations from the exact starts.

Training episodes start from perturbed poses and act stochastically, so their success says little
about the one deterministic policy that will be deployed from the exact starts. Every
`selection.every_steps` world steps the learners' greedy policy drives `selection.episodes`
episodes in a simulator of its own (the training worlds are not touched, nor any random state of
training, so training goes on bit for bit as without evaluations); each evaluation is a row of
``selection.csv``. With `keep: best` the weights of the best evaluation are kept in memory and
become the checkpoint.
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import torch as th

from pipeline.core.episode import summarize
from pipeline.core.scenario import Scenario
from pipeline.learn.common.modes import deterministic_actions
from pipeline.params import SelectionConfig, WorldConfig
from pipeline.rollout.sim import evaluate
from pipeline.sim.env import MultiRobotSim

SELECTION_FILE = "selection.csv"
StateDicts = list[dict[str, th.Tensor]]


def greedy_policy(
    models: Sequence[Any], mode: str, n_robots: int, discrete: bool, n_discrete: int
) -> Callable[[np.ndarray], np.ndarray]:
    """The learners' deterministic policy as ``obs (n_robots, obs_size) -> actions`` for the simulator."""
    policies = [m.policy for m in models]

    def act(obs: np.ndarray) -> np.ndarray:
        batch = deterministic_actions(policies, mode, n_robots, discrete, n_discrete, np.asarray(obs)[None])
        return np.asarray(batch[0])

    return act


@dataclass(frozen=True)
class Evaluation:
    world_steps: int
    episodes: int
    robot_success: float
    team_success: float
    collision_rate: float

    def key(self) -> tuple[float, float, int]:
        """Better evaluations compare greater; ties go to the later."""
        return (round(self.robot_success, 9), round(self.team_success, 9), self.world_steps)


class Selector:
    """Runs the evaluations, writes ``selection.csv`` and keeps the best weights (with `keep: best`)."""

    def __init__(self, cfg: SelectionConfig, scenario: Scenario, world: WorldConfig, out_dir: Path) -> None:
        self.cfg = cfg
        self.sim = MultiRobotSim(scenario, world)
        self.path = out_dir / SELECTION_FILE
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: TextIO = self.path.open("w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._file)
        self._csv.writerow(["world_steps", "episodes", "robot_success", "team_success", "collision_rate", "kept"])
        self.best: Evaluation | None = None
        self.best_state: StateDicts | None = None
        self._next = cfg.every_steps
        self.evaluations: list[Evaluation] = []

    @property
    def enabled(self) -> bool:
        return self.cfg.every_steps > 0

    def due(self, world_steps: int) -> bool:
        return self.enabled and world_steps >= self._next

    def offer(self, world_steps: int, policy: Callable[[np.ndarray], np.ndarray], models: Sequence[Any]) -> Evaluation:
        """Evaluate the current weights; keep a copy of them when they are the best so far."""
        while self._next <= world_steps:
            self._next += self.cfg.every_steps
        results = evaluate(self.sim, policy, self.cfg.episodes, self.cfg.seed, progress=False)
        m = summarize(results, prefix="e")
        ev = Evaluation(world_steps, len(results), m["e/robot_success"], m["e/team_success"], m["e/collision_rate"])
        kept = self.best is None or ev.key() > self.best.key()
        if kept:
            self.best = ev
            if self.cfg.keep == "best":
                self.best_state = [
                    {k: v.detach().clone() for k, v in model.policy.state_dict().items()} for model in models
                ]
        self.evaluations.append(ev)
        self._csv.writerow(
            [
                world_steps,
                ev.episodes,
                f"{ev.robot_success:.4f}",
                f"{ev.team_success:.4f}",
                f"{ev.collision_rate:.4f}",
                int(kept),
            ]
        )
        self._file.flush()
        return ev

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()
