"""A trained policy of any scenario in sim and on the hardware twin: success with 95 % intervals, and timing.

For an exported policy (`--policy`, trained with `python stages/train.py` on the scenario) it runs:

- the simulator, `--sim-episodes` episodes from evaluation seeds (held out from training), at the policy's
  world values and under its training randomization; for a scenario with `layouts` ranges on held-out
  random layouts and on its own fixed layout;
- a twin deployment over DDS on loopback (`--fleet`, a fleet file of the same scenario, `--profile`,
  `--time-scale`), `--twin-episodes` episodes; for random layouts the twin places robots and boxes at the
  layout drawn from each episode's seed;
- `--scenario S`: both in scenario S instead of the policy's own (the twin only where S is another layout
  draw of the room and robots a random-layout policy was trained in), e.g. held-out uniform layouts for a
  policy trained with boxes on the robots' way;
- the emitter/receiver timing of that deployment from its recorded /mrl/timing (tick jitter p99 and
  cross-robot send skew p99; targets 1 ms and 0.5 ms, meaningful at time scale 1).

It prints one line per run with robot and team success and their Wilson 95 % intervals, the mean time to
goal (to capture, for a pursuit), the training wall-clock from the policy's train_metrics.json, and ends with
``scenario=<name> sim_<key>=<..> twin_<key>=<..> jitter_p99_ms=<..> skew_p99_ms=<..>`` where the key is
robot_success, or team_success for a pursuit (one capture is the team's).
Everything is written under `--out` (session.mcap, episodes.csv and metrics.json per world).

    python benchmarks/scenarios.py --policy models/nominal/policy --profile lab --time-scale 3 --out /tmp/bench
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Literal

import numpy as np
import yaml

from pipeline.analysis.timing import timing_figures
from pipeline.mappings import from_mapping, merge, read_yaml, to_mapping
from pipeline.params import EvalSimConfig, RandomizeConfig
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.deployment import DeployRequest, deploy_session
from pipeline.rollout.sim import evaluate_session
from pipeline.ros.fleet import fleet_path, load_fleet
from pipeline.sim import make_world
from pipeline.stage import run_stage


def _line(label: str, metrics: dict[str, float], prefix: str) -> str:
    def figure(key: str) -> str:
        low, high = metrics[f"{prefix}/{key}_ci_low"], metrics[f"{prefix}/{key}_ci_high"]
        return f"{100 * metrics[f'{prefix}/{key}']:.1f} % [{100 * low:.1f}, {100 * high:.1f}]"

    robots = sorted(
        k.split("/")[1]
        for k in metrics
        if k.startswith(f"{prefix}/robot_")
        and k.endswith("_success")
        and k not in (f"{prefix}/robot_success", f"{prefix}/robot_success_completed")
    )
    per_robot = " ".join(f"{r.removesuffix('_success')}={100 * metrics[f'{prefix}/{r}']:.0f}%" for r in robots)
    return (
        f"{label}: robot success {figure('robot_success')}, team {figure('team_success')} over every episode, "
        f"{metrics[f'{prefix}/episodes']:.0f} episodes ({metrics.get(f'{prefix}/aborted_episodes', 0):.0f} aborted; "
        f"completed only {100 * metrics.get(f'{prefix}/robot_success_completed', float('nan')):.1f} %), "
        f"mean time to goal {metrics.get(f'{prefix}/mean_time_to_goal_s', float('nan')):.1f} s; {per_robot}"
    )


def twin_fleet(path: Path, scenario: str, names: tuple[str, ...], limits: np.ndarray, domain_id: int) -> Path:
    """The bundled twin fleet file, driving `scenario` with its robots at their (v_max, w_max) `limits`."""
    fleet = read_yaml(fleet_path("twin"))
    fleet["scenario"] = scenario
    fleet["network"] = {**fleet["network"], "domain_id": domain_id}
    fleet["robots"] = [
        {"name": name, "namespace": name, "v_max_mps": float(v), "w_max_radps": float(w)}
        for name, (v, w) in zip(names, limits, strict=True)
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(fleet, sort_keys=False))
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policy", type=Path, required=True, help="an exported policy folder (policy.json)")
    parser.add_argument(
        "--fleet",
        default=None,
        help="a fleet file (target: twin) of the policy's scenario; default: the bundled twin fleet with the "
        "scenario's robots at their limits, written to --out",
    )
    parser.add_argument("--domain-id", type=int, default=61, help="DDS domain of the default fleet")
    parser.add_argument("--sim-episodes", type=int, default=200)
    parser.add_argument("--twin-episodes", type=int, default=50, help="0: the simulator only")
    parser.add_argument("--sim-seed", type=int, default=10000)
    parser.add_argument("--twin-seed", type=int, default=20000)
    parser.add_argument("--profile", default="lab", help="the twin's reality profile")
    parser.add_argument("--time-scale", type=float, default=3.0, help="1 for the timing targets")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument(
        "--scenario",
        default=None,
        help="judge the policy in this scenario instead of its own, e.g. the layouts it was not trained on: in the "
        "simulator, and on the twin when the policy was trained on random layouts of the same room and robots",
    )
    args = parser.parse_args()

    runtime = PolicyRuntime(args.policy)
    own = runtime.spec.world
    scenario, world = make_world(world=own if args.scenario is None else replace(own, scenario=args.scenario))
    train_file = args.policy.parent / "train_metrics.json"
    if train_file.exists():
        trained = json.loads(train_file.read_text())
        print(
            f"training: {trained['train/world_steps']:.0f} world steps in {trained['train/wall_s']:.0f} s, "
            f"weights of step {trained.get('train/selected_at_steps', float('nan')):.0f}"
        )

    limits = scenario.speed_limits(world.actions.v_max_mps, world.actions.w_max_radps)
    # a pursuit's capture is the team's: its headline figure is team success
    key = "team_success" if scenario.target is not None else "robot_success"
    lines = []
    runs: list[tuple[str, Literal["random", "fixed"], bool]] = []
    if scenario.layouts is not None and world.layouts == "random":
        runs += [("held-out random layouts", "random", False), ("its fixed layout", "fixed", False)]
        runs += [("held-out random layouts, randomized", "random", True)]
    else:
        runs += [("at the world values", world.layouts, False), ("randomized", world.layouts, True)]
    sim_success = float("nan")
    for label, kind, randomized in runs:
        cfg = from_mapping(
            EvalSimConfig,
            merge(to_mapping(EvalSimConfig()), {"episodes": args.sim_episodes, "seed": args.sim_seed}),
            "command-line options",
        )
        wld = replace(world, layouts=kind)
        if not randomized:
            wld = replace(wld, randomize=RandomizeConfig())
        scen, wld = make_world(world=wld)
        folder = args.out / f"sim_{kind}{'_randomized' if randomized else ''}"
        _, metrics = evaluate_session(scen, wld, runtime, cfg, folder)
        lines.append(_line(f"{scenario.name} sim, {label}", metrics, "eval"))
        print(lines[-1], flush=True)
        if np.isnan(sim_success):
            sim_success = metrics[f"eval/{key}"]
    if args.twin_episodes == 0:
        print(f"scenario={scenario.name} sim_{key}={sim_success:.4f}")
        return 0

    fleet_file = args.fleet or str(
        twin_fleet(args.out / "fleet.yaml", world.scenario, scenario.robot_names, limits, args.domain_id)
    )
    fleet = load_fleet(fleet_file)
    request = DeployRequest(
        episodes=args.twin_episodes,
        seed=args.twin_seed,
        recording=args.out / "twin" / "session.mcap",
        time_scale=args.time_scale,
        profile=args.profile,
    )
    outcome = deploy_session(runtime, fleet, fleet_file, request, args.out / "twin")
    lines.append(_line(f"{scenario.name} twin ({args.profile}, {args.time_scale:g}x)", outcome.metrics, "real"))
    timing = timing_figures(args.out / "twin" / "session.mcap")
    lines.append(
        f"twin timing at {args.time_scale:g}x: tick jitter p99 {timing.tick_jitter_p99_ms:.3f} ms (target 1), "
        f"send skew p99 {timing.skew_p99_ms:.3f} ms (target 0.5), state age p99 {timing.age_p99_ms:.1f} ms"
    )
    print("\n".join(lines))
    print(
        f"scenario={scenario.name} sim_{key}={sim_success:.4f} twin_{key}={outcome.metrics[f'real/{key}']:.4f} "
        f"jitter_p99_ms={timing.tick_jitter_p99_ms:.3f} skew_p99_ms={timing.skew_p99_ms:.3f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("scenarios", main))
