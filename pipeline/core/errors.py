"""Errors of the MDP core: scenarios, scans and actions that cannot be used."""

from __future__ import annotations

from pipeline.errors import MrlError


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
