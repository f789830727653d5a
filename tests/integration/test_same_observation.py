"""One MDP, two worlds: the deploy path rebuilds, from recorded messages, the observations the simulator gave."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest

from pipeline.mdp import mdp_parts
from pipeline.params import world_config
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.record.session import SessionLog, session_metadata
from pipeline.rollout.runner import odom_sample, scan_sample
from pipeline.rollout.sim import evaluate
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim
from tests.integration.conftest import TINY_WORLD

pytestmark = pytest.mark.integration


def test_recorded_scans_and_odometry_rebuild_the_simulated_observations(tiny_policy, tmp_path):
    runtime = PolicyRuntime(tiny_policy)
    scenario, world = make_world(world=world_config({**TINY_WORLD, "lidar": {"sim_beams": 360, "noise_sigma_m": 0.02}}))
    session = session_metadata("sim", scenario.name, scenario.robot_names, 0.1, runtime.document)
    with SessionLog(tmp_path / "s.mcap", scenario.robot_names, session) as log:
        evaluate(MultiRobotSim(scenario, world), runtime.actions, 2, 0, progress=False, log=log, layout_name="rich")
    builder = mdp_parts(scenario, runtime.spec.world).observer
    assert builder.reduction == world.lidar.reduction
    recorded: dict[int, dict[str, np.ndarray]] = defaultdict(dict)
    scans: dict[int, dict[str, object]] = defaultdict(dict)
    odoms: dict[int, dict[str, object]] = defaultdict(dict)
    for m in McapLog(tmp_path / "s.mcap").messages():
        if m.topic == "/mrl/observation":
            recorded[m.log_time_ns][m.msg.robot] = np.asarray(m.msg.values)
        elif m.topic.endswith("/scan"):
            scans[m.log_time_ns][m.topic.split("/")[1]] = scan_sample(m.msg, m.log_time_ns)
        elif m.topic.endswith("/odom"):
            odoms[m.log_time_ns][m.topic.split("/")[1]] = odom_sample(m.msg, m.log_time_ns)
    names = scenario.robot_names
    checked = 0
    for t, per_robot in recorded.items():
        s = [scans[t][n] for n in names]
        o = np.stack([odoms[t][n].pose for n in names])  # type: ignore[attr-defined]
        rebuilt = builder.build([x.ranges for x in s], [x.geometry for x in s], o).obs  # type: ignore[attr-defined]
        want = np.stack([per_robot[n] for n in names])
        layout = runtime.layout.slices
        # the ranges come through the LaserScan unchanged: equal to the bit
        np.testing.assert_array_equal(rebuilt[:, layout["ranges"]], want[:, layout["ranges"]])
        # the pose goes through a quaternion: equal within float32 rounding
        np.testing.assert_allclose(rebuilt, want, rtol=0, atol=2e-6)
        checked += 1
    assert checked >= 20


def test_the_deploy_runner_and_the_simulator_get_equal_mdp_parts_from_one_spec(tiny_policy, tmp_path):
    """The runner's MDP is the policy's (its spec), built by the same function as the simulator's."""
    from pipeline.rollout.runner import DeployRunner
    from pipeline.ros.clock import WallClock
    from pipeline.ros.fleet import load_fleet
    from pipeline.ros.transport import open_transport
    from tests.integration.conftest import write_fleet

    runtime = PolicyRuntime(tiny_policy)
    spec = runtime.spec
    fleet = load_fleet(write_fleet(tmp_path / "fleet.yaml"))
    transport = open_transport(fleet.transport, fleet.network_settings())
    session = session_metadata("real", spec.scenario.name, fleet.names, spec.world.control_period_s, runtime.document)
    log = SessionLog(tmp_path / "s.mcap", fleet.names, session)
    try:
        runner = DeployRunner(runtime, fleet, spec.scenario, transport, WallClock(), log)
        sim = MultiRobotSim(spec.scenario, spec.world)
        assert runner.mdp.definition == sim.mdp.definition == spec.mdp
        assert runner.period_ns == round(spec.world.control_period_s * 1e9)
        assert runner.mdp.codec == sim.codec and runner.mdp.layout == sim.layout
        judge_settings = ("max_steps", "margin_m", "distance", "weights")
        for name in judge_settings:
            assert getattr(runner.judge, name) == getattr(sim.judge, name), name
        runner.close()
    finally:
        log.close()
        transport.close()
