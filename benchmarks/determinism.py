"""Digests of tiny seeded runs, to show that a change leaves training, export and evaluation bit for bit alone.

``python benchmarks/determinism.py OUT_DIR [--compare DIGESTS.json]``

Trains SAC (shared), DQN (independent) and PPO (centralized) with tiny budgets and seed 7 in the
obstacles room, exports each to ONNX, evaluates 3 recorded episodes in sim, and prints the sha256 of
the weights, the ONNX graph, the episode results (trajectories and episodes.csv) and of every
recorded topic's messages (log time and CDR bytes). Save the printed JSON from one commit and pass
it with ``--compare`` on another: every line says SAME or DIFF. Recordings are compared per topic,
so a change of one message type (e.g. ``/mrl/episode``) shows as that topic alone.
Digests hold on one machine and library set (torch's CPU kernels may differ elsewhere).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import warnings
from pathlib import Path

import numpy as np

from pipeline.bench.tiny_loop import tiny_train_config
from pipeline.learn.checkpoint import load_checkpoint
from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.params import EvalSimConfig, world_config
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.rollout.sim import evaluate_session
from pipeline.sim import make_world

ROOT = Path(__file__).resolve().parents[1]

CELLS = (("sac", "shared"), ("dqn", "independent"), ("ppo", "centralized"))


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def topic_digests(path: Path) -> dict[str, str]:
    """sha256 over (log time, CDR bytes) of each topic's messages, in file order."""
    per: dict[str, hashlib._Hash] = {}
    for m in McapLog(path).raw():
        h = per.setdefault(m.topic, hashlib.sha256())
        h.update(m.log_time_ns.to_bytes(8, "little", signed=True))
        h.update(m.data)
    return {topic: h.hexdigest() for topic, h in sorted(per.items())}


def run_cell(algorithm: str, mode: str, out: Path) -> dict[str, object]:
    kind = "discrete" if algorithm == "dqn" else "continuous"
    world_keys = {"scenario": "obstacles", "n_robots": 2, "observation": "rich", "max_steps": 60}
    scenario, world = make_world(world=world_config({**world_keys, "actions": {"kind": kind}}))
    cfg = tiny_train_config(seed=7, algorithm=algorithm, mode=mode)
    folder = out / f"{algorithm}_{mode}"
    result = train(scenario, world, cfg, folder, progress=False)
    exported = export_policy(result.checkpoint, folder / "policy", golden_observations(scenario, world, 12, seed=3))
    runtime = PolicyRuntime(folder / "policy")
    eval_cfg = EvalSimConfig(episodes=3, seed=11, record=True, out_dir=str(folder / "eval"))
    results, metrics = evaluate_session(scenario, world, runtime, eval_cfg, folder / "eval", progress=False)
    return {
        "weights": load_checkpoint(result.checkpoint).record.weights_sha256,
        "onnx": exported.onnx_sha256,
        "trajectories": _sha(b"".join(np.ascontiguousarray(r.trajectory).tobytes() for r in results)),
        "episodes_csv": _sha((folder / "eval" / "episodes.csv").read_bytes()),
        "metrics": _sha(json.dumps(metrics, sort_keys=True).encode()),
        "recording": topic_digests(folder / "eval" / "session.mcap"),
    }


def compare(a: dict[str, object], b: dict[str, object], prefix: str = "") -> list[str]:
    lines = []
    for key in sorted(set(a) | set(b)):
        x, y = a.get(key), b.get(key)
        if isinstance(x, dict) and isinstance(y, dict):
            lines += compare(x, y, f"{prefix}{key}.")
        else:
            lines.append(f"{prefix}{key} {'SAME' if x == y else 'DIFF'}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--compare", type=Path, help="digests JSON printed by an earlier run")
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    digests = {f"{a}_{m}": run_cell(a, m, args.out_dir) for a, m in CELLS}
    text = json.dumps(digests, indent=1, sort_keys=True)
    (args.out_dir / "digests.json").write_text(text + "\n")
    print(text)
    if args.compare:
        lines = compare(json.loads(args.compare.read_text()), digests)
        print("\n".join(lines))
        print(
            f"same={sum(line.endswith('SAME') for line in lines)} diff={sum(line.endswith('DIFF') for line in lines)}"
        )


if __name__ == "__main__":
    main()
