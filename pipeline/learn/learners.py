"""Learners: stable-baselines3 algorithms driven by the lockstep multi-robot loop.

SB3's ``learn()`` steps one VecEnv per model; here several models act in the same worlds at the
same time and a robot may finish before its world does. So the training loop owns the worlds
and each learner wraps one SB3 model through a small subclass that exposes SB3's own steps
(store a transition, advance the schedules, run gradient steps, consume a rollout) as public
methods. Only transitions of robots that were active at the start of a step are learned from.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any, Protocol

import gymnasium
import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.utils import obs_as_tensor

from pipeline.learn.common.modes import StreamBatch
from pipeline.learn.common.nstep import NStepReturns
from pipeline.learn.common.scaling import BoundsScaling
from pipeline.learn.dqn.prioritized import PrioritizedReplayBuffer
from pipeline.learn.sac.batched import BatchedSAC
from pipeline.learn.sb3 import LoopDQN, LoopPPO, LoopSAC, SpacesVecEnv
from pipeline.params import TrainConfig


class Learner(Protocol):
    """What the training loop needs of a learner."""

    model: BaseAlgorithm

    def act(self, obs: np.ndarray) -> np.ndarray: ...

    def observe(self, obs: np.ndarray, actions: np.ndarray, batch: StreamBatch) -> None: ...

    def update(self) -> None: ...

    def set_progress(self, fraction_done: float) -> None: ...


class OffPolicyLearner:
    """SAC or DQN: random actions until `learning_starts` transitions, then the model's exploration."""

    def __init__(self, model: LoopSAC | LoopDQN, cfg: TrainConfig, seed: int) -> None:
        self.model = model
        self.cfg = cfg
        self.rng = np.random.default_rng(seed)
        self._credit = 0.0
        self._steps = 0
        self.discrete = isinstance(model.action_space, gymnasium.spaces.Discrete)
        self.n_step = NStepReturns(cfg.n_step, cfg.gamma) if cfg.n_step > 1 else None
        """With ``n_step`` > 1 the streams' windows (the model bootstraps with gamma^n)."""

    def _random(self, n: int) -> np.ndarray:
        space = self.model.action_space
        if isinstance(space, gymnasium.spaces.Discrete):
            return self.rng.integers(0, int(space.n), size=n)
        assert isinstance(space, gymnasium.spaces.Box)
        return self.rng.uniform(space.low, space.high, size=(n, *space.shape)).astype(np.float32)

    def act(self, obs: np.ndarray) -> np.ndarray:
        n = len(obs)
        if self.model.num_timesteps < self.cfg.learning_starts:
            return self._random(n)
        if self.discrete:
            greedy, _ = self.model.policy.predict(obs, deterministic=True)
            explore = self.rng.random(n) < self.model.exploration_rate  # type: ignore[union-attr]
            return np.where(explore, self._random(n), np.asarray(greedy).reshape(n))
        action, _ = self.model.predict(obs, deterministic=False)
        return np.asarray(action, dtype=np.float32)

    def observe(self, obs: np.ndarray, actions: np.ndarray, batch: StreamBatch) -> None:
        buffer = self.model.replay_buffer
        with buffer.batch() if isinstance(buffer, PrioritizedReplayBuffer) else contextlib.nullcontext():
            self._observe(obs, actions, batch)

    def observe_other(self, obs: np.ndarray, actions: np.ndarray, batch: StreamBatch, source: int) -> None:
        """Store robot `source`'s transitions (``share_experience``): they fill the replay and count toward
        ``learning_starts``, but earn no gradient steps, so the learner takes as many as without them."""
        buffer = self.model.replay_buffer
        with buffer.batch() if isinstance(buffer, PrioritizedReplayBuffer) else contextlib.nullcontext():
            self._observe(obs, actions, batch, credit=False, source=source)

    def _observe(
        self, obs: np.ndarray, actions: np.ndarray, batch: StreamBatch, credit: bool = True, source: int = -1
    ) -> None:
        if self.n_step is not None:
            ready = self.n_step.push(source, obs, actions, batch)
            for j in range(len(ready)):
                self.model.store(
                    ready.obs[j],
                    ready.next_obs[j],
                    ready.actions[j],
                    float(ready.rewards[j]),
                    bool(ready.terminated[j]),
                    False,
                )
                if credit and self.model.num_timesteps > self.cfg.learning_starts:
                    self._credit += self.cfg.updates_per_transition
            return
        for i in np.flatnonzero(batch.active):
            self.model.store(
                obs[i],
                batch.next_obs[i],
                actions[i],
                float(batch.reward[i]),
                bool(batch.terminated[i]),
                bool(batch.truncated[i]),
            )
            if credit and self.model.num_timesteps > self.cfg.learning_starts:
                self._credit += self.cfg.updates_per_transition

    def set_progress(self, fraction_done: float) -> None:
        self.model.set_progress(fraction_done)

    def update(self) -> None:
        self._steps += 1
        if self._steps % self.cfg.train_every_steps:
            return
        steps = int(self._credit)
        if (
            steps > 0
            and self.model.replay_buffer is not None
            and self.model.replay_buffer.size() >= self.cfg.batch_size
        ):
            self._credit -= steps
            self.model.train(gradient_steps=steps, batch_size=self.cfg.batch_size)


class BatchedSACMember(OffPolicyLearner):
    """One learner of a :class:`BatchedSAC` group: its transitions go to the group's buffer of this
    learner, and the last member's ``update`` runs the group's gradient steps for every learner."""

    def __init__(self, model: LoopSAC, cfg: TrainConfig, seed: int, group: BatchedSAC, index: int) -> None:
        super().__init__(model, cfg, seed)
        self.group = group
        self.index = index

    def observe(self, obs: np.ndarray, actions: np.ndarray, batch: StreamBatch) -> None:
        before = self.model.num_timesteps
        self._store(obs, actions, batch)
        counted = max(0, self.model.num_timesteps - max(before, self.cfg.learning_starts))
        self.group.credit += self.cfg.updates_per_transition * counted / self.group.k

    def observe_other(self, obs: np.ndarray, actions: np.ndarray, batch: StreamBatch, source: int) -> None:
        """Robot `source`'s transitions into this learner's buffer, without gradient steps of their own."""
        self._store(obs, actions, batch, source)

    def _store(self, obs: np.ndarray, actions: np.ndarray, batch: StreamBatch, source: int = -1) -> None:
        """The batch's active transitions (n-step ones with ``n_step`` > 1, from `source`'s streams) into this
        learner's buffer of the group, counted as its timesteps."""
        if self.n_step is not None:
            ready = self.n_step.push(source, obs, actions, batch)
            if len(ready):
                self.group.add(self.index, ready.obs, ready.next_obs, ready.actions, ready.rewards, ready.terminated)
                self.model.num_timesteps += len(ready)
            return
        active = np.flatnonzero(batch.active)
        if not len(active):
            return
        self.group.add(
            self.index,
            obs[active],
            batch.next_obs[active],
            np.asarray(actions)[active],
            batch.reward[active],
            batch.terminated[active],
        )
        self.model.num_timesteps += len(active)

    def update(self) -> None:
        if self.index != self.group.k - 1:
            return
        self._steps += 1
        if self._steps % self.cfg.train_every_steps:
            return
        steps = int(self.group.credit)
        if steps > 0 and self.group.ready():
            self.group.credit -= steps
            self.group.train(steps)


class OnPolicyLearner:
    """PPO over `n_streams` streams; a robot inactive at the start of a step gives a masked sample."""

    def __init__(self, model: LoopPPO, cfg: TrainConfig) -> None:
        self.model = model
        self.cfg = cfg
        n = model.n_envs
        self._starts = np.ones(n, dtype=bool)
        self._values: th.Tensor | None = None
        self._log_probs: th.Tensor | None = None
        self._raw_actions = np.zeros(0)
        self._mask = np.zeros((model.n_steps, n), dtype=bool)
        self._last_next_obs = np.zeros(0)
        self.discrete = isinstance(model.action_space, gymnasium.spaces.Discrete)

    def act(self, obs: np.ndarray) -> np.ndarray:
        policy = self.model.policy
        with th.no_grad():
            actions, values, log_probs = policy(obs_as_tensor(obs, self.model.device))
        self._values, self._log_probs = values, log_probs
        raw = actions.cpu().numpy()
        self._raw_actions = raw
        if self.discrete:
            return np.asarray(raw).reshape(len(obs))
        space = self.model.action_space
        assert isinstance(space, gymnasium.spaces.Box)
        return np.asarray(np.clip(raw, space.low, space.high), dtype=np.float32)

    def observe(self, obs: np.ndarray, actions: np.ndarray, batch: StreamBatch) -> None:
        model = self.model
        buf = model.rollout_buffer
        rewards = batch.reward.astype(np.float32).copy()
        bootstrap = batch.truncated & batch.active & ~batch.terminated
        if bootstrap.any():
            with th.no_grad():
                values = model.policy.predict_values(obs_as_tensor(batch.next_obs[bootstrap], model.device))
            rewards[bootstrap] += model.gamma * values.cpu().numpy().reshape(-1)
        raw = self._raw_actions.reshape(len(obs), -1) if self.discrete else self._raw_actions
        assert self._values is not None and self._log_probs is not None
        self._mask[buf.pos] = ~batch.active
        buf.add(obs, raw, rewards, self._starts, self._values, self._log_probs)
        model.num_timesteps += len(obs)
        self._starts = batch.terminated | batch.truncated | ~batch.active
        self._last_next_obs = batch.next_obs

    def set_progress(self, fraction_done: float) -> None:
        self.model.set_progress(fraction_done)

    def update(self) -> None:
        model = self.model
        if not model.rollout_buffer.full:
            return
        # the value of what the streams see next: the successor of the last step
        with th.no_grad():
            last_values = model.policy.predict_values(obs_as_tensor(self._last_next_obs, model.device))
        model.train_on_rollout(last_values, self._starts, self._mask.copy())
        self._mask[:] = False


def learning_rate(cfg: TrainConfig) -> float | Callable[[float], float]:
    """The configured learning rate: constant, or decaying linearly to 0 with SB3's progress_remaining (1 -> 0)."""
    if cfg.learning_rate_schedule == "constant":
        return cfg.learning_rate
    start = cfg.learning_rate

    def schedule(progress_remaining: float) -> float:
        return start * progress_remaining

    return schedule


def _net_arch(cfg: TrainConfig) -> list[int]:
    return list(cfg.net_arch)


def build_learner(
    cfg: TrainConfig,
    observation_space: gymnasium.spaces.Box,
    action_space: gymnasium.Space[Any],
    n_streams: int,
    seed: int,
    device: str = "cpu",
) -> OffPolicyLearner | OnPolicyLearner:
    """A learner of `cfg.algorithm` for streams with these spaces, its networks on `device` (training uses the CPU;
    ``benchmarks/train_speed.py --gradient-devices`` times gradient steps on a CUDA GPU too)."""
    if cfg.algorithm == "ppo":
        ppo = cfg.ppo
        env = SpacesVecEnv(observation_space, action_space, n_streams)
        model = LoopPPO(
            "MlpPolicy",
            env,
            learning_rate=learning_rate(cfg),
            n_steps=ppo.n_steps,
            batch_size=min(ppo.minibatch_size, ppo.n_steps * n_streams),
            n_epochs=ppo.n_epochs,
            gamma=cfg.gamma,
            gae_lambda=ppo.gae_lambda,
            clip_range=ppo.clip_range,
            ent_coef=ppo.ent_coef,
            vf_coef=ppo.vf_coef,
            max_grad_norm=ppo.max_grad_norm,
            policy_kwargs={
                "net_arch": {"pi": _net_arch(cfg), "vf": _net_arch(cfg)},
                **({"features_extractor_class": BoundsScaling} if cfg.observation_scaling == "bounds" else {}),
            },
            seed=seed,
            device=device,
            verbose=0,
        )
        model.begin(cfg.total_steps)
        return OnPolicyLearner(model, cfg)
    env = SpacesVecEnv(observation_space, action_space, 1)
    common: dict[str, Any] = {
        "learning_rate": learning_rate(cfg),
        "buffer_size": cfg.buffer_size,
        "learning_starts": 0,
        "batch_size": cfg.batch_size,
        "gamma": cfg.gamma**cfg.n_step,  # a stored transition spans n_step steps
        "train_freq": 1,
        "gradient_steps": 1,
        "seed": seed,
        "device": device,
        "verbose": 0,
    }
    off: LoopSAC | LoopDQN
    if cfg.algorithm == "sac":
        if cfg.sac.update == "batched":
            common["buffer_size"] = 1  # the batched update keeps the replay of its own
        dims = int(np.prod(action_space.shape or (1,)))
        off = LoopSAC(
            "MlpPolicy",
            env,
            tau=cfg.sac.tau,
            ent_coef=f"auto_{cfg.sac.ent_coef_init!r}" if cfg.sac.ent_coef == 0.0 else cfg.sac.ent_coef,
            target_entropy=-cfg.sac.target_entropy_scale * dims,
            policy_kwargs={"net_arch": _net_arch(cfg)},
            **common,
        )
    else:
        d = cfg.dqn
        off = LoopDQN(
            "DuelingMlpPolicy" if d.dueling else "MlpPolicy",
            env,
            target_update_interval=d.target_update_interval,
            exploration_fraction=d.exploration_fraction,
            exploration_initial_eps=d.exploration_initial_eps,
            exploration_final_eps=d.exploration_final_eps,
            max_grad_norm=d.max_grad_norm,
            prioritized=d.prioritized,
            double_q=d.double_q,
            per_alpha=d.per_alpha,
            per_beta0=d.per_beta0,
            per_epsilon=d.per_epsilon,
            policy_kwargs={"net_arch": _net_arch(cfg)},
            **common,
        )
    off.begin(cfg.total_steps)
    return OffPolicyLearner(off, cfg, seed)


def build_learners(
    cfg: TrainConfig,
    observation_space: gymnasium.spaces.Box,
    action_space: gymnasium.Space[Any],
    n_streams: int,
    n_learners: int,
    device: str = "cpu",
) -> list[OffPolicyLearner | OnPolicyLearner]:
    """The `n_learners` learners of a training run (seeds ``cfg.seed + 7919 i``); SAC with
    ``sac.update: batched`` as members of one :class:`BatchedSAC` group."""
    seeds = [cfg.seed + 7919 * i for i in range(n_learners)]
    learners = [build_learner(cfg, observation_space, action_space, n_streams, s, device) for s in seeds]
    if cfg.algorithm != "sac" or cfg.sac.update != "batched":
        return learners
    models = [learner.model for learner in learners]
    group = BatchedSAC(models, cfg, cfg.seed)
    return [
        BatchedSACMember(learner.model, cfg, seeds[i], group, i)  # type: ignore[arg-type]
        for i, learner in enumerate(learners)
    ]
