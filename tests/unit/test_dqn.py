"""Dueling Q-network, its policy, and PerDQN's train step (double-Q target, IS weights, priorities, beta)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from gymnasium.wrappers import TimeLimit
from stable_baselines3.common.buffers import NStepReplayBuffer, ReplayBuffer
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.common.vec_env import DummyVecEnv
from stable_baselines3.dqn.policies import DQNPolicy, QNetwork

from pipeline.learn.dqn.model import DuelingDQNPolicy, DuelingQNetwork, PerDQN
from pipeline.learn.dqn.prioritized import PrioritizedReplayBuffer, PrioritizedReplayBufferSamples
from pipeline.learn.errors import PrioritizedReplayError


@pytest.fixture(autouse=True)
def _sb3_logs_in_tmp(tmp_path: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    """SB3's default logger makes a folder of its own in the system's temporary directory on every
    ``_setup_learn``; here it goes to the test's temporary folder instead."""
    monkeypatch.setenv("SB3_LOGDIR", str(tmp_path / "sb3"))


N_CELLS = 6
GOAL = N_CELLS - 1
LEFT, RIGHT = 0, 1


class Corridor(gym.Env[np.ndarray, int]):
    """1-D corridor of N_CELLS cells, one-hot observation; reward 1 on reaching the rightmost cell."""

    observation_space = spaces.Box(0.0, 1.0, shape=(N_CELLS,), dtype=np.float32)
    action_space = spaces.Discrete(2)

    def __init__(self) -> None:
        self.cell = 0

    def _obs(self) -> np.ndarray:
        return np.eye(N_CELLS, dtype=np.float32)[self.cell]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self.cell = int(self.np_random.integers(0, GOAL)) if options is None else int(options["cell"])
        return self._obs(), {}

    def step(self, action):
        self.cell = min(max(self.cell + (1 if int(action) == RIGHT else -1), 0), GOAL)
        reached = self.cell == GOAL
        return self._obs(), float(reached), reached, False, {}


def corridor() -> gym.Env[np.ndarray, int]:
    return TimeLimit(Corridor(), max_episode_steps=20)


def one_hot(cells: list[int]) -> th.Tensor:
    return th.eye(N_CELLS)[cells]


def make_model(**kwargs: Any) -> PerDQN:
    settings: dict[str, Any] = {
        "learning_starts": 0,
        "buffer_size": 64,
        "seed": 0,
        "device": "cpu",
        "policy_kwargs": {"net_arch": [16, 16]},
    }
    settings.update(kwargs)
    policy = settings.pop("policy", "DuelingMlpPolicy")
    return PerDQN(policy, corridor(), **settings)


def fill(buffer: ReplayBuffer, n: int) -> None:
    """n transitions: cell i % GOAL, alternating actions, reward i / n, every fourth one terminal."""
    for i in range(n):
        cell = i % GOAL
        action = i % 2
        nxt = min(max(cell + (1 if action == RIGHT else -1), 0), GOAL)
        obs, next_obs = one_hot([cell]).numpy(), one_hot([nxt]).numpy()
        buffer.add(obs, next_obs, np.array([action]), np.array([i / n]), np.array([i % 4 == 3]), [{}])


def column(values: list[float]) -> th.Tensor:
    return th.tensor(values, dtype=th.float32).reshape(-1, 1)


def fixed_batch(
    cells: list[int],
    actions: list[int],
    next_cells: list[int],
    rewards: list[float],
    dones: list[float],
    weights: list[float] | None = None,
) -> PrioritizedReplayBufferSamples:
    """A hand-made batch over the corridor's one-hot cells; leaf indices 0..B-1, weights 1 by default."""
    return PrioritizedReplayBufferSamples(
        observations=one_hot(cells),
        actions=th.tensor(actions).reshape(-1, 1),
        next_observations=one_hot(next_cells),
        dones=column(dones),
        rewards=column(rewards),
        discounts=None,
        weights=column([1.0] * len(cells) if weights is None else weights),
        indices=np.arange(len(cells)),
    )


@pytest.fixture(autouse=True)
def one_torch_thread() -> Iterator[None]:
    threads = th.get_num_threads()
    th.set_num_threads(1)
    yield
    th.set_num_threads(threads)


# --- DuelingQNetwork and policy ---------------------------------------------------------------------


def make_network(net_arch: list[int] | None = None, n_actions: int = 4) -> DuelingQNetwork:
    th.manual_seed(0)
    obs_space = spaces.Box(-1.0, 1.0, shape=(5,), dtype=np.float32)
    return DuelingQNetwork(obs_space, spaces.Discrete(n_actions), FlattenExtractor(obs_space), 5, net_arch)


def test_aggregate_centres_advantages_per_sample():
    value = th.tensor([[1.0], [-2.0]])
    advantage = th.tensor([[1.0, 2.0, 3.0], [15.0, 5.0, 1.0]])  # per-sample means 2 and 7
    q = DuelingQNetwork.aggregate(value, advantage)
    expected = th.tensor([[0.0, 1.0, 2.0], [6.0, -4.0, -8.0]])
    th.testing.assert_close(q, expected)


def test_forward_is_value_plus_centred_advantage_per_row():
    net = make_network([32, 32])
    obs = th.randn(7, 5) * 3
    value, advantage = net.value_and_advantage(obs)
    assert value.shape == (7, 1) and advantage.shape == (7, 4)
    assert advantage.mean(dim=1).std() > 1e-3  # per-sample means differ, so a batch mean would show
    q = net(obs)
    assert q.shape == (7, 4)
    residual = q - value - advantage + advantage.mean(dim=1, keepdim=True)
    th.testing.assert_close(residual, th.zeros_like(residual), atol=1e-6, rtol=0)
    th.testing.assert_close(q.mean(dim=1, keepdim=True), value, atol=1e-5, rtol=0)


def test_shifting_one_samples_advantages_leaves_every_q_unchanged():
    net = make_network([32])
    obs = th.randn(5, 5)
    q_before = net(obs).detach()
    shift = th.zeros(5, 1)
    shift[2] = 100.0
    handle = net.advantage_head.register_forward_hook(lambda module, inputs, output: output + shift)
    try:
        q_after = net(obs).detach()
    finally:
        handle.remove()
    th.testing.assert_close(q_after, q_before, atol=1e-4, rtol=0)


def test_state_dict_names_and_shapes():
    net = make_network([64, 64], n_actions=3)
    shapes = {key: tuple(value.shape) for key, value in net.state_dict().items()}
    assert shapes == {
        "shared.0.weight": (64, 5),
        "shared.0.bias": (64,),
        "shared.2.weight": (64, 64),
        "shared.2.bias": (64,),
        "value_head.weight": (1, 64),
        "value_head.bias": (1,),
        "advantage_head.weight": (3, 64),
        "advantage_head.bias": (3,),
    }
    empty = make_network([], n_actions=3)
    assert len(empty.shared) == 0
    assert empty.value_head.in_features == 5 and empty(th.zeros(2, 5)).shape == (2, 3)


def test_network_rebuilds_from_its_state_dict_alone():
    net = make_network([64, 64])
    state = {key: value.clone() for key, value in net.state_dict().items()}
    th.manual_seed(123)  # different initial weights
    obs_space = spaces.Box(-1.0, 1.0, shape=(5,), dtype=np.float32)
    rebuilt = DuelingQNetwork(obs_space, spaces.Discrete(4), FlattenExtractor(obs_space), 5, [64, 64])
    rebuilt.load_state_dict(state, strict=True)
    obs = th.randn(6, 5)
    th.testing.assert_close(rebuilt(obs), net(obs))


def test_policy_alias_builds_dueling_networks_and_predicts():
    model = make_model(policy_kwargs={"net_arch": [64, 64]})
    assert type(model.policy) is DuelingDQNPolicy
    assert isinstance(model.q_net, DuelingQNetwork) and isinstance(model.q_net_target, DuelingQNetwork)
    assert model.q_net is not model.q_net_target
    assert sorted(model.policy.state_dict()) == sorted(
        f"{net}.{name}.{param}"
        for net in ("q_net", "q_net_target")
        for name in ("shared.0", "shared.2", "value_head", "advantage_head")
        for param in ("weight", "bias")
    )
    th.testing.assert_close(model.q_net(one_hot([0, 3])), model.q_net_target(one_hot([0, 3])))
    action, _ = model.predict(np.eye(N_CELLS, dtype=np.float32)[:3], deterministic=True)
    assert action.shape == (3,) and set(action.tolist()) <= {LEFT, RIGHT}

    plain = make_model(policy="MlpPolicy")
    assert type(plain.policy) is DQNPolicy and type(plain.q_net) is QNetwork
    assert isinstance(plain.replay_buffer, PrioritizedReplayBuffer)


# --- PerDQN train step ------------------------------------------------------------------------------


def perturb(module: th.nn.Module, seed: int) -> None:
    generator = th.Generator().manual_seed(seed)
    with th.no_grad():
        for param in module.parameters():
            param.add_(th.randn(param.shape, generator=generator) * 0.5)


@pytest.mark.parametrize("double_q", [True, False])
def test_td_target_matches_manual_computation(double_q):
    model = make_model(double_q=double_q, gamma=0.9)
    perturb(model.q_net_target, seed=1)  # the two networks now disagree
    batch = fixed_batch(
        cells=[0, 1, 2, 3, 4],
        actions=[0, 1, 0, 1, 1],
        next_cells=[1, 0, 3, 4, 5],
        rewards=[0.0, 0.5, 0.0, -1.0, 1.0],
        dones=[0, 0, 0, 0, 1],
    )
    with th.no_grad():
        online = model.q_net(batch.next_observations)
        target = model.q_net_target(batch.next_observations)
    rows = range(5)
    if double_q:
        chosen = [target[i, int(online[i].argmax())].item() for i in rows]
    else:
        chosen = [target[i].max().item() for i in rows]
    expected = [batch.rewards[i].item() + 0.9 * (1 - batch.dones[i].item()) * chosen[i] for i in rows]
    np.testing.assert_allclose(model.td_targets(batch).numpy().reshape(-1), expected, rtol=1e-6)
    assert expected[4] == 1.0  # terminal: no bootstrap


def test_double_q_differs_from_max_target_when_networks_disagree():
    model = make_model()
    perturb(model.q_net_target, seed=1)
    cells = list(range(GOAL))
    batch = fixed_batch(cells, [RIGHT] * GOAL, [c + 1 for c in cells], rewards=[0.0] * GOAL, dones=[0] * GOAL)
    double = model.td_targets(batch)
    model.double_q = False
    maximum = model.td_targets(batch)
    assert th.all(double <= maximum + 1e-6) and not th.allclose(double, maximum)


def one_step_update(model: PerDQN, batch: PrioritizedReplayBufferSamples, monkeypatch) -> dict[str, th.Tensor]:
    """Parameter change of one train step on `batch`, from a fixed start."""
    start = {key: value.clone() for key, value in model.policy.state_dict().items()}
    monkeypatch.setattr(model.replay_buffer, "sample", lambda batch_size, env=None: batch)
    model.train(gradient_steps=1, batch_size=len(batch.indices))
    delta = {key: value - start[key] for key, value in model.policy.state_dict().items()}
    model.policy.load_state_dict(start)
    return delta


def test_importance_weights_scale_each_samples_gradient(monkeypatch):
    model = make_model(
        max_grad_norm=1e9, policy_kwargs={"net_arch": [16], "optimizer_class": th.optim.SGD}, learning_rate=0.1
    )
    model._setup_learn(total_timesteps=100)
    fill(model.replay_buffer, 4)
    a = {"cells": [1], "actions": [RIGHT], "next_cells": [2], "rewards": [1.0], "dones": [0.0]}
    b = {"cells": [3], "actions": [LEFT], "next_cells": [2], "rewards": [-5.0], "dones": [0.0]}
    other_b = {"cells": [0], "actions": [RIGHT], "next_cells": [1], "rewards": [7.0], "dones": [1.0]}

    def pair(first: dict, second: dict, weights: list[float]) -> PrioritizedReplayBufferSamples:
        return fixed_batch(**{key: first[key] + second[key] for key in first}, weights=weights)

    with_b = one_step_update(model, pair(a, b, [1.0, 0.0]), monkeypatch)
    with_other = one_step_update(model, pair(a, other_b, [1.0, 0.0]), monkeypatch)
    counted = one_step_update(model, pair(a, b, [1.0, 1.0]), monkeypatch)
    for key in with_b:
        th.testing.assert_close(with_b[key], with_other[key], atol=1e-7, rtol=0)
    assert any(with_b[key].abs().sum() > 0 for key in with_b)
    assert any(not th.allclose(with_b[key], counted[key]) for key in with_b)
    # Halving a weight halves that sample's gradient: weights (0.5, 0) move half as far as (1, 0).
    halved = one_step_update(model, pair(a, b, [0.5, 0.0]), monkeypatch)
    for key in with_b:
        th.testing.assert_close(halved[key] * 2, with_b[key], atol=1e-6, rtol=1e-4)


def test_priorities_become_abs_td_plus_epsilon(monkeypatch):
    model = make_model(per_alpha=0.5, per_epsilon=1e-3, gamma=0.9)
    model._setup_learn(total_timesteps=100)
    buffer = model.replay_buffer
    assert isinstance(buffer, PrioritizedReplayBuffer)
    fill(buffer, 20)
    perturb(model.q_net_target, seed=2)
    sample = buffer.sample
    seen: list[tuple[np.ndarray, np.ndarray]] = []

    def recording_sample(batch_size: int, env=None) -> PrioritizedReplayBufferSamples:
        batch = sample(batch_size, env)
        with th.no_grad():  # the networks as they are before this step's update
            q = th.gather(model.q_net(batch.observations), 1, batch.actions.long())
            next_online = model.q_net(batch.next_observations).argmax(dim=1, keepdim=True)
            next_q = th.gather(model.q_net_target(batch.next_observations), 1, next_online)
            target = batch.rewards + 0.9 * (1 - batch.dones) * next_q
        seen.append((batch.indices.copy(), (target - q).abs().numpy().reshape(-1)))
        return batch

    monkeypatch.setattr(buffer, "sample", recording_sample)
    model.train(gradient_steps=1, batch_size=8)
    ((indices, abs_td),) = seen
    np.testing.assert_allclose(buffer.sum_tree.values(indices), (abs_td + 1e-3) ** 0.5, rtol=1e-5)
    untouched = np.setdiff1d(np.arange(20), indices)
    np.testing.assert_array_equal(buffer.sum_tree.values(untouched), 1.0)  # still the initial max
    logged = model.logger.name_to_value
    assert logged["train/n_updates"] == 1
    assert logged["train/mean_abs_td"] == pytest.approx(abs_td.mean(), rel=1e-5)
    assert {"train/loss", "train/mean_weight", "train/beta"} <= set(logged)


def test_beta_anneals_linearly_over_training_progress():
    model = make_model(per_beta0=0.4, per_beta_final=0.9)
    model._setup_learn(total_timesteps=1000)
    fill(model.replay_buffer, 8)
    assert model.per_beta == pytest.approx(0.4)
    model._update_current_progress_remaining(250, 1000)
    model.train(gradient_steps=1, batch_size=4)
    assert model.replay_buffer.beta == pytest.approx(0.525)
    assert model.logger.name_to_value["train/beta"] == pytest.approx(0.525)
    model._update_current_progress_remaining(1000, 1000)
    model.train(gradient_steps=1, batch_size=4)
    assert model.replay_buffer.beta == pytest.approx(0.9)


def test_beta_reaches_its_final_value_at_the_end_of_learn():
    model = make_model(per_beta0=0.4, per_beta_final=1.0, learning_starts=10, train_freq=1)
    model.learn(total_timesteps=60)
    assert model.replay_buffer.beta == pytest.approx(1.0)
    assert model._n_updates > 0


def test_without_prioritized_replay_weights_are_one(monkeypatch):
    model = make_model(prioritized=False)
    assert type(model.replay_buffer) is ReplayBuffer
    model._setup_learn(total_timesteps=100)
    fill(model.replay_buffer, 8)
    model.train(gradient_steps=2, batch_size=4)
    assert model.logger.name_to_value["train/mean_weight"] == 1.0
    assert "train/beta" not in model.logger.name_to_value

    n_step = make_model(prioritized=False, n_steps=3)
    assert type(n_step.replay_buffer) is NStepReplayBuffer
    n_step._setup_learn(total_timesteps=100)
    fill(n_step.replay_buffer, 8)
    n_step.train(gradient_steps=1, batch_size=4)


@pytest.mark.parametrize(
    ("kwargs", "argument"),
    [
        ({"replay_buffer_class": ReplayBuffer}, "replay_buffer_class"),
        ({"replay_buffer_class": PrioritizedReplayBuffer, "prioritized": False}, "replay_buffer_class"),
        ({"n_steps": 3}, "n_steps"),
        ({"replay_buffer_kwargs": {"alpha": 0.9}}, "replay_buffer_kwargs"),
        ({"per_alpha": -1.0}, "per_alpha"),
        ({"per_beta0": 1.5}, "per_beta0"),
        ({"per_beta_final": -0.1}, "per_beta_final"),
        ({"per_epsilon": 0.0}, "per_epsilon"),
        ({"optimize_memory_usage": True, "replay_buffer_kwargs": {"handle_timeout_termination": False}}, "optimize"),
    ],
)
def test_incompatible_settings_are_refused(kwargs, argument):
    with pytest.raises(PrioritizedReplayError, match=argument):
        make_model(**kwargs)


def test_custom_prioritized_buffer_subclass_gets_the_per_settings():
    class TaggedBuffer(PrioritizedReplayBuffer):
        pass

    model = make_model(replay_buffer_class=TaggedBuffer, per_alpha=0.3, per_beta0=0.2, per_epsilon=1e-4)
    buffer = model.replay_buffer
    assert type(buffer) is TaggedBuffer
    assert (buffer.alpha, buffer.beta, buffer.epsilon) == (0.3, 0.2, 1e-4)


def test_save_and_load_round_trip(tmp_path):
    model = make_model(per_alpha=0.3)
    path = tmp_path / "per_dqn.zip"
    model.save(path)
    loaded = PerDQN.load(path, env=corridor(), device="cpu")
    assert type(loaded.policy) is DuelingDQNPolicy
    assert isinstance(loaded.replay_buffer, PrioritizedReplayBuffer) and loaded.replay_buffer.alpha == 0.3
    obs = one_hot(list(range(N_CELLS)))
    th.testing.assert_close(loaded.q_net(obs), model.q_net(obs))


def test_two_envs_fill_flat_leaves_and_train():
    model = PerDQN(
        "DuelingMlpPolicy",
        DummyVecEnv([corridor, corridor]),
        buffer_size=64,
        learning_starts=10,
        train_freq=1,
        seed=0,
        device="cpu",
        policy_kwargs={"net_arch": [16]},
    )
    buffer = model.replay_buffer
    assert isinstance(buffer, PrioritizedReplayBuffer)
    assert buffer.buffer_size == 32 and buffer.sum_tree.capacity == 64
    model.learn(total_timesteps=60)  # 30 calls to env.step, 2 transitions each
    assert buffer.n_transitions == 60
    assert model._n_updates > 0
    # Leaves past the stored rows were never written; the stored ones moved off the initial 1.0.
    np.testing.assert_array_equal(buffer.sum_tree.values(np.arange(60, 64)), 0.0)
    assert np.any(buffer.sum_tree.values(np.arange(60)) != 1.0)


def test_same_seed_gives_the_same_parameters():
    def run() -> dict[str, th.Tensor]:
        model = make_model(learning_starts=20, train_freq=1, seed=7)
        model.learn(total_timesteps=120)
        return model.policy.state_dict()

    first, second = run(), run()
    for key in first:
        assert th.equal(first[key], second[key]), key


# --- learning ---------------------------------------------------------------------------------------


def greedy_walk(model: PerDQN, start: int) -> int:
    """Steps the greedy policy takes from `start` to the goal (the time limit if it never arrives)."""
    env = corridor()
    obs, _ = env.reset(options={"cell": start})
    for step in range(1, 21):
        action, _ = model.predict(obs, deterministic=True)
        obs, _, terminated, truncated, _ = env.step(int(action))
        if terminated:
            return step
        if truncated:
            break
    return 20


def test_dueling_per_dqn_learns_the_corridor():
    model = PerDQN(
        "DuelingMlpPolicy",
        corridor(),
        learning_rate=1e-3,
        buffer_size=5_000,
        learning_starts=200,
        batch_size=32,
        gamma=0.9,
        train_freq=1,
        target_update_interval=100,
        exploration_fraction=0.4,
        exploration_final_eps=0.05,
        policy_kwargs={"net_arch": [32, 32]},
        seed=0,
        device="cpu",
    )
    model.learn(total_timesteps=2_000)
    q = model.q_net(one_hot(list(range(GOAL)))).detach()
    assert th.all(q[:, RIGHT] > q[:, LEFT]), q
    assert [greedy_walk(model, start) for start in range(GOAL)] == [GOAL - s for s in range(GOAL)]
