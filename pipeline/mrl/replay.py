"""``mrl replay RECORDING --policy DIR [--out DIR]``: the policy on the recorded observations, and the recorded
commands open loop in the policy's simulator; ``mrl replay BAG --map MAP [--calibration FILE]``: a bag without
motion capture, its commands open loop against its path localized in the map."""

from __future__ import annotations

import argparse
import math
import sys
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
    pose_argument,
    source_name,
)

NAME = "replay"
MAP_HORIZONS_S = (5.0, 10.0, 30.0)
"""With --map: the horizons the drift is read at (the longest is the window, --horizon-s replaces it)."""


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
        "commands, measuring the drift from the recorded ground truth: replay.md, replay.json, divergence.png.\n"
        "With --map instead of --policy: a bag of robots without motion capture, its commands open loop in the\n"
        "nominal simulator (and a calibrated one) against its path localized in the map, the drift at 5, 10\n"
        "and 30 s: replay_map.md, replay_map.json.",
    )
    replay.add_argument(
        "recording", metavar="RECORDING", help="a session with observations and actions (" + BAG_HELP + ")"
    )
    replay.add_argument("--policy", default=None, metavar="DIR", help="the exported policy folder (policy.json)")
    replay.add_argument(
        "--map", default=None, metavar="MAP", help="a map_server map (YAML): replay against the path localized in it"
    )
    replay.add_argument(
        "--initial-pose",
        type=pose_argument,
        default=None,
        metavar="X,Y,YAW",
        help="with --map: where the (single) robot starts, for localization (default: global localization)",
    )
    replay.add_argument("--out", default="replay", metavar="DIR", help="the output folder (default: replay)")
    replay.add_argument(
        "--calibration", default=None, metavar="FILE", help="calibration.yaml: also replay in the calibrated simulator"
    )
    replay.add_argument(
        "--horizon-s",
        type=float,
        default=None,
        metavar="S",
        help=f"seconds replayed per episode (default: {defaults.horizon_s:g}); with --map the window's length "
        f"(default: {MAP_HORIZONS_S[-1]:g}), the drift also read at the shorter of "
        f"{', '.join(f'{h:g}' for h in MAP_HORIZONS_S)} s",
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

    if args.policy is None and args.map is None:
        raise CommandError(
            "one of --policy DIR (a session with observations: the policy re-run on them) or --map MAP (a bag "
            "without motion capture: its commands replayed against its path localized in the map) is needed"
        )
    if args.policy is not None and args.map is not None:
        raise CommandError(
            f"--policy {args.policy} and --map {args.map}: give one of them, not both (--policy for a session "
            "with observations, --map for a bag without motion capture)"
        )
    if args.map is not None:
        return _map_run(args)
    out = output_folder(args.out)
    horizon = args.horizon_s if args.horizon_s is not None else ReplayConfig().horizon_s
    options = {"horizon_s": horizon, "max_episodes": args.max_episodes, "tolerance": args.tolerance}
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


def _map_run(args: argparse.Namespace) -> int:
    """The bag's commands open loop in the nominal simulator (and the calibrated one) against its localized path."""
    import json

    from pipeline.calibration.map_replay import map_replay
    from pipeline.params import calibrated_world, world_config

    longest = args.horizon_s if args.horizon_s is not None else MAP_HORIZONS_S[-1]
    if not (math.isfinite(longest) and longest > 0):
        raise CommandError(f"--horizon-s {args.horizon_s:g}: give a number of seconds above 0")
    horizons = (*(h for h in MAP_HORIZONS_S if h < longest), longest)
    out = output_folder(args.out)
    worlds = {"nominal": world_config({})}
    if args.calibration:
        worlds["calibrated"] = calibrated_world(worlds["nominal"], Path(args.calibration))
    with imported(args, [args.recording]) as (bag,):
        result = map_replay(
            [bag.path],
            args.map,
            worlds,
            horizons_s=horizons,
            initial_pose=args.initial_pose or (),
            progress=lambda stage: print(f"replay: {stage}", file=sys.stderr, flush=True),
        )
    table = result.lines()
    text = "\n".join(
        [
            f"# Open-loop replay of {source_name(bag)} against its path {result.localization}",
            "",
            f"{result.windows} windows of {result.window_s:g} s; the distance from the simulated robot to the path:",
            "",
            *table,
            "",
        ]
    )
    figures = {
        f"{d.world}/drift_{h:g}s_{kind}_m": value
        for d in result.drifts
        for kind, values in (("mean", d.mean_m), ("p90", d.p90_m))
        for h, value in values.items()
    }
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / "replay_map.md").write_text(text, encoding="utf-8")
        summary = {"windows": result.windows, "window_s": result.window_s, **figures}
        (out / "replay_map.json").write_text(json.dumps(summary, indent=2) + "\n")
    except OSError as exc:
        raise CommandError(f"--out {out}: cannot write ({exc.strerror or exc})") from exc
    for line in table:
        print(f"replay: {line}")
    print(f"replay: {out / 'replay_map.md'}")
    return 0
