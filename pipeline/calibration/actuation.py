"""Actuation delay, first-order time constant and velocity gains from commanded vs achieved velocity.

Model, per channel c (forward speed v and yaw rate w): the achieved body velocity (the smoothed
ground truth in the robot's frame) is ``y_c(t) = gain_c * lag_tau(u_c(t - delay))``, where u is
the command as sent (held until the next one, zero after the command timeout) and lag_tau a
first-order low-pass with time constant tau (exact for held inputs: a = exp(-h / tau) per grid
step h), started at each track's measured velocity. Delay and tau are shared by both channels,
as in the simulator; for given (delay, tau) the gains are linear least squares.

The search: a coarse grid of delay and tau, then a local grid around its best point whose cost is
refined by a quadratic fit; the local grid's per-cluster sums (cluster: one robot in one episode)
give a bootstrap over clusters for the uncertainties of all four values.

Tracks are the contact-free stretches of smoothed ground truth (a robot touching a wall, a box or
another robot does not follow its commands).

Speed limits: a real base saturates (its motors reach their top speed), so a commanded 0.5 m/s that
is never exceeded beyond 0.31 m/s is a limit, not a gain of 0.62. Per channel, the model's command
is cut at a knee ``+-k`` (``y = gain * lag(clip(u, -k, k))``, achieved limit ``gain * k``): with the
delay and time constant of a first fit, the knee is searched on a grid of shares of the largest
command; a knee is kept when it removes at least `SATURATION_MIN_DROP` of the channel's residual
with at least `SATURATION_MIN_SHARE` of the samples commanded beyond it, the whole fit is then
done again on the cut commands, and the knee searched again at its delay and time constant, so the
gains are the base's below its limit. The limit's interval is the bootstrap over clusters of the
knee search.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from pipeline.calibration.estimates import Estimate, bootstrap, counted, spread
from pipeline.calibration.options import CalibrationSettings
from pipeline.core.timebase import NS_PER_S

COARSE_STEP_S = 0.01
COARSE_DELAY_STEP_S = 0.02
FINE_STEP_S = 0.005
TAU_MIN_S = 0.01
TAU_MAX_S = 2.0
LOCAL_DELAY_STEPS = 8
"""The local grid spans the coarse delay +- this many fine steps..."""
LOCAL_LOG_TAU = 0.5
"""...and the coarse tau times exp(+-this)."""
CHANNELS = ("linear", "angular")
LIMIT_UNITS = ("m/s", "rad/s")
KNEE_SHARES = np.linspace(0.25, 1.0, 61)
"""Knees searched, as shares of the channel's largest command (1: no limit)."""
SATURATION_MIN_DROP = 0.25
"""A knee must remove this share of the channel's residual sum of squares to be a speed limit..."""
SATURATION_MIN_SHARE = 0.03
"""...with this share of the channel's samples commanded beyond it."""
BLOCK_S = 5.0
"""With a single robot-episode, its tracks are cut into blocks of this length for the bootstrap."""
ONE_LEVEL_SPREAD = 0.05
"""A channel whose moving commands (above 5 % of its largest) lie within this share of their median (5th to 95th
percentile) is commanded at one speed: a gain and a speed limit explain it alike."""
MIN_GAIN_SHORTFALL = 0.02
"""A gain this far below 1 at one commanded speed could as well be a limit (a base that falls short of it)."""
TRADE_OFF_CORRELATION = -0.9
"""Delay and lag whose bootstrap draws correlate this strongly trade against each other in the recording."""


@dataclass(frozen=True)
class CommandTimeline:
    """A robot's commands as sent: times `t_ns` (n,) and (v m/s, w rad/s) `values` (n, 2)."""

    t_ns: np.ndarray
    values: np.ndarray

    def at(self, t_ns: np.ndarray, timeout_s: float) -> np.ndarray:
        """(m, 2) the command acting at times `t_ns` (m,): the latest sent, zero if older than `timeout_s` or none."""
        t = np.asarray(t_ns, dtype=np.int64)
        k = np.searchsorted(self.t_ns, t, side="right") - 1
        out = np.zeros((len(t), 2))
        ok = k >= 0
        ok[ok] &= (t[ok] - self.t_ns[k[ok]]) <= timeout_s * NS_PER_S
        out[ok] = self.values[k[ok]]
        return out


@dataclass(frozen=True)
class VelocityTrack:
    """Achieved body velocity (n, 2) (v m/s, w rad/s) at times `t_ns` (n,) of one contact-free stretch.

    `commands` is the robot's whole command timeline; `cluster` groups tracks for the bootstrap
    (one robot in one episode).
    """

    robot: str
    cluster: str
    t_ns: np.ndarray
    achieved: np.ndarray
    commands: CommandTimeline

    @property
    def duration_s(self) -> float:
        return float(self.t_ns[-1] - self.t_ns[0]) / NS_PER_S


@dataclass(frozen=True)
class Ambiguity:
    """Two drive models that explain a recording equally: the keys concerned, each reading in words, the one kept
    (the reading that changes the simulator least where the data cannot decide) and what recording would tell them
    apart."""

    keys: tuple[str, ...]
    readings: tuple[str, ...]
    kept: str
    separate: str

    def sentence(self) -> str:
        return f"{' or '.join(self.readings)}; kept: {self.kept}; to tell them apart: {self.separate}"

    def as_mapping(self) -> dict[str, object]:
        return {"keys": list(self.keys), "readings": list(self.readings), "kept": self.kept, "separate": self.separate}


@dataclass(frozen=True)
class ActuationFit:
    """The actuation estimates.

    `example` is a stretch for the report: time (s), achieved, model and command velocities ((n, 2) each).
    """

    delay_s: Estimate
    time_constant_s: Estimate
    linear_gain: Estimate
    angular_gain: Estimate
    example: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    residual_rms: tuple[float, float] | None = None
    tracks: int = 0
    duration_s: float = 0.0
    notes: tuple[str, ...] = ()
    speed_limits: tuple[SpeedLimit | None, SpeedLimit | None] = (None, None)
    """Per channel (linear, angular): what the recording says about the base's top speed; None: channel unused."""
    ambiguities: tuple[Ambiguity, ...] = ()
    """Where two drive models explain the recording alike (see :class:`Ambiguity`)."""
    delay_lag_correlation: float | None = None
    """Correlation of the delay's and the lag's bootstrap draws (None without a bootstrap)."""
    response_s: Estimate = field(default_factory=lambda: Estimate.unidentifiable("not fitted", "s"))
    bootstrap_se: dict[str, float | None] = field(default_factory=dict)
    """Each value's standard error over the bootstrap alone, before the misfit widens it (the domain
    randomization's fit starts from these)."""
    """Delay + lag: the mean time a command takes to act (the first moment of the step response), which a lag and
    a delay that trade against each other leave well determined."""

    def ambiguous_gain(self, channel: int) -> bool:
        """The channel's gain could as well be a speed limit (one commanded speed): it is not a setting."""
        return any(a.keys[0] == f"actuation.{CHANNELS[channel]}_gain" for a in self.ambiguities)


@dataclass(frozen=True)
class SpeedLimit:
    """A channel's top speed: `limit` (the achieved speed no command exceeds, m/s or rad/s) when the base
    saturated, else unidentifiable; the largest speed commanded and achieved, and the share of the samples
    commanded beyond the limit."""

    channel: str
    limit: Estimate
    commanded_max: float
    achieved_max: float
    saturated_share: float = 0.0
    achieved_p99: float = math.nan
    """The 99th percentile of the achieved speed: what the base held (the peak is a transient, a turn's overshoot)."""

    @property
    def saturated(self) -> bool:
        return self.limit.ok

    def as_mapping(self) -> dict[str, object]:
        out: dict[str, object] = {"saturated": self.saturated, **self.limit.as_mapping()}
        out["commanded_max"] = float(f"{self.commanded_max:.6g}")
        out["achieved_max"] = float(f"{self.achieved_max:.6g}")
        if math.isfinite(self.achieved_p99):
            out["achieved_p99"] = float(f"{self.achieved_p99:.6g}")
        out["saturated_share"] = float(f"{self.saturated_share:.4g}")
        return out

    def sentence(self) -> str:
        unit = self.limit.unit
        if self.saturated and self.limit.value is not None:
            iv = self.limit.interval
            within = f" [{iv[0]:.3g}, {iv[1]:.3g}]" if iv is not None else ""
            held = (
                f"achieved {self.achieved_p99:.3g} {unit} at the 99th percentile (peak {self.achieved_max:.3g}, a "
                "transient)"
                if math.isfinite(self.achieved_p99)
                else f"achieved up to {self.achieved_max:.3g} {unit}"
            )
            return (
                f"{self.channel} speed limit {self.limit.value:.3g}{within} {unit}: commanded up to "
                f"{self.commanded_max:.3g} {unit}, {held}; {self.saturated_share:.0%} of the samples commanded "
                "beyond the limit, and the gain is fitted below it"
            )
        return f"{self.channel}: no speed limit up to {self.achieved_max:.3g} {unit} achieved ({self.limit.reason})"


class _Problem:
    """Tracks laid out on a common time grid of step `h_s`, padded to one length."""

    def __init__(self, tracks: Sequence[VelocityTrack], h_s: float, timeout_s: float) -> None:
        self.h_s = h_s
        self.timeout_s = timeout_s
        self.tracks = tracks
        h_ns = h_s * NS_PER_S
        lengths = [math.floor((t.t_ns[-1] - t.t_ns[0]) / h_ns) + 2 for t in tracks]
        self.length = max(lengths)
        n = len(tracks)
        self.y0 = np.stack([t.achieved[0] for t in tracks])
        # where each truth sample falls on its track's grid: index and fraction for linear interpolation
        rows, idx, frac, y = [], [], [], []
        for i, t in enumerate(tracks):
            pos = (t.t_ns - t.t_ns[0]) / h_ns
            k = np.minimum(np.floor(pos).astype(np.int64), lengths[i] - 2)
            rows.append(np.full(len(pos), i))
            idx.append(k)
            frac.append(pos - k)
            y.append(t.achieved)
        self.row = np.concatenate(rows)
        self.idx = np.concatenate(idx)
        self.frac = np.concatenate(frac)
        self.y = np.concatenate(y)
        self.n_tracks = n

    def commands(self, delay_s: float, knees: Sequence[float] = (math.inf, math.inf)) -> np.ndarray:
        """(2, n_tracks, length) commands acting at grid cell midpoints delayed by `delay_s`, each channel cut
        at +-its knee."""
        out = np.zeros((2, self.n_tracks, self.length))
        mid = (np.arange(self.length) + 0.5) * self.h_s - delay_s
        for i, t in enumerate(self.tracks):
            times = t.t_ns[0] + np.round(mid * NS_PER_S).astype(np.int64)
            out[:, i, :] = t.commands.at(times, self.timeout_s).T
        for c, knee in enumerate(knees):
            if math.isfinite(knee):
                np.clip(out[c], -knee, knee, out=out[c])
        return out

    def response(self, u: np.ndarray, tau_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Model velocity at every truth sample, (2, n) each: the lag's response to commands `u` (from
        :meth:`commands`) from rest, before the gain; and the decay of each track's initial velocity."""
        a = math.exp(-self.h_s / tau_s)
        out = lfilter([1.0 - a], [1.0, -a], u, axis=-1)
        states = np.concatenate([np.zeros((2, self.n_tracks, 1)), out], axis=-1)  # state at grid times 0..length
        s0 = states[:, self.row, self.idx]
        s1 = states[:, self.row, self.idx + 1]
        forced = s0 + self.frac * (s1 - s0)
        steps = self.idx + self.frac
        free = self.y0.T[:, self.row] * np.power(a, steps)
        return np.asarray(forced), np.asarray(free)


def _sums(
    problem: _Problem, response: tuple[np.ndarray, np.ndarray], clusters: np.ndarray, n_clusters: int
) -> np.ndarray:
    """(n_clusters, 2 channels, 3) per-cluster sums of y'm, mm and y'y', where m is the forced response and
    y' the achieved velocity minus the free response."""
    forced, free = response
    out = np.zeros((n_clusters, 2, 3))
    who = clusters[problem.row]
    for c in range(2):
        y = problem.y[:, c] - free[c]
        m = forced[c]
        # bincount adds in the samples' order, as np.add.at does, many times faster
        out[:, c, 0] = np.bincount(who, y * m, n_clusters)
        out[:, c, 1] = np.bincount(who, m * m, n_clusters)
        out[:, c, 2] = np.bincount(who, y * y, n_clusters)
    return out


def _cost(sums: np.ndarray, yy: np.ndarray, channels: Sequence[int]) -> float:
    """Gain-optimised squared error from sums (2, 3) (see :func:`_sums`), normalised per channel by sum y^2 (2,)."""
    total = 0.0
    for c in channels:
        ym, mm, rr = sums[c]
        if mm <= 0:
            return math.inf
        total += (rr - ym * ym / mm) / yy[c]
    return total


def _quadratic_min(cost: np.ndarray, i: int, j: int) -> tuple[float, float]:
    """Sub-grid offsets (grid steps, within +-1) of the minimum of a quadratic through the 3 x 3 cells around (i, j)."""
    ni, nj = cost.shape
    if not (0 < i < ni - 1 and 0 < j < nj - 1):
        return 0.0, 0.0
    c = cost[i - 1 : i + 2, j - 1 : j + 2]
    if not np.all(np.isfinite(c)):
        return 0.0, 0.0
    di = (c[2, 1] - c[0, 1]) / 2
    dj = (c[1, 2] - c[1, 0]) / 2
    dii = c[2, 1] - 2 * c[1, 1] + c[0, 1]
    djj = c[1, 2] - 2 * c[1, 1] + c[1, 0]
    dij = (c[2, 2] - c[2, 0] - c[0, 2] + c[0, 0]) / 4
    hess = np.array([[dii, dij], [dij, djj]])
    if np.linalg.det(hess) <= 0 or dii <= 0:
        return 0.0, 0.0
    step = -np.linalg.solve(hess, np.array([di, dj]))
    return float(np.clip(step[0], -1, 1)), float(np.clip(step[1], -1, 1))


def _excitation(tracks: Sequence[VelocityTrack]) -> tuple[np.ndarray, np.ndarray]:
    """Per channel: the largest |command| and the number of command steps during the tracks."""
    peak = np.zeros(2)
    steps: list[np.ndarray] = []
    for t in tracks:
        cmd = t.commands
        sel = (cmd.t_ns >= t.t_ns[0]) & (cmd.t_ns <= t.t_ns[-1])
        if not sel.any():
            continue
        values = cmd.values[sel]
        peak = np.maximum(peak, np.abs(values).max(axis=0))
        steps.append(np.abs(np.diff(values, axis=0)))
    jumps = np.concatenate(steps) if steps else np.zeros((0, 2))
    return peak, jumps


UNITS = {"delay_s": "s", "time_constant_s": "s", "linear_gain": "ratio", "angular_gain": "ratio"}


def _all_unidentifiable(reason: str, tracks: int = 0, duration_s: float = 0.0) -> ActuationFit:
    est = {k: Estimate.unidentifiable(reason, u) for k, u in UNITS.items()}
    return ActuationFit(
        est["delay_s"],
        est["time_constant_s"],
        est["linear_gain"],
        est["angular_gain"],
        tracks=tracks,
        duration_s=duration_s,
    )


def _channel_problems(tracks: Sequence[VelocityTrack], settings: CalibrationSettings) -> list[str]:
    """Per channel (linear, angular): why the commands cannot identify it ('' when they can)."""
    peak, jumps = _excitation(tracks)
    thresholds = (settings.actuation_min_linear_mps, settings.actuation_min_angular_radps)
    units = ("m/s", "rad/s")
    words = ("linear commands", "turning commands")
    out: list[str] = []
    for c in range(2):
        n_steps = int(np.sum(jumps[:, c] >= thresholds[c])) if len(jumps) else 0
        if peak[c] < thresholds[c]:
            out.append(f"no {words[c]} above {thresholds[c]:g} {units[c]}")
        elif n_steps < settings.actuation_min_steps:
            out.append(
                f"only {n_steps} steps of the {words[c]} above {thresholds[c]:g} {units[c]} "
                f"(need {settings.actuation_min_steps})"
            )
        else:
            out.append("")
    return out


@dataclass(frozen=True)
class _LocalGrid:
    """The fine grid of delays and lags around the coarse fit, with each cluster's least-squares sums at every point
    (for the bootstrap): `cluster_sums` (delays, taus, clusters, 2 channels, 3), `yy` each channel's sum of squares."""

    delays: np.ndarray
    taus: np.ndarray
    log_step: float
    cluster_sums: np.ndarray
    yy: np.ndarray

    @staticmethod
    def around(
        fine: _Problem,
        d0: float,
        tau0: float,
        knees: Sequence[float],
        max_delay: float,
        cluster_of: np.ndarray,
        n_clusters: int,
    ) -> _LocalGrid:
        yy = np.array([np.sum(fine.y[:, c] ** 2) for c in range(2)])
        local_d = d0 + FINE_STEP_S * np.arange(-LOCAL_DELAY_STEPS, LOCAL_DELAY_STEPS + 1)
        local_d = local_d[(local_d >= -1e-12) & (local_d <= max_delay + 1e-9)]
        local_tau = tau0 * np.exp(np.linspace(-LOCAL_LOG_TAU, LOCAL_LOG_TAU, 21))
        local_tau = local_tau[(local_tau >= TAU_MIN_S) & (local_tau <= TAU_MAX_S)]
        log_step = float(np.log(local_tau[1] / local_tau[0])) if len(local_tau) > 1 else 0.0
        cluster_sums = np.zeros((len(local_d), len(local_tau), n_clusters, 2, 3))
        for i, d in enumerate(local_d):
            u = fine.commands(float(d), knees)
            for j, tau in enumerate(local_tau):
                cluster_sums[i, j] = _sums(fine, fine.response(u, float(tau)), cluster_of, n_clusters)
        return _LocalGrid(local_d, local_tau, log_step, cluster_sums, yy)

    def solve(self, weights: np.ndarray, channels: list[int]) -> np.ndarray:
        """(delay, tau, linear gain, angular gain) of the clusters weighted by `weights` (n_clusters,)."""
        sums = np.tensordot(weights, self.cluster_sums, axes=([0], [2]))  # (n_delays, n_taus, 2, 3)
        cost = np.array(
            [[_cost(sums[i, j], self.yy, channels) for j in range(len(self.taus))] for i in range(len(self.delays))]
        )
        if not np.isfinite(cost).any():
            return np.full(4, np.nan)
        i, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
        di, dj = _quadratic_min(cost, int(i), int(j))
        gains = [sums[i, j, c, 0] / sums[i, j, c, 1] if sums[i, j, c, 1] > 0 else np.nan for c in range(2)]
        return np.array(
            [self.delays[i] + di * FINE_STEP_S, self.taus[j] * math.exp(dj * self.log_step), gains[0], gains[1]]
        )


def _ambiguities(
    fine: _Problem,
    samples: np.ndarray,
    gains: np.ndarray,
    limits: list[SpeedLimit | None],
    problems: list[str],
    channels: list[int],
    commanded: np.ndarray,
    delay: float,
    tau: float,
    n_clusters: int,
) -> tuple[list[Ambiguity], float | None]:
    """What the drive's data leave open: a channel commanded at one speed whose gain short of 1 may be a speed limit
    instead (its limit and problem set in `limits` and `problems`), and a delay and lag that trade off; and the
    delay's and lag's bootstrap correlation (None with one cluster)."""
    ambiguities: list[Ambiguity] = []
    for c in channels:
        level = _one_level(commanded[c])
        limit = limits[c]
        if level is None or limit is None or limit.saturated or not gains[c] < 1.0 - MIN_GAIN_SHORTFALL:
            continue
        g_se, g_interval = spread(samples[:, 2 + c])
        ambiguity, limits[c] = _gain_or_limit(c, float(gains[c]), g_se, g_interval, level, limit, len(fine.y))
        ambiguities.append(ambiguity)
        problems[c] = f"{ambiguity.readings[0]} or {ambiguity.readings[1]} (one commanded speed): {ambiguity.separate}"
    correlation = _correlation(samples[:, 0], samples[:, 1]) if n_clusters >= 2 else None
    if correlation is not None and correlation <= TRADE_OFF_CORRELATION:
        ambiguities.append(
            Ambiguity(
                ("actuation.delay_s", "actuation.time_constant_s"),
                (
                    f"a delay of {delay:.3g} s before a lag of {tau:.3g} s",
                    "a longer delay before a shorter lag, or a shorter delay before a longer one "
                    f"(their bootstrap draws correlate {correlation:+.2f})",
                ),
                "the least-squares pair, with intervals that span the trade-off",
                "commands that reverse sharply, in steps of several sizes, with the base at rest between them",
            )
        )
    return ambiguities, correlation


def _drive_estimates(
    samples: np.ndarray,
    values: tuple[float, float, float, float],
    problems: list[str],
    reach: _Reach,
    method: str,
    n: int,
) -> tuple[dict[str, Estimate], dict[str, float | None], Estimate]:
    """The delay, lag and gains as estimates (unidentifiable where a channel has a problem or the velocity does not
    settle), their bootstrap standard errors, and the response (delay + lag), each interval widened for the misfit
    (`reach`)."""
    delay, tau = values[0], values[1]
    out: dict[str, Estimate] = {}
    bootstrap_se: dict[str, float | None] = {}
    for k, (name, unit) in enumerate(UNITS.items()):
        se, interval = spread(samples[:, k])
        known_se = None if math.isnan(se) else se
        known_interval = None if math.isnan(interval[0]) else interval
        if k >= 2 and problems[k - 2]:
            out[name] = Estimate.unidentifiable(problems[k - 2], unit)
        elif name == "time_constant_s" and tau >= TAU_MAX_S * 0.95:
            out[name] = Estimate.unidentifiable(f"the velocity does not settle within {TAU_MAX_S:g} s", unit)
        else:
            bootstrap_se[name] = known_se
            se_k, interval_k = reach.widen(k, values[k], known_se, known_interval)
            out[name] = Estimate.of(values[k], se_k, interval_k, unit, method + reach.words, n)
    response = Estimate.unidentifiable(out["delay_s"].reason or out["time_constant_s"].reason, "s")
    if out["delay_s"].ok and out["time_constant_s"].ok:
        se, interval = spread(samples[:, 0] + samples[:, 1])
        known = not math.isnan(se)
        se_r, interval_r = reach.widen(4, delay + tau, se if known else None, interval if known else None)
        response = Estimate.of(delay + tau, se_r, interval_r, "s", method + reach.words, n)
    return out, bootstrap_se, response


def estimate_actuation(
    tracks: Sequence[VelocityTrack], settings: CalibrationSettings, rng: np.random.Generator
) -> ActuationFit:
    """Delay (s), time constant (s), linear and angular gain from contact-free velocity `tracks`."""
    tracks = [t for t in tracks if t.duration_s >= settings.actuation_min_track_s]
    duration = float(sum(t.duration_s for t in tracks))
    if not tracks:
        return _all_unidentifiable(
            f"no contact-free stretch of ground truth of >= {settings.actuation_min_track_s:g} s with commands"
        )
    problems = _channel_problems(tracks, settings)
    channels = [c for c in range(2) if not problems[c]]
    if not channels:
        return _all_unidentifiable("; ".join(problems), len(tracks), duration)
    blocks = len({t.cluster for t in tracks}) < 2
    if blocks:  # one robot in one episode: consecutive blocks of its tracks are the bootstrap's clusters
        tracks = [piece for i, t in enumerate(tracks) for piece in _blocks(t, BLOCK_S, f"{t.cluster} track {i}")]
    cluster_names = sorted({t.cluster for t in tracks})
    cluster_of = np.array([cluster_names.index(t.cluster) for t in tracks])
    n_clusters = len(cluster_names)
    max_delay = settings.actuation_delay_max_s
    timeout = settings.command_timeout_s

    # coarse grid over the whole range; the speed limits at its best point; the coarse grid again on the cut commands
    coarse = _Problem(tracks, COARSE_STEP_S, timeout)
    fine = _Problem(tracks, FINE_STEP_S, timeout)
    d0, tau0 = _coarse_fit(coarse, channels, max_delay)
    saturation = _speed_limits(fine, d0, tau0, channels, cluster_of, n_clusters, settings.bootstrap, rng)
    knees = saturation.knees
    if any(math.isfinite(k) for k in knees):
        d0, tau0 = _coarse_fit(coarse, channels, max_delay, knees)

    grid = _LocalGrid.around(fine, d0, tau0, knees, max_delay, cluster_of, n_clusters)
    yy, cluster_sums, local_d, local_tau = grid.yy, grid.cluster_sums, grid.delays, grid.taus

    def solve(weights: np.ndarray) -> np.ndarray:
        return grid.solve(weights, channels)

    best = solve(np.ones(n_clusters))
    delay, tau = max(float(best[0]), 0.0), float(best[1])
    if any(math.isfinite(k) for k in knees):  # the knees again, at the refined (delay, tau)
        saturation = _speed_limits(fine, delay, tau, channels, cluster_of, n_clusters, settings.bootstrap, rng)
        knees = saturation.knees
    # gains, residuals and the report's example at the refined (delay, tau)
    forced, free = fine.response(fine.commands(delay, knees), tau)
    sums = _sums(fine, (forced, free), np.zeros(len(tracks), dtype=np.int64), 1)[0]
    gains = np.array([sums[c, 0] / sums[c, 1] if sums[c, 1] > 0 else np.nan for c in range(2)])
    fitted = forced * gains[:, None] + free
    rms = (
        float(np.sqrt(np.mean((fine.y[:, 0] - fitted[0]) ** 2))),
        float(np.sqrt(np.mean((fine.y[:, 1] - fitted[1]) ** 2))),
    )
    if n_clusters >= 2:
        samples = bootstrap(solve, n_clusters, settings.bootstrap, rng)
        # resampled gains are read at grid points: shift them by the refinement of the full data's
        samples[:, 2:] += gains - best[2:]
        for c, draws in saturation.gain_draws.items():
            # a saturated channel's gain moves with its knee: the draws of the two fitted together
            samples[:, 2 + c] = gains[c] + draws[: len(samples)]
        method = f"bootstrap over {n_clusters} " + (f"blocks of {BLOCK_S:g} s" if blocks else "robot-episodes")
    else:
        samples = np.full((2, 4), np.nan)
        method = "one robot-episode: no uncertainty"
    values = (delay, tau, float(gains[0]), float(gains[1]))
    reach = _misfit_reach(fine, fitted, cluster_sums.sum(axis=2), yy, channels, local_d, local_tau)
    commanded = np.abs(fine.commands(delay)[:, fine.row, fine.idx])
    limits = list(saturation.limits)
    ambiguities, correlation = _ambiguities(
        fine, samples, gains, limits, problems, channels, commanded, delay, tau, n_clusters
    )
    out, bootstrap_se, response = _drive_estimates(samples, values, problems, reach, method, len(fine.y))
    notes: tuple[str, ...] = (
        f"{counted(len(tracks), 'contact-free track')}, {duration:.1f} s, from {counted(n_clusters, 'robot-episode')}",
    )
    notes += tuple(limit.sentence() for limit in limits if limit is not None)
    notes += tuple(f"ambiguous: {a.sentence()}" for a in ambiguities)
    return ActuationFit(
        out["delay_s"],
        out["time_constant_s"],
        out["linear_gain"],
        out["angular_gain"],
        example=_example(fine, fitted),
        residual_rms=rms,
        tracks=len(tracks),
        duration_s=duration,
        notes=notes,
        speed_limits=(limits[0], limits[1]),
        ambiguities=tuple(ambiguities),
        delay_lag_correlation=correlation,
        response_s=response,
        bootstrap_se=bootstrap_se,
    )


@dataclass(frozen=True)
class _Reach:
    """How far the drive's values can move before the fit is worse than the model's misfit allows: per value
    (delay, lag, linear gain, angular gain, delay + lag) the range of the grid cells whose cost is within
    chi2(1, 95 %) / n_eff of the least, n_eff the residual's effective sample count (its lag-one autocorrelation
    rho: n (1 - rho) / (1 + rho)). A model that misses the robot leaves residuals that run together, so few
    effective samples and a wide reach: the interval admits the misfit. The delay's reach also holds both grid
    values around its refined minimum (the cost between them is not evaluated)."""

    ranges: tuple[tuple[float, float], ...]
    correlation: float
    effective_samples: float

    @property
    def words(self) -> str:
        return (
            f"; widened to the values the fitted model's misfit leaves as good (residual autocorrelation "
            f"{self.correlation:.3f}: {self.effective_samples:.0f} effective samples)"
        )

    def widen(
        self, k: int, value: float, se: float | None, interval: tuple[float, float] | None
    ) -> tuple[float | None, tuple[float, float] | None]:
        low, high = self.ranges[k]
        if not (math.isfinite(low) and math.isfinite(high)):
            return se, interval
        low, high = min(low, value), max(high, value)
        if k == 0:  # a delay refined between two grid values fits as well as either: both their half cells
            half = FINE_STEP_S / 2
            low = min(low, math.floor(value / FINE_STEP_S + 1e-9) * FINE_STEP_S - half)
            high = max(high, math.ceil(value / FINE_STEP_S - 1e-9) * FINE_STEP_S + half)
            low = max(low, 0.0)
        if interval is not None:
            low, high = min(low, interval[0]), max(high, interval[1])
        width_se = (high - low) / (2 * 1.96)
        return (width_se if se is None else max(se, width_se)), (low, high)


def _misfit_reach(
    problem: _Problem,
    fitted: np.ndarray,
    sums: np.ndarray,
    yy: np.ndarray,
    channels: Sequence[int],
    delays: np.ndarray,
    taus: np.ndarray,
) -> _Reach:
    """The :class:`_Reach` of the fit over the local grid's summed `sums` (n_delays, n_taus, 2, 3)."""
    residual = problem.y.T - fitted
    same = problem.row[1:] == problem.row[:-1]
    rho = 0.0
    for c in channels:
        r = residual[c]
        den = float(np.sum(r * r))
        if den > 0:
            rho = max(rho, float(np.sum(r[1:][same] * r[:-1][same])) / den)
    rho = min(max(rho, 0.0), 0.999)
    n_eff = max(len(problem.y) * len(channels) * (1 - rho) / (1 + rho), 2.0)
    cost = np.array([[_cost(sums[i, j], yy, channels) for j in range(len(taus))] for i in range(len(delays))])
    nan = (math.nan, math.nan)
    if not np.isfinite(cost).any():
        return _Reach((nan,) * 5, rho, n_eff)
    inside = cost <= float(np.nanmin(cost)) * (1 + 3.84 / n_eff)
    d_grid, t_grid = np.meshgrid(delays, taus, indexing="ij")
    half_d = FINE_STEP_S / 2
    log_half = float(np.log(taus[1] / taus[0])) / 2 if len(taus) > 1 else 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        gains = np.where(sums[..., 1] > 0, sums[..., 0] / sums[..., 1], np.nan)  # (n_delays, n_taus, 2)
    ranges: list[tuple[float, float]] = [
        (max(float(d_grid[inside].min()) - half_d, 0.0), float(d_grid[inside].max()) + half_d),
        (float(t_grid[inside].min()) * math.exp(-log_half), float(t_grid[inside].max()) * math.exp(log_half)),
    ]
    for c in range(2):
        g = gains[..., c][inside]
        ranges.append((float(np.nanmin(g)), float(np.nanmax(g))) if c in channels and np.isfinite(g).any() else nan)
    response = (d_grid + t_grid)[inside]
    ranges.append((max(float(response.min()) - half_d, 0.0), float(response.max()) + half_d))
    return _Reach(tuple(ranges), rho, n_eff)


def _one_level(commanded: np.ndarray) -> float | None:
    """The one speed a channel was commanded at (the median of its moving commands), else None."""
    peak = float(commanded.max()) if commanded.size else 0.0
    moving = commanded[commanded > 0.05 * peak]
    if peak <= 0 or len(moving) < 20:
        return None
    low, mid, high = np.percentile(moving, [5, 50, 95])
    return float(mid) if high - low <= ONE_LEVEL_SPREAD * mid else None


def _gain_or_limit(
    c: int,
    gain: float,
    gain_se: float,
    gain_interval: tuple[float, float],
    level: float,
    limit: SpeedLimit,
    n: int,
) -> tuple[Ambiguity, SpeedLimit]:
    """One commanded speed `level` achieved at `gain` of it: a gain below 1, or the nominal gain up to a top speed of
    gain x level. Over the commands up to `level`, the limit changes the simulator by (1 - gain)^2 level / 2 on
    average, the gain by (1 - gain) level / 2: the limit is kept (commands below it act as nominal), the gain is
    not a setting."""
    unit = LIMIT_UNITS[c]
    top = gain * level
    known = not math.isnan(gain_se)
    interval = (gain_interval[0] * level, gain_interval[1] * level) if known else None
    method = f"one commanded speed ({level:.3g} {unit}) achieved at {gain:.3g} of it: the limit reading"
    estimate = Estimate.of(top, gain_se * level if known else None, interval, unit, method, n)
    channel = CHANNELS[c]
    ambiguity = Ambiguity(
        (f"actuation.{channel}_gain", f"speed_limits.{channel}"),
        (
            f"{'an' if channel[0] in 'aeiou' else 'a'} {channel} gain of {gain:.3g} without a speed limit",
            f"the nominal gain up to a limit of {top:.3g} {unit}",
        ),
        f"the limit ({top:.3g} {unit}): it changes the simulator least, commands below it acting as nominal",
        f"commands at several {channel} speeds, some below {top:.3g} {unit} and some above it",
    )
    return ambiguity, SpeedLimit(channel, estimate, limit.commanded_max, limit.achieved_max, 1.0, limit.achieved_p99)


def _correlation(a: np.ndarray, b: np.ndarray) -> float | None:
    good = np.isfinite(a) & np.isfinite(b)
    if good.sum() < 3 or np.std(a[good]) == 0 or np.std(b[good]) == 0:
        return None
    return float(np.corrcoef(a[good], b[good])[0, 1])


def _blocks(track: VelocityTrack, block_s: float, name: str) -> list[VelocityTrack]:
    """`track` cut into consecutive pieces of about `block_s` (the last one takes the remainder), each its own
    cluster (`name` block k); each piece starts from its own measured velocity, as every track does."""
    rel = (track.t_ns - track.t_ns[0]) / NS_PER_S
    n = max(1, int(rel[-1] // block_s))
    index = np.minimum((rel // block_s).astype(np.int64), n - 1)
    out = []
    for k in range(n):
        sel = index == k
        if sel.sum() >= 3:
            out.append(
                VelocityTrack(track.robot, f"{name} block {k}", track.t_ns[sel], track.achieved[sel], track.commands)
            )
    return out


def _coarse_fit(
    coarse: _Problem, channels: Sequence[int], max_delay: float, knees: Sequence[float] = (math.inf, math.inf)
) -> tuple[float, float]:
    """(delay, tau) of the least cost on the coarse grid, commands cut at `knees`."""
    yy = np.array([np.sum(coarse.y[:, c] ** 2) for c in range(2)])
    delays = np.arange(0.0, max_delay + 1e-9, COARSE_DELAY_STEP_S)
    taus = np.geomspace(TAU_MIN_S, TAU_MAX_S, 36)
    grid = np.full((len(delays), len(taus)), np.inf)
    one = np.zeros(coarse.n_tracks, dtype=np.int64)
    for i, d in enumerate(delays):
        u = coarse.commands(float(d), knees)
        for j, tau in enumerate(taus):
            grid[i, j] = _cost(_sums(coarse, coarse.response(u, float(tau)), one, 1)[0], yy, channels)
    i0, j0 = np.unravel_index(int(np.argmin(grid)), grid.shape)
    return float(delays[i0]), float(taus[j0])


def _knee_of(sums: np.ndarray, c: int) -> tuple[float, float, float, float]:
    """From per-knee sums (n_knees, 2, 3) of channel `c`: the knee index refined by a parabola through the least
    cost and its neighbours (fractional), the gain there, the least cost and the cost without a knee."""
    ym, mm, rr = sums[:, c, 0], sums[:, c, 1], sums[:, c, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        cost = np.where(mm > 0, rr - ym * ym / mm, np.inf)
        gain = np.where(mm > 0, ym / mm, np.nan)
    k = int(np.argmin(cost))
    offset = 0.0
    if 0 < k < len(cost) - 1 and np.all(np.isfinite(cost[k - 1 : k + 2])):
        curve = cost[k - 1] - 2 * cost[k] + cost[k + 1]
        if curve > 0:
            offset = float(np.clip((cost[k - 1] - cost[k + 1]) / (2 * curve), -0.5, 0.5))
    j = k + 1 if offset > 0 else k - 1
    g = gain[k] + abs(offset) * (gain[j] - gain[k]) if 0 <= j < len(gain) else gain[k]
    return k + offset, float(g), float(cost[k]), float(cost[-1])


@dataclass(frozen=True)
class _Limits:
    limits: tuple[SpeedLimit | None, SpeedLimit | None]
    knees: tuple[float, float]
    gain_draws: dict[int, np.ndarray]


def _speed_limits(
    problem: _Problem,
    delay: float,
    tau: float,
    channels: Sequence[int],
    cluster_of: np.ndarray,
    n_clusters: int,
    resamples: int,
    rng: np.random.Generator,
) -> _Limits:
    """Per channel: the speed limit the recording shows (see the module's notes), the command knee (inf: none) and,
    where saturated, the bootstrap draws of the gain fitted with the knee (about the full data's)."""
    u = problem.commands(delay)
    peak = np.abs(u).reshape(2, -1).max(axis=1)
    sums = np.zeros((len(KNEE_SHARES), n_clusters, 2, 3))
    for k, share in enumerate(KNEE_SHARES):
        cut = np.clip(u, -(peak * share)[:, None, None], (peak * share)[:, None, None])
        sums[k] = _sums(problem, problem.response(cut, tau), cluster_of, n_clusters)
    commanded = np.abs(u[:, problem.row, problem.idx])
    limits: list[SpeedLimit | None] = [None, None]
    knees = [math.inf, math.inf]
    gain_draws: dict[int, np.ndarray] = {}
    for c in channels:
        achieved_max = float(np.abs(problem.y[:, c]).max())
        achieved_p99 = float(np.percentile(np.abs(problem.y[:, c]), 99))
        position, gain, least, plain = _knee_of(sums.sum(axis=1), c)
        share_at = float(np.interp(position, np.arange(len(KNEE_SHARES)), KNEE_SHARES))
        knee = peak[c] * share_at
        beyond = float(np.mean(commanded[c] > knee * 1.02))
        drop = 1.0 - least / plain if plain > 0 else 0.0
        unit = LIMIT_UNITS[c]
        if share_at < 1.0 and drop >= SATURATION_MIN_DROP and beyond >= SATURATION_MIN_SHARE:

            def limit_of(weights: np.ndarray, c: int = c) -> np.ndarray:
                pos, g, _, _ = _knee_of(np.tensordot(weights, sums, axes=([0], [1])), c)
                return np.array([g * peak[c] * float(np.interp(pos, np.arange(len(KNEE_SHARES)), KNEE_SHARES)), g])

            if n_clusters >= 2:
                draws = bootstrap(limit_of, n_clusters, resamples, rng)
                gain_draws[c] = draws[:, 1] - gain
                se, interval = spread(draws[:, 0])
                method = f"knee of the command, bootstrap over {n_clusters} clusters"
                estimate = Estimate.of(gain * knee, se, interval, unit, method, len(problem.y))
            else:
                estimate = Estimate.of(gain * knee, None, None, unit, "knee of the command, one robot-episode", 1)
            limits[c] = SpeedLimit(CHANNELS[c], estimate, float(peak[c]), achieved_max, beyond, achieved_p99)
            knees[c] = knee
        else:
            why = (
                f"a limit would explain {max(drop, 0.0):.0%} of the residual (needs {SATURATION_MIN_DROP:.0%}) with "
                f"{beyond:.0%} of the samples beyond it (needs {SATURATION_MIN_SHARE:.0%}); commands reached "
                f"{peak[c]:.3g} {unit}"
            )
            limits[c] = SpeedLimit(CHANNELS[c], Estimate.unidentifiable(why, unit), float(peak[c]), achieved_max)
    return _Limits((limits[0], limits[1]), (knees[0], knees[1]), gain_draws)


def _example(problem: _Problem, fitted: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The longest track: time (s from its start); achieved, fitted, commanded velocity (n, 2) at its truth samples."""
    lengths = [len(t.t_ns) for t in problem.tracks]
    i = int(np.argmax(lengths))
    sel = problem.row == i
    track = problem.tracks[i]
    t_s = (track.t_ns - track.t_ns[0]) / NS_PER_S
    command = track.commands.at(track.t_ns, problem.timeout_s)
    return t_s, problem.y[sel], fitted[:, sel].T, command
