"""Multi-agent modes: how the robots of the parallel worlds map onto learners and their streams.

``independent``: one learner per robot (own network, own buffer), fed by that robot's
transitions in every world: n_robots learners with n_worlds streams each.
``shared``: one learner, every robot of every world a stream (n_worlds * n_robots streams); the
observation must tell robots apart (the ``rich`` layout carries the goal).
``centralized``: one learner over the joint observation (n_robots * obs_size) and joint action
((2 * n_robots,) continuous, or one index over all k ** n_robots combinations, robot_1 the most
significant digit), one stream per world, reward summed over robots.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np

from pipeline.learn.common.worlds import VecWorlds, WorldsStep
from pipeline.params import Mode


@dataclass(frozen=True)
class StreamBatch:
    """One learner's slice of a lockstep step; arrays are (n_streams, ...)."""

    next_obs: np.ndarray
    reward: np.ndarray
    active: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray


class StreamMap:
    """Splits world arrays into learner streams and joins learner actions back into world actions."""

    def __init__(self, mode: Mode, worlds: VecWorlds) -> None:
        self.mode = mode
        self.n_worlds = worlds.n_worlds
        self.n_robots = worlds.n_robots
        self.obs_size = worlds.obs_size
        self.codec = worlds.codec
        low, high = worlds.obs_low, worlds.obs_high
        discrete = self.codec.kind == "discrete"
        robot_action: gymnasium.Space[Any] = (
            gymnasium.spaces.Discrete(self.codec.n_discrete)
            if discrete
            else gymnasium.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        )
        if mode == "centralized":
            n = self.n_robots
            self.observation_space = gymnasium.spaces.Box(np.tile(low, n), np.tile(high, n), dtype=np.float32)
            self.action_space: gymnasium.Space[Any] = (
                gymnasium.spaces.Discrete(self.codec.n_discrete**n)
                if discrete
                else gymnasium.spaces.Box(-1.0, 1.0, shape=(2 * n,), dtype=np.float32)
            )
        else:
            self.observation_space = gymnasium.spaces.Box(low, high, dtype=np.float32)
            self.action_space = robot_action

    @property
    def n_learners(self) -> int:
        return self.n_robots if self.mode == "independent" else 1

    @property
    def n_streams(self) -> int:
        """Streams per learner."""
        return self.n_worlds * self.n_robots if self.mode == "shared" else self.n_worlds

    def learner_obs(self, obs: np.ndarray) -> list[np.ndarray]:
        """Per learner (n_streams, obs_size) from world observations (n_worlds, n_robots, obs_size)."""
        if self.mode == "independent":
            return [obs[:, i, :] for i in range(self.n_robots)]
        if self.mode == "shared":
            return [obs.reshape(-1, self.obs_size)]
        return [obs.reshape(self.n_worlds, -1)]

    def learner_batches(self, step: WorldsStep) -> list[StreamBatch]:
        if self.mode == "independent":
            return [
                StreamBatch(
                    next_obs=step.next_obs[:, i, :],
                    reward=step.reward[:, i],
                    active=step.active[:, i],
                    terminated=step.terminated[:, i],
                    truncated=step.truncated[:, i],
                )
                for i in range(self.n_robots)
            ]
        if self.mode == "shared":
            return [
                StreamBatch(
                    next_obs=step.next_obs.reshape(-1, self.obs_size),
                    reward=step.reward.reshape(-1),
                    active=step.active.reshape(-1),
                    terminated=step.terminated.reshape(-1),
                    truncated=step.truncated.reshape(-1),
                )
            ]
        truncated = np.asarray(step.truncated.any(axis=1))
        return [
            StreamBatch(
                next_obs=step.next_obs.reshape(self.n_worlds, -1),
                reward=step.reward.sum(axis=1),
                active=np.ones(self.n_worlds, dtype=bool),
                terminated=np.asarray(step.world_ended & ~truncated),
                truncated=truncated,
            )
        ]

    def world_actions(self, actions: list[np.ndarray]) -> np.ndarray:
        """World actions (n_worlds, n_robots, 2) or (n_worlds, n_robots) from each learner's actions."""
        k, n = self.n_worlds, self.n_robots
        discrete = self.codec.kind == "discrete"
        if self.mode == "independent":
            stacked = np.stack([np.asarray(a) for a in actions], axis=1)
            return stacked.reshape(k, n) if discrete else stacked.reshape(k, n, 2)
        if self.mode == "shared":
            a = np.asarray(actions[0])
            return a.reshape(k, n) if discrete else a.reshape(k, n, 2)
        a = np.asarray(actions[0])
        if not discrete:
            return a.reshape(k, n, 2)
        return joint_to_robot_actions(a.reshape(k), self.codec.n_discrete, n)

    def learner_actions(self, world_actions: np.ndarray) -> list[np.ndarray]:
        """Per learner its actions from world actions (n_worlds, n_robots, 2) or (n_worlds, n_robots): the
        inverse of :meth:`world_actions`."""
        a = np.asarray(world_actions)
        discrete = self.codec.kind == "discrete"
        if self.mode == "independent":
            return [a[:, i] for i in range(self.n_robots)]
        if self.mode == "shared":
            return [a.reshape(self.n_worlds * self.n_robots, *a.shape[2:])]
        if not discrete:
            return [a.reshape(self.n_worlds, -1)]
        powers = self.codec.n_discrete ** np.arange(self.n_robots - 1, -1, -1, dtype=np.int64)
        return [(a.astype(np.int64) * powers[None, :]).sum(axis=1)]


def joint_to_robot_actions(index: np.ndarray, k: int, n_robots: int) -> np.ndarray:
    """(batch, n_robots) discrete actions from joint indices (batch,) over k ** n_robots (robot_1 most significant)."""
    idx = np.asarray(index, dtype=np.int64).reshape(-1)
    powers = k ** np.arange(n_robots - 1, -1, -1, dtype=np.int64)
    return np.asarray((idx[:, None] // powers[None, :]) % k)


def deterministic_actions(
    policies: Sequence[Any], mode: str, n_robots: int, discrete: bool, n_discrete: int, obs: np.ndarray
) -> np.ndarray:
    """Per-robot actions (samples, n_robots, 2) or (samples, n_robots) of the learners' policies for
    observations (samples, n_robots, obs_size), as the training library's deterministic ``predict``
    gives them (continuous actions clipped to the Box)."""

    def predict(policy: Any, x: np.ndarray) -> np.ndarray:
        actions, _ = policy.predict(np.asarray(x, dtype=np.float32), deterministic=True)
        return np.asarray(actions)

    samples = len(obs)
    if mode == "independent":
        return np.stack([predict(policies[i], obs[:, i, :]) for i in range(n_robots)], axis=1)
    if mode == "shared":
        flat = predict(policies[0], obs.reshape(samples * n_robots, -1))
        return flat.reshape(samples, n_robots) if discrete else flat.reshape(samples, n_robots, 2)
    joint = predict(policies[0], obs.reshape(samples, -1))
    if discrete:
        return joint_to_robot_actions(joint.reshape(-1), n_discrete, n_robots).reshape(samples, n_robots)
    return joint.reshape(samples, n_robots, 2)
