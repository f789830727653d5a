"""Why a navigation policy's robots fail: collisions by what was hit and how, timeouts by where they ended.

Runs `--episodes` simulated episodes of a policy at its world values (no randomization) from evaluation
seeds and sorts every robot-episode that failed:

- a collision, by what the body touched first (wall, box or robot), the robot's forward speed then
  (reversing or driving forward) and the bearing of what it hit;
- a timeout, by the free-path distance to the goal at the end and whether the robot was still moving
  in its last 10 s;

then runs the same episodes again with exact odometry (drift 0), which tells how much of the rest is
the goal vector's odometry error rather than the policy; and, with `--max-steps N`, once more with a step
limit of N, which tells how many of the timeouts were only slow: robots that reach their goal later.

    python benchmarks/layout_failures.py --policy models/nominal/policy --episodes 100 --max-steps 800
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline.core.episode import EpisodeResult, summarize
from pipeline.core.judge import goal_fields
from pipeline.core.layouts import draw_layout
from pipeline.core.scenario import Scenario, box_clearance
from pipeline.params import OdometryConfig, RandomizeConfig
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.sim import evaluate
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim
from pipeline.stage import run_stage

COLLISION_GAP_M = 0.02


def _gaps(layout: Scenario, xy: np.ndarray, i: int) -> list[tuple[float, str, np.ndarray | None]]:
    """Robot i's body gaps (m) at positions `xy` (n_robots, 2): (gap, wall | box | robot, centre or None)."""
    radii = layout.radii
    room = layout.room
    gaps: list[tuple[float, str, np.ndarray | None]] = [
        (
            min(xy[i, 0] - room.x_min_m, room.x_max_m - xy[i, 0], xy[i, 1] - room.y_min_m, room.y_max_m - xy[i, 1])
            - radii[i],
            "wall",
            None,
        )
    ]
    gaps += [
        (float(box_clearance(b, xy[i : i + 1])[0]) - radii[i], "box", np.array([b.x_m, b.y_m]))
        for b in layout.obstacles
    ]
    gaps += [
        (float(np.hypot(*(xy[i] - xy[k]))) - radii[i] - radii[k], "robot", xy[k]) for k in range(len(xy)) if k != i
    ]
    return gaps


def first_contact(
    layout: Scenario, trajectory: np.ndarray, i: int, margin_m: float, period_s: float
) -> tuple[str, int, float, float]:
    """(what: wall | box | robot, step, forward speed m/s, bearing of what was hit in degrees, nan for a wall)
    at the first step where robot i's body comes within `margin_m` of something."""
    for t in range(1, len(trajectory)):
        xy = trajectory[t, :, :2]
        gap, what, where = min(_gaps(layout, xy, i), key=lambda g: g[0])
        if gap < margin_m:
            yaw = trajectory[t, i, 2]
            v = (trajectory[t, i, :2] - trajectory[t - 1, i, :2]) / period_s
            forward = float(np.cos(yaw) * v[0] + np.sin(yaw) * v[1])
            bearing = float("nan")
            if where is not None:
                d = where - xy[i]
                bearing = float(np.degrees(np.angle(np.exp(1j * (np.arctan2(d[1], d[0]) - yaw)))))
            return what, t, forward, bearing
    return "unknown", len(trajectory) - 1, float("nan"), float("nan")


STALLED_NEAR_M = 0.5
"""A stalled robot counts as held up by the nearest wall, box or robot within this body gap at the end."""


def sort_failures(
    scenario: Scenario, results: list[EpisodeResult], margin_m: float, period_s: float, random_layouts: bool = True
) -> dict[str, object]:
    """Counts and figures of the failed robot-episodes of `results` (with `random_layouts`, each episode's
    layout drawn from its seed)."""
    hits: Counter[str] = Counter()
    reversing = early = 0
    side = 0
    end_dist: list[float] = []
    stalled = 0
    stalled_at: Counter[str] = Counter()
    for r in results:
        layout = draw_layout(scenario, r.seed) if random_layouts else scenario
        fields = goal_fields(layout)
        for i in np.flatnonzero(r.collided):
            what, step, forward, bearing = first_contact(layout, r.trajectory, int(i), margin_m, period_s)
            hits[what] += 1
            reversing += forward < -0.05
            early += step * period_s <= 3.0
            side += bool(np.isfinite(bearing) and 45 <= abs(bearing) <= 135)
        for i in np.flatnonzero(~r.reached & ~r.collided):
            end_dist.append(float(fields.distance(r.trajectory[-1:, :, :2][0])[i]))
            last = r.trajectory[-round(10.0 / period_s) :, i, :2]
            if float(np.hypot(*np.diff(last, axis=0).T).sum()) < 0.3:
                stalled += 1
                gap, what, _ = min(_gaps(layout, r.trajectory[-1, :, :2], int(i)), key=lambda g: g[0])
                stalled_at[what if gap < STALLED_NEAR_M else "open space"] += 1
    n = sum(len(r.reached) for r in results)
    return {
        "robot_episodes": n,
        "collisions": int(sum(hits.values())),
        "hit": dict(hits),
        "reversing": reversing,
        "in_first_3_s": early,
        "side_on": side,
        "timeouts": len(end_dist),
        "timeouts_within_0_6_m": int(sum(d <= 0.6 for d in end_dist)),
        "timeouts_stalled": stalled,
        "stalled_at": dict(stalled_at),
    }


def later_arrivals(limited: list[EpisodeResult], longer: list[EpisodeResult], limit_s: float) -> dict[str, object]:
    """The same episodes played with the world's step limit (`limited`, `limit_s` seconds) and a longer one:
    how many of the limited run's timeouts reached their goal in the longer run, and when. `agree` counts
    the robot-episodes whose outcome by `limit_s` is the same in both runs (all of them, for a policy and
    world that do not see the step limit)."""
    if [(r.seed, len(r.reached)) for r in limited] != [(r.seed, len(r.reached)) for r in longer]:
        raise ValueError("the two runs must hold the same episodes, in the same order")
    times: list[float] = []
    timeouts = agree = 0
    for short, long in zip(limited, longer, strict=True):
        by_limit = long.reached & (np.nan_to_num(long.time_to_goal_s, nan=np.inf) <= limit_s + 1e-9)
        agree += int(np.sum(by_limit == short.reached))
        for i in np.flatnonzero(~short.reached & ~short.collided):
            timeouts += 1
            if long.reached[i] and not by_limit[i]:
                times.append(float(long.time_to_goal_s[i]))
    return {
        "timeouts": timeouts,
        "reached_later": len(times),
        "later_median_s": float(np.median(times)) if times else float("nan"),
        "agree": agree,
        "robot_episodes": sum(len(r.reached) for r in limited),
    }


def _success(m: dict[str, float]) -> str:
    low, high = m["eval/robot_success_ci_low"], m["eval/robot_success_ci_high"]
    return f"robot success {m['eval/robot_success']:.3f} [{low:.3f}, {high:.3f}]"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policy", type=Path, required=True, help="an exported policy folder")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=10000, help="the first evaluation seed")
    parser.add_argument(
        "--scenario", default=None, help="judge in this scenario (the same robots) instead of the policy's own"
    )
    parser.add_argument("--layouts", choices=("random", "fixed"), default=None, help="default: the policy's")
    parser.add_argument(
        "--max-steps",
        type=int,
        default=0,
        help="also play the episodes with this step limit (above the world's): how many timeouts were only slow",
    )
    args = parser.parse_args(argv)
    if args.episodes < 1:
        raise SystemExit("--episodes must be at least 1")

    runtime = PolicyRuntime(args.policy)
    world = replace(runtime.spec.world, randomize=RandomizeConfig())
    if args.scenario is not None:
        world = replace(world, scenario=args.scenario)
    if args.layouts is not None:
        world = replace(world, layouts=args.layouts)
    scenario, world = make_world(world=world)
    if args.max_steps and args.max_steps <= world.max_steps:
        raise SystemExit(f"--max-steps must be above the world's step limit ({world.max_steps}), got {args.max_steps}")
    sim = MultiRobotSim(scenario, world)
    results = evaluate(sim, runtime.actions, args.episodes, args.seed, progress=True)
    m = summarize(results)
    s = sort_failures(scenario, results, world.collision_margin_m, world.control_period_s, sim.random_layouts)
    n = s["robot_episodes"]
    kind = "random" if sim.random_layouts else "fixed"
    print(f"{scenario.name} ({kind} layouts): {args.episodes} episodes, {n} robot-episodes, world values")
    print(_success(m))
    print(
        f"collisions {s['collisions']} ({s['hit']}): reversing {s['reversing']}, in the first 3 s {s['in_first_3_s']}, "
        f"side-on (45-135 deg) {s['side_on']}"
    )
    print(
        f"timeouts {s['timeouts']}: ended within 0.6 m of the goal along the free path {s['timeouts_within_0_6_m']}, "
        f"moved under 0.3 m in the last 10 s {s['timeouts_stalled']} "
        f"(within {STALLED_NEAR_M} m of: {s['stalled_at']})"
    )
    exact = replace(world, odometry=OdometryConfig(drift_per_m=0.0))
    exact_results = evaluate(MultiRobotSim(scenario, exact), runtime.actions, args.episodes, args.seed, progress=True)
    print(
        f"with exact odometry: {_success(summarize(exact_results))} "
        f"(odometry drift {world.odometry.drift_per_m} per m otherwise)"
    )
    if args.max_steps:
        longer = replace(world, max_steps=args.max_steps)
        long_sim = MultiRobotSim(scenario, longer)
        long_results = evaluate(long_sim, runtime.actions, args.episodes, args.seed, progress=True)
        limit_s = world.max_steps * world.control_period_s
        later = later_arrivals(results, long_results, limit_s)
        median = f" (median {later['later_median_s']:.1f} s)" if later["reached_later"] else ""
        print(
            f"with a step limit of {args.max_steps} ({args.max_steps * world.control_period_s:.0f} s): "
            f"{_success(summarize(long_results))}; of the {later['timeouts']} timeouts "
            f"{later['reached_later']} reached the goal later{median}, the limit {limit_s:.0f} s; "
            f"outcomes by {limit_s:.0f} s agree in {later['agree']} of "
            f"{later['robot_episodes']} robot-episodes"
        )
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("layout_failures", main))
