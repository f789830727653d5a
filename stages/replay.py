"""dvc stage `replay`: each round's policy re-run on its deployment's observations, and the nominal
deployment's commands replayed open loop in the nominal and the calibrated simulator."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline.analysis.replay_report import run_replay, write_replay
from pipeline.params import load_params, round_world
from pipeline.policy.runtime import PolicyRuntime
from pipeline.sim import make_world
from pipeline.stage import ROUNDS, STAGE_TIMES, run_stage, stage_arguments


def main(argv: Sequence[str] | None = None) -> int:
    args = stage_arguments(__doc__ or "", argv, rounds=False)
    params = load_params(args.params)
    worlds = {r: make_world(world=round_world(params, r, args.params))[1] for r in ROUNDS}
    scenario, _ = make_world(world=params.world)
    recordings = {r: Path(params.deploy.out_dir) / r / "session.mcap" for r in ROUNDS}
    policies = {r: PolicyRuntime(Path(params.export.out_dir) / r / "policy") for r in ROUNDS}
    cfg = params.replay
    result = run_replay(
        recordings, policies, scenario, worlds, "nominal", cfg.horizon_s, cfg.max_episodes, cfg.tolerance
    )
    metrics = write_replay(result, "nominal", Path(cfg.out_dir))
    for key, value in sorted(metrics.items()):
        print(f"replay: {key} = {value}")
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("replay", main, STAGE_TIMES))
