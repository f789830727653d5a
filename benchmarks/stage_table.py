"""The stage table of a ``dvc repro``: seconds per stage, from the ``logs/stages/*.json`` each stage run writes.

    python benchmarks/stage_table.py [--root DIR]

Printed: one line per stage run (in the loop's order), its seconds and share of the sum, its exit code; the last
line ``stages=<n> total_s=<sum> slowest=<stage>``. A stage that dvc did not rerun keeps the time of its last run
(the file's ``started`` says when).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ORDER = ("scripted_eval", "fleet_check", "train", "export", "eval_sim", "deploy", "calibrate", "replay", "report")


def rank(stage: str) -> tuple[int, int]:
    name, _, round_ = stage.partition("@")
    return (ORDER.index(name) if name in ORDER else len(ORDER), 1 if round_ == "calibrated" else 0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path("."), help="the run's folder (default: here)")
    args = parser.parse_args()
    folder = args.root / "logs" / "stages"
    records = []
    for path in sorted(folder.glob("*.json")):
        try:
            records.append(json.loads(path.read_text(encoding="utf-8")))
        except (OSError, ValueError) as exc:
            print(f"stage_table: {path}: unreadable ({exc})", file=sys.stderr)
            return 2
    if not records:
        print(f"stage_table: no stage times in {folder} (each dvc stage writes one as it ends)", file=sys.stderr)
        return 2
    records.sort(key=lambda r: (rank(r["stage"]), r["started"]))
    total = sum(r["seconds"] for r in records)
    print(f"{'stage':28s} {'seconds':>8s} {'share':>6s}  exit  started")
    for r in records:
        print(f"{r['stage']:28s} {r['seconds']:8.1f} {r['seconds'] / total:6.1%}  {r['exit']:4d}  {r['started']}")
    slowest = max(records, key=lambda r: r["seconds"])
    print(f"stages={len(records)} total_s={total:.1f} slowest={slowest['stage']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
