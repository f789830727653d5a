"""The loop's deployment on a busy host: a fixed time scale against ``auto``, every episode counted and marked.

Deploys the exported policy (--policy, the nominal round's) on the bundled twin fleet with the loop's profile
(--profile lab) for --episodes episodes, three times with the same seeds:

- ``quiet``: at --scale (the loop's 3x) on the host as it is;
- ``busy``: at --scale beside --load processes at normal priority: spinning ones (``--load-kind spin``, a CPU load
  of its own: on this 2-core machine, three of them stand for a training and a calibration beside the loop), or
  trainings of the loop's own settings (``--load-kind train``: params.yaml's train section, a second user's loop);
- ``busy-auto``: beside the same load at ``--time-scale auto`` (:mod:`pipeline.rollout.pace`).

Printed per run: episodes, the episodes in which the twin did not keep its clock (marked in episodes.csv, never
dropped), the time scales asked, the least realized, aborted episodes and robot success over every episode with its
95 % interval, and over the episodes the twin kept its clock in. Each run's metrics.json and episodes.csv go to
--out/<run>/ with a run.json naming the command and commit. Last line:
``busy_not_kept=<n> auto_not_kept=<n> busy_success=<rate> auto_success=<rate> quiet_success=<rate>``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from collect_results import ROOT, commit_of  # this folder: the script's own

from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.deployment import DeployRequest, deploy_session
from pipeline.ros.fleet import load_fleet

SPIN = "while True: pass"
LOAD_WORDS = {"spin": "spinning", "train": "trainings of params.yaml's settings"}
TRAIN = """
import sys, tempfile
from dataclasses import replace
from pathlib import Path
from pipeline.learn.trainer import train
from pipeline.params import load_params, round_world
from pipeline.sim import make_world
params = load_params(sys.argv[1])
scenario, world = make_world(world=round_world(params, "nominal", sys.argv[1]))
cfg = replace(params.train, total_steps=10_000_000, seed=int(sys.argv[2]))
with tempfile.TemporaryDirectory() as out:
    train(scenario, world, cfg, Path(out), progress=False)
"""
"""A training of the loop's settings (params.yaml's train section, the nominal world) that runs until killed."""


def load_processes(kind: str, n: int) -> list[subprocess.Popen[bytes]]:
    """`n` processes of CPU load: spinning ones, or trainings of the loop's own settings (one seed each)."""
    if kind == "spin":
        return [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(n)]
    params = str(ROOT / "params.yaml")
    return [
        subprocess.Popen(
            [sys.executable, "-c", TRAIN, params, str(k)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            cwd=ROOT,
            start_new_session=True,  # a training's world workers end with it (stop_load)
        )
        for k in range(n)
    ]


def stop_load(processes: list[subprocess.Popen[bytes]]) -> None:
    """End the load processes and whatever they started (their process groups)."""
    for p in processes:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGKILL) if p.pid == os.getpgid(p.pid) else p.kill()
        p.wait()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, default=Path("models/nominal/policy"))
    parser.add_argument("--fleet", default="twin")
    parser.add_argument("--profile", default="lab")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=20_000)
    parser.add_argument("--scale", type=float, default=3.0)
    parser.add_argument("--load", type=int, default=3, help="processes of load beside the busy runs")
    parser.add_argument(
        "--load-kind",
        choices=("spin", "train"),
        default="spin",
        help="spin: processes that spin; train: trainings of the loop's settings (params.yaml), as a second user's",
    )
    parser.add_argument("--runs", nargs="+", default=["quiet", "busy", "busy-auto"])
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    if not (args.policy / "policy.json").is_file():
        print(f"busy_host: no exported policy at {args.policy} (run `dvc repro` first or pass --policy)")
        return 2
    commit = commit_of(ROOT)  # before this run's outputs change any tracked file
    runtime = PolicyRuntime(args.policy)
    fleet = load_fleet(args.fleet)
    args.out.mkdir(parents=True, exist_ok=True)
    figures: dict[str, dict[str, float]] = {}
    walls: dict[str, float] = {}
    for run in args.runs:
        scale: float | str = "auto" if run.endswith("auto") else args.scale
        load = load_processes(args.load_kind, args.load) if run.startswith("busy") else []
        with tempfile.TemporaryDirectory() as tmp:
            request = DeployRequest(
                episodes=args.episodes,
                seed=args.seed,
                recording=Path(tmp) / "session.mcap",
                time_scale=scale,  # type: ignore[arg-type]  # a number or "auto"
                profile=args.profile,
                progress=False,
            )
            start = time.perf_counter()
            try:
                outcome = deploy_session(runtime, fleet, args.fleet, request, Path(tmp) / "out")
            finally:
                stop_load(load)
            walls[run] = time.perf_counter() - start
            folder = args.out / run
            folder.mkdir(parents=True, exist_ok=True)
            for name in ("metrics.json", "episodes.csv"):
                shutil.copy2(Path(tmp) / "out" / name, folder / name)
        m = outcome.metrics
        figures[run] = m
        kept_rate = m.get("real/robot_success_clock_kept", float("nan"))
        print(
            f"{run:10s} ({scale if isinstance(scale, str) else f'{scale:g}x'}, {len(load)} {args.load_kind}): "
            f"{m['real/episodes']:.0f} episodes, clock not kept in {m['real/clock_not_kept_episodes']:.0f}, "
            f"scales asked {m['real/time_scale_asked_min']:g}-{m['real/time_scale_asked_max']:g}, least realized "
            f"{m['real/time_scale_realized_min']:.2f}; {m['real/aborted_episodes']:.0f} aborted; robot success "
            f"{m['real/robot_success']:.3f} [{m['real/robot_success_ci_low']:.3f}, "
            f"{m['real/robot_success_ci_high']:.3f}] over every episode, {kept_rate:.3f} over the "
            f"{m['real/clock_kept_episodes']:.0f} that kept it; {walls[run]:.0f} s",
            flush=True,
        )
    run_file = {
        "command": "python " + " ".join([str(Path(sys.argv[0]).as_posix()), *sys.argv[1:]]),
        "commit": commit,
        "wall_s": {k: round(v, 1) for k, v in walls.items()},
        "note": f"{args.load} processes ({LOAD_WORDS[args.load_kind]}) at normal priority beside the busy runs",
        "files": sorted(
            str(p.relative_to(args.out)) for p in args.out.rglob("*") if p.is_file() and p.name != "run.json"
        ),
    }
    (args.out / "run.json").write_text(json.dumps(run_file, indent=2) + "\n", encoding="utf-8")

    def get(run: str, key: str) -> float:
        return figures.get(run, {}).get(f"real/{key}", float("nan"))

    print(
        f"busy_not_kept={get('busy', 'clock_not_kept_episodes'):.0f} "
        f"auto_not_kept={get('busy-auto', 'clock_not_kept_episodes'):.0f} "
        f"busy_success={get('busy', 'robot_success'):.3f} auto_success={get('busy-auto', 'robot_success'):.3f} "
        f"quiet_success={get('quiet', 'robot_success'):.3f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
