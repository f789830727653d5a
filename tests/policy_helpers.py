"""A valid policy spec built in code, for tests that write policy files of their own."""

from __future__ import annotations

from typing import Any

from pipeline.core.scenario import load_scenario
from pipeline.mappings import merge, to_mapping
from pipeline.params import world_config
from pipeline.policy.spec import FORMAT


def spec_mapping(
    sha256: str,
    kind: str = "continuous",
    n_robots: int = 2,
    layout: str = "rich",
    beams: int = 15,
    scenario_name: str = "obstacles",
    world: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """What export writes to policy.json for a shared-mode policy of `n_robots` in `scenario_name`;
    `world` overrides further keys of the training world."""
    scenario = load_scenario(scenario_name, n_robots)
    world = world_config(
        merge(
            {
                "scenario": scenario_name,
                "n_robots": n_robots,
                "observation": layout,
                "lidar": {"beams": beams},
                "actions": {"kind": kind},
            },
            world or {},
        )
    )
    size = world.layout().size
    return {
        "format": FORMAT,
        "onnx": {"file": "policy.onnx", "sha256": sha256, "opset": 17, "input": "observation", "output": "action"},
        "golden": "golden.json",
        "algorithm": "dqn" if kind == "discrete" else "sac",
        "mode": "shared",
        "policy_kind": "dqn" if kind == "discrete" else "sac_actor",
        "robots": list(scenario.robot_names),
        "observation": {"layout": layout, "n_beams": beams, "size": size},
        "world": to_mapping(world),
        "scenario": to_mapping(scenario),
        "training": {
            "digest": "0" * 64,
            "seed": 0,
            "world_steps": 100,
            "episodes": 2,
            "converged_at_episode": None,
            "interrupted": False,
            "round": "",
        },
        "versions": {"stable_baselines3": "2.9.2", "torch": "2.13.0", "onnx": "1.17.0", "onnxruntime": "1.20.0"},
    }
