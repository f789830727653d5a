"""SAC and dueling-PER DQN in both reference scenarios: convergence, wall-clock and sim success.

For each (algorithm, scenario) it trains with params.yaml's `train` section (the algorithm,
action kind and scenario swapped in, the budget from --steps), exports the policy, evaluates
it for --episodes episodes in the simulated world and prints one table row: episodes to
convergence (every robot over 80 % success for 20 consecutive episodes), world steps and
wall-clock to convergence, total training wall-clock, and robot-/team-level success with 95 %
Wilson intervals. The table is also written as Markdown and CSV to --out.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

from pipeline.config import TrainConfig, load_params, world_config
from pipeline.core.episode import summarize
from pipeline.learn.trainer import train
from pipeline.policy.export import export_policy, golden_observations
from pipeline.policy.runtime import PolicyRuntime
from pipeline.settings import from_mapping, merge, to_mapping
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim
from pipeline.sim.evaluate import evaluate

PAPER = {
    ("sac", "empty"): "91.5 %",
    ("sac", "obstacles"): "92.0 %",
    ("dqn", "empty"): "82.0 %",
    ("dqn", "obstacles"): "76.5 %",
}


def run(algorithm: str, scenario_name: str, steps: int, episodes: int, out: Path, params_path: str) -> dict[str, object]:
    params = load_params(params_path)
    kind = "continuous" if algorithm == "sac" else "discrete"
    world = world_config({"scenario": scenario_name, "actions": {"kind": kind}}, base=params.world)
    scenario, world = make_world(world=world)
    cfg = from_mapping(TrainConfig, merge(to_mapping(params.train), {"algorithm": algorithm, "total_steps": steps}), "<matrix>")
    folder = out / f"{algorithm}_{scenario_name}"
    start = time.perf_counter()
    result = train(scenario, world, cfg, folder / "run")
    wall = time.perf_counter() - start
    export_policy(result.checkpoint, folder / "policy", golden_observations(scenario, world, 32))
    runtime = PolicyRuntime(folder / "policy")
    results = evaluate(MultiRobotSim(scenario, world), runtime.actions, episodes, seed=10_000)
    m = summarize(results, prefix="eval")
    conv_wall = None
    if result.converged_at_steps is not None:
        conv_wall = wall * result.converged_at_steps / max(result.world_steps, 1)
    return {
        "algorithm": algorithm,
        "mode": cfg.mode,
        "scenario": scenario_name,
        "converged_at_episode": result.converged_at_episode,
        "converged_at_steps": result.converged_at_steps,
        "wall_to_convergence_s": None if conv_wall is None else round(conv_wall),
        "train_episodes": result.episodes,
        "train_wall_s": round(wall),
        "robot_success": m["eval/robot_success"],
        "robot_ci": (m["eval/robot_success_ci_low"], m["eval/robot_success_ci_high"]),
        "team_success": m["eval/team_success"],
        "team_ci": (m["eval/team_success_ci_low"], m["eval/team_success_ci_high"]),
        "collision_rate": m["eval/collision_rate"],
        "paper_sim": PAPER[(algorithm, scenario_name)],
    }


def row_text(r: dict[str, object]) -> str:
    rl, rh = r["robot_ci"]  # type: ignore[misc]
    tl, th = r["team_ci"]  # type: ignore[misc]
    conv = r["converged_at_episode"] if r["converged_at_episode"] is not None else "not reached"
    return (
        f"| {r['algorithm']} ({r['mode']}) | {r['scenario']} | {conv} | {r['wall_to_convergence_s'] or '-'} | "
        f"{r['train_episodes']} / {r['train_wall_s']} s | {100 * float(r['robot_success']):.1f} % [{100 * rl:.1f}, {100 * rh:.1f}] | "  # type: ignore[arg-type]
        f"{100 * float(r['team_success']):.1f} % [{100 * tl:.1f}, {100 * th:.1f}] | {r['paper_sim']} |"  # type: ignore[arg-type]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=0, help="training world steps (default: params.yaml train.total_steps)")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--algorithms", nargs="+", default=["sac", "dqn"])
    parser.add_argument("--scenarios", nargs="+", default=["empty", "obstacles"])
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--out", type=Path, default=Path("logs/train_matrix"))
    args = parser.parse_args()
    steps = args.steps or load_params(args.params).train.total_steps
    header = (
        "| algorithm (mode) | scenario | episodes to convergence | wall-clock to convergence (s) | "
        "training episodes / wall-clock | robot success (95 % CI) | team success (95 % CI) | paper sim |\n"
        "|---|---|---|---|---|---|---|---|"
    )
    rows = []
    for algorithm in args.algorithms:
        for scenario in args.scenarios:
            r = run(algorithm, scenario, steps, args.episodes, args.out, args.params)
            rows.append(r)
            print(row_text(r), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    table = header + "\n" + "\n".join(row_text(r) for r in rows) + "\n"
    (args.out / "train_matrix.md").write_text(table)
    with (args.out / "train_matrix.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(table)


if __name__ == "__main__":
    main()
