"""dvc stage `eval_sim`: episodes of the round's exported policy in its simulated world, recorded to MCAP."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline.params import evaluation_world, load_params
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record.live import live_view
from pipeline.rollout.sim import evaluate_session
from pipeline.runs import eval_summary
from pipeline.sim import make_world
from pipeline.stage import STAGE_TIMES, run_stage, stage_arguments


def main(argv: Sequence[str] | None = None) -> int:
    args = stage_arguments(__doc__ or "", argv)
    params = load_params(args.params)
    cfg = params.eval_sim
    scenario, world = make_world(world=evaluation_world(params, args.round, args.params))
    runtime = PolicyRuntime(Path(params.export.out_dir) / args.round / "policy")
    out = Path(cfg.out_dir) / args.round
    with live_view(cfg.live, cfg.live_port, f"eval_sim ({args.round})") as live:
        results, metrics = evaluate_session(
            scenario, world, runtime, cfg, out, Path(args.params).read_text(encoding="utf-8"), live=live
        )
    conditions = "under the randomization" if cfg.randomized else "at the world values"
    print(f"eval_sim: {eval_summary(metrics, len(results), out, conditions)}")
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("eval_sim", main, STAGE_TIMES))
