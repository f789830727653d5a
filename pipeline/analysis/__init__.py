"""Offline analysis of session recordings: MCAP -> polars tables, sim-vs-real comparison, plots, reports.

Modules (import them directly; this package imports nothing heavy):

- :mod:`pipeline.analysis.decode`: CDR messages of one topic -> numpy columns, vectorised.
- :mod:`pipeline.analysis.tables`: :class:`~pipeline.analysis.tables.Recording`, the episodes table
  (one row per episode and robot), per-topic frames and pose frames.
- :mod:`pipeline.analysis.compare`: success rates with Wilson intervals, sim-vs-real tests.
- :mod:`pipeline.analysis.plots`: learning curves, success rates, trajectories (PNG).
- :mod:`pipeline.analysis.report`: ``report.md`` and ``metrics.json`` of labelled sessions.
- :mod:`pipeline.analysis.stats`: interval estimates and tests without heavy dependencies.

The error types live here so that every module raises the same ones.
"""

from __future__ import annotations

from collections.abc import Sequence

from pipeline.errors import MrlError


class AnalysisError(MrlError):
    """A recording, table or file cannot be analysed; the message names the file and what is wrong."""

    def __init__(self, where: str, problem: str) -> None:
        self.where = where
        self.problem = problem
        super().__init__(f"{where}: {problem}")


class MissingTopicError(AnalysisError):
    """A recording lacks a topic (or every one of several alternatives) that an analysis needs."""

    def __init__(self, path: str, topics: Sequence[str], needed_for: str) -> None:
        self.path = path
        self.topics = tuple(topics)
        names = " or ".join(self.topics)
        super().__init__(path, f"the recording has no topic {names}, needed for {needed_for}")


class TopicTypeError(AnalysisError):
    """A topic of a recording carries a message type other than the one an analysis reads."""

    def __init__(self, path: str, topic: str, found: str, expected: str) -> None:
        self.path = path
        self.topic = topic
        super().__init__(path, f"topic {topic} carries {found}, expected {expected}")


class TableError(AnalysisError):
    """An episodes table (or a training-curve file) lacks columns or rows an analysis needs."""


__all__ = ["AnalysisError", "MissingTopicError", "TableError", "TopicTypeError"]
