"""Observation scaling inside the network: each observation value mapped linearly from its space's
[low, high] to [-1, 1] before the first layer (`train.observation_scaling: bounds`).

The policy's inputs stay the raw observation (metres, radians) everywhere: in the simulator, on the twin,
on robots and in the exported file. The scaling is a fixed affine map from the observation space's bounds,
no running statistics, so training stays deterministic to the bit and the map needs no state of its own at
deployment: the exporter folds it into the first layer's weights
(:func:`pipeline.policy.networks.action_network`), exact up to float32 rounding.
"""

from __future__ import annotations

import gymnasium
import numpy as np
import torch as th
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor


class BoundsScaling(BaseFeaturesExtractor):
    """Features (obs - centre) / half range, the observation space's bounds mapped to [-1, 1]."""

    def __init__(self, observation_space: gymnasium.spaces.Box) -> None:
        size = int(np.prod(observation_space.shape))
        super().__init__(observation_space, size)
        low = np.asarray(observation_space.low, dtype=np.float64).reshape(-1)
        high = np.asarray(observation_space.high, dtype=np.float64).reshape(-1)
        if not (np.isfinite(low).all() and np.isfinite(high).all() and (high > low).all()):
            raise ValueError("bounds scaling needs finite observation bounds with high > low")
        self.center: th.Tensor
        self.half_range: th.Tensor
        self.register_buffer("center", th.as_tensor((high + low) / 2, dtype=th.float32))
        self.register_buffer("half_range", th.as_tensor((high - low) / 2, dtype=th.float32))

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return (th.flatten(observations, start_dim=1) - self.center) / self.half_range


def space_of(center: np.ndarray, half_range: np.ndarray) -> gymnasium.spaces.Box[np.float32]:
    """The observation space whose bounds give this scaling (to rebuild a network from its weights)."""
    c = np.asarray(center, dtype=np.float32)
    h = np.asarray(half_range, dtype=np.float32)
    return gymnasium.spaces.Box(c - h, c + h, dtype=np.float32)
