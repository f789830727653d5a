"""``mrl eval --policy DIR [--episodes N] [--out DIR] [--live]``: a recorded evaluation in the policy's simulator.

(The module is not named ``eval``, which would shadow the builtin where it is imported.)
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

from pipeline.mrl.common import add_verb, config_from_options, live_options, output_folder

NAME = "eval"


def add_parser(subparsers: Any) -> None:
    """The ``eval`` verb's options."""
    evaluate = add_verb(
        subparsers,
        NAME,
        "episodes of a policy in the simulator it was trained in, recorded to MCAP",
        "Episodes of an exported policy in its training world (policy.json's world and scenario), every message\n"
        "recorded: session.mcap, episodes.csv, metrics.json and paths.png in --out.",
    )
    evaluate.add_argument("--policy", required=True, metavar="DIR", help="the exported policy folder (policy.json)")
    evaluate.add_argument("--episodes", type=int, default=20, metavar="N", help="(default: 20)")
    evaluate.add_argument("--seed", type=int, default=10_000, metavar="N", help="(default: 10000)")
    evaluate.add_argument("--out", default="evaluation", metavar="DIR", help="the output folder (default: evaluation)")
    evaluate.add_argument(
        "--layouts",
        choices=("random", "fixed"),
        default="",
        help="a scenario with layouts ranges: a layout per episode (random) or its own (fixed); default: as trained",
    )
    live_options(evaluate)


def run(args: argparse.Namespace) -> int:
    """Evaluate the policy in its training world into --out and print the success rates."""
    from pipeline.params import EvalSimConfig
    from pipeline.policy.runtime import PolicyRuntime
    from pipeline.record.live import live_view
    from pipeline.rollout.sim import evaluate_session
    from pipeline.runs import eval_summary
    from pipeline.sim import make_world

    output_folder(args.out)
    cfg = config_from_options(EvalSimConfig, {"episodes": args.episodes, "seed": args.seed, "out_dir": args.out})
    runtime = PolicyRuntime(args.policy)
    world = runtime.spec.world
    if args.layouts:
        world = replace(world, layouts=args.layouts)
    scenario, world = make_world(world=world)
    out = Path(cfg.out_dir)
    with live_view(args.live, args.live_port, NAME) as live:
        results, metrics = evaluate_session(scenario, world, runtime, cfg, out, live=live)
    print(f"eval: {eval_summary(metrics, len(results), out)}")
    return 0
