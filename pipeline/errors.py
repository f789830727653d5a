"""Error types of the pipeline: one root, specific subclasses that build their own message."""

from __future__ import annotations

from collections.abc import Sequence


class MrlError(Exception):
    """Root of every error the pipeline raises on purpose."""


class RuntimeFault(MrlError):
    """The world failed while running, not the input: a twin or driver gone, a robot blind past its outage limit,
    robots that never answered, a foreign writer on the domain. Commands exit with code 3 on it."""


class InvalidMeasurement(MrlError):
    """The run finished and its files are in place, but some of its episodes do not measure the policy: the hardware
    twin fell behind its clock or its control steps woke late (a host too busy for the time scale asked). They are
    marked and counted; commands exit with :data:`exit_code` on it."""

    exit_code = 4


class ConfigError(MrlError):
    """A parameter file or override holds keys or values that are not allowed.

    Each problem names the file, the dotted key, the bad value and what is allowed.
    """

    def __init__(self, source: str, problems: Sequence[ConfigProblem]) -> None:
        self.source = source
        self.problems = tuple(problems)
        lines = [f"{source}: {len(self.problems)} invalid setting(s)"]
        lines += [f"  {p}" for p in self.problems]
        super().__init__("\n".join(lines))


class ConfigProblem:
    """One bad key or value: where, what was found, what is allowed."""

    __slots__ = ("allowed", "key", "value")

    def __init__(self, key: str, value: object, allowed: str) -> None:
        self.key = key
        self.value = value
        self.allowed = allowed

    def __str__(self) -> str:
        shown = "<missing>" if self.value is _MISSING else repr(self.value)
        return f"{self.key} = {shown}: {self.allowed}"

    def __repr__(self) -> str:
        return f"ConfigProblem({self.key!r}, {self.value!r}, {self.allowed!r})"


class _Missing:
    def __repr__(self) -> str:
        return "<missing>"


_MISSING = _Missing()
MISSING: object = _MISSING
"""Marker for a key that is required but absent."""
