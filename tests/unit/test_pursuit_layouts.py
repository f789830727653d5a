"""Random layouts of the pursuit: the robots' starts, the target's start and the boxes drawn per episode from
the scenario's ranges, and the simulator's evader playing each episode in its layout."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.core.errors import ScenarioError
from pipeline.core.layouts import draw_layout
from pipeline.core.scenario import box_clearance, load_scenario
from pipeline.params import world_config
from pipeline.policy.scripted import GoToGoalController
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim


@pytest.fixture(scope="module")
def scenario():
    return load_scenario("pursuit_random")


def test_each_seed_draws_a_valid_pursuit_layout_of_its_own(scenario):
    ranges, target = scenario.layouts, scenario.target
    keep = target.radius_m + target.clearance_m
    room = scenario.room
    targets = set()
    for seed in range(40):
        layout = draw_layout(scenario, seed)
        assert layout == draw_layout(scenario, seed)  # the seed alone decides it
        t = np.array([layout.target.start.x_m, layout.target.start.y_m])
        targets.add(tuple(t))
        # the target's start keeps its radius and clearance off walls and boxes; the rest of it is the scenario's
        assert room.x_min_m + keep <= t[0] <= room.x_max_m - keep and room.y_min_m + keep <= t[1] <= room.y_max_m - keep
        assert all(box_clearance(b, t[None])[0] >= keep for b in layout.obstacles)
        assert dataclasses.replace(layout.target, start=target.start) == target
        # every robot starts clear of walls and boxes, min_goal_distance_m from the target, and has no goal
        starts = layout.starts[:, :2]
        assert np.hypot(*(starts - t).T).min() >= ranges.min_goal_distance_m
        assert all(spec.goal is None for spec in layout.robots)
        np.testing.assert_array_equal(layout.goals, np.tile(t, (3, 1)))  # the target is every robot's goal
        for b in layout.obstacles:
            assert box_clearance(b, starts).min() >= scenario.robot.radius_m + ranges.clearance_m
        assert layout.beyond_layout(scenario) == [] and scenario.beyond_layout(layout) == []
    assert len(targets) == 40


def test_a_pursuit_layout_is_another_layout_of_the_fixed_pursuit_but_a_faster_target_is_not(scenario):
    fixed = load_scenario("pursuit")
    assert scenario.beyond_layout(fixed) == []
    faster = dataclasses.replace(fixed, target=dataclasses.replace(fixed.target, speed_mps=0.3))
    assert scenario.beyond_layout(faster) == ["target differs"]


def test_boxes_on_the_way_and_impossible_ranges_are_refused_in_a_pursuit(scenario):
    bad = dataclasses.replace(scenario, layouts=dataclasses.replace(scenario.layouts, box_in_way_share=0.5))
    with pytest.raises(ScenarioError, match=r"box_in_way_share is 0\.5: a pursuit scenario must leave it at 0"):
        bad.validate()
    cramped = dataclasses.replace(scenario, layouts=dataclasses.replace(scenario.layouts, min_goal_distance_m=9.0))
    with pytest.raises(ScenarioError, match=r"no valid layout in 1000 draws.*closer than min_goal_distance_m"):
        draw_layout(cramped, 0)


def test_the_simulator_starts_the_target_at_each_episodes_draw_and_the_evader_keeps_off_its_boxes(scenario):
    _, world = make_world(
        world=world_config({"scenario": "pursuit_random", "observation": "rich", "max_steps": 120, "layouts": "random"})
    )
    sim = MultiRobotSim(scenario, world)
    controller = GoToGoalController(world.layout(), world.codec())
    keep = scenario.target.radius_m + scenario.target.clearance_m
    moved = 0
    for seed in (11, 12, 13):
        obs = sim.reset(seed)
        layout = draw_layout(scenario, seed)
        assert sim.episode_layout == layout
        np.testing.assert_array_equal(sim.world.target_xy, (layout.target.start.x_m, layout.target.start.y_m))
        gid = sim.world.model.geom("target").id
        np.testing.assert_allclose(sim.world.data.geom_xpos[gid, :2], sim.world.target_xy, atol=1e-12)
        np.testing.assert_allclose(sim.world.truth, layout.starts, atol=1e-6)
        start = sim.world.target_xy
        for _ in range(world.max_steps):
            step = sim.step(world.codec().encode(controller.commands(obs)))
            obs = step.obs
            xy = sim.world.target_xy
            assert all(box_clearance(b, xy[None])[0] >= keep - 1e-6 for b in layout.obstacles)
            if step.judge.done.all() or step.judge.truncated:
                break
        moved += not np.allclose(sim.world.target_xy, start)
    assert moved >= 1
