"""``mrl deploy --policy DIR --fleet FLEET [--out DIR] [--drive excitation] [--live]``: a recorded deployment on a
fleet."""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from pipeline.mrl.common import add_verb, config_from_options, live_options, output_folder

if TYPE_CHECKING:
    from pipeline.policy.protocol import Policy

NAME = "deploy"


def add_parser(subparsers: Any) -> None:
    """The ``deploy`` verb's options (defaults from the deploy settings)."""
    from pipeline.params import DeployConfig

    defaults = DeployConfig()
    deploy = add_verb(
        subparsers,
        NAME,
        "episodes of a policy on a fleet (the twin by default), recorded to MCAP",
        "Episodes of an exported policy on a fleet, every message recorded: session.mcap (a rosbag2 folder),\n"
        "episodes.csv and metrics.json in --out. A fleet with `target: twin` starts the twin itself.",
    )
    deploy.add_argument("--policy", required=True, metavar="DIR", help="the exported policy folder (policy.json)")
    deploy.add_argument(
        "--fleet",
        required=True,
        metavar="FLEET",
        help="a bundled fleet (twin, twin_ros1, twin_rclpy, spark_lab) or a YAML file",
    )
    deploy.add_argument(
        "--episodes",
        type=int,
        default=defaults.episodes,
        metavar="N",
        help=f"(default: {defaults.episodes})",
    )
    deploy.add_argument("--seed", type=int, default=defaults.seed, metavar="N", help=f"(default: {defaults.seed})")
    deploy.add_argument(
        "--time-scale",
        type=_time_scale,
        default=0.0,
        metavar="X",
        help="the twin's time scale, or auto: the highest this host lets the twin keep, measured before the first "
        "episode and lowered when it falls behind (default: the fleet's)",
    )
    deploy.add_argument("--profile", default="", metavar="P", help="the twin's reality profile (default: the fleet's)")
    deploy.add_argument("--out", default="deployment", metavar="DIR", help="the output folder (default: deployment)")
    deploy.add_argument(
        "--domain-id",
        type=_domain_id,
        default=None,
        metavar="N",
        help="the DDS domain id (0-232) instead of the fleet file's, e.g. to run beside another deployment",
    )
    deploy.add_argument(
        "--drive",
        choices=("policy", "excitation"),
        default="policy",
        help="policy: the policy drives; excitation: a calibration drive with the policy's robots and limits, "
        "held steps of several sizes between the policy's driving (for `mrl calibrate`; default: policy)",
    )
    live_options(deploy)


def run(args: argparse.Namespace) -> int:
    """Deploy the policy on the fleet into --out and print the session's summary."""
    from pipeline.params import DeployConfig
    from pipeline.policy.runtime import PolicyRuntime
    from pipeline.ros.fleet import load_fleet
    from pipeline.runs import run_deployment

    out = output_folder(args.out)
    options = {"fleet": args.fleet, "episodes": args.episodes, "seed": args.seed, "out_dir": args.out}
    options.update(time_scale=args.time_scale, profile=args.profile)
    cfg = config_from_options(DeployConfig, options)
    fleet = load_fleet(cfg.fleet)
    if args.domain_id is not None:  # another DDS domain than the fleet file's, without writing a fleet file
        fleet = replace(fleet, network=replace(fleet.network, domain_id=args.domain_id))
    runtime: Policy = PolicyRuntime(args.policy)
    if args.drive == "excitation":
        from pipeline.policy.excitation import ExcitationDrive

        runtime = ExcitationDrive(runtime, seed=cfg.seed)
    run_deployment(runtime, fleet, cfg, out, live=args.live, live_port=args.live_port, live_label=NAME)
    return 0


def _time_scale(text: str) -> float | str:
    if text == "auto":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: a number of simulated seconds per second, or auto") from None


def _domain_id(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 232:
        raise argparse.ArgumentTypeError(f"{text!r}: a DDS domain id, an integer from 0 to 232")
    return value
