"""Clock offset (s) and drift (ppm) of each robot against the recording host, from one-way stamps.

Model, in host time t (s) with origin t0 = the first message received from the robot (inside the
recording's windows):

    stamp = t_sample + offset + drift * (t_sample - t0)    robot clock: `offset` ahead at t0, `drift` fast
    log   = t_sample + latency,  latency >= 0              host clock, on receipt

so each message's one-way delay y = log - stamp = latency - offset - drift * x, with x = log - t0
(x stands in for t_sample - t0 to within latency * drift, nanoseconds). This is the twin's
``RobotClock``, whose epoch is the twin's start: the two origins differ by seconds at most, which
moves the offset by drift * seconds (under a microsecond).

Drift: latencies are random but never below their floor, so the lower envelope of y falls with
slope -drift. Each topic's messages are cut into time blocks; the lowest delay of each block (a
point on or just above the envelope) is kept, block minima far from a robust line are left out
(corrupt stamps, stalled blocks), and one common slope with an intercept per topic (each topic its
own latency floor: a scan is stamped at the start of its sweep and sent at its end) is fitted by
weighted least squares. Its standard error comes from a bootstrap over the time blocks, so it
grows with the scatter of the envelope about the line rather than shrinking with the message
count; it is widened further for residuals correlated between neighbouring blocks (a clock that
wanders) and for few blocks (Student t).

Offset: a shift of every latency by a constant is a shift of the offset the other way, so one-way
data bound the offset from one side only: latency >= 0 gives offset >= -(the lowest line below
every message). Assuming the quickest message of the robot's quickest topic arrived within
`MAX_QUICKEST_DELIVERY_S` (a wired or loopback link), the offset lies in [bound, bound +
MAX_QUICKEST_DELIVERY_S]. The value reported is the bound itself (quickest delivery 0): with the
twin's network, which adds no latency floor, it is the offset that reproduces the recorded delays.
The interval takes the bound over every slope inside the drift interval and adds the scatter of the
block minima about the line (what a straight line does not explain) on both sides.

A time-scaled fleet: the recorder's clock is its own copy of the fleet's published ``/clock``,
re-anchored on each message and extrapolated at the nominal rate between messages. When the fleet
does not keep its rate (a loaded host) the copy runs ahead or behind between messages by an error
that follows the host's load. The recorded ``/clock`` messages, logged just before they re-anchor
the copy, show that error at its largest: the same envelope fit on them gives the copy's apparent
drift. A robot's envelope holds between none of it (messages logged just after a re-anchoring) and
all of it, so the drift keeps its measured value and its interval spans the measured drift less
none to all of the apparent one. (On twin recordings at 3x, subtracting all of it moved the robots'
drifts away from the truth by up to 20 ppm: the envelope sits near the re-anchoring.)

Only topics stamped by the robot's clock belong here (scan, odom). Ground truth from a motion
capture system is stamped by the host (or the capture system's own clock) and must be left out;
topics that disagree on the drift are named in the notes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from pipeline.calibration.estimates import MAD_TO_SIGMA, Z_95, Estimate, bootstrap, normal_interval, spread
from pipeline.calibration.network import StampStream
from pipeline.calibration.options import CalibrationSettings
from pipeline.core.timebase import NS_PER_S

MAX_QUICKEST_DELIVERY_S = 0.01
"""Assumed upper bound of the robot's quickest delivery (stamp to receipt) on its quickest topic."""
MIN_MESSAGES = 50
"""A topic with fewer messages inside the windows is not used."""
MIN_DRIFT_SPAN_S = 20.0
"""The drift needs a recording spanning at least this long."""
MIN_DRIFT_MINIMA = 8
"""The drift needs at least this many block minima (over the robot's topics)."""
UNMEASURED_DRIFT_PPM = 200.0
"""Largest drift assumed when it cannot be measured (quartz clocks are specified to 100 ppm or better)."""
MIN_BLOCK_S = 2.0
"""Shortest time block."""
MAX_BLOCKS = 30
"""Most time blocks per recording (longer recordings get longer blocks, with lower minima)."""
MIN_BLOCK_MESSAGES = 4
"""A topic's block with fewer messages gives no minimum."""
OUTLIER_SIGMAS = 6.0
"""Block minima further than this many robust standard deviations from a robust line are left out."""
RESOLUTION_S = 1e-6
"""Smallest scatter of block minima assumed (stamps and clocks are not finer than this in practice)."""
MAX_AUTOCORRELATION = 0.8
"""Largest lag-one correlation of neighbouring blocks' residuals used to widen the drift's error."""
SLOPE_GRID = 21
"""Slopes tried across the drift interval when bounding the offset."""


@dataclass(frozen=True)
class ClockFit:
    """Robot clock against the host clock: offset (s, robot ahead, at each robot's first received message)
    and drift (ppm, robot fast).

    `offset_s` and `drift_ppm` pool the robots (their mean; the interval spans every robot's interval,
    so it holds the spread between robots); `per_robot` maps each robot to its (offset_s, drift_ppm).
    """

    offset_s: Estimate
    drift_ppm: Estimate
    per_robot: dict[str, tuple[Estimate, Estimate]]
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class _Delays:
    """One topic's messages, by receipt: host time since t0 (s), one-way delay log - stamp (s), time block."""

    topic: str
    x_s: np.ndarray
    y_s: np.ndarray
    block: np.ndarray


@dataclass(frozen=True)
class _Minima:
    """Block minima, one per (topic, block): time (s), delay (s), topic index, block index."""

    x_s: np.ndarray
    y_s: np.ndarray
    topic: np.ndarray
    block: np.ndarray

    def __len__(self) -> int:
        return len(self.x_s)

    def subset(self, keep: np.ndarray) -> _Minima:
        return _Minima(self.x_s[keep], self.y_s[keep], self.topic[keep], self.block[keep])


def estimate_clock(
    streams_by_robot: Mapping[str, Sequence[StampStream]],
    settings: CalibrationSettings,
    followed: Mapping[str, StampStream] | None = None,
) -> ClockFit:
    """Offset (s) and drift (ppm) of each robot's clock against the host's, and of the fleet.

    Args:
        streams_by_robot: robot name -> its sensor topics stamped by the robot's own clock (stamp_ns
            in the robot's clock, log_ns in the host's, both int ns; only messages received inside
            the windows count). Topics stamped by the host, such as motion-capture ground truth,
            must not be among them.
        settings: `bootstrap` resamples and `seed` of the drift's uncertainty.
        followed: robot name -> the ``/clock`` its recorder followed (stamp = value, log = the recorder's
            reading on receipt), for robots recorded on a time-scaled fleet's clock.

    The offset is known only up to the quickest delivery: its interval assumes that took at most
    `MAX_QUICKEST_DELIVERY_S`, and its value assumes it took none.
    """
    rng = np.random.default_rng(settings.seed)
    per_robot: dict[str, tuple[Estimate, Estimate]] = {}
    notes: list[str] = [
        f"offset: one-way delays bound it from below only; the interval assumes each robot's quickest "
        f"message arrived within {MAX_QUICKEST_DELIVERY_S} s, the value that it arrived at once"
    ]
    for robot in sorted(streams_by_robot):
        offset, drift, robot_notes = _robot_clock(robot, streams_by_robot[robot], settings, rng)
        reference = (followed or {}).get(robot)
        if reference is not None:
            drift, reference_note = _take_in_follower(robot, drift, reference, settings, rng)
            robot_notes.append(reference_note)
        per_robot[robot] = (offset, drift)
        notes += robot_notes
    offset = _pool([o for o, _ in per_robot.values()], "s")
    drift = _pool([d for _, d in per_robot.values()], "ppm")
    if drift.ok and len([d for _, d in per_robot.values() if d.ok]) > 1:
        values = [f"{d.value:.1f}" for _, d in per_robot.values() if d.ok and d.value is not None]
        notes.append(f"drift per robot (ppm): {', '.join(values)}")
    return ClockFit(offset, drift, per_robot, tuple(notes))


def _robot_clock(
    robot: str, streams: Sequence[StampStream], settings: CalibrationSettings, rng: np.random.Generator
) -> tuple[Estimate, Estimate, list[str]]:
    """(offset_s, drift_ppm, notes) of one robot from its topics."""
    selected: list[tuple[str, np.ndarray, np.ndarray]] = []
    notes: list[str] = []
    for stream in streams:
        stamp_ns, log_ns = _received(stream)
        if len(stamp_ns) >= MIN_MESSAGES:
            selected.append((stream.topic, stamp_ns, log_ns))
        else:
            notes.append(f"{robot}: {stream.topic} left out ({len(stamp_ns)} messages, fewer than {MIN_MESSAGES})")
    if not selected:
        reason = f"no topic of {robot} has {MIN_MESSAGES} messages inside the episodes"
        return Estimate.unidentifiable(reason, "s"), Estimate.unidentifiable(reason, "ppm"), notes
    t0_ns = min(int(log[0]) for _, _, log in selected)
    span_s = max(int(log[-1]) for _, _, log in selected) / NS_PER_S - t0_ns / NS_PER_S
    n_blocks = int(min(max(span_s // MIN_BLOCK_S, 1), MAX_BLOCKS))
    width_s = span_s / n_blocks if span_s > 0 else 1.0
    topics: list[_Delays] = []
    for topic, stamp_ns, log_ns in selected:
        x = (log_ns - t0_ns) / NS_PER_S
        y = (log_ns - stamp_ns) / NS_PER_S
        block = np.minimum((x / width_s).astype(np.int64), n_blocks - 1)
        topics.append(_Delays(topic, x, y, block))
    minima = _block_minima(topics)
    measurable = span_s >= MIN_DRIFT_SPAN_S and len(minima) >= MIN_DRIFT_MINIMA
    keep, sigma = _inliers(minima, _robust_slope(minima), len(topics))
    left_out = _blocks_by_topic(minima.subset(~keep), len(topics))
    minima = minima.subset(keep)
    measurable = measurable and len(minima) >= MIN_DRIFT_MINIMA
    count = sum(len(t.x_s) for t in topics)
    n_minima = len(minima)
    summary = (
        f"{robot}: {len(topics)} topics, {count} messages over {span_s:.1f} s from t0 = {t0_ns} ns (host clock), "
        f"{n_blocks} blocks of {width_s:.1f} s, {n_minima} block minima"
    )
    n_left_out = sum(len(b) for b in left_out)
    notes.append(summary + (f" ({n_left_out} far from the line left out)" if n_left_out else ""))
    if measurable:
        drift, slope, slope_half = _drift(minima, sigma, len(topics), settings, rng)
        slopes = np.unique(np.r_[np.linspace(slope - slope_half, slope + slope_half, SLOPE_GRID), slope])
        notes += _disagreements(robot, topics, minima, sigma, slope, slope_half)
    else:
        reason = (
            f"{robot}'s recording spans {span_s:.1f} s with {n_minima} block minima; the drift needs "
            f"{MIN_DRIFT_SPAN_S:.0f} s and {MIN_DRIFT_MINIMA}"
        )
        drift = Estimate.unidentifiable(reason, "ppm", n_minima)
        slope = 0.0
        bound = UNMEASURED_DRIFT_PPM * 1e-6
        slopes = np.linspace(-bound, bound, SLOPE_GRID)
    offset, offset_notes = _offset(robot, topics, minima, left_out, slope, slopes)
    notes += offset_notes
    if not measurable:
        notes.append(f"{robot}: offset bounded for any drift within +-{UNMEASURED_DRIFT_PPM:.0f} ppm")
    return offset, drift, notes


def _take_in_follower(
    robot: str, drift: Estimate, reference: StampStream, settings: CalibrationSettings, rng: np.random.Generator
) -> tuple[Estimate, str]:
    """A robot's drift measured against a recorder that followed a published clock: the copy's error at the
    envelope lies between none (a message logged just after a re-anchoring) and the error the ``/clock``
    messages show (logged just before one), so the drift lies between the one measured and that less the copy's
    apparent drift. The value is the one measured; the interval spans both."""
    _, apparent, _ = _robot_clock(f"{robot} /clock", [reference], settings, rng)
    if not drift.ok or drift.value is None:
        return drift, f"{robot}: drift not measured, so the followed /clock's extrapolation is not bounded"
    if not apparent.ok or apparent.value is None or drift.interval is None:
        reason = (
            f"measured against a recorder that followed a published /clock whose extrapolation error could not be "
            f"measured ({apparent.reason or 'no interval'}), so the slope may be the copy's, not the robot's"
        )
        return Estimate.unidentifiable(reason, drift.unit, drift.n), f"{robot}: {reason}"
    a_lo, a_hi = apparent.interval or (apparent.value, apparent.value)
    d_lo, d_hi = drift.interval
    low, high = min(d_lo, d_lo - a_hi), max(d_hi, d_hi - a_lo)
    se = max(drift.std_error or 0.0, (high - low) / (2 * Z_95))
    method = (
        f"{drift.method}; the interval spans the drift less none to all of the followed /clock's apparent drift "
        f"{apparent.value:+.1f} ppm (the copy's extrapolation error, read before each re-anchoring)"
    )
    note = (
        f"{robot}: the recorder's copy of the published /clock, read just before each re-anchoring, runs "
        f"{apparent.value:+.1f} ppm [{a_lo:+.1f}, {a_hi:+.1f}] against it; the robot's envelope holds between none "
        f"and all of it, so its drift {drift.value:+.1f} ppm has the interval [{low:+.1f}, {high:+.1f}]"
    )
    return Estimate.of(drift.value, se, (low, high), drift.unit, method, drift.n), note


def _blocks_by_topic(minima: _Minima, n_topics: int) -> list[set[int]]:
    """For each topic, the blocks of `minima`."""
    out: list[set[int]] = [set() for _ in range(n_topics)]
    for k, b in zip(minima.topic.tolist(), minima.block.tolist(), strict=True):
        out[k].add(b)
    return out


def _received(stream: StampStream) -> tuple[np.ndarray, np.ndarray]:
    """(stamps, log times) int ns of the messages received inside the windows, by receipt, each stamp once."""
    inside = stream.inside()
    stamp_ns = np.asarray(stream.stamp_ns, dtype=np.int64)[inside]
    log_ns = np.asarray(stream.log_ns, dtype=np.int64)[inside]
    order = np.argsort(log_ns, kind="stable")
    stamp_ns, log_ns = stamp_ns[order], log_ns[order]
    _, first = np.unique(stamp_ns, return_index=True)  # a stamp received twice counts at its first receipt
    first.sort()
    return stamp_ns[first], log_ns[first]


def _block_minima(topics: Sequence[_Delays]) -> _Minima:
    """The lowest delay of each (topic, block) holding at least `MIN_BLOCK_MESSAGES` messages."""
    xs: list[float] = []
    ys: list[float] = []
    ks: list[int] = []
    bs: list[int] = []
    for k, t in enumerate(topics):
        order = np.lexsort((t.y_s, t.block))  # by block, lowest delay first
        blocks, start, size = np.unique(t.block[order], return_index=True, return_counts=True)
        for b, i, n in zip(blocks.tolist(), start.tolist(), size.tolist(), strict=True):
            if n >= MIN_BLOCK_MESSAGES:
                j = order[i]
                xs.append(float(t.x_s[j]))
                ys.append(float(t.y_s[j]))
                ks.append(k)
                bs.append(b)
    return _Minima(np.asarray(xs), np.asarray(ys), np.asarray(ks, dtype=np.int64), np.asarray(bs, dtype=np.int64))


def _robust_slope(minima: _Minima) -> float:
    """Median of the topics' Theil-Sen slopes of delay against time (s/s)."""
    slopes = []
    for k in np.unique(minima.topic):
        sel = minima.topic == k
        if sel.sum() >= 3:
            slopes.append(float(stats.theilslopes(minima.y_s[sel], minima.x_s[sel]).slope))
    return float(np.median(slopes)) if slopes else 0.0


def _inliers(minima: _Minima, slope: float, n_topics: int) -> tuple[np.ndarray, np.ndarray]:
    """Block minima within `OUTLIER_SIGMAS` robust deviations of their topic's line of `slope`, and each
    topic's robust scatter (s, at least `RESOLUTION_S`)."""
    keep = np.ones(len(minima), dtype=bool)
    sigma = np.full(n_topics, RESOLUTION_S)
    for k in range(n_topics):
        sel = minima.topic == k
        if not sel.any():
            continue
        r = minima.y_s[sel] - slope * minima.x_s[sel]
        center = float(np.median(r))
        sigma[k] = max(MAD_TO_SIGMA * float(np.median(np.abs(r - center))), RESOLUTION_S)
        keep[sel] = np.abs(r - center) <= OUTLIER_SIGMAS * sigma[k]
    return keep, sigma


def _common_slope(
    x: np.ndarray, y: np.ndarray, group: np.ndarray, w: np.ndarray, n_groups: int
) -> tuple[float, np.ndarray]:
    """Weighted least squares of y = intercept[group] + slope * x: (slope, (n_groups,) intercepts)."""
    sw = np.bincount(group, w, n_groups)
    has = sw > 0
    xm = np.divide(np.bincount(group, w * x, n_groups), sw, out=np.zeros(n_groups), where=has)
    ym = np.divide(np.bincount(group, w * y, n_groups), sw, out=np.zeros(n_groups), where=has)
    dx = x - xm[group]
    sxx = float(np.sum(w * dx * dx))
    if not sxx > 0:
        return math.nan, np.full(n_groups, math.nan)
    slope = float(np.sum(w * dx * (y - ym[group]))) / sxx
    return slope, ym - slope * xm


def _drift(
    minima: _Minima, sigma: np.ndarray, n_topics: int, settings: CalibrationSettings, rng: np.random.Generator
) -> tuple[Estimate, float, float]:
    """The drift estimate, the fitted slope of delay against time (s/s) and the half-width of its 95 % interval."""
    base_w = 1.0 / sigma[minima.topic] ** 2
    slope, intercepts = _common_slope(minima.x_s, minima.y_s, minima.topic, base_w, n_topics)
    blocks, cluster = np.unique(minima.block, return_inverse=True)

    def statistic(counts: np.ndarray) -> np.ndarray:
        return np.array([_common_slope(minima.x_s, minima.y_s, minima.topic, base_w * counts[cluster], n_topics)[0]])

    samples = bootstrap(statistic, len(blocks), settings.bootstrap, rng)
    se_boot, _ = spread(samples[:, 0])
    residual = minima.y_s - intercepts[minima.topic] - slope * minima.x_s
    rho = _neighbour_correlation(minima, residual / sigma[minima.topic])
    n_fitted = len(np.unique(minima.topic))
    dof = max(len(minima) - n_fitted - 1, 1)
    widen = math.sqrt((1 + rho) / (1 - rho)) * float(stats.t.ppf(0.975, dof)) / Z_95
    se = se_boot * widen
    drift_ppm = -slope * 1e6
    method = (
        "slope of the lower envelope of log - stamp: least squares through block minima (an intercept per topic); "
        f"error from a bootstrap over {len(blocks)} time blocks, widened for neighbouring blocks' correlation "
        f"({rho:.2f}) and Student t ({dof} dof)"
    )
    if not math.isfinite(se):
        return Estimate.of(drift_ppm, None, None, "ppm", method, len(minima)), slope, 0.0
    se_ppm = se * 1e6
    drift = Estimate.of(drift_ppm, se_ppm, normal_interval(drift_ppm, se_ppm), "ppm", method, len(minima))
    return drift, slope, Z_95 * se


def _neighbour_correlation(minima: _Minima, z: np.ndarray) -> float:
    """Lag-one correlation of one topic's standardised residuals in neighbouring blocks, in [0, MAX_AUTOCORRELATION]."""
    num = 0.0
    for k in np.unique(minima.topic):
        sel = np.flatnonzero(minima.topic == k)
        sel = sel[np.argsort(minima.block[sel])]
        nb = np.diff(minima.block[sel]) == 1
        num += float(np.sum(z[sel][:-1][nb] * z[sel][1:][nb]))
    den = float(np.sum(z * z))
    rho = num / den if den > 0 else 0.0
    return min(max(rho, 0.0), MAX_AUTOCORRELATION)


def _offset(
    robot: str,
    topics: Sequence[_Delays],
    minima: _Minima,
    left_out: Sequence[set[int]],
    slope: float,
    slopes: np.ndarray,
) -> tuple[Estimate, list[str]]:
    """The offset (s) at t0: the lower bound from the lowest line below every message (but those in blocks
    whose minimum was left out), over `slopes`."""
    notes: list[str] = []
    floors = np.full((len(topics), len(slopes) + 1), math.inf)  # column 0: the fitted slope
    trial = np.r_[slope, slopes]
    count = 0
    for k, t in enumerate(topics):
        sel = ~np.isin(t.block, np.fromiter(left_out[k], dtype=np.int64, count=len(left_out[k])))
        if not sel.any():
            continue
        count += int(sel.sum())
        # lowest intercept c with c + s x <= y for every message: min over messages of y - s x
        floors[k] = np.min(t.y_s[sel][:, None] - t.x_s[sel][:, None] * trial[None, :], axis=0)
    if not np.isfinite(floors[:, 0]).any():
        reason = f"every block of {robot} was left out as far from the line"
        return Estimate.unidentifiable(reason, "s"), notes
    quickest = int(np.argmin(floors[:, 0]))
    bound = -np.min(floors, axis=0)  # offset >= bound (every latency >= 0)
    sel = minima.topic == quickest
    r = minima.y_s[sel] - slope * minima.x_s[sel]
    scatter = float(np.std(r, ddof=1)) if sel.sum() >= 2 else 0.0
    value = float(bound[0])
    low = float(np.min(bound[1:])) - Z_95 * scatter
    high = float(np.max(bound[1:])) + MAX_QUICKEST_DELIVERY_S + Z_95 * scatter
    method = (
        f"lower bound from the lowest line below {topics[quickest].topic}'s delays (quickest delivery 0); interval: "
        f"that bound over the drift interval, plus up to {MAX_QUICKEST_DELIVERY_S} s of quickest delivery, "
        f"+- 1.96 x the scatter of block minima about the line ({scatter:.2e} s); std_error: half-width / 1.96"
    )
    notes.append(f"{robot}: quickest topic {topics[quickest].topic}")
    for k, t in enumerate(topics):
        if k != quickest and math.isfinite(floors[k, 0]):
            later = float(floors[k, 0] - floors[quickest, 0])
            notes.append(
                f"{robot}: {t.topic}'s lowest delays lie {later:.4f} s above the quickest topic's "
                "(sent later after sampling, or a slower link)"
            )
    return Estimate.of(value, (high - low) / (2 * Z_95), (low, high), "s", method, count), notes


def _disagreements(
    robot: str, topics: Sequence[_Delays], minima: _Minima, sigma: np.ndarray, slope: float, slope_half: float
) -> list[str]:
    """Notes naming topics whose own drift differs from the robot's by more than both errors allow.

    A topic stamped by another clock (the host's, a capture system's) shows up here.
    """
    notes: list[str] = []
    for k, t in enumerate(topics):
        sel = minima.topic == k
        if sel.sum() < 3:
            continue
        x, y = minima.x_s[sel], minima.y_s[sel]
        line = np.polyfit(x, y, 1)
        own = float(line[0])
        scatter = max(float(np.std(y - np.polyval(line, x), ddof=2)), float(sigma[k]))
        se = scatter / math.sqrt(float(np.sum((x - x.mean()) ** 2)))
        if abs(own - slope) > 2 * Z_95 * se + slope_half:
            notes.append(
                f"{robot}: {t.topic} alone gives a drift of {-own * 1e6:.1f} ppm against the robot's "
                f"{-slope * 1e6:.1f} ppm; is it stamped by the robot's clock?"
            )
    return notes


def _pool(estimates: Sequence[Estimate], unit: str) -> Estimate:
    """The fleet's value: the mean of the robots' values; its interval spans every robot's interval
    and its standard error combines the spread between robots with their own errors."""
    good = [e for e in estimates if e.ok and e.value is not None]
    if not good:
        reasons = sorted({e.reason for e in estimates if e.reason}) or ["no robots"]
        return Estimate.unidentifiable("; ".join(reasons), unit)
    values = np.array([e.value for e in good], dtype=np.float64)
    errors = np.array([e.std_error if e.std_error is not None else math.nan for e in good])
    between = float(np.var(values, ddof=1)) if len(values) > 1 else 0.0
    se = math.sqrt(between + float(np.mean(errors**2))) if np.all(np.isfinite(errors)) else None
    intervals = [e.interval for e in good if e.interval is not None]
    interval = (min(i[0] for i in intervals), max(i[1] for i in intervals)) if len(intervals) == len(good) else None
    left = len(estimates) - len(good)
    method = f"mean over {len(good)} robots; interval spans every robot's interval" + (
        f" ({left} robots unidentifiable)" if left else ""
    )
    return Estimate.of(float(values.mean()), se, interval, unit, method, sum(e.n for e in good))
