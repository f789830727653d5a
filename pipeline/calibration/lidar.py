"""Lidar noise, dropout probability, bias and mounting yaw from scans taken while robots stood still.

While a robot stands still its smoothed true pose is exact and the scan's timing does not matter,
so every beam can be compared with the range cast in the known map from that pose. Beams are used
only where the comparison is clean: the cast range lies well inside the sensor's limits, the beam
meets its surface at a moderate angle (not grazing), its angular neighbours hit the same surface
(no corners or box edges), and it passes no other robot.

1. Mounting yaw: a 1-D search over the offset added to every beam angle, minimising a robust
   (truncated absolute) cost of the residuals of the per-span mean scans, first on a coarse grid
   over the search range, then on a fine grid; then Gauss-Newton steps on yaw and bias with Huber
   weights. Its uncertainty comes from a bootstrap over the stationary spans.
2. Dropout probability: the share of usable beams without a valid return (+inf, NaN, or outside
   the scan's range limits).
3. Bias and noise sigma: mean and standard deviation of the residuals (measured - cast) of the
   valid returns after iterative 4-sigma clipping (corrected for the clipping).
Bias, sigma and dropout carry bootstrap uncertainties over stationary spans (clusters of scans
that share a pose) when there are at least `MIN_SPANS_FOR_BOOTSTRAP`, else the textbook standard
errors of independent beams.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from pipeline.calibration.estimates import Z_95, Estimate, binomial_estimate, bootstrap, normal_interval, spread
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.raycast import MapGeometry, cast_circles, wrap
from pipeline.calibration.smoothing import Track
from pipeline.core.timebase import NS_PER_S

MIN_SPANS_FOR_BOOTSTRAP = 5
MIN_BEAMS = 200
"""Fewer usable beams than this leave noise, bias and dropout unidentifiable."""
CLIP_SIGMAS = 4.0
COARSE_STEP_RAD = math.radians(0.5)
FINE_STEP_RAD = math.radians(0.02)
FINE_HALF_WIDTH_RAD = math.radians(0.75)
TRUNCATION_M = 0.25
"""Residuals count at most this much in the coarse yaw search's cost."""
MAX_YAW_STD_ERROR_RAD = 0.05
"""A mounting yaw less certain than this is reported unidentifiable."""
STILL_AVERAGE_S = 0.5
"""Smoothed velocities are averaged over this long before the stationarity thresholds apply."""
GAUSS_NEWTON_STEPS = 6
HUBER_K = 2.0
"""Huber weights down-weight span-mean residuals beyond this many robust standard deviations."""


@dataclass(frozen=True)
class ScanSpan:
    """The scans of one robot during one stationary span.

    `pose` (3,) x, y (m), yaw (rad) of the robot; `beam_angles_rad` (beams,) beam angles in the scan's
    frame as the scan message states them; `ranges` (n_scans, beams) as measured (m); `others`
    (n_scans, k, 2) the other robots' positions (m) at each scan (NaN where unknown).
    """

    robot: str
    label: str
    start_ns: int
    end_ns: int
    pose: np.ndarray
    beam_angles_rad: np.ndarray
    ranges: np.ndarray
    range_min_m: float
    range_max_m: float
    others: np.ndarray

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / NS_PER_S


@dataclass(frozen=True)
class LidarFit:
    """The lidar estimates and what the report plots: residuals (m) of valid returns, the clip limits."""

    noise_sigma_m: Estimate
    dropout_prob: Estimate
    bias_m: Estimate
    mount_yaw_rad: Estimate
    residuals_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    spans: int = 0
    stationary_s: float = 0.0
    beams_used: int = 0
    yaw_cost: tuple[np.ndarray, np.ndarray] | None = None
    notes: tuple[str, ...] = ()


def stationary_spans(
    track: Track, speed_mps: float, yaw_rate_radps: float, min_s: float, average_s: float = STILL_AVERAGE_S
) -> list[tuple[int, int]]:
    """(start_ns, end_ns) of the stretches of `track` whose speed and yaw rate stay below the thresholds for at
    least `min_s` seconds; the smoothed velocities are averaged over `average_s` first (noise of the truth)."""
    vel = track.velocity
    if len(track.t_ns) > 1 and average_s > 0:
        dt = float(np.median(np.diff(track.t_ns))) / NS_PER_S
        k = max(1, round(average_s / dt)) if dt > 0 else 1
        kernel = np.ones(k) / k
        pad = [(k // 2, k - 1 - k // 2)]
        vel = np.stack(
            [np.convolve(np.pad(vel[:, i], pad, mode="edge"), kernel, mode="valid") for i in range(3)], axis=1
        )
    still = (np.hypot(vel[:, 0], vel[:, 1]) < speed_mps) & (np.abs(vel[:, 2]) < yaw_rate_radps)
    out: list[tuple[int, int]] = []
    edges = np.diff(np.r_[0, still.astype(np.int8), 0])
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        start, end = int(track.t_ns[a]), int(track.t_ns[b - 1])
        if (end - start) / NS_PER_S >= min_s:
            out.append((start, end))
    return out


def _unidentifiable(reason: str, notes: Sequence[str] = (), **kw: object) -> LidarFit:
    return LidarFit(
        Estimate.unidentifiable(reason, "m"),
        Estimate.unidentifiable(reason, "probability"),
        Estimate.unidentifiable(reason, "m"),
        Estimate.unidentifiable(reason, "rad"),
        notes=tuple(notes),
        **kw,  # type: ignore[arg-type]
    )


def _span_means(span: ScanSpan) -> tuple[np.ndarray, np.ndarray]:
    """Per beam: mean of the valid returns over the span's scans (m) and how many there were."""
    r = span.ranges
    valid = np.isfinite(r) & (r >= span.range_min_m) & (r <= span.range_max_m)
    count = valid.sum(axis=0)
    total = np.where(valid, r, 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return mean, count


def _cast_span(
    geometry: MapGeometry, span: ScanSpan, yaw_offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Static casts of the span's beams for each mount yaw offset: (range, surface, cos) each (n_offsets, beams)."""
    angles = span.pose[2] + span.beam_angles_rad[None, :] + np.asarray(yaw_offsets)[:, None]
    hits = geometry.cast(span.pose[None, None, :2], angles)
    return hits.range_m, hits.surface, hits.cos_incidence


def _coarse_cost(
    geometry: MapGeometry, spans: Sequence[ScanSpan], means: Sequence[np.ndarray], offsets: np.ndarray
) -> np.ndarray:
    """Robust cost (mean truncated absolute residual about the median) of each yaw offset."""
    cost = np.zeros(len(offsets))
    residuals: list[np.ndarray] = []
    for span, mean in zip(spans, means, strict=True):
        rng, _, _ = _cast_span(geometry, span, offsets)
        inside = (rng > span.range_min_m) & (rng < span.range_max_m)
        residuals.append(np.where(inside & np.isfinite(mean)[None, :], mean[None, :] - rng, np.nan))
    r = np.concatenate(residuals, axis=1)
    med = np.nanmedian(r, axis=1)
    trunc = np.minimum(np.abs(r - med[:, None]), TRUNCATION_M)
    cost = np.nanmean(trunc, axis=1)
    cost[np.sum(np.isfinite(r), axis=1) < 10] = np.inf
    return np.asarray(cost)


def _usable(
    geometry: MapGeometry, span: ScanSpan, yaw: float, settings: CalibrationSettings, edge_rad: float
) -> np.ndarray:
    """(beams,) beams whose cast at mount yaw `yaw` is clean: inside the range margins, not grazing, not at an edge."""
    offs = np.array([yaw - edge_rad, yaw, yaw + edge_rad])
    rng, surface, cos = _cast_span(geometry, span, offs)
    margin = settings.lidar_range_margin_m
    ok = (rng[1] > span.range_min_m + margin) & (rng[1] < span.range_max_m - margin)
    ok &= cos[1] >= math.cos(settings.lidar_max_incidence_rad)
    ok &= (surface[0] == surface[1]) & (surface[2] == surface[1]) & (surface[1] >= 0)
    return np.asarray(ok)


def _robot_free(span: ScanSpan, yaw: float, reach: np.ndarray, radius_m: float, margin_m: float) -> np.ndarray:
    """(n_scans, beams) beams passing no other robot within `margin_m` of its body (up to `reach` m)."""
    n_scans, beams = span.ranges.shape
    free = np.ones((n_scans, beams), dtype=bool)
    angles = span.pose[2] + span.beam_angles_rad + yaw
    for i in range(n_scans):
        others = span.others[i]
        others = others[np.all(np.isfinite(others), axis=1)]
        if len(others) == 0:
            continue
        _, closest = cast_circles(span.pose[:2], angles, others, radius_m, reach)
        free[i] = closest > radius_m + margin_m
    return free


def _mount_yaw(
    geometry: MapGeometry, spans: Sequence[ScanSpan], settings: CalibrationSettings, rng: np.random.Generator
) -> tuple[float, Estimate, tuple[np.ndarray, np.ndarray]]:
    """Mounting yaw (rad): coarse and fine robust searches, then Huber-weighted Gauss-Newton on (yaw, bias)."""
    means = [_span_means(s) for s in spans]
    mean_ranges = [m for m, _ in means]
    order = np.argsort([-s.ranges.shape[0] for s in spans])[:12]
    sub = [spans[i] for i in order]
    sub_means = [mean_ranges[i] for i in order]
    half = settings.lidar_mount_search_rad
    if half >= math.pi - 1e-9:
        coarse = np.arange(-math.pi, math.pi, COARSE_STEP_RAD)
    else:
        coarse = np.arange(-half, half + 1e-12, COARSE_STEP_RAD)
    costs = np.concatenate(
        [_coarse_cost(geometry, sub, sub_means, chunk) for chunk in np.array_split(coarse, max(1, len(coarse) // 60))]
    )
    best = float(coarse[int(np.argmin(costs))])
    fine = best + np.arange(-FINE_HALF_WIDTH_RAD, FINE_HALF_WIDTH_RAD + 1e-12, FINE_STEP_RAD)
    fine_costs = _coarse_cost(geometry, spans, mean_ranges, fine)
    yaw = float(fine[int(np.argmin(fine_costs))])
    curve = (np.r_[coarse, fine], np.r_[costs, fine_costs])
    # Gauss-Newton on (yaw, bias) with Huber weights over a beam set fixed at the current yaw
    edge = settings.lidar_edge_rad + 2 * FINE_STEP_RAD + 0.01
    sets = []
    for span, (_, count) in zip(spans, means, strict=True):
        use = _usable(geometry, span, yaw, settings, edge) & (count > 0)
        rng0, _, _ = _cast_span(geometry, span, np.array([yaw]))
        free = _robot_free(span, yaw, rng0[0], geometry.robot_radius_m, settings.lidar_robot_margin_m).all(axis=0)
        sets.append(use & free)
    total = sum(int(s.sum()) for s in sets)
    if total < 20:
        return yaw, Estimate.unidentifiable("fewer than 20 clean beams in the stationary spans", "rad"), curve
    bias = 0.0
    a = np.zeros((len(spans), 2, 2))
    g = np.zeros((len(spans), 2))
    r = j = w = np.zeros(0)
    for _ in range(GAUSS_NEWTON_STEPS):
        base = yaw
        r, j, w, who = _linearised(geometry, spans, means, sets, yaw)
        e = r - bias
        scale = 1.4826 * float(np.median(np.abs(e - np.median(e)) * np.sqrt(w))) + 1e-6
        delta = HUBER_K * scale / np.sqrt(w)
        w = w * np.minimum(1.0, delta / np.maximum(np.abs(e), 1e-12))
        # per-span normal equations of r = j * (yaw step) + bias
        a = np.zeros((len(spans), 2, 2))
        g = np.zeros((len(spans), 2))
        np.add.at(a[:, 0, 0], who, w * j * j)
        np.add.at(a[:, 0, 1], who, w * j)
        np.add.at(a[:, 1, 1], who, w)
        np.add.at(g[:, 0], who, w * j * r)
        np.add.at(g[:, 1], who, w * r)
        a[:, 1, 0] = a[:, 0, 1]
        A = a.sum(axis=0)
        if abs(np.linalg.det(A)) < 1e-12:
            return yaw, Estimate.unidentifiable("no clean beam hits a surface obliquely", "rad"), curve
        step, bias = np.linalg.solve(A, g.sum(axis=0))
        yaw = base + float(step)
        if abs(step) < 1e-7:
            break
    A = a.sum(axis=0)
    sigma_e = math.sqrt(float(np.sum((r - bias) ** 2 * w) / max(float(np.sum(w)) - 2, 1.0)))
    se = sigma_e * math.sqrt(float(np.linalg.inv(A)[0, 0]))
    interval = normal_interval(yaw, se)
    method = "Gauss-Newton standard error (independent beams)"
    spans_used = int(sum(1 for s in sets if s.any()))
    if spans_used >= MIN_SPANS_FOR_BOOTSTRAP:

        def stat(counts: np.ndarray) -> np.ndarray:
            Ab = np.tensordot(counts, a, axes=1)
            if abs(np.linalg.det(Ab)) < 1e-12:
                return np.array([np.nan])
            return np.array([base + float(np.linalg.solve(Ab, np.tensordot(counts, g, axes=1))[0])])

        boot_se, boot_interval = spread(bootstrap(stat, len(spans), settings.bootstrap, rng)[:, 0])
        if math.isfinite(boot_se):
            # the wider of the bootstrap over spans and the formula for independent beams
            se = max(se, boot_se)
            interval = (min(boot_interval[0], yaw - Z_95 * se), max(boot_interval[1], yaw + Z_95 * se))
            method = f"bootstrap over {spans_used} stationary spans"
    wrapped = float(wrap(yaw))
    interval = (interval[0] + wrapped - yaw, interval[1] + wrapped - yaw)
    if not se < MAX_YAW_STD_ERROR_RAD:
        reason = f"the mounting yaw is uncertain by {se:.3f} rad"
        return wrapped, Estimate.unidentifiable(reason, "rad", total), curve
    return wrapped, Estimate.of(wrapped, se, interval, "rad", method, total), curve


def _linearised(
    geometry: MapGeometry,
    spans: Sequence[ScanSpan],
    means: Sequence[tuple[np.ndarray, np.ndarray]],
    sets: Sequence[np.ndarray],
    yaw: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per clean beam: residual of the span-mean range (m), its derivative by the mount yaw (m/rad), weight (scans)
    and span index."""
    h = 1e-4
    residual, jac, weight, owner = [], [], [], []
    for k, (span, (mean, count), use) in enumerate(zip(spans, means, sets, strict=True)):
        if not use.any():
            continue
        rng3, _, _ = _cast_span(geometry, span, np.array([yaw - h, yaw, yaw + h]))
        residual.append(mean[use] - rng3[1, use])
        jac.append((rng3[2, use] - rng3[0, use]) / (2 * h))
        weight.append(count[use].astype(np.float64))
        owner.append(np.full(int(use.sum()), k))
    return np.concatenate(residual), np.concatenate(jac), np.concatenate(weight), np.concatenate(owner)


def clipped_moments(
    residuals: np.ndarray, sigmas: float = CLIP_SIGMAS, iterations: int = 5
) -> tuple[float, float, float]:
    """Mean, standard deviation (corrected for the clipping) and clip half-width of `residuals` clipped at
    `sigmas` standard deviations about the mean.

    Starts from the median and the scaled median absolute deviation.
    """
    r = np.asarray(residuals, dtype=np.float64)
    centre = float(np.median(r))
    scale = 1.4826 * float(np.median(np.abs(r - centre)))
    correction = truncation_correction(sigmas)
    for _ in range(iterations):
        half = sigmas * max(scale, 1e-9)
        kept = r[np.abs(r - centre) <= half]
        if len(kept) < 2:
            break
        centre = float(kept.mean())
        scale = float(kept.std(ddof=1)) * correction
    return centre, scale, sigmas * max(scale, 1e-9)


def truncation_correction(sigmas: float) -> float:
    """Factor turning the std of a normal sample truncated at +-`sigmas` back into the normal's sigma."""
    mass = 2 * stats.norm.cdf(sigmas) - 1
    var = 1 - 2 * sigmas * stats.norm.pdf(sigmas) / mass
    return 1.0 / math.sqrt(var)


def estimate_lidar(
    geometry: MapGeometry, spans: Sequence[ScanSpan], settings: CalibrationSettings, rng: np.random.Generator
) -> LidarFit:
    """Noise sigma (m), dropout probability, bias (m) and mounting yaw (rad) from stationary `spans`."""
    min_s = settings.stationary_min_s
    spans = [s for s in spans if s.ranges.shape[0] > 0]
    if not spans:
        return _unidentifiable(f"robots never stood still for >= {min_s:g} s while scanning")
    stationary_s = float(sum(s.duration_s for s in spans))
    yaw, yaw_est, curve = _mount_yaw(geometry, spans, settings, rng)
    # per-scan residuals and dropouts at the estimated yaw over the clean beams
    per_span_res: list[np.ndarray] = []
    drops = np.zeros(len(spans))
    trials = np.zeros(len(spans))
    for k, span in enumerate(spans):
        use = _usable(geometry, span, yaw, settings, settings.lidar_edge_rad)
        cast, _, _ = _cast_span(geometry, span, np.array([yaw]))
        cast = cast[0]
        free = _robot_free(span, yaw, cast, geometry.robot_radius_m, settings.lidar_robot_margin_m)
        mask = free & use[None, :]
        r = span.ranges
        valid = np.isfinite(r) & (r >= span.range_min_m) & (r <= span.range_max_m)
        trials[k] = mask.sum()
        drops[k] = (mask & ~valid).sum()
        per_span_res.append((r - cast[None, :])[mask & valid])
    n_trials = int(trials.sum())
    notes = [f"{len(spans)} stationary spans, {stationary_s:.1f} s, {sum(s.ranges.shape[0] for s in spans)} scans"]
    if n_trials < MIN_BEAMS:
        reason = f"only {n_trials} usable beams in {len(spans)} stationary spans (need {MIN_BEAMS})"
        fit = _unidentifiable(reason, notes, spans=len(spans), stationary_s=stationary_s, beams_used=n_trials)
        return dataclasses.replace(fit, mount_yaw_rad=yaw_est, yaw_cost=curve)
    residuals = np.concatenate(per_span_res)
    bias, sigma, half = clipped_moments(residuals)
    correction = truncation_correction(CLIP_SIGMAS)
    kept = [r[np.abs(r - bias) <= half] for r in per_span_res]
    sums = np.array([[len(k), k.sum(), np.square(k).sum()] for k in kept])
    n_res = int(sums[:, 0].sum())
    spans_used = int(np.sum(trials > 0))
    if spans_used >= MIN_SPANS_FOR_BOOTSTRAP:

        def stat(counts: np.ndarray) -> np.ndarray:
            s = counts @ sums
            t = counts @ trials
            if s[0] < 2 or t <= 0:
                return np.array([np.nan, np.nan, np.nan])
            mean = s[1] / s[0]
            var = max(s[2] / s[0] - mean * mean, 0.0) * s[0] / (s[0] - 1)
            return np.array([mean, math.sqrt(var) * correction, (counts @ drops) / t])

        samples = bootstrap(stat, len(spans), settings.bootstrap, rng)
        method = f"bootstrap over {spans_used} stationary spans"
        bias_se, bias_ci = spread(samples[:, 0])
        sigma_se, sigma_ci = spread(samples[:, 1])
        drop_se, drop_ci = spread(samples[:, 2])
        p = float(drops.sum() / n_trials)
        bias_est = Estimate.of(bias, bias_se, bias_ci, "m", method, n_res)
        sigma_est = Estimate.of(sigma, sigma_se, sigma_ci, "m", method, n_res)
        drop_est = Estimate.of(p, drop_se, drop_ci, "probability", method, n_trials)
    else:
        method = "normal theory (independent beams)"
        bias_se = sigma / math.sqrt(n_res)
        sigma_se = sigma / math.sqrt(2 * (n_res - 1))
        bias_est = Estimate.of(bias, bias_se, normal_interval(bias, bias_se), "m", method, n_res)
        sigma_est = Estimate.of(sigma, sigma_se, normal_interval(sigma, sigma_se), "m", method, n_res)
        drop_est = binomial_estimate(int(drops.sum()), n_trials)
    return LidarFit(
        sigma_est, drop_est, bias_est, yaw_est, residuals, len(spans), stationary_s, n_trials, curve, tuple(notes)
    )
