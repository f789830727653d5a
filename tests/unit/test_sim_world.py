"""The MuJoCo world: contacts, lidar, noise, odometry and actuation, checked against geometry."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from pipeline.core.scenario import load_scenario
from pipeline.params import world_config
from pipeline.sim.world import SimWorld


def world(scenario="empty", n_robots=None, **overrides) -> SimWorld:
    cfg = world_config(
        {"lidar": {"noise_sigma_m": 0.0, "robot_radius_seen_m": 0.0}, "odometry": {"drift_per_m": 0.0}, **overrides}
    )
    sim = SimWorld(load_scenario(scenario, n_robots), cfg)
    sim.reset(0)
    return sim


def drive(sim: SimWorld, cmd, steps: int) -> None:
    for _ in range(steps):
        sim.step(np.asarray(cmd, dtype=float))


def test_unicycle_motion_follows_commands():
    sim = world(n_robots=1)
    drive(sim, [[0.4, 0.0]], 20)  # 2 s at 0.4 m/s
    x, y, yaw = sim.truth[0]
    assert x - 1.0 == pytest.approx(0.8, abs=0.03)  # minus the spin-up of the 0.05 s lag
    assert abs(y - 1.0) < 1e-6 and abs(yaw) < 1e-6
    drive(sim, [[0.0, 0.2]], 10)
    assert sim.truth[0, 2] == pytest.approx(0.2, abs=0.02)
    assert sim.truth[0, 0] == pytest.approx(x, abs=0.03)  # turning in place (after coasting ~v * tau)


def test_walls_and_boxes_stop_robots_through_contacts():
    sim = world("obstacles")
    drive(sim, [[0.4, 0.0], [0.0, 0.0], [0.0, 0.0]], 60)  # robot_1 drives at box 0 for 6 s
    box_face = 2.5 - 0.15
    assert sim.truth[0, 0] == pytest.approx(box_face - 0.165, abs=0.01)
    sim = world("empty", n_robots=1)
    drive(sim, [[0.4, 0.0]], 160)  # 6.4 m of command toward the east wall, 4.835 m away
    assert sim.truth[0, 0] == pytest.approx(6.0 - 0.165, abs=0.01)
    assert 0.0 < sim.truth[0, 1] < 4.0


def test_robots_push_against_each_other_without_overlap():
    sim = world("empty")
    # robot_2 (facing -x at (4, 2)) is driven towards robot_1 placed in its path
    drive(sim, [[0.0, 0.0], [0.4, 0.0], [0.0, 0.0]], 5)
    sim.data.qpos[sim.index.qpos[0]] = (2.0, 2.0, 0.0)
    drive(sim, [[0.0, 0.0], [0.4, 0.0], [0.0, 0.0]], 100)
    gap = np.hypot(*(sim.truth[0, :2] - sim.truth[1, :2]))
    assert gap == pytest.approx(0.33, abs=0.01)


def test_lidar_ranges_match_the_map():
    sim = world("obstacles", n_robots=2, lidar={"noise_sigma_m": 0.0, "sim_beams": 4, "robot_radius_seen_m": 0.0})
    ranges = sim.true_ranges()
    # robot_1 at (1, 1) facing +x: box 0 face at x=2.35 ahead, north wall 3 m, west wall 1 m, south wall 1 m
    np.testing.assert_allclose(ranges[0], [1.35, 3.0, 1.0, 1.0], atol=1e-6)
    # robot_2 at (4, 2) facing -x: the west wall 4 m ahead
    assert ranges[1, 0] == pytest.approx(4.0, abs=1e-6)
    with_third = world("obstacles", lidar={"noise_sigma_m": 0.0, "sim_beams": 4, "robot_radius_seen_m": 0.0})
    assert with_third.true_ranges()[0, 1] == pytest.approx(3.0 - 1.0 - 0.165, abs=1e-6)  # robot_3 at (1, 3)


def test_out_of_range_is_inf_and_robots_see_each_other():
    sim = world(
        "empty",
        n_robots=2,
        lidar={"sim_beams": 4, "range_max_m": 2.5, "noise_sigma_m": 0.0, "robot_radius_seen_m": 0.0},
    )
    sim.data.qpos[sim.index.qpos[1]] = (2.0, 1.0, 0.0)  # robot_2 1 m ahead of robot_1
    mujoco.mj_kinematics(sim.model, sim.data)
    sim.truth = sim.read_truth()
    r = sim.true_ranges()[0]
    assert r[0] == pytest.approx(1.0 - 0.165, abs=1e-6)
    assert np.isinf(r[1])  # north wall 3 m away, beyond 2.5 m
    enlarged = world("empty", n_robots=2, lidar={"sim_beams": 4, "robot_radius_seen_m": 0.3, "noise_sigma_m": 0.0})
    enlarged.data.qpos[enlarged.index.qpos[1]] = (2.0, 1.0, 0.0)
    mujoco.mj_kinematics(enlarged.model, enlarged.data)
    enlarged.truth = enlarged.read_truth()
    assert enlarged.true_ranges()[0, 0] == pytest.approx(1.0 - 0.3, abs=1e-6)


def test_gaussian_noise_dropout_and_bias_statistics():
    sim = world("empty", lidar={"noise_sigma_m": 0.05, "bias_m": 0.02, "dropout_prob": 0.1, "sim_beams": 90})
    truth = sim.true_ranges()
    scans = np.stack([sim.scan() for _ in range(200)])
    hit = np.isfinite(truth)[None].repeat(200, 0)
    dropped = ~np.isfinite(scans) & hit
    assert dropped.mean() / hit.mean() == pytest.approx(0.1, abs=0.01)
    keep = hit & ~dropped
    err = scans[keep] - truth[None].repeat(200, 0)[keep]
    assert err.mean() == pytest.approx(0.02, abs=0.003)
    assert err.std() == pytest.approx(0.05, rel=0.03)


def test_the_simulated_lidar_has_what_real_ones_have():
    """The keys calibration finds in a real lidar: ranges in steps, noise that differs per beam (mean square 1),
    mixed pixels at the boxes' depth edges, the driver's no-return value."""
    real = {"noise_sigma_m": 0.01, "sim_beams": 360, "range_step_m": 0.002, "beam_noise_spread": 0.4,
            "mixed_pixel_prob": 0.5, "no_return": "zero", "range_max_m": 4.5, "dropout_prob": 0.05}  # fmt: skip
    sim = world("obstacles", n_robots=1, lidar=real)
    truth = sim.true_ranges()[0]
    scans = np.stack([sim.scan()[0] for _ in range(300)])
    sim.true_ranges()
    returned = scans > 0
    units = scans[returned] / 0.002
    assert np.abs(units - np.round(units)).max() < 1e-3  # on the lattice (float32 as a LaserScan carries it)
    assert (~np.isfinite(truth)).sum() > 10 and (scans[:, ~np.isfinite(truth)] == 0.0).all()  # the driver's 0
    assert 0.03 < (scans[:, np.isfinite(truth)] == 0.0).mean() < 0.07  # and so do dropouts
    before = np.roll(truth, 1)
    both = np.isfinite(truth) & np.isfinite(before)
    here, prev = np.where(both, truth, 0.0), np.where(both, before, 0.0)
    surface = sim.surfaces[0]
    edge = both & (np.abs(here - prev) > 0.1) & (surface != np.roll(surface, 1))  # another surface: a depth edge
    inside = returned & (scans > np.minimum(here, prev) + 0.05) & (scans < np.maximum(here, prev) - 0.05)
    assert edge.sum() >= 2 and inside[:, edge].mean() > 0.05 and not inside[:, ~edge].any()
    clean = world("obstacles", n_robots=1, lidar={**real, "mixed_pixel_prob": 0.0})
    again = np.stack([clean.scan()[0] for _ in range(300)])
    assert not ((again > np.minimum(here, prev) + 0.05) & (again < np.maximum(here, prev) - 0.05))[:, edge].any()
    plain = np.isfinite(truth) & ~edge
    spread = np.std(np.where(returned, scans, np.nan)[:, plain], axis=0, where=returned[:, plain])
    assert spread.max() / spread.min() > 2.0
    assert np.sqrt(np.mean(spread**2)) == pytest.approx(0.01, rel=0.25)


def test_scans_lost_in_the_driver_leave_the_policy_the_previous_one():
    from pipeline.sim.env import NetworkedSensors

    cfg = world_config({"lidar": {"scan_drop_prob": 0.3}})
    sensors = NetworkedSensors(2, cfg)
    assert sensors.plays
    sensors.reset(cfg, seed=1)
    pose = np.zeros((2, 3))
    sensors.receive(np.zeros((2, 4)), pose, first=True)
    for k in range(1, 1001):
        sensors.receive(np.full((2, 4), float(k)), pose, first=False)
    assert sensors.scans is not None
    assert sensors.scans.lost / sensors.scans.sent == pytest.approx(np.full(2, 0.3), abs=0.05)
    ideal = NetworkedSensors(2, world_config({}))
    assert not ideal.plays


def test_odometry_drift_grows_about_drift_per_metre():
    errors = []
    for seed in range(40):
        sim = world("empty", n_robots=1, odometry={"drift_per_m": 0.03})
        sim.reset(seed)
        drive(sim, [[0.4, 0.0]], 25)
        travelled = sim.truth[0, 0] - 1.0
        errors.append(np.hypot(*(sim.odometry.pose[0, :2] - sim.truth[0, :2])) / travelled)
    rms = float(np.sqrt(np.mean(np.square(errors))))
    assert 0.02 < rms < 0.05
    exact = world("empty", n_robots=1)
    drive(exact, [[0.4, 0.1]], 25)
    np.testing.assert_allclose(exact.odometry.pose, exact.truth, atol=1e-9)


def test_actuation_delay_and_gains():
    plain = world("empty", n_robots=1)
    delayed = world("empty", n_robots=1, actuation={"delay_s": 0.2})
    fast = world("empty", n_robots=1, actuation={"linear_gain": 1.5})
    for sim in (plain, delayed, fast):
        drive(sim, [[0.2, 0.0]], 2)
    assert delayed.truth[0, 0] == pytest.approx(1.0, abs=1e-9)  # nothing moved for 0.2 s
    assert plain.truth[0, 0] > 1.03
    for sim in (plain, delayed, fast):
        drive(sim, [[0.2, 0.0]], 20)
    assert (fast.truth[0, 0] - 1.0) / (plain.truth[0, 0] - 1.0) == pytest.approx(1.5, rel=0.02)
    assert plain.truth[0, 0] - delayed.truth[0, 0] == pytest.approx(0.04, abs=0.005)


def test_a_speed_limit_cuts_the_achieved_speed_not_the_slower_commands():
    limited = world("empty", n_robots=1, actuation={"max_linear_mps": 0.25, "max_angular_radps": 0.1})
    plain = world("empty", n_robots=1)
    for sim in (limited, plain):
        drive(sim, [[0.4, 0.0]], 20)
    assert limited.body_velocity()[0, 0] == pytest.approx(0.25, abs=1e-3)
    assert plain.body_velocity()[0, 0] == pytest.approx(0.4, abs=1e-3)
    for sim in (limited, plain):
        drive(sim, [[0.2, 0.3]], 20)
    # below the limit the two bases are the same; the yaw rate is cut at its own limit
    assert limited.body_velocity()[0, 0] == pytest.approx(plain.body_velocity()[0, 0], abs=1e-3)
    assert limited.body_velocity()[0, 1] == pytest.approx(0.1, abs=1e-3)
    assert plain.body_velocity()[0, 1] == pytest.approx(0.3, abs=1e-3)


def test_the_arc_of_unequal_wheels_turns_the_base_and_not_its_odometry():
    # encoders read with the nominal radii count a straight command's arc as straight driving
    sim = world(n_robots=1, actuation={"yaw_rate_per_mps": -0.1})
    drive(sim, [[0.3, 0.0]], 30)  # about 0.85 m forward
    x, y, yaw = sim.truth[0]
    distance = float(np.hypot(x - 1.0, y - 1.0))
    assert distance > 0.7
    assert yaw == pytest.approx(-0.1 * distance, rel=0.1)  # the base curved to the right
    assert y < 1.0 - 0.02
    odom = sim.odometry.pose[0]
    assert abs(odom[2]) < 1e-4 and abs(odom[1] - 1.0) < 1e-3  # the odometry drove straight east (up to the lag)
    assert odom[0] - 1.0 == pytest.approx(distance, rel=0.02)
    sim = world(n_robots=1)
    drive(sim, [[0.3, 0.0]], 30)
    assert np.allclose(sim.odometry.pose[0], sim.truth[0], atol=1e-9)  # equal wheels: odometry is the truth
