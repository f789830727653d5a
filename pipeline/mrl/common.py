"""What the ``mrl`` verbs share: the verb's parser, bag options and bag import, output folders, the command's
error, settings from options."""

from __future__ import annotations

import argparse
import contextlib
import difflib
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar

from pipeline.errors import MrlError

if TYPE_CHECKING:
    from pipeline.record import ImportedBag

BAG_HELP = "an MCAP file, a rosbag2 folder (mcap or sqlite3 storage) or a ROS 1 .bag"
OPTIONS_SOURCE = "command-line options"
"""How settings built from a verb's options are named in their error messages."""

Config = TypeVar("Config")


class CommandError(MrlError):
    """Bad input to a verb (an option, an output path), or a library error reworded for the command line."""

    def __init__(self, message: str, interrupted: bool = False, runtime_fault: bool = False) -> None:
        self.interrupted = interrupted
        self.runtime_fault = runtime_fault
        """A runtime fault reworded onto one line: it still exits 3."""
        super().__init__(message)


class VerbParser(argparse.ArgumentParser):
    """A verb's parser (``mrl`` makes every verb's one): it keeps the option strings given to its ``add_argument``,
    so that any error it reports (an unknown argument, a missing one, a bad value) names the nearest of its options
    to each option it was given that it does not know, under its own usage."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.option_names: list[str] = []
        """Every option string of the verb (``--map``, ``-h``, ...), in the order added."""
        self.given: list[str] = []
        """The arguments of the last parse."""
        super().__init__(*args, **kwargs)

    def add_argument(self, *args: Any, **kwargs: Any) -> argparse.Action:
        action = super().add_argument(*args, **kwargs)
        self.option_names.extend(action.option_strings)
        return action

    def parse_known_args(self, args: Iterable[str] | None = None, namespace: Any = None) -> tuple[Any, list[str]]:
        self.given = list(args) if args is not None else sys.argv[1:]
        return super().parse_known_args(self.given, namespace)

    def unknown_options(self, arguments: Sequence[str]) -> dict[str, str | None]:
        """``{option: the nearest of the verb's options, or None}`` for each argument of `arguments` that looks like
        an option (not a negative number) and is neither one of the verb's nor an abbreviation argparse takes."""
        out: dict[str, str | None] = {}
        for argument in arguments:
            name = argument.split("=", 1)[0]
            if not name.startswith(self.prefix_chars) or name in self.option_names or name in out or _number(name):
                continue
            if name.startswith("--") and len(name) > 2 and any(o.startswith(name) for o in self.option_names):
                continue
            nearest = difflib.get_close_matches(name, self.option_names, n=1)
            out[name] = nearest[0] if nearest else None
        return out

    def error(self, message: str) -> NoReturn:
        """The verb's usage and ``<prog>: error: <message>`` on stderr, the nearest option named for each unknown one
        it was given (``--mpa: did you mean --map?``); exit 2."""
        hints = [
            f"{name}: did you mean {nearest}?" if nearest else f"{name}: not an option of {self.prog}"
            for name, nearest in self.unknown_options(self.given).items()
        ]
        super().error(message + (f" ({'; '.join(hints)})" if hints else ""))

    def refuse_unrecognized(self, arguments: Sequence[str]) -> NoReturn:
        """Exit 2 through :meth:`error` for the arguments of the last parse that the verb did not recognize."""
        self.error(f"unrecognized arguments: {' '.join(arguments)}")


def _number(text: str) -> bool:
    """`text` is a number, or numbers separated by commas (a value such as -1,2,0, not an option)."""
    try:
        [float(part) for part in text.split(",")]
    except ValueError:
        return False
    return True


def add_verb(subparsers: Any, name: str, summary: str, description: str, **kwargs: Any) -> VerbParser:
    """The parser of verb `name`: `summary` in ``mrl --help``, `description` (kept as written) in its own help."""
    parser: VerbParser = subparsers.add_parser(
        name, help=summary, description=description, formatter_class=argparse.RawDescriptionHelpFormatter, **kwargs
    )
    return parser


def config_from_options(cls: type[Config], options: Mapping[str, Any]) -> Config:
    """The settings `cls` with its defaults overridden by `options` (the verb's), checked like params.yaml."""
    from pipeline.mappings import from_mapping, merge, to_mapping

    return from_mapping(cls, merge(to_mapping(cls()), options), OPTIONS_SOURCE)


# -- bags ---------------------------------------------------------------------------------------


def _robot_list(text: str) -> list[str]:
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"{text!r}: expected robot names separated by commas, e.g. robot_1,robot_2")
    return names


def bag_options(parser: argparse.ArgumentParser) -> None:
    """--robots and --topic: which robots of a bag to keep and where it keeps our topics."""
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
def imported(args: argparse.Namespace, paths: Sequence[str]) -> Iterator[list[ImportedBag]]:
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


def stage_line(verb: str) -> Callable[[str], None]:
    """Progress for long work: each stage as it starts, on stderr as ``<verb>: <stage> (<seconds> s)`` (the results
    go to stdout)."""
    start = time.monotonic()

    def show(stage: str) -> None:
        print(f"{verb}: {stage} ({time.monotonic() - start:.0f} s)", file=sys.stderr, flush=True)

    return show


def require_episodes(bag: ImportedBag, verb: str) -> None:
    """Refuse a bag without this project's episode events before any work: what the verb reads, what the bag is and
    which verbs read it instead."""
    from pipeline.record.episodes import EPISODE_TOPIC

    if any(topic.name == EPISODE_TOPIC for topic in bag.topics):
        return
    kind = f"a {bag.source_format} bag of the robots' own topics" if bag.converted else "a recording without them"
    raise CommandError(
        f"{bag.source}: no episodes to {verb} (no {EPISODE_TOPIC} topic): {verb} reads the episodes (starts, goals, "
        f"ends) that mrl deploy and the pipeline's stages record, and this is {kind}; mrl calibrate and mrl replay "
        "read such a bag (mrl info says what it holds)"
    )


def source_name(bag: ImportedBag) -> str:
    """The bag's name for tables and reports: its file name without suffix (a folder's name)."""
    return bag.source.resolve().stem if bag.source.is_file() else bag.source.resolve().name


# -- outputs ------------------------------------------------------------------------------------


def output_folder(text: str, option: str = "--out") -> Path:
    """`text` as a folder the verb can write, checked before any work starts (nothing is created): CommandError
    names the option and what is in the way (a file, a file among its parents, a place that cannot be written)."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise CommandError(f"{option} {text}: a file is in the way; give a folder (it is created if need be)")
    check_writable_parent(path, text, option)
    return path


def check_writable_parent(path: Path, text: str, option: str) -> None:
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


def live_options(parser: argparse.ArgumentParser) -> None:
    """--live and --live-port: serve the session to the Foxglove app while it runs."""
    parser.add_argument(
        "--live", action="store_true", help="serve the session to the Foxglove app while it runs (foxglove-sdk)"
    )
    parser.add_argument(
        "--live-port", type=int, default=8765, metavar="PORT", help="the live view's port (default: 8765)"
    )


def pose_argument(text: str) -> list[float]:
    """An X,Y,YAW option's three finite numbers (argparse type)."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: expected x,y,yaw (metres, metres, radians)")
    return values
