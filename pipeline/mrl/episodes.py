"""``mrl episodes BAG [--out FILE.csv|FILE.parquet]``: the episodes table (one row per episode and robot)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from pipeline.mrl.common import (
    BAG_HELP,
    CommandError,
    add_verb,
    bag_options,
    check_writable_parent,
    imported,
    require_episodes,
    source_name,
    stage_line,
)

NAME = "episodes"
TABLE_SUFFIXES = (".csv", ".parquet")
EPISODE_COLUMNS = (
    "episode",
    "robot",
    "success",
    "collided",
    "timeout",
    "aborted",
    "abort_kind",
    "stale_s",
    "time_to_goal_s",
    "path_length_m",
    "steps",
    "team_success",
)
"""Columns of the episodes table printed by ``mrl episodes`` (a file gets every column)."""


def add_parser(subparsers: Any) -> None:
    """The ``episodes`` verb's options."""
    episodes = add_verb(
        subparsers,
        NAME,
        "the episodes table: one row per episode and robot",
        "One row per episode and robot: success, collision, time to goal, path length, ... (needs the\n"
        "/mrl/episode events this project records). Printed, or written to --out: FILE.csv in the\n"
        "columns of a session's episodes.csv, FILE.parquet with every column of the analysis table.",
    )
    episodes.add_argument("bag", metavar="BAG", help=BAG_HELP)
    episodes.add_argument("--out", default=None, metavar="FILE", help="write the table to FILE.csv or FILE.parquet")
    bag_options(episodes)


def run(args: argparse.Namespace) -> int:
    """Print the bag's episodes table (or write it to --out) and a summary line."""
    import polars as pl

    from pipeline.analysis.tables import Recording
    from pipeline.record.bags import bag_size

    out = _table_path(args.out)
    with imported(args, [args.bag]) as (bag,):
        require_episodes(bag, NAME)
        stage = stage_line(NAME)
        stage(f"reading {bag.source} ({bag_size(bag.source) / 1e6:.1f} MB)")
        table = Recording(bag.path, session=source_name(bag), progress=True).episodes_table()
        stage(f"{table['episode'].n_unique()} episodes of {table['robot'].n_unique()} robots read")
        if bag.converted:
            table = table.with_columns(pl.lit(str(bag.source)).alias("path"))
    if out is not None:
        _write_table(table, out)
    else:
        with pl.Config(tbl_rows=-1, tbl_cols=-1, tbl_hide_dataframe_shape=True, tbl_width_chars=160):
            behind = not table["clock_kept"].all()  # a twin that fell behind its clock: which episodes, shown
            clock = ("time_scale_realized", "control_late_p95", "clock_kept") if behind else ()
            print(table.select(EPISODE_COLUMNS + clock))
    summary = _summary(table, _world_of(table))
    print(f"episodes: {summary}" + (f" -> {out}" if out is not None else ""))
    return 0


def _table_path(text: str | None) -> Path | None:
    if text is None:
        return None
    path = Path(text)
    if path.suffix.lower() not in TABLE_SUFFIXES:
        raise CommandError(f"--out {text}: the file name must end in .csv or .parquet (that picks the format)")
    if path.is_dir():
        raise CommandError(f"--out {text}: a folder is in the way; give a file name ending in .csv or .parquet")
    check_writable_parent(path.parent, text, "--out")
    return path


def _world_of(table: Any) -> str:
    worlds = set(table["world"].to_list())
    return "sim" if worlds == {"sim"} else "real"


def _summary(table: Any, world: str) -> str:
    from pipeline.analysis.compare import compare

    m = compare(table, None) if world == "sim" else compare(None, table)
    metrics = m.metrics

    def rate(key: str) -> str:
        value = metrics.get(f"{world}/{key}", math.nan)
        if math.isnan(value):
            return "-"
        low, high = metrics[f"{world}/{key}_ci_low"], metrics[f"{world}/{key}_ci_high"]
        return f"{100 * value:.1f} % [{100 * low:.1f}, {100 * high:.1f}]"

    return (
        f"{metrics.get(f'{world}/episodes', 0):.0f} episodes ({metrics.get(f'{world}/aborted_episodes', 0):.0f} "
        f"aborted): robot success {rate('robot_success')}, team success {rate('team_success')} over every "
        f"episode; completed episodes only: robot success {rate('robot_success_completed')}; "
        f"collisions {rate('collision_rate')}" + _clock(table)
    )


def _clock(table: Any) -> str:
    """The episodes in which the deployment did not keep its clock (the twin fell behind, or the control steps woke
    late), where there were any."""
    behind = table.filter(~table["clock_kept"])["episode"].unique().sort().to_list()
    if not behind:
        return ""
    episodes = table["episode"].n_unique()
    return (
        f"; the deployment did not keep its clock in {len(behind)} of {episodes} episode(s) "
        f"({', '.join(map(str, behind))}): "
        "they measure the host, not the policy"
    )


def _write_table(table: Any, path: Path) -> None:
    """CSV: the one episodes.csv layout the sessions write (EPISODES_CSV_COLUMNS); Parquet: the whole analysis table
    (the session's world, scenario, policy, clocks and the episode's end beside them)."""
    import polars as pl

    from pipeline.record.results import EPISODES_CSV_COLUMNS

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.suffix.lower() == ".csv":
            flags = ("success", "reached", "collided", "aborted", "team_success", "clock_kept")
            rows = table.select(EPISODES_CSV_COLUMNS).with_columns(
                *(pl.col(c).cast(pl.Int8) for c in flags),
                pl.col("seed").fill_null(-1),
                pl.col("stale_s").round(3),
                pl.col("time_to_goal_s").round(3),
                pl.col("path_length_m").round(4),
                pl.col("time_scale_realized").round(4),
                pl.col("control_late_p95").round(4),
            )
            rows.write_csv(path, float_precision=None)
        else:
            table.write_parquet(path)
    except OSError as exc:
        raise CommandError(f"--out {path}: cannot write ({exc.strerror or exc})") from exc
