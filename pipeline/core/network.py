"""What a robot's messages go through between its sensors and the policy, and what the policy sees of stale data.

Shared by the simulator and the deploy runner, so that a policy trained in one meets the other unchanged:

- :func:`observed_scans` is the one rule for what a policy observes of a robot's scan: the latest one received,
  held while it is stale, or blanked (every beam without a return) when the world says so;
- :func:`stand_still` zeroes the commands of the robots whose data is stale: they wait for fresh data while the
  others drive on.

The simulator plays the network with :class:`MessageStream` (one per sensor stream and robot): messages are
produced at the sensor's rate, lost in bursts (a two-state Gilbert-Elliott chain whose stationary loss is
`loss_prob` and whose mean burst is `burst_len` messages), and delivered after a delay plus a half-normal jitter.
A robot is stale when its latest received message is older (by receive time, as on a fleet) than the staleness
limit. Times are integer nanoseconds of the controller's clock.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

StaleScan = Literal["hold", "blank"]


def observed_scans(latest: Sequence[np.ndarray], stale: np.ndarray, mode: StaleScan) -> list[np.ndarray]:
    """The scans (each (beams,) in m) a policy observes: the latest received of each robot, kept as it is while the
    robot is stale (`mode` 'hold') or with every beam read as no return, +inf ('blank'); `stale` is (n_robots,)."""
    if mode == "hold":
        return [np.asarray(s) for s in latest]
    return [
        np.full_like(np.asarray(s), np.inf) if bool(flag) else np.asarray(s)
        for s, flag in zip(latest, stale, strict=True)
    ]


def stand_still(commands: np.ndarray, stale: np.ndarray) -> np.ndarray:
    """(n_robots, 2) commands with the rows of the stale robots set to zero velocity (in place; returned)."""
    commands[np.asarray(stale, dtype=bool)] = 0.0
    return commands


@dataclass(frozen=True)
class LinkSettings:
    """One sensor stream: its rate (Hz; 0: one message per control step) and what the network does to it."""

    rate_hz: float = 0.0
    loss_prob: float = 0.0
    burst_len: float = 1.0
    delay_s: float = 0.0
    jitter_s: float = 0.0
    drop_prob: float = 0.0
    """Messages lost independently before the link (a sensor's driver), on top of the link's loss."""


class BurstLoss:
    """Gilbert-Elliott loss: a message is lost in the bad state. From good the chain enters bad with probability
    p / (b (1 - p)), and leaves it with 1 / b, so the stationary loss is p and bursts last b messages on average."""

    def __init__(self, loss_prob: float, burst_len: float, n: int) -> None:
        self.loss_prob = loss_prob
        b = max(1.0, burst_len)
        self.leave = 1.0 / b
        self.enter = min(1.0, loss_prob / (b * (1.0 - loss_prob))) if loss_prob < 1.0 else 1.0
        self.bad = np.zeros(n, dtype=bool)

    def reset(self, rng: np.random.Generator) -> None:
        """Start each robot's chain in its stationary distribution."""
        self.bad = rng.random(len(self.bad)) < self.loss_prob

    def lost(self, robot: int, rng: np.random.Generator) -> bool:
        """Advance robot's chain by one message; whether that message is lost."""
        u = rng.random()
        self.bad[robot] = (u >= self.leave) if self.bad[robot] else (u < self.enter)
        return bool(self.bad[robot])


class MessageStream:
    """One sensor stream of every robot through a lossy, late network, stepped at the control times.

    `step(t_ns, payload)` produces the messages due since the last step (each carrying `payload[i]`, the sensor's
    reading now), loses or schedules them, delivers those due by `t_ns`, and keeps each robot's latest received
    message. `receive_ns[i]` is when robot i's latest message arrived (-1: none yet).
    """

    def __init__(self, settings: LinkSettings, n_robots: int, control_period_ns: int) -> None:
        self.settings = settings
        self.n = n_robots
        self.period_ns = round(1e9 / settings.rate_hz) if settings.rate_hz > 0 else control_period_ns
        self.loss = BurstLoss(settings.loss_prob, settings.burst_len, n_robots)
        self._next_ns = np.zeros(n_robots, dtype=np.int64)
        self._pending: list[deque[tuple[int, np.ndarray]]] = [deque() for _ in range(n_robots)]
        self.latest: list[np.ndarray | None] = [None] * n_robots
        self.receive_ns = np.full(n_robots, -1, dtype=np.int64)
        self.sent = np.zeros(n_robots, dtype=np.int64)
        self.lost = np.zeros(n_robots, dtype=np.int64)

    def reset(self, t_ns: int, payload: Sequence[np.ndarray], rng: np.random.Generator) -> None:
        """A new episode at `t_ns`: every robot's first message arrives now (the runner waits for fresh data from
        every robot before it starts an episode); sensors start at a random phase of their period."""
        self.loss.reset(rng)
        for i in range(self.n):
            self._pending[i].clear()
            self.latest[i] = np.array(payload[i], copy=True)
        self.receive_ns[:] = t_ns
        self._next_ns = t_ns + (rng.random(self.n) * self.period_ns).astype(np.int64) + 1
        self.sent[:] = 0
        self.lost[:] = 0

    def step(self, t_ns: int, payload: Sequence[np.ndarray], rng: np.random.Generator) -> None:
        s = self.settings
        delay_ns = round(s.delay_s * 1e9)
        for i in range(self.n):
            while self._next_ns[i] <= t_ns:
                produced = int(self._next_ns[i])
                self._next_ns[i] += self.period_ns
                self.sent[i] += 1
                if s.drop_prob > 0.0 and rng.random() < s.drop_prob:
                    self.lost[i] += 1
                    continue
                if s.loss_prob > 0.0 and self.loss.lost(i, rng):
                    self.lost[i] += 1
                    continue
                jitter = round(abs(rng.normal(0.0, s.jitter_s)) * 1e9) if s.jitter_s > 0 else 0
                self._pending[i].append((produced + delay_ns + jitter, np.array(payload[i], copy=True)))
            if self._pending[i]:
                due = sorted((m for m in self._pending[i] if m[0] <= t_ns), key=lambda m: m[0])
                if due:
                    self._pending[i] = deque(m for m in self._pending[i] if m[0] > t_ns)
                    arrive, data = due[-1]  # the receiver keeps what arrived last
                    self.latest[i] = data
                    self.receive_ns[i] = arrive

    def ages_ns(self, t_ns: int) -> np.ndarray:
        """(n_robots,) how long ago each robot's latest message arrived."""
        return np.asarray(t_ns - self.receive_ns, dtype=np.int64)
