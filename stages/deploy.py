"""dvc stage `deploy`: episodes of the round's exported policy on the fleet (the hardware twin by default),
every message recorded to MCAP in the same layout as eval_sim."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline.cli import deploy_summary, operator_reset, run_stage, stage_arguments
from pipeline.params import load_params
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record.live import live_view
from pipeline.rollout.deployment import DeployRequest, check_scenario_agrees, deploy_session
from pipeline.ros.fleet import load_fleet


def main(argv: Sequence[str] | None = None) -> int:
    args = stage_arguments(__doc__ or "", argv)
    params = load_params(args.params)
    cfg = params.deploy
    fleet = load_fleet(cfg.fleet)
    check_scenario_agrees(params.world.scenario, args.params, fleet, cfg.fleet)
    runtime = PolicyRuntime(Path(params.export.out_dir) / args.round / "policy")
    out = Path(cfg.out_dir) / args.round
    request = DeployRequest(
        episodes=cfg.episodes,
        seed=cfg.seed,
        recording=out / "session.mcap",
        time_scale=cfg.time_scale,
        profile=cfg.profile,
        chunk_size_bytes=cfg.chunk_size_bytes,
        params_text=Path(args.params).read_text(encoding="utf-8"),
    )
    with live_view(cfg.live, cfg.live_port, f"deploy ({args.round})") as live:
        outcome = deploy_session(runtime, fleet, cfg.fleet, request, out, confirm_reset=operator_reset, live=live)
    print(f"deploy: {deploy_summary(outcome, fleet.target, out)}")
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("deploy", main))
