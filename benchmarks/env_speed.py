"""Env steps per second for the 3-robot obstacle scenario, against the cost of its physics and rays.

The limit is measured in the same run on the same compiled model: per control step, the MuJoCo
physics substeps (one mj_step call) plus one mj_multiRay call per robot, and nothing else. The
env adds action decoding, noise, scan reduction, odometry, judging and observation building.
Last line: ``ratio=<env/limit> steps_per_s=<env>``.
"""

from __future__ import annotations

import argparse
import os
import time

import mujoco
import numpy as np

from pipeline.sim import parallel_env


def env_rate(steps: int, seed: int) -> float:
    env = parallel_env("obstacles")
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, size=(steps, 3, 2)).astype(np.float32)
    t0 = time.perf_counter()
    for k in range(steps):
        if not env.agents:
            env.reset()
        env.step({a: actions[k, i] for i, a in enumerate(env.agents)})
    return steps / (time.perf_counter() - t0)


def limit_rate(steps: int, seed: int) -> float:
    env = parallel_env("obstacles")
    env.reset(seed=seed)
    world = env.sim.world
    m, d = world.model, world.data
    substeps, n = world.world.substeps, world.n
    beams = world.world.lidar.sim_beams
    vec = np.tile(np.array([1.0, 0.0, 0.0]), beams)
    geomid = np.zeros(beams, dtype=np.int32)
    dist = np.zeros(beams)
    group = world._geomgroup
    bodies = [int(b) for b in world.index.body]
    pnt = np.zeros(3)
    d.ctrl[:] = 0.1
    t0 = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(m, d, nstep=substeps)
        for i in range(n):
            mujoco.mj_multiRay(m, d, pnt, vec, group, 1, bodies[i], geomid, dist, None, beams, 5.0)
    return steps / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=4000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    env_best = max(env_rate(args.steps, r) for r in range(args.repeats))
    limit_best = max(limit_rate(args.steps, r) for r in range(args.repeats))
    print(f"env (3 robots, obstacles): {env_best:.0f} steps/s")
    print(f"limit (physics substeps + lidar rays only): {limit_best:.0f} steps/s")
    print(f"ratio={env_best / limit_best:.3f} steps_per_s={env_best:.0f}")


if __name__ == "__main__":
    main()
