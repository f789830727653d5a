"""``mrl compare SIM REAL [--out DIR]``: the sim-vs-real report of two recordings."""

from __future__ import annotations

import argparse
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.mrl.common import (
    BAG_HELP,
    CommandError,
    add_verb,
    bag_options,
    imported,
    output_folder,
    require_episodes,
    source_name,
    stage_line,
)

if TYPE_CHECKING:
    from pipeline.record import ImportedBag

NAME = "compare"
ROLES = ("sim", "real")
"""The world each input is given as, by position: SIM, then REAL."""


def add_parser(subparsers: Any) -> None:
    """The ``compare`` verb's options."""
    compare = add_verb(
        subparsers,
        NAME,
        "the sim-vs-real report of two recordings",
        "Success rates with 95 % intervals, their sim - real gaps and tests, time to goal, collisions,\n"
        "trajectories: report.md, metrics.json and figures in --out.\n\n"
        "A recording's world (sim or real) is the one its session metadata names; a bag without session\n"
        "metadata is taken as given (SIM, then REAL). Each input is labelled by its name (the file name\n"
        "without suffix, or the folder's name; with parent folders where both names and worlds agree).\n"
        "A warning (on stderr and in report.md) says when both inputs are the same file or the same\n"
        "content, when a recording's metadata names another world than its position, and when both\n"
        "recordings are of one world (no sim-vs-real gap then).",
    )
    compare.add_argument("sim", metavar="SIM", help="the simulated session (" + BAG_HELP + ")")
    compare.add_argument("real", metavar="REAL", help="the real (or twin) session")
    compare.add_argument("--out", default="report", metavar="DIR", help="the report folder (default: report)")
    compare.add_argument(
        "--trajectory-episodes", type=int, default=3, metavar="N", help="episodes drawn per session (default: 3)"
    )
    bag_options(compare)


@dataclass(frozen=True)
class ComparedInput:
    """One input of the verb: its `label` and `world` in the report, the file read and the path given."""

    label: str
    world: str
    path: Path
    source: Path


def recorded_world(bag: ImportedBag, role: str) -> tuple[str, str]:
    """The world of `bag` (its session metadata's, else `role`) and a warning line when they disagree ('' if none).

    Raises:
        CommandError: the metadata names a world other than sim or real.
    """
    from pipeline.record import McapLog
    from pipeline.record.session import session_info

    world = session_info(McapLog(bag.path).metadata()).world
    if not world:
        return role, ""
    if world not in ROLES:
        raise CommandError(f"{bag.source}: its session metadata names world {world!r}, which is neither sim nor real")
    if world != role:
        return world, (
            f"{bag.source} is given as {role.upper()} but its session metadata says world {world}: "
            f"it is compared as {world}"
        )
    return world, ""


def same_input(first: Path, second: Path) -> str:
    """A warning line when `first` and `second` are one file (one path once resolved, or one SHA-256); else ''."""
    from pipeline.record.bags import bag_sha256, bag_size

    if first.resolve() == second.resolve():
        return f"both inputs are the same file ({first.resolve()}): the report compares a recording with itself"
    if bag_size(first) != bag_size(second):
        return ""
    digest = bag_sha256(first)
    if digest != bag_sha256(second):
        return ""
    return (
        f"both inputs are the same file: {first} and {second} have the same content (SHA-256 {digest[:16]}), "
        "the report compares a recording with itself"
    )


def input_labels(bags: Sequence[ImportedBag], worlds: Sequence[str]) -> list[str]:
    """The two inputs' labels: their names (:func:`source_name`); where names and worlds both agree, the names
    with the parent folders from the first one that differs (``nominal-session``), else numbered (``session-1``)."""
    names = [source_name(bag) for bag in bags]
    if names[0] != names[1] or worlds[0] != worlds[1]:
        return names
    parents = [bag.source.resolve().parent.parts[::-1] for bag in bags]
    for k, (a, b) in enumerate(zip(*parents, strict=False)):
        if a != b:
            return ["-".join([*reversed(up[: k + 1]), name]) for up, name in zip(parents, names, strict=True)]
    return [f"{name}-{k}" for k, name in enumerate(names, start=1)]


def compared_inputs(bags: Sequence[ImportedBag]) -> tuple[list[ComparedInput], list[str]]:
    """The two imported inputs with their worlds and labels, and the warning lines about them (in order)."""
    notes: list[str] = []
    worlds: list[str] = []
    for bag, role in zip(bags, ROLES, strict=True):
        world, note = recorded_world(bag, role)
        worlds.append(world)
        if note:
            notes.append(note)
    same = same_input(bags[0].source, bags[1].source)
    if same:
        notes.insert(0, same)
    if worlds[0] == worlds[1]:
        notes.append(f"both recordings are {worlds[0]} (session metadata): no sim-vs-real gap is computed")
    labels = input_labels(bags, worlds)
    inputs = [
        ComparedInput(label, world, bag.path, bag.source)
        for label, world, bag in zip(labels, worlds, bags, strict=True)
    ]
    return inputs, notes


def run(args: argparse.Namespace) -> int:
    """Write the report of the two sessions and print the gaps of the success and collision rates."""
    from pipeline.analysis.compare import metric_key, pair_label
    from pipeline.analysis.errors import ComparisonWarning
    from pipeline.analysis.gap_report import LabelledSession, write_report

    out = output_folder(args.out)
    with imported(args, [args.sim, args.real]) as bags:
        for bag in bags:
            require_episodes(bag, NAME)
        inputs, notes = compared_inputs(bags)
        for note in notes:
            warnings.warn(note, ComparisonWarning, stacklevel=1)
        by_world = {item.world: item for item in inputs}
        pairs = [(by_world["sim"].label, by_world["real"].label)] if len(by_world) == 2 else []
        report = write_report(
            out,
            [LabelledSession(item.label, item.world, item.path, item.source) for item in inputs],
            trajectory_episodes=args.trajectory_episodes,
            pairs=pairs,
            warnings=notes,
            progress=stage_line(NAME),
        )
    metrics = report.comparison.metrics

    def show(key: str) -> str:
        value = metrics.get(key, math.nan)
        return "-" if math.isnan(value) else f"{value:.3f}"

    for item in inputs:
        print(f"compare: {item.world} {item.label!r}: {item.source}")
    for name in ("robot_success", "team_success", "collision_rate"):
        if not pairs:
            values = " ".join(f"{i.world} {i.label!r} {show(metric_key(i.world, i.label, name))}" for i in inputs)
            print(f"compare: {name} {values} gap -")
            continue
        (sim_label, real_label), base = pairs[0], metric_key("gap", pair_label(*pairs[0]), name)
        print(
            f"compare: {name} sim {show(metric_key('sim', sim_label, name))} "
            f"real {show(metric_key('real', real_label, name))} "
            f"gap {show(base)} [{show(f'{base}_ci_low')}, {show(f'{base}_ci_high')}] "
            f"(Fisher p {show(f'{base}_p_value')})"
        )
    print(f"compare: {report.markdown} and {report.metrics}")
    return 0
