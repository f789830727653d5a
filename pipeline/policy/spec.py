"""The policy spec: everything a runtime needs to know about an exported policy, as one typed, versioned file.

``policy.json`` beside ``policy.onnx`` is written by export (:mod:`pipeline.learn.export`) and read by
the runtime (:mod:`pipeline.policy.runtime`) with the same strict rules as params.yaml: an unknown,
missing, mistyped or out-of-range key is an error naming it, and nothing is filled in by a default.
It records the whole world the policy was trained in (the same keys as params.yaml's ``world``), so
the MDP a fleet runs (:func:`pipeline.mdp.mdp_parts`) is the one of training, and the scenario.

Format ``mrl-policy/2``; files of format 1 (free-form, read with defaults) are refused with the
command that exports them again.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pipeline.core.observation import LayoutName
from pipeline.core.scenario import Scenario
from pipeline.mappings import from_mapping, setting, to_mapping
from pipeline.mdp import MdpDefinition
from pipeline.params import Algorithm, Mode, WorldConfig
from pipeline.policy.errors import PolicyError
from pipeline.policy.networks import PolicyKind

FORMAT = "mrl-policy/2"
SPEC_FILE = "policy.json"
ONNX_FILE = "policy.onnx"
GOLDEN_FILE = "golden.json"


@dataclass(frozen=True)
class OnnxFile:
    """The ONNX graph: file name beside the spec, its sha256, opset, input and output names."""

    file: str = setting()
    sha256: str = setting()
    opset: int = setting(ge=7, le=30)
    input: str = setting()
    output: str = setting()


@dataclass(frozen=True)
class ObservationInput:
    """The graph's input: the observation layout, its lidar beams and the vector's size per robot."""

    layout: LayoutName = setting()
    n_beams: int = setting(ge=1, le=4096)
    size: int = setting(ge=1)


@dataclass(frozen=True)
class TrainingRecord:
    """Where the weights come from: the checkpoint's digest, seed, budget used, convergence."""

    digest: str = setting()
    seed: int = setting(ge=0)
    world_steps: int = setting(ge=0)
    episodes: int = setting(ge=0)
    converged_at_episode: int | None = setting(ge=0)
    interrupted: bool = setting()
    round: str = setting(allow_empty=True)


@dataclass(frozen=True)
class Versions:
    """Library versions of training and export."""

    stable_baselines3: str = setting()
    torch: str = setting()
    onnx: str = setting()
    onnxruntime: str = setting()


@dataclass(frozen=True)
class PolicySpec:
    """One exported policy (``policy.json``)."""

    format: Literal["mrl-policy/2"] = setting()
    onnx: OnnxFile = setting()
    golden: str = setting()
    algorithm: Algorithm = setting()
    mode: Mode = setting()
    policy_kind: PolicyKind = setting()
    robots: tuple[str, ...] = setting(min_len=1)
    observation: ObservationInput = setting()
    world: WorldConfig = setting()
    """The world the policy was trained in (params.yaml ``world`` keys, calibration included)."""
    scenario: Scenario = setting()
    training: TrainingRecord = setting()
    versions: Versions = setting()

    def check(self) -> list[tuple[str, object, str]]:
        bad: list[tuple[str, object, str]] = []
        layout = self.world.layout()
        if (self.observation.layout, self.observation.n_beams, self.observation.size) != (
            layout.name,
            layout.n_beams,
            layout.size,
        ):
            bad.append(
                (
                    "observation",
                    to_mapping(self.observation),
                    f"the layout of world ({layout.name!r} with {layout.n_beams} beams: {layout.size} values)",
                )
            )
        if self.robots != self.scenario.robot_names:
            bad.append(("robots", list(self.robots), f"the scenario's robots {list(self.scenario.robot_names)}"))
        return bad

    @property
    def mdp(self) -> MdpDefinition:
        """The MDP the policy was trained in."""
        return MdpDefinition.of(self.world)

    def to_json(self) -> str:
        return json.dumps(to_mapping(self), indent=2, sort_keys=True) + "\n"


def read_policy_spec(path: str | Path) -> PolicySpec:
    """Read and validate ``policy.json``: PolicyError for an unreadable or old file, ConfigError naming each bad key."""
    p = Path(path)
    data = _json_object(p, "export the policy first (dvc repro export)", "a policy spec")
    fmt = data.get("format")
    if fmt != FORMAT:
        if isinstance(fmt, str) and fmt.startswith("mrl-policy/"):
            raise PolicyError(
                str(p),
                f"format {fmt!r} was written by an earlier export; this runtime reads {FORMAT!r}: export the policy "
                "again from its checkpoint (python stages/export.py --round <round>, or dvc repro export)",
            )
        raise PolicyError(str(p), f"format {fmt!r} is not a policy spec; this runtime reads {FORMAT!r}")
    return from_mapping(PolicySpec, data, str(p))


def _json_object(path: Path, remedy: str, what: str) -> dict[str, Any]:
    """The JSON object in `path`; PolicyError naming it when missing (with `remedy`), unreadable or not an object."""
    try:
        data: Any = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise PolicyError(str(path), f"missing: {remedy}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PolicyError(str(path), f"unreadable or not JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise PolicyError(str(path), f"not {what} (expected a JSON object)")
    return data


def write_policy_spec(spec: PolicySpec, path: str | Path) -> None:
    """Write `spec` as ``policy.json`` (keys sorted, so equal specs give equal bytes)."""
    Path(path).write_text(spec.to_json(), encoding="utf-8")


GOLDEN_FORMAT = "mrl-golden/1"


@dataclass(frozen=True)
class GoldenSet:
    """``golden.json`` beside the policy: observations, the training library's actions for them, and how close the
    exported graph must come. ``compared``: ``commands`` (a share of the robots' limits on the decoded commands) or
    ``actions`` (raw actions; files written before the commands were compared, read as such)."""

    observations: np.ndarray
    """(samples, n_robots, obs_size) float32."""
    actions: np.ndarray
    """(samples, n_robots, 2) continuous or (samples, n_robots) discrete."""
    tolerance: float
    compared: Literal["commands", "actions"]

    def to_json(self) -> str:
        return (
            json.dumps(
                {
                    "format": GOLDEN_FORMAT,
                    "observations": self.observations.tolist(),
                    "actions": self.actions.tolist(),
                    "tolerance": self.tolerance,
                    "compared": self.compared,
                }
            )
            + "\n"
        )


def write_golden(golden: GoldenSet, path: str | Path) -> None:
    """Write ``golden.json``, the one writer (export)."""
    Path(path).write_text(golden.to_json(), encoding="utf-8")


def read_golden(path: str | Path) -> GoldenSet:
    """Read ``golden.json``; PolicyError naming the file and what is wrong. Untagged files are the earlier layout of
    the same keys (``compared`` absent: raw actions)."""
    p = Path(path)
    data = _json_object(p, "export the policy again (dvc repro export)", "a golden set")
    fmt = data.get("format", GOLDEN_FORMAT)
    if fmt != GOLDEN_FORMAT:
        raise PolicyError(str(p), f"format {fmt!r}; this runtime reads {GOLDEN_FORMAT!r}: export the policy again")
    unknown = sorted(set(data) - {"format", "observations", "actions", "tolerance", "compared"})
    if unknown:
        raise PolicyError(str(p), f"unknown key(s) {unknown}; allowed: observations, actions, tolerance, compared")
    compared = data.get("compared", "actions")
    if compared not in ("commands", "actions"):
        raise PolicyError(str(p), f"compared: {compared!r}; allowed: 'commands', 'actions'")
    tolerance = data.get("tolerance")
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) or not 0 <= tolerance < 1:
        raise PolicyError(str(p), f"tolerance: {tolerance!r}; allowed: a number in [0, 1)")
    try:
        obs = np.asarray(data["observations"], dtype=np.float32)
        actions = np.asarray(data["actions"], dtype=np.float64)
    except KeyError as exc:
        raise PolicyError(str(p), f"{exc.args[0]}: missing (observations and actions are required)") from None
    except (TypeError, ValueError) as exc:
        raise PolicyError(str(p), f"observations and actions must be rectangular lists of numbers ({exc})") from exc
    if obs.ndim != 3 or actions.shape[:2] != obs.shape[:2]:
        raise PolicyError(
            str(p), f"observations have shape {obs.shape}, actions {actions.shape}: need (samples, robots, ...) both"
        )
    return GoldenSet(observations=obs, actions=actions, tolerance=float(tolerance), compared=compared)
