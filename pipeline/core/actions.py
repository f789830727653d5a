"""The action codec: policy actions -> (v, w) velocity commands, clamped to the limits.

Continuous actions are (a_v, a_w) in [-1, 1] scaled linearly to [-v_max, v_max] m/s and
[-w_max, w_max] rad/s (values outside [-1, 1] are clamped); with `reverse` off a_v maps to [0, v_max]
(forward only: a_v = -1 stops). Discrete actions index a named set:
forward (0.15 m/s), left (0.1 m/s, +0.2 rad/s), right (0.1 m/s, -0.2 rad/s), and optionally
backward (-0.15 m/s) and stop.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Literal

import numpy as np

from pipeline.core.errors import ActionError

if TYPE_CHECKING:
    from pipeline.core.scenario import Scenario

ActionKind = Literal["continuous", "discrete"]
DiscreteName = Literal["forward", "left", "right", "backward", "stop"]

DISCRETE_COMMANDS: dict[str, tuple[float, float]] = {
    "forward": (0.15, 0.0),
    "left": (0.1, 0.2),
    "right": (0.1, -0.2),
    "backward": (-0.15, 0.0),
    "stop": (0.0, 0.0),
}


@dataclass(frozen=True)
class ActionCodec:
    """Decodes policy actions of `kind` into (v m/s, w rad/s) within the limits."""

    kind: ActionKind
    v_max_mps: float
    w_max_radps: float
    discrete_set: tuple[str, ...] = ("forward", "left", "right")
    robot_limits: tuple[tuple[float, float], ...] = ()
    """Per robot (v_max, w_max) of a mixed fleet: continuous actions scale to each robot's own, discrete
    commands are cut to them; empty: every robot has `v_max_mps`, `w_max_radps`."""
    reverse: bool = True
    """Continuous a_v in [-1, 1] maps to [-v_max, v_max]; False: to [0, v_max]."""

    def limits(self, n: int) -> np.ndarray:
        """(n, 2) each robot's (v_max m/s, w_max rad/s)."""
        if self.robot_limits:
            if len(self.robot_limits) != n:
                raise ActionError(f"actions for {n} robots, the codec has limits for {len(self.robot_limits)}")
            return np.asarray(self.robot_limits, dtype=np.float64)
        return np.tile([self.v_max_mps, self.w_max_radps], (n, 1))

    def for_scenario(self, scenario: Scenario) -> ActionCodec:
        """This codec with the robots' own limits of a mixed `scenario` (itself otherwise)."""
        if not scenario.mixed:
            return self
        limits = scenario.speed_limits(self.v_max_mps, self.w_max_radps)
        return replace(self, robot_limits=tuple((float(v), float(w)) for v, w in limits))

    def __post_init__(self) -> None:
        unknown = [n for n in self.discrete_set if n not in DISCRETE_COMMANDS]
        if unknown:
            raise ActionError(f"unknown discrete action(s) {unknown}; allowed: {', '.join(DISCRETE_COMMANDS)}")

    def differences(self, other: ActionCodec) -> list[str]:
        """Each setting (by its `actions.` key) in which `other` decodes actions differently, with both values."""
        out = []
        if self.kind != other.kind:
            out.append(f"actions.kind {self.kind!r} vs {other.kind!r}")
        for key in ("v_max_mps", "w_max_radps"):
            a, b = getattr(self, key), getattr(other, key)
            if abs(a - b) > 1e-9:
                out.append(f"actions.{key} {a:g} vs {b:g}")
        if self.robot_limits != other.robot_limits:
            out.append(f"the robots' own limits {list(self.robot_limits)} vs {list(other.robot_limits)}")
        if self.kind == other.kind == "continuous" and self.reverse != other.reverse:
            out.append(f"actions.reverse {self.reverse} vs {other.reverse}")
        if self.kind == other.kind == "discrete" and self.discrete_set != other.discrete_set:
            out.append(f"actions.discrete_set {list(self.discrete_set)} vs {list(other.discrete_set)}")
        return out

    @property
    def n_discrete(self) -> int:
        return len(self.discrete_set)

    @property
    def table(self) -> np.ndarray:
        """(n_discrete, 2) (v, w) of each discrete action, clamped to the limits."""
        t = np.array([DISCRETE_COMMANDS[n] for n in self.discrete_set], dtype=np.float64)
        return self.clamp(t)

    @property
    def action_size(self) -> int:
        """Length of one robot's action vector (1 index for discrete)."""
        return 2 if self.kind == "continuous" else 1

    def clamp(self, cmd: np.ndarray) -> np.ndarray:
        """(..., 2) (v, w) clamped to +-v_max, +-w_max."""
        c = np.asarray(cmd, dtype=np.float64)
        return np.stack(
            [
                np.clip(c[..., 0], -self.v_max_mps, self.v_max_mps),
                np.clip(c[..., 1], -self.w_max_radps, self.w_max_radps),
            ],
            axis=-1,
        )

    def command_difference(self, a: np.ndarray, b: np.ndarray) -> float:
        """The largest difference of the commands (n_robots, 2) that two continuous action sets decode to, as a share
        of the robot's limit on that channel: what reaches a robot, not the raw outputs, which decoding clips."""
        ones = np.ones((len(np.asarray(a)), 2))
        scale = np.maximum(np.abs(self.decode(ones)), np.abs(self.decode(-ones)))
        diff = np.abs(self.decode(a) - self.decode(b)) / np.where(scale > 0, scale, 1.0)
        return float(diff.max()) if diff.size else 0.0

    def decode(self, actions: np.ndarray) -> np.ndarray:
        """(n_robots, 2) (v, w) from (n_robots, 2) continuous or (n_robots,) discrete actions."""
        a = np.asarray(actions)
        if self.kind == "continuous":
            a = a.astype(np.float64)
            if a.ndim != 2 or a.shape[1] != 2:
                raise ActionError(f"continuous actions must have shape (n_robots, 2), got {a.shape}")
            if not np.isfinite(a).all():
                raise ActionError(f"continuous actions must be finite, got {a.tolist()}")
            a = np.minimum(np.maximum(a, -1.0), 1.0)
            if not self.reverse:
                a = np.stack([0.5 * (a[:, 0] + 1.0), a[:, 1]], axis=1)
            if self.robot_limits:
                return np.asarray(a * self.limits(len(a)))
            return np.stack([a[:, 0] * self.v_max_mps, a[:, 1] * self.w_max_radps], axis=1)
        idx = a.reshape(-1)
        if not np.issubdtype(idx.dtype, np.integer):
            if not np.all(np.isfinite(idx)) or not np.all(idx == np.round(idx)):
                raise ActionError(f"discrete actions must be integers, got {idx.tolist()}")
            idx = idx.astype(np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= self.n_discrete):
            raise ActionError(
                f"discrete actions must lie in [0, {self.n_discrete - 1}] "
                f"({', '.join(self.discrete_set)}), got {idx.tolist()}"
            )
        table = np.asarray(self.table[idx])
        if self.robot_limits:
            lim = self.limits(len(table))
            table = np.clip(table, -lim, lim)
        return table

    def encode(self, cmd: np.ndarray) -> np.ndarray:
        """Inverse of decode for continuous actions: (n, 2) (v, w) -> (n, 2) in [-1, 1]."""
        if self.kind != "continuous":
            raise ActionError("encode is defined for continuous actions only")
        c = np.asarray(cmd, dtype=np.float64)
        lim = self.limits(len(c))
        a = np.clip(c, -lim, lim) / lim
        if not self.reverse:
            a[:, 0] = 2.0 * np.clip(a[:, 0], 0.0, 1.0) - 1.0
        return np.asarray(a)
