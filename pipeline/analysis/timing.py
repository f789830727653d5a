"""Deployment timing from a recording's ``/mrl/timing``: emitter tick period and jitter, cross-robot
send skew, the age of each robot's data at control steps, and stale records.

All times are on the deploy runner's clock (simulated time when the twin runs time-scaled), so a
4x session is judged against the same 20 ms tick as a 1x one.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import polars as pl
import yaml

from pipeline.analysis.compare import metric_key
from pipeline.analysis.errors import AnalysisError
from pipeline.analysis.tables import Recording
from pipeline.core.timebase import NS_PER_S
from pipeline.messages.convert import TIMING_CODES
from pipeline.record import McapLog

TIMING_TOPIC = "/mrl/timing"
DEFAULT_TICK_PERIOD_S = 0.02
AGE_CHANNELS = ("odom", "scan")
"""The robot topics whose age at a control step makes up the joint-state age."""
GAP_TICKS = 5.0
"""A gap longer than this many tick periods is a pause between episodes (reset), not a tick period."""


@dataclass(frozen=True)
class TimingFigures:
    """Timing of one deployment session; times in milliseconds on the runner's clock."""

    tick_period_ms: float
    """The fleet's nominal emitter period."""
    ticks: int
    tick_p50_ms: float
    tick_jitter_p50_ms: float
    tick_jitter_p99_ms: float
    """|period - nominal| percentiles over consecutive ticks within episodes."""
    skew_p99_ms: float
    """Within a tick, last send minus first send."""
    sends: int
    receives: int
    controls: int
    age_p99_ms: float
    """At each control step, control time minus the receive time of each robot's latest odometry and scan."""
    stale: int
    """Control steps at which some robot's data was too old (one record per robot)."""
    stale_robots: tuple[str, ...]
    stale_examples: tuple[str, ...] = ()
    """The first few stale records as "<robot> <reason>"."""

    def as_metrics(self, prefix: str) -> dict[str, float]:
        """The figures as metrics under `prefix` (e.g. ``real/nominal``; '' for none), one ``/`` between parts."""
        return {
            metric_key(prefix, "tick_jitter_p99_ms"): self.tick_jitter_p99_ms,
            metric_key(prefix, "send_skew_p99_ms"): self.skew_p99_ms,
            metric_key(prefix, "state_age_p99_ms"): self.age_p99_ms,
            metric_key(prefix, "stale_records"): float(self.stale),
        }


def _percentile(values: np.ndarray, q: float) -> float:
    return float(np.percentile(values, q)) if values.size else math.nan


def nominal_tick_period_s(recording: Recording) -> float:
    """The emitter period of the fleet file stored in the recording (20 ms when there is none)."""
    text = recording.document("fleet")
    if not text:
        return DEFAULT_TICK_PERIOD_S
    try:
        fleet = yaml.safe_load(text)
        return float(fleet["timing"]["tick_period_s"])
    except (yaml.YAMLError, KeyError, TypeError, ValueError):
        return DEFAULT_TICK_PERIOD_S


def timing_figures(source: str | os.PathLike[str] | McapLog | Recording) -> TimingFigures:
    """Timing figures of a deployment recording.

    Raises:
        MissingTopicError: the recording has no ``/mrl/timing`` (not a deployment of this pipeline).
        AnalysisError: it has one, but no emitter ticks.
    """
    recording = source if isinstance(source, Recording) else Recording(source)
    recording.require([TIMING_TOPIC], "deployment timing")
    frame = recording.topic_frame(TIMING_TOPIC).select("kind", "robot", "topic", "local_ns", "tick")
    period_ns = nominal_tick_period_s(recording) * NS_PER_S

    ticks = frame.filter(pl.col("kind") == TIMING_CODES["tick"])["local_ns"].sort().to_numpy()
    if ticks.size == 0:
        raise AnalysisError(str(recording.path), f"{TIMING_TOPIC} holds no emitter ticks")
    periods = np.diff(ticks).astype(np.float64)
    periods = periods[periods < GAP_TICKS * period_ns]
    jitter = np.abs(periods - period_ns)

    sends = frame.filter(pl.col("kind") == TIMING_CODES["send"])
    skew = (
        sends.filter(pl.col("tick") > 0)  # tick 0: an abort's zero commands, sent off the grid
        .group_by("tick")
        .agg((pl.col("local_ns").max() - pl.col("local_ns").min()).alias("skew"), pl.len().alias("n"))
        .filter(pl.col("n") > 1)["skew"]
        .to_numpy()
        .astype(np.float64)
    )

    controls = frame.filter(pl.col("kind") == TIMING_CODES["control"])["local_ns"].sort().to_numpy()
    receives = frame.filter(pl.col("kind") == TIMING_CODES["receive"]).with_columns(
        pl.col("topic").str.split("/").list.last().alias("channel")
    )
    ages: list[np.ndarray] = []
    for (_robot, channel), part in receives.group_by(["robot", "channel"]):
        if channel not in AGE_CHANNELS:
            continue
        stamps = np.sort(part["local_ns"].to_numpy())
        idx = np.searchsorted(stamps, controls, side="right") - 1
        ok = idx >= 0
        ages.append((controls[ok] - stamps[idx[ok]]).astype(np.float64))
    age = np.concatenate(ages) if ages else np.zeros(0)

    stale = frame.filter(pl.col("kind") == TIMING_CODES["stale"])
    ms = 1e-6
    return TimingFigures(
        tick_period_ms=period_ns * ms,
        ticks=int(ticks.size),
        tick_p50_ms=_percentile(periods, 50) * ms,
        tick_jitter_p50_ms=_percentile(jitter, 50) * ms,
        tick_jitter_p99_ms=_percentile(jitter, 99) * ms,
        skew_p99_ms=_percentile(skew, 99) * ms,
        sends=sends.height,
        receives=receives.height,
        controls=int(controls.size),
        age_p99_ms=_percentile(age, 99) * ms,
        stale=stale.height,
        stale_robots=tuple(sorted(set(stale["robot"].to_list()))),
        stale_examples=tuple(f"{r} {why}" for r, why in stale.head(3).select("robot", "topic").iter_rows()),
    )


def timing_markdown(rows: list[tuple[str, TimingFigures]]) -> str:
    """A markdown table of labelled sessions' timing."""
    lines = [
        "| session | ticks | tick p50 (ms) | jitter p99 (ms) | send skew p99 (ms) | state age p99 (ms) "
        "| stale records |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, f in rows:
        stale = f"{f.stale}" + (f" ({', '.join(f.stale_robots)})" if f.stale_robots else "")
        lines.append(
            f"| {label} | {f.ticks} | {f.tick_p50_ms:.3f} | {f.tick_jitter_p99_ms:.3f} | {f.skew_p99_ms:.3f} | "
            f"{f.age_p99_ms:.1f} | {stale} |"
        )
    return "\n".join(lines) + "\n"
