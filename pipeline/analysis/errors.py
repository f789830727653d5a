"""Errors of the analysis: recordings, tables and replays that cannot be analysed; warnings of comparisons."""

from __future__ import annotations

from pipeline.errors import MrlError


class AnalysisError(MrlError):
    """A recording, table or file cannot be analysed; the message names the file and what is wrong."""

    def __init__(self, where: str, problem: str) -> None:
        self.where = where
        self.problem = problem
        super().__init__(f"{where}: {problem}")


class TableError(AnalysisError):
    """An episodes table (or a training-curve file) lacks columns or rows an analysis needs."""


class ReplayError(MrlError):
    """A recording cannot be replayed (a needed topic is missing, robots differ); names the file and topic."""


class ComparisonWarning(UserWarning):
    """A comparison that runs but may not mean what it seems: a recording compared with itself, a recording whose
    metadata names another world than it was given as."""
