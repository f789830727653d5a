"""``--time-scale auto``: the highest time scale the host lets the hardware twin keep, measured, and lowered when the
twin falls behind.

The twin reports how it keeps its clock every half second of host time (``twin: pace {...}`` lines of its
``--pace``): its own time, the time it jumped over in host stalls, the host's monotonic time and the most it ran
behind since the last line. Before the first episode, with the fleet up and the runner listening, the twin is asked
for `CAPACITY_SCALE`, more than it can keep: for `PROBE_S` seconds it runs flat out, and the scale it realizes is
what this host gives it now, the robots standing. The episodes add the policy, the recording and the robots' motion
beside it, and a busy host swings: the scale asked for is `HEADROOM` of that capacity, in steps of `SCALE_STEP`, at
most `AUTO_MAX_SCALE`; it is then watched for `PROBE_S` and lowered the same way until the twin keeps it (no more
than the twin's own margin short of it, never a second behind). Between episodes the same test is applied to the
episode just run, and an episode a robot's outage aborted counts as not kept (on the twin's host, a blind robot is
a starved process): the scale is lowered from the next episode on; the episode itself is marked by the twin's
record, as any. A host on which the twin cannot keep 1x even flat out is refused before the first episode.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from pipeline.core.timebase import REALIZED_MARGIN, scale_kept
from pipeline.errors import InvalidMeasurement
from pipeline.ros.clock import ScaledClock

CAPACITY_SCALE = 20.0
"""The scale asked for while the probe measures the twin's capacity: more than a twin keeps, so it runs flat out."""
AUTO_START_SCALE = CAPACITY_SCALE
"""The scale the twin of a deployment at ``auto`` starts at (the probe's first)."""
AUTO_MAX_SCALE = 6.0
"""The most a deployment at ``auto`` asks for."""
HEADROOM = 0.5
"""The share of the capacity measured (or the scale realized in an episode not kept) that is asked for next: room
for the episodes' own work beside the twin and for the host's swings."""
SCALE_STEP = 0.5
PROBE_S = 2.0
"""Host seconds each scale is watched for before the first episode."""
PROBES = 5
"""At most this many scales are tried before the first episode."""
PACE_EVERY_S = 0.5
"""How often (host seconds) the twin reports its pace."""
AUTO_LATE_TARGET = 0.25
"""The most the control steps may wake late at ``auto`` (the 95th percentile, a share of the control period) before
the scale is lowered: well inside the limit past which an episode is marked (`CONTROL_LATE_LIMIT`)."""
RERUN_SHARE = 0.1
"""At ``auto``, episodes the twin did not keep its clock in are run again, up to this share of the episodes asked
for (at least `MIN_RERUNS`): the marked ones stay in the session, counted apart."""
MIN_RERUNS = 2
REPORT_WAIT_S = 3 * PACE_EVERY_S
"""How long the end of an episode waits for the twin's next report (one that covers the episode's end)."""


@dataclass(frozen=True)
class Pace:
    """One of the twin's pace reports (see :meth:`pipeline.twin.twin.HardwareTwin.pace`)."""

    twin_ns: float
    jumped_ns: float
    host_ns: float
    lag_ns: float
    scale: float


def realized(paces: Sequence[Pace]) -> tuple[float, float]:
    """(time scale realized, most lag in ns) over consecutive pace reports: twin time simulated (not jumped over) per
    host second between the first and the last; NaN with fewer than two."""
    if len(paces) < 2:
        return math.nan, max((p.lag_ns for p in paces), default=0.0)
    first, last = paces[0], paces[-1]
    host = last.host_ns - first.host_ns
    twin = (last.twin_ns - first.twin_ns) - (last.jumped_ns - first.jumped_ns)
    return (twin / host if host > 0 else math.nan), max(p.lag_ns for p in paces[1:])


kept = scale_kept
"""The twin kept a scale: by the twin's own rule for its episodes (:func:`pipeline.core.timebase.scale_kept`)."""


def next_scale(realized_scale: float, asked: float) -> float:
    """The scale to ask for after `asked` was not kept at `realized_scale`: `HEADROOM` of it in `SCALE_STEP` steps,
    below `asked` (at least a step below where the twin realized nearly all of it: it fell behind all the same)."""
    step = math.floor(realized_scale * HEADROOM / SCALE_STEP) * SCALE_STEP
    return min(step, asked - SCALE_STEP)


class AutoScale:
    """The time scale of a deployment at ``auto``: `probe` before the first episode, `after_episode` between them.

    `paces` is the twin's reports as they arrive (appended by another thread), `ask` tells the twin a new scale
    (taken at its next reset; at once before the first), `clock` is the runner's copy of the twin's clock."""

    def __init__(
        self,
        paces: list[Pace],
        ask: Callable[[float], None],
        clock: ScaledClock,
        start: float = AUTO_START_SCALE,
        say: Callable[[str], None] | None = None,
    ) -> None:
        self.paces = paces
        self.ask = ask
        self.clock = clock
        self.scale = start
        self.say = say or (lambda line: print(line, file=sys.stderr, flush=True))
        self.tried: list[tuple[float, float]] = []
        """Before the first episode: (scale asked, scale realized) per probe."""
        self.lowered: list[tuple[int, float, float, float]] = []
        """Between episodes: (episode, scale asked, realized, the next scale)."""
        self.capacity = math.nan
        """The scale the twin realized flat out before the first episode."""
        self._episode_from = 0

    def _since(self, host_ns: float) -> list[Pace]:
        """The reports from `host_ns` on, after the last one before it (the window's start)."""
        paces = list(self.paces)
        before = [p for p in paces if p.host_ns < host_ns][-1:]
        return before + [p for p in paces if p.host_ns >= host_ns]

    def _set(self, scale: float) -> None:
        self.ask(scale)
        self.clock.rescale(scale)
        self.scale = scale

    def _watch(self, stop: threading.Event | None) -> tuple[float, float, int]:
        """(scale realized, most lag ns, reports) over `PROBE_S` host seconds at the scale now asked for."""
        began = time.monotonic_ns() + PACE_EVERY_S * 1e9  # the first report taken after the scale took hold
        deadline = time.monotonic() + PACE_EVERY_S + PROBE_S
        while time.monotonic() < deadline:
            if stop is not None and stop.wait(0.05):
                break
            time.sleep(0.05)
        window = self._since(began)
        got, lag = realized(window)
        self.tried.append((self.scale, got))
        return got, lag, len(window)

    def probe(self, stop: threading.Event | None = None) -> float:
        """The scale the episodes start at: `HEADROOM` of the twin's capacity on this host now, lowered until it is
        kept; InvalidMeasurement where even 1x is not kept."""
        if self.scale != CAPACITY_SCALE:
            self._set(CAPACITY_SCALE)
        capacity, lag, reports = self._watch(stop)
        self.capacity = capacity
        if not math.isfinite(capacity):
            raise InvalidMeasurement(
                f"time scale auto: the twin sent {reports} pace report(s) in {PROBE_S:g} s; cannot measure what this "
                "host sustains"
            )
        if capacity < 1.0 * (1 - REALIZED_MARGIN):
            raise self._too_busy(capacity, lag)
        first = math.floor(min(capacity * HEADROOM, AUTO_MAX_SCALE) / SCALE_STEP) * SCALE_STEP
        self._set(max(first, 1.0))
        for _ in range(PROBES):
            got, lag, _ = self._watch(stop)
            if kept(self.scale, got, lag):
                return self.scale
            if self.scale <= 1.0:
                raise self._too_busy(got, lag)
            self._set(max(1.0, next_scale(got, self.scale) if math.isfinite(got) else self.scale - SCALE_STEP))
        raise InvalidMeasurement(
            f"time scale auto: no scale kept after {PROBES} tries ("
            + ", ".join(f"{a:g}x realized {r:.2f}" for a, r in self.tried)
            + "); the host's load swings too much to measure"
        )

    def _too_busy(self, got: float, lag: float) -> InvalidMeasurement:
        return InvalidMeasurement(
            f"time scale auto: the twin realized {got:.2f}x for {self.scale:g}x asked (most {lag / 1e9:.2f} s behind): "
            "this host cannot keep even 1x now; run on a quieter host (other work at lower priority: nice -n 19)"
        )

    @staticmethod
    def reruns_for(episodes: int) -> int:
        """How many episodes a deployment of `episodes` at ``auto`` may run again."""
        return max(MIN_RERUNS, math.ceil(RERUN_SHARE * episodes))

    def said(self) -> str:
        """What the probe found, for the deployment's output."""
        tried = ", ".join(f"{a:g}x realized {r:.2f}" for a, r in self.tried[1:])
        return (
            f"the twin ran at most {self.capacity:.1f}x here (flat out, the robots standing); {tried}; the episodes "
            f"start at {self.scale:g}x (lowered if the twin falls behind)"
        )

    def episode_started(self) -> None:
        self._episode_from = time.monotonic_ns()

    def after_episode(self, episode: int, outage: bool = False, late: float = math.nan) -> bool:
        """Lower the scale from the next episode on where the twin did not keep it in the episode just run, the
        runner's control steps woke late (`late`: the 95th percentile as a share of the control period, above
        `AUTO_LATE_TARGET`), or a robot's outage aborted it (`outage`). True where the twin did not keep it (the
        episode will be marked: it measures the host)."""
        ended = time.monotonic_ns()
        deadline = time.monotonic() + REPORT_WAIT_S
        while not self._since(ended)[1:] and time.monotonic() < deadline:  # a report that covers the episode's end
            time.sleep(0.02)
        window = self._since(self._episode_from)
        got, lag = realized(window)
        if window and window[-1].host_ns < ended:  # none came: the twin has not run since (a host stall)
            lag = max(lag, (time.monotonic_ns() - window[-1].host_ns) * self.scale)
        behind = not kept(self.scale, got, lag)
        slow = late > AUTO_LATE_TARGET  # NaN: not measured
        if not (behind or slow or outage):
            return False
        if behind:
            lower = max(1.0, next_scale(got, self.scale) if math.isfinite(got) else self.scale - SCALE_STEP)
            why = f"the twin fell behind in episode {episode} (realized {got:.2f}x for {self.scale:g}x, most "
            why += f"{lag / 1e9:.2f} s behind)"
        else:
            lower = max(1.0, math.floor(self.scale * HEADROOM / SCALE_STEP) * SCALE_STEP)
            why = (
                f"the control steps of episode {episode} woke {late:.2f} of a period late (95th percentile) at "
                f"{self.scale:g}x"
                if slow
                else f"a robot's outage aborted episode {episode} at {self.scale:g}x (a process starved on a busy host)"
            )
        if lower >= self.scale:
            return behind  # at 1x already: the episodes are marked, nothing lower to ask for
        self.lowered.append((episode, self.scale, got, lower))
        self.say(f"deploy: {why}: time scale {lower:g} from the next episode")
        self._set(lower)
        return behind


BEHIND_WINDOW_S = 5.0
"""How far back (host seconds) `behind_note` looks at the twin's pace."""


def behind_note(paces: Sequence[Pace], now_ns: float | None = None) -> str:
    """Where the twin's last reports show it fell behind its clock (or no report came for a while): a sentence that
    puts a fleet's silence on the host, not the robots; empty where it kept its clock."""
    reports = list(paces)
    if not reports:
        return ""
    now = time.monotonic_ns() if now_ns is None else now_ns
    last = reports[-1]
    window = [p for p in reports if p.host_ns >= last.host_ns - BEHIND_WINDOW_S * 1e9]
    got, lag = realized(window)
    silent_s = (now - last.host_ns) / 1e9
    if silent_s > REPORT_WAIT_S:
        return (
            f"the hardware twin has not run for {silent_s:.1f} s (its last pace report): the host gave it no time, "
            "the robots are not at fault; lower the time scale, use --time-scale auto, or run on a quieter host"
        )
    if kept(last.scale, got, lag):
        return ""
    realized_text = f"realized {got:.2f}x of {last.scale:g}x" if math.isfinite(got) else f"at {last.scale:g}x"
    return (
        f"the hardware twin fell behind its clock ({realized_text} over its last {len(window)} pace reports, up to "
        f"{lag / 1e9:.1f} s behind): the host is too busy for the time scale, the robots are not at fault; lower the "
        "time scale, use --time-scale auto, or run on a quieter host"
    )
