"""Errors and warnings of the MCAP recorder and reader; every message names the file it is about."""

from __future__ import annotations

from collections.abc import Sequence

from pipeline.errors import MrlError


class RecordError(MrlError):
    """A recording cannot be created or written: the path, topic or value is not usable."""

    def __init__(self, path: str, problem: str) -> None:
        self.path = path
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class LogReadError(MrlError):
    """A recording cannot be read: missing, empty, not MCAP, or damaged where it cannot be salvaged."""

    def __init__(self, path: str, problem: str) -> None:
        self.path = path
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class LogFormatError(LogReadError):
    """A channel of a recording is outside the ROS 2 profile (message encoding not cdr, schema not ros2msg)."""

    def __init__(self, path: str, topic: str, problem: str) -> None:
        self.topic = topic
        super().__init__(path, f"topic {topic}: {problem}")


class LogDecodeError(LogReadError):
    """A message's CDR bytes do not decode under the schema its channel declares."""

    def __init__(self, path: str, topic: str, log_time_ns: int, problem: str) -> None:
        self.topic = topic
        self.log_time_ns = log_time_ns
        super().__init__(path, f"topic {topic}, message logged at {log_time_ns} ns: {problem}")


class MissingTopicError(LogReadError):
    """A recording lacks topics that a reader needs: every one of `topics`, or with `any_of` at least one."""

    def __init__(self, path: str, topics: Sequence[str], needed_for: str, any_of: bool = False) -> None:
        self.topics = tuple(topics)
        self.needed_for = needed_for
        if any_of:
            text = f"the recording has no topic {' or '.join(self.topics)}, needed for {needed_for}"
        else:
            plural = "s" if len(self.topics) > 1 else ""
            text = f"the recording has no topic{plural} {', '.join(self.topics)}, needed for {needed_for}"
        super().__init__(path, text)


class TruncatedLogWarning(UserWarning):
    """A recording has no summary (its writer was killed); its complete chunks were salvaged."""


class DamagedLogWarning(TruncatedLogWarning):
    """Part of a recording is damaged (a chunk fails its CRC, a record's length is garbage); the rest was salvaged.

    A subclass of TruncatedLogWarning, so code that handles salvaged files handles both; the lost
    byte ranges are listed in the message and in :attr:`pipeline.record.McapLog.lost`.
    """


class UndecodableMessageWarning(UserWarning):
    """A message was skipped because its bytes do not decode under its schema."""


# -- bag import (pipeline.record.bags) ---------------------------------------------------------


class BagError(MrlError):
    """A bag (MCAP file, rosbag2 folder, ROS 1 .bag) cannot be imported; names the path and what is wrong."""

    def __init__(self, path: str, problem: str) -> None:
        self.path = path
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class NotABagError(BagError):
    """The path is missing, or is neither an MCAP file, a rosbag2 folder nor a ROS 1 bag."""


class BagReadError(BagError):
    """A bag of a known format cannot be read: unreadable, damaged, or refused by its reader."""


class EmptyBagError(BagError):
    """A bag holds no messages."""


class NoRobotsError(BagError):
    """No robot (a namespace with ``scan`` or ``odom`` topics), or not the robots asked for; lists the topics seen."""

    def __init__(self, path: str, problem: str, topics: dict[str, str]) -> None:
        self.topics = dict(topics)
        seen = ", ".join(f"{name} ({typename})" for name, typename in sorted(self.topics.items())) or "none"
        super().__init__(path, f"{problem}; topics in the bag: {seen}")


class UnknownMessageTypeError(BagError):
    """A needed topic's message type has no definition: none in the bag, none in ROS 2 Jazzy or schemas/."""

    def __init__(self, path: str, topic: str, typename: str, problem: str) -> None:
        self.topic = topic
        self.typename = typename
        super().__init__(path, f"topic {topic}: message type {typename} {problem}")


class TopicTypeError(LogReadError):
    """A topic of a recording or bag carries another message type than the one its reader (or the ROS 2
    contract of a robot topic of that name) expects."""

    def __init__(self, path: str, topic: str, found: str, expected: str, source: str = "") -> None:
        self.topic = topic
        self.found = found
        self.expected = expected
        where = f"topic {topic}" + (f" (from {source})" if source and source != topic else "")
        super().__init__(path, f"{where} carries {found}, expected {expected}")


class RemapError(BagError):
    """A topic remapping cannot be applied to a bag (target taken, kind ambiguous, robot count wrong)."""


class RemapTopicMissingError(RemapError):
    """A remapping names a bag topic that the bag does not have; lists the topics it has."""

    def __init__(self, path: str, mapping: str, topic: str, topics: dict[str, str]) -> None:
        self.mapping = mapping
        self.topic = topic
        self.topics = dict(topics)
        seen = ", ".join(sorted(self.topics)) or "none"
        super().__init__(path, f"--topic {mapping}: the bag has no topic {topic}; its topics: {seen}")


class TopicMapError(MrlError):
    """A topic remapping is malformed (``--topic OURS=BAG``); names the item and what is allowed."""

    def __init__(self, item: str, problem: str) -> None:
        self.item = item
        self.problem = problem
        super().__init__(f"--topic {item!r}: {problem}")


class BagImportWarning(UserWarning):
    """A topic of an imported bag was left out (its message type cannot be defined or converted)."""
