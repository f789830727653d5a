"""The dvc stage scripts' plumbing, which the ``mrl`` verbs run through too: arguments, signals, exit codes.

Exit codes: 0 success, 2 bad input (an MrlError: its message names the file, key or topic), 3 runtime fault
(a RuntimeFault: a twin or driver gone, a robot blind past its outage limit, a clash on the domain), 130
interrupted (Ctrl-C or SIGTERM; what was recorded so far is kept).
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Callable, Sequence
from types import FrameType

from pipeline.errors import MrlError, RuntimeFault

ROUNDS = ("nominal", "calibrated")
EXIT_BAD_INPUT = 2
EXIT_RUNTIME_FAULT = 3
EXIT_INTERRUPTED = 130


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


def run_stage(name: str, body: Callable[[], int]) -> int:
    """Run a stage body with SIGTERM treated like Ctrl-C; print errors as one line per problem, no traceback."""
    signal.signal(signal.SIGTERM, _terminate)
    try:
        return body()
    except MrlError as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        if getattr(exc, "interrupted", False):
            return EXIT_INTERRUPTED
        fault = isinstance(exc, RuntimeFault) or getattr(exc, "runtime_fault", False)
        return EXIT_RUNTIME_FAULT if fault else EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
