"""The ``rich_memory`` observation: the previous command, as fractions of each robot's limits, zero at an
episode's start, built by the one builder the simulator and the deploy runner share."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.core.observation import ObservationLayout
from pipeline.params import world_config
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim

WORLD = {"scenario": "obstacles", "observation": "rich_memory", "max_steps": 40}


def test_the_memory_layout_is_rich_with_two_command_fractions_before_the_ranges():
    layout = ObservationLayout("rich_memory", 15)
    rich = ObservationLayout("rich", 15)
    assert layout.size == rich.size + 2 == 23
    assert layout.slices["previous_command"] == slice(6, 8) and layout.slices["ranges"] == slice(8, 23)
    assert layout.names[6:8] == ("previous_v_frac", "previous_w_frac")
    low, high = layout.bounds((0.0, 4.0), (0.0, 6.0), 0.1, 3.5)
    np.testing.assert_array_equal(low[6:8], [-1.0, -1.0])
    np.testing.assert_array_equal(high[6:8], [1.0, 1.0])
    assert layout.has_memory and not rich.has_memory and layout.has_goal
    pose, ranges, goals = np.array([[1.0, 2.0, 0.3]]), np.full((1, 15), 2.0), np.array([[3.0, 4.0]])
    obs = layout.build(pose, ranges, goals, previous=np.array([[0.5, -0.25]]))
    np.testing.assert_array_equal(obs[0, 6:8], [0.5, -0.25])
    # everything else is the rich observation, to the bit
    np.testing.assert_array_equal(np.delete(obs, [6, 7], axis=1), rich.build(pose, ranges, goals))
    with pytest.raises(ValueError, match="rich_memory layout needs previous commands of shape \\(1, 2\\)"):
        layout.build(pose, ranges, goals)


def test_the_builder_scales_remembers_and_forgets_the_commands():
    scenario, world = make_world(world=world_config({**WORLD, "actions": {"v_max_mps": 0.4, "w_max_radps": 2.0}}))
    sim = MultiRobotSim(scenario, world)
    observer, s = sim.observer, sim.layout.slices["previous_command"]
    obs = sim.reset(seed=3)
    np.testing.assert_array_equal(obs[:, s], 0.0)
    step = sim.step(np.array([[1.0, 0.5], [-1.0, -1.0], [0.0, 1.0]], dtype=np.float32))
    # the command each robot was given, over its limits: what the next observation carries
    np.testing.assert_allclose(step.obs[:, s], sim.last_cmd / np.array([0.4, 2.0]), atol=1e-7)
    assert np.abs(step.obs[:, s]).max() > 0.4
    # a command beyond the limits is clipped to them
    observer.remember(np.array([[0.8, -4.0], [0.0, 0.0], [0.2, 1.0]]))
    np.testing.assert_array_equal(observer.previous, [[1.0, -1.0], [0.0, 0.0], [0.5, 0.5]])
    np.testing.assert_array_equal(sim.reset(seed=4)[:, s], 0.0)


def test_a_layout_without_memory_ignores_the_commands():
    scenario, world = make_world(world=world_config({**WORLD, "observation": "rich"}))
    sim = MultiRobotSim(scenario, world)
    sim.reset(seed=1)
    sim.step(np.ones((3, 2), dtype=np.float32))
    np.testing.assert_array_equal(sim.observer.previous, 0.0)
    assert sim.obs.shape == (3, 21)


def test_memory_observations_are_deterministic_to_the_bit():
    scenario, world = make_world(world=world_config(WORLD))
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (25, 3, 2)).astype(np.float32)

    def run() -> np.ndarray:
        sim = MultiRobotSim(scenario, world)
        out = [sim.reset(seed=11)]
        out += [sim.step(a).obs for a in actions]
        return np.stack(out)

    first, second = run(), run()
    np.testing.assert_array_equal(first, second)
    assert np.abs(first[1:, :, 6:8]).max() > 0.0
