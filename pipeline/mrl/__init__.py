"""``mrl``: the pipeline's verbs for recordings brought from elsewhere, without the dvc layout.

Each verb calls the same library function as its dvc stage (stages/), with options instead of
params.yaml, and builds and reports its run through the same functions (:mod:`pipeline.runs`). One module
per verb, each with ``add_parser(subparsers)`` and ``run(args)``:

- ``mrl info BAG...``: topics, types, counts, times, robots, source format, what the other verbs can do;
- ``mrl episodes BAG [--out FILE.csv|FILE.parquet]``: the episodes table (one row per episode and robot);
- ``mrl compare SIM REAL [--out DIR]``: the sim-vs-real report of two recordings;
- ``mrl calibrate BAG... [--scenario S] [--map FLOOR.yaml] [--initial-pose X,Y,YAW] [--out DIR]``: the
  calibration file and its fit report (poses from motion capture, or localized in the map without it);
- ``mrl replay RECORDING --policy DIR [--out DIR]``: the policy on the recorded observations, and the
  recorded commands open loop in the policy's simulator;
- ``mrl twin ...``: the hardware twin (the options of ``python -m pipeline.twin``);
- ``mrl deploy --policy DIR --fleet FLEET [--out DIR] [--live]``: a recorded deployment on a fleet;
- ``mrl eval --policy DIR [--episodes N] [--out DIR] [--live]``: a recorded evaluation in the policy's simulator;
- ``mrl sweep --algorithms ... --seeds N [--axis KEY=V1,V2] [--set KEY=V] [--address ADDR]``: the training
  matrix as Ray tasks (:mod:`pipeline.bench`), resumable, with its statistics across seeds.

``--live`` serves the session to the Foxglove app while it runs (:mod:`pipeline.record.live`).

A BAG is an MCAP file, a rosbag2 folder (``metadata.yaml`` with mcap or sqlite3 storage) or a ROS 1
``.bag``; anything but a session recording of this project is imported into the session layout in
a temporary folder (:func:`pipeline.record.import_bag`), removed when the command ends. Messages
about an imported bag name the bag as given, not the temporary copy.

Exit codes (:data:`pipeline.stage.EXIT_CODES`, listed by ``mrl --help``): 0 done, 1 no result (a sweep whose
trials all failed), 2 bad input (one line ``mrl <verb>: <message>`` on stderr), 3 runtime fault (a twin or driver
gone, a clash on the domain), 4 a deployment that did not keep its clock (episodes marked), 130
interrupted.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import textwrap
import warnings
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import TextIO

from pipeline.errors import InvalidMeasurement, MrlError, RuntimeFault
from pipeline.mrl import calibrate, compare, deploy, episodes, evaluate, info, replay, sweep, twin
from pipeline.mrl.common import CommandError, VerbParser, output_folder
from pipeline.mrl.info import describe
from pipeline.stage import EXIT_CODES, run_stage

__all__ = ["PROG", "VERBS", "CommandError", "build_parser", "describe", "main", "output_folder"]

PROG = "mrl"
VERBS: tuple[ModuleType, ...] = (info, episodes, compare, calibrate, replay, twin, deploy, evaluate, sweep)
"""The verb modules in the order ``mrl --help`` lists them: each has NAME, ``add_parser(subparsers)`` and ``run``
(``run(args)``; the twin's ``run(rest)`` takes the arguments it parses itself)."""


def _help_width() -> int:
    """The width argparse wraps help text to (the terminal's, less a margin)."""
    return max(shutil.get_terminal_size().columns - 2, 40)


def _exit_codes_text() -> str:
    """Every exit code of the verbs with its meaning, one per entry (the epilog of ``mrl --help``)."""
    width = max(len(str(code)) for code in EXIT_CODES) + 2
    lines = ["exit codes:"]
    for code, meaning in EXIT_CODES.items():
        lines += textwrap.wrap(
            meaning, _help_width(), initial_indent=f"  {code:<{width}}", subsequent_indent=" " * (width + 2)
        )
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The ``mrl`` argument parser with every verb."""
    return _parsers()[0]


def _parsers() -> tuple[argparse.ArgumentParser, dict[str, VerbParser]]:
    """The ``mrl`` argument parser, and each verb's parser by name."""
    description = (
        "Recordings of multi-robot sessions (ROS 2 bags, ROS 1 bags, MCAP): inspect, tabulate, compare, calibrate "
        "the simulator, replay; run the hardware twin and deploy policies."
    )
    parser = argparse.ArgumentParser(
        prog=PROG,
        description=textwrap.fill(description, _help_width()),
        epilog=f"{_exit_codes_text()}\n\n`mrl VERB --help` for a verb's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    subparsers = parser.add_subparsers(dest="verb", metavar="VERB", required=True, parser_class=VerbParser)
    for verb in VERBS:
        verb.add_parser(subparsers)
    return parser, dict(subparsers.choices)


def _warning_line(verb: str, stream: TextIO) -> Callable[..., None]:
    """Each warning once, on one line (a file opened twice warns twice otherwise)."""
    shown: set[str] = set()

    def show(message: Warning | str, category: type[Warning], *args: object, **kwargs: object) -> None:
        text = str(message)
        if text in shown:
            return
        shown.add(text)
        print(f"mrl {verb}: warning: {text}", file=stream)

    return show


def _one_line(verb: str, body: Callable[[], int]) -> Callable[[], int]:
    """`body` with every MrlError's message put on one line."""

    def run() -> int:
        try:
            return body()
        except MrlError as exc:
            lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
            if len(lines) <= 1 or isinstance(exc, InvalidMeasurement):
                raise
            text = lines[0].rstrip(":") + ": " + "; ".join(lines[1:])
            raise CommandError(
                text, bool(getattr(exc, "interrupted", False)), runtime_fault=isinstance(exc, RuntimeFault)
            ) from exc

    return run


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``mrl`` with `argv` (default: the command line); the exit code."""
    parser, verbs = _parsers()
    args, rest = parser.parse_known_args(argv)
    verb: str = args.verb
    if verb == twin.NAME:
        return run_stage("mrl twin", lambda: twin.run(rest))
    if rest:
        verbs[verb].refuse_unrecognized(rest)  # the verb's usage and the nearest option; exits 2
    warnings.showwarning = _warning_line(verb, sys.stderr)
    return run_stage(f"mrl {verb}", _one_line(verb, lambda: _run_of(verb)(args)))


def _run_of(verb: str) -> Callable[[argparse.Namespace], int]:
    """The ``run`` of the verb module named `verb`."""
    run: Callable[[argparse.Namespace], int] = next(m.run for m in VERBS if verb == m.NAME)
    return run
