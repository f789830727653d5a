"""Parallel simulated worlds stepped in lockstep, with per-robot transitions for the learners.

Each world is one :class:`~pipeline.sim.env.MultiRobotSim`. A world's episode ends when every
robot is done (goal or collision) or at the step limit; the world then starts its next episode
with a seed drawn from the trainer's seed, so a training run is fixed by its seed. Robots that are
done before their world's episode ends are *inactive*: their transitions are not training data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.core.scenario import Scenario, perturbed_starts
from pipeline.params import WorldConfig
from pipeline.sim.env import MultiRobotSim


@dataclass(frozen=True)
class EpisodeRecord:
    """One finished episode of one world; per-robot arrays are (n_robots,)."""

    world: int
    seed: int
    steps: int
    returns: np.ndarray
    reached: np.ndarray
    collided: np.ndarray
    team_success: bool

    @property
    def success(self) -> np.ndarray:
        """(n_robots,) robots inside their goal without a collision."""
        return np.asarray(self.reached & ~self.collided)


@dataclass(frozen=True)
class WorldsStep:
    """The outcome of one lockstep control step of every world; shapes (n_worlds, n_robots[, obs_size]).

    `next_obs` is each robot's observation at the end of the step (before any reset): the
    transition's successor. `obs` is what the policy sees next: the first observation of a new
    episode in worlds that ended.
    """

    obs: np.ndarray
    next_obs: np.ndarray
    reward: np.ndarray
    active: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    world_ended: np.ndarray
    finished: list[EpisodeRecord]


TRAIN_SEED_MIN = 2**30
"""Training episodes' seeds start here; evaluation, selection and deployment seeds lie below."""


class VecWorlds:
    """`n_worlds` copies of one scenario, stepped together."""

    def __init__(
        self,
        scenario: Scenario,
        world: WorldConfig,
        n_worlds: int,
        seed: int,
        start_xy_m: float = 0.0,
        start_yaw_rad: float = 0.0,
    ) -> None:
        """`start_xy_m`, `start_yaw_rad`: each episode starts every robot this far (uniformly) from its start pose."""
        if n_worlds < 1:
            raise ValueError(f"n_worlds must be >= 1, got {n_worlds}")
        self.scenario = scenario
        self.config = world
        self.sims = [MultiRobotSim(scenario, world) for _ in range(n_worlds)]
        self.n_worlds = n_worlds
        self.n_robots = scenario.n_robots
        self.obs_size = self.sims[0].layout.size
        self.codec = self.sims[0].codec
        self._seeds = np.random.default_rng(seed)
        self._starts = np.random.default_rng([seed, 1])
        self.start_xy_m = start_xy_m
        self.start_yaw_rad = start_yaw_rad
        self._episode_seed = np.zeros(n_worlds, dtype=np.int64)
        self._returns = np.zeros((n_worlds, self.n_robots))
        self._obs = np.zeros((n_worlds, self.n_robots, self.obs_size), dtype=np.float32)

    def _next_seed(self) -> int:
        # training seeds are >= TRAIN_SEED_MIN, evaluation seeds below it: random layouts drawn from the seeds
        # of evaluation episodes are never among those trained on
        return int(self._seeds.integers(TRAIN_SEED_MIN, 2**31 - 1))

    def _reset_world(self, j: int) -> np.ndarray:
        self._episode_seed[j] = self._next_seed()
        sim = self.sims[j]
        if sim.random_layouts:  # the layout's own starts are already a draw
            return sim.reset(int(self._episode_seed[j]))
        starts = perturbed_starts(self.scenario, self._starts, self.start_xy_m, self.start_yaw_rad)
        return sim.reset(int(self._episode_seed[j]), starts)

    def reset(self) -> np.ndarray:
        """Start every world's first episode; returns observations (n_worlds, n_robots, obs_size)."""
        for j in range(self.n_worlds):
            self._obs[j] = self._reset_world(j)
        self._returns[:] = 0.0
        return self._obs.copy()

    def step(self, actions: np.ndarray) -> WorldsStep:
        """Advance every world one control period; `actions` is (n_worlds, n_robots, 2) or (n_worlds, n_robots)."""
        k, n = self.n_worlds, self.n_robots
        next_obs = np.empty((k, n, self.obs_size), dtype=np.float32)
        reward = np.zeros((k, n))
        active = np.zeros((k, n), dtype=bool)
        terminated = np.zeros((k, n), dtype=bool)
        truncated = np.zeros((k, n), dtype=bool)
        ended = np.zeros(k, dtype=bool)
        finished: list[EpisodeRecord] = []
        for j, sim in enumerate(self.sims):
            result = sim.step(actions[j])
            judged = result.judge
            next_obs[j] = result.obs
            act = judged.active
            active[j] = act
            reward[j] = np.where(act, judged.reward, 0.0)
            self._returns[j] += reward[j]
            newly_done = act & judged.done
            terminated[j] = newly_done
            if judged.truncated:
                truncated[j] = act & ~newly_done
            if judged.truncated or judged.done.all():
                ended[j] = True
                finished.append(
                    EpisodeRecord(
                        world=j,
                        seed=int(self._episode_seed[j]),
                        steps=sim.judge.steps,
                        returns=self._returns[j].copy(),
                        reached=judged.reached.copy(),
                        collided=judged.collided.copy(),
                        team_success=judged.team_success,
                    )
                )
                self._obs[j] = self._reset_world(j)
                self._returns[j] = 0.0
            else:
                self._obs[j] = result.obs
        return WorldsStep(
            obs=self._obs.copy(),
            next_obs=next_obs,
            reward=reward,
            active=active,
            terminated=terminated,
            truncated=truncated,
            world_ended=ended,
            finished=finished,
        )
