"""What a recording says about the floor: slip of the wheels under a moving body, and the acceleration it carried."""

from __future__ import annotations

import re

import numpy as np
import pytest

from pipeline.calibration.floor import G_MPS2, estimate_floor
from pipeline.calibration.odometry import OdometryEpisode

NS = 1_000_000_000
DT = 0.02


def episode(seed: int, accel: float, traction: float | None, wheel_scale: float = 1.0) -> OdometryEpisode:
    """A robot that starts and stops hard (`accel` m/s^2 commanded at the wheels) along a gentle arc, 50 Hz. With
    `traction` the body accelerates at most that much and the wheels run ahead of it (slip); the odometry reads the
    wheels' travel with nominal wheels `wheel_scale` times smaller than the true ones."""
    rng = np.random.default_rng(seed)
    wheel_v = body_v = 0.0
    truth = [np.array([1.0, 1.0, 0.0])]
    odom = [truth[0].copy()]
    for k in range(int(16.0 / DT)):
        target = 0.5 if (k * DT) % 4.0 < 2.0 else 0.0
        wheel_v += float(np.clip(target - wheel_v, -accel * DT, accel * DT))
        step = wheel_v - body_v
        if traction is not None:
            step = float(np.clip(step, -traction * DT, traction * DT))
        body_v += step
        w = 0.2
        x, y, yaw = truth[-1]
        truth.append(np.array([x + body_v * DT * np.cos(yaw), y + body_v * DT * np.sin(yaw), yaw + w * DT]))
        ox, oy, oyaw = odom[-1]
        travel = wheel_v * DT / wheel_scale
        odom.append(np.array([ox + travel * np.cos(oyaw), oy + travel * np.sin(oyaw), oyaw + w * DT]))
    truth_arr = np.array(truth)
    truth_arr[:, :2] += rng.normal(0.0, 0.0005, (len(truth_arr), 2))  # motion capture's noise
    t = (np.arange(len(truth)) * DT * NS).astype(np.int64)
    return OdometryEpisode("robot_1", f"episode {seed}", t, np.array(odom), truth_arr)


def test_a_floor_that_never_slipped_bounds_the_friction_from_below():
    fit = estimate_floor([episode(s, accel=1.5, traction=None) for s in range(4)])
    assert fit.slipping == 0 and fit.windows > 200
    assert not fit.friction.ok
    assert fit.transmitted_mps2 is not None and 1.0 < fit.transmitted_mps2 < 2.5
    bound = float(re.search(r"friction is at least ([0-9.]+)", fit.friction.reason).group(1))
    assert bound == pytest.approx(fit.transmitted_mps2 / G_MPS2, abs=0.01)
    assert "hard starts or fast turns" in fit.friction.reason


def test_wheels_that_run_ahead_of_the_body_read_the_acceleration_where_the_floor_gives_way():
    fit = estimate_floor([episode(s, accel=6.0, traction=1.2) for s in range(4)])
    assert fit.slipping >= 5
    assert fit.slip_mps2 == pytest.approx(1.2, rel=0.25)
    assert not fit.friction.ok and "slipped under a moving body" in fit.friction.reason
    assert "share of the weight on the driven wheels" in fit.friction.reason


def test_wheels_other_than_the_odometrys_nominal_ones_are_not_slip():
    # the odometry reads 3 % short everywhere: with the calibrated wheels' scale that is no slip
    episodes = [episode(s, accel=1.5, traction=None, wheel_scale=1.03) for s in range(4)]
    assert estimate_floor(episodes, wheel_scale=1.03).slipping == 0


def test_no_episodes_leave_the_floor_unsaid():
    fit = estimate_floor([])
    assert fit.windows == 0 and fit.transmitted_mps2 is None and "no windows" in fit.friction.reason


def test_robots_that_stand_still_say_nothing_about_the_floor():
    still = episode(0, accel=1.5, traction=None)
    still = OdometryEpisode(
        "robot_1",
        "still",
        still.t_ns,
        np.repeat(still.odom[:1], len(still.t_ns), 0),
        np.repeat(still.truth[:1], len(still.t_ns), 0),
    )
    fit = estimate_floor([still])
    assert fit.windows > 0 and "robots must drive" in fit.friction.reason
