"""Command-line plumbing shared by the dvc stage scripts: arguments, signals, exit codes.

Exit codes: 0 success, 2 bad input (an MrlError: its message names the file, key or topic), 3 runtime fault
(a RuntimeFault: a twin or driver gone, a robot blind past its outage limit, a clash on the domain), 130
interrupted (Ctrl-C or SIGTERM; what was recorded so far is kept).
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from pipeline.core.episode import ABORT_KINDS
from pipeline.errors import MrlError, RuntimeFault

if TYPE_CHECKING:
    from pipeline.rollout.deployment import DeploymentOutcome

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


def operator_reset(episode: int) -> None:
    """Ask the operator to put the robots at their start poses (the deploy runner's reset on real fleets)."""
    input(f"deploy: put every robot at its start pose for episode {episode}, then press Enter ")


def deploy_summary(outcome: DeploymentOutcome, target: str, out: Path) -> str:
    """Lines on a finished deployment: success over every episode with 95 % intervals, the completed-only rate beside
    it, aborted episodes by reason, stale seconds per robot, where it went."""
    kept = f"; earlier sessions kept beside it: {', '.join(p.name for p in outcome.kept)}" if outcome.kept else ""
    return f"{session_summary(outcome.metrics, 'real')} on {target} ({outcome.profile}) -> {out}{kept}"


def session_summary(metrics: dict[str, float], world: str) -> str:
    """What happened in a session, from its metrics (``<world>/...``): episodes, aborted (and why), robot and team
    success over every episode with 95 % intervals, the completed-only robot rate, stale seconds per robot."""
    nan = float("nan")

    def get(key: str) -> float:
        return metrics.get(f"{world}/{key}", nan)

    def rate(key: str) -> str:
        return f"{get(key):.3f} [{get(key + '_ci_low'):.3f}, {get(key + '_ci_high'):.3f}]"

    why = ", ".join(f"{get('aborted_' + k):.0f} {k}" for k in ABORT_KINDS if get("aborted_" + k) > 0)
    robots = sorted(
        k.split("/")[1][: -len("_stale_s")]
        for k in metrics
        if k.startswith(f"{world}/robot_") and k.endswith("_stale_s")
    )
    stale = ", ".join(f"{r} {get(r + '_stale_s'):.1f} s" for r in robots)
    return (
        f"{get('episodes'):.0f} episodes, {get('aborted_episodes'):.0f} aborted{f' ({why})' if why else ''}: "
        f"robot success {rate('robot_success')}, team success {rate('team_success')} over every episode; "
        f"completed episodes only {get('robot_success_completed'):.3f} robot, "
        f"{get('team_success_completed'):.3f} team; stale {stale or 'none'}"
    )
