"""The multi-robot training loop: parallel worlds, learners per mode, curves, convergence, checkpoints."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import stable_baselines3
import torch as th
from stable_baselines3 import PPO
from tqdm import tqdm

from pipeline.core.scenario import Scenario
from pipeline.learn.checkpoint import save_checkpoint
from pipeline.learn.errors import TrainingInterrupted
from pipeline.learn.imitation import ImitationResult, warm_start
from pipeline.learn.learners import build_learners
from pipeline.learn.modes import StreamMap
from pipeline.learn.progress import ConvergenceTracker, LearningCurve
from pipeline.learn.selection import Selector, greedy_policy
from pipeline.learn.worlds import VecWorlds
from pipeline.mappings import to_mapping
from pipeline.params import TrainConfig, WorldConfig

CHECKPOINT_DIR = "checkpoint"
CURVE_FILE = "curve.csv"


@dataclass(frozen=True)
class TrainResult:
    """What a training run produced and how it went."""

    checkpoint: Path
    curve: Path
    world_steps: int
    episodes: int
    converged_at_episode: int | None
    converged_at_steps: int | None
    wall_s: float
    digest: str
    window_success: np.ndarray
    selected_at_steps: int | None = None
    """World steps of the weights in the checkpoint when they were chosen by evaluation (keep: best)."""
    selected_robot_success: float | None = None
    selected_team_success: float | None = None
    imitation: ImitationResult | None = None
    """The warm start's figures (train.imitation.steps > 0)."""

    def metrics(self) -> dict[str, float | None]:
        """Flat ``train/...`` metrics for dvc."""
        out: dict[str, float | None] = {
            "train/world_steps": float(self.world_steps),
            "train/episodes": float(self.episodes),
            "train/converged_at_episode": None
            if self.converged_at_episode is None
            else float(self.converged_at_episode),
            "train/converged_at_steps": None if self.converged_at_steps is None else float(self.converged_at_steps),
            "train/wall_s": round(self.wall_s, 1),
        }
        for i, rate in enumerate(self.window_success):
            out[f"train/robot_{i + 1}_success_window"] = float(rate)
        if self.selected_at_steps is not None:
            out["train/selected_at_steps"] = float(self.selected_at_steps)
            out["train/selected_eval_robot_success"] = self.selected_robot_success
            out["train/selected_eval_team_success"] = self.selected_team_success
        if self.imitation is not None:
            out["train/imitation_world_steps"] = float(self.imitation.world_steps)
            out["train/imitation_samples"] = float(self.imitation.samples)
            out["train/imitation_action_loss"] = self.imitation.action_loss
            out["train/imitation_value_loss"] = self.imitation.value_loss
        return out


def policy_kind(cfg: TrainConfig) -> str:
    """The network the exporter rebuilds: sac_actor, ppo_actor, dqn or dqn_dueling."""
    if cfg.algorithm == "sac":
        return "sac_actor"
    if cfg.algorithm == "ppo":
        return "ppo_actor"
    return "dqn_dueling" if cfg.dqn.dueling else "dqn"


def train(
    scenario: Scenario,
    world: WorldConfig,
    cfg: TrainConfig,
    out_dir: Path,
    progress: bool = True,
    extra_meta: dict[str, Any] | None = None,
    report: Callable[[int, int, float], None] | None = None,
) -> TrainResult:
    """Train `cfg.algorithm` in `cfg.mode` on `scenario`; writes the checkpoint and the learning curve to `out_dir`.

    With `cfg.selection.keep == "best"` the checkpoint holds the weights that did best in the periodic
    deterministic evaluations (see :mod:`pipeline.learn.selection`), else the final ones.
    On KeyboardInterrupt the current weights are checkpointed and TrainingInterrupted is raised.
    `report` is called with (episodes, world steps, windowed robot success) at every checkpoint (progress for
    callers without a terminal, e.g. a sweep's trials).
    """
    th.set_num_threads(cfg.torch_threads)
    start = time.perf_counter()
    worlds = VecWorlds(
        scenario, world, cfg.n_envs, cfg.seed, cfg.start_xy_m, cfg.start_yaw_rad, workers=cfg.world_workers
    )
    try:
        return _train(scenario, world, cfg, out_dir, worlds, start, progress, extra_meta, report)
    finally:
        worlds.close()


def _train(
    scenario: Scenario,
    world: WorldConfig,
    cfg: TrainConfig,
    out_dir: Path,
    worlds: VecWorlds,
    start: float,
    progress: bool,
    extra_meta: dict[str, Any] | None,
    report: Callable[[int, int, float], None] | None,
) -> TrainResult:
    streams = StreamMap(cfg.mode, worlds)
    learners = build_learners(
        cfg, streams.observation_space, streams.action_space, streams.n_streams, streams.n_learners
    )
    tracker = ConvergenceTracker(scenario.n_robots, cfg.convergence.window_episodes, cfg.convergence.success_threshold)
    curve = LearningCurve(out_dir / CURVE_FILE, scenario.robot_names)
    ckpt_dir = out_dir / CHECKPOINT_DIR
    layout = world.layout()
    meta: dict[str, Any] = {
        "algorithm": cfg.algorithm,
        "mode": cfg.mode,
        "policy_kind": policy_kind(cfg),
        "net_arch": list(cfg.net_arch),
        "robots": list(scenario.robot_names),
        "observation": {"layout": layout.name, "n_beams": layout.n_beams, "size": layout.size},
        "actions": to_mapping(world.actions),
        "scenario": to_mapping(scenario),
        "world": to_mapping(world),
        "train": to_mapping(cfg),
        "versions": {"stable_baselines3": stable_baselines3.__version__, "torch": th.__version__},
        **(extra_meta or {}),
    }
    steps = 0
    digest = ""
    selector = Selector(cfg.selection, scenario, world, out_dir)
    models = [learner.model for learner in learners]
    greedy = greedy_policy(
        models, cfg.mode, scenario.n_robots, streams.codec.kind == "discrete", streams.codec.n_discrete
    )
    imitation = None
    if cfg.imitation.steps > 0:  # ppo only (TrainConfig.check)
        imitation = warm_start(worlds, streams, [m for m in models if isinstance(m, PPO)], cfg, progress)
        meta["imitation"] = to_mapping(imitation)
        if selector.enabled:
            selector.offer(0, greedy, models)  # the imitated weights compete for export too

    def checkpoint(interrupted: bool = False, final: bool = False) -> str:
        state = {
            **meta,
            "world_steps": steps,
            "episodes": tracker.episodes,
            "converged_at_episode": tracker.converged_at,
            "interrupted": interrupted,
        }
        weights = [model.policy.state_dict() for model in models]
        if final and selector.best is not None:
            best = selector.best
            state["selection"] = {
                "keep": cfg.selection.keep,
                "evaluations": len(selector.evaluations),
                "best_at_steps": best.world_steps,
                "best_robot_success": best.robot_success,
                "best_team_success": best.team_success,
            }
            if selector.best_state is not None:
                weights = selector.best_state
        return save_checkpoint(ckpt_dir, state, weights)

    converged_steps: int | None = None
    bar = tqdm(
        total=cfg.total_steps,
        desc=f"train {cfg.algorithm}/{cfg.mode}",
        unit="step",
        disable=not progress,
        mininterval=1.0,
    )
    try:
        obs = worlds.reset()
        while steps < cfg.total_steps:
            per_learner = streams.learner_obs(obs)
            actions = [learner.act(o) for learner, o in zip(learners, per_learner, strict=True)]
            result = worlds.step(streams.world_actions(actions))
            batches = streams.learner_batches(result)
            steps += worlds.n_worlds
            for learner, o, a, b in zip(learners, per_learner, actions, batches, strict=True):
                learner.observe(o, a, b)
                learner.set_progress(steps / cfg.total_steps)
                learner.update()
            for record in result.finished:
                tracker.update(record.success)
                curve.add(tracker.episodes, steps, record, float(tracker.rates().mean()))
                if tracker.converged_at == tracker.episodes:
                    converged_steps = steps
                if tracker.episodes % cfg.checkpoint_every_episodes == 0:
                    curve.flush()
                    checkpoint()
                    if report is not None:
                        report(tracker.episodes, steps, float(tracker.rates().mean()))
            evaluated = selector.due(steps)
            good_enough = False
            if evaluated:
                ev = selector.offer(steps, greedy, models)
                stop_at = cfg.selection.stop_at_success
                good_enough = stop_at is not None and ev.robot_success >= stop_at - 1e-12
            if result.finished or evaluated:
                postfix = {"episodes": tracker.episodes, "success": f"{tracker.rates().mean():.2f}"}
                if selector.best is not None:
                    postfix["eval_best"] = f"{selector.best.robot_success:.2f}@{selector.best.world_steps}"
                bar.set_postfix(postfix, refresh=False)
            bar.update(worlds.n_worlds)
            obs = result.obs
            if (cfg.convergence.stop and tracker.converged_at is not None) or good_enough:
                break
        if selector.enabled and (not selector.evaluations or selector.evaluations[-1].world_steps != steps):
            selector.offer(steps, greedy, models)  # the final weights compete too
    except KeyboardInterrupt:
        curve.close()
        selector.close()
        bar.close()
        checkpoint(interrupted=True)
        raise TrainingInterrupted(str(ckpt_dir), steps) from None
    curve.close()
    selector.close()
    bar.close()
    digest = checkpoint(final=True)
    chosen = selector.best if cfg.selection.keep == "best" else None
    return TrainResult(
        checkpoint=ckpt_dir,
        curve=out_dir / CURVE_FILE,
        world_steps=steps,
        episodes=tracker.episodes,
        converged_at_episode=tracker.converged_at,
        converged_at_steps=converged_steps,
        wall_s=time.perf_counter() - start,
        digest=digest,
        window_success=tracker.rates(),
        selected_at_steps=None if chosen is None else chosen.world_steps,
        selected_robot_success=None if chosen is None else chosen.robot_success,
        selected_team_success=None if chosen is None else chosen.team_success,
        imitation=imitation,
    )
