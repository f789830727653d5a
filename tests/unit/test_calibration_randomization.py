"""Randomization ranges fitted to the likelihood of recorded transitions (DROPO-style) on synthetic tracks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.calibration.actuation import CommandTimeline, VelocityTrack
from pipeline.calibration.estimates import Estimate
from pipeline.calibration.randomization import fit_randomization

NS = 1_000_000_000
DELAY_S, TAU_S = 0.1, 0.15


def track(rng: np.random.Generator, k: int, linear_gain: float, angular_gain: float, seconds: float = 10.0):
    """A contact-free track: phases of held commands (10 Hz), the first-order actuation with this track's gains,
    ground truth velocity at 50 Hz with 5 mm/s and 0.01 rad/s noise."""
    t_cmd, values, t = [], [], 0.0
    while t < seconds + 1.0:
        cmd = (rng.uniform(0.0, 0.4), rng.uniform(-0.3, 0.3))
        for _ in range(int(rng.integers(5, 15))):
            t_cmd.append(t)
            values.append(cmd)
            t += 0.1
    timeline = CommandTimeline(np.round(np.asarray(t_cmd) * NS).astype(np.int64), np.asarray(values))
    h = 0.001
    n = int(seconds / h)
    times = np.round(np.arange(n) * h * NS).astype(np.int64)
    u = timeline.at(times - round(DELAY_S * NS), 0.5)
    a = math.exp(-h / TAU_S)
    state = np.zeros(2)
    velocity = np.empty((n, 2))
    for i in range(n):
        state = a * state + (1 - a) * u[i]
        velocity[i] = state * (linear_gain, angular_gain)
    every = 20
    sel = slice(every * 10, n, every)  # from 0.2 s on (a track starts with the robot moving)
    achieved = velocity[sel] + rng.normal(0.0, (0.005, 0.01), size=velocity[sel].shape)
    return VelocityTrack("robot", f"episode {k}", times[sel], achieved, timeline)


def estimates(se: float = 0.005) -> dict[str, Estimate]:
    values = {"delay_s": DELAY_S, "time_constant_s": TAU_S, "linear_gain": 0.9, "angular_gain": 0.9}
    return {f"actuation.{k}": Estimate.of(v, se * v, None, "", "", 100) for k, v in values.items()}


def test_gains_that_vary_between_episodes_widen_their_range_and_no_other():
    rng = np.random.default_rng(0)
    gains = rng.uniform(0.8, 1.0, 16)  # per episode
    tracks = [track(rng, k, g, 0.9) for k, g in enumerate(gains)]
    fit = fit_randomization(tracks, estimates(), timeout_s=0.5)
    assert fit is not None and fit.log_likelihood_fit > fit.log_likelihood_start
    # the fitted spread is the episodes' spread of the linear gain (0.039 for these 16 draws), not the estimate's
    # standard error (0.0045)
    assert fit.sigma["linear_gain"] == pytest.approx(np.std(gains, ddof=1), rel=0.3)
    assert fit.mu["linear_gain"] == pytest.approx(np.mean(gains), abs=0.02)
    low, high = fit.ranges()["linear_gain"]
    assert low <= np.percentile(gains, 10) and high >= np.percentile(gains, 90)
    # what does not vary stays narrow
    assert fit.sigma["angular_gain"] < 0.02 and fit.sigma["delay_s"] < 0.02


def test_a_fixed_robot_keeps_narrow_ranges():
    rng = np.random.default_rng(1)
    tracks = [track(rng, k, 0.9, 0.9) for k in range(8)]
    fit = fit_randomization(tracks, estimates(), timeout_s=0.5)
    assert fit is not None
    assert fit.sigma["linear_gain"] < 0.015 and fit.sigma["angular_gain"] < 0.02
    assert fit.mu["time_constant_s"] == pytest.approx(TAU_S, rel=0.1)


def test_no_fit_without_estimates_or_transitions():
    rng = np.random.default_rng(2)
    tracks = [track(rng, 0, 0.9, 0.9, seconds=2.0)]
    assert fit_randomization(tracks, estimates(), timeout_s=0.5) is None  # 3 windows of 0.5 s
    partial = estimates()
    partial["actuation.delay_s"] = Estimate.unidentifiable("no", "s")
    assert fit_randomization([track(rng, 1, 0.9, 0.9)], partial, timeout_s=0.5) is None


def test_transitions_no_draw_produces_do_not_stretch_the_ranges():
    """Two of eight tracks where the robot was held (velocity stays near zero whatever is commanded): the broad
    component takes those windows, the ranges stay those of a fixed robot, and the fit says what it left."""
    rng = np.random.default_rng(3)
    tracks = [track(rng, k, 0.9, 0.9) for k in range(8)]
    for k in (2, 5):
        held = tracks[k]
        still = rng.normal(0.0, (0.005, 0.01), size=held.achieved.shape)
        tracks[k] = VelocityTrack(held.robot, held.cluster, held.t_ns, still, held.commands)
    fit = fit_randomization(tracks, estimates(), timeout_s=0.5)
    assert fit is not None
    assert fit.sigma["linear_gain"] < 0.03 and fit.sigma["angular_gain"] < 0.03
    assert 0.6 < fit.explained < 0.95
    assert "cannot produce" in fit.notes[0]
