"""Action networks as plain arrays: what an exported policy computes, read from a state dict by name.

A trained learner's weights are a mapping of tensor names to arrays (stable-baselines3's
``policy.state_dict()`` layout). The exporter needs only the deterministic action path:

- ``sac_actor``: ReLU MLP ``actor.latent_pi`` -> ``actor.mu`` -> tanh (actions in [-1, 1]);
- ``ppo_actor``: tanh MLP ``mlp_extractor.policy_net`` -> ``action_net`` -> clip to [-1, 1]
  (continuous) or argmax of the logits (discrete); an input scaling (``features_extractor.center`` and
  ``half_range``, :mod:`pipeline.learn.common.scaling`) is folded into the first layer;
- ``dqn``: ReLU MLP ``q_net.q_net`` whose last layer gives Q values -> argmax;
- ``dqn_dueling``: ReLU MLP ``q_net.shared`` -> ``q_net.value_head`` (1) and
  ``q_net.advantage_head`` (n_actions); Q = V + A - mean(A) per sample -> argmax.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from pipeline.policy.errors import PolicyError

PolicyKind = Literal["sac_actor", "ppo_actor", "dqn", "dqn_dueling"]
POLICY_KINDS: tuple[PolicyKind, ...] = ("sac_actor", "ppo_actor", "dqn", "dqn_dueling")
Activation = Literal["relu", "tanh"]


@dataclass(frozen=True)
class Dense:
    """One affine layer y = x W^T + b: weight (out, in), bias (out,) float32."""

    weight: np.ndarray
    bias: np.ndarray


@dataclass(frozen=True)
class ActionNetwork:
    """The deterministic action path of one network.

    head: ``tanh`` (continuous, squashed), ``clip`` (continuous, clipped to [-1, 1]),
    ``argmax`` (discrete, on `out`), or ``dueling_argmax`` (discrete, on V + A - mean A where
    `out` is the advantage head and `value` the value head).
    """

    hidden: tuple[Dense, ...]
    activation: Activation
    out: Dense
    head: Literal["tanh", "clip", "argmax", "dueling_argmax"]
    value: Dense | None = None

    @property
    def input_size(self) -> int:
        first = self.hidden[0] if self.hidden else self.out
        return int(first.weight.shape[1])

    @property
    def output_size(self) -> int:
        return int(self.out.weight.shape[0])

    def forward(self, obs: np.ndarray) -> np.ndarray:
        """Reference forward pass in float64: (batch, input_size) -> actions (batch, n) or indices (batch,)."""
        x = np.asarray(obs, dtype=np.float64)
        for layer in self.hidden:
            x = x @ layer.weight.T.astype(np.float64) + layer.bias
            x = np.maximum(x, 0.0) if self.activation == "relu" else np.tanh(x)
        y = x @ self.out.weight.T.astype(np.float64) + self.out.bias
        if self.head == "tanh":
            return np.asarray(np.tanh(y))
        if self.head == "clip":
            return np.asarray(np.clip(y, -1.0, 1.0))
        if self.head == "dueling_argmax":
            assert self.value is not None
            v = x @ self.value.weight.T.astype(np.float64) + self.value.bias
            y = v + y - y.mean(axis=1, keepdims=True)
        return np.asarray(y.argmax(axis=1))


def _dense(weights: Mapping[str, Any], prefix: str, where: str) -> Dense:
    try:
        w = np.asarray(weights[f"{prefix}.weight"], dtype=np.float32)
        b = np.asarray(weights[f"{prefix}.bias"], dtype=np.float32)
    except KeyError as exc:
        raise PolicyError(where, f"weights lack {exc.args[0]!r}") from None
    if w.ndim != 2 or b.shape != (w.shape[0],):
        raise PolicyError(where, f"{prefix} has weight {w.shape} and bias {b.shape}, not (out, in) and (out,)")
    return Dense(w, b)


def _sequential(weights: Mapping[str, Any], prefix: str, where: str) -> list[Dense]:
    pattern = re.compile(re.escape(prefix) + r"\.(\d+)\.weight$")
    indices = sorted(int(m.group(1)) for k in weights if (m := pattern.match(k)))
    if not indices:
        raise PolicyError(where, f"weights have no layers under {prefix!r}")
    return [_dense(weights, f"{prefix}.{i}", where) for i in indices]


SCALE_CENTER = "features_extractor.center"
SCALE_HALF_RANGE = "features_extractor.half_range"
"""A PPO network's input scaling (train.observation_scaling: bounds): (obs - centre) / half range."""


def _fold_scaling(weights: Mapping[str, Any], first: Dense, where: str) -> Dense:
    """`first` with the input scaling folded in: W ((x - c) / h) + b = (W / h) x + (b - (W / h) c)."""
    try:
        c = np.asarray(weights[SCALE_CENTER], dtype=np.float64)
        h = np.asarray(weights[SCALE_HALF_RANGE], dtype=np.float64)
    except KeyError as exc:
        raise PolicyError(where, f"weights lack {exc.args[0]!r} (the input scaling has two parts)") from None
    n = first.weight.shape[1]
    if c.shape != (n,) or h.shape != (n,) or not (np.isfinite(c).all() and np.isfinite(h).all() and (h > 0).all()):
        raise PolicyError(where, f"the input scaling needs a centre and positive finite half ranges of {n} values")
    w = first.weight.astype(np.float64) / h[None, :]
    b = first.bias.astype(np.float64) - w @ c
    return Dense(w.astype(np.float32), b.astype(np.float32))


def _chain(layers: list[Dense], where: str) -> None:
    for a, b in itertools.pairwise(layers):
        if a.weight.shape[0] != b.weight.shape[1]:
            raise PolicyError(where, f"layer sizes do not chain: {a.weight.shape} then {b.weight.shape}")


def action_network(kind: str, weights: Mapping[str, Any], discrete: bool, where: str = "<weights>") -> ActionNetwork:
    """The action path of a `kind` network from its named weights; PolicyError names what is missing."""
    if kind == "sac_actor":
        hidden = _sequential(weights, "actor.latent_pi", where)
        out = _dense(weights, "actor.mu", where)
        _chain([*hidden, out], where)
        return ActionNetwork(tuple(hidden), "relu", out, "tanh")
    if kind == "ppo_actor":
        hidden = _sequential(weights, "mlp_extractor.policy_net", where)
        if SCALE_CENTER in weights or SCALE_HALF_RANGE in weights:
            hidden[0] = _fold_scaling(weights, hidden[0], where)
        out = _dense(weights, "action_net", where)
        _chain([*hidden, out], where)
        return ActionNetwork(tuple(hidden), "tanh", out, "argmax" if discrete else "clip")
    if kind == "dqn":
        layers = _sequential(weights, "q_net.q_net", where)
        _chain(layers, where)
        return ActionNetwork(tuple(layers[:-1]), "relu", layers[-1], "argmax")
    if kind == "dqn_dueling":
        hidden = _sequential(weights, "q_net.shared", where)
        adv = _dense(weights, "q_net.advantage_head", where)
        value = _dense(weights, "q_net.value_head", where)
        _chain([*hidden, adv], where)
        _chain([*hidden, value], where)
        return ActionNetwork(tuple(hidden), "relu", adv, "dueling_argmax", value=value)
    raise PolicyError(where, f"unknown policy kind {kind!r}; allowed: {', '.join(POLICY_KINDS)}")
