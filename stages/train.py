"""dvc stage `train`: train the configured algorithm and mode in the round's simulated world."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline.learn.trainer import train
from pipeline.params import load_params, round_world
from pipeline.rollout.outputs import write_metrics
from pipeline.sim import make_world
from pipeline.stage import STAGE_TIMES, run_stage, stage_arguments


def main(argv: Sequence[str] | None = None) -> int:
    args = stage_arguments(__doc__ or "", argv)
    params = load_params(args.params)
    scenario, world = make_world(world=round_world(params, args.round, args.params))
    out = Path(params.train.out_dir) / args.round
    result = train(scenario, world, params.train, out, round_name=args.round)
    write_metrics(out / "train_metrics.json", result.metrics())
    converged = result.converged_at_episode
    chosen = (
        f"weights of step {result.selected_at_steps} (evaluation: robot success {result.selected_robot_success:.3f}, "
        f"team {result.selected_team_success:.3f})"
        if result.selected_at_steps is not None
        else "final weights"
    )
    print(
        f"train: {result.episodes} episodes, {result.world_steps} world steps in {result.wall_s:.0f} s; "
        f"converged at episode {converged if converged is not None else '-'}; {chosen} -> {result.checkpoint}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("train", main, STAGE_TIMES))
