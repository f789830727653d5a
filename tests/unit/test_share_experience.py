"""Independent learners that share their experience (``train.share_experience``): each robot's network stores every
robot's transitions in its own replay, and takes the gradient steps of its own transitions only."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th

from pipeline.errors import ConfigError
from pipeline.learn.common.worlds import VecWorlds
from pipeline.learn.learners import BatchedSACMember, OffPolicyLearner
from pipeline.learn.sac.batched import BatchedSAC
from pipeline.learn.trainer import _TrainingRun
from pipeline.mappings import from_mapping, merge, to_mapping
from pipeline.params import TrainConfig, world_config
from pipeline.sim import make_world

STEPS = 12
N_WORLDS = 2


def _config(algorithm: str, share: bool) -> TrainConfig:
    return TrainConfig(
        algorithm=algorithm,  # type: ignore[arg-type]
        mode="independent",
        n_envs=N_WORLDS,
        net_arch=(8,),
        batch_size=4,
        buffer_size=500,
        learning_starts=0,
        updates_per_transition=1.0,
        train_every_steps=1,
        share_experience=share,
    )


def _run(tmp_path: Path, cfg: TrainConfig) -> tuple[_TrainingRun, list[np.ndarray], np.ndarray]:
    """STEPS steps of 2 worlds of the obstacle room (30-step episodes); the observations each robot acted on
    (robot, step x world, obs) and its active transitions counted."""
    kind = "discrete" if cfg.algorithm == "dqn" else "continuous"
    scenario, world = make_world(
        world=world_config({"scenario": "obstacles", "max_steps": 30, "actions": {"kind": kind}})
    )
    worlds = VecWorlds(scenario, world, cfg.n_envs, cfg.seed, cfg.start_xy_m, cfg.start_yaw_rad)
    run = _TrainingRun(scenario, world, cfg, tmp_path, worlds, "", None)
    seen: list[list[np.ndarray]] = [[] for _ in range(scenario.n_robots)]
    active = np.zeros(scenario.n_robots, dtype=int)
    try:
        obs = worlds.reset()
        for _ in range(STEPS):
            for i, o in enumerate(run.streams.learner_obs(obs)):
                seen[i].append(o.copy())
            result = run.step(obs)
            active += np.asarray(result.active).sum(axis=0)
            obs = result.obs
    finally:
        worlds.close()
    return run, [np.concatenate(s) for s in seen], active


def _dqn_rows(learner: OffPolicyLearner) -> np.ndarray:
    buffer = learner.model.replay_buffer
    assert buffer is not None
    return buffer.observations[: buffer.size(), 0]


def _sac_rows(learner: BatchedSACMember) -> np.ndarray:
    group: BatchedSAC = learner.group
    return group.obs[learner.index, : int(group.size[learner.index])].numpy()


def _holds(rows: np.ndarray, observations: np.ndarray) -> bool:
    """Every observation is one of the stored rows."""
    return all(np.any(np.all(np.isclose(rows, o[None], atol=0), axis=1)) for o in observations)


@pytest.mark.parametrize("algorithm", ["dqn", "sac"])
def test_each_network_stores_every_robots_transitions_and_steps_for_its_own(tmp_path, algorithm):
    run, seen, active = _run(tmp_path / "shared", _config(algorithm, share=True))
    alone, seen_alone, active_alone = _run(tmp_path / "alone", _config(algorithm, share=False))
    rows = _dqn_rows if algorithm == "dqn" else _sac_rows
    total = int(active.sum())
    for i, learner in enumerate(run.learners):
        stored = rows(learner)  # type: ignore[arg-type]
        assert len(stored) == total  # its own transitions and the others'
        for j in range(len(run.learners)):
            assert _holds(stored, seen[j])  # robot j's observations are in robot i's replay
        own_alone = rows(alone.learners[i])  # type: ignore[arg-type]
        assert len(own_alone) == active_alone[i]
        others = [j for j in range(len(alone.learners)) if j != i]
        assert not any(_holds(own_alone, seen_alone[j][:1]) for j in others)  # without sharing: its own only
    if algorithm == "dqn":
        # one gradient step per own transition (learning_starts 0, every world step an update round): the others'
        # transitions earn none, so the networks take what they take without sharing
        for i, learner in enumerate(run.learners):
            assert learner.model._n_updates + learner._credit == pytest.approx(active[i])  # type: ignore[union-attr]
            assert learner.model._n_updates == active[i]  # type: ignore[union-attr]
    else:
        group = run.learners[0].group  # type: ignore[attr-defined]
        assert group.gradient_steps == pytest.approx(active.sum() / len(run.learners), abs=1)
    # the networks stay their own
    first = [p.detach().clone() for p in run.learners[0].model.policy.parameters()]
    second = list(run.learners[1].model.policy.parameters())
    assert any(not th.equal(a, b) for a, b in zip(first, second, strict=True))


@pytest.mark.parametrize(
    ("changes", "word"),
    [({"mode": "shared"}, "mode shared"), ({"mode": "centralized"}, "mode centralized"), ({"algorithm": "ppo"}, "ppo")],
)
def test_sharing_is_refused_outside_independent_off_policy_learners(changes, word):
    mapping = merge(to_mapping(_config("dqn", share=True)), changes)
    with pytest.raises(ConfigError, match=rf"share_experience.*{word}"):
        from_mapping(TrainConfig, mapping, "params.yaml")
