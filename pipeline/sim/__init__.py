"""The simulated world: MuJoCo physics, lidar, noise models and the environments built on them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pipeline.core.scenario import Scenario, load_scenario
from pipeline.errors import ConfigError, ConfigProblem
from pipeline.params import WorldConfig, world_config
from pipeline.sim.env import MultiRobotEnv, MultiRobotSim
from pipeline.sim.views import JointEnv, RobotEnv, TeammatePolicy


def make_world(
    scenario: str | Path | Scenario | None = None, world: WorldConfig | None = None, **overrides: Any
) -> tuple[Scenario, WorldConfig]:
    """Resolve a scenario and a validated WorldConfig from `world` (or defaults) plus overrides.

    Overrides are WorldConfig keys; nested sections take mappings, e.g.
    ``lidar={"noise_sigma_m": 0.02}``. `scenario` overrides ``world.scenario``.
    """
    if scenario is not None and not isinstance(scenario, Scenario):
        overrides = {**overrides, "scenario": str(scenario)}
    cfg = world_config(overrides, base=world)
    resolved = scenario if isinstance(scenario, Scenario) else load_scenario(cfg.scenario)
    if cfg.n_robots:
        resolved = load_scenario(resolved, cfg.n_robots)
    if resolved.layouts is not None and cfg.layouts == "random" and cfg.observation == "paper":
        raise ConfigError(
            "world",
            [
                ConfigProblem(
                    "observation",
                    "paper",
                    f"rich: scenario {resolved.name!r} draws a layout per episode and the paper's observation "
                    "has no goal in it (or world.layouts: fixed)",
                )
            ],
        )
    return resolved, cfg


def parallel_env(
    scenario: str | Path | Scenario | None = None,
    world: WorldConfig | None = None,
    render_mode: str | None = None,
    **overrides: Any,
) -> MultiRobotEnv:
    """The PettingZoo ParallelEnv for `scenario` (a bundled name, a YAML path or a Scenario)."""
    resolved, cfg = make_world(scenario, world, **overrides)
    return MultiRobotEnv(resolved, cfg, render_mode=render_mode)


def joint_env(
    scenario: str | Path | Scenario | None = None,
    world: WorldConfig | None = None,
    render_mode: str | None = None,
    **overrides: Any,
) -> JointEnv:
    """The robots as one Gymnasium agent (centralized control)."""
    resolved, cfg = make_world(scenario, world, **overrides)
    return JointEnv(resolved, cfg, render_mode=render_mode)


def robot_env(
    scenario: str | Path | Scenario | None = None,
    world: WorldConfig | None = None,
    robot: int = 0,
    teammates: TeammatePolicy | None = None,
    render_mode: str | None = None,
    **overrides: Any,
) -> RobotEnv:
    """One robot as a Gymnasium agent; teammates follow `teammates` or stand still."""
    resolved, cfg = make_world(scenario, world, **overrides)
    return RobotEnv(resolved, cfg, robot=robot, teammates=teammates, render_mode=render_mode)


__all__ = [
    "JointEnv",
    "MultiRobotEnv",
    "MultiRobotSim",
    "RobotEnv",
    "joint_env",
    "make_world",
    "parallel_env",
    "robot_env",
]
