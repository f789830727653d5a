"""True wheel radii (left, right) and wheel separation of a differential drive from its odometry vs ground truth.

A robot's driver integrates encoder ticks with the NOMINAL wheel radius r_nom and separation b_nom,
so over a chunk of `CHUNK_S` seconds the odometry's forward distance ds_o and turn dth_o give the
nominal wheel travels dL = ds_o - dth_o b_nom / 2 and dR = ds_o + dth_o b_nom / 2. With the true
radii rL = kL r_nom, rR = kR r_nom and separation b the base truly moves

    ds_t = (kL dL + kR dR) / 2        dth_t = (kR dR - kL dL) / b

and the fit finds (kL, kR, 1 / b) by least squares over all chunks, the turn residuals weighted by
b_nom / 2 so that both residuals are metres of wheel travel (Gauss-Newton from the linear solution
of the distance equation; the problem is linear in (kL, kR) for a given 1 / b).

Chunk sums, as in :mod:`pipeline.calibration.odometry`: the odometry's wheel travels add up its
increments between messages (exact for a driver that integrates with the midpoint rule), the
truth's motion comes from the chunk's two end poses only (the turn summed over wrapped steps, the
distance the chord along the mean heading divided by sinc(dth_t / 2), the arc of constant curvature
through both ends, plus what that arc misses of the odometry's own path where the curvature changes
within the chunk), so errors of the smoothed truth enter at the chunk's ends and do not pile up.
No chunk spans a gap in the truth or a jump of the odometry.

The model is not exact: wheels slip on a floor of finite friction, robots bump into things, the
truth is smoothed. Bursts of slip (a wheel spinning up, a robot pushing a wall) are outliers: chunks
whose residual exceeds `SLIP_CUT` robust spreads (the spread never below `MIN_SLIP_SCALE_M`) are
left out and the fit repeated until the chunks kept settle, so they do not drag it. What remains is
noise shared by the chunks of one robot in one episode (its floor, speeds and errors), so the
uncertainties treat those as a cluster: the standard error is the largest of the cluster-robust
sandwich, the cluster bootstrap's and the leave-one-cluster-out jackknife's (the first two scaled
by G / (G - 1)), and the 95 % interval is the t interval with G - 1 degrees of freedom, G the
number of robot-episodes. So it shrinks with the number of robot-episodes, not of chunks, and grows
with what the model cannot explain between robot-episodes. What it cannot explain within them shows
as estimates that depend on how the robot drove: the fit is repeated on the slower and the faster
half of the chunks, and on the straighter and the more turning half, and where the halves disagree
by more than their own errors allow, the excess counts as a random effect of the driving conditions:
the between-condition variance tau^2 (DerSimonian and Laird's estimator, the largest over the two
splits) is added to the squared standard error, se^2 + tau^2: where the truth lies among the
conditions is not known, so the pooled estimate may be off by as much as one condition's effect (on
the twin, slip and the encoders' ticks bias slow chunks one way and fast ones the other by about
1 %). Slip that biases every chunk
alike, whatever its speed or turn, is indistinguishable from another geometry and is not in the
interval.

Separating the three needs wheel travels that are not always in the same ratio: forward driving and
turning in varying proportion (straight runs and turns on the spot, or arcs of several curvatures).
Driving along one curvature only determines two combinations of the three values.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from pipeline.calibration.estimates import Estimate, bootstrap, counted, spread
from pipeline.calibration.odometry import CHUNK_S, OdometryEpisode, chunk_bounds, continuous_stretches, pose_increments
from pipeline.calibration.options import CalibrationSettings
from pipeline.core.scenario import SPARK_WHEEL_RADIUS_M, SPARK_WHEEL_SEPARATION_M

NOMINAL_WHEEL_RADIUS_M = SPARK_WHEEL_RADIUS_M
NOMINAL_WHEEL_SEPARATION_M = SPARK_WHEEL_SEPARATION_M
"""The geometry the robots' drivers integrate their encoders with (the SPARK's, as the twin's profile states)."""

MIN_CLUSTERS = 3
"""Robot-episodes needed: the intervals rest on the spread between them."""
MIN_CHUNKS = 20
"""Chunks of `CHUNK_S` seconds needed in all."""
MIN_DISTANCE_M = 1.0
"""Total forward wheel travel (mean of both wheels, m) needed to tell the radii from slip."""
MIN_TURN_RAD = math.pi
"""Total turning (rad) needed to separate the wheel separation from the ratio of the radii."""
MIN_INDEPENDENCE = 0.05
"""Smallest share of the turning not explained by forward driving in a fixed ratio (1 - squared cosine)."""
SLIP_CUT = 8.0
"""Chunks whose residual exceeds this many robust spreads are left out (slip bursts, collisions)."""
MIN_SLIP_SCALE_M = 1e-4
"""Floor of the robust spread of the residuals per chunk (m): about one encoder tick of wheel travel."""
RAYLEIGH_MEDIAN = math.sqrt(2 * math.log(2))
"""Median of the length of a 2D standard normal vector: the spread from the median residual length."""
ROBUST_ITERATIONS = 20
GAUSS_NEWTON_ITERATIONS = 50
TOLERANCE = 1e-9
"""Gauss-Newton stops when no parameter moves more than this (relative)."""
_TURN_SIGN = np.array([[1.0, -1.0], [-1.0, 1.0]])
"""Turns (dR - dL) in terms of (dL, dR): the outer product of (-1, 1) with itself."""
_SPIN = np.array([-1.0, 1.0])


@dataclass(frozen=True)
class WheelFit:
    """The true wheel radii and separation (m), each an Estimate, what the data were, and the arc they make."""

    radius_left_m: Estimate
    radius_right_m: Estimate
    separation_m: Estimate
    notes: tuple[str, ...] = ()
    arc_per_m: Estimate = field(default_factory=lambda: Estimate.unidentifiable("not estimated", "rad/m"))
    """The turn per metre the unequal wheels put into a straight command, with an interval of its own: the
    radii's errors are mostly common to both wheels and cancel in it."""


@dataclass(frozen=True)
class WheelChunks:
    """Per chunk of one robot-episode: nominal wheel travels `travel` (n, 2) (dL, dR m) from odometry,
    and the true forward distance `distance_m` (n,) (m, arc length) and turn `turn_rad` (n,) (rad)."""

    label: str
    travel: np.ndarray
    distance_m: np.ndarray
    turn_rad: np.ndarray


@dataclass(frozen=True)
class _Moments:
    """Weighted sums over chunks, per cluster (leading axis) or in all: z z^T (2, 2), ds_t z (2,), dth_t z (2,),
    z = (dL, dR)."""

    zz: np.ndarray
    zd: np.ndarray
    zt: np.ndarray

    def weighted(self, counts: np.ndarray) -> _Moments:
        """The clusters' sums with cluster c counted counts[c] times."""
        w = np.asarray(counts, dtype=np.float64)
        return _Moments(
            np.einsum("c,cij->ij", w, self.zz), np.einsum("c,ci->i", w, self.zd), np.einsum("c,ci->i", w, self.zt)
        )

    def cluster(self, c: int) -> _Moments:
        return _Moments(self.zz[c], self.zd[c], self.zt[c])


def _sinc_half(turn_rad: np.ndarray) -> np.ndarray:
    """sin(x / 2) / (x / 2): the chord of an arc turning by x over its length."""
    return np.asarray(np.sinc(turn_rad / (2 * math.pi)))


def wheel_chunks(episode: OdometryEpisode, nominal_separation_m: float = NOMINAL_WHEEL_SEPARATION_M) -> WheelChunks:
    """The chunks of one robot-episode (see the module's description); none spans a gap or a jump."""
    if len(episode.t_ns) < 2:
        return WheelChunks(episode.label, np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    a, b = chunk_bounds(episode.t_ns, continuous_stretches(episode))
    forward, left, turn_o = pose_increments(episode.odom)
    # the driver moved ds along the mean heading of each step: forward = ds cos(dth/2), left = ds sin(dth/2)
    step_ds = forward * np.cos(turn_o / 2) + left * np.sin(turn_o / 2)
    _, _, turn_t = pose_increments(episode.truth)
    cum_ds = np.r_[0.0, np.cumsum(step_ds)]
    cum_to = np.r_[0.0, np.cumsum(turn_o)]
    cum_tt = np.r_[0.0, np.cumsum(turn_t)]
    ds_o = cum_ds[b] - cum_ds[a]
    dth_o = cum_to[b] - cum_to[a]
    dth_t = cum_tt[b] - cum_tt[a]
    travel = np.stack([ds_o - dth_o * nominal_separation_m / 2, ds_o + dth_o * nominal_separation_m / 2], axis=1)
    # the arc through both ends misses where the curvature changes within the chunk: by what it misses in the odometry
    missed = ds_o - _chord(episode.odom, a, b, dth_o) / _sinc_half(dth_o)
    ds_t = _chord(episode.truth, a, b, dth_t) / _sinc_half(dth_t) + missed
    return WheelChunks(episode.label, travel, ds_t, dth_t)


def _chord(pose: np.ndarray, a: np.ndarray, b: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """Displacement (m) from poses a to poses b along the mean heading (the heading at a plus half the turn)."""
    heading = pose[a, 2] + turn / 2
    d = pose[b, :2] - pose[a, :2]
    return np.asarray(np.cos(heading) * d[:, 0] + np.sin(heading) * d[:, 1])


def _moments(chunks: Sequence[WheelChunks], weights: Sequence[np.ndarray]) -> _Moments:
    """Per-cluster weighted sums (len(chunks), ...) of the chunks' products."""
    zz = np.stack([(c.travel * w[:, None]).T @ c.travel for c, w in zip(chunks, weights, strict=True)])
    zd = np.stack([c.travel.T @ (w * c.distance_m) for c, w in zip(chunks, weights, strict=True)])
    zt = np.stack([c.travel.T @ (w * c.turn_rad) for c, w in zip(chunks, weights, strict=True)])
    return _Moments(zz, zd, zt)


def _predicted(chunks: WheelChunks, theta: np.ndarray) -> np.ndarray:
    """(n, 2) the true distance (m) and turn (rad) the geometry theta = (kL, kR, 1/b) gives the chunks' wheel
    travels."""
    k, beta = theta[:2], theta[2]
    return np.stack([chunks.travel @ k / 2, beta * (chunks.travel * _SPIN) @ k], axis=1)


def _residuals(chunks: WheelChunks, theta: np.ndarray, weight: float) -> np.ndarray:
    """(n, 2) residuals of the chunks at theta = (kL, kR, 1/b): distance (m) and `weight` times turn (rad)."""
    residual = np.stack([chunks.distance_m, chunks.turn_rad], axis=1) - _predicted(chunks, theta)
    return np.asarray(residual * np.array([1.0, weight]))


def _normal_equations(m: _Moments, theta: np.ndarray, weight: float) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton matrix J^T J (3, 3) and gradient J^T r (3,) of the weighted residuals at theta = (kL, kR, 1/b).

    Residuals per chunk: ds_t - k . z / 2 and weight (dth_t - beta k . (-dL, dR)); `m` holds one
    cluster's sums or all of them.
    """
    k, beta = theta[:2], theta[2]
    a = m.zz / 4
    c = m.zz * _TURN_SIGN
    u = m.zd / 2
    v = m.zt * _SPIN
    w2 = weight * weight
    ck = c @ k
    jtj = np.empty((3, 3))
    jtj[:2, :2] = a + w2 * beta * beta * c
    jtj[:2, 2] = jtj[2, :2] = w2 * beta * ck
    jtj[2, 2] = w2 * float(k @ ck)
    grad = np.empty(3)
    grad[:2] = -(u - a @ k) - w2 * beta * (v - beta * ck)
    grad[2] = -w2 * (float(k @ v) - beta * float(k @ ck))
    return jtj, grad


def _solve(m: _Moments, weight: float, start: np.ndarray | None = None) -> np.ndarray:
    """(kL, kR, 1/b) minimising the weighted squared residuals for the summed moments `m`.

    Gauss-Newton from `start`, or from the distance equation's linear solution. Raises
    np.linalg.LinAlgError where the sums do not determine them.
    """
    if start is None:
        k = np.linalg.solve(m.zz / 4, m.zd / 2)
        beta = float(k @ (m.zt * _SPIN)) / float(k @ (m.zz * _TURN_SIGN) @ k)
        theta = np.array([k[0], k[1], beta])
    else:
        theta = np.array(start, dtype=np.float64)
    for _ in range(GAUSS_NEWTON_ITERATIONS):
        jtj, grad = _normal_equations(m, theta, weight)
        step = np.linalg.solve(jtj, -grad)
        theta = theta + step
        if np.all(np.abs(step) <= TOLERANCE * np.maximum(np.abs(theta), 1e-12)):
            break
    if not np.all(np.isfinite(theta)) or not np.all(theta > 0):
        raise np.linalg.LinAlgError("no positive radii and separation fit the data")
    return theta


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The value below which half the weight lies (1.0 where there is no weight)."""
    if not np.any(weights > 0):
        return 1.0
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, cum[-1] / 2)])


def _own_scale_residuals(chunks: WheelChunks, theta: np.ndarray, weight: float, kept: np.ndarray) -> np.ndarray:
    """(n,) lengths of the chunks' residuals about the fit at theta after the robot-episode's own scale of distance
    and of turn (the median ratio of measured to predicted over its kept chunks, each weighted by its predicted
    motion): the residuals a slip burst or a push leaves within its episode, not the per-episode scale errors of the
    odometry that every chunk of the episode shares."""
    predicted = _predicted(chunks, theta)
    measured = np.stack([chunks.distance_m, chunks.turn_rad], axis=1)
    size = np.abs(predicted)
    ratio = measured / np.where(size > 0, predicted, 1.0)
    own = np.array([_weighted_median(ratio[:, j], kept * size[:, j]) for j in range(2)])
    residual = measured - own * predicted
    return np.asarray(np.hypot(residual[:, 0], weight * residual[:, 1]))


def _robust_fit(chunks: Sequence[WheelChunks], weight: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """theta = (kL, kR, 1/b) by least squares without the slip bursts, and the chunks' weights (1 kept, 0 left out).

    A burst is told by its residual within its robot-episode (see :func:`_own_scale_residuals`): an episode whose
    odometry reads a few per cent long or short is not slip, and cutting its fast chunks would take the spread
    between episodes (what the intervals rest on) out of the data."""
    weights = [np.ones(len(c.distance_m)) for c in chunks]
    theta = _solve(_moments(chunks, weights).weighted(np.ones(len(chunks))), weight)
    for _ in range(ROBUST_ITERATIONS):
        lengths = [_own_scale_residuals(c, theta, weight, w) for c, w in zip(chunks, weights, strict=True)]
        moving = np.concatenate([np.any(c.travel != 0.0, axis=1) for c in chunks])
        scale = max(float(np.median(np.concatenate(lengths)[moving])) / RAYLEIGH_MEDIAN, MIN_SLIP_SCALE_M)
        new = [(e <= SLIP_CUT * scale).astype(np.float64) for e in lengths]
        theta = _solve(_moments(chunks, new).weighted(np.ones(len(chunks))), weight, theta)
        settled = all(np.allclose(w, v, rtol=0.0, atol=1e-6) for w, v in zip(weights, new, strict=True))
        weights = new
        if settled:
            break
    return theta, weights


def _geometry(theta: np.ndarray, nominal_radius_m: float) -> np.ndarray:
    """(rL m, rR m, b m, arc rad/m) from (kL, kR, 1/b): the arc is the turn per metre that the unequal wheels put
    into a straight command, (rR - rL) / (r_nominal b) = (kR - kL) / b."""
    return np.array(
        [theta[0] * nominal_radius_m, theta[1] * nominal_radius_m, 1.0 / theta[2], (theta[1] - theta[0]) * theta[2]]
    )


def _sandwich_se(clusters: _Moments, theta: np.ndarray, weight: float, nominal_radius_m: float) -> np.ndarray:
    """Cluster-robust standard errors (3,) of (rL m, rR m, b m), with the G / (G - 1) small-sample factor."""
    g = len(clusters.zz)
    jtj, _ = _normal_equations(clusters.weighted(np.ones(g)), theta, weight)
    scores = np.stack([_normal_equations(clusters.cluster(c), theta, weight)[1] for c in range(g)])
    bread = np.linalg.inv(jtj)
    cov = bread @ (scores.T @ scores) @ bread * g / (g - 1)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return np.array([se[0] * nominal_radius_m, se[1] * nominal_radius_m, se[2] / theta[2] ** 2])


def _fit_with_errors(
    chunks: Sequence[WheelChunks],
    weights: Sequence[np.ndarray],
    weight: float,
    start: np.ndarray,
    nominal_radius_m: float,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Geometry (3,) of the chunks with the given weights and its jackknife standard errors over robot-episodes
    (None where the weighted chunks do not determine it)."""
    clusters = _moments(chunks, weights)
    g = len(chunks)
    try:
        value = _geometry(_solve(clusters.weighted(np.ones(g)), weight, start), nominal_radius_m)
        left_out = np.array(
            [_geometry(_solve(clusters.weighted(np.arange(g) != c), weight, start), nominal_radius_m) for c in range(g)]
        )
    except np.linalg.LinAlgError:
        return None
    return value, np.sqrt((g - 1) / g * np.sum((left_out - left_out.mean(axis=0)) ** 2, axis=0))


def between_condition_variance(values: np.ndarray, errors: np.ndarray) -> np.ndarray:
    """DerSimonian-Laird between-group variance (per column) of estimates `values` (k, p) with standard errors
    `errors` (k, p): what their spread holds beyond their own errors (0 where it holds nothing more)."""
    w = 1.0 / np.maximum(errors, 1e-300) ** 2
    mean = np.sum(w * values, axis=0) / np.sum(w, axis=0)
    q = np.sum(w * (values - mean) ** 2, axis=0)
    scale = np.sum(w, axis=0) - np.sum(w * w, axis=0) / np.sum(w, axis=0)
    return np.asarray(np.maximum(q - (len(values) - 1), 0.0) / scale)


def _condition_variance(
    chunks: Sequence[WheelChunks], weights: Sequence[np.ndarray], weight: float, theta: np.ndarray, r_nom: float
) -> tuple[np.ndarray, list[str]]:
    """The largest between-condition variance (3,) over the splits by speed and by turning, and what each split read."""
    travel = np.concatenate([c.travel for c in chunks])
    kept = np.concatenate(weights) > 0
    speed = np.abs(travel.mean(axis=1))
    turning = np.abs(travel @ _SPIN) / np.maximum(np.abs(travel).sum(axis=1), 1e-12)
    sizes = np.cumsum([0] + [len(c.distance_m) for c in chunks])
    worst = np.zeros(4)
    notes: list[str] = []
    for name, key in (("speed", speed), ("turning", turning)):
        cut = float(np.median(key[kept & (speed > 0)])) if np.any(kept & (speed > 0)) else 0.0
        halves = []
        for side in (key < cut, key >= cut):
            w = [weights[i] * side[sizes[i] : sizes[i + 1]] for i in range(len(chunks))]
            fitted = _fit_with_errors(chunks, w, weight, theta, r_nom)
            if fitted is not None and np.all(np.isfinite(fitted[1])) and np.all(fitted[1] > 0):
                halves.append(fitted)
        if len(halves) < 2:
            notes.append(f"the {name} halves could not be fitted apart")
            continue
        values, errors = np.stack([h[0] for h in halves]), np.stack([h[1] for h in halves])
        tau2 = between_condition_variance(values, errors)
        worst = np.maximum(worst, tau2)
        notes.append(
            f"{name} halves read {values[0, 0] * 1e3:.2f} / {values[1, 0] * 1e3:.2f}, {values[0, 1] * 1e3:.2f} / "
            f"{values[1, 1] * 1e3:.2f}, {values[0, 2] * 1e3:.1f} / {values[1, 2] * 1e3:.1f} mm"
        )
    return worst, notes


def _problems(chunks: Sequence[WheelChunks], nominal_separation_m: float) -> list[str]:
    """Why the data cannot determine the three values (empty: they can)."""
    problems: list[str] = []
    g = len(chunks)
    n = sum(len(c.distance_m) for c in chunks)
    if g < MIN_CLUSTERS:
        problems.append(
            f"only {counted(g, 'robot-episode')} with motion (need {MIN_CLUSTERS}): the intervals rest on the spread "
            "between them"
        )
    if n < MIN_CHUNKS:
        problems.append(f"only {n} chunks of {CHUNK_S:g} s (need {MIN_CHUNKS})")
    if n == 0:
        return problems
    travel = np.concatenate([c.travel for c in chunks])
    forward = travel.mean(axis=1)
    spin = (travel[:, 1] - travel[:, 0]) / 2
    distance = float(np.abs(forward).sum())
    turned = float(np.abs(spin).sum()) * 2 / nominal_separation_m
    if distance < MIN_DISTANCE_M:
        problems.append(f"the robots drove only {distance:.2f} m (need {MIN_DISTANCE_M:g} m)")
    if turned < MIN_TURN_RAD:
        problems.append(
            f"the robots turned only {turned:.2f} rad in all (need {MIN_TURN_RAD:.2f} rad): too little turning "
            "to separate the wheel separation from the ratio of the wheel radii"
        )
    ff, ss, fs = float(forward @ forward), float(spin @ spin), float(forward @ spin)
    independence = 1.0 - fs * fs / (ff * ss) if ff > 0 and ss > 0 else 0.0
    if distance >= MIN_DISTANCE_M and turned >= MIN_TURN_RAD and independence < MIN_INDEPENDENCE:
        problems.append(
            f"driving and turning always came in the same proportion ({independence:.1%} independent, need "
            f"{MIN_INDEPENDENCE:.0%}): drive straight and turn on the spot, or along arcs of several curvatures, "
            "to separate the wheel radii from the separation"
        )
    return problems


def estimate_wheels(
    episodes: Sequence[OdometryEpisode],
    settings: CalibrationSettings,
    nominal_radius_m: float = NOMINAL_WHEEL_RADIUS_M,
    nominal_separation_m: float = NOMINAL_WHEEL_SEPARATION_M,
) -> WheelFit:
    """True wheel radii (left, right) and separation (m) of the robots, one geometry for all of them.

    Args:
        episodes: each robot's odometry and true poses in each episode; each is one cluster.
        settings: `bootstrap` resamples and the `seed` of the cluster bootstrap.
        nominal_radius_m, nominal_separation_m: the geometry the robots' drivers integrate with.
    """
    chunks = [wheel_chunks(e, nominal_separation_m) for e in episodes]
    chunks = [c for c in chunks if np.any(c.travel != 0.0)]
    g = len(chunks)
    n = sum(len(c.distance_m) for c in chunks)
    notes = [f"{counted(g, 'robot-episode')} with motion, {counted(n, 'chunk')} of {CHUNK_S:g} s"]
    problems = _problems(chunks, nominal_separation_m)
    weight = nominal_separation_m / 2
    fitted = None
    if not problems:
        try:
            fitted = _robust_fit(chunks, weight)
        except np.linalg.LinAlgError:
            problems.append("the least-squares fit found no positive radii and separation")
    if fitted is None:
        unknown = Estimate.unidentifiable("; ".join(problems), "m", n)
        return WheelFit(unknown, unknown, unknown, tuple(notes), Estimate.unidentifiable(unknown.reason, "rad/m", n))
    theta, weights = fitted
    clusters = _moments(chunks, weights)
    value = _geometry(theta, nominal_radius_m)

    def statistic(counts: np.ndarray) -> np.ndarray:
        try:
            return _geometry(_solve(clusters.weighted(counts), weight, theta), nominal_radius_m)
        except np.linalg.LinAlgError:
            return np.full(4, np.nan)

    samples = bootstrap(statistic, g, settings.bootstrap, np.random.default_rng(settings.seed))
    left_out = np.array([statistic(np.arange(g) != c) for c in range(g)])
    jackknife = np.sqrt((g - 1) / g * np.sum((left_out - left_out.mean(axis=0)) ** 2, axis=0))
    sandwich = _sandwich_se(clusters, theta, weight, nominal_radius_m)
    small = math.sqrt(g / (g - 1))
    t = float(stats.t.ppf(0.975, g - 1))
    residuals = np.concatenate([_residuals(c, theta, weight) for c in chunks])
    w = np.concatenate(weights)
    rms = np.sqrt(np.sum(w[:, None] * residuals**2, axis=0) / max(float(w.sum()), 1e-12))
    travel = np.concatenate([c.travel for c in chunks])
    notes.append(
        f"drove {float(np.abs(travel.mean(axis=1)).sum()):.1f} m, turned "
        f"{float(np.abs(travel @ _SPIN).sum()) / nominal_separation_m:.1f} rad; weighted rms residual per chunk "
        f"{rms[0]:.2g} m, {rms[1] / weight:.2g} rad; {counted(int(np.sum(w == 0.0)), 'chunk')} left out as slip"
    )
    tau2, split_notes = _condition_variance(chunks, weights, weight, theta, nominal_radius_m)
    notes += split_notes
    notes.append(
        "between conditions: "
        + ", ".join(
            f"{name} {math.sqrt(v) * 1e3:.3f} mm"
            for name, v in zip(("left", "right", "separation"), tau2[:3], strict=True)
        )
        + f", arc {math.sqrt(tau2[3]):.4f} rad/m"
    )
    failed = int(np.sum(~np.all(np.isfinite(samples), axis=1)))
    if failed:
        notes.append(f"{failed} of {settings.bootstrap} bootstrap resamples could not be fitted")
    method = (
        f"least squares over {n} chunks less slip bursts; largest of the cluster-robust sandwich, "
        f"cluster bootstrap ({settings.bootstrap} resamples) and jackknife standard errors over {g} robot-episodes, "
        f"t interval ({g - 1} dof), widened by the variance between slow and fast, straight and turning chunks"
    )
    out: list[Estimate] = []
    for j in range(4):
        boot_se, _ = spread(samples[:, j])
        candidates = [float(sandwich[j]) if j < 3 else math.nan, boot_se * small, float(jackknife[j])]
        se = math.sqrt(max(x for x in candidates if math.isfinite(x)) ** 2 + float(tau2[j]))
        x = float(value[j])
        out.append(Estimate.of(x, se, (x - t * se, x + t * se), "m" if j < 3 else "rad/m", method, n))
    return WheelFit(out[0], out[1], out[2], tuple(notes), out[3])
