"""Re-count committed twin results with every episode: an aborted episode's robots fail unless they had arrived.

Result folders written before aborted episodes counted (their metrics.json left them out of the rates) still hold
every episode in episodes.csv, with each robot's success as it stood when its episode ended or was aborted. This
script re-derives robot- and team-level success over all episodes from those rows (Wilson 95 % intervals), prints
them beside the completed-only rates the folders reported, and writes them to --out with the command and commit.

    python benchmarks/recount.py --out benchmarks/results/recount.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

import polars as pl

from pipeline.core.stats import wilson_interval

ROOT = Path(__file__).resolve().parents[1]


def recount(folder: Path) -> dict[str, float | str]:
    """Every-episode rates of one result folder (episodes.csv) beside the rates its metrics.json reports."""
    table = pl.read_csv(folder / "episodes.csv")
    reported = json.loads((folder / "metrics.json").read_text())
    prefix = next(k.split("/")[0] for k in reported if k.endswith("/robot_success"))
    episodes = table.group_by("episode").agg(pl.col("team_success").all(), pl.col("success").all().alias("all_in"))
    aborted = int(reported.get(f"{prefix}/aborted_episodes", 0))
    k, n = int(table["success"].sum()), table.height
    # a team succeeds when every robot succeeded in an episode that was not aborted (aborted ones never did)
    team_k, team_n = (
        int((episodes["team_success"].cast(pl.Boolean) & episodes["all_in"].cast(pl.Boolean)).sum()),
        episodes.height,
    )
    low, high = wilson_interval(k, n)
    team_low, team_high = wilson_interval(team_k, team_n)
    return {
        "folder": str(folder.relative_to(ROOT)),
        "episodes": float(episodes.height),
        "aborted_episodes": float(aborted),
        "robot_success": k / n,
        "robot_success_ci_low": low,
        "robot_success_ci_high": high,
        "team_success": team_k / team_n,
        "team_success_ci_low": team_low,
        "team_success_ci_high": team_high,
        "robot_success_completed_as_reported": float(reported[f"{prefix}/robot_success"]),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    rows = []
    for csv in sorted(args.results.rglob("episodes.csv")):
        metrics = json.loads((csv.parent / "metrics.json").read_text())
        if not any(k.endswith("/aborted_episodes") and v for k, v in metrics.items()):
            continue
        if any(k.endswith("/robot_success_completed") for k in metrics):
            continue  # written with every episode counted already
        row = recount(csv.parent)
        rows.append(row)
        print(
            f"{row['folder']}: robot success over all {row['episodes']:.0f} episodes "
            f"{100 * float(row['robot_success']):.1f} % [{100 * float(row['robot_success_ci_low']):.1f}, "
            f"{100 * float(row['robot_success_ci_high']):.1f}], team {100 * float(row['team_success']):.1f} %; "
            f"reported over the completed ones ({row['aborted_episodes']:.0f} aborted left out): "
            f"{100 * float(row['robot_success_completed_as_reported']):.1f} %"
        )
    if args.out is not None:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
        document = {
            "command": "python benchmarks/recount.py " + " ".join(sys.argv[1:]),
            "commit": commit,
            "date": datetime.now(UTC).isoformat(timespec="seconds"),
            "rows": rows,
        }
        args.out.write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
