"""Command-line plumbing shared by the dvc stage scripts: arguments, signals, exit codes.

Exit codes: 0 success, 2 bad input (an MrlError: its message names the file, key or topic),
130 interrupted (Ctrl-C or SIGTERM; what was recorded so far is kept).
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from pipeline.errors import MrlError

if TYPE_CHECKING:
    from pipeline.rollout.deployment import DeploymentOutcome

ROUNDS = ("nominal", "calibrated")
EXIT_BAD_INPUT = 2
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
        return EXIT_INTERRUPTED if getattr(exc, "interrupted", False) else EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def operator_reset(episode: int) -> None:
    """Ask the operator to put the robots at their start poses (the deploy runner's reset on real fleets)."""
    input(f"deploy: put every robot at its start pose for episode {episode}, then press Enter ")


def deploy_summary(outcome: DeploymentOutcome, target: str, out: Path) -> str:
    """One line on a finished deployment: robot and team success with 95 % intervals, episodes, where it went."""
    metrics = outcome.metrics
    nan = float("nan")
    return (
        f"robot success {metrics.get('real/robot_success', nan):.3f} "
        f"[{metrics.get('real/robot_success_ci_low', nan):.3f}, {metrics.get('real/robot_success_ci_high', nan):.3f}], "
        f"team success {metrics.get('real/team_success', nan):.3f} over {len(outcome.results)} episodes "
        f"({metrics['real/aborted_episodes']:.0f} aborted) on {target} ({outcome.profile}) -> {out}"
    )
