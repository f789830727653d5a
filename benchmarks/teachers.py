"""The two controllers PPO's warm start can imitate (`train.imitation.teacher`), on held-out layouts.

Plays `--episodes` simulated episodes from evaluation seeds with each teacher, at the world values of
`--params` (no randomization, the pose from the simulator's truth) in `--scenario`, and prints for each its
robot success with a 95 % Wilson interval, team success, collisions and its own compute per control step.
`scripted` sees what the policy sees; `path` is also told the bearing of the point 1 m along each robot's free
path through the episode's map: what that knowledge is worth is the ceiling a student of it can approach.

    python benchmarks/teachers.py --params params.yaml --scenario obstacles_random --episodes 200
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline.core.episode import summarize
from pipeline.params import RandomizeConfig, load_params
from pipeline.policy.scripted import GoToGoalController, PathFollowingController
from pipeline.rollout.sim import evaluate
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim
from pipeline.stage import run_stage


def teachers(sim: MultiRobotSim) -> dict[str, Callable[[np.ndarray], np.ndarray]]:
    """Each teacher as a policy of `sim`'s robots (the path teacher asks `sim` for its bearings)."""
    scripted = GoToGoalController(sim.layout, sim.codec)
    follower = PathFollowingController(sim.layout, sim.codec)

    def path(obs: np.ndarray) -> np.ndarray:
        return follower(obs, sim.path_bearing(follower.ahead_m), sim.others_in_frame())

    return {"scripted": scripted, "path": path}


def timed(policy: Callable[[np.ndarray], np.ndarray], spent: list[float]) -> Callable[[np.ndarray], np.ndarray]:
    def call(obs: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        out = policy(obs)
        spent.append(time.perf_counter() - t0)
        return out

    return call


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--params", type=Path, default=Path("params.yaml"), help="the world's values come from here")
    parser.add_argument("--scenario", default="obstacles_random", help="a scenario with random layouts, or any")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=10000, help="the first evaluation seed")
    parser.add_argument("--max-steps", type=int, default=0, help="the step limit (default: the world's)")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        raise SystemExit("--episodes must be at least 1")
    if args.max_steps < 0:
        raise SystemExit(f"--max-steps must be at least 1 (0: the world's), got {args.max_steps}")
    world = replace(
        load_params(args.params).world,
        scenario=args.scenario,
        observation="rich",
        observed_pose="ground_truth",
        randomize=RandomizeConfig(),
    )
    if args.max_steps:
        world = replace(world, max_steps=args.max_steps)
    scenario, world = make_world(world=world)
    if world.actions.kind != "continuous":
        raise SystemExit(f"{args.params}: world.actions.kind must be 'continuous' for the path teacher")
    sim = MultiRobotSim(scenario, world)
    kind = "random" if sim.random_layouts else "fixed"
    print(
        f"{scenario.name} ({kind} layouts): {args.episodes} episodes from seed {args.seed}, "
        f"{world.max_steps * world.control_period_s:.0f} s limit, path clearance {world.reward.path_clearance_m} m"
    )
    for name, policy in teachers(sim).items():
        spent: list[float] = []
        results = evaluate(sim, timed(policy, spent), args.episodes, args.seed, progress=True)
        m = summarize(results)
        collided = int(np.concatenate([r.collided for r in results]).sum())
        print(
            f"{name:9s} robot success {m['eval/robot_success']:.3f} "
            f"[{m['eval/robot_success_ci_low']:.3f}, {m['eval/robot_success_ci_high']:.3f}], "
            f"team {m['eval/team_success']:.3f}, collisions {collided}, "
            f"{1000 * float(np.mean(spent)):.2f} ms per control step"
        )
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("teachers", main))
