"""Random layouts: per-episode starts, goals and boxes drawn from a scenario's ranges, seeded, valid, refused
when the ranges hold none; the simulator moves its boxes and judges against the episode's layout."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from pipeline.core.errors import ScenarioError
from pipeline.core.judge import goal_fields
from pipeline.core.layouts import draw_layout
from pipeline.core.scenario import box_clearance, box_corners, load_scenario
from pipeline.errors import ConfigError
from pipeline.learn.common.worlds import TRAIN_SEED_MIN, VecWorlds
from pipeline.mappings import read_yaml
from pipeline.params import world_config
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim

RICH = {"scenario": "obstacles_random", "observation": "rich", "max_steps": 40}


@pytest.fixture(scope="module")
def scenario():
    return load_scenario("obstacles_random")


def test_a_seed_gives_one_layout_to_the_bit_and_seeds_give_different_ones(scenario):
    assert draw_layout(scenario, 41) == draw_layout(scenario, 41)
    layouts = [draw_layout(scenario, seed) for seed in range(30)]
    assert len({(lay.starts.tobytes(), lay.goals.tobytes()) for lay in layouts}) == 30
    assert len({(lay.obstacles[0].x_m, lay.obstacles[0].y_m) for lay in layouts}) == 30


def test_every_drawn_layout_keeps_its_ranges_clearances_and_reachable_goals(scenario):
    ranges = scenario.layouts
    r, c, half = scenario.robot.radius_m, ranges.clearance_m, scenario.goal_size_m / 2
    for seed in range(60):
        lay = draw_layout(scenario, seed)
        lay.validate()
        starts, goals = lay.starts, lay.goals
        assert np.all((ranges.start_x_m[0] <= starts[:, 0]) & (starts[:, 0] <= ranges.start_x_m[1]))
        assert np.all((ranges.goal_y_m[0] <= goals[:, 1]) & (goals[:, 1] <= ranges.goal_y_m[1]))
        for box, original in zip(lay.obstacles, scenario.obstacles, strict=True):
            assert (box.size_x_m, box.size_y_m) == (original.size_x_m, original.size_y_m)
            assert ranges.box_yaw_rad[0] <= box.yaw_rad <= ranges.box_yaw_rad[1]
            corners = box_corners(box)
            assert corners[:, 0].min() >= c and corners[:, 0].max() <= 6.0 - c
            assert box_clearance(box, starts[:, :2]).min() >= r + c
            assert box_clearance(box, goals).min() >= r + c
        assert np.all(np.hypot(*(starts[:, :2] - goals).T) >= ranges.min_goal_distance_m)
        for i in range(3):
            for j in range(3):
                far = np.abs(starts[i, :2] - goals[j]) >= half + r + c
                assert far.any(), f"seed {seed}: start of robot_{i + 1} touches goal square {j + 1}"
        assert np.all(np.isfinite(goal_fields(lay).distance(starts[:, :2])))


def test_ranges_that_hold_no_layout_are_refused_with_the_reason(tmp_path):
    data = read_yaml(load_scenario_path("obstacles_random"))
    data["layouts"]["min_goal_distance_m"] = 9.0  # longer than the room's diagonal
    data["layouts"]["tries"] = 50
    path = tmp_path / "impossible.yaml"
    path.write_text(__import__("yaml").safe_dump(data))
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    text = str(err.value)
    assert "no valid layout in 50 draws" in text and "min_goal_distance_m" in text and str(path) in text


def test_a_range_with_low_above_high_is_a_config_error(tmp_path):
    data = read_yaml(load_scenario_path("obstacles_random"))
    data["layouts"]["goal_x_m"] = [5.0, 1.0]
    path = tmp_path / "backwards.yaml"
    path.write_text(__import__("yaml").safe_dump(data))
    with pytest.raises(ConfigError, match=r"layouts\.goal_x_m = \[5\.0, 1\.0\]: \[low, high\] with low <= high"):
        load_scenario(path)


def load_scenario_path(name: str) -> str:
    from importlib import resources

    return str(resources.files("pipeline.core") / "scenarios" / f"{name}.yaml")


def test_the_simulator_moves_its_boxes_and_judges_each_episode_in_its_layout():
    scenario, world = make_world(world=world_config(RICH))
    sim = MultiRobotSim(scenario, world)
    for seed in (5, 6):
        obs = sim.reset(seed)
        lay = draw_layout(scenario, seed)
        assert sim.episode_layout == lay
        np.testing.assert_allclose(sim.world.truth[:, :2], lay.starts[:, :2], atol=1e-9)
        np.testing.assert_array_equal(sim.judge.goals, lay.goals)
        for k, box in enumerate(lay.obstacles):
            gid = mujoco.mj_name2id(sim.world.model, mujoco.mjtObj.mjOBJ_GEOM, f"box_{k}")
            np.testing.assert_allclose(sim.world.data.geom_xpos[gid, :2], (box.x_m, box.y_m), atol=1e-12)
        # the rich observation's goal is the layout's goal, in the robot's frame
        pose = sim.world.odometry.pose
        d = lay.goals - pose[:, :2]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        expected = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)
        np.testing.assert_allclose(obs[:, 4:6], expected, atol=1e-5)
    # a robot placed in front of a moved box sees it at the distance the layout puts it
    lay = sim.episode_layout
    box = lay.obstacles[0]
    pose = np.array(lay.starts)
    gap = float(box_clearance(box, pose[:1, :2])[0])
    heading = math.atan2(box.y_m - pose[0, 1], box.x_m - pose[0, 0])
    pose[0, 2] = heading
    sim.world.reset(6, pose)
    scan = sim.world.scan()
    beam = round((heading - pose[0, 2]) % (2 * math.pi) / (2 * math.pi / scan.shape[1])) % scan.shape[1]
    assert scan[0, beam] == pytest.approx(gap, abs=0.06)


def test_fixed_layouts_keep_the_scenario_and_training_seeds_stay_apart_from_evaluation_seeds():
    scenario, world = make_world(world=world_config({**RICH, "layouts": "fixed"}))
    sim = MultiRobotSim(scenario, world)
    sim.reset(5)
    assert sim.episode_layout == scenario and np.array_equal(sim.judge.goals, scenario.goals)

    scenario, world = make_world(world=world_config(RICH))
    worlds = VecWorlds(scenario, world, 2, seed=3, start_xy_m=0.3, start_yaw_rad=0.6)
    worlds.reset()
    for sim, seed in zip(worlds.sims, worlds._episode_seed, strict=True):
        assert seed >= TRAIN_SEED_MIN
        assert sim.episode_layout == draw_layout(scenario, int(seed))  # starts are the layout's, not perturbed
        np.testing.assert_allclose(sim.world.truth[:, :2], sim.episode_layout.starts[:, :2], atol=1e-9)


def test_random_layouts_need_an_observation_with_the_goal():
    with pytest.raises(ConfigError, match=r"observation = 'paper': rich: scenario 'obstacles_random' draws a layout"):
        make_world(world=world_config({**RICH, "observation": "paper"}))


def _in_way_share(share: float, tmp_path, offset: float = 0.15):
    data = read_yaml(load_scenario_path("obstacles_random"))
    data["layouts"]["box_in_way_share"] = share
    data["layouts"]["box_in_way_offset_m"] = offset
    path = tmp_path / f"in_way_{share}.yaml"
    path.write_text(__import__("yaml").safe_dump(data))
    return load_scenario(path)


def _on_a_way(box, lay, offset: float) -> bool:
    """Whether the box centre lies 35-65 % of the way from some robot's start to its goal, within `offset` of it."""
    for start, goal in zip(lay.starts[:, :2], lay.goals, strict=True):
        d = goal - start
        length = float(np.hypot(*d))
        u = d / length
        p = np.array([box.x_m, box.y_m]) - start
        t = float(p @ u) / length
        side = abs(float(p @ np.array([-u[1], u[0]])))
        if 0.35 - 1e-9 <= t <= 0.65 + 1e-9 and side <= offset + 1e-9:
            return True
    return False


def test_boxes_put_in_the_way_lie_on_a_robots_straight_way_and_keep_the_layout_valid(scenario, tmp_path):
    every = _in_way_share(1.0, tmp_path)
    r, c = scenario.robot.radius_m, scenario.layouts.clearance_m
    for seed in range(40):
        lay = draw_layout(every, seed)
        assert lay == draw_layout(every, seed)
        lay.validate()
        for box in lay.obstacles:
            assert _on_a_way(box, lay, 0.15), f"seed {seed}: a box off every robot's way"
            assert box_clearance(box, lay.starts[:, :2]).min() >= r + c
            assert box_clearance(box, lay.goals).min() >= r + c
        assert np.all(np.isfinite(goal_fields(lay).distance(lay.starts[:, :2])))
    # the uniform draws stay as they were: a share of 0 is the bundled scenario's layouts, bit for bit
    none = _in_way_share(0.0, tmp_path)
    assert all(draw_layout(none, seed) == draw_layout(scenario, seed) for seed in range(20))
    # a share in between puts some boxes in the way, more than the uniform draw does by chance
    half = _in_way_share(0.5, tmp_path)
    on = sum(_on_a_way(b, lay, 0.15) for lay in (draw_layout(half, s) for s in range(60)) for b in lay.obstacles)
    by_chance = sum(
        _on_a_way(b, lay, 0.15) for lay in (draw_layout(scenario, s) for s in range(60)) for b in lay.obstacles
    )
    assert on > by_chance + 30


def test_a_share_outside_zero_to_one_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError) as err:
        _in_way_share(1.5, tmp_path)
    assert "in_way_1.5.yaml" in str(err.value)
    assert "layouts.box_in_way_share = 1.5: a value >= 0.0 and <= 1.0" in str(err.value)
