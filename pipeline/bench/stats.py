"""Statistics of a sweep across seeds, with ``rliable``: interquartile means, stratified bootstrap intervals,
performance profiles.

Per cell (algorithm, mode, scenario and any swept keys), the scores are a runs x tasks matrix as rliable
takes them: robot-level success is seeds x robots (each robot's success over the evaluation episodes of
one seed), team-level success seeds x 1. The interquartile mean (IQM) is rliable's ``aggregate_iqm`` and
its 95 % interval rliable's stratified bootstrap over the seeds (``get_interval_estimates``,
percentile method). With 3 seeds the IQM is the mean of all 3 and the interval reflects only what 3
seeds can show; the table says how many seeds each cell has. Convergence is the paper's criterion
(every robot over 80 % success in 20 consecutive training episodes); the episodes and wall-clock to
it are medians over the seeds that reached it, with the count of those seeds and of those that reached it
within 300 episodes. A cell meets the target with a robot IQM of at least 95 % over at least 5 seeds, at
least 4 in 5 of them converged within 300 training episodes.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import polars as pl

TARGET_SUCCESS = 0.95
"""The benchmark's bar: robot-level sim success IQM..."""
TARGET_EPISODES = 300
"""...convergence within this many training episodes..."""
TARGET_SEEDS = 5
"""...over at least this many seeds..."""
TARGET_CONVERGED_SHARE = 0.8
"""...of which at least this share converged within TARGET_EPISODES (4 of 5)."""


@dataclass(frozen=True)
class CellStats:
    cell: str
    algorithm: str
    mode: str
    scenario: str
    seeds: int
    robot_iqm: float
    robot_ci: tuple[float, float]
    team_iqm: float
    team_ci: tuple[float, float]
    per_robot_iqm: dict[str, float]
    converged_seeds: int
    episodes_to_convergence: float | None
    wall_to_convergence_s: float | None
    train_wall_s: float
    env_steps_per_s: float
    train_steps: float = 0.0
    converged_in_time: int = 0
    """Seeds that converged within TARGET_EPISODES training episodes."""

    @property
    def meets_target(self) -> bool:
        """IQM >= 95 % over >= 5 seeds, and >= 4 in 5 of them converged within 300 episodes."""
        return (
            self.seeds >= TARGET_SEEDS
            and self.robot_iqm >= TARGET_SUCCESS
            and self.converged_in_time >= np.ceil(TARGET_CONVERGED_SHARE * self.seeds - 1e-9)
        )


def _robots(rows: pl.DataFrame) -> list[str]:
    return sorted((c.removeprefix("success_") for c in rows.columns if c.startswith("success_")), key=_natural)


def _natural(name: str) -> tuple[str, int]:
    head, _, tail = name.rpartition("_")
    return (head, int(tail)) if tail.isdigit() else (name, 0)


@contextmanager
def _bootstrap_draws(seed: int, key: str) -> Iterator[None]:
    """Seed numpy's global generator for one of rliable's bootstraps, and restore it after.

    rliable's ``StratifiedBootstrap.update_indices`` draws its resamples with ``np.random.choice``, numpy's
    global generator, whatever ``random_state`` it is given; seeding that generator from (`seed`, `key`) is
    what makes an interval reproducible."""
    saved = np.random.get_state()
    np.random.seed([seed, zlib.crc32(key.encode())])
    try:
        yield
    finally:
        np.random.set_state(saved)


def score_matrices(rows: pl.DataFrame) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per cell: (seeds x robots robot-level success, seeds x 1 team success), rows in seed order."""
    robots = _robots(rows)
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for (cell,), part in rows.sort("seed").group_by(["cell"], maintain_order=True):
        present = [r for r in robots if part[f"success_{r}"].null_count() < part.height]
        robot = part.select([f"success_{r}" for r in present]).to_numpy().astype(np.float64)
        team = part["team_success"].to_numpy().astype(np.float64)[:, None]
        out[str(cell)] = (robot, team)
    return out


def iqm_intervals(
    matrices: Sequence[np.ndarray], key: str, reps: int = 2000, seed: int = 0
) -> list[tuple[float, tuple[float, float]]]:
    """rliable's IQM of each runs x tasks score matrix and its 95 % stratified bootstrap interval (percentile),
    drawn in order from one generator seeded from (`seed`, `key`): the same matrices under the same key give
    the same intervals."""
    from rliable import library as rly
    from rliable import metrics

    def iqm(x: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_iqm(x)])

    out = []
    with _bootstrap_draws(seed, key):
        for scores in matrices:
            point, ci = rly.get_interval_estimates({key: scores}, iqm, reps=reps)
            out.append((float(point[key][0]), (float(ci[key][0, 0]), float(ci[key][1, 0]))))
    return out


def cell_stats(rows: pl.DataFrame, reps: int = 2000, seed: int = 0) -> list[CellStats]:
    """Every cell's IQMs with 95 % stratified bootstrap intervals, per-robot IQMs and convergence figures."""
    from rliable import metrics

    matrices = score_matrices(rows)
    # a cell's interval depends neither on the other cells nor the rows' order
    estimates = {cell: iqm_intervals([robot, team], cell, reps, seed) for cell, (robot, team) in matrices.items()}
    robots = _robots(rows)
    out = []
    for cell, (robot, _team) in matrices.items():
        part = rows.filter(pl.col("cell") == cell)
        first = part.row(0, named=True)
        converged = part.filter(pl.col("converged_at_episode").is_not_null())
        present = [r for r in robots if part[f"success_{r}"].null_count() < part.height]
        out.append(
            CellStats(
                cell=cell,
                algorithm=str(first["algorithm"]),
                mode=str(first["mode"]),
                scenario=str(first["scenario"]),
                seeds=part.height,
                robot_iqm=estimates[cell][0][0],
                robot_ci=estimates[cell][0][1],
                team_iqm=estimates[cell][1][0],
                team_ci=estimates[cell][1][1],
                per_robot_iqm={r: float(metrics.aggregate_iqm(robot[:, [k]])) for k, r in enumerate(present)},
                converged_seeds=converged.height,
                episodes_to_convergence=_median(converged["converged_at_episode"]) if converged.height else None,
                wall_to_convergence_s=_median(converged["wall_to_convergence_s"]) if converged.height else None,
                train_wall_s=_median(part["train_wall_s"]) or 0.0,
                env_steps_per_s=_median(part["env_steps_per_s"]) or 0.0,
                train_steps=_median(part["train_steps"]) or 0.0,
                converged_in_time=converged.filter(pl.col("converged_at_episode") <= TARGET_EPISODES).height,
            )
        )
    return out


def _median(series: pl.Series) -> float | None:
    value = series.drop_nulls().median()
    return None if value is None else float(value)  # type: ignore[arg-type]


def performance_profiles(
    rows: pl.DataFrame, taus: Sequence[float] | None = None, reps: int = 2000
) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray]]:
    """rliable's score distributions of robot-level success per cell: the share of (seed, robot) scores above each
    threshold tau, with 95 % bootstrap bands. Returns (taus, profiles, bands (2 x taus))."""
    from rliable import library as rly

    grid = np.linspace(0.0, 1.0, 51) if taus is None else np.asarray(taus, dtype=np.float64)
    matrices = {c: m[0] for c, m in score_matrices(rows).items()}
    with _bootstrap_draws(0, "performance profiles"):
        profiles, bands = rly.create_performance_profile(matrices, grid, reps=reps)
    return grid, dict(profiles), dict(bands)


def _pct(x: float) -> str:
    return f"{100 * x:.1f}"


def cell_settings(cell: str) -> str:
    """A cell's own params keys (the part of its name after algorithm/mode/scenario), or ''."""
    parts = cell.split("/", 3)
    return parts[3] if len(parts) == 4 else ""


def interval_text(ci: tuple[float, float], seeds: int) -> str:
    """`[low, high]` in percent; a cell of one seed has no interval across seeds, and says so."""
    return "(one seed: no interval)" if seeds < 2 else f"[{_pct(ci[0])}, {_pct(ci[1])}]"


def markdown_table(stats: Sequence[CellStats]) -> str:
    """The results table: one line per cell (generated, not typed); a column of the cells' own params keys
    when any cell has some."""
    keyed = any(cell_settings(s.cell) for s in stats)
    lines = [
        "| algorithm | mode | scenario |"
        + (" settings |" if keyed else "")
        + " seeds | robot success IQM, % [95 % CI] | team success IQM, % [95 % CI] | "
        "per robot (IQM, %) | converged seeds | episodes to convergence | wall-clock to convergence | "
        "training steps, wall-clock | env steps/s | target |",
        "|---|---|---|" + ("---|" if keyed else "") + "---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in stats:
        robots = ", ".join(_pct(v) for v in s.per_robot_iqm.values())
        episodes = "-" if s.episodes_to_convergence is None else f"{s.episodes_to_convergence:.0f}"
        wall = "-" if s.wall_to_convergence_s is None else f"{s.wall_to_convergence_s:.0f} s"
        target = "met" if s.meets_target else "missed"
        settings = f" {cell_settings(s.cell).replace(',', ', ') or '-'} |" if keyed else ""
        lines.append(
            f"| {s.algorithm} | {s.mode} | {s.scenario} |{settings} {s.seeds} | {_pct(s.robot_iqm)} "
            f"{interval_text(s.robot_ci, s.seeds)} | {_pct(s.team_iqm)} "
            f"{interval_text(s.team_ci, s.seeds)} | {robots} | {s.converged_seeds}/{s.seeds} "
            f"({s.converged_in_time} within {TARGET_EPISODES}) | "
            f"{episodes} | {wall} | {s.train_steps / 1000:.0f}k, {s.train_wall_s / 60:.0f} min | "
            f"{s.env_steps_per_s:.0f} | {target} |"
        )
    return "\n".join(lines) + "\n"
