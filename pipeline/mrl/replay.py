"""``mrl replay RECORDING --policy DIR [--out DIR]``: the policy on the recorded observations, and the recorded
commands open loop in the policy's simulator."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from pipeline.mrl.common import (
    BAG_HELP,
    CommandError,
    add_verb,
    bag_options,
    config_from_options,
    imported,
    output_folder,
    source_name,
)

NAME = "replay"


def add_parser(subparsers: Any) -> None:
    """The ``replay`` verb's options (defaults from the replay settings)."""
    from pipeline.params import ReplayConfig

    defaults = ReplayConfig()
    replay = add_verb(
        subparsers,
        NAME,
        "a policy on a recording's observations, and its commands open loop in the simulator",
        "Re-runs the policy on the recorded observations (does it give the recorded actions?) and drives\n"
        "the simulator the policy was trained in (and a calibrated one) open loop with the recorded\n"
        "commands, measuring the drift from the recorded ground truth: replay.md, replay.json, divergence.png.",
    )
    replay.add_argument(
        "recording", metavar="RECORDING", help="a session with observations and actions (" + BAG_HELP + ")"
    )
    replay.add_argument("--policy", required=True, metavar="DIR", help="the exported policy folder (policy.json)")
    replay.add_argument("--out", default="replay", metavar="DIR", help="the output folder (default: replay)")
    replay.add_argument(
        "--calibration", default=None, metavar="FILE", help="calibration.yaml: also replay in the calibrated simulator"
    )
    replay.add_argument(
        "--horizon-s", type=float, default=defaults.horizon_s, metavar="S", help="seconds replayed per episode"
    )
    replay.add_argument(
        "--max-episodes", type=int, default=defaults.max_episodes, metavar="N", help="episodes replayed"
    )
    replay.add_argument(
        "--tolerance",
        type=float,
        default=defaults.tolerance,
        metavar="X",
        help="largest |replayed - recorded| policy output counted as agreement",
    )
    bag_options(replay)


def run(args: argparse.Namespace) -> int:
    """Replay the recording, write replay.md, replay.json and divergence.png, print the metrics."""
    from pipeline.analysis.replay_report import run_replay, write_replay
    from pipeline.params import ReplayConfig, calibrated_world
    from pipeline.policy.runtime import PolicyRuntime

    out = output_folder(args.out)
    options = {"horizon_s": args.horizon_s, "max_episodes": args.max_episodes, "tolerance": args.tolerance}
    cfg = config_from_options(ReplayConfig, options)
    runtime = PolicyRuntime(args.policy)
    scenario = runtime.spec.scenario
    worlds = {"trained": runtime.spec.world}
    if args.calibration:
        worlds["calibrated"] = calibrated_world(worlds["trained"], Path(args.calibration))
    with imported(args, [args.recording]) as (bag,):
        label = source_name(bag)
        result = run_replay(
            {label: bag.path},
            {label: runtime},
            scenario,
            worlds,
            label,
            cfg.horizon_s,
            cfg.max_episodes,
            cfg.tolerance,
        )
    try:
        metrics = write_replay(result, label, out)
    except OSError as exc:
        raise CommandError(f"--out {out}: cannot write ({exc.strerror or exc})") from exc
    for key, value in sorted(metrics.items()):
        print(f"replay: {key} = {value}")
    print(f"replay: {out / 'replay.md'}")
    return 0
