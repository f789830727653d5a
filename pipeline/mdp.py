"""The MDP of a world: observation builder, action codec and episode judge (with its reward), built in one place.

Simulated training and evaluation, weight selection, deployment and replay all get these parts from
:func:`mdp_parts`, from a :class:`~pipeline.params.WorldConfig`: params.yaml's world in simulation, the
world a policy was trained in (its spec, :mod:`pipeline.policy.spec`) on a fleet. :class:`MdpDefinition`
is the part of a world that defines the MDP (as opposed to how the simulator renders it: noise, physics,
the simulated lidar's beam count), so two worlds give a policy the same MDP exactly when their
definitions are equal.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from pipeline.core.actions import ActionCodec
from pipeline.core.judge import EpisodeJudge, ProgressDistance, RewardWeights
from pipeline.core.observation import LayoutName, ObservationBuilder, ObservationLayout, ObservedPose
from pipeline.core.scan import Reduction
from pipeline.core.scenario import Scenario
from pipeline.core.timebase import NS_PER_S
from pipeline.params import ActionConfig, WorldConfig

_WORLD_KEYS = {
    "observation": "world.observation",
    "observed_pose": "world.observed_pose",
    "beams": "world.lidar.beams",
    "range_min_m": "world.lidar.range_min_m",
    "range_max_m": "world.lidar.range_max_m",
    "reduction": "world.lidar.reduction",
    "actions": "world.actions",
    "reward": "world.reward",
    "control_period_s": "world.control_period_s",
    "max_steps": "world.max_steps",
    "collision_margin_m": "world.collision_margin_m",
    "progress_distance": "world.progress_distance",
}
"""Where each field of a definition lives in params.yaml."""
REWARD_FIELDS = ("reward", "progress_distance")
"""The fields that only shape the reward."""


@dataclass(frozen=True)
class MdpDefinition:
    """What a policy sees, does and is judged by: observation layout and the lidar limits and reduction
    that build it, actions, reward, control period, step limit, collision margin, progress measure."""

    observation: LayoutName
    observed_pose: ObservedPose
    beams: int
    range_min_m: float
    range_max_m: float
    reduction: Reduction
    actions: ActionConfig
    reward: RewardWeights
    control_period_s: float
    max_steps: int
    collision_margin_m: float
    progress_distance: ProgressDistance

    @classmethod
    def of(cls, world: WorldConfig) -> MdpDefinition:
        lidar = world.lidar
        return cls(
            observation=world.observation,
            observed_pose=world.observed_pose,
            beams=lidar.beams,
            range_min_m=lidar.range_min_m,
            range_max_m=lidar.range_max_m,
            reduction=lidar.reduction,
            actions=world.actions,
            reward=world.reward,
            control_period_s=world.control_period_s,
            max_steps=world.max_steps,
            collision_margin_m=world.collision_margin_m,
            progress_distance=world.progress_distance,
        )

    def differences(self, other: MdpDefinition, reward: bool = True) -> list[str]:
        """One line per setting that differs: its params.yaml key, this value, then the other's.

        With `reward` False the reward's settings (weights, progress measure) are left out: they do
        not change what a policy observes or does, nor how an episode ends.
        """
        out = []
        for f in fields(self):
            if not reward and f.name in REWARD_FIELDS:
                continue
            mine, theirs = getattr(self, f.name), getattr(other, f.name)
            if mine == theirs:
                continue
            if isinstance(mine, (ActionConfig, RewardWeights)):
                for sub in fields(mine):
                    a, b = getattr(mine, sub.name), getattr(theirs, sub.name)
                    if a != b:
                        out.append(f"{_WORLD_KEYS[f.name]}.{sub.name} {_show(a)} vs {_show(b)}")
            else:
                out.append(f"{_WORLD_KEYS[f.name]} {_show(mine)} vs {_show(theirs)}")
        return out


def _show(value: object) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, tuple):
        return repr(list(value))
    return repr(value)


@dataclass(frozen=True)
class MdpParts:
    """The built parts; the judge keeps an episode's state, so each rollout builds its own parts."""

    definition: MdpDefinition
    layout: ObservationLayout
    observer: ObservationBuilder
    codec: ActionCodec
    judge: EpisodeJudge

    @property
    def period_ns(self) -> int:
        return round(self.definition.control_period_s * NS_PER_S)

    def use_layout(self, layout: Scenario) -> None:
        """Observe and judge against `layout` (another layout of the same room and robots) from the next episode."""
        self.judge.use_layout(layout)
        self.observer.use_layout(layout)

    def track(self, target_xy: np.ndarray) -> None:
        """A pursuit's target is now at `target_xy` (2,): every robot's goal in the judge and the observation."""
        self.judge.track(target_xy)
        self.observer.goals = self.judge.goals


def mdp_parts(scenario: Scenario, world: WorldConfig) -> MdpParts:
    """The observation builder, action codec and judge of `world` in `scenario`."""
    d = MdpDefinition.of(world)
    layout = ObservationLayout(d.observation, d.beams)
    codec = d.actions.codec().for_scenario(scenario)
    observer = ObservationBuilder(scenario, layout, d.range_min_m, d.range_max_m, d.reduction)
    observer.limits = np.column_stack([codec.limits(scenario.n_robots), scenario.radii])
    return MdpParts(
        definition=d,
        layout=layout,
        observer=observer,
        codec=codec,
        judge=EpisodeJudge(scenario, d.reward, d.max_steps, d.collision_margin_m, d.progress_distance),
    )
