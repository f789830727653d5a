"""The wheel motors' deadband (rad/s) and acceleration limit (rad/s^2), from commanded vs achieved wheel speeds.

Commanded wheel speeds: the commands as sent, turned into left and right wheel speeds by the nominal
geometry, as the robot's driver does. Achieved: the odometry's twist turned back into wheel speeds by
the same geometry; it is the encoders' change over one odometry period, so the model is averaged over
that period too. Only contact-free samples count (a robot pushing a wall does not turn its wheels as
commanded).

Model per wheel: the command passes a delay and the driver's lag, is scaled by the linear and angular
gains, zeroed where smaller than the deadband, followed by a setpoint that changes at most `accel`
rad/s^2 (a slew-rate limit), which the wheel follows through the motor's lag.

Stages, because the body-velocity fit of the actuation module (one lag, no deadband) absorbs a
deadband into smaller gains and a slew limit into a longer lag:
1. Held commands: samples at least `SETTLE_S` after the command last changed show the steady state,
   where the achieved speed is the gained target, or zero under the deadband. For each deadband on a
   grid the gains are least squares over the moving samples (classified by the current gains,
   iterated); the deadband with the least total squared error wins.
2. Transients: with those gains and deadband, a grid over delay x total lag x the motor's share of it
   x acceleration limit (with "no limit"), simulated from rest at each episode's start. Where the held
   commands never came near the deadband (it is unidentifiable from them), the transients pick it from
   `TRANSIENT_DEADBANDS_RADPS` within the range the held commands leave open: an arbitrary deadband
   there biased the limit upwards by about one grid step.
The chain is simulated in `STEP_S` steps, each stage taking its input's value at a step's end as held through the
step (half a step early per lag stage) and the odometry's window read from end-of-step values: the commands enter
half a step late and the windows end a step early, so that a delay reads true to within half a step on a
continuous chain (it read 10-15 ms long before). Both stages keep per-episode sums, so a bootstrap over
robot-episodes gives the intervals (percentiles widened by half a grid step; the delay and the limit by a whole
step, which the coarse deadband grid and the chain's steps bend; the lags also by the small-sample factor of so few
robot-episodes, :func:`small_sample_factor`).
3. Between the grid's values: from the grid's best point, least squares moves the delay, both lags and the limit on
   the same chain simulated in `REFINE_STEP_S` steps, each step's input the command's mean over the step
   (:func:`_refine`; the limit's estimate stays the grid's); the intervals hold both the grid's and a one-step
   bootstrap's about the fit. The delay read so
   at the wheels holds whatever the commands' path adds between their sending and the driver (on the twin at time
   scale 3, 8 ms in the median).
A deadband is identifiable only where commands asked for wheel speeds near it, an acceleration limit
only where they asked for more than it: otherwise the key is reported unidentifiable with the bound the
data do give.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.optimize import least_squares
from scipy.signal import lfilter

from pipeline.calibration.actuation import CommandTimeline
from pipeline.calibration.estimates import Estimate, bootstrap, counted
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.wheels import NOMINAL_WHEEL_RADIUS_M, NOMINAL_WHEEL_SEPARATION_M
from pipeline.core.timebase import NS_PER_S

STEP_S = 0.01
"""Time step of the simulated wheel chain."""
SETTLE_S = 0.8
"""A sample counts as steady when the command has not changed for this long before its odometry period."""
DEADBANDS_RADPS = np.round(np.arange(0.0, 2.501, 0.05), 3)
"""Deadbands tried (rad/s of wheel speed)."""
ACCELS_RADPS2 = np.r_[np.geomspace(5.0, 300.0, 41), np.inf]
"""Acceleration limits tried (rad/s^2); the last is no limit."""
DELAYS_S = np.round(np.arange(0.0, 0.241, 0.02), 3)
"""Delays of the first pass (s)."""
FINE_DELAY_STEP_S = 0.01
"""The second pass tries delays this far apart (the wheel chain's step) between the first pass's neighbours of its
best."""
FINE_MARGIN = 2
"""Steps of the second pass's delays kept on each side of its least cost (see :func:`_fine_window`)."""
LAGS_S = np.geomspace(0.03, 0.4, 24)
"""Total lags tried (driver + motor, s)."""
TRANSIENT_DEADBANDS_RADPS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5)
"""Deadbands the transients try where the held commands leave the deadband open (those within the range they leave
open). A deadband sits between the driver's lag and the motors' and bends the share of the lag the transients give
the motors: with steps of 0.5 rad/s a deadband of 0.75 read the motors' lag 2-3 times too long."""
MOTOR_SHARES = np.linspace(0.0, 2 / 3, 9)
"""Fractions of the total lag taken by the motor (after the limit) rather than the driver (before it)."""
COARSE_MOTOR_SHARES = MOTOR_SHARES[::2]
COARSE_ACCELS_RADPS2 = np.array([10.0, 20.0, 40.0, 80.0, np.inf])
"""The first pass, which picks the delay (and the deadband where the held commands leave it open), on every lag,
every other share and these limits; the second tries every share and limit at the delays next to it. (Every other
lag in the first pass moved the delay a grid step or two, with the motors' lag, on one robot of the coverage run.)"""
MOTOR_LAG_MAX_SPREAD = 4.0
"""The motors' lag is identified only where its interval spans less than this factor: wider, the transients leave
it to the drive's lag as a whole (the drawn robots' motors lie within a factor of 5 of each other)."""
MIN_BELOW_SAMPLES = 20
"""Steady samples with a commanded wheel speed inside the deadband grid needed to tell the deadband."""
MIN_EPISODES = 2
MIN_LIMIT_GAIN = 0.05
"""A limit must lower the wheel-speed residual sum of squares by this share against no limit to be reported."""
MAX_TRANSIENT_EPISODES = 10
"""Most robot-episodes the transient grid is simulated on (evenly chosen; the grid's cost grows with each)."""
MOVING_RADPS = 0.05
"""A commanded wheel speed above this is a command to move."""


@dataclass(frozen=True)
class WheelEpisode:
    """One robot in one episode: odometry times `t_ns` (n,) on the recorder's clock, the achieved wheel speeds
    (n, 2) (left, right, rad/s) over the odometry period ending at each, which samples are contact-free, the
    command timeline, and the episode's start (the robot at rest)."""

    robot: str
    cluster: str
    start_ns: int
    t_ns: np.ndarray
    wheels: np.ndarray
    free: np.ndarray
    commands: CommandTimeline


@dataclass(frozen=True)
class MotorFit:
    deadband_radps: Estimate
    max_wheel_accel_radps2: Estimate
    gains: tuple[float, float] | None = None
    """(linear, angular) gains of the wheel chain (stage 1), free of the deadband."""
    notes: tuple[str, ...] = ()
    motor_time_constant_s: Estimate = field(
        default_factory=lambda: Estimate.unidentifiable("the transients were not fitted", "s")
    )
    """The motors' own lag (after the acceleration limit): the motor's share of the total lag of the transients."""
    delay_s: Estimate = field(default_factory=lambda: Estimate.unidentifiable("the transients were not fitted", "s"))
    """The driver's delay, read at the wheels (before the deadband, the limit and the motors' lag)."""
    driver_time_constant_s: Estimate = field(
        default_factory=lambda: Estimate.unidentifiable("the transients were not fitted", "s")
    )
    """The driver's lag: the rest of the transients' total lag."""


def wheel_speeds(v_mps: np.ndarray, w_radps: np.ndarray) -> np.ndarray:
    """(n, 2) left and right wheel speeds (rad/s) of body velocities by the nominal geometry."""
    half = NOMINAL_WHEEL_SEPARATION_M / 2
    return np.stack([(v_mps - w_radps * half), (v_mps + w_radps * half)], axis=1) / NOMINAL_WHEEL_RADIUS_M


def _parts(commands: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The linear and angular parts (n, 2) of the wheel speeds of commands (n, 2): wheels = a * g_lin + b * g_ang."""
    zero = np.zeros(len(commands))
    return wheel_speeds(commands[:, 0], zero), wheel_speeds(zero, commands[:, 1])


@dataclass(frozen=True)
class _Steady:
    """Steady samples of one episode: the wheel speed parts (m, 2) each and the achieved speeds (m, 2)."""

    a: np.ndarray
    b: np.ndarray
    y: np.ndarray


def _steady(episode: WheelEpisode, period_s: float, timeout_s: float) -> _Steady:
    cmd = episode.commands
    t = episode.t_ns[episode.free]
    y = episode.wheels[episode.free]
    begin = t - round(period_s * NS_PER_S)
    k = np.searchsorted(cmd.t_ns, begin, side="right") - 1
    ok = k >= 0
    values = cmd.values[np.maximum(k, 0)]
    # when did the command acting at the period's start take that value?
    changed = np.r_[True, np.any(np.diff(cmd.values, axis=0) != 0, axis=1)]
    since = np.maximum.accumulate(np.where(changed, np.arange(len(changed)), 0))
    set_ns = cmd.t_ns[since[np.maximum(k, 0)]]
    held = ok & (begin - set_ns >= SETTLE_S * NS_PER_S)
    # the same command still acting at the sample (no change within the period) and not timed out
    k_end = np.searchsorted(cmd.t_ns, t, side="right") - 1
    same = since[np.maximum(k_end, 0)] == since[np.maximum(k, 0)]
    fresh = t - cmd.t_ns[np.maximum(k_end, 0)] <= timeout_s * NS_PER_S
    keep = held & same & fresh
    a, b = _parts(values[keep])
    return _Steady(a, b, y[keep])


def _steady_fit(samples: Sequence[_Steady], weights: np.ndarray) -> tuple[float, float, float, float]:
    """(deadband low, deadband high, linear gain, angular gain) minimizing the weighted squared error of the steady
    samples: every deadband on the grid between the same data points fits equally, so the least cost holds a
    range of them."""
    a = np.concatenate([s.a for s in samples]).ravel()
    b = np.concatenate([s.b for s in samples]).ravel()
    y = np.concatenate([s.y for s in samples]).ravel()
    w = np.concatenate([np.full(2 * len(s.y), wt, dtype=float) for s, wt in zip(samples, weights, strict=True)])
    costs, fitted = [], []
    for db in DEADBANDS_RADPS:
        g = np.array([1.0, 1.0])
        for _ in range(3):
            target = a * g[0] + b * g[1]
            moving = (np.abs(target) >= db) & (w > 0)
            x = np.stack([a[moving], b[moving]], axis=1) * np.sqrt(w[moving])[:, None]
            if len(x) < 3 or np.linalg.matrix_rank(x) < 2:
                break
            g = np.linalg.lstsq(x, y[moving] * np.sqrt(w[moving]), rcond=None)[0]
        target = a * g[0] + b * g[1]
        model = np.where(np.abs(target) < db, 0.0, target)
        costs.append(float(np.sum(w * (y - model) ** 2)))
        fitted.append(g)
    cost = np.asarray(costs)
    best = np.flatnonzero(cost <= cost.min() * (1 + 1e-9) + 1e-12)
    first, last = int(best[0]), int(best[-1])
    # the tie may break where classification changes within the run; keep its contiguous part
    run = last
    while run > first and run - 1 not in best:
        run -= 1
    g = fitted[first]
    return float(DEADBANDS_RADPS[first]), float(DEADBANDS_RADPS[run]), float(g[0]), float(g[1])


def _lag(x: np.ndarray, tau_s: float, step_s: float = STEP_S) -> np.ndarray:
    """First-order lag along axis 0 in steps of `step_s` (exact for inputs held over each step), from rest."""
    if tau_s <= 0:
        return x
    a = math.exp(-step_s / tau_s)
    return np.asarray(lfilter([1.0 - a], [1.0, -a], x, axis=0))


def _unseparated(lo: float, hi: float) -> str:
    """Why the motors' lag is unidentified where its interval spans [lo, hi] s."""
    return (
        f"the transients leave the motors' own lag between {lo:.3g} and {hi:.3g} s (a spread beyond a factor "
        f"of {MOTOR_LAG_MAX_SPREAD:g}): it is part of effective.drive_lag_s; steps of several sizes against a "
        "binding acceleration limit would separate it"
    )


def _transient_costs(
    episode: WheelEpisode,
    deadband: float,
    gains: tuple[float, float],
    period_s: float,
    timeout_s: float,
    delays: np.ndarray,
    accels: np.ndarray,
    lags: np.ndarray = LAGS_S,
    shares: np.ndarray = MOTOR_SHARES,
) -> np.ndarray:
    """(delays, lags, shares, accels) sums of squared residuals over the episode's free samples."""
    n = int((int(episode.t_ns[-1]) - episode.start_ns) / (STEP_S * NS_PER_S)) + 2
    grid_ns = episode.start_ns + np.round(np.arange(n) * STEP_S * NS_PER_S).astype(np.int64)
    free_t = episode.t_ns[episode.free]
    achieved = episode.wheels[episode.free]
    # the chain's wheel speed after step k stands for the end of that step and a mean of such end values stands
    # for a window half a step later again: the sample's window (its odometry period ending at t) ends in step
    # k_end where that lands nearest to t
    k_end = np.clip(np.searchsorted(grid_ns, free_t, side="right") - 2, 0, n - 1)
    span = max(round(period_s / STEP_S), 1)
    n_d, n_l, n_s, n_a = len(delays), len(lags), len(shares), len(accels)
    # the driver's output for every (delay, lag, share), deadbanded: (n, 2, d, l, s), the wheel first so that each
    # wheel's part of the state below is contiguous
    targets = np.empty((n, 2, n_d, n_l, n_s))
    wheels = np.empty((n, 2, n_d))
    for i, delay in enumerate(delays):
        # each stage below takes its input's value at the end of a step as held through that step, half a step
        # early: the driver's lag and the motors' put the wheels a whole step ahead, which the command in effect
        # half a step before each step's start takes back (and a command change lands on the step nearest to it)
        u = episode.commands.at(grid_ns - round((STEP_S / 2 + float(delay)) * NS_PER_S), timeout_s)
        a, b = _parts(u)
        wheels[:, :, i] = a * gains[0] + b * gains[1]
    for j, lag in enumerate(lags):
        for m, share in enumerate(shares):  # every delay's wheels through one filter
            targets[:, :, :, j, m] = _lag(wheels, float(lag) * (1.0 - float(share)))
    targets[np.abs(targets) < deadband] = 0.0
    # the state (2, d, l, s, a) with its bounds and the motors' factor laid out in full: min/max and products
    # against contiguous arrays of its shape run several times faster than np.clip against broadcast views
    shape = (2, n_d, n_l, n_s, n_a)
    step = np.ascontiguousarray(np.broadcast_to(accels * STEP_S, shape))
    neg_step = -step
    motor_tau = lags[:, None] * shares[None, :]
    follow = np.where(motor_tau > 0, 1.0 - np.exp(-STEP_S / np.maximum(motor_tau, 1e-12)), 1.0)[None, None, :, :, None]
    follow = np.ascontiguousarray(np.broadcast_to(follow, shape))
    setpoint = np.zeros(shape)
    wheel = np.zeros_like(setpoint)
    running = np.zeros_like(setpoint)
    change = np.empty_like(setpoint)
    history = np.zeros((span + 1, *shape))  # running sums of the last span + 1 steps
    costs = np.zeros((n_d, n_l, n_s, n_a))
    order = np.argsort(k_end, kind="stable")
    j = 0
    last = int(k_end.max()) if len(k_end) else -1
    for k in range(last + 1):  # no sample reads a step after the last one's
        np.subtract(targets[k][..., None], setpoint, out=change)
        np.minimum(change, step, out=change)  # the limit: np.clip(change, neg_step, step)
        np.maximum(change, neg_step, out=change)
        setpoint += change
        np.subtract(setpoint, wheel, out=change)
        change *= follow
        wheel += change
        running += wheel
        history[k % (span + 1)] = running
        while j < len(order) and k_end[order[j]] == k:
            sample = order[j]
            steps = min(span, k + 1)
            if k >= steps:
                np.subtract(running, history[(k - steps) % (span + 1)], out=change)
            else:
                change[...] = running
            change /= steps
            change -= achieved[sample][:, None, None, None, None]
            change *= change
            costs += change[0]
            costs += change[1]
            j += 1
    return costs


REFINE_STEP_S = 0.002
"""Time step of the chain in the refinement (a drive's own control period: nothing the steps bend is a grid's)."""


@dataclass(frozen=True)
class _Samples:
    """What the chain of one robot-episode is compared with: the free samples' times (s from the episode's start) and
    achieved speeds (m, 2), the odometry period, and the commands as pieces."""

    t_s: np.ndarray
    period_s: float
    achieved: np.ndarray
    wheels: np.ndarray
    """(pieces, 2) the wheel speeds the commands ask for (gains applied), each from `since_s` to the next piece."""
    since_s: np.ndarray
    integral: np.ndarray
    """(pieces, 2) the wheel speeds' integral (rad) from the first piece to each piece's start."""


def _samples(episode: WheelEpisode, gains: tuple[float, float], period_s: float, timeout_s: float) -> _Samples:
    # the commands as pieces: each from its sending until the next, or until it times out (then zero)
    cmd = episode.commands
    t = (cmd.t_ns - episode.start_ns) / NS_PER_S
    ends = np.r_[t[1:], np.inf]
    lapsed = ends - t > timeout_s
    since = np.r_[t, t[lapsed] + timeout_s]
    values = np.r_[cmd.values, np.zeros((int(lapsed.sum()), 2))]
    order = np.argsort(since, kind="stable")
    since, values = np.r_[-np.inf, since[order]], np.r_[np.zeros((1, 2)), values[order]]
    a, b = _parts(values)
    wheels = a * gains[0] + b * gains[1]
    lengths = np.diff(since)[1:, None]
    integral = np.r_[np.zeros((2, 2)), np.cumsum(wheels[1:-1] * lengths, axis=0)]
    t_s = (episode.t_ns[episode.free] - episode.start_ns) / NS_PER_S
    return _Samples(t_s, period_s, episode.wheels[episode.free], wheels, since, integral)


def _commanded_integral(s: _Samples, t: np.ndarray) -> np.ndarray:
    """(len(t), 2) the commanded wheel speeds' integral (rad) up to times `t` (s from the episode's start)."""
    j = np.searchsorted(s.since_s, t, side="right") - 1
    start = np.where(j > 0, s.since_s[np.maximum(j, 1)], 0.0)
    return np.asarray(s.integral[j] + s.wheels[j] * np.where(j > 0, t - start, 0.0)[:, None])


def _slew(target: np.ndarray, step: float) -> np.ndarray:
    """A setpoint that follows `target` (n, 2) from rest by at most `step` per step."""
    if not math.isfinite(step):
        return target
    out = np.empty_like(target)
    for side in range(target.shape[1]):
        s, column = 0.0, out[:, side]
        for k, x in enumerate(target[:, side].tolist()):
            s += min(max(x - s, -step), step)
            column[k] = s
    return out


def _chain_residuals(
    s: _Samples, delay: float, deadband: float, driver_s: float, motor_s: float, accel: float
) -> np.ndarray:
    """(m, 2) the chain's mean wheel speeds over each sample's odometry period less the achieved ones, for one set of
    values, from rest at the episode's start: in steps of `REFINE_STEP_S`, each step's input the command's mean
    over the step (delayed), the lags exact for inputs held through a step, the limit per step, and the window's
    mean by the trapezoid rule on the steps' ends."""
    h = REFINE_STEP_S
    n = math.ceil(float(s.t_s.max()) / h) + 1
    times = np.arange(n + 1) * h
    commanded = _commanded_integral(s, times - delay)
    target = _lag(np.diff(commanded, axis=0) / h, driver_s, h)
    target = np.where(np.abs(target) < deadband, 0.0, target)
    wheel = np.r_[np.zeros((1, 2)), _lag(_slew(target, accel * h), motor_s, h)]
    travelled = np.r_[np.zeros((1, 2)), np.cumsum((wheel[1:] + wheel[:-1]) / 2 * h, axis=0)]

    def at(t: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t, times, travelled[:, side]) for side in range(2)], axis=1)

    return np.asarray((at(s.t_s) - at(s.t_s - s.period_s)) / s.period_s - s.achieved)


@dataclass(frozen=True)
class _Refined:
    """The delay, the lags (driver, motor) and the limit fitted between the grid's values (`values`, the delay in s
    and the rest as logs), and each robot-episode's part of the least-squares normal equations there: J^T J
    (episodes, k, k) and J^T r (episodes, k) of its residuals r and their Jacobian J."""

    values: np.ndarray
    normal: np.ndarray
    gradient: np.ndarray


REFINE_STEPS = (0.2, 0.02, 0.02, 0.02)
"""Steps of the delay (in steps of the chain) and of the log lags and limit by which the residuals' Jacobian is
taken."""


def _refine(samples: Sequence[_Samples], deadband: float, start: tuple[float, float, float, float]) -> _Refined:
    """Least squares over the delay (in steps of the chain) and log (driver lag, motor lag[, limit]) from `start` and
    from a step of delay either side of it (the delay trades against the lags along a narrow valley); the limit
    stays infinite where `start`'s is."""
    free = 4 if math.isfinite(start[3]) else 3

    def residuals(x: np.ndarray) -> list[np.ndarray]:
        d, m = math.exp(x[1]), math.exp(x[2])
        a = math.exp(x[3]) if free == 4 else math.inf
        return [_chain_residuals(s, float(x[0]) * STEP_S, deadband, d, m, a).ravel() for s in samples]

    x0 = np.r_[start[0] / STEP_S, np.log(np.maximum(np.array(start[1:free]), 1e-3))]
    fits = [
        least_squares(lambda x: np.concatenate(residuals(x)), x0 + shift * np.eye(free)[0], diff_step=1e-2)
        for shift in (0.0, -1.0, 1.0)
    ]
    x = min(fits, key=lambda f: float(f.cost)).x
    base = residuals(x)
    moved = [residuals(x + REFINE_STEPS[i] * np.eye(free)[i]) for i in range(free)]
    jacobians = [
        np.stack([(mv[e] - base[e]) / REFINE_STEPS[i] for i, mv in enumerate(moved)], axis=1) for e in range(len(base))
    ]
    normal = np.stack([j.T @ j for j in jacobians])
    gradient = np.stack([j.T @ r for j, r in zip(jacobians, base, strict=True)])
    return _Refined(np.r_[x[0] * STEP_S, x[1:]], normal, gradient)


def _refined_draw(r: _Refined, weights: np.ndarray) -> np.ndarray:
    """(delay, driver lag, motor lag) of one bootstrap draw: the fit moved by the linearized least-squares step of
    the draw's weights; NaN where the step is singular or leaves the linear neighbourhood."""
    h = np.tensordot(weights, r.normal, axes=1)
    g = np.tensordot(weights, r.gradient, axes=1)
    try:
        step = -np.linalg.solve(h, g)
    except np.linalg.LinAlgError:
        return np.full(3, np.nan)
    if np.any(np.abs(step[1:]) > 2.0):
        return np.full(3, np.nan)
    x = r.values + step
    return np.array([r.values[0] + step[0] * STEP_S, math.exp(x[1]), math.exp(x[2])])


def _least_delay(costs: np.ndarray) -> int:
    """Index of the delay of the least total cost over the episodes' costs (episodes, delays, ...)."""
    total = costs.sum(axis=0)
    return int(np.unravel_index(int(np.argmin(total)), total.shape)[0])


def _fine_window(
    transient: Sequence[WheelEpisode],
    args: tuple[float, tuple[float, float], float, float],
    delays: np.ndarray,
    costs: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The second pass's delays (and costs (episodes, delays, ...)) moved outwards, a step at a time, until the least
    cost lies `FINE_MARGIN` steps inside them (or at the first pass's range's end). The first pass sees the limit on
    a coarse grid, and a limit between two of its values bends the delay: on a coverage robot (limit 23.6 rad/s^2,
    delay 29 ms) it chose 80 ms, the second pass's least cost lay on its window's edge at 60 ms, and the interval
    missed the delay and the motors' lag that traded against it."""
    low, high = float(DELAYS_S[0]), float(DELAYS_S[-1])

    def at(delay: float) -> tuple[np.ndarray, np.ndarray]:
        new = np.array([round(delay, 3)])
        return new, np.stack([_transient_costs(e, *args, new, ACCELS_RADPS2) for e in transient])

    while True:
        best = _least_delay(costs)
        lower = best < FINE_MARGIN and delays[0] > low + 1e-9
        upper = best > len(delays) - 1 - FINE_MARGIN and delays[-1] < high - 1e-9
        if not (lower or upper):
            return delays, costs
        if lower:
            new, more = at(float(delays[0]) - FINE_DELAY_STEP_S)
            delays, costs = np.r_[new, delays], np.concatenate([more, costs], axis=1)
        if upper:
            new, more = at(float(delays[-1]) + FINE_DELAY_STEP_S)
            delays, costs = np.r_[delays, new], np.concatenate([costs, more], axis=1)


def _unfitted(reason: str) -> MotorFit:
    """Every motor key unidentifiable for `reason`."""
    return MotorFit(
        Estimate.unidentifiable(reason, "rad/s"),
        Estimate.unidentifiable(reason, "rad/s^2"),
        motor_time_constant_s=Estimate.unidentifiable(reason, "s"),
        delay_s=Estimate.unidentifiable(reason, "s"),
        driver_time_constant_s=Estimate.unidentifiable(reason, "s"),
    )


def _transient_deadband(
    transient: Sequence[WheelEpisode],
    deadband_value: float,
    identified: bool,
    flat: tuple[float, float],
    gains: tuple[float, float],
    odometry_period_s: float,
    timeout: float,
) -> tuple[np.ndarray, float, list[float]]:
    """The deadband the transients are fitted with, and their coarse grid of costs at it: the steady fit's where it
    is identified; else, since held commands that never came near the deadband leave a range of deadbands that fit
    them alike (whose middle is arbitrary and, put into the transients, bends the limit), the candidate within that
    range the transients fit best. Returns (coarse costs, the deadband, the candidates)."""
    candidates = [deadband_value]
    if not identified:
        candidates = [d for d in TRANSIENT_DEADBANDS_RADPS if flat[0] <= d <= flat[1]] or [flat[0]]
    coarse_by = []
    for candidate in candidates:
        args = (candidate, gains, odometry_period_s, timeout)
        coarse_by.append(
            np.sum(
                [
                    _transient_costs(e, *args, DELAYS_S, COARSE_ACCELS_RADPS2, shares=COARSE_MOTOR_SHARES)
                    for e in transient
                ],
                axis=0,
            )
        )
    chosen = int(np.argmin([float(c.min()) for c in coarse_by]))
    return coarse_by[chosen], candidates[chosen], candidates


def _fine_costs(
    transient: Sequence[WheelEpisode], coarse: np.ndarray, args: tuple[float, tuple[float, float], float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """The transients' costs on the fine grid of delays around the coarse grid's best (its largest limit among equal
    costs), every limit, lag and share: (delays, costs (episodes, delays, lags, shares, limits))."""
    i = int(np.unravel_index(int(np.argmin(coarse[..., ::-1])), coarse.shape)[0])
    lo_d, hi_d = DELAYS_S[max(i - 1, 0)], DELAYS_S[min(i + 1, len(DELAYS_S) - 1)]
    delays = np.round(np.arange(lo_d, hi_d + FINE_DELAY_STEP_S / 2, FINE_DELAY_STEP_S), 3)
    costs = np.stack([_transient_costs(e, *args, delays, ACCELS_RADPS2) for e in transient])
    return _fine_window(transient, args, delays, costs)


def _accel_estimate(
    costs: np.ndarray, best: np.ndarray, accel_draws: np.ndarray, n_free: int, n_episodes: int
) -> Estimate:
    """The acceleration limit at the grid's best point, unidentifiable where the best limit lowers the residual by
    less than MIN_LIMIT_GAIN against none (model mismatch, not a motor's limit)."""
    full = costs.sum(axis=0)[int(best[0]), int(best[1]), int(best[2])]
    followed = float(ACCELS_RADPS2[int(np.argmax(full <= full[-1]))])  # the least limit that never binds
    totals = costs.sum(axis=0)
    gain = 1.0 - float(totals.min()) / max(float(totals[..., -1].min()), 1e-300)
    if gain < MIN_LIMIT_GAIN:
        return Estimate.unidentifiable(
            f"no limit binds clearly: the best limit lowers the wheel-speed residual by {gain:.1%} against none "
            f"(needs {MIN_LIMIT_GAIN:.0%}), less than the simulator's single lag leaves unexplained",
            "rad/s^2",
        )
    return _accel(int(best[3]), accel_draws[:, 3], n_free, n_episodes, followed)


def estimate_motors(
    episodes: Sequence[WheelEpisode], odometry_period_s: float, settings: CalibrationSettings, rng: np.random.Generator
) -> MotorFit:
    """Deadband and acceleration limit of the wheel motors from the contact-free odometry of `episodes`."""
    used = [e for e in episodes if int(e.free.sum()) >= 3]
    if len(used) < MIN_EPISODES:
        reason = f"{counted(len(used), 'robot-episode')} with contact-free odometry; the fit needs {MIN_EPISODES}"
        return _unfitted(reason)
    moving = [e for e in used if np.any(np.abs(np.concatenate(_parts(e.commands.values), axis=1)) > MOVING_RADPS)]
    if len(moving) < MIN_EPISODES:
        reason = f"{len(moving)} robot-episodes commanded the wheels to turn; the robots must drive ({MIN_EPISODES})"
        return _unfitted(reason)
    timeout = settings.command_timeout_s
    steady = [_steady(e, odometry_period_s, timeout) for e in used]
    n_steady = sum(len(s.y) for s in steady)
    flat_lo, flat_hi, g_lin, g_ang = _steady_fit(steady, np.ones(len(used)))
    deadband_value = (flat_lo + flat_hi) / 2
    draws = bootstrap(lambda w: np.array(_steady_fit(steady, w)[:2]), len(used), settings.bootstrap, rng)
    commanded = np.abs(np.concatenate([s.a * g_lin + s.b * g_ang for s in steady]).ravel())
    deadband = _deadband(deadband_value, draws, commanded, n_steady, len(used))

    transient = used
    if len(used) > MAX_TRANSIENT_EPISODES:
        transient = [used[k] for k in np.linspace(0, len(used) - 1, MAX_TRANSIENT_EPISODES).round().astype(int)]
    gains = (g_lin, g_ang)
    coarse, transient_deadband, candidates = _transient_deadband(
        transient, deadband_value, deadband.ok, (flat_lo, flat_hi), gains, odometry_period_s, timeout
    )
    args = (transient_deadband, gains, odometry_period_s, timeout)
    delays, costs = _fine_costs(transient, coarse, args)
    shape = costs.shape[1:]

    def solve(weights: np.ndarray) -> np.ndarray:
        """Grid indices of the least cost; among equal costs the largest limit (one that never binds ties with
        none), so "no limit" wins unless a limit explains the data better."""
        total = np.tensordot(weights, costs, axes=([0], [0]))[..., ::-1]
        d, lag, share, a = np.unravel_index(int(np.argmin(total)), shape)
        return np.array([d, lag, share, shape[3] - 1 - a], dtype=float)

    best = solve(np.ones(len(transient)))
    accel_draws = bootstrap(solve, len(transient), settings.bootstrap, rng)
    n_free = sum(int(e.free.sum()) for e in transient)
    accel = _accel_estimate(costs, best, accel_draws, n_free, len(transient))
    d, lag, share = delays[int(best[0])], LAGS_S[int(best[1])], MOTOR_SHARES[int(best[2])]
    motor = _motor_lag(best, accel_draws, n_free, len(transient))
    delay, driver = _driver(best, accel_draws, delays, n_free, len(transient), motor)
    refined_note = ""
    if motor.ok and driver.ok:
        limit = float(ACCELS_RADPS2[int(best[3])]) if accel.ok else math.inf
        samples = [_samples(e, (g_lin, g_ang), odometry_period_s, timeout) for e in transient]
        start = (float(d), float(driver.value or 0.0), float(motor.value or 0.0), limit)
        refined = _refine(samples, transient_deadband, start)
        delay, driver, motor = _refined_estimates(refined, delay, driver, motor, n_free, settings, rng)
        refined_note = (
            f"; between the grid's values (least squares): delay {delay.value:.3f} s, driver lag "
            f"{driver.value:.3f} s, motors' lag {motor.value:.3f} s"
            if motor.ok
            else f"; {motor.reason}"
        )
    notes = (
        f"motors: {counted(len(used), 'robot-episode')}; {n_steady} steady samples give the deadband and the wheel "
        "chain's "
        f"gains {g_lin:.3f} (linear), {g_ang:.3f} (angular); {n_free} samples of {len(transient)} of them give "
        f"delay {d:.2f} s, total lag {lag:.3f} s ({share:.0%} after the limit)"
        + (
            f"; deadband for them {transient_deadband:g} rad/s, the best of {', '.join(f'{c:g}' for c in candidates)}"
            if len(candidates) > 1
            else ""
        )
        + refined_note,
    )
    return MotorFit(deadband, accel, (g_lin, g_ang), notes, motor, delay, driver)


def _refined_estimates(
    r: _Refined,
    grid_delay: Estimate,
    grid_driver: Estimate,
    grid_motor: Estimate,
    n: int,
    settings: CalibrationSettings,
    rng: np.random.Generator,
) -> tuple[Estimate, Estimate, Estimate]:
    """The delay and the lags of the refinement: its values, and intervals that hold both the one-step bootstrap's
    (:func:`_refined_draw`; the lags' widened by the small-sample factor) and the grid's, stretched to hold the
    value: the refinement moves the point off the grid, the grid's intervals already allow for a chain that is not
    exactly the robot's."""
    episodes = len(r.normal)
    draws = bootstrap(lambda w: _refined_draw(r, w), episodes, settings.bootstrap, rng)
    good = draws[np.all(np.isfinite(draws), axis=1)]
    if len(good) < 0.9 * len(draws):
        reason = (
            f"the driver's and the motors' lags trade freely: {len(draws) - len(good)} of {len(draws)} bootstrap "
            "draws leave them unseparated; they are part of effective.drive_lag_s"
        )
        return grid_delay, Estimate.unidentifiable(reason, "s"), Estimate.unidentifiable(reason, "s")
    values = (float(r.values[0]), math.exp(r.values[1]), math.exp(r.values[2]))
    out = []
    for column, (v, grid) in enumerate(zip(values, (grid_delay, grid_driver, grid_motor), strict=True)):
        lo, hi = (float(x) for x in np.percentile(good[:, column], [2.5, 97.5]))
        if column:
            lo, hi = _widened(v, lo, hi, episodes)
        grid_lo, grid_hi = grid.interval or (v, v)
        lo, hi = min(lo, grid_lo, v), max(hi, grid_hi, v)
        method = (
            f"{grid.method}; then least squares between the grid's values, the interval also holding a one-step "
            f"bootstrap's about it"
        )
        out.append((Estimate.of(v, float(np.std(good[:, column], ddof=1)), (lo, hi), "s", method, n), (lo, hi)))
    (delay, _), (driver, _), (motor, (lo, hi)) = out
    if hi > MOTOR_LAG_MAX_SPREAD * lo:
        reason = _unseparated(lo, hi)
        return delay, Estimate.unidentifiable(reason, "s"), Estimate.unidentifiable(reason, "s")
    return delay, driver, motor


def _interval(indices: np.ndarray, grid: np.ndarray, steps: float = 0.5) -> tuple[float, float]:
    """Percentile interval of bootstrap grid indices, widened by `steps` grid steps on each side."""
    lo_f, hi_f = np.percentile(indices, [2.5, 97.5])
    lo_i, hi_i = math.floor(lo_f), math.ceil(hi_f)
    step_lo = (grid[lo_i] - grid[lo_i - 1]) * steps if lo_i > 0 else 0.0
    step_hi = (grid[hi_i + 1] - grid[hi_i]) * steps if hi_i + 1 < len(grid) else 0.0
    return float(max(grid[lo_i] - step_lo, 0.0)), float(grid[hi_i] + step_hi)


def _deadband(value: float, draws: np.ndarray, commanded: np.ndarray, n: int, episodes: int) -> Estimate:
    top = float(DEADBANDS_RADPS[-1])
    below = int(np.sum((commanded > MOVING_RADPS) & (commanded < top)))
    if below < MIN_BELOW_SAMPLES:
        return Estimate.unidentifiable(
            f"{below} steady samples commanded a wheel between {MOVING_RADPS:g} and {top:g} rad/s; a deadband "
            f"shows only there (needs {MIN_BELOW_SAMPLES})",
            "rad/s",
        )
    good = draws[np.all(np.isfinite(draws), axis=1)]
    step = float(DEADBANDS_RADPS[1] - DEADBANDS_RADPS[0])
    # a deadband between two grid values fits as well as either: one grid step more on each side
    lo = max(float(np.percentile(good[:, 0], 2.5)) - step, 0.0) if len(good) else 0.0
    hi = float(np.percentile(good[:, 1], 97.5)) + step if len(good) else top
    if value >= top or hi > top:
        return Estimate.unidentifiable(
            f"the fit reaches the largest deadband tried ({top:g} rad/s): the wheels hardly follow small commands",
            "rad/s",
        )
    se = float(np.std(good.mean(axis=1), ddof=1)) if len(good) > 1 else None
    method = (
        "steady wheel speeds under held commands: grid over the deadband, gains by least squares; bootstrap over "
        f"{episodes} robot-episodes"
    )
    return Estimate.of(value, se, (lo, hi), "rad/s", method, n)


def small_sample_factor(clusters: int) -> float:
    """How much wider (on a log scale, about the estimate) a 95 % interval from `clusters` robot-episodes must be than
    the bootstrap's percentiles: sqrt(G / (G - 1)) t(0.975, G - 1) / z(0.975), the correction the wheels' t
    interval makes (1.22 for the 10 robot-episodes the transients use; without it the motors' lag interval covered
    the truth on 77 % and 83 % of the coverage benchmark's robots, policy and calibration drive)."""
    if clusters < 2:
        return math.inf
    return math.sqrt(clusters / (clusters - 1)) * float(stats.t.ppf(0.975, clusters - 1) / stats.norm.ppf(0.975))


def _widened(value: float, lo: float, hi: float, clusters: int) -> tuple[float, float]:
    """(lo, hi) stretched to hold `value` and, about a positive `value`, each side's log distance stretched by
    :func:`small_sample_factor`."""
    lo, hi = min(lo, value), max(hi, value)
    f = small_sample_factor(clusters)
    if value <= 0:
        return lo, hi
    low = value * (lo / value) ** f if lo > 0 and math.isfinite(f) else 0.0
    return min(low, lo), max(value * (hi / value) ** f if math.isfinite(f) else math.inf, hi)


def _motor_lag(best: np.ndarray, draws: np.ndarray, n: int, episodes: int) -> Estimate:
    """The motor's lag, share x total lag of the transients' grid: its bootstrap values' percentiles, widened by half
    a share step of the total lag on each side (the grid's resolution) and by the small-sample factor of the
    robot-episodes (:func:`small_sample_factor`). Unidentifiable where the draws span every share tried, or the
    interval a factor of `MOTOR_LAG_MAX_SPREAD`: the transients do not tell the motor's lag from the driver's."""
    good = draws[np.all(np.isfinite(draws[:, 1:3]), axis=1)]
    if len(good) < 2:
        return Estimate.unidentifiable("too few transients for a bootstrap", "s")
    lags = LAGS_S[good[:, 1].astype(int)]
    shares = MOTOR_SHARES[good[:, 2].astype(int)]
    spread = np.unique(good[:, 2].astype(int))
    if len(spread) == len(MOTOR_SHARES) or (spread.min() == 0 and spread.max() == len(MOTOR_SHARES) - 1):
        return Estimate.unidentifiable(
            "the transients fit every share of the lag between the driver and the motors alike: the motors' own lag "
            "is part of effective.drive_lag_s",
            "s",
        )
    value = float(LAGS_S[int(best[1])] * MOTOR_SHARES[int(best[2])])
    motor = lags * shares
    half_step = float(MOTOR_SHARES[1] - MOTOR_SHARES[0]) / 2 * lags
    lo = max(float(np.percentile(motor - half_step, 2.5)), 0.0)
    hi = float(np.percentile(motor + half_step, 97.5))
    lo, hi = _widened(value, lo, hi, episodes)
    if hi > MOTOR_LAG_MAX_SPREAD * lo:
        return Estimate.unidentifiable(_unseparated(lo, hi), "s")
    method = (
        "transients of the wheel speeds: the motor's share of the total lag; bootstrap over "
        f"{episodes} robot-episodes, widened by half a share step and the small-sample factor "
        f"{small_sample_factor(episodes):.2f}"
    )
    return Estimate.of(value, float(np.std(motor, ddof=1)), (lo, hi), "s", method, n)


def _driver(
    best: np.ndarray, draws: np.ndarray, delays: np.ndarray, n: int, episodes: int, motor: Estimate
) -> tuple[Estimate, Estimate]:
    """The driver's delay and lag from the transients' grid (bootstrap percentiles widened by a delay step, the lag
    by half a grid step and the small-sample factor); its lag is the total less the motors' share, unidentifiable
    where the motors' lag is."""
    good = draws[np.all(np.isfinite(draws[:, :3]), axis=1)]
    method = (
        f"transients of the wheel speeds: grid over delay, lag, the motor's share and the limit; bootstrap over "
        f"{episodes} robot-episodes, the delay widened by a grid step, the lag by half of one"
    )
    if len(good) < 2:
        reason = "too few transients for a bootstrap"
        return Estimate.unidentifiable(reason, "s"), Estimate.unidentifiable(reason, "s")
    step = float(DELAYS_S[1] - DELAYS_S[0])
    d_draws = delays[good[:, 0].astype(int)]
    d_value = float(delays[int(best[0])])
    # a delay between two grid values fits as well as either (the deadband's and the limit's grids bend the
    # transients the same way): one grid step more on each side, as for the deadband
    d_lo = max(float(np.percentile(d_draws, 2.5)) - step, 0.0)
    d_hi = float(np.percentile(d_draws, 97.5)) + step
    delay = Estimate.of(d_value, float(np.std(d_draws, ddof=1)), (d_lo, d_hi), "s", method, n)
    if not motor.ok:
        return delay, Estimate.unidentifiable(motor.reason, "s")
    lags = LAGS_S[good[:, 1].astype(int)]
    shares = MOTOR_SHARES[good[:, 2].astype(int)]
    own = lags * (1 - shares)
    ratio = float(LAGS_S[1] / LAGS_S[0])
    half = (MOTOR_SHARES[1] - MOTOR_SHARES[0]) / 2 * lags + own * (math.sqrt(ratio) - 1)
    value = float(LAGS_S[int(best[1])] * (1 - MOTOR_SHARES[int(best[2])]))
    lo = max(float(np.percentile(own - half, 2.5)), 0.0)
    hi = float(np.percentile(own + half, 97.5))
    lo, hi = _widened(value, lo, hi, episodes)
    lag = Estimate.of(value, float(np.std(own, ddof=1)), (lo, hi), "s", method, n)
    return delay, lag


def _accel(best: int, draws: np.ndarray, n: int, episodes: int, followed: float) -> Estimate:
    idx = draws[np.isfinite(draws)].astype(int)
    unlimited = len(ACCELS_RADPS2) - 1
    if best == unlimited or len(idx) == 0 or np.mean(idx == unlimited) > 0.025:
        bound = f"above {followed:.0f} rad/s^2" if math.isfinite(followed) else "above the largest tried"
        return Estimate.unidentifiable(
            f"no limit binds in the recording: the wheels followed every commanded change (a limit, if any, lies "
            f"{bound})",
            "rad/s^2",
        )
    # a whole grid step: the chain is simulated in steps of STEP_S, which moves the limit that fits best by about one
    lo, hi = _interval(idx.astype(float), ACCELS_RADPS2[:-1], steps=1.0)
    value = float(ACCELS_RADPS2[best])
    se = float(value * np.std(np.log(ACCELS_RADPS2[idx]), ddof=1)) if len(idx) > 1 else None
    method = (
        f"transients of the wheel speeds: grid over delay, lag, the motor's share and the limit; bootstrap over "
        f"{episodes} robot-episodes"
    )
    return Estimate.of(value, se, (lo, hi), "rad/s^2", method, n)
