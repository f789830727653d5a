"""Trials of the benchmark: one algorithm in one mode and scenario with one seed (and any params.yaml keys set).

A trial trains with params.yaml's ``train`` section (algorithm, mode, seed and the trial's keys swapped in;
the action kind follows the algorithm), exports the policy, evaluates it in the simulated world from the
scenario's exact starts and writes its row (``row.json``, written whole or not at all) beside its learning
curve and policy in ``<sweep>/trials/<name>/``. A trial whose row exists, made with the same settings (the
row keeps a digest of them), is finished: a sweep run again skips it; a row of other settings (params.yaml
changed since) is stale, and the trial runs again.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline.errors import ConfigError, ConfigProblem
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import NetworkConfig, NetworkRanges, Params

ALGORITHMS = ("sac", "dqn", "ppo")
MODES = ("independent", "shared", "centralized")
ROW_FILE = "row.json"
EVAL_SEED = 10_000
"""Evaluation episodes use noise seeds EVAL_SEED, EVAL_SEED + 1, ... (the same for every trial)."""


DIGEST_KEYS_ADDED: dict[str, Any] = {
    "world.reward.path_clearance_m": 0.0,
    "world.reward.proximity": 0.0,
    "world.reward.proximity_m": 0.3,
    "world.observed_pose": "odometry",
    "train.observation_scaling": "none",
    "train.imitation.steps": 0,
    "train.imitation.epochs": 20,
    "train.imitation.log_std": -1.0,
    "train.imitation.rounds": 1,
    "train.imitation.teacher": "scripted",
    "train.imitation.memory_dropout": 0.0,
    "train.share_experience": False,
    "train.overlap": False,
    "train.n_step": 1,
    "train.selection.stop_after_convergence": False,
    "world.lidar.range_step_m": 0.0,
    "world.lidar.beam_noise_spread": 0.0,
    "world.lidar.mixed_pixel_prob": 0.0,
    "world.lidar.no_return": "inf",
    "world.lidar.scan_drop_prob": 0.0,
    "fleet_check.out": "logs/fleet_check.json",
    **{f"world.network.{k}": v for k, v in to_mapping(NetworkConfig()).items()},
    **{f"world.randomize.network.{k}": v for k, v in to_mapping(NetworkRanges()).items()},
}
"""Settings added to params.yaml after trials were first digested, each with the value that behaves as before it
existed. At that value a setting is left out of a trial's digest, so a trial finished before the setting
existed stays finished; at any other value the trial differs and runs. A new setting is added here."""


def action_kind(algorithm: str) -> str:
    """The action space an algorithm trains on: DQN's are discrete, SAC's and PPO's continuous."""
    return "discrete" if algorithm == "dqn" else "continuous"


SECTIONS_ADDED = ("world.network", "world.randomize.network")
"""Sections added whole after trials were run: with each of their keys at its neutral value they are left out."""


def _prune_empty(settings: dict[str, Any]) -> None:
    """Remove the sections of :data:`SECTIONS_ADDED` that hold nothing (every key at its neutral value)."""
    for section in SECTIONS_ADDED:
        *path, leaf = section.split(".")
        node = settings
        for part in path:
            node = node.get(part, {})
        if node.get(leaf) == {}:
            del node[leaf]


@dataclass(frozen=True)
class Trial:
    """One cell of the matrix with one seed; `keys` are params.yaml keys (dotted) set for this trial."""

    algorithm: str
    mode: str
    scenario: str
    seed: int
    keys: tuple[tuple[str, Any], ...] = ()

    @property
    def scenario_label(self) -> str:
        """The scenario in names and tables: a bundled one's name; a file's stem and a short digest of its path
        (a path's slashes would split the cell and nest the trial's folder)."""
        if "/" not in self.scenario and not self.scenario.endswith((".yaml", ".yml")):
            return self.scenario
        digest = hashlib.sha256(self.scenario.encode()).hexdigest()[:6]
        return f"{Path(self.scenario).stem}.{digest}"

    @property
    def cell(self) -> str:
        """The trial without its seed: what seeds are aggregated over."""
        extra = ",".join(f"{k}={v}" for k, v in self.keys)
        return f"{self.algorithm}/{self.mode}/{self.scenario_label}" + (f"/{extra}" if extra else "")

    @property
    def name(self) -> str:
        """A folder name, unique per trial (the keys by a short digest)."""
        base = f"{self.algorithm}-{self.mode}-{self.scenario_label}-seed{self.seed}"
        if not self.keys:
            return base
        digest = hashlib.sha256(json.dumps(self.keys, sort_keys=True).encode()).hexdigest()[:8]
        return f"{base}-{digest}"

    def digest(self, base: Mapping[str, Any]) -> str:
        """A short digest of every setting the trial trains and evaluates with (a row of other settings is stale).

        Not of `train.world_workers`: how many processes step the worlds changes no transition; nor of a
        setting of :data:`DIGEST_KEYS_ADDED` at its value from before it existed."""
        settings = to_mapping(self.params(base))
        settings["train"].pop("world_workers", None)
        for key, neutral in DIGEST_KEYS_ADDED.items():
            *path, leaf = key.split(".")
            node = settings
            for part in path:
                node = node[part]
            if node.get(leaf) == neutral:
                del node[leaf]
        _prune_empty(settings)
        text = json.dumps(settings, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def params(self, base: Mapping[str, Any], source: str = "params.yaml") -> Params:
        """`base` (params.yaml as a mapping) with this trial's algorithm, mode, seed, action kind and keys."""
        changes: dict[str, Any] = {
            "train": {"algorithm": self.algorithm, "mode": self.mode, "seed": self.seed},
            "world": {"scenario": self.scenario, "actions": {"kind": action_kind(self.algorithm)}},
        }
        for key, value in self.keys:
            changes = merge(changes, _nested(key, value))
        return from_mapping(Params, merge(dict(base), changes), f"{source} with trial {self.name}")


def _nested(key: str, value: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    node = out
    parts = key.split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    node[parts[-1]] = value
    return out


def parse_axis(text: str) -> tuple[str, list[Any]]:
    """``train.learning_rate=0.0003,0.001`` -> ("train.learning_rate", [0.0003, 0.001]) (values read as YAML)."""
    key, sep, values = text.partition("=")
    if not sep or not key or not values or "." not in key:
        raise ConfigError(
            "--axis", [ConfigProblem(text, "", "KEY=V1,V2,... with a dotted params.yaml key (train.learning_rate)")]
        )
    return key, [yaml.safe_load(v) for v in values.split(",")]


def parse_setting(text: str) -> tuple[str, Any]:
    """``train.total_steps=300000`` -> ("train.total_steps", 300000) (the value read as YAML)."""
    key, sep, value = text.partition("=")
    if not sep or not key or not value or "." not in key:
        raise ConfigError(
            "--set", [ConfigProblem(text, "", "KEY=VALUE with a dotted params.yaml key (train.total_steps=300000)")]
        )
    return key, yaml.safe_load(value)


def with_settings(base: Mapping[str, Any], settings: Sequence[tuple[str, Any]]) -> dict[str, Any]:
    """`base` with every trial's `settings` set; checked against params.yaml's rules before anything runs."""
    out = dict(base)
    for key, value in settings:
        out = merge(out, _nested(key, value))
    if settings:
        from_mapping(Params, out, "params.yaml with --set " + " ".join(f"{k}={v}" for k, v in settings))
    return out


def expand(
    algorithms: Sequence[str],
    modes: Sequence[str],
    scenarios: Sequence[str],
    seeds: Sequence[int],
    axes: Sequence[tuple[str, Sequence[Any]]] = (),
) -> list[Trial]:
    """Every combination, seeds innermost, in a fixed order."""
    bad = [ConfigProblem("algorithm", a, " | ".join(ALGORITHMS)) for a in algorithms if a not in ALGORITHMS]
    bad += [ConfigProblem("mode", m, " | ".join(MODES)) for m in modes if m not in MODES]
    if len(set(seeds)) != len(seeds):
        bad.append(ConfigProblem("seeds", list(seeds), "distinct seeds"))
    if bad:
        raise ConfigError("sweep", bad)
    keys = [key for key, _ in axes]
    combos = list(itertools.product(*[values for _, values in axes])) if axes else [()]
    return [
        Trial(a, m, s, seed, tuple(zip(keys, combo, strict=True)))
        for a in algorithms
        for m in modes
        for s in scenarios
        for combo in combos
        for seed in seeds
    ]


def scoped_settings(trials: Sequence[Trial], scoped: Sequence[Sequence[str]]) -> list[Trial]:
    """`trials` with each (algorithm, ``KEY=VALUE``) of `scoped` added to the keys of that algorithm's trials."""
    parsed = []
    for pair in scoped:
        algorithm, text = pair[0], pair[1]
        if algorithm not in ALGORITHMS:
            raise ConfigError("--set-for", [ConfigProblem("algorithm", algorithm, " | ".join(ALGORITHMS))])
        key, value = parse_setting(text)
        parsed.append((algorithm, key, value))
    return scoped_keys(trials, parsed)


SETTINGS_SCOPES = ("all", *ALGORITHMS)
"""The sections of a sweep's settings file: keys for every trial, and keys for one algorithm's trials."""


def read_settings_file(path: str | Path) -> tuple[list[tuple[str, Any]], list[tuple[str, str, Any]]]:
    """A sweep's settings file: ``all:`` (keys for every trial) and ``sac:``/``dqn:``/``ppo:`` (keys for that
    algorithm's trials), each a mapping of dotted params.yaml keys to values. Returns (every trial's settings,
    (algorithm, key, value) of the scoped ones); a section or a key that is not allowed raises ConfigError naming the
    file and the key (the values are checked against params.yaml's rules with the trials)."""
    where = str(path)
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(where, [ConfigProblem("file", where, f"a readable YAML file ({exc.strerror})")]) from exc
    except yaml.YAMLError as exc:
        raise ConfigError(where, [ConfigProblem("file", where, f"valid YAML ({exc})")]) from exc
    if not isinstance(data, dict):
        raise ConfigError(
            where, [ConfigProblem("file", type(data).__name__, "a mapping of " + ", ".join(SETTINGS_SCOPES))]
        )
    problems = [ConfigProblem(str(k), "", " | ".join(SETTINGS_SCOPES)) for k in data if k not in SETTINGS_SCOPES]
    every: list[tuple[str, Any]] = []
    scoped: list[tuple[str, str, Any]] = []
    for scope, keys in data.items():
        if scope not in SETTINGS_SCOPES:
            continue
        if not isinstance(keys, dict):
            problems.append(ConfigProblem(str(scope), keys, "a mapping of dotted params.yaml keys to values"))
            continue
        for key, value in keys.items():
            if not isinstance(key, str) or key.count(".") < 1 or key.split(".")[0] not in ("train", "world"):
                problems.append(ConfigProblem(f"{scope}.{key}", value, "a dotted params.yaml key under train or world"))
            elif scope == "all":
                every.append((key, value))
            else:
                scoped.append((scope, key, value))
    if problems:
        raise ConfigError(where, problems)
    return every, scoped


def scoped_keys(trials: Sequence[Trial], scoped: Sequence[tuple[str, str, Any]]) -> list[Trial]:
    """`trials` with each (algorithm, key, value) of `scoped` added to the keys of that algorithm's trials."""
    return [
        dataclasses.replace(t, keys=t.keys + tuple((k, v) for a, k, v in scoped if a == t.algorithm)) for t in trials
    ]


@dataclass
class TrialRow:
    """What one finished trial reports (one row of the sweep's table)."""

    name: str
    cell: str
    algorithm: str
    mode: str
    scenario: str
    seed: int
    keys: str
    train_steps: int
    train_episodes: int
    train_wall_s: float
    env_steps_per_s: float
    converged_at_episode: int | None
    converged_at_steps: int | None
    wall_to_convergence_s: float | None
    eval_episodes: int
    robot_success: float
    team_success: float
    collision_rate: float
    time_to_goal_s: float | None = None
    """Mean time of the robots that reached their goals (in a pursuit: time to capture); None if none did."""
    params_digest: str = ""
    fixed_layout_robot_success: float | None = None
    """With random layouts: robot success over the same number of episodes in the scenario's own layout."""
    fixed_layout_team_success: float | None = None
    robot_success_by_robot: dict[str, float] = field(default_factory=dict)

    def as_flat(self) -> dict[str, Any]:
        """One flat record (per-robot success as ``success_<robot>`` columns)."""
        out = {k: v for k, v in self.__dict__.items() if k != "robot_success_by_robot"}
        out.update({f"success_{robot}": v for robot, v in self.robot_success_by_robot.items()})
        return out


def run_trial(
    trial: Trial,
    base: Mapping[str, Any],
    folder: Path,
    eval_episodes: int,
    say: Callable[[str], None] = print,
    scenario_file: Path | None = None,
) -> dict[str, Any]:
    """Train, export and evaluate `trial`; write and return its row (see the module's description). With
    `scenario_file`, the trial's scenario is read from there (its copy on this node; the row keeps its name)."""
    import torch

    from pipeline.core.episode import summarize
    from pipeline.learn.export import export_policy, golden_observations
    from pipeline.learn.trainer import train
    from pipeline.policy.runtime import PolicyRuntime
    from pipeline.rollout.sim import evaluate
    from pipeline.sim import make_world
    from pipeline.sim.env import MultiRobotSim

    params = trial.params(base)
    if scenario_file is not None:
        params = replace(params, world=replace(params.world, scenario=str(scenario_file)))
    torch.manual_seed(trial.seed)
    scenario, world = make_world(world=params.world)
    folder.mkdir(parents=True, exist_ok=True)
    say(f"trial {trial.name}: training {params.train.total_steps} steps")
    start = time.perf_counter()

    def report(episodes: int, steps: int, success: float) -> None:
        rate = steps / max(time.perf_counter() - start, 1e-9)
        say(f"trial {trial.name}: {episodes} episodes, {steps} steps, success {success:.2f}, {rate:.0f} steps/s")

    result = train(scenario, world, params.train, folder / "run", progress=False, report=report)
    wall = time.perf_counter() - start
    export_policy(result.checkpoint, folder / "policy", golden_observations(scenario, world, 32))
    runtime = PolicyRuntime(folder / "policy")
    results = evaluate(MultiRobotSim(scenario, world), runtime.actions, eval_episodes, seed=EVAL_SEED, progress=False)
    summary = summarize(results, prefix="eval")
    per_robot = np.stack([r.success for r in results]).mean(axis=0)  # every episode counts
    fixed: dict[str, float] = {}
    if scenario.layouts is not None and world.layouts == "random":  # held-out layouts above; the own one too
        own = MultiRobotSim(scenario, replace(world, layouts="fixed"))
        fixed = summarize(evaluate(own, runtime.actions, eval_episodes, seed=EVAL_SEED, progress=False), prefix="f")
    converged_wall = (
        wall * result.converged_at_steps / max(result.world_steps, 1) if result.converged_at_steps is not None else None
    )
    row = TrialRow(
        name=trial.name,
        cell=trial.cell,
        algorithm=trial.algorithm,
        mode=trial.mode,
        scenario=trial.scenario,
        seed=trial.seed,
        keys=json.dumps(dict(trial.keys), sort_keys=True),
        train_steps=result.world_steps,
        train_episodes=result.episodes,
        train_wall_s=wall,
        env_steps_per_s=result.world_steps / max(wall, 1e-9),
        converged_at_episode=result.converged_at_episode,
        converged_at_steps=result.converged_at_steps,
        wall_to_convergence_s=converged_wall,
        eval_episodes=len(results),
        robot_success=summary["eval/robot_success"],
        team_success=summary["eval/team_success"],
        collision_rate=summary["eval/collision_rate"],
        time_to_goal_s=None if math.isnan(summary["eval/mean_time_to_goal_s"]) else summary["eval/mean_time_to_goal_s"],
        params_digest=trial.digest(base),
        fixed_layout_robot_success=fixed.get("f/robot_success"),
        fixed_layout_team_success=fixed.get("f/team_success"),
        robot_success_by_robot={name: float(v) for name, v in zip(scenario.robot_names, per_robot, strict=True)},
    )
    record = row.as_flat()
    write_row(folder, record)
    say(
        f"trial {trial.name}: done in {wall:.0f} s, robot success {row.robot_success:.3f}, team {row.team_success:.3f}"
        + (f", converged at episode {row.converged_at_episode}" if row.converged_at_episode is not None else "")
    )
    return record


def write_row(folder: Path, record: Mapping[str, Any]) -> Path:
    """Write `record` as the trial's row, atomically (a killed trial leaves no row)."""
    path = folder / ROW_FILE
    tmp = folder / f".{ROW_FILE}.{os.getpid()}"
    tmp.write_text(json.dumps(record, indent=1, sort_keys=True), encoding="utf-8")
    os.replace(tmp, path)
    return path


def read_row(folder: Path, digest: str | None = None) -> dict[str, Any] | None:
    """The trial's row, or None when it has not finished (or, with `digest`, finished with other settings)."""
    path = folder / ROW_FILE
    if not path.is_file():
        return None
    row = dict(json.loads(path.read_text(encoding="utf-8")))
    if digest is not None and row.get("params_digest") != digest:
        return None
    return row


def base_mapping(params: Params) -> dict[str, Any]:
    """params.yaml as the plain mapping trials start from."""
    mapping: dict[str, Any] = to_mapping(params)
    return mapping
