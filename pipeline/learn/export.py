"""Export: a training checkpoint (weights only) -> ONNX graph + JSON description + golden set.

The exporter never unpickles: it reads the checkpoint's tensors with ``weights_only`` loading,
builds the ONNX graph from them (:mod:`pipeline.policy.onnx_graph`), and checks it against the
training library's own torch network rebuilt from the same weights on a golden set of
observations. The golden set (observations and the torch actions) is written beside the policy,
so any runtime can re-check the file it loaded.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import gymnasium
import numpy as np
import onnx
import onnxruntime
import torch as th

from pipeline.learn.checkpoint import META_FILE, TrainRecord, load_checkpoint
from pipeline.learn.common.modes import deterministic_actions
from pipeline.learn.common.scaling import BoundsScaling, space_of
from pipeline.mappings import from_mapping, to_mapping
from pipeline.params import WorldConfig
from pipeline.policy.errors import PolicyError
from pipeline.policy.networks import SCALE_CENTER, SCALE_HALF_RANGE, ActionNetwork, action_network
from pipeline.policy.onnx_graph import INPUT, policy_graph
from pipeline.policy.spec import (
    FORMAT,
    GOLDEN_FILE,
    ONNX_FILE,
    SPEC_FILE,
    GoldenSet,
    PolicySpec,
    write_golden,
    write_policy_spec,
)


@dataclass(frozen=True)
class ExportResult:
    folder: Path
    onnx_sha256: str
    max_abs_diff: float
    golden_samples: int
    discrete_agreement: float


def _torch_policy(
    kind: str, weights: dict[str, th.Tensor], obs_size: int, action_space: gymnasium.Space[Any], net_arch: list[int]
) -> Any:
    """The training library's own network for `kind`, built from spaces and loaded with `weights` (strict)."""
    obs_space: gymnasium.spaces.Box[Any] = gymnasium.spaces.Box(-np.inf, np.inf, shape=(obs_size,), dtype=np.float32)

    def lr(_: float) -> float:
        return 0.0

    policy: Any
    if kind == "sac_actor":
        from stable_baselines3.sac.policies import SACPolicy

        policy = SACPolicy(obs_space, action_space, lr, net_arch=net_arch)  # type: ignore[arg-type]
    elif kind == "ppo_actor":
        from stable_baselines3.common.policies import ActorCriticPolicy

        scaled: dict[str, Any] = {}
        if SCALE_CENTER in weights:
            obs_space = space_of(weights[SCALE_CENTER].numpy(), weights[SCALE_HALF_RANGE].numpy())
            scaled = {"features_extractor_class": BoundsScaling}
        policy = ActorCriticPolicy(obs_space, action_space, lr, net_arch={"pi": net_arch, "vf": net_arch}, **scaled)
    else:
        from stable_baselines3.dqn.policies import DQNPolicy

        from pipeline.learn.dqn.model import DuelingDQNPolicy

        cls = DuelingDQNPolicy if kind == "dqn_dueling" else DQNPolicy
        policy = cls(obs_space, action_space, lr, net_arch=net_arch)  # type: ignore[arg-type]
    policy.load_state_dict(weights, strict=True)
    policy.set_training_mode(False)
    return policy


def learner_spaces(record: TrainRecord) -> tuple[int, gymnasium.Space[Any]]:
    """(input size, action space) of each learner network of a checkpoint description."""
    n = len(record.robots)
    obs_size = record.observation.size
    discrete = record.actions.kind == "discrete"
    k = len(record.actions.discrete_set)
    if record.mode == "centralized":
        space: gymnasium.Space[Any] = (
            gymnasium.spaces.Discrete(k**n) if discrete else gymnasium.spaces.Box(-1.0, 1.0, (2 * n,), np.float32)
        )
        return n * obs_size, space
    space = gymnasium.spaces.Discrete(k) if discrete else gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
    return obs_size, space


def _reference_actions(nets: list[Any], record: TrainRecord, obs: np.ndarray) -> np.ndarray:
    """Per-robot actions (samples, n_robots, 2) or (samples, n_robots) from the torch networks."""
    return deterministic_actions(
        nets,
        record.mode,
        len(record.robots),
        record.actions.kind == "discrete",
        len(record.actions.discrete_set),
        obs,
    )


def _check_sizes(networks: list[ActionNetwork], record: TrainRecord, where: str) -> None:
    size, space = learner_spaces(record)
    want_out = int(space.n) if isinstance(space, gymnasium.spaces.Discrete) else int(np.prod(space.shape or (1,)))
    for i, net in enumerate(networks):
        if net.input_size != size or net.output_size != want_out:
            raise PolicyError(
                where,
                f"network {i} maps {net.input_size} -> {net.output_size} values, but the recorded layout and "
                f"action space need {size} -> {want_out}",
            )


GOLDEN_COMPARED: Literal["commands"] = "commands"
"""golden.json's tolerance is a share of the robots' limits on the decoded commands (older files: raw actions)."""
COMMAND_TOLERANCE = 1e-3
"""How far the exported graph's commands may be from torch's, as a share of each robot's limit on each channel (0.4
mm/s and 0.2 mrad/s for the SPARK's 0.4 m/s and 0.2 rad/s): far below what a base can execute, far above the float32
round-off of a correct graph (about 1e-5 of its raw outputs), and far below what a wrong layer or order gives."""


def command_difference(world: WorldConfig, onnx_actions: np.ndarray, torch_actions: np.ndarray) -> float:
    """The largest :meth:`~pipeline.core.actions.ActionCodec.command_difference` over (samples, n_robots, 2) actions."""
    codec = world.codec()
    return max((codec.command_difference(a, b) for a, b in zip(onnx_actions, torch_actions, strict=True)), default=0.0)


def export_policy(
    checkpoint_dir: Path,
    out_dir: Path,
    golden_obs: np.ndarray,
    tolerance: float = COMMAND_TOLERANCE,
    opset: int = 17,
) -> ExportResult:
    """Export the checkpoint in `checkpoint_dir` to `out_dir`; `golden_obs` is (samples, n_robots, obs_size).

    Raises PolicyError if the ONNX graph's commands differ from the torch network's by more than `tolerance` of the
    robots' limits (continuous; :func:`command_difference`) or if it picks another action (discrete).
    """
    ckpt = load_checkpoint(checkpoint_dir)
    record = ckpt.record
    where = str(checkpoint_dir)
    discrete = record.actions.kind == "discrete"
    n = len(record.robots)
    obs_size = record.observation.size
    networks = [
        action_network(record.policy_kind, {k: v.numpy() for k, v in w.items()}, discrete, f"{where}/learner_{i}.pt")
        for i, w in enumerate(ckpt.weights)
    ]
    _check_sizes(networks, record, where)
    golden = np.asarray(golden_obs, dtype=np.float32)
    if golden.ndim != 3 or golden.shape[1:] != (n, obs_size):
        raise PolicyError(where, f"golden observations have shape {golden.shape}, need (samples, {n}, {obs_size})")
    model = policy_graph(
        networks,
        record.mode,
        n,
        obs_size,
        discrete,
        len(record.actions.discrete_set),
        opset=opset,
        doc=f"{record.algorithm} {record.mode} policy for {', '.join(record.robots)}",
    )
    data = model.SerializeToString()
    session = onnxruntime.InferenceSession(data, providers=["CPUExecutionProvider"])
    onnx_actions = np.stack([session.run(None, {INPUT: o})[0] for o in golden])
    size, space = learner_spaces(record)
    torch_nets = [_torch_policy(record.policy_kind, w, size, space, list(record.net_arch)) for w in ckpt.weights]
    torch_actions = _reference_actions(torch_nets, record, golden)
    if discrete:
        agree = onnx_actions == torch_actions
        if not agree.all():
            raise PolicyError(
                where, f"ONNX and torch pick different discrete actions on {int((~agree).sum())} golden rows"
            )
        max_diff, agreement = 0.0, 1.0
    else:
        max_diff, agreement = command_difference(record.world, onnx_actions, torch_actions), 1.0
        if max_diff > tolerance:
            raise PolicyError(
                where,
                f"the ONNX graph's commands differ from torch's by {max_diff:.3g} of the robots' limits "
                f"(tolerance {tolerance:g}): the graph does not compute the trained network",
            )
    sha = hashlib.sha256(data).hexdigest()
    spec = policy_spec(record, sha, opset, f"{where}/{META_FILE}")  # validated before any file is written
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / ONNX_FILE).write_bytes(data)
    write_golden(GoldenSet(golden, torch_actions, tolerance, GOLDEN_COMPARED), out_dir / GOLDEN_FILE)
    write_policy_spec(spec, out_dir / SPEC_FILE)
    return ExportResult(
        folder=out_dir, onnx_sha256=sha, max_abs_diff=max_diff, golden_samples=len(golden), discrete_agreement=agreement
    )


def policy_spec(record: TrainRecord, onnx_sha256: str, opset: int, source: str) -> PolicySpec:
    """The spec of a policy exported from a checkpoint described by `record`; ConfigError names a bad key."""
    mapping = {
        "format": FORMAT,
        "onnx": {"file": ONNX_FILE, "sha256": onnx_sha256, "opset": opset, "input": INPUT, "output": "action"},
        "golden": GOLDEN_FILE,
        "algorithm": record.algorithm,
        "mode": record.mode,
        "policy_kind": record.policy_kind,
        "robots": to_mapping(record.robots),
        "observation": to_mapping(record.observation),
        "world": to_mapping(record.world),
        "scenario": to_mapping(record.scenario),
        "training": {
            "digest": record.weights_sha256,
            "seed": record.train.seed,
            "world_steps": record.world_steps,
            "episodes": record.episodes,
            "converged_at_episode": record.converged_at_episode,
            "interrupted": record.interrupted,
            "round": record.round,
        },
        "versions": {**to_mapping(record.versions), "onnx": onnx.__version__, "onnxruntime": onnxruntime.__version__},
    }
    return from_mapping(PolicySpec, mapping, source)


def golden_observations(scenario: Any, world: Any, count: int, seed: int = 0) -> np.ndarray:
    """(count, n_robots, obs_size) observations from simulated episodes under random actions.

    Random driving spreads the set over the room: near walls, boxes and other robots as well as
    at the starts.
    """
    from pipeline.sim.env import MultiRobotSim

    sim = MultiRobotSim(scenario, world)
    rng = np.random.default_rng(seed)
    out = [sim.reset(seed)]
    episode = 0
    while len(out) < count:
        if world.actions.kind == "continuous":
            act: np.ndarray = rng.uniform(-1.0, 1.0, size=(scenario.n_robots, 2))
        else:
            act = rng.integers(0, sim.codec.n_discrete, size=scenario.n_robots)
        step = sim.step(act)
        out.append(step.obs)
        if step.judge.done.all() or step.judge.truncated:
            episode += 1
            out.append(sim.reset(seed + episode))
    return np.stack(out[:count]).astype(np.float32)
