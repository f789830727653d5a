"""Estimates with their uncertainty and status, and the interval helpers the estimators share."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from scipy import stats

from pipeline.core.stats import wilson_interval

Status = Literal["ok", "weak", "unidentifiable"]
"""``weak``: a value whose 95 % interval is wider than the value itself (the data bound it more than they pin it);
used as an identified one, flagged in the report."""
Z_95 = 1.959963984540054
MAD_TO_SIGMA = 1.4826
"""A normal variable's standard deviation over its median absolute deviation."""


@dataclass(frozen=True)
class Estimate:
    """One estimated value in `unit`, or the reason why the data cannot determine it.

    `std_error` is the standard error and `interval` the 95 % interval (low, high), both in `unit`;
    `method` says how they were obtained and `n` how many samples (beams, spans, draws...) went in.
    """

    status: Status
    value: float | None = None
    std_error: float | None = None
    interval: tuple[float, float] | None = None
    unit: str = ""
    method: str = ""
    n: int = 0
    reason: str = ""

    @property
    def ok(self) -> bool:
        """Identified: a value with its uncertainty (``ok`` or ``weak``)."""
        return self.status in ("ok", "weak")

    @property
    def weak(self) -> bool:
        return self.status == "weak"

    def flagged(self, low_bound: float, negligible: float = 0.0) -> Estimate:
        """This estimate, ``weak`` where its key cannot go below `low_bound` >= 0 (a scale, a probability, a rate)
        and its interval is wider than its value above that bound; not where the whole interval lies within
        `negligible` of the bound (the key is determined: as good as none)."""
        if self.status != "ok" or self.value is None or self.interval is None or low_bound < 0:
            return self
        if self.interval[1] - low_bound <= negligible:
            return self
        width = self.interval[1] - self.interval[0]
        if width > abs(self.value - low_bound):
            reason = "weakly determined: its 95 % interval is wider than its value"
            return dataclasses.replace(self, status="weak", reason=reason)
        return self

    @staticmethod
    def of(
        value: float,
        std_error: float | None,
        interval: tuple[float, float] | None,
        unit: str,
        method: str,
        n: int,
    ) -> Estimate:
        """An identified value."""
        low_high = None if interval is None else (float(interval[0]), float(interval[1]))
        se = None if std_error is None else float(std_error)
        return Estimate("ok", float(value), se, low_high, unit, method, int(n))

    @staticmethod
    def unidentifiable(reason: str, unit: str = "", n: int = 0) -> Estimate:
        """A value the data cannot determine, with the reason in words."""
        return Estimate("unidentifiable", unit=unit, n=int(n), reason=reason)

    def as_mapping(self) -> dict[str, Any]:
        """Plain YAML-ready mapping: status and either value, std_error, interval_95, method, n or the reason."""
        if not self.ok:
            return {"status": self.status, "reason": self.reason, "unit": self.unit, "n": self.n}
        out: dict[str, Any] = {"status": self.status, "value": _round(self.value), "unit": self.unit}
        out["std_error"] = _round(self.std_error)
        out["interval_95"] = None if self.interval is None else [_round(self.interval[0]), _round(self.interval[1])]
        out["method"] = self.method
        out["n"] = self.n
        if self.weak:
            out["reason"] = self.reason
        return out


def six_digits(x: float) -> float:
    """`x` to six significant digits: how calibration files write numbers."""
    return float(f"{x:.6g}")


def _round(x: float | None) -> float | None:
    if x is None or not math.isfinite(x):
        return None
    return six_digits(x)


def normal_interval(value: float, std_error: float) -> tuple[float, float]:
    """value +- 1.96 standard errors."""
    return value - Z_95 * std_error, value + Z_95 * std_error


def binomial_estimate(events: int, trials: int, unit: str = "probability") -> Estimate:
    """A proportion with its binomial standard error (p (1 - p) kept >= 1 / trials) and 95 % Wilson interval."""
    p = events / trials
    se = math.sqrt(max(p * (1 - p), 1.0 / trials) / trials)
    return Estimate.of(p, se, wilson_interval(events, trials), unit, "binomial (Wilson interval)", trials)


def chi_interval(sigma_hat: float, n: int) -> tuple[float, float]:
    """95 % interval of a normal spread sigma from the root mean square `sigma_hat` of `n` zero-mean draws.

    n sigma_hat^2 / sigma^2 follows chi-square with n degrees of freedom.
    """
    low = sigma_hat * math.sqrt(n / float(stats.chi2.ppf(0.975, n)))
    high = sigma_hat * math.sqrt(n / float(stats.chi2.ppf(0.025, n)))
    return low, high


def bootstrap(
    statistic: Callable[[np.ndarray], np.ndarray], n_clusters: int, resamples: int, rng: np.random.Generator
) -> np.ndarray:
    """(resamples, k) values of `statistic` on cluster weights drawn with replacement.

    `statistic` receives (n_clusters,) integer counts (how often each cluster was drawn) and returns
    a (k,) array; resamples where it returns non-finite values are kept as NaN.
    """
    counts = rng.multinomial(n_clusters, np.full(n_clusters, 1.0 / n_clusters), size=resamples)
    return np.array([statistic(c) for c in counts], dtype=np.float64)


def spread(samples: np.ndarray) -> tuple[float, tuple[float, float]]:
    """Standard error (std) and 2.5-97.5 % percentile interval of bootstrap `samples` (NaN ignored)."""
    good = samples[np.isfinite(samples)]
    if len(good) < 2:
        return math.nan, (math.nan, math.nan)
    low, high = np.percentile(good, [2.5, 97.5])
    return float(np.std(good, ddof=1)), (float(low), float(high))


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``"1 robot-episode"``, ``"3 robot-episodes"``: a count with its noun in the right number."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"
