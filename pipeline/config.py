"""params.yaml sections as frozen, typed dataclasses.

Each top-level section of params.yaml maps to one class here and carries the name of the dvc
stage or library part that reads it. Loading is strict: unknown, missing, mistyped and
out-of-range keys are reported together in one ConfigError naming the file and dotted keys.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pipeline.core.actions import ActionCodec, ActionKind
from pipeline.core.judge import RewardWeights
from pipeline.core.observation import LayoutName, ObservationLayout
from pipeline.core.scan import Reduction
from pipeline.settings import from_mapping, merge, read_yaml, setting, to_mapping


@dataclass(frozen=True)
class LidarConfig:
    """The policy's lidar: beam count and range limits (m), and the simulated sensor's noise."""

    beams: int = setting(15, ge=1, le=4096)
    range_min_m: float = setting(0.055, ge=0.0)
    range_max_m: float = setting(5.0, gt=0.0, le=100.0)
    noise_sigma_m: float = setting(0.01, ge=0.0, le=1.0)
    dropout_prob: float = setting(0.0, ge=0.0, le=1.0)
    bias_m: float = setting(0.0, ge=-1.0, le=1.0)
    sim_beams: int = setting(15, ge=1, le=4096)
    reduction: Reduction = setting("sector_min")
    robot_radius_seen_m: float = setting(0.0, ge=0.0, le=1.0)
    height_m: float = setting(0.1, gt=0.0)

    def check(self) -> list[tuple[str, object, str]]:
        if not self.range_max_m > self.range_min_m:
            return [("range_max_m", self.range_max_m, f"a value > range_min_m ({self.range_min_m})")]
        return []


@dataclass(frozen=True)
class OdometryConfig:
    """Odometry error: about `drift_per_m` metres of position error per metre travelled."""

    drift_per_m: float = setting(0.03, ge=0.0, le=1.0)


@dataclass(frozen=True)
class ActuationConfig:
    """How the simulated base follows (v, w) commands: delay, first-order lag, gains."""

    delay_s: float = setting(0.0, ge=0.0, le=1.0)
    time_constant_s: float = setting(0.05, gt=0.0, le=2.0)
    linear_gain: float = setting(1.0, gt=0.0, le=5.0)
    angular_gain: float = setting(1.0, gt=0.0, le=5.0)


@dataclass(frozen=True)
class ActionConfig:
    """Action space: continuous (v, w) scaled to the limits or a discrete named set."""

    kind: ActionKind = setting("continuous")
    v_max_mps: float = setting(0.4, gt=0.0, le=5.0)
    w_max_radps: float = setting(0.2, gt=0.0, le=10.0)
    discrete_set: tuple[Literal["forward", "left", "right", "backward", "stop"], ...] = setting(
        ("forward", "left", "right"), min_len=2
    )

    def codec(self) -> ActionCodec:
        return ActionCodec(self.kind, self.v_max_mps, self.w_max_radps, tuple(self.discrete_set))


@dataclass(frozen=True)
class WorldConfig:
    """The simulated world: scenario, timing, sensors, actions and reward (params.yaml `world`)."""

    scenario: str = setting("obstacles")
    n_robots: int = setting(0, ge=0, le=64)
    control_period_s: float = setting(0.1, gt=0.0, le=1.0)
    physics_timestep_s: float = setting(0.005, gt=0.0, le=0.05)
    max_steps: int = setting(350, ge=1, le=100_000)
    collision_margin_m: float = setting(0.02, ge=0.0, le=0.5)
    observation: LayoutName = setting("paper")
    lidar: LidarConfig = setting(LidarConfig())
    odometry: OdometryConfig = setting(OdometryConfig())
    actuation: ActuationConfig = setting(ActuationConfig())
    actions: ActionConfig = setting(ActionConfig())
    reward: RewardWeights = setting(RewardWeights())

    def check(self) -> list[tuple[str, object, str]]:
        ratio = self.control_period_s / self.physics_timestep_s
        if abs(ratio - round(ratio)) > 1e-9 * ratio:
            return [
                (
                    "physics_timestep_s",
                    self.physics_timestep_s,
                    f"a value that divides control_period_s ({self.control_period_s}) evenly",
                )
            ]
        return []

    @property
    def substeps(self) -> int:
        """Physics steps per control step."""
        return round(self.control_period_s / self.physics_timestep_s)

    @property
    def delay_substeps(self) -> int:
        """Actuation delay in physics steps (rounded)."""
        return math.floor(self.actuation.delay_s / self.physics_timestep_s + 0.5)

    def layout(self) -> ObservationLayout:
        return ObservationLayout(self.observation, self.lidar.beams)

    def codec(self) -> ActionCodec:
        return self.actions.codec()


@dataclass(frozen=True)
class ScriptedEvalConfig:
    """The `scripted_eval` stage: episodes of the scripted controller in the simulated world."""

    episodes: int = setting(20, ge=1, le=100_000)
    seed: int = setting(0, ge=0)
    out_dir: str = setting("logs/scripted")


@dataclass(frozen=True)
class Params:
    """All of params.yaml."""

    world: WorldConfig = setting()
    scripted_eval: ScriptedEvalConfig = setting()


def load_params(path: str | Path = "params.yaml") -> Params:
    """Read and validate params.yaml; raises ConfigError naming every bad key."""
    return from_mapping(Params, read_yaml(path), str(path))


def world_config(
    overrides: dict[str, Any] | None = None, base: WorldConfig | None = None, source: str = "<overrides>"
) -> WorldConfig:
    """A WorldConfig from `base` (defaults if None) with nested `overrides` merged in and validated."""
    data = to_mapping(base if base is not None else WorldConfig())
    return from_mapping(WorldConfig, merge(data, overrides or {}), source)
