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
from dataclasses import asdict, dataclass
from pathlib import Path

from pipeline.core.episode import summarize
from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import Params, TrainConfig, load_params, world_config
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.sim import evaluate
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim

PAPER = {
    ("sac", "empty"): "91.5 %",
    ("sac", "obstacles"): "92.0 %",
    ("dqn", "empty"): "82.0 %",
    ("dqn", "obstacles"): "76.5 %",
}


@dataclass(frozen=True)
class Row:
    algorithm: str
    mode: str
    scenario: str
    converged_at_episode: int | None
    converged_at_steps: int | None
    wall_to_convergence_s: float | None
    train_episodes: int
    train_steps: int
    train_wall_s: float
    robot_success: float
    robot_ci: tuple[float, float]
    team_success: float
    team_ci: tuple[float, float]
    collision_rate: float
    paper_sim: str

    def text(self) -> str:
        conv = self.converged_at_episode if self.converged_at_episode is not None else "not reached"
        wall = "-" if self.wall_to_convergence_s is None else f"{self.wall_to_convergence_s:.0f}"
        robot = f"{100 * self.robot_success:.1f} % [{100 * self.robot_ci[0]:.1f}, {100 * self.robot_ci[1]:.1f}]"
        team = f"{100 * self.team_success:.1f} % [{100 * self.team_ci[0]:.1f}, {100 * self.team_ci[1]:.1f}]"
        return (
            f"| {self.algorithm} ({self.mode}) | {self.scenario} | {conv} | {wall} | "
            f"{self.train_episodes} / {self.train_steps} / {self.train_wall_s:.0f} s | "
            f"{robot} | {team} | {self.paper_sim} |"
        )


def run(algorithm: str, scenario_name: str, steps: int, episodes: int, out: Path, params: Params) -> Row:
    kind = "continuous" if algorithm == "sac" else "discrete"
    world = world_config({"scenario": scenario_name, "actions": {"kind": kind}}, base=params.world)
    scenario, world = make_world(world=world)
    changes = {"algorithm": algorithm, "total_steps": steps}
    cfg = from_mapping(TrainConfig, merge(to_mapping(params.train), changes), "<matrix>")
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
    return Row(
        algorithm=algorithm,
        mode=cfg.mode,
        scenario=scenario_name,
        converged_at_episode=result.converged_at_episode,
        converged_at_steps=result.converged_at_steps,
        wall_to_convergence_s=conv_wall,
        train_episodes=result.episodes,
        train_steps=result.world_steps,
        train_wall_s=wall,
        robot_success=m["eval/robot_success"],
        robot_ci=(m["eval/robot_success_ci_low"], m["eval/robot_success_ci_high"]),
        team_success=m["eval/team_success"],
        team_ci=(m["eval/team_success_ci_low"], m["eval/team_success_ci_high"]),
        collision_rate=m["eval/collision_rate"],
        paper_sim=PAPER[(algorithm, scenario_name)],
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--steps",
        nargs="+",
        default=[],
        metavar="ALGO=STEPS",
        help="training world steps per algorithm, e.g. sac=400000",
    )
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--algorithms", nargs="+", default=["sac", "dqn"])
    parser.add_argument("--scenarios", nargs="+", default=["empty", "obstacles"])
    parser.add_argument("--params", default="params.yaml")
    parser.add_argument("--out", type=Path, default=Path("logs/train_matrix"))
    args = parser.parse_args()
    params = load_params(args.params)  # read once: the whole table is made with one set of parameters
    default = params.train.total_steps
    budgets = {k: int(v) for k, _, v in (s.partition("=") for s in args.steps)}
    header = (
        "| algorithm (mode) | scenario | episodes to convergence | wall-clock to convergence (s) | "
        "training episodes / steps / wall-clock | robot success (95 % CI) | team success (95 % CI) | paper sim |\n"
        "|---|---|---|---|---|---|---|---|"
    )
    rows = []
    for algorithm in args.algorithms:
        for scenario in args.scenarios:
            row = run(algorithm, scenario, budgets.get(algorithm, default), args.episodes, args.out, params)
            rows.append(row)
            print(row.text(), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    table = header + "\n" + "\n".join(r.text() for r in rows) + "\n"
    (args.out / "train_matrix.md").write_text(table)
    with (args.out / "train_matrix.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(asdict(rows[0])))
        writer.writeheader()
        writer.writerows(asdict(r) for r in rows)
    print(table)


if __name__ == "__main__":
    main()
