"""How much delivery jitter the twin's link realizes, read the way calibration reads it.

Nine topics publish at --rate-hz through one `pipeline.twin.twin.LossyLink` (no loss, jitter --jitter-s) on a
clock --scale times faster than wall time, for --ticks ticks, in a process with the twin's switch interval and
--busy-threads threads of pure Python work beside it (the twin's physics and sensors want the interpreter too);
each message's delay is its publish time at the link (the clock's reading when the link hands it on) less its send
time. The pair rule of `pipeline.calibration.network` (the interquartile range of two topics' delay differences for
the same tick, over 2 - sqrt 2) then reads the jitter. Printed: the delays' range and median, and the pair rule's
reading beside the profile's. Last line: ``jitter_read_s=<..> jitter_profile_s=<..> ratio=<read / profile>``.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.calibration.network import TRIANGULAR_IQR
from pipeline.ros.clock import ScaledClock
from pipeline.twin.twin import LossyLink

ROOT = Path(__file__).resolve().parents[1]

TOPICS = 9


class _Recorder:
    """Stands for a publisher: notes the clock's reading when the link hands a message on."""

    def __init__(self, name: str, clock: ScaledClock, out: list[tuple[str, Any, int]]) -> None:
        self.closed = False
        self.name = name
        self.clock = clock
        self.out = out

    def publish(self, msg: Any) -> None:
        self.out.append((self.name, msg, self.clock.now_ns()))


def _busy(stop: threading.Event) -> None:
    """Pure Python work that wants the interpreter all the time (the twin's physics loop does, at 3x)."""
    x = 0
    while not stop.is_set():
        for i in range(10_000):
            x = (x + i * i) % 1_000_003


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=3.0)
    parser.add_argument("--jitter-s", type=float, default=0.015)
    parser.add_argument("--rate-hz", type=float, default=50.0)
    parser.add_argument("--ticks", type=int, default=1500)
    parser.add_argument(
        "--busy-threads", type=int, default=0, help="threads of pure Python work beside the link, as the twin's physics"
    )
    args = parser.parse_args()
    sys.setswitchinterval(0.0002)  # as the twin's process sets it
    stop = threading.Event()
    for _ in range(args.busy_threads):
        threading.Thread(target=_busy, args=(stop,), daemon=True).start()
    clock = ScaledClock(args.scale, time.time_ns())
    out: list[tuple[str, Any, int]] = []
    link = LossyLink(clock, 0.0, args.jitter_s, np.random.default_rng(0))
    pubs = [_Recorder(f"topic_{i}", clock, out) for i in range(TOPICS)]
    period = round(1e9 / args.rate_hz)
    sent: dict[tuple[str, int], int] = {}
    t = clock.now_ns()
    for k in range(args.ticks):
        clock.sleep_until(t)
        for pub in pubs:
            sent[(pub.name, k)] = clock.now_ns()
            link.send(pub, k)  # type: ignore[arg-type]
        t += period
    time.sleep(3 * args.jitter_s / args.scale + 0.1)
    link.close()
    stop.set()
    delay = {(name, k): (t_ns - sent[(name, k)]) / 1e9 for name, k, t_ns in out}
    pairs = [delay[("topic_0", k)] - delay[("topic_1", k)] for k in range(args.ticks) if ("topic_1", k) in delay]
    q25, q75 = np.percentile(pairs, [25, 75])
    read = float(q75 - q25) / TRIANGULAR_IQR
    values = np.array(list(delay.values()))
    print(
        f"{len(values)} messages of {TOPICS} topics at {args.rate_hz:g} Hz, clock x{args.scale:g}, "
        f"{args.busy_threads} busy thread(s): delay min "
        f"{values.min() * 1e3:.2f} ms, median {np.median(values) * 1e3:.2f} ms, max {values.max() * 1e3:.2f} ms"
    )
    print(f"pair rule reads {read * 1e3:.2f} ms for a profile of {args.jitter_s * 1e3:.2f} ms")
    print(f"jitter_read_s={read:.5f} jitter_profile_s={args.jitter_s} ratio={read / args.jitter_s:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
