"""Sim vs real: success rates with 95 % Wilson intervals, tests of their difference, time to goal, collisions.

Input are episodes tables (:func:`pipeline.analysis.tables.episodes_table`, one row per episode and
robot), several sessions of one world concatenated, keyed by a label (e.g. ``nominal`` and
``calibrated`` rounds). Each label present in both worlds is compared sim against real, or the
(sim label, real label) pairs given (e.g. two recordings labelled by their names).

Trials: every episode. An aborted episode (a robot blind past the outage limit, a driver or twin gone,
an operator's stop, a recording that stops inside it) is a trial like any other: a robot succeeds only
if it reached its goal without colliding before the abort, and the team fails. The aborted episodes are
also counted apart (``aborted_episodes``), and the rates over the completed episodes alone stand beside
the headline rates under names that say so (``robot_success_completed``, ``team_success_completed``).
A robot trial succeeds when the robot reached its goal without colliding; a team trial when every robot
did in an episode that was not aborted. An episode in which a deployment did not keep its clock (a hardware twin that
fell behind its time scale, control steps that woke late: ``clock_kept`` false) measures the host, not the policy: it
is no trial, and is counted apart (``clock_not_kept_episodes``).
Differences are sim - real (a positive success gap: sim is more optimistic than reality).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import polars as pl
from scipy import stats as sps

from pipeline.analysis.errors import TableError
from pipeline.core.episode import ABORT_KINDS
from pipeline.core.stats import Z_95, newcombe_interval, two_proportion_z_test, wilson_interval

WORLDS = ("sim", "real")
REQUIRED_COLUMNS = ("episode", "robot", "success", "collided", "aborted", "time_to_goal_s", "team_success")
"""Columns compare() reads from each table (plus ``session`` or ``path`` to tell sessions apart, if present)."""
RATES = ("robot_success", "team_success", "collision_rate")

Tables = pl.DataFrame | Mapping[str, pl.DataFrame]
"""One world's episodes tables: one table (label ''), or tables keyed by label."""


@dataclass(frozen=True)
class Comparison:
    """The result of :func:`compare`.

    Attributes:
        groups: one row per (world, label): trials, successes, rates with 95 % Wilson intervals,
            time to goal (mean with a 95 % t interval, median), path length.
        robots: one row per (world, label, robot): the same per robot.
        gaps: one row per (label, metric) compared in both worlds: sim and real values, the
            difference sim - real with its 95 % interval (Newcombe for rates, Welch t for the mean
            time to goal) and p-values (Fisher exact and two-proportion z for rates, Mann-Whitney
            U for time to goal). The label of a pair of two labels is :func:`pair_label`'s.
        metrics: flat ``{key: value}`` for dvc metrics: ``<world>[/<label>]/<metric>`` and
            ``gap[/<label>]/<metric>[_p_value|_z_p_value|_ci_low|_ci_high]`` (:func:`metric_key`);
            NaN where undefined.
    """

    groups: pl.DataFrame
    robots: pl.DataFrame
    gaps: pl.DataFrame
    metrics: dict[str, float]


def _labelled(tables: Tables | None) -> dict[str, pl.DataFrame]:
    if tables is None:
        return {}
    if isinstance(tables, pl.DataFrame):
        return {"": tables}
    return dict(tables)


def _check(table: pl.DataFrame, world: str, label: str) -> None:
    missing = [c for c in REQUIRED_COLUMNS if c not in table.columns]
    if missing:
        name = f"{world} table{f' {label!r}' if label else ''}"
        raise TableError(name, f"lacks column(s) {', '.join(missing)} (an episodes table has {REQUIRED_COLUMNS})")


def _session_keys(table: pl.DataFrame) -> list[str]:
    return [c for c in ("path", "session") if c in table.columns] + ["episode"]


def _mean_interval(values: np.ndarray, z: float) -> tuple[float, float, float]:
    """Mean and its two-sided t interval at the confidence of normal quantile `z`; nan where undefined."""
    n = len(values)
    if n == 0:
        return math.nan, math.nan, math.nan
    mean = float(values.mean())
    if n < 2:
        return mean, math.nan, math.nan
    level = 1 - 2 * float(sps.norm.sf(z))
    half = float(sps.t.ppf(0.5 + level / 2, n - 1)) * float(values.std(ddof=1)) / math.sqrt(n)
    return mean, mean - half, mean + half


@dataclass(frozen=True)
class _Counts:
    robot_k: int
    robot_n: int
    team_k: int
    team_n: int
    collision_k: int
    timeout_k: int
    times: np.ndarray
    completed_robot_k: int = 0
    completed_robot_n: int = 0
    completed_team_k: int = 0
    completed_team_n: int = 0


def _counts(table: pl.DataFrame) -> tuple[_Counts, int, int]:
    """Counts over every episode of `table` (and over its completed ones), its episode and aborted-episode counts."""
    keys = _session_keys(table)
    episodes = table.group_by(keys).agg(
        pl.col("aborted").any().alias("aborted"), pl.col("team_success").all().alias("team_success")
    )
    team = episodes["team_success"] & ~episodes["aborted"]
    success = table["success"].cast(pl.Boolean)
    completed = table.filter(~pl.col("aborted"))
    times = table.filter(pl.col("success"))["time_to_goal_s"].drop_nulls().to_numpy().astype(np.float64)
    counts = _Counts(
        robot_k=int(success.sum()),
        robot_n=table.height,
        team_k=int(team.sum()),
        team_n=episodes.height,
        collision_k=int(table["collided"].sum()),
        timeout_k=int(table["timeout"].sum()) if "timeout" in table.columns else 0,
        times=times[np.isfinite(times)],
        completed_robot_k=int(completed["success"].cast(pl.Boolean).sum()),
        completed_robot_n=completed.height,
        completed_team_k=int(team.filter(~episodes["aborted"]).sum()),
        completed_team_n=int((~episodes["aborted"]).sum()),
    )
    return counts, episodes.height, int(episodes["aborted"].sum())


def _clock_kept(table: pl.DataFrame) -> tuple[pl.DataFrame, int]:
    """`table` without the episodes in which a deployment did not keep its clock (they measure the host, not the
    policy), and how many there were (0 for a table without a ``clock_kept`` column: the simulator's)."""
    if "clock_kept" not in table.columns:
        return table, 0
    kept = pl.col("clock_kept").fill_null(True)
    episodes = table.group_by(_session_keys(table)).agg(kept.all().alias("kept"))
    return table.filter(kept), int((~episodes["kept"]).sum())


def _abort_kinds(table: pl.DataFrame) -> dict[str, int]:
    """Aborted episodes of `table` by kind (``aborted_<kind>``; all zero for tables without an abort_kind column)."""
    out = {f"aborted_{kind}": 0 for kind in ABORT_KINDS}
    if "abort_kind" not in table.columns:
        return out
    episodes = table.group_by(_session_keys(table)).agg(pl.col("abort_kind").first())
    for kind in ABORT_KINDS:
        out[f"aborted_{kind}"] = int((episodes["abort_kind"] == kind).sum())
    return out


def _rate(k: int, n: int, z: float) -> tuple[float, float, float]:
    low, high = wilson_interval(k, n, z)
    low, high = (0.0 if k == 0 else low), (1.0 if k == n else high)  # exact ends, not rounding residue
    return (k / n if n else math.nan), (low if n else math.nan), (high if n else math.nan)


def _summary(counts: _Counts, z: float, team: bool = True) -> dict[str, Any]:
    out: dict[str, Any] = {"robot_trials": counts.robot_n, "robot_successes": counts.robot_k}
    rate, low, high = _rate(counts.robot_k, counts.robot_n, z)
    out.update(robot_success=rate, robot_success_ci_low=low, robot_success_ci_high=high)
    if team:
        rate, low, high = _rate(counts.team_k, counts.team_n, z)
        out.update(team_trials=counts.team_n, team_successes=counts.team_k)
        out.update(team_success=rate, team_success_ci_low=low, team_success_ci_high=high)
    rate, low, high = _rate(counts.completed_robot_k, counts.completed_robot_n, z)
    out.update(robot_success_completed=rate, robot_success_completed_ci_low=low, robot_success_completed_ci_high=high)
    if team:
        rate, low, high = _rate(counts.completed_team_k, counts.completed_team_n, z)
        out.update(team_success_completed=rate, team_success_completed_ci_low=low, team_success_completed_ci_high=high)
    rate, low, high = _rate(counts.collision_k, counts.robot_n, z)
    out.update(
        collisions=counts.collision_k, collision_rate=rate, collision_rate_ci_low=low, collision_rate_ci_high=high
    )
    out["timeout_rate"] = counts.timeout_k / counts.robot_n if counts.robot_n else math.nan
    mean, low, high = _mean_interval(counts.times, z)
    out.update(
        goals=len(counts.times),
        mean_time_to_goal_s=mean,
        mean_time_to_goal_s_ci_low=low,
        mean_time_to_goal_s_ci_high=high,
        median_time_to_goal_s=float(np.median(counts.times)) if len(counts.times) else math.nan,
    )
    return out


def _fisher(k_a: int, n_a: int, k_b: int, n_b: int) -> float:
    if n_a == 0 or n_b == 0:
        return math.nan
    result = sps.fisher_exact([[k_a, n_a - k_a], [k_b, n_b - k_b]], alternative="two-sided")
    return float(result.pvalue)


def _mann_whitney(a: np.ndarray, b: np.ndarray) -> float:
    if len(a) == 0 or len(b) == 0:
        return math.nan
    return float(sps.mannwhitneyu(a, b, alternative="two-sided").pvalue)


def _welch_interval(a: np.ndarray, b: np.ndarray, z: float) -> tuple[float, float]:
    """Welch's t interval for mean(a) - mean(b); nan with fewer than two values on a side."""
    if len(a) < 2 or len(b) < 2:
        return math.nan, math.nan
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    se = math.sqrt(va + vb)
    d = float(a.mean() - b.mean())
    if se == 0:
        return d, d
    dof = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))
    level = 1 - 2 * float(sps.norm.sf(z))
    half = float(sps.t.ppf(0.5 + level / 2, dof)) * se
    return d - half, d + half


def metric_key(*parts: str) -> str:
    """A metrics key: the non-empty `parts` joined by one ``/`` (``metric_key("real", "", "x")`` is ``real/x``)."""
    return "/".join(p for part in parts for p in part.split("/") if p)


def pair_label(sim_label: str, real_label: str) -> str:
    """The label of the comparison of sim label `sim_label` with real label `real_label`: the label they share, or
    ``<sim_label> vs <real_label>``."""
    return sim_label if sim_label == real_label else f"{sim_label} vs {real_label}"


def compare(
    sim: Tables | None,
    real: Tables | None,
    *,
    z: float = Z_95,
    pairs: Sequence[tuple[str, str]] | None = None,
) -> Comparison:
    """Compare sim and real episodes tables, label by label (see the module docstring).

    Args:
        sim, real: each a table (label '') or ``{label: table}``; None or ``{}`` for a world
            without sessions (its groups are absent and nothing is compared).
        z: the normal quantile of the intervals (1.96: 95 %).
        pairs: the (sim label, real label) pairs to compare; by default each label of both worlds with itself.

    Raises:
        TableError: a table lacks a needed column, or a pair names a label without a table.
    """
    worlds = {"sim": _labelled(sim), "real": _labelled(real)}
    if pairs is None:
        pairs = [(label, label) for label in worlds["sim"] if label in worlds["real"]]
    for sim_label, real_label in pairs:
        for world, label in (("sim", sim_label), ("real", real_label)):
            if label not in worlds[world]:
                raise TableError(
                    f"{world} label {label!r}", f"is compared but has no table (labels: {sorted(worlds[world])})"
                )
    group_rows: list[dict[str, Any]] = []
    robot_rows: list[dict[str, Any]] = []
    metrics: dict[str, float] = {}
    counts: dict[tuple[str, str], _Counts] = {}
    for world, tables in worlds.items():
        for label, table in tables.items():
            _check(table, world, label)
            table, not_kept = _clock_kept(table)
            c, episodes, aborted = _counts(table)
            counts[(world, label)] = c
            summary = {
                "episodes": episodes,
                "aborted_episodes": aborted,
                **_abort_kinds(table),
                "clock_not_kept_episodes": not_kept,
                **_summary(c, z),
            }
            group_rows.append({"world": world, "label": label, **summary})
            for name, value in summary.items():
                metrics[metric_key(world, label, name)] = float(value)
            for robot in sorted(table["robot"].unique().to_list()):
                rc, _, _ = _counts(table.filter(pl.col("robot") == robot))
                row = _summary(rc, z, team=False)
                row["stale_s"] = (
                    float(table.filter(pl.col("robot") == robot)["stale_s"].fill_null(0.0).sum())
                    if "stale_s" in table.columns
                    else 0.0
                )
                robot_rows.append({"world": world, "label": label, "robot": robot, **row})
                metrics[metric_key(world, label, f"{robot}_success")] = float(row["robot_success"])
                metrics[metric_key(world, label, f"{robot}_stale_s")] = float(row["stale_s"])
    gap_rows: list[dict[str, Any]] = []
    for sim_label, real_label in pairs:
        label = pair_label(sim_label, real_label)
        s, r = counts[("sim", sim_label)], counts[("real", real_label)]
        proportions = {
            "robot_success": (s.robot_k, s.robot_n, r.robot_k, r.robot_n),
            "team_success": (s.team_k, s.team_n, r.team_k, r.team_n),
            "collision_rate": (s.collision_k, s.robot_n, r.collision_k, r.robot_n),
        }
        for metric, (ks, ns, kr, nr) in proportions.items():
            low, high = newcombe_interval(ks, ns, kr, nr, z)
            _, z_p = two_proportion_z_test(ks, ns, kr, nr)
            sim_rate = ks / ns if ns else math.nan
            real_rate = kr / nr if nr else math.nan
            gap_rows.append(
                {
                    "label": label,
                    "metric": metric,
                    "sim": sim_rate,
                    "real": real_rate,
                    "difference": sim_rate - real_rate,
                    "ci_low": low,
                    "ci_high": high,
                    "p_value": _fisher(ks, ns, kr, nr),
                    "test": "fisher_exact",
                    "z_p_value": z_p,
                }
            )
        sim_mean = float(s.times.mean()) if len(s.times) else math.nan
        real_mean = float(r.times.mean()) if len(r.times) else math.nan
        low, high = _welch_interval(s.times, r.times, z)
        gap_rows.append(
            {
                "label": label,
                "metric": "mean_time_to_goal_s",
                "sim": sim_mean,
                "real": real_mean,
                "difference": sim_mean - real_mean,
                "ci_low": low,
                "ci_high": high,
                "p_value": _mann_whitney(s.times, r.times),
                "test": "mann_whitney_u",
                "z_p_value": math.nan,
            }
        )
        for row in gap_rows[-4:]:
            base = metric_key("gap", label, row["metric"])
            metrics[base] = row["difference"]
            metrics[f"{base}_ci_low"] = row["ci_low"]
            metrics[f"{base}_ci_high"] = row["ci_high"]
            metrics[f"{base}_p_value"] = row["p_value"]
            if row["test"] == "fisher_exact":
                metrics[f"{base}_z_p_value"] = row["z_p_value"]
    return Comparison(
        groups=_frame(group_rows, _GROUP_SCHEMA),
        robots=_frame(robot_rows, _ROBOT_SCHEMA),
        gaps=_frame(gap_rows, _GAP_SCHEMA),
        metrics=metrics,
    )


def _frame(rows: list[dict[str, Any]], schema: dict[str, Any]) -> pl.DataFrame:
    return pl.DataFrame(rows, schema=schema)


_RATE_COLUMNS: dict[str, Any] = {
    "robot_trials": pl.Int64,
    "robot_successes": pl.Int64,
    "robot_success": pl.Float64,
    "robot_success_ci_low": pl.Float64,
    "robot_success_ci_high": pl.Float64,
    "robot_success_completed": pl.Float64,
    "robot_success_completed_ci_low": pl.Float64,
    "robot_success_completed_ci_high": pl.Float64,
}
_TEAM_COLUMNS: dict[str, Any] = {
    "team_trials": pl.Int64,
    "team_successes": pl.Int64,
    "team_success": pl.Float64,
    "team_success_ci_low": pl.Float64,
    "team_success_ci_high": pl.Float64,
    "team_success_completed": pl.Float64,
    "team_success_completed_ci_low": pl.Float64,
    "team_success_completed_ci_high": pl.Float64,
}
_OTHER_COLUMNS: dict[str, Any] = {
    "collisions": pl.Int64,
    "collision_rate": pl.Float64,
    "collision_rate_ci_low": pl.Float64,
    "collision_rate_ci_high": pl.Float64,
    "timeout_rate": pl.Float64,
    "goals": pl.Int64,
    "mean_time_to_goal_s": pl.Float64,
    "mean_time_to_goal_s_ci_low": pl.Float64,
    "mean_time_to_goal_s_ci_high": pl.Float64,
    "median_time_to_goal_s": pl.Float64,
}
_GROUP_SCHEMA: dict[str, Any] = {
    "world": pl.String,
    "label": pl.String,
    "episodes": pl.Int64,
    "aborted_episodes": pl.Int64,
    **{f"aborted_{kind}": pl.Int64 for kind in ABORT_KINDS},
    "clock_not_kept_episodes": pl.Int64,
    **_RATE_COLUMNS,
    **_TEAM_COLUMNS,
    **_OTHER_COLUMNS,
}
_ROBOT_SCHEMA: dict[str, Any] = {
    "world": pl.String,
    "label": pl.String,
    "robot": pl.String,
    **_RATE_COLUMNS,
    **_OTHER_COLUMNS,
    "stale_s": pl.Float64,
}
_GAP_SCHEMA: dict[str, Any] = {
    "label": pl.String,
    "metric": pl.String,
    "sim": pl.Float64,
    "real": pl.Float64,
    "difference": pl.Float64,
    "ci_low": pl.Float64,
    "ci_high": pl.Float64,
    "p_value": pl.Float64,
    "test": pl.String,
    "z_p_value": pl.Float64,
}
