"""Sum tree and prioritized replay buffer: sums, search, sampling proportions, IS weights, SB3 layout."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from scipy import stats

from pipeline.errors import MrlError
from pipeline.learn.dqn.prioritized import PrioritizedReplayBuffer, PrioritizedReplayBufferSamples, SumTree
from pipeline.learn.errors import PrioritizedReplayError

OBS_SPACE = spaces.Box(-10.0, 10.0, shape=(2,), dtype=np.float32)
ACTION_SPACE = spaces.Discrete(3)


def make_buffer(size: int = 8, n_envs: int = 1, **kwargs) -> PrioritizedReplayBuffer:
    return PrioritizedReplayBuffer(size, OBS_SPACE, ACTION_SPACE, device="cpu", n_envs=n_envs, **kwargs)


def add_steps(buffer: PrioritizedReplayBuffer, n_steps: int, start: int = 0, timeouts: bool = False) -> None:
    """Store steps whose observation encodes (step, env): obs = [step, env], reward = step + env / 10."""
    n = buffer.n_envs
    for step in range(start, start + n_steps):
        obs = np.stack([np.full(n, step), np.arange(n)], axis=1).astype(np.float32)
        infos = [{"TimeLimit.truncated": timeouts} for _ in range(n)]
        reward = step + np.arange(n) / 10
        buffer.add(obs, obs + 0.5, np.zeros(n, dtype=np.int64), reward, np.full(n, timeouts), infos)


def chi_square_p_value(counts: np.ndarray, probabilities: np.ndarray) -> float:
    expected = probabilities * counts.sum()
    return float(stats.chisquare(counts, expected).pvalue)


# --- SumTree -----------------------------------------------------------------------------------------


def test_sum_tree_total_min_max_follow_updates():
    tree = SumTree(5)
    assert tree.total == 0.0 and tree.empty
    with pytest.raises(ValueError, match="no priorities"):
        _ = tree.max_priority
    tree.update([0, 1, 2], [1.0, 2.0, 3.0])
    assert tree.total == 6.0
    assert (tree.min_priority, tree.max_priority) == (1.0, 3.0)  # unwritten leaves 3, 4 do not count
    tree.update([1], [0.5])
    assert tree.total == 4.5
    assert (tree.min_priority, tree.max_priority) == (0.5, 3.0)
    tree.update(np.array([2, 4]), 7.0)  # a scalar broadcasts over the indices
    assert tree.total == 1.0 + 0.5 + 7.0 + 7.0
    assert tree.max_priority == 7.0
    np.testing.assert_array_equal(tree.values([0, 1, 2, 3, 4]), [1.0, 0.5, 7.0, 0.0, 7.0])


def test_sum_tree_repeated_indices_keep_the_last_value():
    tree = SumTree(4)
    tree.update([2, 2, 2], [5.0, 1.0, 3.0])
    assert tree.total == 3.0
    assert tree.values([2])[0] == 3.0


def test_sum_tree_find_boundaries():
    tree = SumTree(4)
    tree.update([0, 1, 2, 3], [1.0, 2.0, 0.0, 3.0])  # cumulative: 1, 3, 3, 6
    sums = np.array([0.0, 0.999, 1.0, 2.999, 3.0, 5.999, 6.0, 100.0])
    np.testing.assert_array_equal(tree.find(sums), [0, 0, 1, 1, 3, 3, 3, 3])  # leaf 2 (p = 0) never
    assert tree.find(np.array([[0.5, 1.5], [3.5, 0.1]])).shape == (2, 2)


@pytest.mark.parametrize("capacity", [1, 3, 5, 6, 7, 13, 100])
def test_sum_tree_non_power_of_two_capacity(capacity):
    rng = np.random.default_rng(capacity)
    priorities = rng.uniform(0.1, 2.0, size=capacity)
    tree = SumTree(capacity)
    tree.update(np.arange(capacity), priorities)
    assert tree.total == pytest.approx(priorities.sum())
    assert tree.min_priority == priorities.min() and tree.max_priority == priorities.max()
    cumulative = np.cumsum(priorities)
    lower = np.concatenate([[0.0], cumulative[:-1]])
    # The middle of every leaf's interval maps to that leaf; the very top maps to the last leaf.
    np.testing.assert_array_equal(tree.find((lower + cumulative) / 2), np.arange(capacity))
    found = tree.find(np.array([tree.total, np.nextafter(tree.total, 0.0)]))
    np.testing.assert_array_equal(found, [capacity - 1, capacity - 1])  # never a padding leaf
    with pytest.raises(ValueError, match="leaf indices"):
        tree.update([capacity], [1.0])


def test_sum_tree_sampling_proportions_match_priorities():
    priorities = np.array([1.0, 2.0, 3.0, 4.0, 0.5, 9.5])  # capacity 6: not a power of two
    tree = SumTree(len(priorities))
    tree.update(np.arange(len(priorities)), priorities)
    rng = np.random.default_rng(0)
    leaves = tree.find(rng.uniform(0.0, tree.total, size=40_000))
    counts = np.bincount(leaves, minlength=len(priorities))
    assert chi_square_p_value(counts, priorities / priorities.sum()) > 0.01


def test_sum_tree_overwrite_replaces_old_leaves():
    capacity = 5
    tree = SumTree(capacity)
    for step in range(12):  # wraps around twice, like a ring buffer
        tree.update([step % capacity], [float(step)])
    # Leaves now hold steps 10, 11, 7, 8, 9.
    np.testing.assert_array_equal(tree.values(np.arange(capacity)), [10.0, 11.0, 7.0, 8.0, 9.0])
    assert tree.total == 45.0
    assert (tree.min_priority, tree.max_priority) == (7.0, 11.0)


def test_sum_tree_rejects_bad_input():
    tree = SumTree(3)
    with pytest.raises(ValueError, match="capacity"):
        SumTree(0)
    with pytest.raises(ValueError, match="priorities"):
        tree.update([0], [-1.0])
    with pytest.raises(ValueError, match="priorities"):
        tree.update([0], [np.nan])
    with pytest.raises(ValueError, match="total priority is 0"):
        tree.find([0.0])
    tree.update([0], [1.0])
    with pytest.raises(ValueError, match=">= 0"):
        tree.find([-0.5])


# --- PrioritizedReplayBuffer -------------------------------------------------------------------------


def test_new_transitions_get_the_current_max_priority():
    buffer = make_buffer(8, alpha=0.5)
    add_steps(buffer, 3)
    np.testing.assert_array_equal(buffer.sum_tree.values([0, 1, 2]), [1.0, 1.0, 1.0])  # 1 while empty
    buffer.update_priorities([0, 1, 2], [3.0, 8.0, 0.0])
    eps = buffer.epsilon
    expected = (np.array([3.0, 8.0, 0.0]) + eps) ** 0.5
    np.testing.assert_allclose(buffer.sum_tree.values([0, 1, 2]), expected)
    add_steps(buffer, 1, start=3)
    assert buffer.sum_tree.values([3])[0] == pytest.approx(expected.max())
    buffer.update_priorities([1, 3], [1.0, 1.0])  # the max drops: later transitions follow it down
    add_steps(buffer, 1, start=4)
    assert buffer.sum_tree.values([4])[0] == pytest.approx(expected[0])


@pytest.mark.parametrize("n_envs", [1, 2])
def test_adds_in_a_batch_leave_the_tree_as_adds_one_at_a_time(n_envs):
    one, batched = make_buffer(8, n_envs=n_envs, alpha=0.5), make_buffer(8, n_envs=n_envs, alpha=0.5)
    for buffer in (one, batched):
        with buffer.batch() if buffer is batched else contextlib.nullcontext():
            add_steps(buffer, 3)
        buffer.update_priorities(np.arange(3 * n_envs), np.linspace(0.0, 4.0, 3 * n_envs))
        with buffer.batch() if buffer is batched else contextlib.nullcontext():
            add_steps(buffer, 7, start=3)  # wraps around the 8 rows
    np.testing.assert_array_equal(one.sum_tree._sum, batched.sum_tree._sum)
    np.testing.assert_array_equal(one.sum_tree._min, batched.sum_tree._min)
    np.testing.assert_array_equal(one.sum_tree._max, batched.sum_tree._max)
    np.testing.assert_array_equal(one.observations, batched.observations)


def test_no_sampling_inside_a_batch():
    buffer = make_buffer(8)
    add_steps(buffer, 2)
    with buffer.batch():
        add_steps(buffer, 1, start=2)
        with pytest.raises(RuntimeError, match=r"inside PrioritizedReplayBuffer\.batch"):
            buffer.sample(2)
    assert buffer.sum_tree.values([2])[0] == 1.0


def test_weights_match_the_formula_by_hand():
    alpha, beta, eps = 0.7, 0.5, 1e-6
    buffer = make_buffer(4, alpha=alpha, beta=beta, epsilon=eps)
    add_steps(buffer, 4)
    td = np.array([0.5, 1.0, 2.0, 4.0])
    buffer.update_priorities(np.arange(4), td)
    np.random.seed(3)
    batch = buffer.sample(64)
    assert isinstance(batch, PrioritizedReplayBufferSamples)
    assert batch.weights.shape == (64, 1) and batch.weights.dtype == th.float32
    assert batch.indices.shape == (64,)

    scaled = (td + eps) ** alpha
    probability = scaled / scaled.sum()
    n = 4
    max_weight = (n * probability.min()) ** -beta  # over the whole buffer (Schaul et al. 2016)
    expected = (n * probability[batch.indices]) ** -beta / max_weight
    np.testing.assert_allclose(batch.weights.numpy().reshape(-1), expected, rtol=1e-6)
    assert float(batch.weights.max()) <= 1.0
    # The batch rows are the transitions the indices name (obs[0] is the step).
    np.testing.assert_array_equal(batch.observations[:, 0].numpy(), batch.indices.astype(np.float32))

    buffer.beta = 0.0
    assert np.all(buffer.sample(16).weights.numpy() == 1.0)


def test_stratified_sampling_draws_in_proportion_to_priorities():
    alpha = 0.6
    buffer = make_buffer(6, alpha=alpha)
    add_steps(buffer, 6)
    td = np.array([0.1, 0.2, 0.4, 0.8, 1.6, 3.2])
    buffer.update_priorities(np.arange(6), td)
    np.random.seed(0)
    counts = np.bincount(np.concatenate([buffer.sample(32).indices for _ in range(500)]), minlength=6)
    scaled = (td + buffer.epsilon) ** alpha
    assert chi_square_p_value(counts, scaled / scaled.sum()) > 0.01


def test_update_priorities_changes_sampling_frequencies():
    buffer = make_buffer(4, alpha=1.0)
    add_steps(buffer, 4)
    np.random.seed(1)
    before = np.bincount(np.concatenate([buffer.sample(8).indices for _ in range(200)]), minlength=4)
    assert before.min() > 300  # equal priorities: about 400 each
    buffer.update_priorities([0, 1, 2, 3], [0.0, 0.0, 0.0, 1.0])
    after = np.bincount(np.concatenate([buffer.sample(8).indices for _ in range(200)]), minlength=4)
    assert after[3] > 0.99 * after.sum()


def test_two_envs_map_to_flat_leaves():
    buffer = make_buffer(8, n_envs=2, alpha=1.0)
    assert buffer.buffer_size == 4 and buffer.sum_tree.capacity == 8
    add_steps(buffer, 3)
    assert buffer.n_transitions == 6
    assert buffer.sum_tree.total == 6.0  # leaves 6, 7 are not written yet
    # Only (step 2, env 1) = leaf 2 * 2 + 1 = 5 keeps a real priority.
    buffer.update_priorities(np.arange(6), [0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    np.random.seed(2)
    batch = buffer.sample(16)
    assert set(batch.indices.tolist()) == {5}
    np.testing.assert_array_equal(batch.observations.numpy(), np.tile([[2.0, 1.0]], (16, 1)))
    np.testing.assert_allclose(batch.rewards.numpy(), np.full((16, 1), 2.1), rtol=1e-6)
    np.testing.assert_array_equal(batch.next_observations.numpy(), np.tile([[2.5, 1.5]], (16, 1)))
    with pytest.raises(ValueError, match="stored transitions"):
        buffer.update_priorities([6], [1.0])


def test_wrap_around_overwrites_rows_and_their_priorities():
    buffer = make_buffer(3, alpha=1.0)
    add_steps(buffer, 3)
    buffer.update_priorities([0, 1, 2], [5.0, 1.0, 1.0])
    add_steps(buffer, 1, start=3)  # overwrites row 0 (step 0), with the max priority of before
    assert buffer.full and buffer.pos == 1
    assert buffer.sum_tree.values([0])[0] == pytest.approx(5.0 + buffer.epsilon)
    buffer.update_priorities([0], [0.0])
    np.random.seed(4)
    batch = buffer.sample(30)
    assert 0.0 not in batch.observations[:, 0].numpy()  # step 0 is gone
    assert buffer.n_transitions == 3


def test_timeouts_do_not_end_the_bootstrap():
    buffer = make_buffer(4, handle_timeout_termination=True)
    add_steps(buffer, 2, timeouts=True)  # done=True but truncated by a time limit
    assert np.all(buffer.sample(8).dones.numpy() == 0.0)
    plain = make_buffer(4, handle_timeout_termination=False)
    add_steps(plain, 2, timeouts=True)
    assert np.all(plain.sample(8).dones.numpy() == 1.0)


def test_reset_forgets_priorities():
    buffer = make_buffer(4)
    add_steps(buffer, 4)
    buffer.reset()
    assert buffer.sum_tree.empty and buffer.n_transitions == 0
    with pytest.raises(ValueError, match="empty"):
        buffer.sample(2)


@pytest.mark.parametrize(
    ("kwargs", "argument"),
    [
        ({"alpha": -0.1}, "alpha"),
        ({"beta": -0.1}, "beta"),
        ({"beta": 1.5}, "beta"),
        ({"beta": float("nan")}, "beta"),
        ({"epsilon": 0.0}, "epsilon"),
        ({"epsilon": -1e-3}, "epsilon"),
        ({"optimize_memory_usage": True, "handle_timeout_termination": False}, "optimize_memory_usage"),
    ],
)
def test_bad_arguments_are_rejected(kwargs, argument):
    with pytest.raises(PrioritizedReplayError, match=argument) as caught:
        make_buffer(8, **kwargs)
    assert isinstance(caught.value, ValueError) and isinstance(caught.value, MrlError)
    assert caught.value.argument == argument


def test_beta_setter_validates():
    buffer = make_buffer(4)
    buffer.beta = 1.0
    assert buffer.beta == 1.0
    with pytest.raises(PrioritizedReplayError, match="beta"):
        buffer.beta = 1.01


def test_dict_observations_are_rejected():
    with pytest.raises(PrioritizedReplayError, match="observation_space"):
        PrioritizedReplayBuffer(8, spaces.Dict({"a": OBS_SPACE}), ACTION_SPACE)
