"""``mrl calibrate BAG... [--scenario S] [--map FLOOR.yaml] [--initial-pose X,Y,YAW] [--out DIR]``: the calibration
file and its fit report (poses from motion capture, or localized in the map without it)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from pipeline.mrl.common import (
    BAG_HELP,
    OPTIONS_SOURCE,
    CommandError,
    add_verb,
    bag_options,
    imported,
    output_folder,
    pose_argument,
)

NAME = "calibrate"


def add_parser(subparsers: Any) -> None:
    """The ``calibrate`` verb's options."""
    calibrate = add_verb(
        subparsers,
        NAME,
        "estimate lidar noise, actuation, odometry and network from recordings",
        "Estimates of the reality profile (lidar, actuation, odometry, network) with uncertainties from\n"
        "recordings of one scenario, with motion capture or localized in the map from scans and odometry:\n"
        "calibration.yaml (read by training) and a fit\n"
        "report (calibration.md with plots) in --out.",
    )
    calibrate.add_argument(
        "bags", nargs="+", metavar="BAG", help=BAG_HELP + "; several of one kind and one fleet are pooled"
    )
    calibrate.add_argument(
        "--pool",
        action="store_true",
        help="pool recordings of different kinds (sim, twin, real) or of different robots (refused without it)",
    )
    calibrate.add_argument(
        "--scenario",
        default="",
        metavar="S",
        help="the scenario the robots drove in (a bundled name or a YAML file); needed when the bags name none",
    )
    calibrate.add_argument(
        "--out", default="calibration", metavar="DIR", help="the output folder (default: calibration)"
    )
    calibrate.add_argument(
        "--parts",
        type=_parts,
        default=None,
        metavar="P,...",
        help="what to estimate, of lidar,actuation,odometry,network (default: all)",
    )
    calibrate.add_argument(
        "--bootstrap",
        type=int,
        default=None,
        metavar="N",
        help="bootstrap resamples of the uncertainties (default: 200)",
    )
    calibrate.add_argument("--seed", type=int, default=None, metavar="N", help="seed of the bootstrap (default: 0)")
    _pose_options(calibrate)
    bag_options(calibrate)


def _pose_options(calibrate: argparse.ArgumentParser) -> None:
    """--pose-source, --map and --initial-pose: where the robots' poses come from."""
    calibrate.add_argument(
        "--pose-source",
        choices=("auto", "ground_truth", "scans"),
        default="auto",
        help="the robots' poses: motion capture (/<ns>/ground_truth), localization from scans and odometry "
        "against the map, or auto (ground truth where every robot has it; default)",
    )
    calibrate.add_argument(
        "--map",
        default=None,
        metavar="FLOOR.yaml",
        help="a ROS map_server map (YAML + image) to localize in (default: the scenario's walls and boxes)",
    )
    calibrate.add_argument(
        "--initial-pose",
        type=pose_argument,
        default=None,
        metavar="X,Y,YAW",
        help="where the (single) robot starts, for localization (default: global localization)",
    )


def run(args: argparse.Namespace) -> int:
    """Calibrate from the bags, write calibration.yaml and its report, print what could not be identified."""
    from pipeline.calibration import PARTS, calibrate, calibration_settings, write_calibration
    from pipeline.calibration.scan_only import scans_only
    from pipeline.record.bags import bag_sha256

    output_folder(args.out)
    options: dict[str, Any] = {"parts": list(args.parts or PARTS), "scenario": args.scenario}
    options.update({k: v for k, v in (("bootstrap", args.bootstrap), ("seed", args.seed)) if v is not None})
    options.update(
        {
            "pose_source": args.pose_source,
            "map_file": args.map or "",
            "initial_pose": args.initial_pose or [],
            "pool": args.pool,
        }
    )
    settings = calibration_settings(options, source=OPTIONS_SOURCE)
    alone = [bag for bag in args.bags if scans_only(Path(bag))]
    if alone:
        return _scans_alone(args, alone, settings)
    with imported(args, args.bags) as bags:
        calibration = calibrate([bag.path for bag in bags], settings, progress=_progress)
        given = {str(bag.path): bag for bag in bags}
        sources = []
        for source in calibration.sources:  # a converted bag named and hashed as the user has it, not its copy
            bag = given.get(source.path)
            if bag is not None and bag.converted:
                source = replace(source, path=str(bag.source), sha256=bag_sha256(bag.source))
            sources.append(source)
        path = write_calibration(replace(calibration, sources=tuple(sources)), args.out)
    _print_values(calibration)
    for limit in calibration.speed_limits():
        print(f"calibrate: {limit.sentence()}")
    for ambiguity in calibration.actuation.ambiguities if calibration.actuation else ():
        print(f"calibrate: ambiguous: {ambiguity.sentence()}")
    for agreement in calibration.gain_agreement():
        print(f"calibrate: {agreement.sentence()}")
    for name, value in calibration.effective.items():
        if value.estimate.ok and value.estimate.value is not None:
            print(f"calibrate: {_effective_sentence(calibration, name, value)}")
    poses = calibration.pose_source.sentence()
    if poses:
        print(f"calibrate: {poses}")
    print(f"calibrate: {path} from {', '.join(str(bag.source) for bag in bags)}")
    return 0


def _effective_sentence(calibration: Any, name: str, value: Any) -> str:
    """What an effective value is, beside the values of the keys it stands for that were measured apart."""
    parts = []
    for key in value.stands_for:
        est = calibration.values.get(key)
        if est is not None and est.ok and est.value is not None:
            parts.append(f"{key} {est.value:.3g} {est.unit}, measured at the wheels")
        else:
            parts.append(f"{key} (not measured apart)")
    return (
        f"effective.{name} {value.estimate.value:.3g} {value.estimate.unit}: the simulator's drive model as the body "
        f"moved, from each command's time in the recording (the command path's latency included); it stands for "
        f"{'; '.join(parts)}"
    )


def _progress(stage: str) -> None:
    """Each stage of the calibration as it starts, on stderr (the results go to stdout)."""
    print(f"calibrate: {stage}", file=sys.stderr, flush=True)


def _print_values(calibration: Any) -> None:
    """One line per key: the estimate with its interval and status, or why it is unidentifiable."""
    for key, est in calibration.values.items():
        if est.ok and est.value is not None and est.interval is not None:
            lo, hi = est.interval
            flag = f" ({est.reason})" if est.status != "ok" else ""
            print(f"calibrate: {key} {est.value:.4g} {est.unit} [{lo:.4g}, {hi:.4g}]{flag}")
    for key, reason in calibration.unidentified().items():
        print(f"calibrate: {key} unidentifiable: {reason}")


def _scans_alone(args: argparse.Namespace, alone: list[str], settings: Any) -> int:
    """A bag of scans alone (no odometry, no commands): the lidar's keys the scans tell, the rest named."""
    from pipeline.calibration import write_calibration
    from pipeline.calibration.scan_only import calibrate_scans

    if len(args.bags) > 1:
        raise CommandError(
            f"{alone[0]} holds scans alone (no odometry or commands): calibrate it by itself, not pooled with "
            f"{', '.join(b for b in args.bags if b != alone[0])}"
        )
    if args.map:
        print(
            f"calibrate: --map {args.map} not used: localizing in a map needs odometry, and {alone[0]} has scans "
            "alone (the noise, range step, rate and beams are read from the scans where the sensor stood still)"
        )
    calibration = calibrate_scans(Path(alone[0]), settings)
    path = write_calibration(calibration, args.out)
    _print_values(calibration)
    for note in calibration.lidar.notes if calibration.lidar else ():
        print(f"calibrate: {note}")
    print(f"calibrate: {path} from {alone[0]} (scans alone)")
    return 0


def _parts(text: str) -> list[str]:
    from pipeline.calibration import PARTS

    parts = [p.strip() for p in text.split(",") if p.strip()]
    bad = [p for p in parts if p not in PARTS]
    if bad or not parts:
        raise argparse.ArgumentTypeError(f"{text!r}: expected some of {','.join(PARTS)} separated by commas")
    return parts
