"""Errors of the calibration: each names the recording (or file) and the topic or value at fault."""

from __future__ import annotations

from collections.abc import Sequence

from pipeline.errors import MrlError


class CalibrationError(MrlError):
    """Recordings cannot be calibrated from; the message names the file and what is wrong."""

    def __init__(self, where: str, problem: str) -> None:
        self.where = where
        self.problem = problem
        super().__init__(f"{where}: {problem}")


class MissingTopicError(CalibrationError):
    """A recording lacks topics that an estimate needs."""

    def __init__(self, path: str, topics: Sequence[str], needed_for: str) -> None:
        self.path = path
        self.topics = tuple(topics)
        names = ", ".join(self.topics)
        plural = "s" if len(self.topics) > 1 else ""
        super().__init__(path, f"the recording has no topic{plural} {names}, needed for {needed_for}")


class ScenarioMismatchError(CalibrationError):
    """A recording was made in another scenario than the one calibration was asked for (or than another recording)."""

    def __init__(self, path: str, recorded: str, expected: str) -> None:
        self.path = path
        self.recorded = recorded
        self.expected = expected
        super().__init__(
            path, f"the recording was made in scenario {recorded!r}, calibration was asked for scenario {expected!r}"
        )


__all__ = ["CalibrationError", "MissingTopicError", "ScenarioMismatchError"]
