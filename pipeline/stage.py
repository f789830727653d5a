"""The dvc stage scripts' plumbing, which the ``mrl`` verbs run through too: arguments, signals, exit codes.

Exit codes (:data:`EXIT_CODES`, which ``mrl --help`` lists): 0 success, 1 no result (``mrl sweep`` whose trials
all failed), 2 bad input (an MrlError: its message names the file, key or topic), 3 runtime fault (a RuntimeFault:
a twin or driver gone, a robot blind past its outage limit, a clash on the domain), 4 a deployment whose twin fell
behind its clock in some episodes (InvalidMeasurement: marked, not the policy's), 130 interrupted (Ctrl-C or
SIGTERM; what was recorded so far is kept).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from types import FrameType

from pipeline.errors import InvalidMeasurement, MrlError, RuntimeFault

ROUNDS = ("nominal", "calibrated")
EXIT_DONE = 0
EXIT_NO_RESULT = 1
EXIT_BAD_INPUT = 2
EXIT_RUNTIME_FAULT = 3
EXIT_INVALID_MEASUREMENT = 4
EXIT_INTERRUPTED = 130
EXIT_CODES: dict[int, str] = {
    EXIT_DONE: "done",
    EXIT_NO_RESULT: "no result: every trial of an mrl sweep failed, nothing to report (a program error, with its "
    "traceback, exits 1 too)",
    EXIT_BAD_INPUT: "bad input: one line on stderr naming the file, key, option or topic (after the verb's usage "
    "for a mistyped, missing or malformed option)",
    EXIT_RUNTIME_FAULT: "runtime fault: a twin or driver gone, robots that never answered, a robot blind past its "
    "outage limit that ended the run, a clash on the DDS domain; the episodes run are kept",
    EXIT_INVALID_MEASUREMENT: "a deployment that finished, but in some episodes it did not keep its clock (the "
    "hardware twin fell behind, or the control steps woke late: a host too busy for the time scale): they are "
    "marked in episodes.csv and metrics.json, not the policy's",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C, SIGTERM); what was recorded so far is kept",
}
"""Every exit code of the stages and the ``mrl`` verbs, with its meaning."""


def stage_arguments(description: str, argv: Sequence[str] | None = None, rounds: bool = True) -> argparse.Namespace:
    """--params (default params.yaml) and, for per-round stages, --round (nominal | calibrated)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--params", default="params.yaml", help="the parameter file (default: params.yaml)")
    if rounds:
        parser.add_argument(
            "--round", default="nominal", choices=ROUNDS, help="which round of the loop (default: nominal)"
        )
    return parser.parse_args(argv)


def _terminate(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt


STAGE_TIMES = Path("logs/stages")
"""Where each dvc stage run writes its wall time (``<stage>[@<round>].json``): the stage table of a run
(benchmarks/stage_table.py)."""


def run_stage(name: str, body: Callable[[], int], times: Path | None = None) -> int:
    """Run a stage body with SIGTERM treated like Ctrl-C; print errors as one line per problem, no traceback.

    With `times` (the stage scripts pass `STAGE_TIMES`), the run's wall time, exit code and end go to
    ``times/<name>[@<round>].json``, the round read from the script's ``--round``."""
    start, began = time.monotonic(), datetime.now(UTC)
    code = _run(name, body)
    if times is not None:
        argv = sys.argv[1:]
        key = name + (f"@{argv[argv.index('--round') + 1]}" if "--round" in argv[:-1] else "")
        record = {
            "stage": key,
            "seconds": round(time.monotonic() - start, 1),
            "exit": code,
            "started": began.isoformat(timespec="seconds"),
        }
        try:
            times.mkdir(parents=True, exist_ok=True)
            (times / f"{key}.json").write_text(json.dumps(record) + "\n", encoding="utf-8")
        except OSError as exc:
            print(f"{name}: the stage's time was not written to {times} ({exc.strerror or exc})", file=sys.stderr)
    return code


def _run(name: str, body: Callable[[], int]) -> int:
    signal.signal(signal.SIGTERM, _terminate)
    try:
        return body()
    except MrlError as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        if getattr(exc, "interrupted", False):
            return EXIT_INTERRUPTED
        if isinstance(exc, InvalidMeasurement):
            return EXIT_INVALID_MEASUREMENT
        fault = isinstance(exc, RuntimeFault) or getattr(exc, "runtime_fault", False)
        return EXIT_RUNTIME_FAULT if fault else EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
