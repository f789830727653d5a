"""The whole loop on a tiny budget: params.yaml's settings that make ``dvc repro`` run every stage in a few minutes
(a few thousand training steps, a handful of episodes per stage), for tests and benchmarks of the loop's machinery
rather than of its policies."""

from __future__ import annotations

import copy
import shutil
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig

TINY_LOOP: dict[str, dict[str, Any]] = {
    "world": {"max_steps": 60},
    "scripted_eval": {"episodes": 2},
    "train": {
        "total_steps": 1600,
        "n_envs": 4,
        "net_arch": [16, 16],
        "checkpoint_every_episodes": 5,
        "ppo": {"n_steps": 32, "minibatch_size": 64},
    },
    "export": {"golden_observations": 8},
    "eval_sim": {"episodes": 3},
    "deploy": {"episodes": 3, "time_scale": 3.0},
    "calibrate": {"bootstrap": 20},
    "replay": {"max_episodes": 3, "horizon_s": 3.0},
}
"""Per params.yaml section, the keys changed (nested mappings merged key by key)."""

TINY_TRAINING: dict[str, Any] = {
    "total_steps": 240,
    "n_envs": 2,
    "net_arch": [16, 16],
    "batch_size": 16,
    "buffer_size": 2000,
    "learning_starts": 40,
    "updates_per_transition": 0.25,
    "train_every_steps": 2,
    "checkpoint_every_episodes": 1,
    "ppo": {"n_steps": 16, "n_epochs": 2, "minibatch_size": 32},
    "dqn": {"target_update_interval": 50},
}
"""A training of a few hundred steps (TrainConfig's keys changed): every algorithm's and mode's machinery, gradient
steps included, in seconds; for tests and the determinism digests, not for policies."""


def tiny_train_config(**overrides: Any) -> TrainConfig:
    """TrainConfig's defaults with `TINY_TRAINING` and then `overrides` merged in (nested mappings key by key)."""
    return from_mapping(
        TrainConfig, merge(merge(to_mapping(TrainConfig()), TINY_TRAINING), overrides), "<tiny training>"
    )


def tiny_params(params: Mapping[str, Any], changes: Mapping[str, Mapping[str, Any]] = TINY_LOOP) -> dict[str, Any]:
    """`params` (params.yaml's content) with `changes` applied, one level of nested mappings merged."""
    out = copy.deepcopy(dict(params))
    for section, keys in changes.items():
        for key, value in keys.items():
            if isinstance(value, Mapping):
                out[section][key].update(value)
            else:
                out[section][key] = value
    return out


def copy_checkout(source: Path, dest: Path) -> Path:
    """The files git tracks in `source`, copied to `dest` (a clone without history, as a second user's)."""
    files = subprocess.run(["git", "ls-files"], cwd=source, capture_output=True, text=True, check=True).stdout.split()
    for name in files:
        src = source / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    return dest
