"""Randomization ranges fitted to a recording: the likelihood of its transitions under the randomized simulator.

The calibration's intervals say how well the data pin each value down; they do not say how much
the robot varies from one moment to the next, or how much of the data the simulator's model cannot
produce at any one value (a twin with two lags in series, a slew limit, wheels that slip). Training
over ranges that only reflect the estimates' uncertainty then over-trusts the simulator. Offline
domain randomization (DROPO, Tiboni et al. 2023) fits the randomization itself: each parameter is
drawn from N(mu, sigma^2), and mu, sigma maximize the likelihood of the recorded transitions under
the simulator driven by those draws.

Here a transition is a short window of a contact-free track (`WINDOW_S`): it starts from the
recorded body velocity, is driven by the commands as sent through the simulator's actuation model
(delay, first-order lag, gains, the wheels' deadband and arc where calibrated: `pipeline.sim`'s model),
and ends at the recorded velocity `WINDOW_S` later. For each window the simulator is run under
`DRAWS` parameter draws (common random numbers, so the likelihood is smooth in mu and sigma); the
draws' end velocities give a Gaussian (mean, covariance + the measurement noise), and the recorded
end velocity its log-likelihood. The measurement noise is not the simulator's to explain: it is the
ground truth's own velocity noise, from successive differences of each track (their median absolute
value, as a standard deviation, over sqrt 2), but at least `EPSILON` of the recorded velocities' rms
(a smoothed ground truth looks smoother than it is right). mu and log sigma are found by
Nelder-Mead from the calibration's point estimates and standard errors.

A uniform range with the fitted spread is mu +- sqrt(3) sigma; training draws from the union of it
and the estimate's widened 95 % interval.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from pipeline.calibration.actuation import VelocityTrack
from pipeline.calibration.estimates import MAD_TO_SIGMA, Estimate
from pipeline.calibration.wheels import NOMINAL_WHEEL_RADIUS_M, NOMINAL_WHEEL_SEPARATION_M
from pipeline.core.timebase import NS_PER_S

WINDOW_S = 0.5
"""Length of one transition."""
STEP_S = 0.01
"""Time step of the simulated actuation."""
DRAWS = 16
"""Parameter draws per likelihood evaluation (the same standard normal draws throughout the fit)."""
MAX_WINDOWS = 200
"""Most transitions used (evenly spread over the tracks)."""
MIN_WINDOWS = 20
KEYS = ("delay_s", "time_constant_s", "linear_gain", "angular_gain")
"""The actuation keys whose randomization is fitted, in the model's order."""
LOWER = np.array([0.0, 0.005, 0.01, 0.01])
"""Draws are clipped to the simulator's bounds of each key."""
UPPER = np.array([1.0, 2.0, 5.0, 5.0])
EPSILON = 0.02
"""Least measurement noise per channel, as a fraction of the recorded velocities' rms (DROPO's epsilon: a smoothed
ground truth is smoother than it is right)."""
UNIFORM_HALF_WIDTH = math.sqrt(3.0)
UNEXPLAINED_PROB = 0.05
"""Prior share of transitions that no draw of the simulator produces (a robot caught on something, a slipping
wheel): the likelihood is a mixture of the simulator's Gaussian and a broad one (the recorded velocities' own
spread), so a few such windows do not stretch every range to cover them."""
"""A uniform range mu +- sqrt(3) sigma has standard deviation sigma."""


@dataclass(frozen=True)
class RandomizationFit:
    """Fitted N(mu, sigma^2) per actuation key, the uniform range of the same spread, and the total log-likelihood
    of the transitions at the start (point estimates, their standard errors) and at the fit."""

    mu: dict[str, float]
    sigma: dict[str, float]
    log_likelihood_start: float
    log_likelihood_fit: float
    windows: int
    noise_std: tuple[float, float]
    explained: float = 1.0
    """Share of the transitions the fitted randomized simulator explains better than the broad component."""
    notes: tuple[str, ...] = ()

    def ranges(self) -> dict[str, tuple[float, float]]:
        """Uniform ranges (low, high) with the fitted mean and spread, inside the simulator's bounds."""
        out = {}
        for k, key in enumerate(KEYS):
            half = UNIFORM_HALF_WIDTH * self.sigma[key]
            out[key] = (max(self.mu[key] - half, float(LOWER[k])), min(self.mu[key] + half, float(UPPER[k])))
        return out


@dataclass(frozen=True)
class _Windows:
    """Transitions: start velocity (w, 2), recorded end velocity (w, 2), and for each the command acting at each
    step for every delay (looked up per draw): command times (w, n_steps) relative to each window's start."""

    start: np.ndarray
    end: np.ndarray
    tracks: tuple[VelocityTrack, ...]
    t0_ns: np.ndarray
    timeout_s: float


def _windows(tracks: Sequence[VelocityTrack], timeout_s: float) -> tuple[_Windows, tuple[float, float]]:
    starts, ends, owners, t0 = [], [], [], []
    noise: list[np.ndarray] = []
    window_ns = WINDOW_S * NS_PER_S
    for track in tracks:
        if len(track.t_ns) > 2:
            noise.append(np.diff(track.achieved, axis=0))
        t = track.t_ns
        begin = int(t[0])
        while begin + window_ns <= int(t[-1]):
            i = int(np.searchsorted(t, begin))
            j = int(np.searchsorted(t, begin + window_ns))
            j = min(j, len(t) - 1)
            if j > i:
                starts.append(track.achieved[i])
                ends.append(track.achieved[j])
                owners.append(track)
                t0.append(int(t[i]))
            begin += round(window_ns)
    keep = np.arange(len(starts))
    if len(keep) > MAX_WINDOWS:
        keep = np.unique(np.linspace(0, len(starts) - 1, MAX_WINDOWS).round().astype(int))
    diffs = np.concatenate(noise) if noise else np.zeros((0, 2))
    # robust to the velocity's own changes between samples: the median absolute difference
    std = np.median(np.abs(diffs), axis=0) * MAD_TO_SIGMA / math.sqrt(2) if len(diffs) else np.zeros(2)
    recorded = np.concatenate([t.achieved for t in tracks]) if tracks else np.zeros((0, 2))
    floor = EPSILON * np.sqrt(np.mean(recorded**2, axis=0)) if len(recorded) else np.full(2, 1e-3)
    std = np.maximum(std, np.maximum(floor, 1e-4))
    windows = _Windows(
        np.asarray([starts[k] for k in keep]).reshape(-1, 2),
        np.asarray([ends[k] for k in keep]).reshape(-1, 2),
        tuple(owners[k] for k in keep),
        np.asarray([t0[k] for k in keep], dtype=np.int64),
        timeout_s,
    )
    return windows, (float(std[0]), float(std[1]))


def _targets(u: np.ndarray, gains: np.ndarray, deadband_radps: float, arc_per_m: float) -> np.ndarray:
    """The simulator's velocity targets for commands (..., 2): gained, wheel speeds under the deadband zeroed per
    wheel (nominal geometry), and the yaw rate that unequal wheels add per m/s."""
    target = u * gains
    if deadband_radps > 0:
        half = NOMINAL_WHEEL_SEPARATION_M / 2
        left = target[..., 0] - half * target[..., 1]
        right = target[..., 0] + half * target[..., 1]
        limit = deadband_radps * NOMINAL_WHEEL_RADIUS_M
        left = np.where(np.abs(left) < limit, 0.0, left)
        right = np.where(np.abs(right) < limit, 0.0, right)
        target = np.stack([(left + right) / 2, (right - left) / (2 * half)], axis=-1)
    if arc_per_m != 0.0:
        target = np.stack([target[..., 0], target[..., 1] + arc_per_m * target[..., 0]], axis=-1)
    return np.asarray(target)


class _Likelihood:
    """Total log-likelihood of the windows' end velocities under N(mu, sigma^2) draws of the actuation keys."""

    def __init__(
        self, windows: _Windows, noise_std: tuple[float, float], seed: int, deadband: float, arc_per_m: float
    ) -> None:
        self.w = windows
        self.broad_mean = windows.end.mean(axis=0) if len(windows.end) else np.zeros(2)
        self.broad_var = np.maximum(windows.end.var(axis=0), 1e-6) if len(windows.end) else np.ones(2)
        self.deadband = deadband
        self.arc = arc_per_m
        self.z = np.random.default_rng(seed).standard_normal((DRAWS, len(KEYS)))
        self.noise = np.diag(np.square(np.maximum(noise_std, 1e-6)))
        self.n_steps = round(WINDOW_S / STEP_S)
        self.mid_ns = np.round((np.arange(self.n_steps) + 0.5) * STEP_S * NS_PER_S).astype(np.int64)
        self._commands: dict[int, np.ndarray] = {}

    def _u(self, delay_ns: int) -> np.ndarray:
        """(windows, steps, 2) commands acting at each step's midpoint with a delay of `delay_ns` (cached per ms)."""
        key = round(delay_ns / 1e6)
        if key not in self._commands:
            out = np.empty((len(self.w.t0_ns), self.n_steps, 2))
            for k, (track, t0) in enumerate(zip(self.w.tracks, self.w.t0_ns, strict=True)):
                out[k] = track.commands.at(t0 + self.mid_ns - key * 1_000_000, self.w.timeout_s)
            self._commands[key] = out
        return self._commands[key]

    def predict(self, params: np.ndarray) -> np.ndarray:
        """(draws, windows, 2) end velocities for parameter draws (draws, 4)."""
        out = np.empty((len(params), len(self.w.t0_ns), 2))
        for d, (delay, tau, g_lin, g_ang) in enumerate(params):
            gains = np.array([g_lin, g_ang])
            a = math.exp(-STEP_S / tau)
            target = _targets(self._u(round(delay * NS_PER_S)), gains, self.deadband, self.arc)
            weights = (1 - a) * a ** np.arange(self.n_steps - 1, -1, -1)  # the last step weighs most
            out[d] = self.w.start * a**self.n_steps + np.einsum("wsc,s->wc", target, weights)
        return out

    def __call__(self, mu: np.ndarray, sigma: np.ndarray) -> float:
        params = np.clip(mu[None, :] + sigma[None, :] * self.z, LOWER, UPPER)
        pred = self.predict(params)  # (draws, windows, 2)
        mean = pred.mean(axis=0)
        centred = pred - mean
        cov = np.einsum("dwi,dwj->wij", centred, centred) / max(len(params) - 1, 1) + self.noise
        return float(np.sum(self.window_log_likelihoods(mean, cov)[0]))

    def window_log_likelihoods(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per window: the log-likelihood under the mixture, and the probability that the simulator's component
        (rather than the broad one) produced it."""
        r = self.w.end - mean
        _, logdet = np.linalg.slogdet(cov)
        quad = np.einsum("wi,wij,wj->w", r, np.linalg.inv(cov), r)
        sim = math.log(1 - UNEXPLAINED_PROB) - 0.5 * (quad + logdet + 2 * math.log(2 * math.pi))
        broad_r = self.w.end - self.broad_mean
        broad = math.log(UNEXPLAINED_PROB) - 0.5 * (
            np.sum(broad_r**2 / self.broad_var, axis=1) + np.sum(np.log(self.broad_var)) + 2 * math.log(2 * math.pi)
        )
        total = np.logaddexp(sim, broad)
        return total, np.exp(sim - total)

    def explained(self, mu: np.ndarray, sigma: np.ndarray) -> float:
        """Share of the windows that the simulator's component explains better than the broad one."""
        params = np.clip(mu[None, :] + sigma[None, :] * self.z, LOWER, UPPER)
        pred = self.predict(params)
        mean = pred.mean(axis=0)
        centred = pred - mean
        cov = np.einsum("dwi,dwj->wij", centred, centred) / max(len(params) - 1, 1) + self.noise
        return float(np.mean(self.window_log_likelihoods(mean, cov)[1] > 0.5))


def fit_randomization(
    tracks: Sequence[VelocityTrack],
    estimates: Mapping[str, Estimate],
    timeout_s: float,
    seed: int = 0,
    deadband_radps: float = 0.0,
    arc_per_m: float = 0.0,
) -> RandomizationFit | None:
    """mu and sigma of each actuation key maximizing the likelihood of the tracks' transitions; None when a key
    has no estimate or the tracks hold fewer than `MIN_WINDOWS` transitions."""
    est = [estimates.get(f"actuation.{k}") for k in KEYS]
    if not all(e is not None and e.ok and e.value is not None for e in est):
        return None
    windows, noise = _windows(tracks, timeout_s)
    if len(windows.t0_ns) < MIN_WINDOWS:
        return None
    mu0 = np.array([float(e.value) for e in est if e is not None and e.value is not None])
    se0 = np.array(
        [e.std_error if e is not None and e.std_error else 0.01 * abs(m) + 1e-3 for e, m in zip(est, mu0, strict=True)]
    )
    scale = np.maximum(np.abs(mu0), 0.01)
    likelihood = _Likelihood(windows, noise, seed, deadband_radps, arc_per_m)
    start = likelihood(mu0, se0)

    def cost(x: np.ndarray) -> float:
        mu = mu0 + x[:4] * scale
        sigma = np.exp(x[4:]) * scale
        return -likelihood(mu, sigma)

    x0 = np.r_[np.zeros(4), np.log(np.maximum(se0, 1e-4 * scale) / scale)]
    simplex = np.vstack([x0, x0 + np.diag(np.r_[np.full(4, 0.05), np.full(4, 1.5)])])
    options = {"maxfev": 800, "xatol": 1e-3, "fatol": 0.05, "initial_simplex": simplex}
    result = minimize(cost, x0, method="Nelder-Mead", options=options)
    x = result.x
    mu = np.clip(mu0 + x[:4] * scale, LOWER, UPPER)
    sigma = np.exp(x[4:]) * scale
    explained = likelihood.explained(mu, sigma)
    notes = (
        f"randomization fitted to {len(windows.t0_ns)} transitions of {WINDOW_S:g} s ({DRAWS} draws each): "
        f"log-likelihood {start:.1f} at the estimates and their standard errors, {-result.fun:.1f} fitted; "
        f"ground truth velocity noise {noise[0]:.4f} m/s, {noise[1]:.4f} rad/s; the randomized simulator "
        f"explains {explained:.0%} of the transitions, the rest it cannot produce at any draw",
    )
    return RandomizationFit(
        dict(zip(KEYS, mu.tolist(), strict=True)),
        dict(zip(KEYS, sigma.tolist(), strict=True)),
        start,
        -float(result.fun),
        len(windows.t0_ns),
        noise,
        explained,
        notes,
    )
