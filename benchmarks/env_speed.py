"""Env steps per second for the 3-robot obstacle scenario, against MuJoCo's own work on the same states.

The limit is what MuJoCo itself spends on the env's own trajectory: every call into MuJoCo that the simulated world
makes (the physics substeps, the kinematics pass the rays read, the lidar rays, the resets) is timed where it is made,
so the limit is the rate the env would have if nothing but MuJoCo took time, on exactly the states the env stepped
through (contacts included). Each repeat steps the env twice from the same seed, once with those timers and once
without (the env's rate); the ratio is MuJoCo's seconds in the first over the env's in the second. MuJoCo's calls
are timed between the env's Python, with the caches that leaves them: MuJoCo alone in a tight loop over the same
states would be a little faster, so the ratio errs on the env's side. The env adds action decoding, the drive's
mapping, the lidar's noise, scan reduction, odometry, the network model, judging and rewards, observation building
and PettingZoo's dicts.

``--profile`` then times those parts too (exclusive times, in a run of its own: the timers cost a little) and prints
where the rest of the step goes.

``--fixed-limit`` also prints the earlier limit: MuJoCo stepping the same model with every robot driven forward
at 0.1 and one ray call per robot, in a run of its own. Its robots end up pushing into the walls, and the contacts
make its physics costlier per step than the env's own trajectory, so it flatters the env; it is printed against the
env's best rate without timers.

Last line: ``ratio=<MuJoCo share> steps_per_s=<env> limit_steps_per_s=<MuJoCo alone on those states>``.
"""

from __future__ import annotations

import argparse
import os
import time
import types
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import mujoco
import numpy as np

import pipeline.sim.world as sim_world
from pipeline.core import judge as core_judge
from pipeline.core import observation as core_observation
from pipeline.sim import env as sim_env
from pipeline.sim import noise as sim_noise
from pipeline.sim import parallel_env

MUJOCO = "MuJoCo (physics, kinematics, rays, resets)"


class Timers:
    """Exclusive seconds per part: a timed call's own time, less the timed calls made inside it."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self._stack: list[float] = []

    def timed(self, label: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def call(*args: Any, **kwargs: Any) -> Any:
            self._stack.append(0.0)
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent = time.perf_counter() - t0
                inner = self._stack.pop()
                self.seconds[label] += spent - inner
                if self._stack:
                    self._stack[-1] += spent

        return call


@contextmanager
def mujoco_timed(timers: Timers) -> Iterator[None]:
    """The simulated world's calls into MuJoCo (`mujoco.mj_*`) timed as one part while the block runs."""
    previous = getattr(sim_world, "mujoco")  # noqa: B009 - the world's module reference, put back below
    proxy = types.SimpleNamespace(**{k: getattr(previous, k) for k in dir(previous) if not k.startswith("__")})
    for name in dir(previous):
        if name.startswith("mj_"):
            setattr(proxy, name, timers.timed(MUJOCO, getattr(previous, name)))
    setattr(sim_world, "mujoco", proxy)  # noqa: B010
    try:
        yield
    finally:
        setattr(sim_world, "mujoco", previous)  # noqa: B010


PARTS: tuple[tuple[Any, str, str], ...] = (
    (sim_env.MultiRobotEnv, "step", "PettingZoo view (dicts, infos)"),
    (sim_env.MultiRobotSim, "step", "episode step (the rest)"),
    (sim_world.SimWorld, "step", "world step (the rest)"),
    (sim_world.SimWorld, "_apply", "drive mapping"),
    (sim_world.SimWorld, "true_ranges", "beam directions (the rays' own time: MuJoCo)"),
    (sim_noise.OdometryDrift, "update", "odometry drift"),
    (sim_env.NetworkedSensors, "receive", "network model"),
    (core_observation.ObservationBuilder, "build", "scan reduction and observation"),
    (core_judge.EpisodeJudge, "step", "judge and rewards"),
)
"""The parts ``--profile`` times (class, method, label); :func:`pipeline.sim.noise.noisy_ranges` is timed as
the lidar's noise."""


@contextmanager
def parts_timed(timers: Timers, env: Any) -> Iterator[None]:
    """The env's parts timed while the block runs (the methods patched on their classes, put back afterwards)."""
    saved = [(cls, name, cls.__dict__[name]) for cls, name, _ in PARTS]
    codec = type(env.sim.codec)
    saved.append((codec, "decode", codec.__dict__["decode"]))
    try:
        for cls, name, label in PARTS:
            setattr(cls, name, timers.timed(label, cls.__dict__[name]))
        setattr(codec, "decode", timers.timed("action decoding", codec.__dict__["decode"]))  # noqa: B010
        noisy = getattr(sim_world, "noisy_ranges")  # noqa: B009 - the name the world calls, patched on its module
        setattr(sim_world, "noisy_ranges", timers.timed("lidar noise", noisy))  # noqa: B010
        try:
            yield
        finally:
            setattr(sim_world, "noisy_ranges", noisy)  # noqa: B010
    finally:
        for cls, name, fn in saved:
            setattr(cls, name, fn)


def run_env(steps: int, seed: int, timers: Timers | None, profile: bool = False) -> float:
    """Seconds for `steps` env steps (random actions, episodes reset as they end); MuJoCo's calls timed into
    `timers` (and the env's parts with `profile`), none where it is None."""
    env = parallel_env("obstacles")
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, size=(steps, 3, 2)).astype(np.float32)
    timing = _nothing() if timers is None else mujoco_timed(timers)
    with timing, parts_timed(timers, env) if profile and timers is not None else _nothing():
        t0 = time.perf_counter()
        for k in range(steps):
            if not env.agents:
                env.reset()
            env.step({a: actions[k, i] for i, a in enumerate(env.agents)})
        return time.perf_counter() - t0


@contextmanager
def _nothing() -> Iterator[None]:
    yield


def fixed_limit_rate(steps: int, seed: int) -> float:
    """The earlier limit: every robot driven forward at ctrl 0.1, the physics substeps and one ray call per robot."""
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
    parser.add_argument("--profile", action="store_true", help="time the env's parts too (a run of its own)")
    parser.add_argument("--fixed-limit", action="store_true", help="also the earlier limit (robots into the walls)")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    runs: list[tuple[float, float, float]] = []  # (share, env steps/s, MuJoCo-only steps/s) per repeat
    for r in range(args.repeats):
        timers = Timers()
        run_env(args.steps, r, timers)
        inside = timers.seconds[MUJOCO]
        total = run_env(args.steps, r, None)  # the same steps without timers: the env's own rate
        runs.append((inside / total, args.steps / total, args.steps / inside))
        print(f"run {r}: env {runs[-1][1]:.0f} steps/s, MuJoCo's calls {inside / args.steps * 1e6:.1f} us of "
              f"{total / args.steps * 1e6:.1f} us per step (share {runs[-1][0]:.3f})")  # fmt: skip
    share, rate, limit = sorted(runs)[len(runs) // 2]  # the median run's own three figures
    print(f"env (3 robots, obstacles): {rate:.0f} steps/s (the median run of {args.repeats})")
    print(f"limit (MuJoCo's own calls on the env's states): {limit:.0f} steps/s")
    if args.fixed_limit:
        fixed = max(fixed_limit_rate(args.steps, r) for r in range(args.repeats))
        best = max(run[1] for run in runs)
        print(f"earlier limit (robots driven into the walls, best of {args.repeats}): {fixed:.0f} steps/s; "
              f"the env's best against it {best / fixed:.3f}")  # fmt: skip
    if args.profile:
        timers = Timers()
        total = run_env(args.steps, 0, timers, profile=True)
        print(f"where a step's {total / args.steps * 1e6:.1f} us go (exclusive, timers included):")
        parts = dict(timers.seconds)
        parts["the loop and the timers themselves"] = total - sum(parts.values())
        for label, seconds in sorted(parts.items(), key=lambda kv: -kv[1]):
            print(f"  {label:46s} {seconds / args.steps * 1e6:7.1f} us  {seconds / total:6.1%}")
    print(f"ratio={share:.3f} steps_per_s={rate:.0f} limit_steps_per_s={limit:.0f}")


if __name__ == "__main__":
    main()
