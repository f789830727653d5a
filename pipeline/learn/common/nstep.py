"""n-step returns for the off-policy learners: each stream's one-step transitions turned into n-step ones.

A learner stores ``(s_t, a_t, R, s_{t+n}, terminated)`` with ``R = r_t + gamma r_{t+1} + ... + gamma^(n-1)
r_{t+n-1}``, and bootstraps it with ``gamma^n`` (its model is built with that discount): the goal's reward reaches
a start n times faster through the value backups, at the bias of returns collected by an older policy (no
off-policy correction, as in Rainbow's multi-step DQN). So that every stored transition has exactly n steps or ends
in a terminal state, a stream's last transitions are handled at its episode's end:

- terminated (the robot reached its goal or collided) within the window: the return stops there and the
  transition is terminal (no bootstrap), so each of the stream's last n - 1 steps is stored with its shorter
  return;
- truncated (the episode's time limit) or gone inactive without terminating: the steps whose window would reach
  past the end are dropped (fewer than n per episode), never stored with a shorter bootstrap at ``gamma^n``.

The streams are a learner's own (its index in the batch) and, with ``share_experience``, the other robots' (a
source key per robot), each with its own window. ``n = 1`` stores each transition as it comes.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Hashable
from dataclasses import dataclass

import numpy as np

from pipeline.learn.common.modes import StreamBatch


@dataclass
class NStepTransitions:
    """Transitions ready to store, arrays with a leading m (m may be 0)."""

    obs: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    next_obs: np.ndarray
    terminated: np.ndarray

    def __len__(self) -> int:
        return len(self.rewards)


class NStepReturns:
    """Per-stream windows of the last n steps; :meth:`push` returns the transitions whose window is complete."""

    def __init__(self, n: int, gamma: float) -> None:
        if n < 1:
            raise ValueError(f"n-step returns need n >= 1, got {n}")
        self.n = n
        self.gamma = float(gamma)
        self.discounts = self.gamma ** np.arange(n)
        self._windows: dict[Hashable, deque[tuple[np.ndarray, np.ndarray, float]]] = {}

    def pending(self) -> int:
        """Steps held in the windows, not yet stored."""
        return sum(len(w) for w in self._windows.values())

    def push(self, source: Hashable, obs: np.ndarray, actions: np.ndarray, batch: StreamBatch) -> NStepTransitions:
        """One lockstep step of a learner's streams from `source` (its own: any fixed key; another robot's: that
        robot's key): `obs` (streams, d) the observations acted on, `actions` (streams, ...) the actions."""
        out_obs: list[np.ndarray] = []
        out_act: list[np.ndarray] = []
        out_ret: list[float] = []
        out_next: list[np.ndarray] = []
        out_term: list[bool] = []
        actions = np.asarray(actions)
        for i in range(len(obs)):
            key = (source, i)
            window = self._windows.get(key)
            if not batch.active[i]:
                if window:
                    window.clear()  # the stream stopped without a terminal step: its partial windows are dropped
                continue
            if window is None:
                window = self._windows[key] = deque()
            window.append((np.array(obs[i], copy=True), np.array(actions[i], copy=True), float(batch.reward[i])))
            terminated, truncated = bool(batch.terminated[i]), bool(batch.truncated[i])
            if terminated:
                rewards = np.array([r for _, _, r in window])
                while window:  # every pending step's return runs to the terminal step
                    o, a, _ = window.popleft()
                    k = len(rewards)
                    out_obs.append(o)
                    out_act.append(a)
                    out_ret.append(float(np.dot(self.discounts[:k], rewards)))
                    out_next.append(np.array(batch.next_obs[i], copy=True))
                    out_term.append(True)
                    rewards = rewards[1:]
                continue
            if len(window) == self.n:
                o, a, _ = window[0]
                rewards = np.array([r for _, _, r in window])
                out_obs.append(o)
                out_act.append(a)
                out_ret.append(float(np.dot(self.discounts, rewards)))
                out_next.append(np.array(batch.next_obs[i], copy=True))
                out_term.append(False)
                window.popleft()
            if truncated:
                window.clear()
        d = obs.shape[1] if obs.ndim > 1 else 0
        return NStepTransitions(
            obs=np.array(out_obs).reshape(len(out_obs), d) if out_obs else np.zeros((0, d), dtype=np.float32),
            actions=np.array(out_act) if out_act else np.zeros((0, *actions.shape[1:]), dtype=actions.dtype),
            rewards=np.array(out_ret, dtype=np.float64),
            next_obs=np.array(out_next).reshape(len(out_next), d) if out_next else np.zeros((0, d), np.float32),
            terminated=np.array(out_term, dtype=bool),
        )
