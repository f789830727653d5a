"""Clocks of the deploy side: wall time, or simulated time scaled against wall time.

Times are integer nanoseconds. ``WallClock`` reads Unix time (robots and the twin at 1x).
``ScaledClock`` runs `scale` times faster than wall time from an anchor; the twin owns one and
publishes it on ``/clock``, and the deploy runner's follows those messages (``follow``), as a
ROS 2 node with ``use_sim_time`` does.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol

from pipeline.core.timebase import NS_PER_S

SPIN_NS = 400_000
"""The last stretch before a deadline is waited out by spinning: OS sleeps overshoot by ~0.1 ms."""


class Clock(Protocol):
    scale: float
    """Clock seconds per wall second."""

    def now_ns(self) -> int: ...

    def sleep_until(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        """Block until the clock reads `t_ns`; False if `stop` was set first."""
        ...


def _sleep_wall_until(deadline_wall_ns: int, stop: threading.Event | None) -> bool:
    while True:
        remaining = deadline_wall_ns - time.time_ns()
        if remaining <= 0:
            return True
        if stop is not None and stop.is_set():
            return False
        if remaining > SPIN_NS:
            wait_s = (remaining - SPIN_NS) / NS_PER_S
            if stop is not None:
                if stop.wait(min(wait_s, 0.05)):
                    return False
            else:
                time.sleep(min(wait_s, 0.05))


class WallClock:
    """Unix time in nanoseconds."""

    scale = 1.0

    def now_ns(self) -> int:
        return time.time_ns()

    def sleep_until(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        return _sleep_wall_until(t_ns, stop)


class ScaledClock:
    """Simulated time running `scale` times faster than wall time, anchored at (sim_ns, wall_ns).

    `follow(sim_ns)` re-anchors on a received ``/clock`` message; the reading never goes back.
    """

    def __init__(self, scale: float, sim_start_ns: int = 0, wall_start_ns: int | None = None) -> None:
        if not scale > 0:
            raise ValueError(f"clock scale must be > 0, got {scale}")
        self.scale = scale
        self._lock = threading.Lock()
        self._sim0 = sim_start_ns
        self._wall0 = time.time_ns() if wall_start_ns is None else wall_start_ns
        self._last = sim_start_ns
        self.anchored = wall_start_ns is not None or sim_start_ns != 0

    def now_ns(self) -> int:
        with self._lock:
            t = self._sim0 + int((time.time_ns() - self._wall0) * self.scale)
            self._last = max(self._last, t)
            return self._last

    def follow(self, sim_ns: int, wall_ns: int | None = None) -> None:
        """Re-anchor on a ``/clock`` reading received at `wall_ns` (now if None)."""
        with self._lock:
            self._sim0 = sim_ns
            self._wall0 = time.time_ns() if wall_ns is None else wall_ns
            self.anchored = True

    def rescale(self, scale: float) -> None:
        """Run `scale` times faster than wall time from now on, from the present reading (no jump)."""
        if not scale > 0:
            raise ValueError(f"clock scale must be > 0, got {scale}")
        with self._lock:
            wall = time.time_ns()
            self._sim0 = max(self._last, self._sim0 + int((wall - self._wall0) * self.scale))
            self._wall0 = wall
            self.scale = scale

    def wall_deadline(self, t_ns: int) -> int:
        with self._lock:
            return self._wall0 + int((t_ns - self._sim0) / self.scale)

    def sleep_until(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        while True:
            if self.now_ns() >= t_ns:
                return True
            if not _sleep_wall_until(self.wall_deadline(t_ns), stop):
                return False
