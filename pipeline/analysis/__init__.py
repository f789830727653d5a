"""Offline analysis of session recordings: MCAP -> polars tables, sim-vs-real comparison, plots, reports.

Modules (import them directly; this package imports nothing heavy):

- :mod:`pipeline.analysis.decode`: CDR messages of one topic -> numpy columns, vectorised.
- :mod:`pipeline.analysis.layouts`: the field layouts it reads each recorded type with.
- :mod:`pipeline.analysis.tables`: :class:`~pipeline.analysis.tables.Recording`, the episodes table
  (one row per episode and robot), per-topic frames and pose frames.
- :mod:`pipeline.analysis.compare`: success rates with Wilson intervals, sim-vs-real tests.
- :mod:`pipeline.analysis.plots`: learning curves, success rates, trajectories (PNG).
- :mod:`pipeline.analysis.gap_report`: ``report.md`` and ``metrics.json`` of labelled sessions.
- :mod:`pipeline.core.stats`: interval estimates and tests without heavy dependencies.

Errors: :mod:`pipeline.analysis.errors`; a recording that lacks a topic or carries another type than
expected raises the recording reader's own errors (:mod:`pipeline.record.errors`).
"""
