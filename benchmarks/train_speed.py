"""Training speed per algorithm and mode, against the rate of the simulated worlds alone.

For each algorithm and mode, training runs `--steps` world steps (params.yaml's settings, with updates
from `--learning-starts` transitions on, no periodic evaluations, one torch thread) in the obstacle room;
its rate (world steps per second, summed over the `train.n_envs` parallel worlds, as training counts
them) is set against the env-only limit measured in the same run: the same parallel worlds stepped with
random actions and nothing else. Where the ratio is far below 1 the learner (action inference and
gradient steps) is the bottleneck, not the simulator. Printed per row: steps/s, seconds per 100k steps,
ratio to the limit, and where the time goes (the worlds' step, the learners' action inference, storing
transitions, gradient updates; measured by timing those calls; with world workers "worlds" is the
trainer's wait for them). The worlds are stepped by `--world-workers` processes (params.yaml's
`train.world_workers` by default); the env-only rate is also measured in the trainer's own process,
and their ratio is the workers' speed-up. Each row also gives the updates-only bound: the rate if nothing but
the gradient updates took time (rate / their share), the most a faster simulator or inference could give.
`--settings benchmarks/sweeps/paper.yaml` trains with a sweep's keys (the paper cells' update ratio and SAC's
changes). `--gradient-devices cpu cuda` first times one gradient step of each row's learner alone (params.yaml's
networks and batch, a replay of random transitions) on the CPU (one torch thread) and on a CUDA GPU, with its matrix
products' operations (torch's FlopCounterMode) and their rate against a dense float32 matrix product's on the same
device, the arithmetic limit measured in the same run; then it prints under each training row the updates-only bound
with its gradient steps at the GPU's time (the bound times the steps' CPU/GPU ratio): what moving the learner to the
GPU would give at most; `--gradient-only` stops after those step times. Last line:
``env_only=<steps/s> env_only_1=<steps/s> <algorithm>/<mode>=<steps/s> (ratio <r>) ...``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from pipeline.bench.trials import action_kind, read_settings_file
from pipeline.learn import learners
from pipeline.learn.common.worlds import VecWorlds
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig, load_params, world_config
from pipeline.sim import make_world


def env_only_rate(scenario_name: str, kind: str, n_envs: int, steps: int, seed: int, workers: int = 1) -> float:
    """World steps per second of `n_envs` worlds stepped together (by `workers` processes) with random actions."""
    params = load_params()
    world_map = merge(to_mapping(params.world), {"scenario": scenario_name, "actions": {"kind": kind}})
    scenario, world = make_world(world=world_config(world_map))
    with VecWorlds(scenario, world, n_envs, seed, workers=workers) as worlds:
        rng = np.random.default_rng(seed)
        worlds.reset()
        n = scenario.n_robots
        rounds = max(1, steps // n_envs)
        if kind == "discrete":
            actions = rng.integers(0, worlds.codec.n_discrete, size=(rounds, n_envs, n))
        else:
            actions = rng.uniform(-1.0, 1.0, size=(rounds, n_envs, n, 2)).astype(np.float32)
        t0 = time.perf_counter()
        for k in range(rounds):
            worlds.step(actions[k])
        return rounds * n_envs / (time.perf_counter() - t0)


class StepTime(NamedTuple):
    ms: float
    """Milliseconds per gradient step."""
    gflop: float
    """Floating-point operations of one step's matrix products (forward and backward), as torch counts them."""


def _timed_steps(run: Callable[[int], None], steps: int, device: str) -> StepTime:
    """The time of one call of ``run(1)`` over `steps` calls after 10 warm-up calls (the device's queue drained
    before each clock reading), and the matrix products' operations of one call (torch's FlopCounterMode)."""
    from torch.utils.flop_counter import FlopCounterMode

    run(10)
    with FlopCounterMode(display=False) as counter:
        run(1)
    t0 = _drained(device)
    run(steps)
    return StepTime(1e3 * (_drained(device) - t0) / steps, counter.get_total_flops() / 1e9)


def _drained(device: str) -> float:
    """The clock once `device`'s queue of work has run (a CUDA GPU runs it asynchronously)."""
    import torch as th

    if device != "cpu":
        th.cuda.synchronize()
    return time.perf_counter()


def dense_gflops(device: str, n: int = 1024, reps: int = 10) -> float:
    """The rate of an (n x n) @ (n x n) float32 matrix product on `device` (one torch thread on the CPU): the
    attainable arithmetic rate the gradient steps are set against."""
    import torch as th

    _device_ready(device)
    th.set_num_threads(1)
    a = th.randn(n, n, device=device)
    b = th.randn(n, n, device=device)
    for _ in range(3):
        a @ b
    t0 = _drained(device)
    for _ in range(reps):
        a @ b
    return 2 * n**3 * reps / (_drained(device) - t0) / 1e9


def _device_ready(device: str) -> None:
    import torch as th

    if device != "cpu" and not th.cuda.is_available():
        raise SystemExit(f"train_speed: --gradient-devices {device}: torch {th.__version__} sees no CUDA GPU here")


def sac_gradient_step(update: str, k: int, steps: int = 200, device: str = "cpu") -> StepTime:
    """One SAC gradient step of `k` learners together, timed and counted (params.yaml's network and batch, one torch
    thread, a replay of random transitions, the networks on `device`): SB3's ``SAC.train`` per learner (`library`)
    or one batched pass."""
    import dataclasses

    import gymnasium
    import torch as th

    _device_ready(device)
    th.set_num_threads(1)
    cfg = load_params().train
    cfg = dataclasses.replace(cfg, algorithm="sac", sac=dataclasses.replace(cfg.sac, update=update))
    obs_space = gymnasium.spaces.Box(-np.inf, np.inf, (21,), np.float32)
    act_space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
    group = learners.build_learners(cfg, obs_space, act_space, 8, k, device=device)
    rng = np.random.default_rng(0)
    n = 2 * cfg.batch_size
    if update == "batched":
        batched = group[0]
        assert isinstance(batched, learners.BatchedSACMember)
        for i in range(k):
            batched.group.add(
                i, rng.normal(size=(n, 21)), rng.normal(size=(n, 21)), rng.uniform(-1, 1, (n, 2)),
                rng.normal(size=n), np.zeros(n),
            )  # fmt: skip

        def run(m: int) -> None:
            batched.group.train(m)
    else:
        for learner in group:
            for _ in range(n):
                learner.model.store(  # type: ignore[union-attr]
                    rng.normal(size=21).astype(np.float32), rng.normal(size=21).astype(np.float32),
                    rng.uniform(-1, 1, 2).astype(np.float32), 0.0, False, False,
                )  # fmt: skip

        def run(m: int) -> None:
            for learner in group:
                learner.model.train(gradient_steps=m, batch_size=cfg.batch_size)  # type: ignore[union-attr]

    return _timed_steps(run, steps, device)


def dqn_gradient_step(k: int, steps: int = 200, device: str = "cpu") -> StepTime:
    """One DQN gradient step of `k` learners, one after another, timed and counted (params.yaml's network, batch,
    dueling heads and prioritized replay, one torch thread, a replay of random transitions, the networks on
    `device`)."""
    import gymnasium
    import torch as th

    _device_ready(device)
    th.set_num_threads(1)
    params = load_params()
    cfg = replace(params.train, algorithm="dqn")
    obs_space = gymnasium.spaces.Box(-np.inf, np.inf, (21,), np.float32)
    act_space = gymnasium.spaces.Discrete(len(params.world.actions.discrete_set))
    group = learners.build_learners(cfg, obs_space, act_space, 8, k, device=device)
    rng = np.random.default_rng(0)
    for learner in group:
        for _ in range(2 * cfg.batch_size):
            learner.model.store(  # type: ignore[union-attr]
                rng.normal(size=21).astype(np.float32), rng.normal(size=21).astype(np.float32),
                np.array(rng.integers(0, act_space.n)), float(rng.normal()), False, False,
            )  # fmt: skip

    def run(m: int) -> None:
        for learner in group:
            learner.model.train(gradient_steps=m, batch_size=cfg.batch_size)  # type: ignore[union-attr]

    return _timed_steps(run, steps, device)


def gradient_step_times(device: str, n_robots: int) -> dict[str, StepTime]:
    """The gradient step on `device` of each training row's learner: independent SAC's batched pass of `n_robots`
    learners, shared SAC's one learner, one DQN learner (independent mode takes `n_robots` of those per step of
    the robots, shared mode one with `n_robots` times the transitions)."""
    dqn = dqn_gradient_step(1, device=device)
    return {
        "sac[batched]/independent": sac_gradient_step("batched", n_robots, device=device),
        "sac[batched]/shared": sac_gradient_step("batched", 1, device=device),
        "dqn/independent": dqn,
        "dqn/shared": dqn,
    }


SPENT: dict[str, float] = defaultdict(float)


def _timed(kind: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            SPENT[kind] += time.perf_counter() - t0

    return wrapper


def instrument() -> None:
    """Time the calls the training loop makes (for the breakdown only)."""
    VecWorlds.step = _timed("worlds", VecWorlds.step)  # type: ignore[method-assign]
    VecWorlds.step_wait = _timed("worlds", VecWorlds.step_wait)  # type: ignore[method-assign]  # overlap's wait
    for cls in (learners.OffPolicyLearner, learners.BatchedSACMember, learners.OnPolicyLearner):
        for name, kind in (("act", "inference"), ("observe", "store"), ("update", "updates")):
            if name in vars(cls):  # inherited methods are timed once, where they are defined
                setattr(cls, name, _timed(kind, getattr(cls, name)))


def train_rate(
    algorithm: str,
    mode: str,
    scenario_name: str,
    steps: int,
    learning_starts: int,
    workers: int,
    out: Path,
    sac_update: str = "batched",
    settings: Sequence[tuple[str, Any]] = (),
    overlap: bool = False,
) -> tuple[float, dict[str, float]]:
    params = load_params()
    kind = action_kind(algorithm)
    world_map = merge(to_mapping(params.world), {"scenario": scenario_name, "actions": {"kind": kind}})
    train_map = to_mapping(params.train)
    for key, value in settings:  # a sweep's settings (keys this script sets itself win below)
        group, _, rest = key.partition(".")
        nested: dict[str, Any] = {}
        node = nested
        *path, leaf = rest.split(".")
        for part in path:
            node = node.setdefault(part, {})
        node[leaf] = value
        if group == "world":
            world_map = merge(world_map, nested)
        elif group == "train":
            train_map = merge(train_map, nested)
        else:
            raise SystemExit(f"train_speed: --settings key {key!r}: only world.* and train.* keys are taken")
    scenario, world = make_world(world=world_config(world_map))
    changes = {
        "algorithm": algorithm,
        "mode": mode,
        "total_steps": steps,
        "learning_starts": learning_starts,
        "torch_threads": 1,
        "world_workers": workers,
        "checkpoint_every_episodes": 1_000_000,
        "selection": {"keep": "last", "every_steps": 0, "stop_at_success": None, "stop_after_convergence": False},
        "convergence": {"stop": False},
        "sac": {"update": sac_update},
        "overlap": overlap,
    }
    cfg = from_mapping(TrainConfig, merge(train_map, changes), "params.yaml (train_speed)")
    SPENT.clear()
    result = train(scenario, world, cfg, out, progress=False)
    shares = {kind: SPENT[kind] / result.wall_s for kind in ("worlds", "inference", "store", "updates")}
    return result.world_steps / result.wall_s, shares


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algorithms", nargs="+", default=["sac", "dqn", "ppo"])
    parser.add_argument("--modes", nargs="+", default=["independent", "shared", "centralized"])
    parser.add_argument("--scenario", default="obstacles")
    parser.add_argument("--steps", type=int, default=12_000, help="world steps per training run")
    parser.add_argument("--learning-starts", type=int, default=1_000, help="transitions before updates (sac, dqn)")
    parser.add_argument("--world-workers", type=int, default=None, help="(default: params.yaml's)")
    parser.add_argument(
        "--sac-updates",
        nargs="+",
        default=["batched", "library"],
        choices=["batched", "library"],
        help="SAC's train.sac.update settings to measure, each a row",
    )
    parser.add_argument(
        "--settings",
        default=None,
        help="a sweep's settings file (benchmarks/sweeps/paper.yaml): its world and train keys for every trial and "
        "per algorithm, but the budget, evaluations and workers, which this script sets",
    )
    parser.add_argument(
        "--gradient-devices",
        nargs="+",
        default=["cpu"],
        choices=["cpu", "cuda"],
        help="where to time the gradient steps alone and the updates-only bound they set (cuda: a CUDA GPU)",
    )
    parser.add_argument(
        "--gradient-only", action="store_true", help="only the gradient steps' rows, no worlds and no training runs"
    )
    parser.add_argument(
        "--overlap",
        nargs="+",
        default=["off"],
        choices=["off", "on"],
        help="train.overlap settings to measure, each a row (on: sac and dqn; the worlds in their process while the "
        "learners update, 'worlds' is then the wait for them)",
    )
    args = parser.parse_args()
    common: list[tuple[str, Any]] = []
    scoped: list[tuple[str, str, Any]] = []
    if args.settings:
        common, scoped = read_settings_file(args.settings)
    steps_ms: dict[str, dict[str, float]] = {}
    for device in args.gradient_devices:
        dense = dense_gflops(device)
        threads = " (one thread)" if device == "cpu" else ""
        print(f"dense float32 matrix product on {device}{threads}: {dense:.0f} GFLOP/s", flush=True)
        times = gradient_step_times(device, 3)
        steps_ms[device] = {label: t.ms for label, t in times.items()}
        for label, t in times.items():
            if label != "dqn/shared":
                name = "dqn" if label.startswith("dqn") else label
                rate = t.gflop / (t.ms / 1e3)
                print(
                    f"gradient step on {device:<4} {name:<26} {t.ms:>7.2f} ms, {1e3 / t.ms:>5.0f} steps/s, "
                    f"{t.gflop:.3f} GFLOP in matrix products: {rate:.1f} GFLOP/s, "
                    f"{100 * rate / dense:.2g} % of the dense rate",
                    flush=True,
                )
    if args.gradient_only:
        return
    n_envs = load_params().train.n_envs
    workers = args.world_workers or load_params().train.world_workers
    single = env_only_rate(args.scenario, "continuous", n_envs, args.steps, 0)
    print(f"env only (continuous actions, {n_envs} worlds, 1 process): {single:.0f} steps/s")
    limits = {
        kind: env_only_rate(args.scenario, kind, n_envs, args.steps, 0, workers) for kind in ("continuous", "discrete")
    }
    for kind, rate in limits.items():
        print(
            f"env only ({kind} actions, {n_envs} worlds, {workers} world workers): {rate:.0f} steps/s, "
            f"{1e5 / rate:.0f} s per 100k steps"
        )
    print(f"world workers' speed-up (continuous): {limits['continuous'] / single:.2f}")
    figures = [f"env_only={limits['continuous']:.0f}", f"env_only_1={single:.0f}"]
    if "sac" in args.algorithms and len(args.sac_updates) == 2:
        for k in (1, 3):
            times = {u: sac_gradient_step(u, k).ms for u in ("library", "batched")}
            print(
                f"SAC gradient step of {k} learner(s) together: library {times['library']:.2f} ms, "
                f"batched {times['batched']:.2f} ms, speed-up {times['library'] / times['batched']:.2f}"
            )
            figures.append(f"sac_step_speedup_{k}={times['library'] / times['batched']:.2f}")
    instrument()
    print(f"{'algorithm/mode':<28} {'steps/s':>8} {'s/100k':>8} {'ratio':>6}   time in: worlds inference store updates")
    with tempfile.TemporaryDirectory() as tmp:
        for algorithm in args.algorithms:
            for mode in args.modes:
                for update, overlap in [
                    (u, o == "on")
                    for u in (args.sac_updates if algorithm == "sac" else ["-"])
                    for o in args.overlap
                    if not (o == "on" and algorithm == "ppo")
                ]:
                    limit = limits[action_kind(algorithm)]
                    rate, shares = train_rate(
                        algorithm,
                        mode,
                        args.scenario,
                        args.steps,
                        args.learning_starts,
                        workers,
                        Path(tmp) / f"{algorithm}-{mode}-{update}-{overlap}",
                        sac_update=update if algorithm == "sac" else "batched",
                        settings=[*common, *[(k, v) for a, k, v in scoped if a == algorithm]],
                        overlap=overlap,
                    )
                    name = f"{algorithm}[{update}]/{mode}" if algorithm == "sac" else f"{algorithm}/{mode}"
                    name += "+overlap" if overlap else ""
                    parts = " ".join(f"{shares[k]:>6.0%}" for k in ("worlds", "inference", "store", "updates"))
                    # the rate if nothing but the gradient updates took time: the bound the learner sets
                    bound = rate / shares["updates"] if shares["updates"] > 0 else float("inf")
                    print(
                        f"{name:<28} {rate:>8.0f} {1e5 / rate:>8.0f} {rate / limit:>6.2f}   {parts}"
                        f"   updates-only bound {bound:.0f} steps/s (rate {rate / bound:.2f} of it)",
                        flush=True,
                    )
                    figures.append(f"{name}={rate:.0f} (ratio {rate / limit:.2f}, updates bound {bound:.0f})")
                    if "cpu" in steps_ms and "cuda" in steps_ms and name in steps_ms["cpu"]:
                        # the same gradient steps, each at the GPU's time: the bound scales by the steps' ratio
                        gpu_bound = bound * steps_ms["cpu"][name] / steps_ms["cuda"][name]
                        print(
                            f"{'':<28} with its gradient steps on cuda: updates-only bound {gpu_bound:.0f} steps/s "
                            f"({gpu_bound / limit:.2f} of the worlds' rate)",
                            flush=True,
                        )
                        figures.append(f"{name}@cuda_bound={gpu_bound:.0f}")
    print(" ".join(figures))


if __name__ == "__main__":
    main()
