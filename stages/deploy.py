"""dvc stage `deploy`: episodes of the round's exported policy on the fleet (the hardware twin by default),
every message recorded to MCAP in the same layout as eval_sim."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline.params import load_params
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.deployment import check_scenario_agrees
from pipeline.ros.fleet import load_fleet
from pipeline.runs import run_deployment
from pipeline.stage import STAGE_TIMES, run_stage, stage_arguments


def main(argv: Sequence[str] | None = None) -> int:
    args = stage_arguments(__doc__ or "", argv)
    params = load_params(args.params)
    cfg = params.deploy
    fleet = load_fleet(cfg.fleet)
    check_scenario_agrees(params.world.scenario, args.params, fleet, cfg.fleet)
    runtime = PolicyRuntime(Path(params.export.out_dir) / args.round / "policy")
    out = Path(cfg.out_dir) / args.round
    params_text = Path(args.params).read_text(encoding="utf-8")
    live_label = f"deploy ({args.round})"
    run_deployment(runtime, fleet, cfg, out, params_text, live=cfg.live, live_port=cfg.live_port, live_label=live_label)
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("deploy", main, STAGE_TIMES))
