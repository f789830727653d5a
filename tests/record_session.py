"""A recording process for the integration tests: ``python -m tests.record_session PATH MODE``.

It records ``/mrl/timing`` messages whose ``seq`` counts 0, 1, 2, ... until a signal stops it,
printing progress lines (flushed) that the test reads:

- ``kill``: small chunks, a flush every 25 messages, ``sealed N`` after each flush returned
  (messages 0..N-1 are then in complete chunks); it never closes, the test SIGKILLs it.
- ``raise``: SIGINT and SIGTERM raise KeyboardInterrupt, the ``with`` block closes the file;
  prints ``written N`` every 50 messages and ``closed N`` at the end.
- ``handler``: a SIGINT/SIGTERM handler calls ``close()`` itself, prints ``closed N``, exits 0.
"""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path
from types import FrameType

from pipeline.messages import convert as C
from pipeline.messages import fleet_topics, message_store
from pipeline.record import McapRecorder

T0_NS = 1_700_000_000_000_000_000
LIMIT_S = 120.0


def _timing(i: int) -> object:
    return C.timing(T0_NS + i * 1000, "send", "robot_1", "/robot_1/cmd_vel", 0, i, i // 5, store=message_store())


def record_until_killed(path: Path) -> None:
    rec = McapRecorder(path, fleet_topics(["robot_1"]), chunk_size=2048)
    start = time.monotonic()
    i = 0
    while time.monotonic() - start < LIMIT_S:
        rec.write("/mrl/timing", _timing(i), T0_NS + i * 1000)
        i += 1
        if i % 25 == 0:
            rec.flush()
            print(f"sealed {i}", flush=True)
            time.sleep(0.001)


def record_until_interrupted(path: Path) -> None:
    signal.signal(signal.SIGINT, signal.default_int_handler)  # also when started with SIGINT ignored
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    rec = McapRecorder(path, fleet_topics(["robot_1"]), chunk_size=4096)
    try:
        with rec:
            start = time.monotonic()
            i = 0
            while time.monotonic() - start < LIMIT_S:
                rec.write("/mrl/timing", _timing(i), T0_NS + i * 1000)
                i += 1
                if i % 50 == 0:
                    print(f"written {i}", flush=True)
    except KeyboardInterrupt:
        print(f"closed {rec.message_count}", flush=True)


def record_until_handler_closes(path: Path) -> None:
    rec = McapRecorder(path, fleet_topics(["robot_1"]), chunk_size=4096)

    def stop(signum: int, frame: FrameType | None) -> None:
        rec.close()
        print(f"closed {rec.message_count}", flush=True)
        sys.exit(0)

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    start = time.monotonic()
    i = 0
    while time.monotonic() - start < LIMIT_S:
        rec.write("/mrl/timing", _timing(i), T0_NS + i * 1000)
        i += 1
        if i % 50 == 0:
            print(f"written {i}", flush=True)


MODES = {"kill": record_until_killed, "raise": record_until_interrupted, "handler": record_until_handler_closes}


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[1] not in MODES:
        print(f"usage: python -m tests.record_session PATH {{{','.join(MODES)}}}", file=sys.stderr)
        return 2
    MODES[argv[1]](Path(argv[0]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
