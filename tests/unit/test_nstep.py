"""n-step transitions: returns summed with the right discounts, windows that end at a terminal step, truncated
tails dropped, streams and sources kept apart, and learners that bootstrap with gamma^n."""

from __future__ import annotations

import dataclasses

import gymnasium
import numpy as np
import pytest
import torch as th

from pipeline.errors import ConfigError
from pipeline.learn.common.modes import StreamBatch
from pipeline.learn.common.nstep import NStepReturns
from pipeline.learn.learners import BatchedSACMember, OffPolicyLearner, build_learners
from pipeline.mappings import from_mapping
from pipeline.params import TrainConfig

G = 0.9


def _batch(rewards, next_obs, active=None, terminated=None, truncated=None) -> StreamBatch:
    n = len(rewards)
    return StreamBatch(
        next_obs=np.asarray(next_obs, dtype=np.float32).reshape(n, -1),
        reward=np.asarray(rewards, dtype=np.float64),
        active=np.ones(n, bool) if active is None else np.asarray(active, bool),
        terminated=np.zeros(n, bool) if terminated is None else np.asarray(terminated, bool),
        truncated=np.zeros(n, bool) if truncated is None else np.asarray(truncated, bool),
    )


def _run(acc: NStepReturns, rewards, terminal_at=None, truncated_at=None):
    """One stream: observations 0, 1, 2, ... (the step index), action 10 + step; the transitions stored."""
    out = []
    for t, r in enumerate(rewards):
        batch = _batch([r], [[t + 1]], terminated=[t == terminal_at], truncated=[t == truncated_at])
        ready = acc.push("own", np.array([[t]], np.float32), np.array([10 + t]), batch)
        out += [
            (int(ready.obs[j, 0]), int(ready.actions[j]), ready.rewards[j], int(ready.next_obs[j, 0]),
             bool(ready.terminated[j]))
            for j in range(len(ready))
        ]  # fmt: skip
    return out


def test_full_windows_sum_n_discounted_rewards_and_bootstrap_from_n_steps_later():
    acc = NStepReturns(3, G)
    stored = _run(acc, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    assert [(o, a, nxt, term) for o, a, _, nxt, term in stored] == [
        (0, 10, 3, False),
        (1, 11, 4, False),
        (2, 12, 5, False),
        (3, 13, 6, False),
    ]
    assert [r for _, _, r, _, _ in stored] == pytest.approx([1 + 2 * G + 3 * G**2, 2 + 3 * G + 4 * G**2,
                                                             3 + 4 * G + 5 * G**2, 4 + 5 * G + 6 * G**2])  # fmt: skip
    assert acc.pending() == 2


def test_a_terminal_step_ends_every_pending_window_there_without_a_bootstrap():
    acc = NStepReturns(3, G)
    stored = _run(acc, [1.0, 2.0, 3.0, 4.0, 10.0], terminal_at=4)
    assert [(o, nxt, term) for o, _, _, nxt, term in stored] == [
        (0, 3, False),
        (1, 4, False),
        (2, 5, True),
        (3, 5, True),
        (4, 5, True),
    ]
    assert [r for _, _, r, _, _ in stored][2:] == pytest.approx([3 + 4 * G + 10 * G**2, 4 + 10 * G, 10.0])
    assert acc.pending() == 0


def test_a_truncated_episode_drops_the_steps_whose_window_reaches_past_its_end():
    acc = NStepReturns(3, G)
    stored = _run(acc, [1.0, 2.0, 3.0, 4.0, 5.0], truncated_at=4)
    # the window of step 2 is complete at the truncation (bootstrapped from the last state); steps 3 and 4 are not
    assert [(o, nxt, term) for o, _, _, nxt, term in stored] == [(0, 3, False), (1, 4, False), (2, 5, False)]
    assert acc.pending() == 0
    # the stream's next episode starts from an empty window
    again = _run(acc, [7.0, 7.0, 7.0])
    assert len(again) == 1 and again[0][2] == pytest.approx(7 * (1 + G + G**2))


def test_one_step_windows_are_the_transitions_as_they_come():
    acc = NStepReturns(1, G)
    stored = _run(acc, [1.0, 2.0, 3.0], terminal_at=2)
    assert stored == [(0, 10, 1.0, 1, False), (1, 11, 2.0, 2, False), (2, 12, 3.0, 3, True)]


def test_streams_and_sources_keep_windows_of_their_own_and_inactive_streams_add_nothing():
    acc = NStepReturns(2, G)
    obs = np.array([[0.0], [100.0], [200.0]], np.float32)
    first = acc.push("own", obs, np.array([0, 1, 2]), _batch([1.0, 2.0, 3.0], obs + 1, active=[True, True, False]))
    other = acc.push(1, obs, np.array([5, 5, 5]), _batch([9.0, 9.0, 9.0], obs + 1))
    assert len(first) == 0 and len(other) == 0 and acc.pending() == 2 + 3
    second = acc.push("own", obs + 1, np.array([0, 1, 2]), _batch([1.0, 2.0, 3.0], obs + 2))
    assert sorted(second.obs[:, 0].tolist()) == [0.0, 100.0]  # stream 2 had no first step: its window has one
    assert second.rewards.tolist() == pytest.approx([1 + G * 1, 2 + G * 2])
    assert acc.pending() == 2 + 1 + 3


def _cfg(algorithm: str, **changes: object) -> TrainConfig:
    cfg = TrainConfig(algorithm=algorithm, net_arch=(16, 16), batch_size=32, buffer_size=1000, learning_starts=0)
    return dataclasses.replace(cfg, **changes)  # type: ignore[arg-type]


def test_a_dqn_learner_stores_n_step_transitions_and_bootstraps_with_gamma_to_the_n():
    cfg = _cfg("dqn", n_step=3, gamma=G)
    space = gymnasium.spaces.Box(-10.0, 10.0, (1,), np.float32)
    (learner,) = build_learners(cfg, space, gymnasium.spaces.Discrete(3), 2, 1)
    assert isinstance(learner, OffPolicyLearner)
    assert learner.model.gamma == pytest.approx(G**3)
    for t in range(4):
        obs = np.array([[t], [50 + t]], np.float32)
        learner.observe(obs, np.array([1, 2]), _batch([1.0, 1.0], obs + 1))
    buffer = learner.model.replay_buffer
    assert buffer is not None and buffer.size() == 4  # two complete windows per stream
    assert sorted(buffer.observations[:4, 0, 0].tolist()) == [0.0, 1.0, 50.0, 51.0]
    assert buffer.rewards[:4, 0] == pytest.approx([1 + G + G**2] * 4)
    assert sorted(buffer.next_observations[:4, 0, 0].tolist()) == [3.0, 4.0, 53.0, 54.0]


def test_batched_sac_bootstraps_with_gamma_to_the_n():
    """Two groups from the same seed and data: gamma 0.9 with n = 2 trains as gamma 0.9**2 with n = 1, to the bit."""
    obs_space = gymnasium.spaces.Box(-np.inf, np.inf, (4,), np.float32)
    act_space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
    weights = []
    for cfg in (_cfg("sac", gamma=G, n_step=2), _cfg("sac", gamma=G**2, n_step=1)):
        members = build_learners(cfg, obs_space, act_space, 2, 2)
        assert isinstance(members[0], BatchedSACMember)
        group = members[0].group
        rng = np.random.default_rng(3)
        for k in range(2):
            group.add(k, rng.normal(size=(200, 4)), rng.normal(size=(200, 4)), rng.uniform(-1, 1, (200, 2)),
                      rng.normal(size=200), rng.random(200) < 0.1)  # fmt: skip
        group.train(10)
        weights.append([m.model.policy.state_dict() for m in members])
    for a, b in zip(*weights, strict=True):
        assert all(th.equal(a[k], b[k]) for k in a)


def test_a_batched_sac_member_stores_only_complete_windows_of_each_source():
    cfg = _cfg("sac", n_step=2, gamma=G, share_experience=True)
    obs_space = gymnasium.spaces.Box(-np.inf, np.inf, (1,), np.float32)
    members = build_learners(cfg, obs_space, gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32), 1, 2)
    first = members[0]
    assert isinstance(first, BatchedSACMember)
    for t in range(3):
        own = np.array([[t]], np.float32)
        first.observe(own, np.zeros((1, 2), np.float32), _batch([1.0], own + 1))
        other = np.array([[100 + t]], np.float32)
        first.observe_other(other, np.ones((1, 2), np.float32), _batch([2.0], other + 1), source=1)
    group = first.group
    assert group.size[0] == 4 and first.model.num_timesteps == 4
    assert sorted(group.obs[0, :4, 0].tolist()) == [0.0, 1.0, 100.0, 101.0]
    assert sorted(group.rewards[0, :4].tolist()) == pytest.approx(sorted([1 + G, 1 + G, 2 + 2 * G, 2 + 2 * G]))


def test_n_step_transitions_are_refused_for_ppo_by_name():
    with pytest.raises(ConfigError, match="n_step"):
        from_mapping(TrainConfig, {"algorithm": "ppo", "n_step": 3}, "params.yaml")
    with pytest.raises(ConfigError, match="n_step"):
        from_mapping(TrainConfig, {"algorithm": "dqn", "n_step": 0}, "params.yaml")
