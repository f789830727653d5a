"""``--time-scale auto``: the highest time scale the host lets the hardware twin keep, measured, and lowered when the
twin falls behind.

The twin reports how it keeps its clock every half second of host time (``twin: pace {...}`` lines of its
``--pace``): its own time, the time it jumped over in host stalls, the host's monotonic time and the most it ran
behind since the last line. Before the first episode, with the fleet up and the runner listening (the runner's own
work on the host included), the twin runs at `AUTO_START_SCALE` for `PROBE_S` seconds; the scale it realized,
times `HEADROOM` and rounded down to a step of `SCALE_STEP`, is the next one tried, until one is kept (no more than
the twin's own margin short of it, never a second behind). Between episodes the same test is applied to the
episode just run: one the twin did not keep lowers the scale from the next episode on (the episode itself is
marked by the twin's record, as any). A host that cannot keep 1x is refused before the first episode.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from pipeline.core.timebase import LAG_LIMIT_NS, REALIZED_MARGIN
from pipeline.errors import InvalidMeasurement
from pipeline.ros.clock import ScaledClock

AUTO_START_SCALE = 6.0
"""The scale tried first (the most a deployment at ``auto`` asks for)."""
HEADROOM = 0.8
"""The share of the scale realized that is asked for next: room for the episodes' own work and the host's swings."""
SCALE_STEP = 0.5
PROBE_S = 2.0
"""Host seconds each scale is watched for before the first episode."""
PROBES = 5
"""At most this many scales are tried before the first episode."""
PACE_EVERY_S = 0.5
"""How often (host seconds) the twin reports its pace."""
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


def kept(scale: float, realized_scale: float, lag_ns: float) -> bool:
    """The twin kept `scale`: by the twin's own rule for its episodes (`REALIZED_MARGIN`, `LAG_LIMIT_NS`)."""
    short = math.isfinite(realized_scale) and realized_scale < scale * (1 - REALIZED_MARGIN)
    return not short and lag_ns <= LAG_LIMIT_NS


def next_scale(realized_scale: float, asked: float) -> float:
    """The scale to ask for after `asked` was not kept at `realized_scale`: `HEADROOM` of it in `SCALE_STEP` steps,
    below `asked` (one step below where the twin realized nearly all of it: it fell behind all the same)."""
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

    def probe(self, stop: threading.Event | None = None) -> float:
        """The highest scale the twin keeps on this host now, tried from `start` down; InvalidMeasurement where even
        1x is not kept."""
        for _ in range(PROBES):
            began = time.monotonic_ns() + PACE_EVERY_S * 1e9  # the first report taken after the scale took hold
            deadline = time.monotonic() + PACE_EVERY_S + PROBE_S
            while time.monotonic() < deadline:
                if stop is not None and stop.wait(0.05):
                    break
                time.sleep(0.05)
            got, lag = realized(self._since(began))
            self.tried.append((self.scale, got))
            if not math.isfinite(got):
                raise InvalidMeasurement(
                    f"time scale auto: the twin sent {len(self._since(began))} pace report(s) in {PROBE_S:g} s; "
                    "cannot measure what this host sustains"
                )
            if kept(self.scale, got, lag):
                return self.scale
            lower = next_scale(got, self.scale)
            if lower < 1.0:
                raise InvalidMeasurement(
                    f"time scale auto: the twin realized {got:.2f}x for {self.scale:g}x asked (most {lag / 1e9:.2f} s "
                    "behind): this host cannot keep even 1x now; run on a quieter host (other work at lower "
                    "priority: nice -n 19)"
                )
            self._set(lower)
        raise InvalidMeasurement(
            f"time scale auto: no scale kept after {PROBES} tries ("
            + ", ".join(f"{a:g}x realized {r:.2f}" for a, r in self.tried)
            + "); the host's load swings too much to measure"
        )

    def episode_started(self) -> None:
        self._episode_from = time.monotonic_ns()

    def after_episode(self, episode: int) -> None:
        """Lower the scale from the next episode on where the twin did not keep it in the episode just run."""
        ended = time.monotonic_ns()
        deadline = time.monotonic() + REPORT_WAIT_S
        while not self._since(ended)[1:] and time.monotonic() < deadline:  # a report that covers the episode's end
            time.sleep(0.02)
        window = self._since(self._episode_from)
        got, lag = realized(window)
        if window and window[-1].host_ns < ended:  # none came: the twin has not run since (a host stall)
            lag = max(lag, (time.monotonic_ns() - window[-1].host_ns) * self.scale)
        if kept(self.scale, got, lag):
            return
        lower = max(1.0, next_scale(got, self.scale) if math.isfinite(got) else self.scale - SCALE_STEP)
        if lower >= self.scale:
            return  # at 1x already: the episodes are marked, nothing lower to ask for
        self.lowered.append((episode, self.scale, got, lower))
        self.say(
            f"deploy: the twin fell behind in episode {episode} (realized {got:.2f}x for {self.scale:g}x, most "
            f"{lag / 1e9:.2f} s behind): time scale {lower:g} from the next episode"
        )
        self._set(lower)
