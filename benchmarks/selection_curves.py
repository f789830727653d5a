"""Periodic evaluations of trainings side by side: robot success and collision rate against world steps.

Each run is a training's round folder (the one holding ``selection.csv``, e.g. ``models/nominal``),
given as LABEL=FOLDER. Prints each run's best evaluation and its last, and writes one PNG:

    python benchmarks/selection_curves.py --run "plain path=/tmp/a/models/nominal" \\
        --run "path 0.15 m clear=/tmp/b/models/nominal" --out benchmarks/figures/layouts_training.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import polars as pl

from pipeline.learn.selection import SELECTION_FILE


def _runs(specs: list[str]) -> list[tuple[str, pl.DataFrame]]:
    runs = []
    for spec in specs:
        label, sep, folder = spec.rpartition("=")
        if not sep or not label:
            raise SystemExit(f"--run {spec!r}: expected LABEL=FOLDER")
        path = Path(folder) / SELECTION_FILE
        if not path.is_file():
            raise SystemExit(f"--run {spec!r}: {path} does not exist (the folder of a training round)")
        table = pl.read_csv(path)
        missing = {"world_steps", "robot_success", "collision_rate"} - set(table.columns)
        if missing:
            raise SystemExit(f"{path}: columns {sorted(missing)} are missing")
        runs.append((label, table.unique("world_steps", keep="last").sort("world_steps")))
    return runs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", action="append", required=True, help="LABEL=FOLDER (repeat)")
    parser.add_argument("--out", type=Path, required=True, help="the PNG to write")
    parser.add_argument("--title", default="periodic deterministic evaluations during training")
    args = parser.parse_args(argv)
    runs = _runs(args.run)

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for k, (label, table) in enumerate(runs):
        steps = table["world_steps"].to_numpy() / 1e6
        color = f"C{k}"
        top.plot(steps, 100 * table["robot_success"].to_numpy(), color=color, label=label)
        bottom.plot(steps, 100 * table["collision_rate"].to_numpy(), color=color, label=label)
        best = table.sort("robot_success", descending=True).row(0, named=True)
        last = table.row(-1, named=True)
        print(
            f"{label}: best robot success {best['robot_success']:.3f} at {best['world_steps']} steps "
            f"(collisions {best['collision_rate']:.3f}); last {last['robot_success']:.3f} at {last['world_steps']} "
            f"(collisions {last['collision_rate']:.3f})"
        )
    top.set_ylabel("robot success (%)")
    bottom.set_ylabel("robots collided (%)")
    bottom.set_xlabel("world steps (millions)")
    top.set_ylim(0, 100)
    bottom.set_ylim(0, 100)
    top.set_title(args.title, fontsize=10)
    top.legend(fontsize=8, loc="upper left")
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
