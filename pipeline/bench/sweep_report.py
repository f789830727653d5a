"""A sweep's report: the results table (Markdown), learning curves with seed bands, performance profiles.

Written into the sweep folder: ``results.md`` (the table of :func:`pipeline.bench.stats.markdown_table`
with the sweep's command line), ``learning_curves.png`` (per cell, the windowed robot success of the
training episodes: median over seeds, band from the lowest to the highest seed) and
``performance_profiles.png`` (rliable's score distributions of robot-level success with their 95 %
bands). :func:`splice_readme` puts the report between a README's sweep markers, its plots copied beside the
README (``benchmarks/figures/<section>_*.png``) so that its links work there.
"""

from __future__ import annotations

import csv
import re
import shutil
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import polars as pl

from pipeline.bench.stats import CellStats, cell_settings, markdown_table, performance_profiles

CURVE_GRID = 200
"""Points on the common episode grid the seeds' curves are put on."""
FIGURES = Path("benchmarks") / "figures"
"""Where the README's copies of a sweep's plots go (relative to the README)."""


def marks(section: str = "") -> tuple[str, str]:
    """The README markers of a sweep's report (``<!-- sweep results[ SECTION]: start/end -->``)."""
    name = f"sweep results {section}" if section else "sweep results"
    return f"<!-- {name}: start -->", f"<!-- {name}: end -->"


def _curve(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(episode, windowed robot success) of one trial's learning curve."""
    if not path.is_file():
        return None
    episodes, success = [], []
    with path.open(newline="") as f:
        for rec in csv.DictReader(f):
            episodes.append(float(rec["episode"]))
            success.append(float(rec["robot_success_window"]))
    if not episodes:
        return None
    return np.asarray(episodes), np.asarray(success)


def cell_label(cell: str) -> str:
    """A legend label for a cell: algorithm/mode/scenario, its own keys by their last name (``reverse=False``)."""
    settings = cell_settings(cell)
    if not settings:
        return cell
    pairs = [item.partition("=") for item in settings.split(",")]
    keys = ", ".join(f"{key.rsplit('.', 1)[-1]}={value}" for key, _, value in pairs)
    return f"{'/'.join(cell.split('/', 3)[:3])} ({keys})"


def plot_learning_curves(out: Path, rows: pl.DataFrame, path: Path) -> bool:
    """Per cell: median windowed training success over seeds and the band between the lowest and highest seed."""
    cells = rows["cell"].unique(maintain_order=True).to_list()
    fig, ax = plt.subplots(figsize=(8, 4.5 + 0.2 * len(cells)))
    drawn = False
    for cell in cells:
        curves = [
            c
            for name in rows.filter(pl.col("cell") == cell)["name"].to_list()
            if (c := _curve(out / "trials" / name / "run" / "curve.csv")) is not None
        ]
        if not curves:
            continue
        last = min(float(e[-1]) for e, _ in curves)
        grid = np.linspace(1.0, last, CURVE_GRID)
        ys = np.stack([np.interp(grid, e, s) for e, s in curves])
        line = ax.plot(grid, np.median(ys, axis=0), label=f"{cell_label(cell)}, {len(curves)} seeds")[0]
        ax.fill_between(grid, ys.min(axis=0), ys.max(axis=0), color=line.get_color(), alpha=0.2)
        drawn = True
    if not drawn:
        plt.close(fig)
        return False
    ax.set_xlabel("training episode")
    ax.set_ylabel("robot success (last 20 episodes)")
    ax.set_ylim(-0.02, 1.02)
    ax.axhline(0.8, color="grey", lw=0.8, ls=":")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=1, frameon=False)
    ax.set_title("Learning curves: median over seeds, band lowest to highest seed")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def plot_profiles(rows: pl.DataFrame, path: Path) -> bool:
    taus, profiles, bands = performance_profiles(rows)
    if not profiles:
        return False
    fig, ax = plt.subplots(figsize=(8, 4.2 + 0.2 * len(profiles)))
    for cell, profile in profiles.items():
        line = ax.plot(taus, profile, label=cell_label(cell))[0]
        ax.fill_between(taus, bands[cell][0], bands[cell][1], color=line.get_color(), alpha=0.2)
    ax.set_xlabel("robot success threshold tau")
    ax.set_ylabel("fraction of (seed, robot) scores > tau")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)
    ax.set_title("Performance profiles (rliable score distributions, 95 % bands)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def write_report(out: Path, rows: pl.DataFrame, stats: Sequence[CellStats], command: str) -> Path:
    """``results.md`` and the plots in `out`; the Markdown file's path."""
    table = markdown_table(stats)
    lines = [f"Generated by `{command}` from {rows.height} trials in `{out}`.", "", table]
    if plot_learning_curves(out, rows, out / "learning_curves.png"):
        lines += ["![learning curves](learning_curves.png)", ""]
    if plot_profiles(rows, out / "performance_profiles.png"):
        lines += ["![performance profiles](performance_profiles.png)", ""]
    path = out / "results.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def splice_readme(readme: Path, report: Path, section: str = "") -> bool:
    """Put the `report` (``results.md``) between the README's markers of `section`, its plots copied to the
    README's ``benchmarks/figures`` and linked from there; False (and nothing changed) without the markers."""
    content = readme.read_text(encoding="utf-8")
    start_mark, end_mark = marks(section)
    start, end = content.find(start_mark), content.find(end_mark)
    if start < 0 or end < start:
        return False
    text = report.read_text(encoding="utf-8")
    figures = readme.parent / FIGURES
    prefix = f"{section or 'sweep'}_"

    def relink(match: re.Match[str]) -> str:
        source = report.parent / match.group(2)
        figures.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, figures / (prefix + source.name))
        return f"![{match.group(1)}]({(FIGURES / (prefix + source.name)).as_posix()})"

    text = re.sub(r"!\[([^\]]*)\]\(([^)/]+\.png)\)", relink, text)
    new = content[: start + len(start_mark)] + "\n" + text.rstrip("\n") + "\n" + content[end:]
    readme.write_text(new, encoding="utf-8")
    return True
