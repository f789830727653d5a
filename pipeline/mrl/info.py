"""``mrl info BAG...``: topics, types, counts, times, robots, source format, what the other verbs can do."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from pipeline.core.timebase import NS_PER_S
from pipeline.mrl.common import BAG_HELP, add_verb, bag_options, imported

if TYPE_CHECKING:
    from pipeline.record import ImportedBag
    from pipeline.record.session import SessionInfo

NAME = "info"
UNIX_TIME_FROM_NS = 946_684_800 * NS_PER_S
"""Log times from 2000-01-01 on are shown as dates (Unix time); earlier ones are a session clock."""


def add_parser(subparsers: Any) -> None:
    """The ``info`` verb's options."""
    info = add_verb(
        subparsers,
        NAME,
        "topics, counts, times, robots and what the other verbs can do with a bag",
        "Topics, message types and counts, start, end and duration, robots, source format, whether the bag has\n"
        "this project's session metadata, episode events and ground truth, and what each verb can do with it.",
    )
    info.add_argument("bags", nargs="+", metavar="BAG", help=BAG_HELP)
    bag_options(info)


def run(args: argparse.Namespace) -> int:
    """Print what each bag holds; a bag without robot topics is described, not refused."""
    from pipeline.record.errors import NoRobotsError

    texts = []
    for path in args.bags:
        try:
            with imported(args, [path]) as (bag,):
                texts.append(describe(bag))
        except NoRobotsError as exc:
            texts.append(_robotless(path, exc))
    print("\n\n".join(texts))
    return 0


def _robotless(path: str, exc: Any) -> str:
    """A bag whose topics name no robot: its topics, and what would make the verbs read it."""
    lines = [f"bag: {path}", "  robots: none (no /<robot>/scan LaserScan or /<robot>/odom Odometry topic)", "  topics:"]
    topics: dict[str, str] = exc.topics
    width = max((len(t) for t in topics), default=0)
    lines += [f"    {name:<{width}}  {typename}" for name, typename in sorted(topics.items())] or ["    none"]
    lines += [
        "  what the verbs can do with it:",
        "    nothing as it is: map the robot's topics with --topic (e.g. --topic scan=/base_scan, "
        "--topic odom=/wheel_odom) where they have other names",
    ]
    return "\n".join(lines)


def describe(bag: ImportedBag) -> str:
    """What ``mrl info`` prints about one imported bag."""
    from pipeline.analysis.tables import EPISODE_TOPIC, Recording
    from pipeline.record.session import session_info

    log = bag.log()
    info = session_info(log.metadata())
    topics = bag.topic_types()
    counts = bag.message_counts()
    scenario = info.scenario_name()
    episodes = Recording(log).episodes().height if EPISODE_TOPIC in topics else 0
    truth = [r for r in bag.robots if f"/{r}/ground_truth" in topics]
    lines = _fact_lines(bag, info, topics, scenario, episodes, truth)
    lines += _topic_lines(bag, topics, counts)
    lines.append("  what the verbs can do with it:")
    lines.append(f"    calibrate: {_calibrate_text(bag.robots, topics, scenario, truth)}")
    lines += _verb_lines(bag.robots, topics, episodes)
    return "\n".join(lines)


def _when(t_ns: int) -> str:
    if t_ns >= UNIX_TIME_FROM_NS:
        stamp = datetime.fromtimestamp(t_ns / NS_PER_S, tz=UTC).isoformat(timespec="milliseconds")
        return f"{stamp} ({t_ns} ns)"
    return f"{t_ns / NS_PER_S:.3f} s on the session clock ({t_ns} ns)"


def _fact_lines(
    bag: ImportedBag,
    info: SessionInfo,
    topics: dict[str, str],
    scenario: str,
    episodes: int,
    truth: list[str],
) -> list[str]:
    """The bag's format, times, robots, session metadata, scenario, episode events and ground truth."""
    from pipeline.analysis.tables import EPISODE_TOPIC

    robots = bag.robots
    session = info.fields if info.recorded else None
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
    if EPISODE_TOPIC in topics:
        lines.append(f"  episode events: yes ({episodes} episodes on {EPISODE_TOPIC})")
    else:
        lines.append(f"  episode events: no ({EPISODE_TOPIC} absent)")
    if truth:
        which = "every robot" if len(truth) == len(robots) else ", ".join(truth)
        lines.append(f"  ground truth: yes ({which})")
    else:
        lines.append("  ground truth: no")
    return lines


def _topic_lines(bag: ImportedBag, topics: dict[str, str], counts: dict[str, int]) -> list[str]:
    """Each topic with its type, count and the bag's name for it, then the topics left out and why."""
    lines = ["  topics:"]
    width = max(len(t) for t in topics)
    type_width = max(len(t) for t in topics.values())
    renamed = {t.name: t.source for t in bag.topics if t.source != t.name}
    for name in sorted(topics):
        origin = f"  (from {renamed[name]})" if name in renamed else ""
        lines.append(f"    {name:<{width}}  {topics[name]:<{type_width}}  {counts[name]:>8}{origin}")
    if bag.salvaged:
        lines.append(f"  salvaged: {bag.salvaged}")
    if bag.skipped:
        lines.append("  left out:")
        lines += [f"    {topic}: {why}" for topic, why in bag.skipped.items()]
    return lines


def _calibrate_text(robots: Sequence[str], topics: dict[str, str], scenario: str, truth: list[str]) -> str:
    """Which parts ``mrl calibrate`` can estimate from the bag, with which poses, and what the others lack."""
    from pipeline.calibration import PARTS
    from pipeline.calibration.recording import PoseSourceKind, topics_for

    usable: list[tuple[str, list[str]]] = []
    missing: list[tuple[str, list[str]]] = []
    source: PoseSourceKind = "ground_truth" if truth and len(truth) == len(robots) else "scans"
    for part in PARTS:
        kinds = topics_for(part, source)
        absent = [f"/{r}/{kind}" for kind in kinds for r in robots if f"/{r}/{kind}" not in topics]
        (missing if absent else usable).append((part, absent))
    if not usable:
        return "nothing: needs /<robot>/ground_truth (motion capture) or /<robot>/scan and /<robot>/odom, and commands"
    poses = (
        "ground truth present"
        if source == "ground_truth"
        else "no ground truth: poses localized from scans and odometry in the scenario's room or --map FLOOR.yaml"
    )
    text = ", ".join(part for part, _ in usable) + f" ({poses})"
    text += f"; scenario {scenario} recorded" if scenario else "; needs --scenario or --map since the bag names none"
    if missing:
        text += "; not " + "; not ".join(f"{part} (no {', '.join(absent)})" for part, absent in missing)
    return text


def _verb_lines(robots: Sequence[str], topics: dict[str, str], episodes: int) -> list[str]:
    """What ``mrl episodes``, ``compare`` and ``replay`` can do with the bag, or what they need."""
    from pipeline.analysis.tables import EPISODE_TOPIC

    episodes_text = (
        f"{episodes} episodes x {len(robots)} robots"
        if EPISODE_TOPIC in topics
        else f"needs {EPISODE_TOPIC} (recorded by this project)"
    )
    lines = [
        f"    episodes: {episodes_text}",
        f"    compare: {'as SIM or REAL' if EPISODE_TOPIC in topics else episodes_text}",
    ]
    agreement = [t for t in ("/mrl/observation", "/mrl/action") if t not in topics]
    open_loop = [f"/{r}/{k}" for r in robots for k in ("cmd_vel", "ground_truth") if f"/{r}/{k}" not in topics]
    open_loop += [] if EPISODE_TOPIC in topics else [EPISODE_TOPIC]
    if not agreement and not open_loop:
        lines.append("    replay: policy re-run on the observations and open-loop commands (needs --policy)")
    else:
        lines.append(f"    replay --policy: needs {', '.join(dict.fromkeys(agreement + open_loop))}")
    driven = [f"/{r}/{k}" for r in robots for k in ("cmd_vel", "scan", "odom") if f"/{r}/{k}" not in topics]
    if not driven:
        lines.append(
            "    replay --map FLOOR.yaml: the commands open loop against the path localized in the map from scans "
            "and odometry (ground truth where recorded)"
        )
    else:
        lines.append(f"    replay --map FLOOR.yaml: needs {', '.join(driven)}")
    return lines
