"""The reality profile's schema is defined once (pipeline/core/reality.py): the twin loads it, calibration estimates
its keys within its bounds, and the SPARK's nominal geometry is the scenario's."""

from __future__ import annotations

import math

import pytest

from pipeline.calibration.estimates import Estimate
from pipeline.calibration.keys import PROFILE_KEYS, within_physical_ranges, world_bounds
from pipeline.core import reality
from pipeline.core.scenario import SPARK_WHEEL_RADIUS_M, SPARK_WHEEL_SEPARATION_M
from pipeline.twin import profile as twin_profile


def test_every_estimated_key_is_a_key_of_the_schema():
    for group, names in PROFILE_KEYS.items():
        for name in names:
            assert reality.profile_setting(f"{group}.{name}").name == name
    with pytest.raises(KeyError):
        reality.profile_setting("lidar.no_such_key")


def test_the_twin_loads_the_one_schema_and_the_nominal_geometry_is_the_spark_s():
    assert twin_profile.RealityProfile is reality.RealityProfile
    assert reality.BaseProfile().wheel_radius_left_m == SPARK_WHEEL_RADIUS_M
    assert reality.BaseProfile().wheel_separation_m == SPARK_WHEEL_SEPARATION_M
    _, lab = twin_profile.load_profile("lab")
    assert isinstance(lab, reality.RealityProfile)


def test_exclusive_bounds_are_kept_inside_and_open_ends_are_infinite():
    low, high = reality.profile_bounds("network.loss_prob")  # ge 0, lt 1
    assert low == 0.0 and high < 1.0 and math.nextafter(high, 2.0) == 1.0
    low, _ = reality.profile_bounds("actuation.time_constant_s")  # gt 0
    assert 0.0 < low < 1e-300
    assert world_bounds("actuation.time_constant_s")[0] > 0.0  # the simulator's lag is > 0 too
    assert reality.bounds_of({}) == (-math.inf, math.inf)


def test_an_estimate_a_robot_cannot_have_is_not_a_setting_though_the_simulator_would_take_it():
    # the simulator's lidar bias may be +-1 m; a real lidar's (the profile's) +-0.5 m
    far = Estimate.of(0.7, 0.01, (0.68, 0.72), "m", "test", 100)
    near = Estimate.of(0.2, 0.01, (0.18, 0.22), "m", "test", 100)
    out = within_physical_ranges({"lidar.bias_m": far, "lidar.noise_sigma_m": near})
    assert not out["lidar.bias_m"].ok and "outside its physical range" in out["lidar.bias_m"].reason
    assert ">= -0.5 and <= 0.5" in out["lidar.bias_m"].reason
    assert out["lidar.noise_sigma_m"] == near
