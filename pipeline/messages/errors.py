"""Errors of the message layer: schemas and messages that cannot be built, encoded or decoded."""

from __future__ import annotations

from pipeline.errors import MrlError


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
