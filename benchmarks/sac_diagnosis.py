"""Why SAC misses its target: one change at a time against a baseline, as one sweep on Ray.

Every variant trains SAC in `--mode` (default: the paper's independent mode) in `--scenario` (default:
the obstacle room) with params.yaml's settings plus the shared `--set` keys, over `--seeds` seeds;
each variant changes one thing, named after the factor it tests:

- entropy: where the learned entropy coefficient starts (SB3's 1.0 against 0.05);
- budget: gradient steps per transition (0.2 against 1.0), and both together;
- shaping: a time penalty per step;
- network: two layers of 256 instead of 128;
- exploration: forward-only speed commands (actions in [0, v_max] instead of [-v_max, v_max]: random
  actions drive forward, as the discrete set's do);
- and the three that helped, together, also with a constant learning rate (params.yaml's decays to 0
  over the budget).

The trials run as one `mrl sweep` (``pipeline.bench.sweep``: finished trials are skipped when the
script runs again) and the table prints robot-level success IQM with its stratified bootstrap interval
(rliable), per robot, the seeds that met the paper's convergence criterion and the median training
episodes to it. Last line: ``<variant>=<IQM> ...``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import polars as pl

from pipeline.bench.stats import cell_stats
from pipeline.bench.sweep import collect, run_sweep, trial_folder
from pipeline.bench.trials import Trial, base_mapping, parse_setting, read_row, with_settings
from pipeline.params import load_params

VARIANTS: dict[str, tuple[tuple[str, Any], ...]] = {
    "baseline": (),
    "entropy: alpha from 0.05": (("train.sac.ent_coef_init", 0.05),),
    "budget: 1.0 updates/transition": (("train.updates_per_transition", 1.0),),
    "budget + entropy": (("train.updates_per_transition", 1.0), ("train.sac.ent_coef_init", 0.05)),
    "shaping: -0.05 per step": (("world.reward.step", -0.05),),
    "network: [256, 256]": (("train.net_arch", [256, 256]),),
    "exploration: forward only": (("world.actions.reverse", False),),
    "forward + budget": (("world.actions.reverse", False), ("train.updates_per_transition", 1.0)),
    "forward + budget + entropy": (
        ("world.actions.reverse", False),
        ("train.updates_per_transition", 1.0),
        ("train.sac.ent_coef_init", 0.05),
    ),
    "the three + constant learning rate": (
        ("world.actions.reverse", False),
        ("train.updates_per_transition", 1.0),
        ("train.sac.ent_coef_init", 0.05),
        ("train.learning_rate_schedule", "constant"),
    ),
}

DEFAULT_SET = [
    "train.total_steps=100000",
    "train.selection.every_steps=10000",
    "train.selection.keep=best",
    "train.selection.stop_at_success=1.0",
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS), metavar="V")
    parser.add_argument("--mode", default="independent")
    parser.add_argument("--scenario", default="obstacles")
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="added to " + str(DEFAULT_SET))
    parser.add_argument("--episodes", type=int, default=100, help="evaluation episodes per trial")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="logs/sac_diagnosis")
    parser.add_argument("--report-only", action="store_true", help="the table of the finished trials, run nothing")
    parser.add_argument(
        "--any-digest",
        action="store_true",
        help="with --report-only: take each trial's row whatever settings digest it carries (rows written before a "
        "params key with a default was added)",
    )
    args = parser.parse_args()

    settings = [parse_setting(text) for text in [*DEFAULT_SET, *args.set]]
    settings.append(("train.world_workers", 1))
    base = with_settings(base_mapping(load_params()), settings)
    trials = {
        (name, seed): Trial("sac", args.mode, args.scenario, seed, VARIANTS[name])
        for seed in range(args.seeds)  # every variant's first seed first
        for name in args.variants
    }
    if args.report_only and args.any_digest:
        found = [read_row(trial_folder(Path(args.out), t)) for t in trials.values()]
        rows = pl.DataFrame([r for r in found if r is not None])
    elif args.report_only:
        rows = collect(Path(args.out), list(trials.values()), base)
    else:
        rows = run_sweep(list(trials.values()), base, Path(args.out), args.episodes, workers=args.workers).rows
    stats = {s.cell: s for s in cell_stats(rows)} if not rows.is_empty() else {}
    shared = " ".join(DEFAULT_SET + args.set)
    print(f"SAC, {args.mode} mode, {args.scenario}, {args.seeds} seeds; shared settings: {shared}")
    print(
        "| variant | seeds | robot success IQM, % [95 % CI] | per robot, % | converged seeds | "
        "episodes to convergence |"
    )
    print("|---|---|---|---|---|---|")
    figures = []
    for name in args.variants:
        cell = trials[(name, 0)].cell
        s = stats.get(cell)
        if s is None:
            print(f"| {name} | 0 | - | - | - | - |")
            continue
        per_robot = ", ".join(f"{100 * v:.0f}" for v in s.per_robot_iqm.values())
        episodes = "-" if s.episodes_to_convergence is None else f"{s.episodes_to_convergence:.0f}"
        print(
            f"| {name} | {s.seeds} | {100 * s.robot_iqm:.1f} [{100 * s.robot_ci[0]:.1f}, {100 * s.robot_ci[1]:.1f}] "
            f"| {per_robot} | {s.converged_seeds}/{s.seeds} | {episodes} |"
        )
        figures.append(f"{name.split(':')[0].replace(' ', '')}={100 * s.robot_iqm:.1f}")
    print(" ".join(figures))


if __name__ == "__main__":
    main()
