"""Sensor error models of the simulator: lidar noise, dropouts, bias, range steps, mixed pixels and the driver's
no-return value; odometry drift."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DEPTH_EDGE_M = 0.1
"""A beam that hits another surface than the previous beam, nearer or farther by more than this, straddles a depth
edge."""


@dataclass(frozen=True)
class RealLidar:
    """What a real 2-D lidar adds to Gaussian noise: ranges in steps of `step_m` (0: continuous), a per-beam noise
    factor (`beam_factor`, (..., beams), None: 1), mixed pixels at depth edges with probability `mixed_prob`, and what
    a beam without a return reads (`no_return`: +inf, 0, the range maximum or NaN)."""

    step_m: float = 0.0
    beam_factor: np.ndarray | None = None
    mixed_prob: float = 0.0
    no_return: float = math.inf


def noisy_ranges(
    true_m: np.ndarray,
    rng: np.random.Generator,
    sigma_m: float,
    dropout_prob: float,
    bias_m: float,
    noise_per_m: float = 0.0,
    real: RealLidar | None = None,
    surfaces: np.ndarray | None = None,
) -> np.ndarray:
    """Measured ranges (same shape) from true ones (m); +inf (no return) stays +inf unless `real` says otherwise.

    Adds `bias_m` and zero-mean Gaussian noise of `sigma_m` + `noise_per_m` * range; each beam
    drops out (reads +inf) with probability `dropout_prob`. With `real` (beams along the last axis): a beam at a depth
    edge (another surface than the previous beam's in `surfaces`, nearer or farther by more than 0.1 m) returns, with
    its probability, a range drawn evenly between the two surfaces; each beam's noise is scaled by its factor; ranges
    are rounded to the step; no return reads the driver's value.
    """
    if real is not None and real.mixed_prob > 0:
        before = np.roll(true_m, 1, axis=-1)
        both = np.isfinite(true_m) & np.isfinite(before)
        here, prev = np.where(both, true_m, 0.0), np.where(both, before, 0.0)
        edge = both & (np.abs(here - prev) > DEPTH_EDGE_M)
        if surfaces is not None and surfaces.shape == true_m.shape:
            edge &= surfaces != np.roll(surfaces, 1, axis=-1)  # another surface: a smooth one is no edge
        mixed = edge & (rng.random(true_m.shape) < real.mixed_prob)
        if mixed.any():
            near, far = np.minimum(here, prev), np.maximum(here, prev)
            true_m = np.where(mixed, near + rng.random(true_m.shape) * (far - near), true_m)
    out = true_m + bias_m
    factor = 1.0 if real is None or real.beam_factor is None else real.beam_factor
    if noise_per_m > 0:
        finite = np.where(np.isfinite(true_m), true_m, 0.0)
        out = out + rng.standard_normal(size=true_m.shape) * (sigma_m + noise_per_m * finite) * factor
    elif sigma_m > 0:
        out = out + rng.normal(0.0, sigma_m, size=true_m.shape) * factor
    if dropout_prob > 0:
        out = np.where(rng.random(true_m.shape) < dropout_prob, np.inf, out)
    if real is not None:
        if real.step_m > 0:
            out = np.where(np.isfinite(out), np.round(out / real.step_m) * real.step_m, out)
        if not (math.isinf(real.no_return) and real.no_return > 0):
            out = np.where(np.isposinf(out), real.no_return, out)
    return np.asarray(out)


def beam_factors(spread: float, shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray | None:
    """Per-beam noise factors exp(s z - s^2) (mean square 1) of log-sd `spread`; None for 0."""
    if spread <= 0:
        return None
    return np.exp(spread * rng.standard_normal(shape) - spread * spread)


class OdometryDrift:
    """Wheel odometry with systematic per-episode errors that grow with distance travelled.

    Per robot and episode: a distance scale error, a yaw-rate scale error and a heading drift per
    metre, each drawn from N(0, drift_per_m). Over 1 m of straight driving this gives a position
    error of about drift_per_m metres (along-track from the scale error, cross-track from the
    heading drift). Poses are (n_robots, 3): x, y (m), yaw (rad).

    `unseen_yaw_per_m` is the turn (rad per metre driven forward, signed) that the odometry does
    not see: wheel encoders read with the nominal radii count the arc that unequal wheels put into
    a straight command as straight driving, so the base turns and its odometry does not.
    """

    def __init__(self, drift_per_m: float, unseen_yaw_per_m: float = 0.0) -> None:
        self.drift_per_m = drift_per_m
        self.unseen_yaw_per_m = unseen_yaw_per_m
        self.pose = np.zeros((0, 3))
        self._scale = np.zeros(0)
        self._yaw_scale = np.zeros(0)
        self._yaw_per_m = np.zeros(0)

    def reset(self, start: np.ndarray, rng: np.random.Generator) -> None:
        n = len(start)
        self.pose = np.array(start, dtype=np.float64)
        draws = rng.normal(0.0, self.drift_per_m, size=(3, n)) if self.drift_per_m > 0 else np.zeros((3, n))
        self._scale, self._yaw_scale, self._yaw_per_m = draws

    def update(self, prev_truth: np.ndarray, truth: np.ndarray) -> np.ndarray:
        """Advance by the true motion between two truth poses; returns the odometry pose."""
        d = truth[:, :2] - prev_truth[:, :2]
        c, s = np.cos(prev_truth[:, 2]), np.sin(prev_truth[:, 2])
        forward = c * d[:, 0] + s * d[:, 1]
        left = -s * d[:, 0] + c * d[:, 1]
        dyaw = np.angle(np.exp(1j * (truth[:, 2] - prev_truth[:, 2])))
        if self.unseen_yaw_per_m != 0.0:  # take the arc out of the turn and of the chord's direction
            unseen = self.unseen_yaw_per_m * forward
            dyaw = dyaw - unseen
            cu, su = np.cos(unseen / 2), np.sin(unseen / 2)
            forward, left = cu * forward + su * left, -su * forward + cu * left
        dist = np.hypot(forward, left)
        forward = forward * (1 + self._scale)
        left = left * (1 + self._scale)
        dyaw_odom = dyaw * (1 + self._yaw_scale) + self._yaw_per_m * dist
        # the displacement is expressed in the frame of the previous pose: rotate it by the
        # previous odometry heading
        yaw = self.pose[:, 2]
        cy, sy = np.cos(yaw), np.sin(yaw)
        self.pose[:, 0] += cy * forward - sy * left
        self.pose[:, 1] += sy * forward + cy * left
        self.pose[:, 2] = np.angle(np.exp(1j * (yaw + dyaw_odom)))
        return self.pose.copy()
