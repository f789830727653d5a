"""The analysis report: ``report.md`` (tables and figures) and ``metrics.json`` (for ``dvc metrics show``).

:func:`write_report` takes labelled sessions (label, world, recording), e.g. the nominal and the
calibrated round recorded in sim and on the fleet, optional training curves and an optional
markdown section written elsewhere (e.g. the calibration results), and writes into one folder:

- ``report.md``: sessions, success rates with 95 % Wilson intervals, sim-vs-real gaps with their
  tests, per-robot rates, the deployments' timing (:mod:`pipeline.analysis.timing`), and the
  figures below;
- ``metrics.json``: the flat metrics of :func:`pipeline.analysis.compare.compare` (NaN as null)
  and each deployment's timing figures (``real/<label>/tick_jitter_p99_ms``, ``real/tick_jitter_p99_ms``
  for label '', ...);
- ``success_rates.png``, ``trajectories.png`` and, given curves, ``learning_curves.png``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import polars as pl

from pipeline.analysis.compare import WORLDS, Comparison, compare, metric_key
from pipeline.analysis.errors import AnalysisError
from pipeline.analysis.plots import plot_learning_curves, plot_success_rates, plot_trajectories, success_panels
from pipeline.analysis.tables import Recording
from pipeline.analysis.timing import TIMING_TOPIC, TimingFigures, timing_figures, timing_markdown
from pipeline.core.episode import ABORT_KINDS
from pipeline.record.bags import bag_size

REPORT_NAME = "report.md"
METRICS_NAME = "metrics.json"


@dataclass(frozen=True)
class LabelledSession:
    """One recording in the report: its `label` (e.g. the round), its `world` (sim or real) and its file."""

    label: str
    world: str
    path: Path
    shown: Path | None = None
    """The file as the user gave it, where `path` is a copy read in its place (a converted bag)."""


@dataclass(frozen=True)
class Report:
    """What :func:`write_report` wrote, and the numbers behind it."""

    markdown: Path
    metrics: Path
    figures: dict[str, Path]
    comparison: Comparison
    episodes: pl.DataFrame = field(repr=False)


def _session(item: LabelledSession | tuple[str, str, str | os.PathLike[str]]) -> LabelledSession:
    if isinstance(item, LabelledSession):
        session = item
    else:
        label, world, path = item
        session = LabelledSession(str(label), str(world), Path(path))
    if session.world not in WORLDS:
        raise AnalysisError(
            str(session.path), f"world {session.world!r} of session {session.label!r} is not sim or real"
        )
    return LabelledSession(session.label, session.world, Path(session.path), session.shown)


def write_report(
    out_dir: str | os.PathLike[str],
    sessions: Sequence[LabelledSession | tuple[str, str, str | os.PathLike[str]]],
    curves: Mapping[str, str | os.PathLike[str]] | Sequence[str | os.PathLike[str]] = (),
    extra_markdown: str = "",
    *,
    title: str = "Sim-to-real report",
    extra_title: str = "Calibration",
    trajectory_episodes: int = 3,
    pairs: Sequence[tuple[str, str]] | None = None,
    warnings: Sequence[str] = (),
    progress: Callable[[str], None] | None = None,
) -> Report:
    """Analyse `sessions` and write ``report.md``, ``metrics.json`` and the figures into `out_dir`.

    Args:
        out_dir: the report folder (created).
        sessions: (label, world, recording path) triples or LabelledSession; several sessions
            with the same label and world are pooled.
        curves: training-curve CSVs, ``{label: path}`` or a list (labelled by file stem).
        extra_markdown: a markdown section appended under `extra_title` (skipped when empty).
        trajectory_episodes: episodes drawn per session in ``trajectories.png``.
        pairs: the (sim label, real label) pairs compared; by default each label with itself.
        warnings: lines shown under "Warnings" at the top of ``report.md`` (e.g. a recording compared with itself).
        progress: called with each stage as it starts (reading a recording, the comparison, the figures); the
            recordings' reading also shows a bar on a terminal when it is given.

    Raises:
        AnalysisError: no sessions, a world other than sim/real, a pair naming a label without sessions, sessions
            compared with each other from different scenarios, or a recording that cannot be analysed (missing
            topics, see :func:`pipeline.analysis.tables.episodes_table`).
        LogReadError: a recording cannot be read.
    """
    items = [_session(s) for s in sessions]
    if not items:
        raise AnalysisError(str(out_dir), "no sessions to report on")
    out = Path(out_dir)
    stage = progress or (lambda _: None)
    recordings: list[tuple[LabelledSession, Recording]] = []
    tables: dict[str, dict[str, list[pl.DataFrame]]] = {w: {} for w in WORLDS}
    for item in items:
        recording = Recording(item.path, progress=progress is not None)
        given = item.shown or item.path
        stage(f"reading {item.world} {item.label!r} ({given}, {bag_size(given) / 1e6:.1f} MB)")
        table = recording.episodes_table().with_columns(pl.lit(item.label).alias("label"))
        tables[item.world].setdefault(item.label, []).append(table)
        recordings.append((item, recording))
    if pairs is None:
        pairs = [(label, label) for label in tables["sim"] if label in tables["real"]]
    _check_pairs(out, pairs, tables)
    _check_scenarios(recordings, pairs)
    out.mkdir(parents=True, exist_ok=True)  # every recording read and checked before the report folder is touched
    stage("comparing the episodes")
    pooled = {w: {label: pl.concat(parts) for label, parts in by_label.items()} for w, by_label in tables.items()}
    comparison = compare(pooled["sim"], pooled["real"], pairs=pairs)
    episodes = pl.concat([t for by_label in pooled.values() for t in by_label.values()], how="diagonal_relaxed")

    stage("drawing the figures")
    figures: dict[str, Path] = {}
    figures["success_rates"] = plot_success_rates(success_panels(comparison.groups), out / "success_rates.png")
    shown: dict[tuple[str, str], Recording] = {}
    for item, recording in recordings:
        shown.setdefault((item.label, item.world), recording)
    order = sorted(shown, key=lambda key: (_label_order(items, key[0]), WORLDS.index(key[1])))
    figures["trajectories"] = plot_trajectories(
        [(_session_name(world, label), shown[(label, world)]) for label, world in order],
        out / "trajectories.png",
        trajectory_episodes,
    )
    if curves:
        figures["learning_curves"] = plot_learning_curves(curves, out / "learning_curves.png")

    timing: list[tuple[str, TimingFigures]] = []
    metrics = dict(comparison.metrics)
    for item, recording in recordings:
        if item.world == "real" and TIMING_TOPIC in recording.topics():
            figures_of = timing_figures(recording)
            timing.append((_session_name(item.world, item.label), figures_of))
            metrics.update(figures_of.as_metrics(metric_key(item.world, item.label)))

    metrics_path = out / METRICS_NAME
    metrics_path.write_text(json.dumps(_json_safe(metrics), indent=2, sort_keys=True) + "\n", encoding="utf-8")
    markdown = _markdown(title, recordings, comparison, figures, out, extra_title, extra_markdown, timing, warnings)
    report_path = out / REPORT_NAME
    report_path.write_text(markdown, encoding="utf-8")
    return Report(report_path, metrics_path, figures, comparison, episodes)


def _session_name(world: str, label: str) -> str:
    """A session's name in figures and tables: its world, then its label if it has one."""
    return " ".join(p for p in (world, label) if p)


def _check_pairs(
    out: Path, pairs: Sequence[tuple[str, str]], tables: Mapping[str, Mapping[str, list[pl.DataFrame]]]
) -> None:
    for sim_label, real_label in pairs:
        for world, label in (("sim", sim_label), ("real", real_label)):
            if label not in tables[world]:
                raise AnalysisError(
                    str(out), f"{world} label {label!r} is to be compared, but no {world} session has it"
                )


def _check_scenarios(
    recordings: Sequence[tuple[LabelledSession, Recording]], pairs: Sequence[tuple[str, str]] = ()
) -> None:
    """Sessions compared under one label, or in one pair of labels, must come from one scenario."""
    groups = [{(label, w) for w in WORLDS} for label in dict.fromkeys(item.label for item, _ in recordings)]
    groups += [{(sim_label, "sim"), (real_label, "real")} for sim_label, real_label in pairs]
    for members in groups:
        seen: tuple[str, LabelledSession] | None = None
        for item, recording in recordings:
            if (item.label, item.world) not in members:
                continue
            scenario = recording.info.scenario
            if seen is None:
                seen = (scenario, item)
            elif seen[0] != scenario:
                first = seen[1]
                raise AnalysisError(
                    str(item.path),
                    f"recorded in scenario {scenario!r}, but {first.path} (label {first.label!r}) is from {seen[0]!r}; "
                    "compared sim and real sessions must share a scenario",
                )


def _label_order(items: Sequence[LabelledSession], label: str) -> int:
    return next(k for k, item in enumerate(items) if item.label == label)


def _json_safe(metrics: Mapping[str, float]) -> dict[str, float | None]:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in metrics.items()}


# -- markdown ------------------------------------------------------------------------------------


def _cell(value: Any, digits: int = 3) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if math.isnan(value):
            return "n/a"
        if value != 0 and abs(value) < 10 ** (-digits):
            return f"{value:.2e}"
        return f"{value:.{digits}f}"
    return str(value).replace("|", "\\|")


def markdown_table(frame: pl.DataFrame, digits: int = 3) -> str:
    """`frame` as a GitHub markdown table (floats to `digits` decimals, NaN as n/a)."""
    if not frame.columns:
        return ""
    lines = ["| " + " | ".join(frame.columns) + " |", "|" + "---|" * len(frame.columns)]
    for row in frame.iter_rows():
        lines.append("| " + " | ".join(_cell(v, digits) for v in row) + " |")
    return "\n".join(lines)


def _rate_text(rate: float, low: float, high: float, k: int, n: int) -> str:
    if not n:
        return "no trials"
    return f"{rate:.1%} [{low:.1%}, {high:.1%}] ({k}/{n})"


def _markdown(
    title: str,
    recordings: Sequence[tuple[LabelledSession, Recording]],
    comparison: Comparison,
    figures: Mapping[str, Path],
    out: Path,
    extra_title: str,
    extra_markdown: str,
    timing: Sequence[tuple[str, TimingFigures]] = (),
    warnings: Sequence[str] = (),
) -> str:
    parts = [f"# {title}", ""]
    if warnings:
        parts += ["## Warnings", "", *[f"- **Warning:** {line}" for line in warnings], ""]
    parts += _sessions_section(recordings)
    parts += _success_section(comparison, figures, out)
    parts += _gaps_section(comparison)
    parts += _robots_section(comparison)
    parts += _timing_section(timing)
    parts += ["## Trajectories", "", f"![trajectories]({_relative(figures['trajectories'], out)})", ""]
    if "learning_curves" in figures:
        parts += ["## Training", "", f"![learning curves]({_relative(figures['learning_curves'], out)})", ""]
    if extra_markdown.strip():
        parts += [f"## {extra_title}", "", extra_markdown.strip(), ""]
    return "\n".join(parts)


def _sessions_section(recordings: Sequence[tuple[LabelledSession, Recording]]) -> list[str]:
    parts: list[str] = []
    sessions = pl.DataFrame(
        [
            {
                "label": item.label,
                "world": item.world,
                "file": str(item.shown or item.path),
                "scenario": rec.info.scenario,
                "policy": rec.info.policy,
                "profile": rec.info.profile,
                "episodes": rec.episodes().height,
                "salvaged": rec.salvaged,
            }
            for item, rec in recordings
        ]
    )
    parts += ["## Sessions", "", markdown_table(sessions), ""]
    if any(rec.salvaged for _, rec in recordings):
        parts += [
            "Salvaged recordings had no index (the recorder was killed); they were read up to their last "
            "complete chunk and an episode cut off by the end of the file counts as aborted.",
            "",
        ]
    return parts


def _success_section(comparison: Comparison, figures: Mapping[str, Path], out: Path) -> list[str]:
    groups = comparison.groups
    summary = pl.DataFrame(
        [
            {
                "world": row["world"],
                "label": row["label"],
                "episodes": _episodes_text(row),
                "aborted": _aborted_text(row),
                "robot success [95 % CI]": _rate_text(
                    row["robot_success"],
                    row["robot_success_ci_low"],
                    row["robot_success_ci_high"],
                    row["robot_successes"],
                    row["robot_trials"],
                ),
                "team success [95 % CI]": _rate_text(
                    row["team_success"],
                    row["team_success_ci_low"],
                    row["team_success_ci_high"],
                    row["team_successes"],
                    row["team_trials"],
                ),
                "robot success, completed episodes only": _cell(row["robot_success_completed"]),
                "collision rate [95 % CI]": _rate_text(
                    row["collision_rate"],
                    row["collision_rate_ci_low"],
                    row["collision_rate_ci_high"],
                    row["collisions"],
                    row["robot_trials"],
                ),
                "mean time to goal (s) [95 % CI]": _mean_text(
                    row["mean_time_to_goal_s"], row["mean_time_to_goal_s_ci_low"], row["mean_time_to_goal_s_ci_high"]
                ),
            }
            for row in groups.iter_rows(named=True)
        ]
    )
    parts: list[str] = []
    parts += [
        "## Success",
        "",
        "Every episode counts: a robot of an aborted episode succeeds only if it had reached its goal before the "
        "abort, and the team fails (the completed-only rate stands beside, named so). Robot success: reached its "
        "goal square without colliding; team success: every robot did. Intervals: Wilson score (rates), t (mean "
        "time to goal). Aborted: outage (a robot blind past the fleet's outage limit), fault (a twin, driver or "
        "emitter gone), clash (a foreign writer on the domain), interrupted (an operator's stop), cut_off (the "
        "recording stops inside the episode).",
        "",
        markdown_table(summary),
        "",
        f"![success rates]({_relative(figures['success_rates'], out)})",
        "",
    ]
    return parts


def _gaps_section(comparison: Comparison) -> list[str]:
    parts: list[str] = []
    if comparison.gaps.height:
        parts += [
            "## Sim vs real",
            "",
            "Difference = sim - real with a 95 % interval (Newcombe hybrid score for rates, Welch for the mean "
            "time to goal); p-values: two-sided Fisher exact test (z: pooled two-proportion z-test) for rates, "
            "Mann-Whitney U for the times to goal.",
            "",
            markdown_table(comparison.gaps, digits=4),
            "",
        ]
    return parts


def _robots_section(comparison: Comparison) -> list[str]:
    parts: list[str] = []
    robots = comparison.robots.select(
        "world",
        "label",
        "robot",
        "robot_trials",
        "robot_successes",
        "robot_success",
        "robot_success_ci_low",
        "robot_success_ci_high",
        "collision_rate",
        "timeout_rate",
        "mean_time_to_goal_s",
        "stale_s",
    )
    parts += [
        "## Per robot",
        "",
        "stale_s: the seconds the robot stood still for want of fresh data (between its `stale` and `fresh` events).",
        "",
        markdown_table(robots),
        "",
    ]
    return parts


def _timing_section(timing: Sequence[tuple[str, TimingFigures]]) -> list[str]:
    parts: list[str] = []
    if timing:
        parts += [
            "## Deployment timing",
            "",
            "On the runner's clock (simulated time when the twin runs time-scaled): emitter tick period and "
            "jitter, last-minus-first send within a tick, the age of each robot's odometry and scan at the "
            "control steps, and control steps at which a robot's data was stale.",
            "",
            timing_markdown(list(timing)),
        ]
    return parts


def _episodes_text(row: Mapping[str, Any]) -> str:
    """The episodes that are trials, and beside them those a deployment did not keep its clock in (left out)."""
    off = int(row.get("clock_not_kept_episodes") or 0)
    return f"{row['episodes']}" + (f" (+{off} off the clock: the host's, not the policy's; left out)" if off else "")


def _aborted_text(row: Mapping[str, Any]) -> str:
    """The aborted episodes with their kinds, e.g. ``3 (2 outage, 1 fault)``."""
    kinds = [f"{row[f'aborted_{k}']} {k}" for k in ABORT_KINDS if row.get(f"aborted_{k}")]
    return f"{row['aborted_episodes']}" + (f" ({', '.join(kinds)})" if kinds else "")


def _mean_text(mean: float, low: float, high: float) -> str:
    if math.isnan(mean):
        return "n/a"
    if math.isnan(low):
        return f"{mean:.2f}"
    return f"{mean:.2f} [{low:.2f}, {high:.2f}]"


def _relative(path: Path, folder: Path) -> str:
    try:
        return path.relative_to(folder).as_posix()
    except ValueError:
        return path.as_posix()
