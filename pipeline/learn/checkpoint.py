"""Training checkpoints: network weights as plain tensors plus a typed, versioned description, written atomically.

Weights are saved with ``torch.save`` of a dict of tensors and read back with
``torch.load(weights_only=True)``, which refuses anything but tensors and plain containers: no
code runs when a checkpoint is loaded.

The description, ``train.json`` (format ``mrl-train/1``), is a :class:`TrainRecord`: written by the trainer, read by
export, checked on read with the same strict rules as params.yaml (an unknown, missing or mistyped key is an error
naming it). A file without the format tag was written by an earlier version and is refused with the command that
trains again.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Final, Literal

import torch as th

from pipeline.core.scenario import Scenario
from pipeline.learn.errors import CheckpointError
from pipeline.mappings import from_mapping, setting, to_mapping
from pipeline.params import ActionConfig, Algorithm, Mode, TrainConfig, WorldConfig
from pipeline.policy.networks import PolicyKind
from pipeline.policy.spec import ObservationInput

META_FILE = "train.json"
TRAIN_FORMAT: Final = "mrl-train/1"


@dataclass(frozen=True)
class TrainVersions:
    """The training libraries' versions."""

    stable_baselines3: str = setting()
    torch: str = setting()


@dataclass(frozen=True)
class ImitationRecord:
    """The warm start by imitation (train.imitation.steps > 0): its budget and last-epoch losses."""

    world_steps: int = setting(ge=0)
    samples: int = setting(ge=0)
    episodes: int = setting(ge=0)
    rounds: int = setting(ge=0)
    action_loss: float = setting()
    value_loss: float = setting()


@dataclass(frozen=True)
class SelectionRecord:
    """How the exported weights were chosen by periodic evaluation (train.selection)."""

    keep: Literal["best", "last"] = setting()
    evaluations: int = setting(ge=0)
    best_at_steps: int = setting(ge=0)
    best_robot_success: float = setting(ge=0.0, le=1.0)
    best_team_success: float = setting(ge=0.0, le=1.0)


@dataclass(frozen=True)
class TrainRecord:
    """``train.json``: what was trained, in which world, with which settings, and how far it got."""

    format: Literal["mrl-train/1"] = setting()
    algorithm: Algorithm = setting()
    mode: Mode = setting()
    policy_kind: PolicyKind = setting()
    net_arch: tuple[int, ...] = setting(min_len=1)
    robots: tuple[str, ...] = setting(min_len=1)
    observation: ObservationInput = setting()
    actions: ActionConfig = setting()
    scenario: Scenario = setting()
    world: WorldConfig = setting()
    train: TrainConfig = setting()
    versions: TrainVersions = setting()
    world_steps: int = setting(ge=0)
    episodes: int = setting(ge=0)
    converged_at_episode: int | None = setting(ge=0)
    interrupted: bool = setting()
    round: str = setting("", allow_empty=True, optional=True)
    """The loop's round (nominal, calibrated) when a stage trained it; empty otherwise."""
    imitation: ImitationRecord | None = setting(None, optional=True)
    selection: SelectionRecord | None = setting(None, optional=True)
    n_learners: int = setting(0, ge=0)
    weights_sha256: str = setting("", allow_empty=True)
    """Filled in by :func:`save_checkpoint`: the learners' count and the digest of their weight files."""

    def check(self) -> list[tuple[str, object, str]]:
        bad: list[tuple[str, object, str]] = []
        if self.robots != self.scenario.robot_names:
            bad.append(("robots", list(self.robots), f"the scenario's robots {list(self.scenario.robot_names)}"))
        if self.actions != self.world.actions:
            bad.append(("actions", to_mapping(self.actions), "the world's actions"))
        return bad


def learner_file(index: int) -> str:
    return f"learner_{index}.pt"


@dataclass(frozen=True)
class Checkpoint:
    """A loaded checkpoint: its description and each learner's policy weights."""

    record: TrainRecord
    weights: list[dict[str, th.Tensor]]


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def save_checkpoint(folder: Path, record: TrainRecord, weights: list[dict[str, th.Tensor]]) -> str:
    """Write every learner's weights, then the description with their count and digest; returns the digest."""
    folder.mkdir(parents=True, exist_ok=True)
    digest = hashlib.sha256()
    for i, state in enumerate(weights):
        buffer = _tensor_bytes({k: v.detach().cpu().clone() for k, v in state.items()})
        digest.update(buffer)
        _atomic_write(folder / learner_file(i), buffer)
    full = replace(record, n_learners=len(weights), weights_sha256=digest.hexdigest())
    _atomic_write(folder / META_FILE, (json.dumps(to_mapping(full), indent=2, sort_keys=True) + "\n").encode())
    return digest.hexdigest()


def _tensor_bytes(state: dict[str, th.Tensor]) -> bytes:
    import io

    buf = io.BytesIO()
    th.save(state, buf)
    return buf.getvalue()


def load_checkpoint(folder: Path) -> Checkpoint:
    """Read a checkpoint folder; a missing, corrupt or mismatching file raises CheckpointError naming it."""
    meta_path = folder / META_FILE
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CheckpointError(str(meta_path), "missing: train the policy first (dvc repro train)") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise CheckpointError(str(meta_path), f"unreadable or not JSON ({exc})") from exc
    record = read_train_record(meta, meta_path)
    weights = []
    digest = hashlib.sha256()
    for i in range(record.n_learners):
        path = folder / learner_file(i)
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise CheckpointError(str(path), f"missing or unreadable ({exc.strerror})") from exc
        digest.update(data)
        try:
            import io

            state = th.load(io.BytesIO(data), map_location="cpu", weights_only=True)
        except Exception as exc:  # torch raises several unpickling and zip errors for corrupt files
            raise CheckpointError(str(path), f"corrupt weights file ({type(exc).__name__}: {exc})") from exc
        if not isinstance(state, dict) or not all(isinstance(v, th.Tensor) for v in state.values()):
            raise CheckpointError(str(path), "holds something other than a mapping of tensors")
        weights.append(state)
    if digest.hexdigest() != record.weights_sha256:
        raise CheckpointError(str(folder), "weights do not match the digest in train.json (a partial or mixed write)")
    return Checkpoint(record=record, weights=weights)


def read_train_record(data: Any, path: Path) -> TrainRecord:
    """The checked description of parsed ``train.json`` `data`; CheckpointError for another format, ConfigError naming
    each bad key."""
    if not isinstance(data, dict) or not isinstance(data.get("n_learners"), int):
        raise CheckpointError(str(path), "not a training checkpoint description (no n_learners)")
    fmt = data.get("format")
    if fmt != TRAIN_FORMAT:
        raise CheckpointError(
            str(path),
            f"format {fmt!r} (none: written by an earlier version); this version reads {TRAIN_FORMAT!r}: train the "
            "policy again (dvc repro train, or python stages/train.py --round <round>)",
        )
    return from_mapping(TrainRecord, data, str(path))
