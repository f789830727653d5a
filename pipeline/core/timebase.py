"""Time units: every time inside the pipeline is an int of nanoseconds, as in ROS 2 stamps."""

from __future__ import annotations

import math

NS_PER_S = 1_000_000_000
NS_PER_MS = 1_000_000
NS_PER_US = 1_000

LAG_LIMIT_NS = 1_000_000_000
"""An episode in which the twin ran behind its clock by more than this (twin time: twice the fleet's staleness limits,
its sensors reach the runner stale; the host stall a twin jumps over) did not keep its time scale. Shorter lags are
a slow link's: the runner's staleness rules already hold them."""
CONTROL_LATE_LIMIT = 1.0
"""An episode whose control steps woke later than this share of the control period (the 95th percentile, on the
fleet's clock) did not keep its clock on the runner's side: a twentieth of its steps acted a whole period late, the
policy ran at another rate than it was trained at. (``--time-scale auto`` aims lower: `pace.AUTO_LATE_TARGET`.)"""
REALIZED_MARGIN = 0.05
"""An episode whose realized time scale falls short of the one asked by more than this share did not keep it."""


def scale_kept(asked: float, realized: float, lag_ns: float) -> bool:
    """The twin kept the time scale `asked`: `realized` no more than `REALIZED_MARGIN` short of it (NaN: not
    measured, not short), never more than `LAG_LIMIT_NS` behind its clock."""
    short = not math.isnan(realized) and realized < asked * (1 - REALIZED_MARGIN)
    return not short and lag_ns <= LAG_LIMIT_NS
