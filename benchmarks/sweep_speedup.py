"""Speed-up of a training sweep from 1 to 2 Ray workers on this machine.

Runs the same sweep twice into fresh folders (SAC and DQN, independent mode, the empty room, `--seeds`
seeds, `--steps` world steps per trial, `--episodes` evaluation episodes; everything else from
params.yaml): once on a local Ray instance with one worker, once with two. Each trial uses one CPU and
one torch thread. Last line: ``speedup=<wall 1 worker / wall 2 workers> wall_1=<s> wall_2=<s> trials=<n>``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from pipeline.bench.sweep import run_sweep
from pipeline.bench.trials import base_mapping, expand
from pipeline.mappings import merge
from pipeline.params import load_params


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--episodes", type=int, default=20)
    args = parser.parse_args()
    base = merge(base_mapping(load_params()), {"train": {"total_steps": args.steps, "torch_threads": 1}})
    trials = expand(["sac", "dqn"], ["independent"], ["empty"], list(range(args.seeds)))
    walls = {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            start = time.perf_counter()
            outcome = run_sweep(trials, base, Path(tmp) / f"w{workers}", args.episodes, workers=workers)
            walls[workers] = time.perf_counter() - start
            if outcome.failed:
                raise SystemExit(f"sweep_speedup: trials failed: {outcome.failed}")
            print(f"{workers} worker(s): {len(trials)} trials in {walls[workers]:.0f} s", flush=True)
    print(
        f"speedup={walls[1] / walls[2]:.2f} wall_1={walls[1]:.0f} wall_2={walls[2]:.0f} trials={len(trials)} "
        f"steps_per_trial={args.steps}"
    )


if __name__ == "__main__":
    main()
