"""The policy as the episode loops see it: what sim evaluation, deployment, replay and the calibration drives take.

:class:`~pipeline.policy.runtime.PolicyRuntime` (an exported policy) implements it, and so do the drives of
:mod:`pipeline.policy.excitation`, which run over a policy with its robots, layout, limits and world. The scripted
controllers and the imitation teachers of :mod:`pipeline.policy.scripted` are not policies in this sense: they have
no spec to check a world or a fleet against, and a simulator's episodes take them as plain functions from
observations to actions (:data:`pipeline.rollout.sim.ActionFunction`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from pipeline.core.actions import ActionCodec
from pipeline.core.observation import ObservationLayout
from pipeline.policy.spec import PolicySpec


@runtime_checkable
class Policy(Protocol):
    """Observations of every robot in, actions for the codec out, with the interface they were trained with."""

    @property
    def spec(self) -> PolicySpec:
        """The exported policy's spec: the world it was trained in (control period in s, network, MDP), its
        scenario and robots."""
        ...

    @property
    def robots(self) -> tuple[str, ...]:
        """The robot names in row order of the observations and actions (``robot_1..N``)."""
        ...

    @property
    def layout(self) -> ObservationLayout:
        """The observation layout: one row of `obs` is ``layout.size`` float32 values, sliced by
        ``layout.slices``."""
        ...

    @property
    def codec(self) -> ActionCodec:
        """The action codec: decodes :meth:`actions` to (v m/s, w rad/s) within the robots' limits."""
        ...

    @property
    def name(self) -> str:
        """One line naming the policy in messages and refusals."""
        ...

    @property
    def document(self) -> dict[str, Any]:
        """The spec as plain data, for the ``policy`` document and session metadata of a recording."""
        ...

    @property
    def session_extra(self) -> Mapping[str, str]:
        """Keys added to a deployment recording's session metadata (empty where the policy itself drives)."""
        ...

    def actions(self, obs: np.ndarray) -> np.ndarray:
        """Actions for the codec from observations (n_robots, layout.size) float32 in `robots` order:
        (n_robots, 2) float in [-1, 1] (continuous) or (n_robots,) int64 indices into the codec's table
        (discrete)."""
        ...

    def commands(self, obs: np.ndarray) -> np.ndarray:
        """(n_robots, 2) velocity commands (v m/s, w rad/s) from observations (n_robots, layout.size)."""
        ...

    def check_fits(
        self,
        robots: Sequence[str],
        layout: ObservationLayout,
        action_kind: str | None = None,
        limits: tuple[float, float] | None = None,
    ) -> None:
        """Refuse (:class:`~pipeline.policy.errors.PolicyMismatch`) a world or fleet whose robots, observation
        layout or beam count differ, whose actions are of another `action_kind`, or whose `limits`
        (v m/s, w rad/s) are below what the policy commands."""
        ...
