"""dvc stage `scripted_eval`: episodes of the scripted go-to-goal controller in the simulated world.

The controller reads heading and the goal vector, so the stage runs the world with the `rich`
observation layout; everything else comes from params.yaml `world`.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline.core.episode import summarize
from pipeline.params import load_params, world_config
from pipeline.policy.scripted import GoToGoalController
from pipeline.rollout.outputs import write_episodes, write_metrics, write_paths_picture
from pipeline.rollout.sim import evaluate
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim
from pipeline.stage import STAGE_TIMES, run_stage, stage_arguments


def main(argv: Sequence[str] | None = None) -> int:
    args = stage_arguments(__doc__ or "", argv, rounds=False)
    params = load_params(args.params)
    cfg = params.scripted_eval
    world = world_config({"observation": "rich"}, base=params.world, source=args.params)
    scenario, world = make_world(world=world)
    sim = MultiRobotSim(scenario, world)
    results = evaluate(sim, GoToGoalController(world.layout(), world.codec()), cfg.episodes, cfg.seed)
    out = Path(cfg.out_dir)
    metrics = summarize(results, prefix="scripted")
    write_metrics(out / "metrics.json", metrics)
    write_episodes(out / "episodes.csv", results)
    write_paths_picture(out / "paths.png", scenario, results)
    print(
        f"scripted_eval: robot success {metrics['scripted/robot_success']:.3f} "
        f"[{metrics['scripted/robot_success_ci_low']:.3f}, {metrics['scripted/robot_success_ci_high']:.3f}], "
        f"team success {metrics['scripted/team_success']:.3f} over {cfg.episodes} episodes -> {out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("scripted_eval", main, STAGE_TIMES))
