"""The drive's gain read two ways, reconciled: the body-velocity fit, which holds the wheels' deadband in a smaller
gain, and the wheel chain's gain with the deadband, run over the same recorded commands; and the gains the simulator
takes with the deadband, which move its body over those commands as the body-velocity fit read it."""

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
    gain), and the wheel chain's gain at body level (`wheel_chain`, through the calibrated wheel radii and
    separation) whose deadband gives `with_deadband` over the recorded commands. They agree when `with_deadband` is
    within the fit's interval widened by :data:`GAIN_AGREEMENT_TOLERANCE`. `simulator`: the gain the simulator takes
    (:func:`drive_gains`): with the deadband it moves the body over those commands as the body-velocity fit read
    it, so it has the fit's precision and not the wheel radii's."""

    channel: str
    body_fit: Estimate
    wheel_chain: float
    with_deadband: float
    simulator: float

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
            "body-velocity fit's gain, the drive is not the simulator's model (a lag or limit the simulator lacks, "
            "or wheel radii read off)"
        )
        return (
            f"{self.channel} gain: the wheel chain reads {self.wheel_chain:.3f}, which with the deadband moves the "
            f"body over the recorded commands as a gain of {self.with_deadband:.3f}; the body-velocity fit reads "
            f"{self.body_fit.value:.4g} [{lo:.4g}, {hi:.4g}]: {verdict}; the simulator takes {self.simulator:.3f} "
            "with the deadband, which moves its body as the fit read it"
        )

    def as_mapping(self) -> dict[str, object]:
        lo, hi = self.body_fit.interval or (math.nan, math.nan)
        return {
            "body_fit": six_digits(self.body_fit.value or math.nan),
            "body_fit_interval": [six_digits(lo), six_digits(hi)],
            "wheel_chain": six_digits(self.wheel_chain),
            "wheel_chain_with_deadband": six_digits(self.with_deadband),
            "simulator": six_digits(self.simulator),
            "agrees": self.agrees,
        }


def deadband_gains(
    tracks: Sequence[VelocityTrack], gains: tuple[float, float], deadband_radps: float, timeout_s: float
) -> tuple[float, float] | None:
    """The gains (linear, angular) through the origin of the simulator's drive (`gains` times the command, then the
    wheels' deadband by the nominal geometry) against the commands acting at the tracks' samples (NaN for a channel
    never commanded); None without tracks."""
    u = _commands(tracks, timeout_s)
    if u is None:
        return None
    return _through_origin(u, gains, deadband_radps)


def drive_gains(
    tracks: Sequence[VelocityTrack],
    body_fit: tuple[float, float],
    start: tuple[float, float],
    deadband_radps: float,
    timeout_s: float,
    iterations: int = 50,
) -> tuple[float, float] | None:
    """The gains (linear, angular) for the simulator's drive, deadband included, that move the body over the
    tracks' commands as the body-velocity fit (`body_fit`) read it: each channel's fit divided by the share of it
    the deadband leaves at those gains, by fixed-point iteration from `start` (the wheel chain's gains). A channel
    whose fit is not finite, or that was never commanded, keeps its `start`. None without tracks."""
    u = _commands(tracks, timeout_s)
    if u is None:
        return None
    target = np.asarray(body_fit, dtype=np.float64)
    gains = np.asarray(start, dtype=np.float64).copy()
    fixed = ~np.isfinite(target)
    for _ in range(iterations):
        read = np.asarray(_through_origin(u, (float(gains[0]), float(gains[1])), deadband_radps))
        moving = ~fixed & np.isfinite(read) & (read > 0.0)
        new = np.where(moving, gains * target / np.where(moving, read, 1.0), gains)
        done = bool(np.all(np.abs(new - gains) <= 1e-12 * np.abs(gains)))
        gains = new
        if done:
            break
    return float(gains[0]), float(gains[1])


def _commands(tracks: Sequence[VelocityTrack], timeout_s: float) -> np.ndarray | None:
    commands = [t.commands.at(t.t_ns, timeout_s) for t in tracks]
    return np.concatenate(commands) if commands else None


def _through_origin(u: np.ndarray, gains: tuple[float, float], deadband_radps: float) -> tuple[float, float]:
    """Per channel, the least-squares gain through the origin of the simulator's body velocity (`gains` times the
    commands `u`, then the wheels' deadband by the nominal geometry) against `u`; NaN for a channel never commanded."""
    from pipeline.sim.world import deadband_body

    body = deadband_body(u * np.asarray(gains), NOMINAL_WHEEL_SEPARATION_M, deadband_radps * NOMINAL_WHEEL_RADIUS_M)
    out = []
    for c in range(2):
        uu = float(np.sum(u[:, c] ** 2))
        out.append(float(np.sum(body[:, c] * u[:, c])) / uu if uu > 0.0 else math.nan)
    return out[0], out[1]
