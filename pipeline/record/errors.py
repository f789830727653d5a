"""Errors and warnings of the MCAP recorder and reader; every message names the file it is about."""

from __future__ import annotations

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


class TruncatedLogWarning(UserWarning):
    """A recording has no summary (its writer was killed); its complete chunks were salvaged."""


class UndecodableMessageWarning(UserWarning):
    """A message was skipped because its bytes do not decode under its schema."""
