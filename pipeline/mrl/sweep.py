"""``mrl sweep --algorithms ... --seeds N [--axis KEY=V1,V2] [--set KEY=V] [--address ADDR]``: the training
matrix as Ray tasks (:mod:`pipeline.bench`), resumable, with its statistics across seeds."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.errors import ConfigError, ConfigProblem
from pipeline.mrl.common import add_verb, output_folder
from pipeline.stage import EXIT_DONE, EXIT_NO_RESULT

if TYPE_CHECKING:
    from pipeline.bench.trials import Trial

NAME = "sweep"


def add_parser(subparsers: Any) -> None:
    """The ``sweep`` verb's options: the matrix, then how it runs and where its report goes."""
    sweep = add_verb(
        subparsers,
        NAME,
        "the training matrix (algorithm x mode x scenario x seed x params keys) as Ray tasks, with statistics",
        "Each trial trains, exports and evaluates (--episodes from the exact starts) and writes its row; finished\n"
        "trials are skipped when the sweep is run again. Results: results.parquet/csv, results.md (IQM with\n"
        "stratified bootstrap intervals, by rliable), learning_curves.png, performance_profiles.png in --out.",
    )
    sweep.add_argument("--algorithms", nargs="+", default=["sac", "dqn"], metavar="A", help="sac dqn ppo")
    sweep.add_argument(
        "--modes", nargs="+", default=["independent"], metavar="M", help="independent shared centralized"
    )
    sweep.add_argument("--scenarios", nargs="+", default=["empty", "obstacles"], metavar="S", help="bundled or YAML")
    sweep.add_argument("--seeds", type=int, default=3, metavar="N", help="seeds per cell (default: 3)")
    sweep.add_argument("--first-seed", type=int, default=0, metavar="N", help="(default: 0)")
    sweep.add_argument(
        "--axis",
        action="append",
        default=[],
        metavar="KEY=V1,V2",
        help="a params.yaml key as one more axis, e.g. train.total_steps=100000,200000 (repeatable)",
    )
    sweep.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a params.yaml key set for every trial, e.g. train.total_steps=300000 (repeatable)",
    )
    sweep.add_argument(
        "--settings",
        default=None,
        metavar="FILE",
        help="a settings file: all: {KEY: VALUE} for every trial, sac:/dqn:/ppo: {KEY: VALUE} for one algorithm's "
        "(see benchmarks/sweeps/)",
    )
    sweep.add_argument(
        "--set-for",
        nargs=2,
        action="append",
        default=[],
        metavar=("ALGORITHM", "KEY=VALUE"),
        help="a params.yaml key set for that algorithm's trials only, e.g. sac train.updates_per_transition=1.0 "
        "(repeatable; shown in the table's settings column)",
    )
    _run_options(sweep)


def _run_options(sweep: argparse.ArgumentParser) -> None:
    """Where the settings come from, how the trials run and where the report goes."""
    sweep.add_argument(
        "--params", default="params.yaml", metavar="FILE", help="the base settings (default: params.yaml)"
    )
    sweep.add_argument("--episodes", type=int, default=200, metavar="N", help="evaluation episodes (default: 200)")
    sweep.add_argument("--out", default="logs/sweep", metavar="DIR", help="the sweep folder (default: logs/sweep)")
    sweep.add_argument("--address", default="", metavar="ADDR", help="a Ray cluster to use (default: a local one)")
    sweep.add_argument(
        "--workers", type=int, default=1, metavar="N", help="trials at once on the local Ray (default 1)"
    )
    sweep.add_argument("--cpus-per-trial", type=float, default=1.0, metavar="X", help="(default: 1)")
    sweep.add_argument("--bootstrap", type=int, default=2000, metavar="N", help="bootstrap resamples (default: 2000)")
    sweep.add_argument("--report-only", action="store_true", help="report the finished trials, run nothing")
    sweep.add_argument("--readme", default="", metavar="FILE", help="put the report between FILE's sweep markers")
    sweep.add_argument(
        "--readme-section",
        default="",
        metavar="NAME",
        help="use the markers '<!-- sweep results NAME: start/end -->' (default: '<!-- sweep results: ... -->')",
    )


def run(args: argparse.Namespace) -> int:
    """Run (or, with --report-only, collect) the trials, print their statistics and write the report."""
    from pipeline.bench.stats import cell_stats, markdown_table
    from pipeline.bench.sweep import collect, run_sweep, write_table
    from pipeline.bench.sweep_report import splice_readme, write_report

    if args.readme:  # checked before a sweep of hours, not after it
        _check_readme(args.readme, args.readme_section)
    trials, base = _matrix(args)
    out = output_folder(args.out)
    command = "mrl sweep " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["sweep"] else "mrl sweep"
    if args.report_only:
        rows = collect(out, trials, base)
        write_table(out, rows)
        print(f"sweep: report of {rows.height} finished trials of {len(trials)} in {out}")
    else:
        outcome = run_sweep(
            trials, base, out, args.episodes, args.address or None, args.workers, args.cpus_per_trial, command=command
        )
        rows = outcome.rows
    if rows.is_empty():
        print("sweep: no finished trial yet: nothing to report")
        return EXIT_DONE if args.report_only else EXIT_NO_RESULT
    stats = cell_stats(rows, reps=args.bootstrap)
    print(markdown_table(stats), end="")
    report = write_report(out, rows, stats, command)
    print(f"sweep: {report}, {out / 'results.parquet'}, {out / 'results.csv'}")
    if args.readme:
        readme = Path(args.readme)
        if splice_readme(readme, report, args.readme_section):
            print(f"sweep: the results table is in {readme}")
        else:
            print(f"sweep: {readme} lost its sweep markers while the sweep ran: left as it is")
    return 0


def _check_readme(readme: str, section: str) -> None:
    """ConfigError unless `section` is a plain name and `readme` holds its start and end markers."""
    from pipeline.bench.sweep_report import marks

    start_mark, end_mark = marks(section)
    if not re.fullmatch(r"[A-Za-z0-9_-]*", section):
        problem = ConfigProblem("name", section, "letters, digits, _ and -")
        raise ConfigError("--readme-section", [problem])
    text = Path(readme).read_text(encoding="utf-8") if Path(readme).is_file() else None
    if text is None or start_mark not in text or end_mark not in text:
        found = "missing" if text is None else "without the markers"
        problem = ConfigProblem(readme, found, f"a file with {start_mark} and {end_mark}")
        raise ConfigError("--readme", [problem])


def _matrix(args: argparse.Namespace) -> tuple[list[Trial], dict[str, Any]]:
    """The trials of the options' matrix and the base settings every trial starts from."""
    from pipeline.bench.trials import (
        base_mapping,
        expand,
        parse_axis,
        parse_setting,
        read_settings_file,
        scoped_keys,
        scoped_settings,
        with_settings,
    )
    from pipeline.params import load_params

    params = load_params(args.params)
    axes = [parse_axis(text) for text in args.axis]
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    trials = expand(args.algorithms, args.modes, args.scenarios, seeds, axes)
    settings: list[tuple[str, Any]] = []
    if args.settings:
        settings, scoped = read_settings_file(args.settings)
        trials = scoped_keys(trials, scoped)
    trials = scoped_settings(trials, args.set_for)
    settings += [parse_setting(text) for text in args.set]
    if not any(key == "train.world_workers" for key, _ in settings):  # a trial's worlds use the CPUs it holds
        settings.append(("train.world_workers", max(1, int(args.cpus_per_trial))))
    return trials, with_settings(base_mapping(params), settings)
