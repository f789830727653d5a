"""The multi-robot training loop: parallel worlds, learners per mode, curves, convergence, checkpoints."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import stable_baselines3
import torch as th
from stable_baselines3 import PPO
from tqdm import tqdm

from pipeline.core.scenario import Scenario
from pipeline.learn.checkpoint import (
    TRAIN_FORMAT,
    ImitationRecord,
    SelectionRecord,
    TrainRecord,
    TrainVersions,
    save_checkpoint,
)
from pipeline.learn.common.modes import StreamMap
from pipeline.learn.common.progress import ConvergenceTracker, LearningCurve
from pipeline.learn.common.worlds import VecWorlds
from pipeline.learn.errors import TrainingInterrupted
from pipeline.learn.imitation import ImitationResult, warm_start
from pipeline.learn.learners import build_learners
from pipeline.learn.selection import Selector, greedy_policy
from pipeline.mappings import to_mapping
from pipeline.params import TrainConfig, WorldConfig
from pipeline.policy.networks import PolicyKind
from pipeline.policy.spec import ObservationInput

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


def policy_kind(cfg: TrainConfig) -> PolicyKind:
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
    round_name: str = "",
    report: Callable[[int, int, float], None] | None = None,
) -> TrainResult:
    """Train `cfg.algorithm` in `cfg.mode` on `scenario`; writes the checkpoint and the learning curve to `out_dir`.

    With `cfg.selection.keep == "best"` the checkpoint holds the weights that did best in the periodic
    deterministic evaluations (see :mod:`pipeline.learn.selection`), else the final ones.
    On KeyboardInterrupt the current weights are checkpointed and TrainingInterrupted is raised.
    `round_name` is the loop's round recorded in train.json (empty outside the loop). `report` is called with
    (episodes, world steps, windowed robot success) at every checkpoint (progress for callers without a terminal,
    e.g. a sweep's trials).
    """
    th.set_num_threads(cfg.torch_threads)
    start = time.perf_counter()
    worlds = VecWorlds(
        scenario,
        world,
        cfg.n_envs,
        cfg.seed,
        cfg.start_xy_m,
        cfg.start_yaw_rad,
        workers=cfg.world_workers,
        remote=cfg.overlap,
    )
    try:
        return _train(scenario, world, cfg, out_dir, worlds, start, progress, round_name, report)
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
    round_name: str,
    report: Callable[[int, int, float], None] | None,
) -> TrainResult:
    run = _TrainingRun(scenario, world, cfg, out_dir, worlds, round_name, report)
    if cfg.imitation.steps > 0:  # ppo only (TrainConfig.check)
        run.warm_start(progress)
    bar = tqdm(
        total=cfg.total_steps,
        desc=f"train {cfg.algorithm}/{cfg.mode}",
        unit="step",
        disable=not progress,
        mininterval=1.0,
    )
    try:
        run.loop(bar)
    except KeyboardInterrupt:
        run.close()
        bar.close()
        run.checkpoint(interrupted=True)
        raise TrainingInterrupted(str(run.ckpt_dir), run.steps) from None
    run.close()
    bar.close()
    digest = run.checkpoint(final=True)
    return run.result(digest, time.perf_counter() - start)


class _TrainingRun:
    """One training: the learners on their streams of the worlds, the convergence tracker and learning curve, the
    periodic selection, and the checkpoint's description."""

    def __init__(
        self,
        scenario: Scenario,
        world: WorldConfig,
        cfg: TrainConfig,
        out_dir: Path,
        worlds: VecWorlds,
        round_name: str,
        report: Callable[[int, int, float], None] | None,
    ) -> None:
        self.cfg, self.worlds, self.out_dir, self.report = cfg, worlds, out_dir, report
        self.streams = StreamMap(cfg.mode, worlds)
        streams = self.streams
        self.learners = build_learners(
            cfg, streams.observation_space, streams.action_space, streams.n_streams, streams.n_learners
        )
        self.tracker = ConvergenceTracker(
            scenario.n_robots, cfg.convergence.window_episodes, cfg.convergence.success_threshold
        )
        self.curve = LearningCurve(out_dir / CURVE_FILE, scenario.robot_names)
        self.ckpt_dir = out_dir / CHECKPOINT_DIR
        self.described = _describe(scenario, world, cfg, round_name)
        self.steps = 0
        self.converged_steps: int | None = None
        self.selector = Selector(cfg.selection, scenario, world, out_dir)
        self.models = [learner.model for learner in self.learners]
        self.greedy = greedy_policy(
            self.models, cfg.mode, scenario.n_robots, streams.codec.kind == "discrete", streams.codec.n_discrete
        )
        self.imitation: ImitationResult | None = None

    def warm_start(self, progress: bool) -> None:
        """Imitate the teacher before the first PPO step; the imitated weights compete for export too."""
        ppo: list[PPO] = [m for m in self.models if isinstance(m, PPO)]
        self.imitation = warm_start(self.worlds, self.streams, ppo, self.cfg, progress)
        self.described = replace(self.described, imitation=ImitationRecord(**to_mapping(self.imitation)))
        if self.selector.enabled:
            self.selector.offer(0, self.greedy, self.models)

    def checkpoint(self, interrupted: bool = False, final: bool = False) -> str:
        """Write the current weights (the final ones: the selected ones where selection keeps the best)."""
        state = replace(
            self.described,
            world_steps=self.steps,
            episodes=self.tracker.episodes,
            converged_at_episode=self.tracker.converged_at,
            interrupted=interrupted,
        )
        weights = [model.policy.state_dict() for model in self.models]
        best = self.selector.best
        if final and best is not None:
            selection = SelectionRecord(
                keep=self.cfg.selection.keep,
                evaluations=len(self.selector.evaluations),
                best_at_steps=best.world_steps,
                best_robot_success=best.robot_success,
                best_team_success=best.team_success,
            )
            state = replace(state, selection=selection)
            if self.selector.best_state is not None:
                weights = self.selector.best_state
        return save_checkpoint(self.ckpt_dir, state, weights)

    def loop(self, bar: tqdm) -> None:
        """Step the worlds until the budget is spent, training converged (where it stops there) or the selection's
        evaluation is good enough; the final weights are evaluated too."""
        cfg, selector = self.cfg, self.selector
        obs = self.worlds.reset()
        while self.steps < cfg.total_steps:
            result = self.step(obs)
            self.count_episodes(result.finished)
            evaluated = selector.due(self.steps)
            good_enough = False
            if evaluated:
                ev = selector.offer(self.steps, self.greedy, self.models)
                stop_at = cfg.selection.stop_at_success
                good_enough = stop_at is not None and ev.robot_success >= stop_at - 1e-12
                if cfg.selection.stop_after_convergence and self.tracker.converged_at is None:
                    good_enough = False
            if result.finished or evaluated:
                self.show(bar)
            bar.update(self.worlds.n_worlds)
            obs = result.obs
            if (cfg.convergence.stop and self.tracker.converged_at is not None) or good_enough:
                break
        if selector.enabled and (not selector.evaluations or selector.evaluations[-1].world_steps != self.steps):
            selector.offer(self.steps, self.greedy, self.models)

    def step(self, obs: Any) -> Any:
        """One step of every world with the learners' actions; each learner observes its batch and updates.

        With `overlap` the worlds step (in their process) while the learners take the gradient steps due so far,
        on the transitions up to the previous step; the step's transitions are stored afterwards."""
        streams = self.streams
        per_learner = streams.learner_obs(obs)
        actions = [learner.act(o) for learner, o in zip(self.learners, per_learner, strict=True)]
        if self.cfg.overlap:
            self.worlds.step_async(streams.world_actions(actions))
            for learner in self.learners:
                learner.set_progress(self.steps / self.cfg.total_steps)
                learner.update()
            result = self.worlds.step_wait()
        else:
            result = self.worlds.step(streams.world_actions(actions))
        batches = streams.learner_batches(result)
        self.steps += self.worlds.n_worlds
        share = self.cfg.share_experience
        for i, (learner, o, a, b) in enumerate(zip(self.learners, per_learner, actions, batches, strict=True)):
            learner.observe(o, a, b)
            if share:  # independent off-policy learners: the other robots' transitions too, in robot order
                for j in range(len(self.learners)):
                    if j != i:
                        learner.observe_other(per_learner[j], actions[j], batches[j], j)  # type: ignore[union-attr]
            if not self.cfg.overlap:
                learner.set_progress(self.steps / self.cfg.total_steps)
                learner.update()
        return result

    def count_episodes(self, finished: Any) -> None:
        """Track convergence and the learning curve; checkpoint (and report) every few episodes."""
        tracker = self.tracker
        for record in finished:
            tracker.update(record.success)
            self.curve.add(tracker.episodes, self.steps, record, float(tracker.rates().mean()))
            if tracker.converged_at == tracker.episodes:
                self.converged_steps = self.steps
            if tracker.episodes % self.cfg.checkpoint_every_episodes == 0:
                self.curve.flush()
                self.checkpoint()
                if self.report is not None:
                    self.report(tracker.episodes, self.steps, float(tracker.rates().mean()))

    def show(self, bar: tqdm) -> None:
        postfix = {"episodes": self.tracker.episodes, "success": f"{self.tracker.rates().mean():.2f}"}
        best = self.selector.best
        if best is not None:
            postfix["eval_best"] = f"{best.robot_success:.2f}@{best.world_steps}"
        bar.set_postfix(postfix, refresh=False)

    def close(self) -> None:
        self.curve.close()
        self.selector.close()

    def result(self, digest: str, wall_s: float) -> TrainResult:
        chosen = self.selector.best if self.cfg.selection.keep == "best" else None
        return TrainResult(
            checkpoint=self.ckpt_dir,
            curve=self.out_dir / CURVE_FILE,
            world_steps=self.steps,
            episodes=self.tracker.episodes,
            converged_at_episode=self.tracker.converged_at,
            converged_at_steps=self.converged_steps,
            wall_s=wall_s,
            digest=digest,
            window_success=self.tracker.rates(),
            selected_at_steps=None if chosen is None else chosen.world_steps,
            selected_robot_success=None if chosen is None else chosen.robot_success,
            selected_team_success=None if chosen is None else chosen.team_success,
            imitation=self.imitation,
        )


def _describe(scenario: Scenario, world: WorldConfig, cfg: TrainConfig, round_name: str) -> TrainRecord:
    """train.json before the first step: what is trained, where and how."""
    layout = world.layout()
    return TrainRecord(
        format=TRAIN_FORMAT,
        algorithm=cfg.algorithm,
        mode=cfg.mode,
        policy_kind=policy_kind(cfg),
        net_arch=tuple(cfg.net_arch),
        robots=tuple(scenario.robot_names),
        observation=ObservationInput(layout=layout.name, n_beams=layout.n_beams, size=layout.size),
        actions=world.actions,
        scenario=scenario,
        world=world,
        train=cfg,
        versions=TrainVersions(stable_baselines3=stable_baselines3.__version__, torch=th.__version__),
        world_steps=0,
        episodes=0,
        converged_at_episode=None,
        interrupted=False,
        round=round_name,
    )
