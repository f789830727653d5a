"""Commit-ready copies of a finished run's small result files, with the command, commit, machine and date.

The loop's outputs (logs/, models/) are dvc outputs, not git files. This copies the small files that the README and
docs/ quote (metrics.json, episodes.csv, train_metrics.json, calibration.yaml, report.md and its metrics) from a
run's folder into ``benchmarks/results/<name>/`` beside a ``run.json`` that says how they were made, so every figure
can be re-derived from a committed file:

    python benchmarks/collect_results.py --root . --name loop/lab --command "dvc repro" --wall-s 1712

``--root`` is the folder the run wrote into (a checkout; its git commit is recorded), ``--files`` the files to copy
(globs relative to it; by default the loop's). Printed: the files copied and the headline figures found in them.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOOP_FILES = (
    "logs/sim/*/metrics.json",
    "logs/sim/*/episodes.csv",
    "logs/real/*/metrics.json",
    "logs/real/*/episodes.csv",
    "models/*/train_metrics.json",
    "logs/calibration/calibration.yaml",
    "logs/report/report.md",
    "logs/report/metrics.json",
    "logs/report/success_rates.png",
    "logs/replay/replay.json",
    "logs/replay/replay.md",
    "logs/scripted/metrics.json",
    "logs/stages/*.json",
    "dvc.lock",
)


RUN_RECORDS = ("dvc.lock",)
"""Tracked files that a run itself writes (dvc.lock: the hashes of each stage's inputs and outputs, as this run made
them): not local changes of the tree it ran from; they are copied with the results."""


def commit_of(root: Path) -> str:
    """The commit checked out at `root`, with ``+local changes`` when a tracked file other than the run's own
    records (:data:`RUN_RECORDS`) differs from it."""
    done = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"collect_results: {root} is in no git worktree; --made-in names the checkout of the run")
    status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True,
                            text=True, check=False).stdout  # fmt: skip
    dirty = [line for line in status.splitlines() if line[3:].strip() not in RUN_RECORDS]
    return done.stdout.strip() + ("+local changes" if dirty else "")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=ROOT, help="the folder the run wrote into (default: this one)")
    parser.add_argument("--name", required=True, help="the results folder under benchmarks/results/")
    parser.add_argument("--command", required=True, help="the command that made the run, as a user would type it")
    parser.add_argument("--files", nargs="*", default=list(LOOP_FILES), help="globs relative to --root")
    parser.add_argument("--wall-s", type=float, default=None, help="the run's wall time (s), when it was measured")
    parser.add_argument("--note", default="", help="what else a reader must know (other jobs beside it, ...)")
    parser.add_argument(
        "--made-in", type=Path, default=None, help="the checkout the run was made in, if not --root's (default: --root)"
    )
    args = parser.parse_args()
    root = args.root.resolve()
    commit = commit_of(args.made_in.resolve() if args.made_in is not None else root)  # before the copies change it
    out = ROOT / "benchmarks" / "results" / args.name
    copied = []
    for pattern in args.files:
        for path in sorted(root.glob(pattern)):
            target = out / path.relative_to(root)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, target)
            copied.append(str(path.relative_to(root)))
    if not copied:
        raise SystemExit(f"collect_results: nothing matched {args.files} under {root}")
    run = {
        "command": args.command,
        "commit": commit,
        "machine": f"{platform.node()} ({platform.machine()}, {os.cpu_count()} CPUs, {platform.python_version()})",
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "wall_s": args.wall_s,
        "note": args.note,
        "files": copied,
    }
    (out / "run.json").write_text(json.dumps(run, indent=2) + "\n", encoding="utf-8")
    for name in copied:
        print(f"collect_results: {name}")
        if name.endswith("metrics.json"):
            metrics = json.loads((out / name).read_text())
            for key in sorted(k for k in metrics if k.endswith(("/robot_success", "/aborted_episodes", "/episodes"))):
                print(f"  {key} = {metrics[key]}")
    print(f"collect_results: {out / 'run.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
