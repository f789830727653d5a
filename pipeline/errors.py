"""Error types of the pipeline: one root, specific subclasses that build their own message."""

from __future__ import annotations

from collections.abc import Sequence


class MrlError(Exception):
    """Root of every error the pipeline raises on purpose."""


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


class ScenarioError(MrlError):
    """A scenario is geometrically impossible (overlapping starts, goal outside the room, ...)."""

    def __init__(self, scenario: str, problem: str) -> None:
        self.scenario = scenario
        self.problem = problem
        super().__init__(f"scenario {scenario!r}: {problem}")


class ScanError(MrlError):
    """A LaserScan-shaped input cannot be reduced (bad shape, angles or limits)."""


class ActionError(MrlError):
    """An action does not fit the action codec (wrong shape, index out of range, NaN)."""


class SchemaError(MrlError):
    """A message definition in schemas/ is missing, malformed or disagrees with ROS 2 Jazzy."""

    def __init__(self, path: str, problem: str) -> None:
        self.path = path
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class MessageError(MrlError):
    """A message cannot be built, encoded or decoded; names the message type or topic."""

    def __init__(self, where: str, problem: str) -> None:
        self.where = where
        self.problem = problem
        super().__init__(f"{where}: {problem}")


class CheckpointError(MrlError):
    """A training checkpoint is missing, corrupt or inconsistent; names the file."""

    def __init__(self, path: str, problem: str) -> None:
        self.path = path
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class TrainingInterrupted(MrlError):
    """Training stopped on a signal; the last checkpoint was written."""

    interrupted = True

    def __init__(self, checkpoint: str, steps: int) -> None:
        self.checkpoint = checkpoint
        self.steps = steps
        super().__init__(f"training interrupted after {steps} world steps; checkpoint kept at {checkpoint}")


class PolicyError(MrlError):
    """An exported policy (or the weights it is built from) is missing, corrupt or malformed; names the file."""

    def __init__(self, where: str, problem: str) -> None:
        self.where = where
        self.problem = problem
        super().__init__(f"{where}: {problem}")


class PolicyMismatch(MrlError):
    """A policy does not fit the world or fleet it is asked to drive; says what differs."""

    def __init__(self, policy: str, problems: list[str]) -> None:
        self.policy = policy
        self.problems = problems
        super().__init__(f"policy {policy} does not fit: " + "; ".join(problems))
