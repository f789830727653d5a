"""The drive's gain read two ways, reconciled: the body-velocity fit, which holds the wheels' deadband in a smaller
gain, and the wheel chain's gain that the simulator takes with the deadband, run over the same recorded commands."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.calibration.actuation import VelocityTrack
from pipeline.calibration.estimates import Estimate, six_digits
from pipeline.calibration.wheels import NOMINAL_WHEEL_RADIUS_M, NOMINAL_WHEEL_SEPARATION_M

GAIN_AGREEMENT_TOLERANCE = 0.05
"""How far (share of the value) the simulator's gain with the deadband may lie outside the body-velocity fit's
interval and still agree with it: the steady-state reading leaves out the lag's share of each transition."""


@dataclass(frozen=True)
class GainAgreement:
    """One channel's gain read two ways: the body-velocity fit (`body_fit`, which holds the deadband in a smaller
    gain), and the wheel chain's gain at body level (`wheel_chain`, what the simulator takes) whose deadband gives
    `with_deadband` over the recorded commands. They agree when `with_deadband` is within the fit's interval widened
    by :data:`GAIN_AGREEMENT_TOLERANCE`."""

    channel: str
    body_fit: Estimate
    wheel_chain: float
    with_deadband: float

    @property
    def agrees(self) -> bool:
        lo, hi = self.body_fit.interval or (math.nan, math.nan)
        slack = GAIN_AGREEMENT_TOLERANCE * abs(self.with_deadband)
        return lo - slack <= self.with_deadband <= hi + slack

    def sentence(self) -> str:
        lo, hi = self.body_fit.interval or (math.nan, math.nan)
        bites = self.with_deadband < (1 - GAIN_AGREEMENT_TOLERANCE) * self.wheel_chain
        verdict = (
            ("they agree: the deadband accounts for the body-velocity fit's smaller gain" if bites else "they agree")
            if self.agrees
            else f"they differ by more than {GAIN_AGREEMENT_TOLERANCE:.0%}: the deadband does not explain the "
            "body-velocity fit's gain, the drive is not the simulator's model (a lag or limit the simulator lacks)"
        )
        return (
            f"{self.channel} gain: the simulator takes the wheel chain's {self.wheel_chain:.3f} with the deadband, "
            f"which over the recorded commands moves the body as a gain of {self.with_deadband:.3f}; the "
            f"body-velocity fit reads {self.body_fit.value:.4g} [{lo:.4g}, {hi:.4g}]: {verdict}"
        )

    def as_mapping(self) -> dict[str, object]:
        lo, hi = self.body_fit.interval or (math.nan, math.nan)
        return {
            "body_fit": six_digits(self.body_fit.value or math.nan),
            "body_fit_interval": [six_digits(lo), six_digits(hi)],
            "simulator": six_digits(self.wheel_chain),
            "simulator_with_deadband": six_digits(self.with_deadband),
            "agrees": self.agrees,
        }


def deadband_gains(
    tracks: Sequence[VelocityTrack], gains: tuple[float, float], deadband_radps: float, timeout_s: float
) -> tuple[float, float] | None:
    """The gains (linear, angular) through the origin of the simulator's drive (`gains` times the command, then the
    wheels' deadband by the nominal geometry) against the commands acting at the tracks' samples (NaN for a channel
    never commanded); None without tracks."""
    from pipeline.sim.world import deadband_body

    commands = [t.commands.at(t.t_ns, timeout_s) for t in tracks]
    if not commands:
        return None
    u = np.concatenate(commands)
    body = deadband_body(u * np.asarray(gains), NOMINAL_WHEEL_SEPARATION_M, deadband_radps * NOMINAL_WHEEL_RADIUS_M)
    out = []
    for c in range(2):
        uu = float(np.sum(u[:, c] ** 2))
        out.append(float(np.sum(body[:, c] * u[:, c])) / uu if uu > 0.0 else math.nan)
    return out[0], out[1]
