"""Figures of the analysis as PNG files: learning curves, success rates, trajectories over the room.

Figures are drawn on matplotlib's Agg canvas directly (no pyplot, no display, no global backend
state), so they render headless and from any thread.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
import polars as pl
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Polygon, Rectangle

from pipeline.analysis.errors import AnalysisError, TableError
from pipeline.analysis.tables import PoseKind, Recording, Source, open_recording
from pipeline.core.scenario import Scenario, box_corners
from pipeline.core.stats import Z_95, wilson_interval

ROBOT_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive")
CURVE_COLUMNS = ("episode", "world_steps", "robot_success", "team_success")
"""Columns a training-curve CSV must have (pipeline.learn.common.progress.LearningCurve writes them)."""
DPI = 110


def _save(fig: Figure, path: str | os.PathLike[str]) -> Path:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(out, dpi=DPI)
    return out


def _robot_colour(index: int) -> str:
    return ROBOT_COLOURS[index % len(ROBOT_COLOURS)]


# -- learning curves -----------------------------------------------------------------------------


def read_curve(path: str | os.PathLike[str]) -> pl.DataFrame:
    """A training-curve CSV (one row per finished episode); TableError if it is unreadable or lacks columns."""
    where = str(path)
    try:
        frame = pl.read_csv(Path(path))
    except FileNotFoundError:
        raise TableError(where, "no such training-curve file") from None
    except (OSError, pl.exceptions.PolarsError) as exc:
        raise TableError(where, f"not a readable CSV file: {exc}") from exc
    missing = [c for c in CURVE_COLUMNS if c not in frame.columns]
    if missing:
        raise TableError(where, f"lacks column(s) {', '.join(missing)} of a training curve (needs {CURVE_COLUMNS})")
    return frame


def plot_learning_curves(
    curves: Mapping[str, str | os.PathLike[str]] | Sequence[str | os.PathLike[str]],
    path: str | os.PathLike[str],
    window: int = 20,
) -> Path:
    """Success and return against world steps for one or more training runs -> PNG at `path`.

    `curves` maps a label to a training-curve CSV (or is a list of CSVs, labelled by file stem).
    Success is the per-episode robot-level (mean over robots) and team-level success, averaged over
    the last `window` episodes; the return is the mean over robots, averaged likewise.
    """
    labelled = dict(curves) if isinstance(curves, Mapping) else {Path(p).stem: p for p in curves}
    if not labelled:
        raise AnalysisError(str(path), "no training curves to plot")
    fig = Figure(figsize=(10, 4.2))
    ax_success, ax_return = fig.subplots(1, 2)
    for k, (label, csv) in enumerate(labelled.items()):
        frame = read_curve(csv).sort("episode")
        colour = ROBOT_COLOURS[k % len(ROBOT_COLOURS)]
        steps = frame["world_steps"].to_numpy()
        robot = frame["robot_success"].cast(pl.Float64).rolling_mean(window, min_samples=1).to_numpy()
        team = frame["team_success"].cast(pl.Float64).rolling_mean(window, min_samples=1).to_numpy()
        ax_success.plot(steps, robot, color=colour, label=f"{label} robot")
        ax_success.plot(steps, team, color=colour, linestyle="--", label=f"{label} team")
        returns = [c for c in frame.columns if c.startswith("return_")]
        if returns:
            mean_return = frame.select(pl.mean_horizontal(returns).alias("r"))["r"]
            ax_return.plot(steps, mean_return.rolling_mean(window, min_samples=1).to_numpy(), color=colour, label=label)
    ax_success.set(xlabel="world steps", ylabel=f"success (mean of last {window} episodes)", ylim=(-0.02, 1.02))
    ax_success.axhline(0.8, color="grey", linewidth=0.8, linestyle=":")
    ax_success.legend(fontsize="small")
    ax_success.grid(alpha=0.3)
    ax_return.set(xlabel="world steps", ylabel=f"return per robot (mean of last {window} episodes)")
    ax_return.grid(alpha=0.3)
    if ax_return.get_legend_handles_labels()[0]:
        ax_return.legend(fontsize="small")
    fig.suptitle("Learning curves")
    fig.tight_layout()
    return _save(fig, path)


# -- success rates -------------------------------------------------------------------------------


class Rate(NamedTuple):
    """One bar: `successes` of `trials`, shown with its 95 % Wilson interval."""

    label: str
    successes: int
    trials: int


def success_panels(groups: pl.DataFrame) -> dict[str, list[Rate]]:
    """Robot- and team-level bars from ``Comparison.groups`` (one bar per world and label)."""
    panels: dict[str, list[Rate]] = {"robot-level success": [], "team-level success": []}
    for row in groups.iter_rows(named=True):
        label = " ".join(str(p) for p in (row["world"], row["label"]) if p)
        panels["robot-level success"].append(Rate(label, int(row["robot_successes"]), int(row["robot_trials"])))
        panels["team-level success"].append(Rate(label, int(row["team_successes"]), int(row["team_trials"])))
    return panels


def plot_success_rates(
    panels: Mapping[str, Sequence[Rate]], path: str | os.PathLike[str], title: str = "Success rates", z: float = Z_95
) -> Path:
    """Bars of success rates with Wilson-interval error bars, one panel per entry of `panels` -> PNG."""
    if not panels:
        raise AnalysisError(str(path), "no success rates to plot")
    widest = max((len(r) for r in panels.values()), default=1)
    fig = Figure(figsize=(max(4.5, 1.3 * widest) * len(panels), 4.4))
    axes = np.atleast_1d(fig.subplots(1, len(panels)))
    for ax, (name, rates) in zip(axes, panels.items(), strict=True):
        x = np.arange(len(rates))
        value = np.array([r.successes / r.trials if r.trials else np.nan for r in rates])
        bounds = np.array([wilson_interval(r.successes, r.trials, z) for r in rates]).reshape(-1, 2)
        errors = np.clip(np.stack([value - bounds[:, 0], bounds[:, 1] - value]), 0.0, None)
        colours = ["tab:blue" if r.label.startswith("sim") else "tab:red" for r in rates]
        ax.bar(x, np.nan_to_num(value), color=colours, alpha=0.75)
        ax.errorbar(x, value, yerr=np.nan_to_num(errors), fmt="none", ecolor="black", capsize=5)
        for xi, v, top, r in zip(x, value, bounds[:, 1], rates, strict=True):
            text = f"{v:.0%}\n{r.successes}/{r.trials}" if r.trials else "no trials"
            ax.text(xi, min(top, 1.0) + 0.02, text, ha="center", va="bottom", fontsize="small")
        ax.set_xticks(x, [r.label for r in rates], rotation=20, ha="right")
        ax.set(ylim=(0, 1.18), ylabel="success rate (95 % Wilson interval)", title=name)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)


# -- trajectories --------------------------------------------------------------------------------


def draw_room(ax: Axes, scenario: Scenario) -> None:
    """The room's walls, obstacles, goal squares and start poses of `scenario` on `ax`, axes labelled in metres."""
    room = scenario.room
    ax.add_patch(
        Rectangle(
            (room.x_min_m, room.y_min_m),
            room.x_max_m - room.x_min_m,
            room.y_max_m - room.y_min_m,
            fill=False,
            edgecolor="black",
            linewidth=2.5,
        )
    )
    for box in scenario.obstacles:
        ax.add_patch(Polygon(box_corners(box), closed=True, facecolor="dimgrey", edgecolor="black"))
    half = scenario.goal_size_m / 2
    for i, goal in enumerate(scenario.goals):
        colour = _robot_colour(i)
        ax.add_patch(Rectangle((goal[0] - half, goal[1] - half), 2 * half, 2 * half, color=colour, alpha=0.25))
        start = scenario.starts[i]
        ax.plot(start[0], start[1], marker="o", markersize=5, color=colour, markerfacecolor="white")
    margin = 0.15
    ax.set_xlim(room.x_min_m - margin, room.x_max_m + margin)
    ax.set_ylim(room.y_min_m - margin, room.y_max_m + margin)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)", fontsize="x-small")
    ax.set_ylabel("y (m)", fontsize="x-small")
    ax.tick_params(labelsize="x-small")


def plot_trajectories(
    sessions: Sequence[tuple[str, Source]],
    path: str | os.PathLike[str],
    episodes: int | Sequence[int] = 3,
) -> Path:
    """Robot paths of a few episodes per session, sessions side by side (columns), episodes in rows -> PNG.

    `sessions` are (label, recording) pairs, e.g. ``[("sim nominal", sim_path), ("real nominal",
    real_path)]``; `episodes` is a count (the first episodes of each session) or episode numbers.
    Paths come from ground truth where recorded, else odometry; a star marks a robot that reached
    its goal, a cross one that collided. The room comes from each recording's scenario metadata;
    axes are x and y in metres.
    """
    if not sessions:
        raise AnalysisError(str(path), "no sessions to draw")
    return _save(trajectories_figure(sessions, episodes), path)


def trajectories_figure(sessions: Sequence[tuple[str, Source]], episodes: int | Sequence[int] = 3) -> Figure:
    """The figure :func:`plot_trajectories` saves (one axes per session and episode row)."""
    if not sessions:
        raise AnalysisError("trajectories", "no sessions to draw")
    opened: list[tuple[str, Recording]] = [(label, open_recording(source)) for label, source in sessions]
    chosen: list[list[int]] = []
    for _, recording in opened:
        numbers = recording.episodes()["episode"].to_list()
        if isinstance(episodes, int):
            chosen.append(numbers[:episodes])
        else:
            chosen.append([e for e in episodes if e in numbers])
    rows = max(1, max(len(c) for c in chosen))
    first = opened[0][1].scenario()
    width = first.room.x_max_m - first.room.x_min_m
    height = first.room.y_max_m - first.room.y_min_m
    tile = 3.6
    fig = Figure(figsize=(tile * len(opened), max(2.0, tile * height / max(width, 1e-9)) * rows + 0.6))
    grid = np.array(fig.subplots(rows, len(opened), squeeze=False))
    for col, ((label, recording), numbers) in enumerate(zip(opened, chosen, strict=True)):
        scenario = recording.scenario()
        kind: PoseKind = (
            "ground_truth" if len(recording.pose_topics("ground_truth")) == len(recording.robots) else "odom"
        )
        poses = recording.poses(kind)
        table = recording.episodes_table()
        for row in range(rows):
            ax = grid[row, col]
            draw_room(ax, scenario)
            if row >= len(numbers):
                ax.set_axis_off()
                continue
            episode = numbers[row]
            outcome = table.filter(pl.col("episode") == episode)
            for i, robot in enumerate(recording.robots):
                track = poses.filter((pl.col("robot") == robot) & (pl.col("episode") == episode))
                if track.is_empty():
                    continue
                x, y = track["x_m"].to_numpy(), track["y_m"].to_numpy()
                colour = _robot_colour(i)
                ax.plot(x, y, color=colour, linewidth=1.4, label=robot)
                facts = outcome.filter(pl.col("robot") == robot)
                reached = bool(facts["reached"].any()) if facts.height else False
                collided = bool(facts["collided"].any()) if facts.height else False
                marker = "*" if reached else ("X" if collided else "o")
                ax.plot(x[-1], y[-1], marker=marker, markersize=10 if marker != "o" else 4, color=colour)
            team = outcome.height and bool(outcome["team_success"].all())
            aborted = outcome.height and bool(outcome["aborted"].any())
            note = " (team success)" if team else (" (aborted)" if aborted else "")
            ax.set_title(f"{label}: episode {episode}{note}", fontsize="small")
            if row == 0 and col == 0:
                ax.legend(fontsize="x-small", loc="upper right")
    fig.suptitle(f"Trajectories ({', '.join(label for label, _ in opened)})")
    fig.tight_layout()
    return fig
