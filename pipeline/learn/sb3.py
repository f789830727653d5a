"""The adapter to stable-baselines3's algorithms: the one module of the project that calls SB3's protected members.

SB3's ``learn()`` steps one VecEnv per model; the multi-robot loop owns its worlds instead, and drives each model
through SB3's own steps, exposed here as public methods: begin a run (``_setup_learn``), store one transition and
advance the per-step bookkeeping (``_on_step``), drive the schedules from the loop's progress
(``_current_progress_remaining``), consume a rollout. :func:`progress_remaining` reads the schedules' progress for a
learner that computes its own learning rate (the batched SAC step). :class:`pipeline.learn.dqn.model.PerDQN` is a
subclass of SB3's DQN that overrides its ``train()`` and ``_setup_model()``, as SB3's own algorithms do, and uses the
members they use.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
import torch as th
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvStepReturn

from pipeline.learn.dqn.model import PerDQN


class SpacesVecEnv(VecEnv):
    """A VecEnv that only carries spaces: SB3 models are built on it, the training loop steps the worlds."""

    def __init__(self, observation_space: gymnasium.Space[Any], action_space: gymnasium.Space[Any], n: int) -> None:
        super().__init__(n, observation_space, action_space)

    def reset(self) -> Any:
        shape = (self.num_envs, *(self.observation_space.shape or ()))
        return np.zeros(shape, dtype=np.float32)

    def step_async(self, actions: np.ndarray) -> None:
        raise RuntimeError("this VecEnv carries spaces only; the multi-robot training loop steps the worlds")

    def step_wait(self) -> VecEnvStepReturn:
        raise RuntimeError("this VecEnv carries spaces only; the multi-robot training loop steps the worlds")

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [None] * self.num_envs

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        pass

    def env_method(self, method_name: str, *args: Any, indices: Any = None, **kwargs: Any) -> list[Any]:
        return [None] * self.num_envs

    def env_is_wrapped(
        self, wrapper_class: type[gymnasium.Wrapper[Any, Any, Any, Any]], indices: Any = None
    ) -> list[bool]:
        return [False] * self.num_envs


def _quiet(model: BaseAlgorithm) -> None:
    """A logger that keeps SB3's records in memory: without one, every ``_setup_learn`` makes an empty
    ``SB3-<time>`` folder in the temporary directory."""
    if not model._custom_logger:
        model.set_logger(Logger(folder=None, output_formats=[]))


class _ExternalOffPolicy(OffPolicyAlgorithm):
    """Public steps of an SB3 off-policy algorithm for a loop outside ``learn()`` (one transition at a time)."""

    def begin(self, total_transitions: int) -> None:
        _quiet(self)
        self._setup_learn(total_transitions, callback=None, reset_num_timesteps=True)

    def store(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: float,
        terminated: bool,
        truncated: bool,
    ) -> None:
        """Add one transition to the replay buffer and advance SB3's per-step bookkeeping."""
        done = np.array([terminated or truncated])
        info = [{"TimeLimit.truncated": bool(truncated and not terminated)}]
        assert self.replay_buffer is not None
        self.replay_buffer.add(
            obs[None], next_obs[None], np.asarray(action).reshape(1, -1), np.array([reward]), done, info
        )
        self.num_timesteps += 1
        self._on_step()

    def set_progress(self, fraction_done: float) -> None:
        """Drive SB3's schedules (learning rate, exploration, PER beta) from the loop's progress in [0, 1]."""
        self._current_progress_remaining = 1.0 - min(max(fraction_done, 0.0), 1.0)


class LoopSAC(_ExternalOffPolicy, SAC):
    """SAC whose transitions come from the multi-robot loop."""


class LoopDQN(_ExternalOffPolicy, PerDQN):
    """Dueling / prioritized / double DQN whose transitions come from the multi-robot loop."""


class LoopPPO(PPO):
    """PPO whose rollouts come from the multi-robot loop; masked samples carry no gradient."""

    def begin(self, total_steps: int) -> None:
        _quiet(self)
        self._setup_learn(total_steps, callback=None, reset_num_timesteps=True)
        self.rollout_buffer.reset()

    def set_progress(self, fraction_done: float) -> None:
        self._current_progress_remaining = 1.0 - min(max(fraction_done, 0.0), 1.0)

    def train_on_rollout(self, last_values: th.Tensor, dones: np.ndarray, mask: np.ndarray) -> None:
        """Finish the full rollout buffer, zero the advantages of `mask`ed samples (n_steps, n_envs), train."""
        buf = self.rollout_buffer
        buf.compute_returns_and_advantage(last_values=last_values, dones=dones)
        buf.advantages[mask] = 0.0
        buf.returns[mask] = buf.values[mask]
        self.train()
        buf.reset()


def progress_remaining(model: BaseAlgorithm) -> float:
    """What is left of the run, in [0, 1], as SB3's schedules read it (1 at the start)."""
    return float(model._current_progress_remaining)
