"""``mrl twin ...``: the hardware twin (the options of ``python -m pipeline.twin``)."""

from __future__ import annotations

from typing import Any

from pipeline.mrl.common import VerbParser, add_verb

NAME = "twin"


def add_parser(subparsers: Any) -> None:
    """The ``twin`` verb: its options are the twin's own, parsed by it."""
    add_verb(
        subparsers,
        NAME,
        "run the hardware twin (options of python -m pipeline.twin; mrl twin --help lists them)",
        "The hardware twin: plays the robots' drivers over DDS until Ctrl-C.",
        add_help=False,
    )


def run(rest: list[str]) -> int:
    """Run the twin with the arguments after ``mrl twin``; an argument it does not know is refused with the twin's
    usage and the nearest of its options (exit 2) before anything starts."""
    from pipeline.twin.__main__ import build_parser
    from pipeline.twin.__main__ import main as twin_main

    parser = build_parser(f"mrl {NAME}", VerbParser)
    assert isinstance(parser, VerbParser)
    _, unknown = parser.parse_known_args(rest)
    if unknown:
        parser.refuse_unrecognized(unknown)
    return twin_main(rest, prog=f"mrl {NAME}")
