"""The pursuit on the hardware twin: the twin plays the target as a robot of its own (its evader, its body in
the twin's physics, its motion-capture pose on /target/ground_truth); the runner sees it only there and
through the lidar, tracks it in the observation and the judge, and records it."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import train
from pipeline.mappings import from_mapping, merge, read_yaml, to_mapping
from pipeline.params import TrainConfig, world_config
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.ros.fleet import load_fleet
from pipeline.sim import make_world
from tests.integration.conftest import TINY_TRAIN, write_fleet

pytestmark = pytest.mark.integration


def test_the_twin_plays_the_target_and_the_runner_tracks_it(tmp_path):
    from importlib import resources

    data = read_yaml(resources.files("pipeline.core") / "scenarios" / "pursuit.yaml")
    data["name"] = "near_pursuit"
    data["target"]["start"] = {"x_m": 2.6, "y_m": 2.0}  # robot_2 starts 1.6 m away: it flees at once
    room = tmp_path / "near_pursuit.yaml"
    room.write_text(yaml.safe_dump(data))
    scenario, world = make_world(world=world_config({"scenario": str(room), "observation": "rich", "max_steps": 30}))
    cfg = from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), TINY_TRAIN), "<test>")
    trained = train(scenario, world, cfg, tmp_path / "run", progress=False)
    export_policy(trained.checkpoint, tmp_path / "policy", golden_observations(scenario, world, 8))

    fleet_file = write_fleet(tmp_path / "fleet.yaml", scenario=str(room))
    request = DeployRequest(episodes=2, seed=5, recording=tmp_path / "session.mcap", progress=False)
    runtime = PolicyRuntime(tmp_path / "policy")
    results, _ = deploy_policy(runtime, load_fleet(fleet_file), str(fleet_file), request)
    assert len(results) == 2 and not any(r.aborted for r in results)

    log = McapLog(tmp_path / "session.mcap")
    poses = np.array([(m.msg.pose.position.x, m.msg.pose.position.y) for m in log.messages(["/target/ground_truth"])])
    assert len(poses) > 20
    assert np.hypot(*(poses - (2.6, 2.0)).T).max() > 0.1  # it ran from robot_2
    # the observation's goal is the target in each robot's frame: its length is the distance to the target
    obs = [m.msg for m in log.messages(["/mrl/observation"]) if m.msg.robot == "robot_2"]
    goal = np.array([o.values[4:6] for o in obs])
    assert np.all(np.hypot(goal[:, 0], goal[:, 1]) < 2.5) and np.hypot(*goal[0]) == pytest.approx(1.6, abs=0.1)

    # a fleet without motion capture cannot show the policy its target
    blind = write_fleet(tmp_path / "blind.yaml", scenario=str(room), timing={"use_ground_truth": False})
    with pytest.raises(PolicyMismatch, match="is a pursuit: the policy needs the target's pose from motion capture"):
        deploy_policy(runtime, load_fleet(blind), str(blind), request)


def test_the_twin_starts_the_target_and_robots_at_each_episodes_drawn_layout(tmp_path):
    from pipeline.core.layouts import draw_layout

    scenario, world = make_world(
        world=world_config({"scenario": "pursuit_random", "observation": "rich", "max_steps": 20})
    )
    cfg = from_mapping(TrainConfig, merge(to_mapping(TrainConfig()), TINY_TRAIN), "<test>")
    trained = train(scenario, world, cfg, tmp_path / "run", progress=False)
    export_policy(trained.checkpoint, tmp_path / "policy", golden_observations(scenario, world, 8))
    fleet_file = write_fleet(tmp_path / "fleet.yaml", scenario="pursuit_random")
    request = DeployRequest(episodes=2, seed=7, recording=tmp_path / "session.mcap", progress=False)
    results, _ = deploy_policy(PolicyRuntime(tmp_path / "policy"), load_fleet(fleet_file), str(fleet_file), request)
    assert [r.seed for r in results] == [7, 8] and not any(r.aborted for r in results)

    log = McapLog(tmp_path / "session.mcap")
    maps = [m for m in log.messages(["/mrl/map"])]
    target = [(m.log_time_ns, m.msg) for m in log.messages(["/target/ground_truth"])]
    truth = [(m.log_time_ns, m.msg) for m in log.messages(["/robot_2/ground_truth"])]
    assert len(maps) == 2
    for episode, map_msg in enumerate(maps):
        layout = draw_layout(scenario, 7 + episode)
        assert layout.target.start != scenario.target.start
        boxes = [(mk.pose.position.x, mk.pose.position.y) for mk in map_msg.msg.markers if mk.ns == "boxes"]
        np.testing.assert_allclose(boxes, [(b.x_m, b.y_m) for b in layout.obstacles], atol=1e-9)
        # the twin's evader and robot_2 begin the episode where the draw put them
        first = next(msg for t, msg in target if t >= map_msg.log_time_ns)
        at = np.array([first.pose.position.x, first.pose.position.y])
        assert np.hypot(*(at - (layout.target.start.x_m, layout.target.start.y_m))) < 0.05
        robot = next(msg for t, msg in truth if t >= map_msg.log_time_ns)
        assert np.hypot(robot.pose.position.x - layout.starts[1, 0], robot.pose.position.y - layout.starts[1, 1]) < 0.05
