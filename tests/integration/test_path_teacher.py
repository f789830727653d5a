"""The path-following teacher (`train.imitation.teacher: path`): the point ahead on each robot's free path, the
bearing the simulator tells the teacher, the teacher driving real MuJoCo worlds, and PPO's warm start from it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pipeline.core.judge import goal_fields
from pipeline.core.layouts import draw_layout
from pipeline.errors import ConfigError
from pipeline.learn.common.modes import StreamMap
from pipeline.learn.common.worlds import VecWorlds
from pipeline.learn.imitation import demonstrate
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, read_yaml
from pipeline.params import NetworkRanges, Params, load_params, world_config
from pipeline.policy.scripted import GoToGoalController, PathFollowingController
from pipeline.rollout.sim import evaluate
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim
from tests.integration.test_train_export import tiny_config

pytestmark = pytest.mark.integration


def in_way_world(max_steps: int = 350, **extra: object):
    return make_world(
        world=world_config(
            {
                "scenario": "obstacles_random_in_way",
                "observation": "rich",
                "observed_pose": "ground_truth",
                "progress_distance": "geodesic",
                "max_steps": max_steps,
                **extra,
            }
        )
    )


def path_length(points: np.ndarray) -> float:
    return float(np.hypot(*np.diff(points, axis=0).T).sum())


def test_the_point_ahead_follows_the_free_path_around_a_box_and_stops_at_the_goal() -> None:
    scenario, _ = in_way_world()
    layout = draw_layout(scenario, 11)
    fields = goal_fields(layout)
    start, goal = layout.starts[:, :2], layout.goals
    ahead = fields.ahead(start, goal, 1.0)
    # one metre along the path: no farther than a metre away in a straight line, and a metre nearer the goal
    far = fields.distance(start) > 1.3
    assert far.any()
    assert (np.hypot(*(ahead - start).T)[far] <= 1.0 + 1e-9).all()
    np.testing.assert_allclose((fields.distance(start) - fields.distance(ahead))[far], 1.0, atol=0.12)
    # a box stands on the straight line of some robot (the scenario puts them in the way): the path bends around
    # it, so the point ahead leaves the straight line by more than a grid cell
    straight = goal - start
    unit = straight / np.hypot(*straight.T)[:, None]
    off = np.abs(unit[:, 0] * (ahead - start)[:, 1] - unit[:, 1] * (ahead - start)[:, 0])
    assert off.max() > 0.1
    # from within a step of the goal, the point is the goal itself
    near = goal + np.array([0.03, 0.0])
    np.testing.assert_array_equal(fields.ahead(near, goal, 1.0), goal)


def test_the_simulator_tells_the_bearing_of_the_path_in_the_robot_frame() -> None:
    scenario, world = in_way_world()
    sim = MultiRobotSim(scenario, world)
    sim.reset(7)
    truth = sim.world.truth
    point = sim.judge.path_point(truth, 0.8)
    bearing = sim.path_bearing(0.8)
    # turning the robot by its bearing faces the point ahead
    heading = truth[:, 2] + bearing
    to_point = point - truth[:, :2]
    np.testing.assert_allclose(np.cos(heading), to_point[:, 0] / np.hypot(*to_point.T), atol=1e-9)
    np.testing.assert_allclose(np.sin(heading), to_point[:, 1] / np.hypot(*to_point.T), atol=1e-9)
    # straight-line progress: the bearing is the goal's own
    scenario, world = in_way_world(progress_distance="euclidean")
    sim = MultiRobotSim(scenario, world)
    obs = sim.reset(7)
    goal = obs[:, sim.layout.slices["goal_in_robot"]].astype(np.float64)
    np.testing.assert_allclose(sim.path_bearing(0.8), np.arctan2(goal[:, 1], goal[:, 0]), atol=1e-5)


def test_worlds_give_the_same_bearings_from_worker_processes() -> None:
    scenario, world = in_way_world(max_steps=20)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(12, 4, scenario.n_robots, 2)).astype(np.float32)
    seen = []
    for workers in (1, 2):
        with VecWorlds(scenario, world, 4, seed=3, workers=workers) as worlds:
            worlds.reset()
            bearings = [worlds.path_bearings(1.0)]
            others = [worlds.others_in_frame()]
            for a in actions:
                worlds.step(a)
                bearings.append(worlds.path_bearings(1.0))
                others.append(worlds.others_in_frame())
            seen.append((np.stack(bearings), np.stack(others)))
    assert seen[0][0].shape == (13, 4, scenario.n_robots)
    assert seen[0][1].shape == (13, 4, scenario.n_robots, scenario.n_robots - 1, 2)
    for one, two in zip(seen[0], seen[1], strict=True):
        np.testing.assert_array_equal(one, two)
    assert np.isfinite(seen[0][0]).all() and np.abs(seen[0][0]).max() <= np.pi


def test_the_simulator_tells_where_the_other_robots_are_in_each_robot_frame() -> None:
    scenario, world = in_way_world()
    sim = MultiRobotSim(scenario, world)
    starts = np.array([[1.0, 1.0, 0.0], [2.0, 1.0, np.pi / 2], [1.0, 3.0, np.pi]])
    sim.reset(7, starts)
    truth = sim.world.truth
    others = sim.others_in_frame()
    assert others.shape == (3, 2, 2)
    # robot_1 faces +x: robot_2 a metre ahead, robot_3 two metres to its left
    np.testing.assert_allclose(others[0], [[1.0, 0.0], [0.0, 2.0]], atol=0.02)
    # robot_2 faces +y: robot_1 a metre to its left, robot_3 two ahead and one to its left
    np.testing.assert_allclose(others[1], [[0.0, 1.0], [2.0, 1.0]], atol=0.02)
    # and in general: turning back by the robot's heading and adding its position gives the others' positions
    for i in range(3):
        c, s = np.cos(truth[i, 2]), np.sin(truth[i, 2])
        world_xy = truth[i, :2] + others[i] @ np.array([[c, s], [-s, c]])
        np.testing.assert_allclose(world_xy, np.delete(truth[:, :2], i, axis=0), atol=1e-9)


def test_told_of_a_robot_in_its_way_the_teacher_swerves_right_where_the_lidar_is_clear() -> None:
    scenario, world = in_way_world()
    sim = MultiRobotSim(scenario, world)
    teacher = PathFollowingController(sim.layout, sim.codec)
    obs = sim.reset(7)[:1].copy()
    obs[:, sim.layout.slices["ranges"]] = world.lidar.range_max_m  # nothing in sight
    obs[:, sim.layout.slices["goal_in_robot"]] = [3.0, 0.0]
    bearing = np.zeros(1)
    alone = teacher.commands(obs, bearing)
    assert alone[0, 0] > 0.3 and alone[0, 1] == pytest.approx(0.0, abs=1e-9)
    met = teacher.commands(obs, bearing, np.array([[[0.8, 0.0], [-2.0, 0.0]]]))
    assert met[0, 0] >= 0.0 and met[0, 1] < 0.0  # around it on its right
    # one out of the corridor, or behind, changes nothing
    np.testing.assert_array_equal(teacher.commands(obs, bearing, np.array([[[0.8, 0.9], [-0.6, 0.0]]])), alone)


# held-out layouts where boxes stand so that the go-to-goal controller stalls for at least one robot
HARD_LAYOUTS = (10015, 10023, 10036, 10049)
# the teacher checks the lidar near it only: its path must keep clear of the boxes, as training's setting has it
CLEAR_PATH = {"reward": {"path_clearance_m": 0.15}}


def test_the_teacher_that_knows_the_map_brings_robots_home_where_the_go_to_goal_controller_stalls() -> None:
    scenario, world = in_way_world(**CLEAR_PATH)
    sim = MultiRobotSim(scenario, world)
    teacher = PathFollowingController(sim.layout, sim.codec)

    def taught(obs: np.ndarray) -> np.ndarray:
        return teacher(obs, sim.path_bearing(teacher.ahead_m), sim.others_in_frame())

    scripted = GoToGoalController(sim.layout, sim.codec)
    by_path = [evaluate(sim, taught, 1, seed=s, progress=False)[0] for s in HARD_LAYOUTS]
    by_goal = [evaluate(sim, scripted, 1, seed=s, progress=False)[0] for s in HARD_LAYOUTS]
    assert all(r.success.all() for r in by_path)
    assert all(not r.success.all() for r in by_goal)
    assert not np.concatenate([r.collided for r in by_path + by_goal]).any()
    # it drives in reverse where its way lies behind it
    obs = sim.reset(10_000)
    cmd = teacher.commands(obs, np.full(scenario.n_robots, np.pi))
    assert (cmd[:, 0] <= 0).all()


def test_a_warm_start_from_the_path_teacher_records_its_reversing_and_repeats_to_the_bit(tmp_path: Path) -> None:
    scenario, world = in_way_world(max_steps=40)
    cfg = tiny_config(algorithm="ppo", mode="shared", imitation={"steps": 240, "epochs": 2, "teacher": "path"})
    with VecWorlds(scenario, world, 2, seed=1) as worlds:
        streams = StreamMap("shared", worlds)
        demos, steps, _ = demonstrate(worlds, streams, 240, cfg.gamma, teacher="path")
        scripted, _, _ = demonstrate(worlds, streams, 240, cfg.gamma)
    assert steps == 240
    # the path teacher reverses at times; the go-to-goal controller never does
    v = [d.actions[:, 0] for d in demos]
    assert np.concatenate(v).min() < -0.2 and np.concatenate([d.actions[:, 0] for d in scripted]).min() >= 0.0
    a = train(scenario, world, cfg, tmp_path / "a", progress=False)
    b = train(scenario, world, cfg, tmp_path / "b", progress=False)
    scripted_cfg = tiny_config(algorithm="ppo", mode="shared", imitation={"steps": 240, "epochs": 2})
    c = train(scenario, world, scripted_cfg, tmp_path / "c", progress=False)
    assert a.digest == b.digest != c.digest


def test_the_path_teacher_is_refused_where_it_cannot_drive() -> None:
    params = read_yaml(Path(__file__).resolve().parents[2] / "params.yaml")
    discrete = merge(
        params,
        {
            "train": {"algorithm": "ppo", "imitation": {"steps": 100, "teacher": "path"}},
            "world": {"observation": "rich", "actions": {"kind": "discrete"}},
        },
    )
    with pytest.raises(ConfigError, match=r"world\.actions\.kind.*'continuous' with train\.imitation\.teacher 'path'"):
        from_mapping(Params, discrete, "<test>")
    unknown = merge(params, {"train": {"imitation": {"teacher": "planner"}}})
    with pytest.raises(ConfigError, match=r"imitation\.teacher.*'planner'.*'scripted'.*'path'"):
        from_mapping(Params, unknown, "<test>")
    no_rounds = merge(params, {"train": {"imitation": {"rounds": 0}}})
    with pytest.raises(ConfigError, match=r"imitation\.rounds"):
        from_mapping(Params, no_rounds, "<test>")


def test_on_the_paper_layout_the_teacher_told_of_the_robots_passes_the_box_corners() -> None:
    """Checking the lidar only for the corridor to the point ahead, robot_1 stalls at its box's corner (the
    corridor clips it); told where the robots are, the teacher checks the lidar near it only and brings all home."""
    world = load_params(Path("params.yaml")).world
    world = replace(
        world,
        randomize=replace(world.randomize, network=NetworkRanges()),  # the corner geometry, on an ideal link
        scenario="obstacles",
        observation="rich",
        observed_pose="ground_truth",
        progress_distance="geodesic",
        reward=replace(world.reward, path_clearance_m=0.15),
    )
    sim = MultiRobotSim(*make_world(world=world))
    teacher = PathFollowingController(sim.layout, sim.codec)
    told = evaluate(sim, lambda o: teacher(o, sim.path_bearing(1.0), sim.others_in_frame()), 1, 0, progress=False)
    lidar_only = evaluate(sim, lambda o: teacher(o, sim.path_bearing(1.0)), 1, 0, progress=False)
    assert told[0].success.all()
    assert not lidar_only[0].success[0]
