"""dvc stage `eval_sim`: episodes of the round's exported policy in its simulated world, recorded to MCAP."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline.cli import run_stage, stage_arguments
from pipeline.params import evaluation_world, load_params
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record.live import live_view
from pipeline.rollout.sim import evaluate_session
from pipeline.sim import make_world


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
    print(
        f"eval_sim: robot success {metrics['eval/robot_success']:.3f} "
        f"[{metrics['eval/robot_success_ci_low']:.3f}, {metrics['eval/robot_success_ci_high']:.3f}], "
        f"team success {metrics['eval/team_success']:.3f} over {len(results)} episodes "
        f"({'under the randomization' if cfg.randomized else 'at the world values'}) -> {out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("eval_sim", main))
