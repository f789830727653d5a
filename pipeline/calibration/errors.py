"""Errors of the calibration: each names the recording (or file) and the topic or value at fault."""

from __future__ import annotations

from pipeline.errors import MrlError


class CalibrationError(MrlError):
    """Recordings cannot be calibrated from; the message names the file and what is wrong."""

    def __init__(self, where: str, problem: str) -> None:
        self.where = where
        self.problem = problem
        super().__init__(f"{where}: {problem}")


class ScenarioMismatchError(CalibrationError):
    """A recording was made in another scenario than the one calibration was asked for (or than another recording)."""

    def __init__(self, path: str, recorded: str, expected: str) -> None:
        self.path = path
        self.recorded = recorded
        self.expected = expected
        super().__init__(
            path, f"the recording was made in scenario {recorded!r}, calibration was asked for scenario {expected!r}"
        )


__all__ = ["CalibrationError", "ScenarioMismatchError"]
