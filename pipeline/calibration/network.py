"""Message loss and delivery jitter of the robots' sensor topics, and the rates of the sensors.

The network model is the twin's: each message is lost independently with probability p, and
delivered after a delay spread uniformly over [base, base + jitter].

Ticks: topics that share their sender's clock ticks (the same stamps appear on several topics, as
when one driver publishes every robot's data in one tick) are compared against the union of their
stamps: a stamp one topic lacks is a message lost on it, even when the ticks are irregular. Other
topics are read by stamp gaps: a gap of about k periods (the period is the median gap) means k - 1
messages were lost; gaps longer than `network_max_gap_s` are pauses, not losses.

Loss: a receiver that stalls (a busy host) drops bursts of consecutive messages, which are not
the network's independent losses. So p comes from isolated losses only: with independent losses
a message is lost while both its neighbours arrive with probability p (1 - p)^2, which is solved
for p. All missing messages (bursts included) are reported in the notes.

Jitter: a message's delay is its receive (log) time minus its stamp. Stalls of the receiver delay
every message waiting at the time alike, so for topics sharing ticks the jitter comes from the
difference of two topics' delays for the same stamp, which cancels them: the difference of two
independent uniform delays on [0, J] has an interquartile range of (2 - sqrt 2) J. Topics without
a partner fall back to twice the interquartile range of their own delays, which includes the
receiver's stalls. A receiver that stalls also logs messages of one tick together that arrived apart, which
shrinks their small differences, and logs late ones later, which stretches the large ones: where the jitter read
from the 0.5 (the interquartile rule), 0.75 and 0.9 quantiles of the differences' size disagree beyond the
interquartile rule's bootstrap interval, the value is the median of the three readings, the interval is widened to
hold them all, and a note says so.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from pipeline.calibration.estimates import MAD_TO_SIGMA, Z_95, Estimate, bootstrap, spread
from pipeline.calibration.options import CalibrationSettings
from pipeline.core.stats import wilson_interval
from pipeline.core.timebase import NS_PER_S

MIN_MESSAGES = 50
SHARED_TICKS = 0.5
"""Topics of one period whose stamps appear on another topic at least this often share their sender's ticks."""
TRIANGULAR_IQR = 2.0 - math.sqrt(2.0)
"""Interquartile range of the difference of two independent uniform [0, 1] variables."""
BURST_PERIODS = 20
"""A gap of up to this many sending periods is lost messages (longer: the sender paused)."""
MIN_LOSS_CLUSTERS = 5
"""Topic-episodes needed to resample the loss over them."""
MAX_ISOLATED_SHARE = 4.0 / 27.0
RUN_BREAK_MADS = 6.0
"""A gap off the fitted period by more than this many robust deviations ends its run of regular sending..."""
GRID_MIN_COUNT = 3
"""A gap deviation seen this often is a level of the stamps' grid."""
RUN_BREAK_MIN_S = 2e-6
"""...or by more than this (stamps exact to the nanosecond have no spread)."""
"""The largest value of p (1 - p)^2 (at p = 1/3)."""


@dataclass(frozen=True)
class StampStream:
    """One sensor topic of one robot: stamps (n,) as sent and log times (n,) as received, int ns.

    `windows` are the (start, end) log times of its recording's episodes; only messages received
    inside them count (None: all).
    """

    topic: str
    stamp_ns: np.ndarray
    log_ns: np.ndarray
    windows: tuple[tuple[int, int], ...] | None = None

    def inside(self) -> np.ndarray:
        """(n,) messages received inside the windows."""
        if self.windows is None:
            return np.ones(len(self.log_ns), dtype=bool)
        out = np.zeros(len(self.log_ns), dtype=bool)
        for a, b in self.windows:
            out |= (self.log_ns >= a) & (self.log_ns <= b)
        return out


@dataclass(frozen=True)
class NetworkFit:
    """Loss probability, jitter (s) and the mean length of a run of lost messages."""

    loss_prob: Estimate
    jitter_s: Estimate
    notes: tuple[str, ...] = ()
    burst_len: Estimate = field(default_factory=lambda: Estimate.unidentifiable("not estimated", "messages"))


def period_s(stamp_ns: np.ndarray) -> float | None:
    """The sending period (s): the median gap between consecutive distinct stamps; None with fewer than 3."""
    s = np.unique(np.asarray(stamp_ns, dtype=np.int64))
    if len(s) < 3:
        return None
    return float(np.median(np.diff(s))) / NS_PER_S


def _slope_over_runs(t: np.ndarray, regular: np.ndarray, steps: np.ndarray) -> tuple[float, float, list[np.ndarray]]:
    """Period (s), its standard error and the runs' centred indices: one slope of stamp `t` on message index over
    the runs of `regular` gaps (`steps` periods each), each run with its own start."""
    run = np.r_[0, np.cumsum(~regular)]
    index = np.r_[0.0, np.cumsum(np.where(regular, steps, 0.0))]
    xs, ys = [], []
    for r in np.unique(run):
        sel = run == r
        if sel.sum() < 3:
            continue
        xs.append(index[sel] - index[sel].mean())
        ys.append(t[sel] - t[sel].mean())
    if not xs:
        return math.nan, math.nan, []
    x, y = np.concatenate(xs), np.concatenate(ys)
    sxx = float(x @ x)
    if sxx <= 0:
        return math.nan, math.nan, []
    slope = float(x @ y) / sxx
    resid = y - slope * x
    dof = max(len(x) - len(xs) - 1, 1)
    return slope, math.sqrt(float(resid @ resid) / dof / sxx), xs


def _grid_s(deviation_s: np.ndarray, steps: np.ndarray) -> float:
    """The step of the grid the stamps fall on (s; 0 if none): the smallest spacing of the gaps' deviations from
    the period (in microseconds) among the values that recur (at least `GRID_MIN_COUNT` times; a gap cut short by
    a reset is a value of its own, not a grid level), compared among gaps of the same number of periods (one and
    two periods differ by the period's own error, which is no grid)."""
    spacings: list[float] = []
    for k in np.unique(steps):
        levels, counts = np.unique(np.round(deviation_s[steps == k] * 1e6), return_counts=True)
        common = levels[counts >= GRID_MIN_COUNT]
        if len(common) >= 2:
            spacings.append(float(np.diff(common).min()))
    return min(spacings) * 1e-6 if spacings else 0.0


def _runs_period(ticks: np.ndarray, period0: float) -> tuple[float, float, int] | None:
    """(period s, its standard error, gaps used) from stamps `ticks` (ns): each stamp's index in its run of
    regular sending (gaps near whole multiples of `period0`, losses allowed), then one slope of stamp on
    index over all runs (each with its own start). A sender whose stamps fall on a coarser grid (24 and
    26 ms apart for 40 Hz on a 2 ms grid) still gets its mean period, where a median gap would not. A gap
    that the first slope cannot explain (off by more than `RUN_BREAK_MADS` robust deviations of the gaps and
    1.5 grid steps; e.g. a sweep cut short by a reset, 1.2 periods long) ends its run, and the slope is fitted
    again."""
    t = (ticks - ticks[0]) / NS_PER_S
    gaps = np.diff(t)
    steps = np.round(gaps / period0)
    regular = (steps >= 1) & (steps <= 10) & (np.abs(gaps / period0 - steps) < 0.25)
    slope, se, xs = _slope_over_runs(t, regular, steps)
    if not xs:
        return None
    deviation = gaps - steps * slope
    grid_s = _grid_s(deviation[regular], steps[regular])
    spread_s = MAD_TO_SIGMA * float(np.median(np.abs(deviation[regular])))
    regular &= np.abs(deviation) <= max(RUN_BREAK_MADS * spread_s, 1.5 * grid_s, RUN_BREAK_MIN_S)
    refit = _slope_over_runs(t, regular, steps)
    if refit[2]:
        slope, se, xs = refit
    # stamps on a grid (a sender that stamps at its physics steps) fix each run's ends only to a grid step, so
    # the period is no more certain than one grid step over a typical run, whatever the message count
    grid_s = max(_grid_s((gaps - steps * slope)[regular], steps[regular]), 1e-9)  # stamps are whole nanoseconds
    spans = [float(np.ptp(i)) * slope for i in xs]
    if grid_s > 0 and spans and np.median(spans) > 0:
        se = max(se, grid_s / float(np.median(spans)) * slope)
    # a period that wanders from one message to the next (a lidar's motor) makes the stamps a random walk, not a line
    # with noise on it: the slope's error is then the gaps' spread over the square root of their number
    per_step = (gaps / np.maximum(steps, 1) - slope)[regular]
    if len(per_step) > 1:
        se = max(se, float(np.std(per_step, ddof=1)) / math.sqrt(len(per_step)))
    return slope, se, sum(len(i) for i in xs)


def rate_estimate(streams: Sequence[np.ndarray], unit: str = "Hz") -> Estimate:
    """The sending rate (Hz) of one sensor on several robots, from their stamps (one (n,) array per robot).

    Streams sharing their sender's ticks are merged first (their union has no lost messages); the
    period is the slope of stamp on message index over the runs of regular sending (see
    :func:`_runs_period`), the median over groups; the interval spans the groups' values and their errors.
    """
    stamps = [np.unique(np.asarray(s, dtype=np.int64)) for s in streams if len(s) >= 3]
    if not stamps:
        return Estimate.unidentifiable("fewer than 3 messages on the topic", unit)
    rates: list[float] = []
    ses: list[float] = []
    count = 0
    for group in _shared_groups(stamps):
        ticks = np.unique(np.concatenate([stamps[i] for i in group]))
        gaps = np.diff(ticks) / NS_PER_S
        period0 = float(np.median(gaps))
        fitted = _runs_period(ticks, period0)
        if fitted is None:
            q25, q75 = np.percentile(gaps, [25, 75])
            period, se_period, n = period0, 1.2533 * (q75 - q25) / 1.349 / math.sqrt(len(gaps)), len(gaps)
        else:
            period, se_period, n = fitted
        rates.append(1.0 / period)
        ses.append(se_period / period**2)
        count += n
    rate = float(np.median(rates))
    se = float(np.median(ses))
    interval = (min(rates) - 1.96 * max(ses), max(rates) + 1.96 * max(ses))
    return Estimate.of(rate, se, interval, unit, "stamp on message index over runs of regular sending", count)


RESET_PAUSE_NS = 1_000_000
"""Episodes further apart than this (1 ms) have a reset's pause between them."""
OUTLIER_MADS = 6.0
"""A period further than this many robust deviations from its stream's is a restart, not the sensor's wander."""
WANDER_FLOOR = 1e-4
"""Relative spreads of the sweep period below this are not told apart from a steady one."""


def rate_wander_estimate(streams: Sequence[np.ndarray]) -> Estimate:
    """The relative spread of a sensor's period from one sweep to the next (a lidar's motor speed wandering), from
    the stamps of each robot's stream: gaps of about one period (a lost message's longer gap and a restart's left
    out), each over its stream's mean, their root mean square about 1; the interval chi-square's (n - k degrees of
    freedom for k streams), at least up to `WANDER_FLOOR`. Stamps taken at reception rather than at the sweep's
    start add their own jitter to it."""
    unit = "relative"
    deviations: list[np.ndarray] = []
    for s in streams:
        t = np.unique(np.asarray(s, dtype=np.int64))
        if len(t) < 10:
            continue
        gaps = np.diff(t).astype(np.float64)
        single = np.abs(gaps / np.median(gaps) - 1) < 0.25
        if single.sum() < 10:
            continue
        g = gaps[single]
        x = g / np.median(g) - 1
        # a sensor restarted (an episode's reset) leaves one gap of any length: far outside the others' spread
        scale = MAD_TO_SIGMA * float(np.median(np.abs(x - np.median(x))))
        x = x[np.abs(x - np.median(x)) <= max(OUTLIER_MADS * scale, 1e-9)]
        deviations.append(x - x.mean())
    if not deviations:
        return Estimate.unidentifiable("fewer than 10 periods of one length on any stream", unit)
    d = np.concatenate(deviations)
    dof = max(len(d) - len(deviations), 1)
    rms = math.sqrt(float(np.sum(d**2)) / dof)
    lo = rms * math.sqrt(dof / float(stats.chi2.ppf(0.975, dof)))
    hi = max(rms * math.sqrt(dof / float(stats.chi2.ppf(0.025, dof))), WANDER_FLOOR)
    method = f"root mean square of {len(d)} single periods about their stream's mean (chi-square interval)"
    return Estimate.of(rms, rms / math.sqrt(2 * dof), (lo, hi), unit, method, len(d))


def _gap_missing(stamp_ns: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Per gap between consecutive stamps (sorted, distinct): the messages missing in it (0 for a pause)."""
    s = np.asarray(stamp_ns, dtype=np.int64)
    p = period_s(s)
    if p is None:
        return np.zeros(max(len(s) - 1, 0), dtype=np.int64)
    gaps = np.diff(s) / NS_PER_S
    inside = gaps <= max(max_gap_s, BURST_PERIODS * p)
    return np.where(inside, np.maximum(np.round(gaps / p).astype(np.int64) - 1, 0), 0)


def _episode_of(log_ns: np.ndarray, windows: tuple[tuple[int, int], ...] | None) -> np.ndarray:
    """(n,) index of the window each log time falls in (0 without windows; -1 outside them all)."""
    if windows is None:
        return np.zeros(len(log_ns), dtype=np.int64)
    out = np.full(len(log_ns), -1, dtype=np.int64)
    for k, (a, b) in enumerate(windows):
        out[(log_ns >= a) & (log_ns <= b)] = k
    return out


def _tick_runs(own: np.ndarray, ticks: np.ndarray) -> np.ndarray:
    """Lengths of the runs of `ticks` missing from the stream's stamps `own`."""
    missing = ~np.isin(ticks, own)
    edges = np.diff(np.r_[0, missing.astype(np.int8), 0])
    return np.asarray(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1))


def _shared_groups(stamps: Sequence[np.ndarray]) -> list[list[int]]:
    """Indices of streams grouped by shared ticks (same period, stamps found on the group's other topics)."""
    periods = [period_s(s) for s in stamps]
    groups: dict[int, list[int]] = {}
    for i, p in enumerate(periods):
        if p is not None:
            groups.setdefault(round(math.log(p) * 50), []).append(i)  # periods within 2 %
    out: list[list[int]] = []
    for members in groups.values():
        # streams are linked when one's stamps are mostly the other's; groups are the linked components (so two
        # sensors at about the same rate on different clocks, each shared by several robots, stay two groups)
        parent = {m: m for m in members}
        for a, i in enumerate(members):
            for j in members[a + 1 :]:
                if np.isin(stamps[i], stamps[j]).sum() >= SHARED_TICKS * min(len(stamps[i]), len(stamps[j])):
                    parent[_root(parent, j)] = _root(parent, i)
        components: dict[int, list[int]] = {}
        for m in members:
            components.setdefault(_root(parent, m), []).append(m)
        out.extend(components.values())
    return out


def _root(parent: dict[int, int], m: int) -> int:
    while parent[m] != m:
        m = parent[m]
    return m


def isolated_loss(isolated: int, expected: int) -> Estimate:
    """Loss probability p of independent losses from the number of isolated losses among `expected` messages.

    Solves p (1 - p)^2 = isolated / expected on [0, 1/3]; the 95 % interval maps the Wilson interval of
    that share, the standard error follows the delta method.
    """
    share = isolated / expected

    def invert(q: float) -> float:
        q = min(max(q, 0.0), MAX_ISOLATED_SHARE)
        if q == 0.0:
            return 0.0
        lo, hi = 0.0, 1.0 / 3.0
        for _ in range(60):
            mid = (lo + hi) / 2
            if mid * (1 - mid) ** 2 < q:
                lo = mid
            else:
                hi = mid
        return (lo + hi) / 2

    p = invert(share)
    slope = (1 - p) * (1 - 3 * p)
    se_share = math.sqrt(max(share * (1 - share), 1.0 / expected) / expected)
    se = se_share / slope if slope > 1e-6 else math.inf
    low, high = wilson_interval(isolated, expected)
    method = "isolated losses, p (1 - p)^2 = share of lost messages with both neighbours received (Wilson interval)"
    return Estimate.of(p, se, (invert(low), invert(high)), "probability", method, expected)


@dataclass
class _Runs:
    """The loss runs counted so far, one entry per topic-episode (the bootstrap's clusters): each run's length of lost
    messages, the messages expected, the runs that ended inside the episode; and all messages expected."""

    runs: list[np.ndarray] = field(default_factory=list)
    expected_per_run: list[int] = field(default_factory=list)
    ended: list[int] = field(default_factory=list)
    expected: int = 0

    def add(self, run: np.ndarray, expected: int, ended: int) -> None:
        self.runs.append(run)
        self.expected_per_run.append(expected)
        self.ended.append(ended)
        self.expected += expected


def estimate_network(
    streams: Sequence[StampStream], settings: CalibrationSettings, rng: np.random.Generator
) -> NetworkFit:
    """Loss probability and jitter (s) of sensor `streams`, from the messages received inside their windows.

    Topics that share their ticks (a twin's scans and odometry stamped together) are read together: a tick lost is
    one no topic of the group received in its episode, and the jitter is the spread of two topics' delay
    differences (:func:`_shared_ticks`); a topic of its own is read from the gaps in its stamps and its own delays
    (:func:`_own_ticks`)."""
    kept: list[StampStream] = []
    received: list[np.ndarray] = []
    for stream in streams:
        inside = stream.inside()
        if inside.sum() >= MIN_MESSAGES:
            _, first = np.unique(stream.stamp_ns[inside], return_index=True)
            kept.append(
                StampStream(stream.topic, stream.stamp_ns[inside][first], stream.log_ns[inside][first], stream.windows)
            )
            received.append(np.unique(stream.stamp_ns))
    if not kept:
        reason = f"fewer than {MIN_MESSAGES} sensor messages per topic inside episodes"
        return NetworkFit(Estimate.unidentifiable(reason, "probability"), Estimate.unidentifiable(reason, "s"))
    counted_runs = _Runs()
    pair_jitter: list[float] = []
    pair_shape: list[np.ndarray] = []
    own_jitter: list[float] = []
    for group in _shared_groups([k.stamp_ns for k in kept]):
        if len(group) > 1:
            _shared_ticks([kept[i] for i in group], [received[i] for i in group], counted_runs, pair_jitter, pair_shape)
        else:
            own_jitter.append(_own_ticks(kept[group[0]], settings, counted_runs))
    runs, expected = counted_runs.runs, counted_runs.expected
    all_runs = np.concatenate(runs) if runs else np.zeros(0, dtype=np.int64)
    isolated = int(np.sum(all_runs == 1))
    lost = int(all_runs.sum())
    # every message the receiver never got counts (dropped on the wire, in a burst, or by a stalled receiver's
    # full queue: the policy misses it all the same); with too few topic-episodes to resample, the
    # isolated-loss estimate of independent losses
    loss, burst = _burst_loss(runs, counted_runs.ended, counted_runs.expected_per_run, settings, rng)
    if loss is None:
        loss = isolated_loss(isolated, max(expected, 1))
    jitter_est, shape_note = _jitter_estimate(pair_jitter, pair_shape, own_jitter, settings, rng)
    bursts = int(np.sum(all_runs >= 2))
    notes = (
        f"{len(kept)} sensor topics, {expected} messages expected, {lost} missing "
        f"({lost / max(expected, 1):.3f}; {isolated} isolated, {bursts} bursts of 2 or more)",
        *shape_note,
    )
    return NetworkFit(loss, jitter_est, notes, burst)


def _shared_ticks(
    group: Sequence[StampStream],
    received: Sequence[np.ndarray],
    counted: _Runs,
    pair_jitter: list[float],
    pair_shape: list[np.ndarray],
) -> None:
    """A group of topics sharing their ticks: its loss runs per topic-episode into `counted`, and each pair's jitter
    rule and quantile readings of their delay differences into `pair_jitter` and `pair_shape`.

    Each tick belongs to the episode its first reception falls in; a topic lost it only if it never received it (a
    message delayed past an episode's end by its jitter is no loss)."""
    ticks, first = np.unique(np.concatenate([k.stamp_ns for k in group]), return_index=True)
    episode = _episode_of(np.concatenate([k.log_ns for k in group])[first], group[0].windows)
    for w in np.unique(episode):
        in_episode = ticks[episode == w]
        for got in received:
            run = _tick_runs(got, in_episode)
            # a run still going at the episode's last tick is cut short: its messages count, its end does not
            counted.add(run, len(in_episode), len(run) - int(not np.isin(in_episode[-1], got)))
    for a_i, sa in enumerate(group):
        for sb in group[a_i + 1 :]:
            common, ia, ib = np.intersect1d(sa.stamp_ns, sb.stamp_ns, return_indices=True)
            if len(common) < MIN_MESSAGES:
                continue
            diff = ((sa.log_ns[ia] - sa.stamp_ns[ia]) - (sb.log_ns[ib] - sb.stamp_ns[ib])) / NS_PER_S
            pair_jitter.append(pair_rule(diff))
            pair_shape.append(_quantile_readings(diff))


def _own_ticks(stream: StampStream, settings: CalibrationSettings, counted: _Runs) -> float:
    """A topic with ticks of its own: its loss runs per episode into `counted` from the gaps in its stamps, and its
    own jitter (2 x the interquartile range of its delays) returned.

    Gaps are read over the whole stream (a burst across an episode's start is still counted), each told to the
    episode its first message after the gap falls in."""
    missing = _gap_missing(stream.stamp_ns, settings.network_max_gap_s)
    if stream.windows:
        # a gap across the pause before an episode's start is the reset's (the sensor restarts with the episode),
        # no loss; episodes that follow each other without a pause keep theirs
        ordered = sorted(stream.windows)
        paused = [b for (_, end), (b, _) in itertools.pairwise(ordered) if b - end > RESET_PAUSE_NS]
        starts = np.array(paused, dtype=np.int64)
        before, after = stream.log_ns[:-1], stream.log_ns[1:]
        across = np.searchsorted(starts, before, side="right") < np.searchsorted(starts, after, side="right")
        missing = np.where(across, 0, missing)
    for a, b in stream.windows or [(int(stream.log_ns.min()), int(stream.log_ns.max()))]:
        sel = (stream.log_ns >= a) & (stream.log_ns <= b)
        if sel.sum() >= 3:
            r = missing[sel[1:]]
            r = r[r > 0]
            counted.add(r, int(sel.sum() + r.sum()), len(r))
    delay = (stream.log_ns - stream.stamp_ns) / NS_PER_S
    q25, q75 = np.percentile(delay, [25, 75])
    return 2.0 * float(q75 - q25)


def _jitter_estimate(
    pair_jitter: list[float],
    pair_shape: list[np.ndarray],
    own_jitter: list[float],
    settings: CalibrationSettings,
    rng: np.random.Generator,
) -> tuple[Estimate, tuple[str, ...]]:
    """The jitter (s): the median of the topic pairs' readings where topics share ticks, else of each topic's own;
    its interval by a bootstrap over them, widened to hold the pairs' quantile readings where those disagree (with
    the note that says so)."""
    if pair_jitter:
        values = np.asarray(pair_jitter)
        method = f"interquartile range of delay differences between {len(values)} topic pairs sharing ticks, median"
    else:
        values = np.asarray(own_jitter)
        method = "2 x interquartile range of each topic's delays (receiver stalls included), median over topics"
    jitter = float(np.median(values))
    shape_note: tuple[str, ...] = ()
    if len(values) < 2:
        return Estimate.of(jitter, None, None, "s", method, len(values)), shape_note
    samples = bootstrap(lambda c: np.array([np.median(np.repeat(values, c))]), len(values), settings.bootstrap, rng)
    se, interval = spread(samples[:, 0])
    method += "; bootstrap over them"
    if pair_shape and interval is not None:
        readings = np.median(np.asarray(pair_shape), axis=0)
        low, high = float(readings.min()), float(readings.max())
        if low < interval[0] or high > interval[1]:
            shape_note = (
                "the delay differences are not the triangle of uniform delays: read at the "
                + ", ".join(f"{q:.2f}" for q in SHAPE_QUANTILES)
                + " quantiles of their size they give a jitter of "
                + ", ".join(f"{r * 1e3:.1f}" for r in readings)
                + f" ms (a receiver that stalls logs deliveries together, which shrinks the lower ones; late ones "
                f"stretch the tail): the value is their median, {float(np.median(readings)) * 1e3:.1f} ms, not "
                f"the interquartile rule's {jitter * 1e3:.1f} ms, and the interval holds them all",
            )
            jitter = float(np.median(readings))
            interval = (min(interval[0], low), max(interval[1], high))
            se = max(se or 0.0, (interval[1] - interval[0]) / (2 * Z_95))
            method += "; the differences' quantiles disagree: their median reading, widened to hold them all"
    return Estimate.of(jitter, se, interval, "s", method, len(values)), shape_note


SHAPE_QUANTILES = (0.5, 0.75, 0.9)
"""Quantiles of the size of two topics' delay differences that each read the jitter under the model (the
interquartile rule is the first); where they disagree, the model does not hold and the interval holds them all."""


def pair_rule(diff_s: np.ndarray) -> float:
    """The jitter (s) that two topics' delay differences for the same stamps read: their interquartile range over
    2 - sqrt 2 (the difference of two uniform delays on [0, J] is a triangle on [-J, J])."""
    q25, q75 = np.percentile(diff_s, [25, 75])
    return float(q75 - q25) / TRIANGULAR_IQR


def _quantile_readings(diff: np.ndarray) -> np.ndarray:
    """The jitter each of `SHAPE_QUANTILES` of |diff| reads: the difference of two uniform delays on [0, J] has
    P(|D| > x) = (1 - x / J)^2, so its q quantile is J (1 - sqrt(1 - q))."""
    q = np.asarray(SHAPE_QUANTILES)
    return np.asarray(np.quantile(np.abs(diff), q) / (1.0 - np.sqrt(1.0 - q)), dtype=float)


def _burst_loss(
    runs: Sequence[np.ndarray],
    ended: Sequence[int],
    expected: Sequence[int],
    settings: CalibrationSettings,
    rng: np.random.Generator,
) -> tuple[Estimate | None, Estimate]:
    """Loss probability (missing / expected) and mean burst length, with a bootstrap over topic-episodes, so
    losses that come in bursts widen the interval as they should.

    The mean burst length is missing messages / runs seen to end (`ended`): a run cut short by the end of its
    episode adds its messages but no end, which is the maximum-likelihood mean of geometric run lengths
    (a two-state loss chain's) with right-censored runs; counting it as a whole run biases the mean short by
    the share of runs an episode's end cuts (a few % at a loss of 0.04 in 15 s episodes).

    (None, ...) with fewer than `MIN_LOSS_CLUSTERS` topic-episodes: the isolated-loss estimate is used then.
    """
    n = len(runs)
    table = np.array(
        [[float(r.sum()), float(k), float(e)] for r, k, e in zip(runs, ended, expected, strict=True)]
    ).reshape(-1, 3)
    if n < MIN_LOSS_CLUSTERS or table[:, 2].sum() <= 0:
        return None, Estimate.unidentifiable(f"fewer than {MIN_LOSS_CLUSTERS} topic-episodes", "messages")

    def stat(counts: np.ndarray) -> np.ndarray:
        lost, bursts, total = counts @ table
        return np.array([lost / total if total > 0 else np.nan, lost / bursts if bursts > 0 else np.nan])

    lost, bursts, total = table.sum(axis=0)
    samples = bootstrap(stat, n, settings.bootstrap, rng)
    se, interval = spread(samples[:, 0])
    p = lost / total
    if math.isfinite(se) and se > 0 and 0 < p < 1:
        # a share of rare, clustered events is skewed: a Wilson interval on the effective sample size the
        # bootstrap's spread implies (the design effect of the bursts) is long on the upper side, as it must be
        n_eff = p * (1 - p) / (se * se)
        z2 = Z_95 * Z_95
        centre = (p + z2 / (2 * n_eff)) / (1 + z2 / n_eff)
        half = Z_95 * math.sqrt(p * (1 - p) / n_eff + z2 / (4 * n_eff * n_eff)) / (1 + z2 / n_eff)
        interval = (max(0.0, min(interval[0], centre - half)), min(1.0, max(interval[1], centre + half)))
    method = f"missing / expected messages, bootstrap over {n} topic-episodes (Wilson on the effective size)"
    loss = Estimate.of(p, se, interval, "probability", method, int(total))
    if bursts < 2:
        return loss, Estimate.unidentifiable(
            f"{int(bursts)} run(s) of lost messages seen to end", "messages", int(bursts)
        )
    b_se, b_interval = spread(samples[:, 1])
    method = "missing messages / runs of them seen to end (runs cut by an episode's end censored)"
    burst = Estimate.of(lost / bursts, b_se, b_interval, "messages", method, int(bursts))
    return loss, burst
