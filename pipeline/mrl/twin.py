"""``mrl twin ...``: the hardware twin (the options of ``python -m pipeline.twin``)."""

from __future__ import annotations

from typing import Any

from pipeline.mrl.common import add_verb

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
    """Run the twin with the arguments after ``mrl twin``."""
    from pipeline.twin.__main__ import main as twin_main

    return twin_main(rest, prog="mrl twin")
