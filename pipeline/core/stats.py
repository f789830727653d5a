"""Small statistics shared by evaluation, deployment and analysis: binomial intervals and tests, and the
mean of a few runs with its Student-t interval."""

from __future__ import annotations

import math
from collections.abc import Sequence

Z_95 = 1.959963984540054
"""The two-sided 95 % normal quantile."""


def wilson_interval(successes: float, trials: float, z: float = Z_95) -> tuple[float, float]:
    """The Wilson score interval (default 95 %) for a binomial proportion; (0, 1) when trials == 0. Counts may be
    fractional (effective counts of overdispersed data: the counts divided by the dispersion)."""
    if trials < 0 or not 0 <= successes <= trials:
        raise ValueError(f"need 0 <= successes <= trials, got successes={successes}, trials={trials}")
    if trials == 0:
        return 0.0, 1.0
    p = successes / trials
    denom = 1 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denom
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denom
    low = 0.0 if successes == 0 else max(0.0, centre - half)  # exact where rounding leaves a trace
    return low, 1.0 if successes == trials else min(1.0, centre + half)


def newcombe_interval(
    successes_a: int, trials_a: int, successes_b: int, trials_b: int, z: float = Z_95
) -> tuple[float, float]:
    """Newcombe's hybrid score interval (his method 10, from two Wilson intervals) for p_a - p_b.

    Returns (nan, nan) when either group has no trials.
    """
    if trials_a == 0 or trials_b == 0:
        return math.nan, math.nan
    p_a, p_b = successes_a / trials_a, successes_b / trials_b
    low_a, high_a = wilson_interval(successes_a, trials_a, z)
    low_b, high_b = wilson_interval(successes_b, trials_b, z)
    d = p_a - p_b
    return d - math.hypot(p_a - low_a, high_b - p_b), d + math.hypot(high_a - p_a, p_b - low_b)


def two_proportion_z_test(successes_a: int, trials_a: int, successes_b: int, trials_b: int) -> tuple[float, float]:
    """The pooled two-proportion z statistic for p_a - p_b and its two-sided p-value.

    When both groups are all successes or all failures the difference is 0 with p = 1; with no
    trials in either group both values are nan.
    """
    if trials_a == 0 or trials_b == 0:
        return math.nan, math.nan
    pooled = (successes_a + successes_b) / (trials_a + trials_b)
    se = math.sqrt(pooled * (1 - pooled) * (1 / trials_a + 1 / trials_b))
    if se == 0:
        return 0.0, 1.0
    z = (successes_a / trials_a - successes_b / trials_b) / se
    return z, math.erfc(abs(z) / math.sqrt(2))


def mean_interval(values: Sequence[float], level: float = 0.95) -> tuple[float, float, float]:
    """The mean of independent runs (e.g. one figure per training seed) and its two-sided Student-t interval.

    The interval is for the expected value of a run: it takes the spread between runs as it is, so with
    few runs it is wide rather than overconfident. Returns (mean, nan, nan) for a single run."""
    from scipy import stats as sps  # only here: every rollout imports the rest of this module

    x = [float(v) for v in values]
    if not x:
        raise ValueError("need at least one value")
    mean = math.fsum(x) / len(x)
    if len(x) < 2:
        return mean, math.nan, math.nan
    sd = math.sqrt(math.fsum((v - mean) ** 2 for v in x) / (len(x) - 1))
    half = float(sps.t.ppf(0.5 + level / 2, len(x) - 1)) * sd / math.sqrt(len(x))
    return mean, mean - half, mean + half
