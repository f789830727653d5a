"""The twin's wheel-level physics (real MuJoCo): wheels, motors, slip, collisions, lidar rays."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.core.scenario import load_scenario
from pipeline.errors import ConfigError
from pipeline.twin.physics import BaseParams, FleetPhysics

R = 0.034


@pytest.fixture(scope="module")
def empty():
    return load_scenario("empty", 1)


def drive(physics: FleetPhysics, left: float, right: float, seconds: float) -> None:
    physics.set_wheel_targets(np.array([[left, right]]))
    physics.step(round(seconds / physics.timestep_s))


def test_equal_wheel_speeds_drive_straight_at_r_times_omega(empty):
    physics = FleetPhysics(empty, BaseParams())
    start = physics.poses()[0].copy()
    drive(physics, 0.2 / R, 0.2 / R, 3.0)
    v, w = physics.body_velocity()[0]
    assert v == pytest.approx(0.2, rel=0.02) and abs(w) < 1e-3
    pose = physics.poses()[0]
    heading = np.array([math.cos(start[2]), math.sin(start[2])])
    d = pose[:2] - start[:2]
    lateral = heading[0] * d[1] - heading[1] * d[0]
    assert abs(lateral) < 0.005 and abs(pose[2] - start[2]) < 0.01


def test_unequal_wheel_radii_curve_as_predicted(empty):
    base = BaseParams(wheel_radius_left_m=0.033, wheel_radius_right_m=0.035)
    physics = FleetPhysics(empty, base)
    omega = 5.0
    drive(physics, omega, omega, 4.0)
    v, w = physics.body_velocity()[0]
    predicted = omega * (0.035 - 0.033) / base.wheel_separation_m
    assert w == pytest.approx(predicted, rel=0.1) and v == pytest.approx(omega * 0.034, rel=0.03)


def test_a_target_inside_the_deadband_does_not_move_the_robot(empty):
    physics = FleetPhysics(empty, BaseParams(deadband_radps=1.0))
    start = physics.poses()[0].copy()
    drive(physics, 0.8, 0.8, 1.0)
    assert np.hypot(*(physics.poses()[0, :2] - start[:2])) < 1e-3
    drive(physics, 3.0, 3.0, 1.0)
    assert np.hypot(*(physics.poses()[0, :2] - start[:2])) > 0.05


def test_wheel_speed_ramps_no_faster_than_the_acceleration_limit(empty):
    physics = FleetPhysics(empty, BaseParams(max_wheel_accel_radps2=10.0))
    physics.set_wheel_targets(np.array([[8.0, 8.0]]))
    speeds = []
    for _ in range(100):  # 1 s in steps of 10 ms
        physics.step(5)
        speeds.append(physics.wheel_speeds()[0, 0])
    assert speeds[24] == pytest.approx(2.5, abs=0.3)  # 0.25 s at 10 rad/s^2
    ramp = np.minimum(10.0 * 0.01 * np.arange(1, 101), 8.0)
    assert np.abs(np.array(speeds) - ramp).max() < 0.5  # the wheel follows the limited setpoint
    assert max(speeds) <= 8.3 and speeds[-1] == pytest.approx(8.0, abs=0.3)


def test_the_motor_lag_reaches_63_percent_at_its_time_constant(empty):
    physics = FleetPhysics(empty, BaseParams(motor_time_constant_s=0.2))
    drive(physics, 10.0, 10.0, 0.2)
    assert physics.wheel_speeds()[0, 0] == pytest.approx(10.0 * (1 - math.exp(-1)), rel=0.08)


def test_wheels_slip_on_a_slippery_floor_and_not_on_the_nominal_one(empty):
    ratios = {}
    for friction in (1.0, 0.05):
        physics = FleetPhysics(empty, BaseParams(friction=friction))
        drive(physics, 12.0, 12.0, 0.15)
        rim = R * physics.wheel_speeds()[0].mean()
        ratios[friction] = rim / max(physics.body_velocity()[0, 0], 1e-6)
    assert ratios[1.0] == pytest.approx(1.0, abs=0.05) and ratios[0.05] > 1.5


def test_a_robot_driven_into_a_box_stops_and_is_in_collision():
    scenario = load_scenario("obstacles")
    physics = FleetPhysics(scenario, BaseParams())
    box = scenario.obstacles[0]
    start = np.array([[box.x_m - 0.6, box.y_m, 0.0], [4.0, 2.0, math.pi], [1.0, 3.0, 0.0]])
    physics.reset(start)
    physics.set_wheel_targets(np.array([[0.3 / R] * 2, [0.0] * 2, [0.0] * 2]))
    physics.step(2000)  # 4 s at 0.3 m/s would be 1.2 m
    x = physics.poses()[0, 0]
    assert x < box.x_m - box.size_x_m / 2 - scenario.robot.radius_m + 0.02
    assert physics.in_collision()[0] and not physics.in_collision()[1:].any()


def test_rays_see_walls_and_other_robots_and_not_their_own_robot():
    scenario = load_scenario("obstacles")
    physics = FleetPhysics(scenario, BaseParams())
    poses = np.array([[1.0, 1.0, 0.0], [2.0, 1.0, 0.0], [1.0, 3.0, 0.0]])
    physics.reset(poses)
    at = physics.poses()
    ranges = physics.cast(0, at[0, :2], np.array([-math.pi / 2, math.pi, 0.0]))
    room = scenario.room
    assert ranges[0] == pytest.approx(at[0, 1] - room.y_min_m, abs=0.002)
    assert ranges[1] == pytest.approx(at[0, 0] - room.x_min_m, abs=0.002)
    assert ranges[2] == pytest.approx(at[1, 0] - at[0, 0] - scenario.robot.radius_m, abs=0.01)  # robot_2's body


def test_displaced_boxes_and_walls_move_the_hits():
    scenario = load_scenario("obstacles")
    box = scenario.obstacles[0]
    origin = np.array([box.x_m - 1.0, box.y_m])
    hits = {}
    for dx, wall in ((0.0, 0.0), (0.05, 0.03)):
        physics = FleetPhysics(scenario, BaseParams(), box_offsets_m=np.array([[dx, 0.0]]), wall_offset_m=wall)
        physics.reset(np.array([[origin[0], origin[1] - 0.5, 0.0], [4.0, 2.0, math.pi], [1.0, 3.0, 0.0]]))
        hits[dx] = physics.cast(0, origin, np.array([0.0, -math.pi / 2]))
    assert hits[0.05][0] - hits[0.0][0] == pytest.approx(0.05, abs=1e-6)
    assert hits[0.05][1] - hits[0.0][1] == pytest.approx(0.03, abs=1e-6)


def test_the_same_inputs_give_the_same_poses_bit_for_bit(empty):
    runs = []
    for _ in range(2):
        physics = FleetPhysics(empty, BaseParams(friction=0.3, max_wheel_accel_radps2=30.0))
        drive(physics, 6.0, 9.0, 1.0)
        runs.append(physics.poses().tobytes() + physics.wheel_angles().tobytes())
    assert runs[0] == runs[1]


@pytest.mark.parametrize(
    ("base", "offsets", "key"),
    [
        (BaseParams(wheel_radius_left_m=-0.03), None, "base.wheel_radius_left_m"),
        (BaseParams(deadband_radps=-1.0), None, "base.deadband_radps"),
        (BaseParams(max_wheel_accel_radps2=0.0), None, "base.max_wheel_accel_radps2"),
        (BaseParams(), np.zeros((3, 2)), "map.box_offsets_m"),
        (BaseParams(), np.zeros((1, 3)), "map.box_offsets_m"),
    ],
)
def test_bad_parameters_are_named(base, offsets, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        FleetPhysics(load_scenario("obstacles"), base, box_offsets_m=offsets)
