"""What each multi-agent mode's learner gets from a training budget, and what centralized mode would need.

For SAC, DQN and PPO in independent, shared and centralized mode, with the paper settings
(`benchmarks/sweeps/paper.yaml` over params.yaml) in the obstacle room, the learners the trainer builds are
built (nothing is trained) and counted: per learner its input and output sizes, its network's parameters,
and per `--budget` world steps (summed over the parallel worlds, as training counts them) the transitions
it stores and the gradient steps it takes (off-policy: updates_per_transition per stored transition; PPO:
epochs x minibatches per rollout). For discrete actions the number of actions its epsilon-greedy exploration
draws from (centralized DQN: every combination of the robots' sets). Printed per row, then the budget at
which centralized mode's learner gets as many transitions and gradient steps per robot decision as shared
mode's does at `--budget`: data accounting, a lower bound on what it needs (its larger input and joint
action space and its summed reward ask for more, not less), not a measured convergence.

Last line: ``budget=<steps> sac_centralized_needs_at_least=<steps> dqn_... ppo_... dqn_joint_actions=<n>``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from pipeline.bench.trials import base_mapping, expand, read_settings_file, scoped_keys, with_settings
from pipeline.learn.common.modes import StreamMap
from pipeline.learn.common.worlds import VecWorlds
from pipeline.learn.learners import build_learner
from pipeline.params import load_params
from pipeline.sim import make_world

ROOT = Path(__file__).resolve().parents[1]
MODES = ("independent", "shared", "centralized")


def parameters(learner: Any) -> int:
    """Trainable parameters of the learner's policy (actor and critics, or the Q network; not target copies)."""
    policy = learner.model.policy
    skip = ("critic_target", "q_net_target")
    return sum(p.numel() for name, p in policy.named_parameters() if not name.startswith(skip))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=int, default=100_000, help="world steps of training (default 100000)")
    parser.add_argument("--settings", type=Path, default=ROOT / "benchmarks" / "sweeps" / "paper.yaml")
    parser.add_argument("--scenario", default="obstacles")
    args = parser.parse_args()

    print(f"{'algorithm':9} {'mode':12} {'learners':>8} {'input':>6} {'output':>6} {'params':>8} "
          f"{'transitions/learner':>19} {'grad steps/learner':>18} {'grad steps/robot decision':>25}")  # fmt: skip
    needs: dict[str, int] = {}
    joint = 0
    settings, scoped = read_settings_file(args.settings)
    base = with_settings(base_mapping(load_params(ROOT / "params.yaml")), settings)
    for algorithm in ("sac", "dqn", "ppo"):
        # the trials a sweep with this settings file makes: their params exactly
        trials = scoped_keys(expand([algorithm], list(MODES), [args.scenario], [0], []), scoped)
        first = trials[0].params(base)
        cfg = first.train
        scenario, world = make_world(world=first.world)
        worlds = VecWorlds(scenario, world, cfg.n_envs, seed=0)
        per_decision: dict[str, float] = {}
        for trial in trials:
            mode = trial.mode
            cfg = trial.params(base).train
            streams = StreamMap(cfg.mode, worlds)
            obs_space = streams.observation_space
            assert isinstance(obs_space, gymnasium.spaces.Box)
            learner = build_learner(cfg, obs_space, streams.action_space, streams.n_streams, seed=0)
            lockstep = args.budget / cfg.n_envs  # world steps are summed over the parallel worlds
            transitions = lockstep * streams.n_streams
            if algorithm == "ppo":
                rollouts = lockstep / cfg.ppo.n_steps
                batch = cfg.ppo.n_steps * streams.n_streams
                grad = rollouts * cfg.ppo.n_epochs * math.ceil(batch / min(cfg.ppo.minibatch_size, batch))
            else:
                grad = transitions * cfg.updates_per_transition
            decisions = args.budget * worlds.n_robots  # robot decisions the learners see in all
            total_grad = grad * streams.n_learners
            per_decision[mode] = total_grad / decisions
            space = streams.action_space
            output = int(space.n) if isinstance(space, gymnasium.spaces.Discrete) else int(np.prod(space.shape or (1,)))
            if algorithm == "dqn" and mode == "centralized":
                joint = output
            size = int(np.prod(obs_space.shape))
            print(f"{algorithm:9} {mode:12} {streams.n_learners:>8} {size:>6} {output:>6} {parameters(learner):>8} "
                  f"{transitions:>19.0f} {grad:>18.0f} {per_decision[mode]:>25.2f}")  # fmt: skip
        worlds.close()
        needs[algorithm] = round(args.budget * per_decision["shared"] / per_decision["centralized"])
    print()
    for algorithm, steps in needs.items():
        print(f"{algorithm}: centralized mode gets shared mode's gradient steps per robot decision at {steps} steps")
    figures = " ".join(f"{a}_centralized_needs_at_least={s}" for a, s in needs.items())
    print(f"budget={args.budget} {figures} dqn_joint_actions={joint}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
