"""Errors of exported policies: files that cannot be loaded, policies that do not fit a world or fleet."""

from __future__ import annotations

from pipeline.errors import MrlError


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
