"""Calibration's tables of profile keys and the simulator settings they become agree with the one reality model
(pipeline.core.quantities.SHARED): each shared quantity is either in a table or left out of it by name."""

from __future__ import annotations

import dataclasses

from pipeline.calibration.keys import (
    NETWORK_RATE_SOURCES,
    NETWORK_SOURCES,
    PHYSICAL_KEYS,
    PHYSICAL_LEFT_OUT,
    PROFILE_KEYS,
    RANDOMIZED_LEFT_OUT,
    RANDOMIZED_SOURCES,
    physical_ranges,
)
from pipeline.core.quantities import SHARED
from pipeline.core.reality import profile_setting
from pipeline.params import RandomizeConfig, WorldConfig


def _setting(key: str) -> str:
    section, sim_key, _ = SHARED[key]
    return f"{section}.{sim_key}"


def _randomized_settings() -> set[str]:
    return {key for key, _ in RandomizeConfig().entries()}


def test_every_physical_key_becomes_the_shared_quantity_s_setting():
    for key, setting in PHYSICAL_KEYS.items():
        assert setting == _setting(key), key
        assert physical_ranges(key, setting)  # a setting of the simulator's world


def test_every_shared_quantity_is_range_checked_or_left_out_by_name():
    outside_network = {key for key, (section, _, _) in SHARED.items() if section != "network"}
    assert set(PHYSICAL_LEFT_OUT) <= outside_network
    assert not set(PHYSICAL_KEYS) & set(PHYSICAL_LEFT_OUT)
    assert set(PHYSICAL_KEYS) | set(PHYSICAL_LEFT_OUT) == outside_network
    checked = {**PHYSICAL_KEYS, **{v: f"network.{k}" for k, v in NETWORK_SOURCES.items()}}
    assert set(SHARED) - set(checked) == set(PHYSICAL_LEFT_OUT)


def test_the_network_takes_every_shared_network_quantity_and_the_sensors_rates():
    shared = {sim_key: key for key, (section, sim_key, _) in SHARED.items() if section == "network"}
    assert {**NETWORK_RATE_SOURCES, **shared} == NETWORK_SOURCES
    assert not set(NETWORK_RATE_SOURCES) & set(shared) and not set(NETWORK_RATE_SOURCES.values()) & set(SHARED)
    network = {f.name for f in dataclasses.fields(WorldConfig().network)}
    assert set(NETWORK_SOURCES) <= network
    for source in NETWORK_SOURCES.values():
        assert profile_setting(source) is not None


def test_training_draws_every_shared_quantity_it_has_a_range_of_and_no_other():
    pairs = {(_setting(key), key) for key in SHARED} | {(f"network.{k}", v) for k, v in NETWORK_SOURCES.items()}
    assert set(RANDOMIZED_SOURCES.items()) <= pairs
    assert not set(RANDOMIZED_SOURCES.values()) & set(RANDOMIZED_LEFT_OUT)
    assert set(RANDOMIZED_LEFT_OUT) <= set(SHARED)
    assert set(SHARED) - set(RANDOMIZED_SOURCES.values()) == set(RANDOMIZED_LEFT_OUT)
    # a setting training draws is one the simulator's randomization has; a shared one it has is drawn
    ranged = _randomized_settings()
    assert set(RANDOMIZED_SOURCES) <= ranged
    shared_settings = {_setting(key) for key in SHARED} | {f"network.{k}" for k in NETWORK_SOURCES}
    assert ranged & shared_settings == set(RANDOMIZED_SOURCES)
    assert {_setting(key) for key in RANDOMIZED_LEFT_OUT}.isdisjoint(ranged)


def test_every_shared_quantity_is_estimated():
    estimated = {f"{group}.{name}" for group, names in PROFILE_KEYS.items() for name in names}
    for key, (_, _, quantity) in SHARED.items():
        assert key in estimated or quantity.per_element, f"{key} is shared but calibration does not estimate it"


def test_the_tables_keep_the_order_calibration_yaml_is_written_in():
    """calibration.yaml's world and randomization sections are written in these tables' order (``sort_keys=False``):
    a quantity added to SHARED lands at its place in its group, and the tables as they stand keep their order."""
    lidar = [f"lidar.{k}" for k in ("noise_sigma_m", "dropout_prob", "bias_m", "mount_yaw_rad")]
    actuation = [f"actuation.{k}" for k in ("delay_s", "time_constant_s", "linear_gain", "angular_gain")]
    assert list(PHYSICAL_KEYS.items()) == [
        *((k, k) for k in lidar),
        *((k, k) for k in actuation),
        ("odometry.drift_per_m", "odometry.drift_per_m"),
        ("base.deadband_radps", "actuation.deadband_radps"),
        ("base.wheel_radius_left_m", "actuation.wheel_radius_m"),
        ("base.wheel_radius_right_m", "actuation.wheel_radius_m"),
        ("base.wheel_separation_m", "actuation.wheel_separation_m"),
    ]
    network = [
        ("scan_rate_hz", "lidar.rate_hz"),
        ("odom_rate_hz", "odometry.rate_hz"),
        ("loss_prob", "network.loss_prob"),
        ("burst_len", "network.burst_len"),
        ("jitter_s", "network.jitter_s"),
    ]
    assert list(NETWORK_SOURCES.items()) == [
        *network,
        ("clock_offset_s", "clock.offset_s"),
        ("clock_drift_ppm", "clock.drift_ppm"),
    ]
    assert list(RANDOMIZED_SOURCES.items()) == [
        *((k, k) for k in ("lidar.noise_sigma_m", "lidar.noise_per_m", "lidar.dropout_prob", "lidar.bias_m")),
        ("lidar.mount_yaw_rad", "lidar.mount_yaw_rad"),
        *((k, k) for k in actuation),
        ("odometry.drift_per_m", "odometry.drift_per_m"),
        ("actuation.deadband_radps", "base.deadband_radps"),
        *((f"network.{k}", v) for k, v in network),
    ]
