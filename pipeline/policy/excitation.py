"""A calibration drive: an exported policy's robots and interface, driven for system identification.

A policy's commands change every control step and seldom hold a small one, so a recording of it leaves the
drive chain's parts to trade against each other: a delay against a lag, a deadband against a gain, the motors'
lag against the driver's. Steps tell them apart: the dead time before any response is the delay, the shape of
the rise is the lag, a step that the acceleration limit clips rises differently from one it does not, and a held
small command shows the deadband. This drive gives each robot, independently, phases of

- ``policy``: the policy drives (it keeps the robots moving through the room and toward their goals);
- ``step``: a forward command held at one of `STEP_SIZES` of the policy's top speed (each robot's own), where the
  lidar shows room ahead for it, ended early (to a stop) when the room runs out;
- ``turn``: a turn in place held at a share of the policy's top turn rate drawn uniformly from `TURN_SHARES`,
  either way (each turn at a level of its own, so the held wheel speeds below a deadband and above it close in
  on it from both sides);
- ``stop``: zero, held (a step down, and the stationary spans the lidar's noise is read from),

each `PHASE_S` long (drawn per phase). The robots, observation layout, limits and world are the policy's, so
the deployment checks it as it checks the policy; its recording is calibrated like any other. Its success
rates say nothing about the policy.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pipeline.core.observation import ObservationLayout
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.protocol import Policy
from pipeline.policy.scripted import GoToGoalController, front_beams, range_ahead

PHASES = ("policy", "step", "turn", "stop")
PHASE_WEIGHTS = (0.25, 0.4, 0.15, 0.2)
STEP_SIZES = (0.05, 0.075, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0)
"""Held forward commands, shares of the top speed: the small ones near a deadband (the nominal SPARK's wheels at
0.59, 0.88 and 1.18 rad/s, above the fastest turn's 0.83), the large ones against an acceleration limit."""
TURN_SHARES = (0.05, 1.0)
"""A held turn's share of the top turn rate is drawn uniformly between these. Three fixed shares (0.25, 0.5, 1)
held the nominal SPARK's wheels at 0.21, 0.41 and 0.83 rad/s only: a deadband between two of them fitted anywhere in
the bracket, and the coverage benchmark's deadbands (0-1 rad/s) read with a median error of 16 %."""
PHASE_S = (1.0, 2.5)
"""A phase lasts between these (s), drawn per phase."""
ROOM_AHEAD_M = 1.0
"""A step starts only with this much free range ahead (the lidar's front beams)."""
STOP_AHEAD_M = 0.45
"""A step ends (the robot stops) once the free range ahead falls below this."""


class DriveOver:
    """What a drive over `policy` takes from it unchanged: its spec, layout, codec, document and robots, the fit
    check, and actions as the codec's encoding of the drive's :meth:`commands`. A subclass says what it drives."""

    def __init__(self, policy: Policy) -> None:
        self.policy = policy
        self.spec = policy.spec
        self.layout = policy.layout
        self.codec = policy.codec

    @property
    def document(self) -> dict[str, Any]:
        return self.policy.document

    @property
    def robots(self) -> tuple[str, ...]:
        return self.spec.robots

    def check_fits(
        self,
        robots: Sequence[str],
        layout: ObservationLayout,
        action_kind: str | None = None,
        limits: tuple[float, float] | None = None,
    ) -> None:
        self.policy.check_fits(robots, layout, action_kind, limits)

    def commands(self, obs: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def actions(self, obs: np.ndarray) -> np.ndarray:
        """Actions for the policy's codec: (n_robots, 2) in [-1, 1]."""
        return self.codec.encode(self.commands(obs))

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.actions(obs)


class ExcitationDrive(DriveOver):
    """Drives `policy`'s robots through phases of the policy's own driving and held steps (the module's text); a
    :class:`~pipeline.policy.protocol.Policy` itself."""

    def __init__(self, policy: Policy, seed: int = 0) -> None:
        if policy.codec.kind != "continuous":
            raise PolicyMismatch(
                policy.name,
                [
                    f"the calibration drive holds commands of several sizes; a {policy.codec.kind!r} policy's actions "
                    "name only its discrete set (use a policy with continuous actions)"
                ],
            )
        if "ranges" not in policy.layout.slices:
            raise PolicyMismatch(policy.name, [f"observation layout {policy.layout.name!r} has no lidar ranges"])
        super().__init__(policy)
        self.period_s = float(policy.spec.world.control_period_s)
        self.rng = np.random.default_rng(seed)
        n = len(policy.spec.robots)
        self._phase = ["stop"] * n
        self._left = np.zeros(n, dtype=int)
        self._hold = np.zeros((n, 2))
        self._limits = self.codec.limits(n)
        self._front = front_beams(self.layout.n_beams)
        self.session_extra: dict[str, str] = {"drive": "excitation", "drive_seed": str(seed)}
        """Written into the recording's session metadata: its episodes are a calibration drive, not the policy's."""

    @property
    def name(self) -> str:
        return f"excitation drive over {self.policy.name}"

    def _steps(self) -> int:
        return max(1, round(float(self.rng.uniform(*PHASE_S)) / self.period_s))

    def _start(self, i: int, ahead_m: float) -> None:
        phase = str(self.rng.choice(PHASES, p=PHASE_WEIGHTS))
        if phase == "step" and ahead_m < ROOM_AHEAD_M:
            phase = "turn"  # no room for a held step: turning in place needs none
        self._phase[i] = phase
        self._left[i] = self._steps()
        self._hold[i] = 0.0
        if phase == "step":
            self._hold[i, 0] = float(self.rng.choice(STEP_SIZES)) * self._limits[i, 0]
        elif phase == "turn":
            share = float(self.rng.uniform(*TURN_SHARES))
            self._hold[i, 1] = float(self.rng.choice([-1.0, 1.0])) * share * self._limits[i, 1]

    def commands(self, obs: np.ndarray) -> np.ndarray:
        """(n_robots, 2) (v m/s, w rad/s) for observations (n_robots, layout.size)."""
        ahead = range_ahead(np.asarray(obs, dtype=np.float64)[:, self.layout.slices["ranges"]], self._front)
        for i in range(len(obs)):
            if self._phase[i] == "step" and ahead[i] < STOP_AHEAD_M:
                self._phase[i], self._hold[i], self._left[i] = "stop", 0.0, self._steps()
            if self._left[i] <= 0:
                self._start(i, float(ahead[i]))
            self._left[i] -= 1
        out = self._hold.copy()
        driven = np.array([phase == "policy" for phase in self._phase])
        if driven.any():  # the policy runs only while it drives a robot
            out[driven] = self.policy.commands(np.asarray(obs, dtype=np.float32))[driven]
        return out


class StillThenDrive(DriveOver):
    """A recording as a user's bag often starts: every robot stands still for `still_s`, then drives to its goal
    (the scripted go-to-goal controller where the policy's layout has the goal, else the policy). The robots,
    layout, limits and world are `policy`'s, so the deployment checks it as it checks the policy; a
    :class:`~pipeline.policy.protocol.Policy` itself."""

    def __init__(self, policy: Policy, still_s: float) -> None:
        super().__init__(policy)
        self.still_steps = round(still_s / float(policy.spec.world.control_period_s))
        self.controller = GoToGoalController(policy.layout, policy.codec) if policy.layout.has_goal else None
        self._steps = 0
        self.session_extra: dict[str, str] = {"drive": "still_then_drive", "still_s": f"{still_s:g}"}

    @property
    def name(self) -> str:
        return f"still, then driving, over {self.policy.name}"

    def commands(self, obs: np.ndarray) -> np.ndarray:
        """(n_robots, 2) (v m/s, w rad/s): zero for the first `still_s`, then the drive's."""
        self._steps += 1
        if self._steps <= self.still_steps:
            return np.zeros((len(obs), 2))
        if self.controller is not None:
            return self.controller.commands(np.asarray(obs, dtype=np.float64))
        return self.policy.commands(np.asarray(obs, dtype=np.float32))
