"""Training checkpoints: network weights as plain tensors plus a JSON description, written atomically.

Weights are saved with ``torch.save`` of a dict of tensors and read back with
``torch.load(weights_only=True)``, which refuses anything but tensors and plain containers: no
code runs when a checkpoint is loaded.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch as th

from pipeline.learn.errors import CheckpointError

META_FILE = "train.json"


def learner_file(index: int) -> str:
    return f"learner_{index}.pt"


@dataclass(frozen=True)
class Checkpoint:
    """A loaded checkpoint: its description and each learner's policy weights."""

    meta: dict[str, Any]
    weights: list[dict[str, th.Tensor]]


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def save_checkpoint(folder: Path, meta: dict[str, Any], weights: list[dict[str, th.Tensor]]) -> str:
    """Write every learner's weights, then the description with their digest; returns the digest."""
    folder.mkdir(parents=True, exist_ok=True)
    digest = hashlib.sha256()
    for i, state in enumerate(weights):
        buffer = _tensor_bytes({k: v.detach().cpu().clone() for k, v in state.items()})
        digest.update(buffer)
        _atomic_write(folder / learner_file(i), buffer)
    full = {**meta, "n_learners": len(weights), "weights_sha256": digest.hexdigest()}
    _atomic_write(folder / META_FILE, (json.dumps(full, indent=2, sort_keys=True) + "\n").encode())
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
    if not isinstance(meta, dict) or not isinstance(meta.get("n_learners"), int):
        raise CheckpointError(str(meta_path), "not a training checkpoint description (no n_learners)")
    weights = []
    digest = hashlib.sha256()
    for i in range(meta["n_learners"]):
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
    if digest.hexdigest() != meta.get("weights_sha256"):
        raise CheckpointError(str(folder), "weights do not match the digest in train.json (a partial or mixed write)")
    return Checkpoint(meta=meta, weights=weights)
