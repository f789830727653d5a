"""The lidar's range noise from repeated returns of a still robot: the range step, the noise and its growth with range,
its spread over beams, with intervals that stay inside their keys' domains.

- Range step: real drivers report ranges in steps (0.25-2 mm). The changes of a beam's range between scans of a
  still robot all lie on the step's lattice: the step is the largest q (of the most common small change divided by
  1 to 12) on whose lattice `LATTICE_SHARE` of the changes lie, refined by least squares; none of 10 um or more:
  continuous ranges.
- Noise: each range bin's spread (clipped at 4 sigma, corrected for the clipping) is a Gaussian variance
  ``(noise_sigma_m + noise_per_m * range)^2 + step^2 / 12`` (a uniform rounding adds step^2 / 12): the two are fitted
  by maximum likelihood with both >= 0. Their 95 % intervals come from a bootstrap of that bounded fit over clusters
  of spans where there are enough, else from the profile likelihood (the set of values whose likelihood ratio stays
  within chi-square's 95 % point, the other parameter maximized within its bound); either way scaled by the bins'
  dispersion about the fit (quasi-likelihood: what the model leaves out widens it), on a log scale, so no interval
  leaves [0, inf). Intercept and slope trade off where the ranges seen span little: their correlation is reported
  with the combination that is determined, the noise at the median range seen.
- Spread over beams: the noise of each beam (index) about the fitted line, pooled over spans; the variance of its
  log beyond what sampling gives is 4 s^2 for a per-beam factor exp(s z - s^2).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import optimize, special, stats

from pipeline.calibration.estimates import Z_95, Estimate
from pipeline.core.quantities import NOISE_PER_M, NOISE_SIGMA_M

MIN_STEP_M = 1e-5
"""No 2-D lidar reports ranges finer than this; finer lattices are the float32 the ranges travel in."""
LATTICE_SHARE = 0.99
LATTICE_TOL = 0.02
"""A change lies on the lattice of q when it is within this share of q of a multiple of it."""
MIN_CHANGES = 50
LATTICE_SPAN = 50
"""The lattice is read on changes of up to this many steps."""
CHI2_95_1DOF = float(stats.chi2.ppf(0.95, 1))
NOISE_BOUNDS = {q.name: (q.low, q.high) for q in (NOISE_SIGMA_M, NOISE_PER_M)}
"""The noise's domain (:mod:`pipeline.core.quantities`): where its fits and intervals stay."""


def range_step(changes_m: np.ndarray) -> Estimate:
    """The step of the ranges from the changes of beams' ranges between scans of a still robot (m, any sign)."""
    d = np.abs(np.asarray(changes_m, dtype=np.float64))
    d = d[np.isfinite(d) & (d >= MIN_STEP_M / 2)]
    if len(d) < MIN_CHANGES:
        return Estimate.unidentifiable(
            f"only {len(d)} changes of a beam's range between scans of a still robot (need {MIN_CHANGES}): the "
            "ranges stand still or the robot never did",
            "m",
            len(d),
        )
    small = d[d <= np.percentile(d, 5)]
    values, counts = np.unique(np.round(small, 6), return_counts=True)  # micrometres: float32 noise rounded away
    q0 = float(values[counts.argmax()])
    for k in range(1, 13):
        q = q0 / k
        if q < MIN_STEP_M:
            break
        near = d[d <= LATTICE_SPAN * q]  # a large change (something moved) tells the step less than its rounding
        if len(near) < MIN_CHANGES:
            continue
        units = near / q
        on = np.abs(units - np.round(units)) < LATTICE_TOL
        share = float(on.mean())
        if share >= LATTICE_SHARE:
            m = np.round(units[on])
            q_hat = float(np.sum(near[on] * m) / np.sum(m * m))
            resid = near[on] - m * q_hat
            se = math.sqrt(float(np.sum(resid**2)) / max(len(m) - 1, 1) / float(np.sum(m * m)))
            half = max(Z_95 * se, 1e-3 * q_hat)  # at least the float32 the ranges travel in
            method = f"lattice of the changes of each beam's range between scans ({share:.1%} of {len(near)} on it)"
            return Estimate.of(q_hat, se, (q_hat - half, q_hat + half), "m", method, len(d))
    method = f"no lattice: continuous ranges (no step of {MIN_STEP_M * 1e6:g} um or more holds {LATTICE_SHARE:.0%})"
    return Estimate.of(0.0, 0.0, (0.0, MIN_STEP_M), "m", method, len(d))


@dataclass(frozen=True)
class NoiseBins:
    """Per range bin: returns, their variance about their beam's mean (clipping corrected), their mean range (m)."""

    n: np.ndarray
    var: np.ndarray
    range_m: np.ndarray

    @staticmethod
    def of(total: np.ndarray, correction: float) -> NoiseBins:
        """From (bins, [count, sum, sum of squares, sum of ranges]) sums; bins with fewer than 2 returns left out."""
        ok = total[:, 0] >= 2
        n = total[ok, 0]
        var = np.maximum(total[ok, 2] / n - (total[ok, 1] / n) ** 2, 0.0) * correction**2
        return NoiseBins(n, var, total[ok, 3] / n)

    @property
    def spans_range(self) -> bool:
        return len(self.n) >= 2

    def median_range(self) -> float:
        order = np.argsort(self.range_m)
        cum = np.cumsum(self.n[order])
        return float(self.range_m[order][np.searchsorted(cum, cum[-1] / 2)])


def _nll(bins: NoiseBins, a: float, b: float, step_var: float) -> float:
    v = (a + b * bins.range_m) ** 2 + step_var
    v = np.maximum(v, 1e-18)
    return 0.5 * float(np.sum(bins.n * (np.log(v) + bins.var / v)))


def fit_noise(bins: NoiseBins, step_m: float, slope: bool) -> np.ndarray:
    """[noise_sigma_m, noise_per_m] by maximum likelihood with both >= 0 (slope NaN where not fitted)."""
    step_var = step_m**2 / 12
    if not len(bins.n):
        return np.array([math.nan, math.nan])
    if not slope:
        pooled = float(np.sum(bins.n * bins.var) / np.sum(bins.n))
        return np.array([math.sqrt(max(pooled - step_var, 0.0)), math.nan])
    sigma = np.sqrt(np.maximum(bins.var - step_var, 0.0))
    x = np.stack([np.ones_like(bins.range_m), bins.range_m], axis=1)
    start, _ = optimize.nnls(x * np.sqrt(bins.n)[:, None], sigma * np.sqrt(bins.n))
    scale = max(float(np.sqrt(np.average(bins.var, weights=bins.n))), 1e-6)
    res = optimize.minimize(
        lambda p: _nll(bins, p[0] * scale, p[1] * scale, step_var),
        start / scale,
        method="L-BFGS-B",
        bounds=[(0.0, NOISE_BOUNDS["noise_sigma_m"][1] / scale), (0.0, NOISE_BOUNDS["noise_per_m"][1] / scale)],
    )
    return np.asarray(res.x, dtype=np.float64) * scale


def dispersion(bins: NoiseBins, fit: np.ndarray, step_m: float) -> float:
    """The bins' spread about the fit over what sampling gives (Pearson's, at least 1): a variance of n returns
    reads v chi2(n) / n, so (var / v - 1) sqrt(n / 2) is about N(0, 1) where the model holds."""
    params = 1 if not math.isfinite(float(fit[1])) else 2
    if len(bins.n) <= params:
        return 1.0
    b = float(fit[1]) if params == 2 else 0.0
    v = (float(fit[0]) + b * bins.range_m) ** 2 + step_m**2 / 12
    z = (bins.var / np.maximum(v, 1e-18) - 1) * np.sqrt(bins.n / 2)
    return max(1.0, float(np.sum(z**2)) / (len(bins.n) - params))


def _bracket_root(f: Callable[[float], float], lo: float, hi: float, limit: float) -> float:
    """The x in [lo, ...] where f crosses zero going up from f(lo) < 0, hi doubled up to `limit`; `limit` if never."""
    while f(hi) < 0:
        if hi >= limit:
            return limit
        lo, hi = hi, min(2 * hi, limit)
    return float(optimize.brentq(f, lo, hi, xtol=1e-12, rtol=1e-6))


def profile_intervals(
    bins: NoiseBins, fit: np.ndarray, step_m: float, phi: float, at_m: float
) -> tuple[tuple[float, float], tuple[float, float], tuple[float, float]]:
    """Profile-likelihood 95 % intervals of (noise_sigma_m, noise_per_m, the noise at `at_m`), each within [0, its
    bound]; the likelihood ratio's threshold scaled by the dispersion `phi`. The slope's is (nan, nan) where it
    was not fitted."""
    step_var = step_m**2 / 12
    slope = math.isfinite(float(fit[1]))
    a_hat, b_hat = float(fit[0]), float(fit[1]) if slope else 0.0
    best = _nll(bins, a_hat, b_hat, step_var)
    limit = phi * CHI2_95_1DOF / 2
    a_max, b_max = NOISE_BOUNDS["noise_sigma_m"][1], NOISE_BOUNDS["noise_per_m"][1]

    def over(nll_of: Callable[[float], float]) -> Callable[[float], float]:
        return lambda x: nll_of(x) - best - limit

    def prof_a(a: float) -> float:
        if not slope:
            return _nll(bins, a, 0.0, step_var)
        r = optimize.minimize_scalar(lambda b: _nll(bins, a, b, step_var), bounds=(0.0, b_max), method="bounded")
        return float(min(r.fun, _nll(bins, a, 0.0, step_var)))

    def prof_b(b: float) -> float:
        r = optimize.minimize_scalar(lambda a: _nll(bins, a, b, step_var), bounds=(0.0, a_max), method="bounded")
        return float(min(r.fun, _nll(bins, 0.0, b, step_var)))

    def prof_c(c: float) -> float:  # the noise at at_m: a = c - b at_m >= 0
        if not slope:
            return _nll(bins, c, 0.0, step_var)
        top = min(c / at_m, b_max) if at_m > 0 else b_max
        r = optimize.minimize_scalar(
            lambda b: _nll(bins, c - b * at_m, b, step_var), bounds=(0.0, top), method="bounded"
        )
        return float(min(r.fun, _nll(bins, c, 0.0, step_var), _nll(bins, c - top * at_m, top, step_var)))

    def interval(prof: Callable[[float], float], value: float, bound: float) -> tuple[float, float]:
        f = over(prof)
        scale = max(value, math.sqrt(float(np.average(bins.var, weights=bins.n))) * 1e-3, 1e-9)
        low = 0.0 if f(0.0) <= 0 else float(optimize.brentq(lambda x: f(x), 0.0, max(value, 1e-15), xtol=1e-12))
        high = _bracket_root(f, value, value + scale, bound)
        return low, high

    c_hat = a_hat + b_hat * at_m
    a_int = interval(prof_a, a_hat, a_max)
    b_int = interval(prof_b, b_hat, b_max) if slope else (math.nan, math.nan)
    c_int = interval(prof_c, c_hat, a_max + b_max * at_m)
    return a_int, b_int, c_int


def correlation(bins: NoiseBins, fit: np.ndarray, step_m: float) -> float:
    """The correlation of intercept and slope from the likelihood's curvature at the fit (NaN without a slope)."""
    if not math.isfinite(float(fit[1])):
        return math.nan
    step_var = step_m**2 / 12
    a, b = float(fit[0]), float(fit[1])
    ha = max(abs(a), 1e-4) * 1e-3
    hb = max(abs(b), 1e-4) * 1e-3

    def f(x: float, y: float) -> float:
        return _nll(bins, x, y, step_var)

    faa = (f(a + ha, b) - 2 * f(a, b) + f(a - ha, b)) / ha**2
    fbb = (f(a, b + hb) - 2 * f(a, b) + f(a, b - hb)) / hb**2
    fab = (f(a + ha, b + hb) - f(a + ha, b - hb) - f(a - ha, b + hb) + f(a - ha, b - hb)) / (4 * ha * hb)
    h = np.array([[faa, fab], [fab, fbb]])
    try:
        cov = np.linalg.inv(h)
    except np.linalg.LinAlgError:
        return math.nan
    if cov[0, 0] <= 0 or cov[1, 1] <= 0:
        return math.nan
    return float(cov[0, 1] / math.sqrt(cov[0, 0] * cov[1, 1]))


def log_widen(
    value: float, interval: tuple[float, float], factor: float, low_bound: float = 0.0
) -> tuple[float, float]:
    """`interval` about `value` widened by `factor` on a log scale (distances of log(x) from log(value) multiplied),
    so it stays above `low_bound` (0); an end at the bound stays there."""
    lo, hi = interval
    if factor <= 1.0:
        return lo, hi
    if not value > low_bound:
        return lo, low_bound + (hi - low_bound) * factor
    new_lo = low_bound if lo <= low_bound else value * (lo / value) ** factor
    new_hi = value * (hi / value) ** factor if hi > value else hi
    return new_lo, new_hi


def log_add(value: float, interval: tuple[float, float], rel_sd: float) -> tuple[float, float]:
    """`interval` about `value` (> 0) with a further relative error of `rel_sd` (1 sigma) added in quadrature on a log
    scale; unchanged for a value at 0 or no further error."""
    lo, hi = interval
    if not value > 0 or not rel_sd > 0:
        return lo, hi
    extra = (Z_95 * rel_sd) ** 2
    down = math.sqrt(math.log(value / lo) ** 2 + extra) if lo > 0 else math.inf
    up = math.sqrt(math.log(hi / value) ** 2 + extra) if hi > value else math.sqrt(extra)
    return (value * math.exp(-down) if math.isfinite(down) else 0.0), value * math.exp(up)


OWN_SCALE_TRIM = 5.0
"""A still return further than this many of its beam's own robust scales (the median absolute deviation over 0.6745)
from the beam's mean is left out of the beams' spread: a leak of something passing through the beam, not its noise.
A beam's own tails, however wide, stay in (a Gaussian loses 6e-7 of its returns there)."""


def _group_median(values: np.ndarray, group: np.ndarray, groups: int) -> np.ndarray:
    """The median of `values` within each of `groups` groups (`group` each value's, 0..groups-1; every group used)."""
    order = np.lexsort((values, group))
    ordered = values[order]
    count = np.bincount(group, minlength=groups)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    return np.asarray(0.5 * (ordered[start + (count - 1) // 2] + ordered[start + count // 2]), dtype=np.float64)


def beam_spread(
    deviations: Sequence[tuple[np.ndarray, ...]],
    sigma_of: Callable[[np.ndarray], np.ndarray],
    step_m: float = 0.0,
) -> tuple[float, float, tuple[float, float], int]:
    """(s, its standard error, its 95 % interval, beams) of the per-beam noise factor exp(s z - s^2) from (beam
    index, deviation, range[, inflation]) arrays (gross outliers left out, the tails kept: a noisy beam's are its own;
    `inflation` each deviation's n / (n - 1), where its span's mean of n returns was taken out and the deviation
    scaled back up: its beam's square then has fewer degrees of freedom than returns): per beam, the mean of its
    squared deviations less the rounding's step^2 / 12, each over the fitted noise's square at its range, is its
    factor squared;
    the variance of its log beyond sampling (chi-square's trigamma(dof / 2) at the beam's effective degrees of
    freedom, scaled for the rounding taken out) is 4 s^2. Returns beyond `OWN_SCALE_TRIM` of their beam's own robust
    scale are left out, and beams whose spread is mostly rounding. The interval from a bootstrap over beams."""
    if not deviations:
        return math.nan, math.nan, (math.nan, math.nan), 0
    beam = np.concatenate([d[0] for d in deviations])
    dev = np.concatenate([d[1] for d in deviations])
    rng_m = np.concatenate([d[2] for d in deviations])
    inflation = np.concatenate([d[3] if len(d) > 3 else np.ones(len(d[0])) for d in deviations])
    step_var = step_m**2 / 12
    _, inverse = np.unique(beam, return_inverse=True)
    groups = int(inverse.max()) + 1 if len(inverse) else 0
    own = _group_median(np.abs(dev), inverse, groups) / 0.6745
    # a beam whose returns mostly repeat one value (noise under the range step) has no scale of its own to trim by
    inside = (np.abs(dev) <= OWN_SCALE_TRIM * own[inverse]) | (own[inverse] <= 0.5 * step_m)
    dev, rng_m, inflation, inverse = dev[inside], rng_m[inside], inflation[inside], inverse[inside]
    n = np.bincount(inverse, minlength=groups).astype(np.float64)
    used = np.maximum(n, 1)
    # each deviation over the fitted noise at its own range: a beam seen at several ranges (from several spans) then
    # has the sampling of its degrees of freedom; its mean square over the mean model square would weigh the far
    # returns' deviations more and spread wider than that sampling says
    model = np.maximum(sigma_of(rng_m) ** 2, 1e-18)
    square = np.bincount(inverse, weights=dev**2 / model, minlength=groups) / used
    rounding = np.bincount(inverse, weights=step_var / model, minlength=groups) / used
    dof = n**2 / np.maximum(np.bincount(inverse, weights=inflation, minlength=groups), 1e-12)
    keep = (n >= 20) & (square > 1.5 * rounding) & (square > 0)
    if keep.sum() < 20:
        return math.nan, math.nan, (math.nan, math.nan), int(keep.sum())
    signal = square[keep] - rounding[keep]
    y = np.log(signal)
    sampling = special.polygamma(1, dof[keep] / 2) * (square[keep] / signal) ** 2

    def s_of(idx: np.ndarray) -> float:
        excess = float(np.var(y[idx], ddof=1) - np.mean(sampling[idx]))
        return math.sqrt(max(excess, 0.0) / 4)

    all_idx = np.arange(int(keep.sum()))
    s = s_of(all_idx)
    rng = np.random.default_rng(0)
    boot = np.array([s_of(rng.integers(0, len(all_idx), len(all_idx))) for _ in range(400)])
    lo, hi = np.percentile(boot, [2.5, 97.5])
    shift = s - float(np.median(boot))
    low = max(float(lo) + shift, 0.0)
    # at the bound the bootstrap cannot say whether 0 is in: Bartlett's test of equal variances over the beams can
    ratio = square[keep]
    dof = dof[keep]
    total = float(dof.sum())
    pooled = float(np.sum(dof * ratio)) / total
    stat = total * math.log(pooled) - float(np.sum(dof * np.log(ratio)))
    scale = 1 + (float(np.sum(1 / dof)) - 1 / total) / (3 * (len(dof) - 1))
    if float(stats.chi2.sf(stat / scale, len(dof) - 1)) > 0.05:
        low = 0.0
    return s, float(np.std(boot, ddof=1)), (low, max(float(hi) + shift, s)), len(all_idx)
