"""Batched SAC updates: the SB3 modules see the stacked weights, the networks and log-probabilities are
SB3's, learners do not leak into each other, and the losses learn."""

from __future__ import annotations

import dataclasses

import gymnasium
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.distributions import SquashedDiagGaussianDistribution

from pipeline.learn.learners import BatchedSACMember, OffPolicyLearner, build_learners
from pipeline.learn.sac.batched import BatchedSAC
from pipeline.params import TrainConfig

OBS, ACT = 6, 2
DEVICES = [
    "cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(not th.cuda.is_available(), reason="torch sees no CUDA GPU here")),
]


def _config(**changes: object) -> TrainConfig:
    cfg = TrainConfig(algorithm="sac", net_arch=(32, 32), batch_size=64, buffer_size=5000, learning_rate=0.001)
    return dataclasses.replace(cfg, **changes)  # type: ignore[arg-type]


def _group(k: int, cfg: TrainConfig | None = None, device: str = "cpu") -> list[BatchedSACMember]:
    obs_space = gymnasium.spaces.Box(-np.inf, np.inf, (OBS,), np.float32)
    act_space = gymnasium.spaces.Box(-1.0, 1.0, (ACT,), np.float32)
    learners = build_learners(cfg or _config(), obs_space, act_space, n_streams=4, n_learners=k, device=device)
    assert all(isinstance(learner, BatchedSACMember) for learner in learners)
    return learners  # type: ignore[return-value]


def _fill(group: BatchedSAC, n: int, seed: int, reward_shift: tuple[float, ...] = ()) -> None:
    rng = np.random.default_rng(seed)
    for k in range(group.k):
        obs = rng.normal(size=(n, OBS))
        shift = reward_shift[k] if k < len(reward_shift) else 0.0
        group.add(
            k,
            obs,
            rng.normal(size=(n, OBS)),
            rng.uniform(-1, 1, (n, ACT)),
            rng.normal(size=n) + shift,
            rng.random(n) < 0.1,
        )


def test_library_update_builds_plain_learners():
    cfg = _config()
    cfg = dataclasses.replace(cfg, sac=dataclasses.replace(cfg.sac, update="library"))
    obs_space = gymnasium.spaces.Box(-np.inf, np.inf, (OBS,), np.float32)
    learners = build_learners(cfg, obs_space, gymnasium.spaces.Box(-1.0, 1.0, (ACT,), np.float32), 4, 3)
    assert [type(x) for x in learners] == [OffPolicyLearner] * 3


@pytest.mark.parametrize("device", DEVICES)
def test_sb3_modules_see_every_update_and_compute_the_same_networks(device: str):
    members = _group(3, device=device)
    group = members[0].group
    assert group.device.type == device and group.obs.device.type == device
    before = [{k: v.clone() for k, v in m.model.policy.state_dict().items()} for m in members]
    _fill(group, 300, seed=1)
    group.train(5)
    obs = th.as_tensor(np.random.default_rng(2).normal(size=(3, 10, OBS)), dtype=th.float32, device=device)
    act = th.as_tensor(np.random.default_rng(3).uniform(-1, 1, (3, 10, ACT)), dtype=th.float32, device=device)
    q = group.q_values(obs, act)
    mean = group.actor_mean(obs)
    for k, member in enumerate(members):
        policy = member.model.policy
        after = policy.state_dict()
        for name in ("actor.mu.weight", "actor.log_std.bias", "critic.qf1.2.weight", "critic_target.qf0.0.bias"):
            assert not th.equal(after[name], before[k][name]), name  # trained, and SB3's module shows it
        with th.no_grad():
            q0, q1 = policy.critic(obs[k], act[k])
            sb3_mean = policy.actor(obs[k], deterministic=True)
        th.testing.assert_close(q[k, 0], q0.squeeze(-1))
        th.testing.assert_close(q[k, 1], q1.squeeze(-1))
        th.testing.assert_close(mean[k], sb3_mean)


def test_log_probability_is_sb3s_squashed_gaussian():
    members = _group(2)
    group = members[0].group
    obs = th.as_tensor(np.random.default_rng(4).normal(size=(2, 50, OBS)), dtype=th.float32)
    noise = th.as_tensor(np.random.default_rng(5).normal(size=(2, 50, ACT)), dtype=th.float32)
    with th.no_grad():
        actions, log_prob = group._policy_sample(obs, noise)
    for k, member in enumerate(members):
        actor = member.model.policy.actor
        with th.no_grad():
            mean, log_std, _ = actor.get_action_dist_params(obs[k])
            dist = SquashedDiagGaussianDistribution(ACT).proba_distribution(mean, log_std)
            gaussian = mean + log_std.exp() * noise[k]
            expected = dist.log_prob(th.tanh(gaussian), gaussian)
        th.testing.assert_close(actions[k], th.tanh(gaussian))
        th.testing.assert_close(log_prob[k], expected)


def test_a_learner_trains_on_its_own_transitions_only():
    """Two groups from the same seed, differing only in learner 2's rewards: learner 1 ends bit-identical."""
    results = []
    for shift in (0.0, 5.0):
        members = _group(2)
        _fill(members[0].group, 400, seed=6, reward_shift=(0.0, shift))
        members[0].group.train(30)
        results.append([{k: v.clone() for k, v in m.model.policy.state_dict().items()} for m in members])
    first, second = results
    assert all(th.equal(first[0][k], second[0][k]) for k in first[0])
    assert not all(th.equal(first[1][k], second[1][k]) for k in first[1])


def test_same_seed_same_weights_to_the_bit():
    runs = []
    for _ in range(2):
        members = _group(3)
        _fill(members[0].group, 300, seed=7)
        members[0].group.train(20)
        runs.append([m.model.policy.state_dict() for m in members])
    for a, b in zip(*runs, strict=True):
        assert all(th.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("k", [1, 3])
def test_the_losses_learn_the_best_action_of_a_contextual_bandit(k: int, device: str):
    """Reward -(a - t(s))^2 with every step terminal: each learner's mean action moves to t(s)."""
    members = _group(k, device=device)
    group = members[0].group
    rng = np.random.default_rng(8)
    targets = np.array([[0.6, -0.4], [-0.5, 0.3], [0.2, 0.7]])[:k]
    for member in range(k):
        obs = rng.normal(size=(2000, OBS))
        actions = rng.uniform(-1, 1, (2000, ACT))
        target = np.where(obs[:, :1] > 0, targets[member], -targets[member])
        reward = -np.square(actions - target).sum(axis=1)
        group.add(member, obs, obs, actions, reward, np.ones(2000))
    group.train(1500)
    test_obs = rng.normal(size=(k, 200, OBS))
    mean = group.actor_mean(th.as_tensor(test_obs, dtype=th.float32, device=device)).cpu().numpy()
    for member in range(k):
        want = np.where(test_obs[member, :, :1] > 0, targets[member], -targets[member])
        error = np.abs(mean[member] - want).mean()
        assert error < 0.15, (member, error)


def test_updates_wait_for_every_learner_and_follow_the_update_ratio():
    cfg = _config(learning_starts=10, batch_size=8, updates_per_transition=0.5, train_every_steps=1)
    members = _group(2, cfg)
    group = members[0].group
    from pipeline.learn.common.modes import StreamBatch

    def batch(active: list[bool]) -> StreamBatch:
        n = len(active)
        return StreamBatch(
            next_obs=np.zeros((n, OBS), np.float32),
            reward=np.zeros(n, np.float32),
            active=np.array(active),
            terminated=np.zeros(n, bool),
            truncated=np.zeros(n, bool),
        )

    obs, act = np.zeros((4, OBS), np.float32), np.zeros((4, ACT), np.float32)
    for _ in range(5):  # learner 1: 20 transitions (10 counted), learner 2: 5 (none counted)
        members[0].observe(obs, act, batch([True] * 4))
        members[1].observe(obs, act, batch([True, False, False, False]))
        members[0].update()
        members[1].update()
    assert group.size.tolist() == [20, 5]
    assert group.gradient_steps == 0  # learner 2 has no batch yet
    assert group.credit == pytest.approx(0.5 * 10 / 2)
    for _ in range(3):
        members[1].observe(obs, act, batch([True] * 4))
    members[1].update()
    # learner 2 now has 17 transitions, 7 counted: 0.5 * (10 + 7) / 2 = 4.25 -> 4 steps
    assert group.gradient_steps == 4
    assert group.credit == pytest.approx(0.25)
