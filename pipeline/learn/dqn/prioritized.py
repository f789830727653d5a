"""Proportional prioritized experience replay (Schaul et al. 2016) on stable-baselines3's ReplayBuffer.

A transition is stored with priority p (its last absolute TD error plus epsilon; a new transition
gets the largest priority currently stored, 1 in an empty buffer) and is drawn with probability
P(i) = p_i^alpha / sum_k p_k^alpha over the N stored transitions. The bias this introduces is
corrected by importance-sampling weights w_i = (N * P(i))^-beta, divided by the largest weight any
stored transition could get, (N * min_k P(k))^-beta, i.e. the normalisation uses the smallest stored
priority rather than the largest weight within the batch. Weights then lie in (0, 1] and a
transition's weight does not depend on which other transitions share its batch.

Leaf layout: SB3 stores transitions as (buffer_size, n_envs); transition (pos, env) is leaf
``pos * n_envs + env`` of the sum tree.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from numpy.typing import ArrayLike
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.vec_env import VecNormalize

from pipeline.learn.errors import PrioritizedReplayError


def _check_beta(beta: float) -> None:
    if not 0.0 <= beta <= 1.0:  # also refuses NaN
        raise PrioritizedReplayError("beta", beta, "must lie in [0, 1]")


class SumTree:
    """Binary sum tree over `capacity` non-negative leaf priorities, with batch (vectorised) operations.

    The tree is array-backed: node 1 is the root, node k has children 2k and 2k + 1, and the leaves
    sit at ``[size, 2 * size)`` where `size` is `capacity` rounded up to a power of two. Padding
    leaves hold 0 and are never returned by :meth:`find`. Next to the sums the tree keeps the
    minimum and the maximum over the leaves that have been written, so both cost O(1) to read.
    Every batch operation is O(batch * log capacity) in numpy.
    """

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"capacity = {capacity!r}: must be at least 1")
        self.capacity = int(capacity)
        self._depth = max(self.capacity - 1, 0).bit_length()
        self._size = 1 << self._depth
        self._sum = np.zeros(2 * self._size, dtype=np.float64)
        self._min = np.full(2 * self._size, np.inf, dtype=np.float64)  # +inf: leaf not written yet
        self._max = np.full(2 * self._size, -np.inf, dtype=np.float64)  # -inf: leaf not written yet

    @property
    def total(self) -> float:
        """Sum of all leaf priorities."""
        return float(self._sum[1])

    @property
    def empty(self) -> bool:
        """True while no leaf has been written."""
        return bool(self._max[1] == -np.inf)

    @property
    def max_priority(self) -> float:
        """Largest priority over the written leaves; ValueError while the tree is empty."""
        if self.empty:
            raise ValueError("the sum tree holds no priorities yet")
        return float(self._max[1])

    @property
    def min_priority(self) -> float:
        """Smallest priority over the written leaves; ValueError while the tree is empty."""
        if self.empty:
            raise ValueError("the sum tree holds no priorities yet")
        return float(self._min[1])

    def values(self, indices: ArrayLike) -> np.ndarray:
        """Leaf priorities at `indices`, shape of `indices`, float64 (0 for unwritten leaves)."""
        leaves = self._check_indices(indices)
        values: np.ndarray = self._sum[leaves + self._size]
        return values

    def update(self, indices: ArrayLike, priorities: ArrayLike) -> None:
        """Set leaves `indices` (int, any shape) to `priorities` (same shape or broadcastable, >= 0).

        Repeated indices take the last of their priorities, as in numpy assignment.
        """
        leaves = self._check_indices(indices).reshape(-1)
        values = np.broadcast_to(np.asarray(priorities, dtype=np.float64), np.shape(indices)).reshape(-1)
        bad = ~(np.isfinite(values) & (values >= 0))
        if np.any(bad):
            raise ValueError(f"priorities must be finite and >= 0, got {values[bad]}")
        nodes = leaves + self._size
        self._sum[nodes] = values
        self._min[nodes] = values
        self._max[nodes] = values
        nodes = np.unique(nodes)  # sorted once: each level's parents stay sorted, so duplicates are neighbours
        for _ in range(self._depth):
            nodes = nodes // 2
            if len(nodes) > 1:
                nodes = nodes[np.concatenate(([True], nodes[1:] != nodes[:-1]))]
            left, right = 2 * nodes, 2 * nodes + 1
            self._sum[nodes] = self._sum[left] + self._sum[right]
            self._min[nodes] = np.minimum(self._min[left], self._min[right])
            self._max[nodes] = np.maximum(self._max[left], self._max[right])

    def find(self, prefix_sums: ArrayLike) -> np.ndarray:
        """Leaf index for each prefix sum: the leaf i with cumsum[i - 1] <= s < cumsum[i].

        `prefix_sums` has any shape; the result has the same shape, int64. Sums at or above
        :attr:`total` give the last leaf with a positive priority; leaves with priority 0 are never
        returned. Needs a positive total.
        """
        sums = np.asarray(prefix_sums, dtype=np.float64)
        if not self.total > 0.0:
            raise ValueError("cannot search a sum tree whose total priority is 0")
        if not np.all(sums >= 0):  # also catches NaN
            raise ValueError("prefix sums must be >= 0")
        remaining = sums.reshape(-1).copy()
        nodes = np.ones(remaining.shape, dtype=np.int64)
        for _ in range(self._depth):
            left = 2 * nodes
            left_sum = self._sum[left]
            go_right = (remaining >= left_sum) & (self._sum[left + 1] > 0)
            remaining = np.where(go_right, remaining - left_sum, remaining)
            nodes = np.where(go_right, left + 1, left)
        return (nodes - self._size).reshape(sums.shape)

    def _check_indices(self, indices: ArrayLike) -> np.ndarray:
        leaves = np.asarray(indices)
        if leaves.size and not np.issubdtype(leaves.dtype, np.integer):
            raise ValueError(f"leaf indices must be integers, got dtype {leaves.dtype}")
        leaves = leaves.astype(np.int64, copy=False)
        if leaves.size and (leaves.min() < 0 or leaves.max() >= self.capacity):
            raise ValueError(f"leaf indices must lie in [0, {self.capacity}), got {leaves.min()}..{leaves.max()}")
        return leaves


class PrioritizedReplayBufferSamples(NamedTuple):
    """A prioritized batch: SB3's ReplayBufferSamples fields (same order) plus weights and indices.

    Shapes for a batch of B: observations/next_observations (B, *obs_shape), actions
    (B, action_dim), dones/rewards (B, 1), discounts None (one-step returns), weights (B, 1)
    float32 importance-sampling weights in (0, 1], indices (B,) int64 leaf indices to pass back to
    :meth:`PrioritizedReplayBuffer.update_priorities`.
    """

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    discounts: th.Tensor | None
    weights: th.Tensor
    indices: np.ndarray


class PrioritizedReplayBuffer(ReplayBuffer):
    """SB3 ReplayBuffer that samples in proportion to p^alpha and returns importance-sampling weights.

    :param alpha: priority exponent, >= 0 (0: uniform sampling).
    :param beta: initial importance-sampling exponent in [0, 1]; the algorithm anneals it through
        the :attr:`beta` property (1: full correction).
    :param epsilon: added to |TD error| so that no transition gets priority 0; > 0.

    The other parameters are ReplayBuffer's. ``optimize_memory_usage=True`` is refused: it stores
    the next observation in the following row, so the row at ``pos`` has no valid next observation
    and would have to be kept out of every prioritized draw.

    Sampling uses numpy's global random state, like SB3's buffers, so ``set_random_seed`` seeds it.
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space[Any],
        action_space: spaces.Space[Any],
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        *,
        alpha: float = 0.6,
        beta: float = 0.4,
        epsilon: float = 1e-6,
    ) -> None:
        if optimize_memory_usage:
            raise PrioritizedReplayError(
                "optimize_memory_usage", optimize_memory_usage, "must be False for prioritized replay"
            )
        if not alpha >= 0 or not math.isfinite(alpha):
            raise PrioritizedReplayError("alpha", alpha, "must be a finite number >= 0")
        if not epsilon > 0 or not math.isfinite(epsilon):
            raise PrioritizedReplayError("epsilon", epsilon, "must be a finite number > 0")
        _check_beta(beta)
        if isinstance(observation_space, spaces.Dict):
            raise PrioritizedReplayError(
                "observation_space", observation_space, "Dict observation spaces are not supported"
            )
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device=device,
            n_envs=n_envs,
            optimize_memory_usage=False,
            handle_timeout_termination=handle_timeout_termination,
        )
        self.alpha = float(alpha)
        self.epsilon = float(epsilon)
        self._beta = float(beta)
        self.sum_tree = SumTree(self.buffer_size * self.n_envs)
        """Leaf ``pos * n_envs + env`` holds p^alpha of transition (pos, env)."""
        self._deferred: list[int] | None = None

    @contextlib.contextmanager
    def batch(self) -> Iterator[None]:
        """Adds inside the block write their priorities to the sum tree in one update when it ends.

        Every transition added in the block gets the largest priority stored when it starts (1 in an
        empty buffer), as it would one add at a time (adding at the largest priority never changes it);
        nothing may be sampled inside the block."""
        if self._deferred is not None:
            raise RuntimeError("PrioritizedReplayBuffer.batch blocks do not nest")
        self._deferred = []
        try:
            yield
        finally:
            rows, self._deferred = self._deferred, None
            if rows:
                priority = 1.0 if self.sum_tree.empty else self.sum_tree.max_priority
                leaves = np.asarray(rows)[:, None] * self.n_envs + np.arange(self.n_envs)[None, :]
                self.sum_tree.update(leaves.reshape(-1), priority)

    @property
    def beta(self) -> float:
        """Importance-sampling exponent in [0, 1] used by the next :meth:`sample`."""
        return self._beta

    @beta.setter
    def beta(self, value: float) -> None:
        _check_beta(value)
        self._beta = float(value)

    @property
    def n_transitions(self) -> int:
        """Number of stored transitions over all envs (size() * n_envs)."""
        return self.size() * self.n_envs

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """Store one step of every env (arrays with leading axis n_envs) at the current max priority."""
        row = self.pos
        if self._deferred is not None:
            super().add(obs, next_obs, action, reward, done, infos)
            self._deferred.append(row)
            return
        priority = 1.0 if self.sum_tree.empty else self.sum_tree.max_priority
        super().add(obs, next_obs, action, reward, done, infos)
        self.sum_tree.update(row * self.n_envs + np.arange(self.n_envs), priority)

    def sample(  # type: ignore[override]
        self, batch_size: int, env: VecNormalize | None = None
    ) -> PrioritizedReplayBufferSamples:
        """Draw `batch_size` transitions, one from each of `batch_size` equal segments of the total priority."""
        if batch_size < 1:
            raise PrioritizedReplayError("batch_size", batch_size, "must be at least 1")
        if self.n_transitions == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        if self._deferred is not None:
            raise RuntimeError("cannot sample inside PrioritizedReplayBuffer.batch: priorities are not written yet")
        total = self.sum_tree.total
        segment = total / batch_size
        prefix_sums = (np.arange(batch_size) + np.random.random(batch_size)) * segment
        leaves = self.sum_tree.find(np.minimum(prefix_sums, total))
        # w_i = (N P(i))^-beta / max_k (N P(k))^-beta, the max taken over every stored transition.
        n = self.n_transitions
        probabilities = self.sum_tree.values(leaves) / total
        min_probability = self.sum_tree.min_priority / total
        weights = (n * probabilities) ** -self.beta / (n * min_probability) ** -self.beta
        return self._gather(leaves, weights.astype(np.float32), env)

    def update_priorities(self, indices: ArrayLike, td_errors: ArrayLike) -> None:
        """Set p = |td_error| + epsilon for the leaves `indices` (B,), td_errors of shape (B,) or (B, 1)."""
        leaves = np.asarray(indices).reshape(-1)
        errors = np.asarray(td_errors, dtype=np.float64).reshape(-1)
        if leaves.shape != errors.shape:
            raise ValueError(f"{leaves.size} indices but {errors.size} TD errors")
        if not np.all(np.isfinite(errors)):
            raise ValueError("TD errors must be finite")
        if leaves.size and (leaves.min() < 0 or leaves.max() >= self.n_transitions):
            raise ValueError(f"indices must address stored transitions, [0, {self.n_transitions})")
        self.sum_tree.update(leaves, (np.abs(errors) + self.epsilon) ** self.alpha)

    def reset(self) -> None:
        """Forget every transition and priority."""
        super().reset()
        self.sum_tree = SumTree(self.buffer_size * self.n_envs)

    def _gather(
        self, leaves: np.ndarray, weights: np.ndarray, env: VecNormalize | None
    ) -> PrioritizedReplayBufferSamples:
        rows, envs = np.divmod(leaves, self.n_envs)
        observations = self._normalize_obs(self.observations[rows, envs, :], env)
        next_observations = self._normalize_obs(self.next_observations[rows, envs, :], env)
        assert isinstance(observations, np.ndarray) and isinstance(next_observations, np.ndarray)
        # Only dones that are not time-limit truncations end the bootstrap (timeouts stay 0 if unhandled).
        dones = self.dones[rows, envs] * (1 - self.timeouts[rows, envs])
        rewards = self._normalize_reward(self.rewards[rows, envs].reshape(-1, 1), env)
        return PrioritizedReplayBufferSamples(
            observations=self.to_torch(observations),
            actions=self.to_torch(self.actions[rows, envs, :]),
            next_observations=self.to_torch(next_observations),
            dones=self.to_torch(dones.reshape(-1, 1)),
            rewards=self.to_torch(rewards),
            discounts=None,
            weights=self.to_torch(weights.reshape(-1, 1)),
            indices=leaves.astype(np.int64),
        )
