"""``mrl``: the pipeline's verbs for recordings brought from elsewhere, without the dvc layout.

Each verb calls the same library function as its dvc stage (stages/), with options instead of
params.yaml:

- ``mrl info BAG...``: topics, types, counts, times, robots, source format, what the other verbs can do;
- ``mrl episodes BAG [--out FILE.csv|FILE.parquet]``: the episodes table (one row per episode and robot);
- ``mrl compare SIM REAL [--out DIR]``: the sim-vs-real report of two recordings;
- ``mrl calibrate BAG... [--scenario S] [--map FLOOR.yaml] [--initial-pose X,Y,YAW] [--out DIR]``: the
  calibration file and its fit report (poses from motion capture, or localized in the map without it);
- ``mrl replay RECORDING --policy DIR [--out DIR]``: the policy on the recorded observations, and the
  recorded commands open loop in the policy's simulator;
- ``mrl twin ...``: the hardware twin (the options of ``python -m pipeline.twin``);
- ``mrl deploy --policy DIR --fleet FLEET [--out DIR] [--live]``: a recorded deployment on a fleet;
- ``mrl eval --policy DIR [--episodes N] [--out DIR] [--live]``: a recorded evaluation in the policy's simulator;
- ``mrl sweep --algorithms ... --seeds N [--axis KEY=V1,V2] [--set KEY=V] [--address ADDR]``: the training
  matrix as Ray tasks (:mod:`pipeline.bench`), resumable, with its statistics across seeds.

``--live`` serves the session to the Foxglove app while it runs (:mod:`pipeline.record.live`).

A BAG is an MCAP file, a rosbag2 folder (``metadata.yaml`` with mcap or sqlite3 storage) or a ROS 1
``.bag``; anything but a session recording of this project is imported into the session layout in
a temporary folder (:func:`pipeline.record.import_bag`), removed when the command ends. Messages
about an imported bag name the bag as given, not the temporary copy.

Exit codes (:mod:`pipeline.cli`): 0 done, 2 bad input (one line ``mrl <verb>: <message>`` on stderr),
130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import sys
import tempfile
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from pipeline.cli import deploy_summary, operator_reset, run_stage
from pipeline.core.timebase import NS_PER_S
from pipeline.errors import ConfigError, ConfigProblem, MrlError, RuntimeFault
from pipeline.record.live import live_view

if TYPE_CHECKING:
    from pipeline.record import ImportedBag

PROG = "mrl"
UNIX_TIME_FROM_NS = 946_684_800 * NS_PER_S
"""Log times from 2000-01-01 on are shown as dates (Unix time); earlier ones are a session clock."""
TABLE_SUFFIXES = (".csv", ".parquet")
EPISODE_COLUMNS = (
    "episode",
    "robot",
    "success",
    "collided",
    "timeout",
    "aborted",
    "abort_kind",
    "stale_s",
    "time_to_goal_s",
    "path_length_m",
    "steps",
    "team_success",
)
"""Columns of the episodes table printed by ``mrl episodes`` (a file gets every column)."""
BAG_HELP = "an MCAP file, a rosbag2 folder (mcap or sqlite3 storage) or a ROS 1 .bag"


class CommandError(MrlError):
    """Bad input to a verb (an option, an output path), or a library error reworded for the command line."""

    def __init__(self, message: str, interrupted: bool = False, runtime_fault: bool = False) -> None:
        self.interrupted = interrupted
        self.runtime_fault = runtime_fault
        """A runtime fault reworded onto one line: it still exits 3."""
        super().__init__(message)


# -- bags ---------------------------------------------------------------------------------------


def _robot_list(text: str) -> list[str]:
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"{text!r}: expected robot names separated by commas, e.g. robot_1,robot_2")
    return names


def _bag_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--robots",
        type=_robot_list,
        default=None,
        metavar="A,B,...",
        help="the robots' namespaces to keep, in this order (default: every robot found); one name for a bag "
        "whose topics carry no namespace",
    )
    parser.add_argument(
        "--topic",
        action="append",
        default=[],
        metavar="OURS=BAG",
        help="where the bag keeps a topic of ours (repeatable): a kind of the single robot (scan, odom, cmd_vel, "
        "ground_truth) or a full topic, e.g. --topic scan=/base_scan or --topic /robot_1/scan=/r1/base_scan",
    )


@contextlib.contextmanager
def _imported(args: argparse.Namespace, paths: Sequence[str]) -> Iterator[list[ImportedBag]]:
    """The bags of `paths` imported into a temporary folder (removed afterwards); errors name the bags as given."""
    from tqdm import tqdm

    from pipeline.record import import_bag, parse_topic_map

    topic_map = parse_topic_map(args.topic)
    with tempfile.TemporaryDirectory(prefix="mrl-") as work:
        bags: list[ImportedBag] = []
        with _as_given(bags):
            for path in tqdm(paths, desc="import", unit="bag", disable=None if len(paths) > 1 else True):
                bags.append(import_bag(path, robots=args.robots, topic_map=topic_map, work_dir=work))
            yield bags


@contextlib.contextmanager
def _as_given(bags: Sequence[ImportedBag]) -> Iterator[None]:
    """Reword MrlErrors raised inside so that they name each converted bag by its source path."""
    try:
        yield
    except MrlError as exc:
        text = str(exc)
        for bag in bags:
            if bag.converted:
                text = text.replace(str(bag.path), str(bag.source)).replace(str(bag.path.parent), str(bag.source))
        if text == str(exc):
            raise
        raise CommandError(text, bool(getattr(exc, "interrupted", False))) from exc


def _source_name(bag: ImportedBag) -> str:
    """The bag's name for tables and reports: its file name without suffix (a folder's name)."""
    return bag.source.resolve().stem if bag.source.is_file() else bag.source.resolve().name


# -- info ---------------------------------------------------------------------------------------


def _when(t_ns: int) -> str:
    if t_ns >= UNIX_TIME_FROM_NS:
        stamp = datetime.fromtimestamp(t_ns / NS_PER_S, tz=UTC).isoformat(timespec="milliseconds")
        return f"{stamp} ({t_ns} ns)"
    return f"{t_ns / NS_PER_S:.3f} s on the session clock ({t_ns} ns)"


def _recorded_scenario(meta: dict[str, dict[str, str]]) -> str:
    """The scenario a recording names (its ``scenario`` document or its session's ``scenario``), else ''."""
    import json

    text = meta.get("scenario", {}).get("text")
    if text:
        try:
            return str(json.loads(text).get("name", "")) or "(a scenario document)"
        except (ValueError, AttributeError):
            return "(an unreadable scenario document)"
    return meta.get("session", {}).get("scenario", "")


def describe(bag: ImportedBag) -> str:
    """What ``mrl info`` prints about one imported bag."""
    from pipeline.analysis.tables import EPISODE_TOPIC, Recording
    from pipeline.calibration import PARTS
    from pipeline.calibration.recording import PoseSourceKind, topics_for

    log = bag.log()
    meta = log.metadata()
    topics = bag.topic_types()
    counts = bag.message_counts()
    robots = bag.robots
    session = meta.get("session")
    scenario = _recorded_scenario(meta)
    how = "a session recording of this project, read as it is" if not bag.converted else "imported"
    lines = [
        f"bag: {bag.source}",
        f"  format: {bag.source_format} ({how})",
        f"  start: {_when(bag.start_ns)}",
        f"  end: {_when(bag.end_ns)}",
        f"  duration: {bag.duration_ns / NS_PER_S:.3f} s",
        f"  messages: {bag.message_count} on {len(topics)} topics",
        f"  robots: {', '.join(robots)} ({len(robots)})",
    ]
    if session:
        facts = ", ".join(f"{k} {session[k]}" for k in ("world", "profile", "policy") if session.get(k))
        lines.append(f"  session metadata: yes ({facts or 'no details'})")
    else:
        lines.append("  session metadata: no (not recorded by this project)")
    lines.append(f"  scenario: {scenario or 'not named'}")
    episodes = 0
    if EPISODE_TOPIC in topics:
        episodes = Recording(log).episodes().height
        lines.append(f"  episode events: yes ({episodes} episodes on {EPISODE_TOPIC})")
    else:
        lines.append(f"  episode events: no ({EPISODE_TOPIC} absent)")
    truth = [r for r in robots if f"/{r}/ground_truth" in topics]
    if truth:
        which = "every robot" if len(truth) == len(robots) else ", ".join(truth)
        lines.append(f"  ground truth: yes ({which})")
    else:
        lines.append("  ground truth: no")
    lines.append("  topics:")
    width = max(len(t) for t in topics)
    type_width = max(len(t) for t in topics.values())
    renamed = {t.name: t.source for t in bag.topics if t.source != t.name}
    for name in sorted(topics):
        origin = f"  (from {renamed[name]})" if name in renamed else ""
        lines.append(f"    {name:<{width}}  {topics[name]:<{type_width}}  {counts[name]:>8}{origin}")
    if bag.skipped:
        lines.append("  left out:")
        lines += [f"    {topic}: {why}" for topic, why in bag.skipped.items()]

    lines.append("  what the verbs can do with it:")
    usable: list[tuple[str, list[str]]] = []
    missing: list[tuple[str, list[str]]] = []
    source: PoseSourceKind = "ground_truth" if truth and len(truth) == len(robots) else "scans"
    for part in PARTS:
        kinds = topics_for(part, source)
        absent = [f"/{r}/{kind}" for kind in kinds for r in robots if f"/{r}/{kind}" not in topics]
        (missing if absent else usable).append((part, absent))
    if usable:
        poses = (
            "ground truth present"
            if source == "ground_truth"
            else "no ground truth: poses localized from scans and odometry in the scenario's room or --map FLOOR.yaml"
        )
        text = ", ".join(part for part, _ in usable) + f" ({poses})"
        text += (
            f"; scenario {scenario} recorded" if scenario else "; needs --scenario or --map since the bag names none"
        )
        if missing:
            text += "; not " + "; not ".join(f"{part} (no {', '.join(absent)})" for part, absent in missing)
    else:
        text = "nothing: needs /<robot>/ground_truth (motion capture) or /<robot>/scan and /<robot>/odom, and commands"
    lines.append(f"    calibrate: {text}")
    episodes_text = (
        f"{episodes} episodes x {len(robots)} robots"
        if EPISODE_TOPIC in topics
        else f"needs {EPISODE_TOPIC} (recorded by this project)"
    )
    lines.append(f"    episodes: {episodes_text}")
    lines.append(f"    compare: {'as SIM or REAL' if EPISODE_TOPIC in topics else episodes_text}")
    agreement = [t for t in ("/mrl/observation", "/mrl/action") if t not in topics]
    open_loop = [f"/{r}/{k}" for r in robots for k in ("cmd_vel", "ground_truth") if f"/{r}/{k}" not in topics]
    open_loop += [] if EPISODE_TOPIC in topics else [EPISODE_TOPIC]
    if not agreement and not open_loop:
        lines.append("    replay: policy re-run on the observations and open-loop commands (needs --policy)")
    else:
        lines.append(f"    replay: needs {', '.join(dict.fromkeys(agreement + open_loop))}")
    return "\n".join(lines)


def _info(args: argparse.Namespace) -> int:
    with _imported(args, args.bags) as bags:
        print("\n\n".join(describe(bag) for bag in bags))
    return 0


# -- outputs ------------------------------------------------------------------------------------


def output_folder(text: str, option: str = "--out") -> Path:
    """`text` as a folder the verb can write, checked before any work starts (nothing is created): CommandError
    names the option and what is in the way (a file, a file among its parents, a place that cannot be written)."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise CommandError(f"{option} {text}: a file is in the way; give a folder (it is created if need be)")
    _check_writable_parent(path, text, option)
    return path


def _check_writable_parent(path: Path, text: str, option: str) -> None:
    """The nearest existing folder of `path` is a folder and accepts new entries (probed, then removed)."""
    ancestor = path
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise CommandError(f"{option} {text}: {ancestor} is a file, not a folder")
    try:
        probe = tempfile.mkdtemp(prefix=".mrl-probe-", dir=ancestor)
        os.rmdir(probe)
    except OSError as exc:
        raise CommandError(f"{option} {text}: cannot write in {ancestor} ({exc.strerror or exc})") from exc


# -- episodes -----------------------------------------------------------------------------------


def _table_path(text: str | None) -> Path | None:
    if text is None:
        return None
    path = Path(text)
    if path.suffix.lower() not in TABLE_SUFFIXES:
        raise CommandError(f"--out {text}: the file name must end in .csv or .parquet (that picks the format)")
    if path.is_dir():
        raise CommandError(f"--out {text}: a folder is in the way; give a file name ending in .csv or .parquet")
    _check_writable_parent(path.parent, text, "--out")
    return path


def _world_of(table: Any) -> str:
    worlds = set(table["world"].to_list())
    return "sim" if worlds == {"sim"} else "real"


def _summary(table: Any, world: str) -> str:
    from pipeline.analysis.compare import compare

    m = compare(table, None) if world == "sim" else compare(None, table)
    metrics = m.metrics

    def rate(key: str) -> str:
        value = metrics.get(f"{world}/{key}", math.nan)
        if math.isnan(value):
            return "-"
        low, high = metrics[f"{world}/{key}_ci_low"], metrics[f"{world}/{key}_ci_high"]
        return f"{100 * value:.1f} % [{100 * low:.1f}, {100 * high:.1f}]"

    return (
        f"{metrics.get(f'{world}/episodes', 0):.0f} episodes ({metrics.get(f'{world}/aborted_episodes', 0):.0f} "
        f"aborted): robot success {rate('robot_success')}, team success {rate('team_success')} over every "
        f"episode; completed episodes only: robot success {rate('robot_success_completed')}; "
        f"collisions {rate('collision_rate')}"
    )


def _write_table(table: Any, path: Path) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.suffix.lower() == ".csv":
            table.write_csv(path)
        else:
            table.write_parquet(path)
    except OSError as exc:
        raise CommandError(f"--out {path}: cannot write ({exc.strerror or exc})") from exc


def _episodes(args: argparse.Namespace) -> int:
    import polars as pl

    from pipeline.analysis.tables import Recording

    out = _table_path(args.out)
    with _imported(args, [args.bag]) as (bag,):
        table = Recording(bag.path, session=_source_name(bag)).episodes_table()
        if bag.converted:
            table = table.with_columns(pl.lit(str(bag.source)).alias("path"))
    if out is not None:
        _write_table(table, out)
    else:
        with pl.Config(tbl_rows=-1, tbl_cols=-1, tbl_hide_dataframe_shape=True, tbl_width_chars=160):
            print(table.select(EPISODE_COLUMNS))
    summary = _summary(table, _world_of(table))
    print(f"episodes: {summary}" + (f" -> {out}" if out is not None else ""))
    return 0


# -- compare ------------------------------------------------------------------------------------


def _compare(args: argparse.Namespace) -> int:
    from pipeline.analysis.report import write_report

    out = output_folder(args.out)
    with _imported(args, [args.sim, args.real]) as (sim, real):
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


# -- calibrate ----------------------------------------------------------------------------------


def _parts(text: str) -> list[str]:
    from pipeline.calibration import PARTS

    parts = [p.strip() for p in text.split(",") if p.strip()]
    bad = [p for p in parts if p not in PARTS]
    if bad or not parts:
        raise argparse.ArgumentTypeError(f"{text!r}: expected some of {','.join(PARTS)} separated by commas")
    return parts


def _calibrate(args: argparse.Namespace) -> int:
    from pipeline.calibration import PARTS, calibrate, calibration_settings, write_calibration

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
    settings = calibration_settings(options, source="command-line options")
    with _imported(args, args.bags) as bags:
        calibration = calibrate([bag.path for bag in bags], settings)
        given = {str(bag.path): str(bag.source) for bag in bags}
        sources = tuple(replace(s, path=given.get(s.path, s.path)) for s in calibration.sources)
        path = write_calibration(replace(calibration, sources=sources), args.out)
    for key, reason in calibration.unidentified().items():
        print(f"calibrate: {key} unidentifiable: {reason}")
    for limit in calibration.speed_limits():
        print(f"calibrate: {limit.sentence()}")
    poses = calibration.pose_source
    if poses.kind == "localized":
        print(f"calibrate: poses localized from scans and odometry in the {poses.map}, match score "
              f"{poses.median_score:.2f} (fraction of scan endpoints on the map)")  # fmt: skip
    print(f"calibrate: {path} from {', '.join(str(bag.source) for bag in bags)}")
    return 0


def _domain_id(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 232:
        raise argparse.ArgumentTypeError(f"{text!r}: a DDS domain id, an integer from 0 to 232")
    return value


def _pose(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: expected x,y,yaw (metres, metres, radians)")
    return values


# -- replay -------------------------------------------------------------------------------------


def _replay(args: argparse.Namespace) -> int:
    from pipeline.analysis.replay_report import run_replay, write_replay
    from pipeline.mappings import from_mapping, merge, to_mapping
    from pipeline.params import ReplayConfig, calibrated_world
    from pipeline.policy.runtime import PolicyRuntime

    out = output_folder(args.out)
    cfg = from_mapping(
        ReplayConfig,
        merge(
            to_mapping(ReplayConfig()),
            {"horizon_s": args.horizon_s, "max_episodes": args.max_episodes, "tolerance": args.tolerance},
        ),
        "command-line options",
    )
    runtime = PolicyRuntime(args.policy)
    scenario = runtime.spec.scenario
    worlds = {"trained": runtime.spec.world}
    if args.calibration:
        worlds["calibrated"] = calibrated_world(worlds["trained"], Path(args.calibration))
    with _imported(args, [args.recording]) as (bag,):
        label = _source_name(bag)
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


# -- twin and deploy ----------------------------------------------------------------------------


def _twin(args: argparse.Namespace, rest: list[str]) -> int:
    from pipeline.twin.__main__ import main as twin_main

    return twin_main(rest, prog="mrl twin")


def _deploy(args: argparse.Namespace) -> int:
    from pipeline.mappings import from_mapping, merge, to_mapping
    from pipeline.params import DeployConfig
    from pipeline.policy.runtime import PolicyRuntime
    from pipeline.rollout.deployment import DeployRequest, deploy_session
    from pipeline.ros.fleet import load_fleet

    out = output_folder(args.out)
    options = {"fleet": args.fleet, "episodes": args.episodes, "seed": args.seed, "out_dir": args.out}
    options.update(time_scale=args.time_scale, profile=args.profile)
    cfg = from_mapping(DeployConfig, merge(to_mapping(DeployConfig()), options), "command-line options")
    fleet = load_fleet(cfg.fleet)
    if args.domain_id is not None:  # another DDS domain than the fleet file's, without writing a fleet file
        fleet = replace(fleet, network=replace(fleet.network, domain_id=args.domain_id))
    runtime = PolicyRuntime(args.policy)
    request = DeployRequest(
        episodes=cfg.episodes,
        seed=cfg.seed,
        recording=out / "session.mcap",
        time_scale=cfg.time_scale,
        profile=cfg.profile,
        chunk_size_bytes=cfg.chunk_size_bytes,
    )
    with live_view(args.live, args.live_port, "deploy") as live:
        outcome = deploy_session(runtime, fleet, cfg.fleet, request, out, confirm_reset=operator_reset, live=live)
    print(f"deploy: {deploy_summary(outcome, fleet.target, out)}")
    return 0


def _eval(args: argparse.Namespace) -> int:
    from pipeline.mappings import from_mapping, merge, to_mapping
    from pipeline.params import EvalSimConfig
    from pipeline.policy.runtime import PolicyRuntime
    from pipeline.rollout.sim import evaluate_session
    from pipeline.sim import make_world

    output_folder(args.out)
    options = {"episodes": args.episodes, "seed": args.seed, "out_dir": args.out}
    cfg = from_mapping(EvalSimConfig, merge(to_mapping(EvalSimConfig()), options), "command-line options")
    runtime = PolicyRuntime(args.policy)
    world = runtime.spec.world
    if args.layouts:
        world = replace(world, layouts=args.layouts)
    scenario, world = make_world(world=world)
    out = Path(cfg.out_dir)
    with live_view(args.live, args.live_port, "eval") as live:
        results, metrics = evaluate_session(scenario, world, runtime, cfg, out, live=live)
    print(
        f"eval: robot success {metrics['eval/robot_success']:.3f} "
        f"[{metrics['eval/robot_success_ci_low']:.3f}, {metrics['eval/robot_success_ci_high']:.3f}], "
        f"team success {metrics['eval/team_success']:.3f} over {len(results)} episodes -> {out}"
    )
    return 0


def _live_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--live", action="store_true", help="serve the session to the Foxglove app while it runs (foxglove-sdk)"
    )
    parser.add_argument(
        "--live-port", type=int, default=8765, metavar="PORT", help="the live view's port (default: 8765)"
    )


# -- the command --------------------------------------------------------------------------------


def _verb(subparsers: Any, name: str, summary: str, description: str, **kwargs: Any) -> argparse.ArgumentParser:
    parser: argparse.ArgumentParser = subparsers.add_parser(
        name, help=summary, description=description, formatter_class=argparse.RawDescriptionHelpFormatter, **kwargs
    )
    return parser


def build_parser() -> argparse.ArgumentParser:
    """The ``mrl`` argument parser with every verb."""
    from pipeline.params import DeployConfig, ReplayConfig

    deploy_defaults = DeployConfig()
    replay_defaults = ReplayConfig()
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Recordings of multi-robot sessions (ROS 2 bags, ROS 1 bags, MCAP): inspect, tabulate, compare, "
        "calibrate the simulator, replay; run the hardware twin and deploy policies.",
        epilog="Exit codes: 0 done, 2 bad input (one line on stderr), 130 interrupted. "
        "`mrl VERB --help` for a verb's options.",
    )
    subparsers = parser.add_subparsers(dest="verb", metavar="VERB", required=True)

    info = _verb(
        subparsers,
        "info",
        "topics, counts, times, robots and what the other verbs can do with a bag",
        "Topics, message types and counts, start, end and duration, robots, source format, whether the bag has\n"
        "this project's session metadata, episode events and ground truth, and what each verb can do with it.",
    )
    info.add_argument("bags", nargs="+", metavar="BAG", help=BAG_HELP)
    _bag_options(info)

    episodes = _verb(
        subparsers,
        "episodes",
        "the episodes table: one row per episode and robot",
        "One row per episode and robot: success, collision, time to goal, path length, ... (needs the\n"
        "/mrl/episode events this project records). Printed, or written whole to --out.",
    )
    episodes.add_argument("bag", metavar="BAG", help=BAG_HELP)
    episodes.add_argument("--out", default=None, metavar="FILE", help="write the table to FILE.csv or FILE.parquet")
    _bag_options(episodes)

    compare = _verb(
        subparsers,
        "compare",
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
    _bag_options(compare)

    calibrate = _verb(
        subparsers,
        "calibrate",
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
        type=_pose,
        default=None,
        metavar="X,Y,YAW",
        help="where the (single) robot starts, for localization (default: global localization)",
    )
    _bag_options(calibrate)

    replay = _verb(
        subparsers,
        "replay",
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
        "--horizon-s", type=float, default=replay_defaults.horizon_s, metavar="S", help="seconds replayed per episode"
    )
    replay.add_argument(
        "--max-episodes", type=int, default=replay_defaults.max_episodes, metavar="N", help="episodes replayed"
    )
    replay.add_argument(
        "--tolerance",
        type=float,
        default=replay_defaults.tolerance,
        metavar="X",
        help="largest |replayed - recorded| policy output counted as agreement",
    )
    _bag_options(replay)

    _verb(
        subparsers,
        "twin",
        "run the hardware twin (options of python -m pipeline.twin; mrl twin --help lists them)",
        "The hardware twin: plays the robots' drivers over DDS until Ctrl-C.",
        add_help=False,
    )

    deploy = _verb(
        subparsers,
        "deploy",
        "episodes of a policy on a fleet (the twin by default), recorded to MCAP",
        "Episodes of an exported policy on a fleet, every message recorded: session.mcap (a rosbag2 folder),\n"
        "episodes.csv and metrics.json in --out. A fleet with `target: twin` starts the twin itself.",
    )
    deploy.add_argument("--policy", required=True, metavar="DIR", help="the exported policy folder (policy.json)")
    deploy.add_argument(
        "--fleet", required=True, metavar="FLEET", help="a bundled fleet (twin, spark_lab) or a YAML file"
    )
    deploy.add_argument(
        "--episodes",
        type=int,
        default=deploy_defaults.episodes,
        metavar="N",
        help=f"(default: {deploy_defaults.episodes})",
    )
    deploy.add_argument(
        "--seed", type=int, default=deploy_defaults.seed, metavar="N", help=f"(default: {deploy_defaults.seed})"
    )
    deploy.add_argument(
        "--time-scale", type=float, default=0.0, metavar="X", help="the twin's time scale (default: the fleet's)"
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
    _live_options(deploy)

    evaluate = _verb(
        subparsers,
        "eval",
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
    _live_options(evaluate)

    sweep = _verb(
        subparsers,
        "sweep",
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
        "--set-for",
        nargs=2,
        action="append",
        default=[],
        metavar=("ALGORITHM", "KEY=VALUE"),
        help="a params.yaml key set for that algorithm's trials only, e.g. sac train.updates_per_transition=1.0 "
        "(repeatable; shown in the table's settings column)",
    )
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
    return parser


def _sweep(args: argparse.Namespace) -> int:
    from pipeline.bench.report import marks, splice_readme, write_report
    from pipeline.bench.stats import cell_stats, markdown_table
    from pipeline.bench.sweep import collect, run_sweep
    from pipeline.bench.trials import base_mapping, expand, parse_axis, parse_setting, scoped_settings, with_settings
    from pipeline.params import load_params

    if args.readme:  # checked before a sweep of hours, not after it
        start_mark, end_mark = marks(args.readme_section)
        if not re.fullmatch(r"[A-Za-z0-9_-]*", args.readme_section):
            problem = ConfigProblem("name", args.readme_section, "letters, digits, _ and -")
            raise ConfigError("--readme-section", [problem])
        text = Path(args.readme).read_text(encoding="utf-8") if Path(args.readme).is_file() else None
        if text is None or start_mark not in text or end_mark not in text:
            found = "missing" if text is None else "without the markers"
            problem = ConfigProblem(args.readme, found, f"a file with {start_mark} and {end_mark}")
            raise ConfigError("--readme", [problem])
    params = load_params(args.params)
    axes = [parse_axis(text) for text in args.axis]
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    trials = expand(args.algorithms, args.modes, args.scenarios, seeds, axes)
    trials = scoped_settings(trials, args.set_for)
    settings = [parse_setting(text) for text in args.set]
    if not any(key == "train.world_workers" for key, _ in settings):  # a trial's worlds use the CPUs it holds
        settings.append(("train.world_workers", max(1, int(args.cpus_per_trial))))
    base = with_settings(base_mapping(params), settings)
    out = output_folder(args.out)
    command = "mrl sweep " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["sweep"] else "mrl sweep"
    if args.report_only:
        rows = collect(out, trials, base)
        print(f"sweep: report of {rows.height} finished trials of {len(trials)} in {out}")
    else:
        outcome = run_sweep(trials, base, out, args.episodes, args.address or None, args.workers, args.cpus_per_trial)
        rows = outcome.rows
    if rows.is_empty():
        print("sweep: no finished trial yet: nothing to report")
        return 0 if args.report_only else 1
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


VERBS: dict[str, Callable[[argparse.Namespace], int]] = {
    "info": _info,
    "episodes": _episodes,
    "compare": _compare,
    "calibrate": _calibrate,
    "replay": _replay,
    "deploy": _deploy,
    "eval": _eval,
    "sweep": _sweep,
}


def _warning_line(verb: str, stream: TextIO) -> Callable[..., None]:
    """Each warning once, on one line (a file opened twice warns twice otherwise)."""
    shown: set[str] = set()

    def show(message: Warning | str, category: type[Warning], *args: object, **kwargs: object) -> None:
        text = str(message)
        if text in shown:
            return
        shown.add(text)
        print(f"mrl {verb}: warning: {text}", file=stream)

    return show


def _one_line(verb: str, body: Callable[[], int]) -> Callable[[], int]:
    """`body` with every MrlError's message put on one line."""

    def run() -> int:
        try:
            return body()
        except MrlError as exc:
            lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
            if len(lines) <= 1:
                raise
            text = lines[0].rstrip(":") + ": " + "; ".join(lines[1:])
            raise CommandError(
                text, bool(getattr(exc, "interrupted", False)), runtime_fault=isinstance(exc, RuntimeFault)
            ) from exc

    return run


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``mrl`` with `argv` (default: the command line); the exit code."""
    parser = build_parser()
    args, rest = parser.parse_known_args(argv)
    verb: str = args.verb
    if verb == "twin":
        return run_stage("mrl twin", lambda: _twin(args, rest))
    if rest:
        parser.parse_args(argv)  # reports the unknown arguments and exits 2
    warnings.showwarning = _warning_line(verb, sys.stderr)
    return run_stage(f"mrl {verb}", _one_line(verb, lambda: VERBS[verb](args)))


if __name__ == "__main__":
    sys.exit(main())
