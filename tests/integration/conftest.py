"""Shared fixtures of the integration tier: a tiny trained and exported policy, fleet files on loopback, twin
recordings of the bundled profiles."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig, load_params, world_config
from pipeline.sim import make_world
from tests.domains import domain_id

ROOT = Path(__file__).resolve().parents[2]
TINY_TRAIN = {
    "algorithm": "sac",
    "mode": "shared",
    "total_steps": 200,
    "n_envs": 2,
    "net_arch": [16, 16],
    "batch_size": 16,
    "buffer_size": 2000,
    "learning_starts": 40,
    "checkpoint_every_episodes": 5,
}
TINY_WORLD = {"scenario": "obstacles", "observation": "rich", "max_steps": 30}


@pytest.fixture(scope="session")
def tiny_policy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 3-robot SAC policy for the obstacles room (30-step episodes), exported; its folder."""
    root = tmp_path_factory.mktemp("tiny_policy")
    scenario, world = make_world(world=world_config(TINY_WORLD))
    cfg = from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), TINY_TRAIN), "<test>")
    result = train(scenario, world, cfg, root / "run", progress=False)
    export_policy(result.checkpoint, root / "policy", golden_observations(scenario, world, 8))
    return root / "policy"


def free_domain_id() -> int:
    """A DDS domain id unlikely to be used by another test run on this host, and not by this run's other worker."""
    return domain_id("fleet", os.getpid() * 7 + int(np.random.default_rng().integers(0, 1000)))


def write_fleet(path: Path, **changes: object) -> Path:
    """A twin fleet file on loopback with a fresh domain id and short timeouts; `changes` override top-level keys."""
    fleet = {
        "target": "twin",
        "transport": "dds",
        "scenario": "obstacles",
        "network": {"domain_id": free_domain_id(), "loopback_only": True, "peers": []},
        "robots": [
            {"name": f"robot_{i}", "namespace": f"robot_{i}", "v_max_mps": 0.4, "w_max_radps": 0.2} for i in (1, 2, 3)
        ],
        "twin": {"profile": "mild", "time_scale": 2.0, "seed": 0},
        "timing": {
            "tick_period_s": 0.02,
            "command_validity_s": 0.12,
            "discovery_timeout_s": 15.0,
            "reset_timeout_s": 10.0,
            "scan_stale_s": 0.5,
            "odom_stale_s": 0.3,
            "truth_stale_s": 0.3,
            "outage_limit_s": 5.0,
            "use_ground_truth": True,
        },
    }
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(fleet.get(key), dict):
            fleet[key] = {**fleet[key], **value}  # type: ignore[dict-item]
        else:
            fleet[key] = value
    path.write_text(yaml.safe_dump(fleet, sort_keys=False))
    return path


TINY_SWEEP = {
    "world": {"max_steps": 80},
    "train": {
        "total_steps": 600,
        "n_envs": 2,
        "net_arch": [16, 16],
        "batch_size": 32,
        "buffer_size": 2000,
        "learning_starts": 100,
        "checkpoint_every_episodes": 4,
        "selection": {"keep": "last"},
    },
}


@pytest.fixture(scope="session")
def tiny_params(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """params.yaml with tiny training settings for sweeps, written to a file of its own."""
    path = tmp_path_factory.mktemp("sweep_params") / "params.yaml"
    data = merge(yaml.safe_load((ROOT / "params.yaml").read_text()), TINY_SWEEP)
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    load_params(path)  # valid
    return path


@pytest.fixture(scope="session")
def twin_session(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Path]:
    """The recording of one session of the excitation drive against the twin playing a bundled profile (mild,
    harsh), made once per test run, in its deployment's folder (the episodes.csv and metrics.json the deployment
    wrote beside it): the twin calibration, the plain-bag and the ``mrl episodes`` tests read the same recording,
    and none writes into its folder."""
    from tests.calibration_helpers import TWIN_EPISODES, TWIN_STEPS, TWIN_TIME_SCALE, record_twin_session

    made: dict[str, Path] = {}

    def session(profile: str) -> Path:
        if profile not in made:
            made[profile] = record_twin_session(
                tmp_path_factory.mktemp(f"twin_{profile}"),
                profile,
                TWIN_EPISODES,
                time_scale=TWIN_TIME_SCALE,
                max_steps=TWIN_STEPS,
            )
        return made[profile]

    return session


TWIN_SESSION_TOPICS = {"/tf", "/clock", "/mrl/reset", "/mrl/observation", "/mrl/action", "/mrl/episode"} | {
    f"/robot_{i}/{t}" for i in (1, 2, 3) for t in ("scan", "odom", "ground_truth", "cmd_vel")
}


def check_twin_fleet_plays_two_episodes(policy: Path, fleet_file: Path, folder: Path, transport: str) -> None:
    """Deploys `policy` on the twin fleet of `fleet_file` for two episodes and checks the whole session's recording:
    every topic, both episodes, one observation and one action per robot and step, the twin's 360-beam scans."""
    from pipeline.messages.convert import EVENT_NAMES
    from pipeline.policy.runtime import PolicyRuntime
    from pipeline.record import McapLog
    from pipeline.rollout.deployment import DeployRequest, deploy_policy
    from pipeline.ros.fleet import load_fleet

    request = DeployRequest(episodes=2, seed=5, recording=folder / "session.mcap", progress=False)
    results, profile = deploy_policy(PolicyRuntime(policy), load_fleet(fleet_file), str(fleet_file), request)
    assert profile == "mild" and len(results) == 2
    assert all(r.steps >= 1 and not r.aborted for r in results)
    log = McapLog(folder / "session.mcap")
    counts = log.message_counts()
    assert set(counts) >= TWIN_SESSION_TOPICS and counts["/mrl/reset"] == 2 and counts["/clock"] > 0
    session = log.metadata()["session"]
    assert session["target"] == "twin" and session["transport"] == transport
    names = [EVENT_NAMES[m.msg.event] for m in log.messages(["/mrl/episode"])]
    assert names.count("start") == 2 and names.count("end") == 2
    assert counts["/mrl/observation"] == counts["/mrl/action"] == 3 * sum(r.steps for r in results)
    assert len(next(iter(log.messages(["/robot_1/scan"]))).msg.ranges) == 360
