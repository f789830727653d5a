"""``mrl compare SIM REAL [--out DIR]``: the sim-vs-real report of two recordings."""

from __future__ import annotations

import argparse
import math
from typing import Any

from pipeline.mrl.common import BAG_HELP, add_verb, bag_options, imported, output_folder

NAME = "compare"


def add_parser(subparsers: Any) -> None:
    """The ``compare`` verb's options."""
    compare = add_verb(
        subparsers,
        NAME,
        "the sim-vs-real report of two recordings",
        "Success rates with 95 % intervals, their sim - real gaps and tests, time to goal, collisions,\n"
        "trajectories: report.md, metrics.json and figures in --out.",
    )
    compare.add_argument("sim", metavar="SIM", help="the simulated session (" + BAG_HELP + ")")
    compare.add_argument("real", metavar="REAL", help="the real (or twin) session")
    compare.add_argument("--out", default="report", metavar="DIR", help="the report folder (default: report)")
    compare.add_argument(
        "--trajectory-episodes", type=int, default=3, metavar="N", help="episodes drawn per session (default: 3)"
    )
    bag_options(compare)


def run(args: argparse.Namespace) -> int:
    """Write the report of the two sessions and print the gaps of the success and collision rates."""
    from pipeline.analysis.gap_report import write_report

    out = output_folder(args.out)
    with imported(args, [args.sim, args.real]) as (sim, real):
        report = write_report(
            out, [("", "sim", sim.path), ("", "real", real.path)], trajectory_episodes=args.trajectory_episodes
        )
    metrics = report.comparison.metrics

    def show(key: str) -> str:
        value = metrics.get(key, math.nan)
        return "-" if math.isnan(value) else f"{value:.3f}"

    for name in ("robot_success", "team_success", "collision_rate"):
        print(
            f"compare: {name} sim {show(f'sim/{name}')} real {show(f'real/{name}')} "
            f"gap {show(f'gap/{name}')} [{show(f'gap/{name}_ci_low')}, {show(f'gap/{name}_ci_high')}] "
            f"(Fisher p {show(f'gap/{name}_p_value')})"
        )
    print(f"compare: {report.markdown} and {report.metrics}")
    return 0
