"""dvc stage `report`: sim vs real success before and after calibration, with plots, as report.md and metrics.json."""

from __future__ import annotations

import json
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline.analysis.gap_report import write_report
from pipeline.params import load_params
from pipeline.stage import ROUNDS, STAGE_TIMES, run_stage, stage_arguments


def relink_images(markdown: str, source: Path, target: Path) -> str:
    """Markdown from `source` with its relative image links rewritten to work from `target`."""
    prefix = Path(os.path.relpath(source, target))

    def fix(match: re.Match[str]) -> str:
        link = match.group(2)
        if "://" in link or link.startswith("/"):
            return match.group(0)
        return f"![{match.group(1)}]({(prefix / link).as_posix()})"

    return re.sub(r"!\[([^\]]*)\]\(([^)]+)\)", fix, markdown)


def main(argv: Sequence[str] | None = None) -> int:
    args = stage_arguments(__doc__ or "", argv, rounds=False)
    params = load_params(args.params)
    out = Path(params.report.out_dir)
    sessions = []
    for r in ROUNDS:
        sessions.append((r, "sim", Path(params.eval_sim.out_dir) / r / "session.mcap"))
        sessions.append((r, "real", Path(params.deploy.out_dir) / r / "session.mcap"))
    curves = {r: Path(params.train.out_dir) / r / "curve.csv" for r in ROUNDS}
    calibration = Path(params.calibrate.out_dir)
    replay = Path(params.replay.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    extra = []
    for folder, name in ((calibration, "calibration.md"), (replay, "replay.md")):
        text = (folder / name).read_text(encoding="utf-8")
        extra.append(relink_images(text, folder, out))
    warnings = []
    for r in ROUNDS:  # a deployment whose twin fell behind its clock: said at the top, not read as the policy's
        deployed = Path(params.deploy.out_dir) / r / "metrics.json"
        metrics = json.loads(deployed.read_text(encoding="utf-8")) if deployed.is_file() else {}
        behind = int(metrics.get("real/clock_not_kept_episodes", 0))
        if behind:
            warnings.append(
                f"deploy {r}: in {behind} of {int(metrics['real/episodes'])} episodes the deployment did not keep its "
                f"clock (the twin fell behind, or the control steps woke late; least time scale realized "
                f"{metrics.get('real/time_scale_realized_min', float('nan')):.2f}, control steps at most "
                f"{metrics.get('real/control_late_p95_max', float('nan')):.2f} of a period late): they measure the "
                f"host, not the policy; robot success over the others {metrics['real/robot_success_clock_kept']:.3f}"
            )
    report = write_report(
        out,
        sessions,
        curves,
        "\n\n".join(extra),
        extra_title="Calibration and replay",
        trajectory_episodes=params.report.trajectory_episodes,
        warnings=warnings,
    )
    print(f"report: {report.markdown} and {report.metrics}")
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("report", main, STAGE_TIMES))
