"""Speed-up of a training sweep from 1 to 2 Ray workers on this machine, and on a two-node Ray cluster.

Runs the same sweep three times into fresh folders (SAC and DQN, independent mode, the empty room, `--seeds`
seeds, `--steps` world steps per trial, `--episodes` evaluation episodes; everything else from
params.yaml): on a local Ray instance with one worker, with two, and on a cluster of a head and a worker node
with one CPU each (``ray.cluster_utils.Cluster`` on this machine: real nodes, the driver joins by address, as
on machines of their own but without the network between them). Each trial uses one CPU and one torch thread.
Last line: ``speedup=<wall 1 worker / wall 2 workers> cluster_speedup=<wall 1 worker / wall on the cluster>
wall_1=<s> wall_2=<s> wall_cluster=<s> trials=<n>``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any

from pipeline.bench.sweep import run_sweep
from pipeline.bench.trials import Trial, base_mapping, expand
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
    walls: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            walls[str(workers)] = timed(trials, base, Path(tmp) / f"w{workers}", args.episodes, workers=workers)
            print(f"{workers} worker(s): {len(trials)} trials in {walls[str(workers)]:.0f} s", flush=True)
        from ray.cluster_utils import Cluster

        cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
        try:
            cluster.add_node(num_cpus=1)
            cluster.wait_for_nodes()
            walls["cluster"] = timed(trials, base, Path(tmp) / "cluster", args.episodes, address=cluster.address)
        finally:
            cluster.shutdown()
        print(f"two-node cluster: {len(trials)} trials in {walls['cluster']:.0f} s", flush=True)
    print(
        f"speedup={walls['1'] / walls['2']:.2f} cluster_speedup={walls['1'] / walls['cluster']:.2f} "
        f"wall_1={walls['1']:.0f} wall_2={walls['2']:.0f} wall_cluster={walls['cluster']:.0f} trials={len(trials)} "
        f"steps_per_trial={args.steps}"
    )


def timed(trials: list[Trial], base: dict[str, Any], out: Path, episodes: int, **where: Any) -> float:
    """Wall-clock of the sweep of `trials` (a local Ray with `workers`, or a cluster's `address`)."""
    start = time.perf_counter()
    outcome = run_sweep(trials, base, out, episodes, **where)
    if outcome.failed:
        raise SystemExit(f"sweep_speedup: trials failed: {outcome.failed}")
    return time.perf_counter() - start


if __name__ == "__main__":
    main()
