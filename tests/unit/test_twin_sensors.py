"""The twin's own sensors, clock and link: each behaviour the profile keys promise, measured."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.core.scenario import load_scenario
from pipeline.errors import ConfigError
from pipeline.mappings import from_mapping
from pipeline.twin.profile import (
    NOMINAL_WHEEL_RADIUS_M,
    NOMINAL_WHEEL_SEPARATION_M,
    ClockProfile,
    LidarProfile,
    OdometryProfile,
    RealityProfile,
    load_profile,
    load_profile_for,
)
from pipeline.twin.sensors import MAST_RANGE_M, BurstLoss, EncoderOdometry, LidarSweep, RobotClock

MS = 1_000_000


def lidar(**keys: object) -> LidarProfile:
    base = {
        "beams": 360,
        "rate_hz": 8.0,
        "noise_sigma_m": 0.0,
        "dropout_prob": 0.0,
        "bias_m": 0.0,
        "mount_yaw_rad": 0.0,
    }
    return from_mapping(LidarProfile, {**base, **keys}, "<test>")


# -- lidar ----------------------------------------------------------------------------------------


def test_with_motion_distortion_each_beam_is_taken_at_its_own_time_within_the_sweep():
    sweep = LidarSweep(lidar(motion_distortion=True), np.random.default_rng(0), t0_ns=1_000 * MS)
    assert sweep.period_ns == 125 * MS  # 8 Hz exactly, on no tick
    times = sweep.beam_time_ns(np.arange(360))
    assert times[0] == 1_000 * MS and times[-1] < 1_125 * MS and (np.diff(times) > 0).all()
    first_half = sweep.due(1_000 * MS + 125 * MS // 2)
    assert len(first_half) == 181
    sweep.measure(first_half, np.ones(len(first_half)))
    assert len(sweep.due(1_000 * MS + 125 * MS // 2)) == 0 and not sweep.complete


def test_without_motion_distortion_a_sweep_is_one_instant():
    sweep = LidarSweep(lidar(), np.random.default_rng(0), t0_ns=0)
    assert (sweep.beam_time_ns(np.arange(360)) == 0).all() and len(sweep.due(0)) == 360


def test_noise_grows_with_range_as_the_profile_says():
    sweep = LidarSweep(lidar(noise_sigma_m=0.01, noise_per_m=0.005), np.random.default_rng(1))
    k = np.arange(360)
    spread = {}
    for r in (1.0, 6.0):
        samples = []
        for _ in range(40):
            sweep.restart(0)
            sweep.measure(k, np.full(360, r))
            samples.append(sweep.ranges - r)
        spread[r] = np.std(np.concatenate(samples))
    assert spread[1.0] == pytest.approx(0.015, rel=0.08) and spread[6.0] == pytest.approx(0.04, rel=0.08)


def test_blocked_sectors_read_the_mast_and_far_returns_read_no_return():
    sweep = LidarSweep(lidar(blocked_sectors_rad=[[3.0, 3.3]]), np.random.default_rng(0))
    sweep.measure(np.arange(360), np.concatenate([np.full(180, 2.0), np.full(180, 9.0)]))
    angles = np.degrees(sweep.angles)
    blocked = (angles >= math.degrees(3.0)) & (angles <= math.degrees(3.3))
    assert blocked.sum() == 18 and (sweep.ranges[blocked] == MAST_RANGE_M).all()
    assert (sweep.ranges[:170] == 2.0).all() and np.isinf(sweep.ranges[~blocked & (angles >= 190)]).all()


def test_the_mounting_offset_moves_and_turns_the_lidar_with_the_base():
    sweep = LidarSweep(lidar(mount_xy_m=[0.05, 0.02], mount_yaw_rad=0.1), np.random.default_rng(0))
    origin, heading = sweep.pose_of_lidar(np.array([1.0, 2.0, math.pi / 2]))
    np.testing.assert_allclose(origin, [1.0 - 0.02, 2.0 + 0.05], atol=1e-12)
    assert heading == pytest.approx(math.pi / 2 + 0.1)


# -- odometry -------------------------------------------------------------------------------------


def _drive(odometry: EncoderOdometry, radius: tuple[float, float], separation: float, v: float, w: float) -> np.ndarray:
    """True poses of a base with wheel radii `radius` driven 10 s at (v, w); odometry updated at 40 Hz."""
    dt, pose, angles = 0.025, np.zeros(3), np.zeros((1, 2))
    for _ in range(400):
        wl = (v - w * separation / 2) / radius[0]
        wr = (v + w * separation / 2) / radius[1]
        angles = angles + np.array([[wl, wr]]) * dt
        pose = pose + np.array(
            [v * math.cos(pose[2] + w * dt / 2) * dt, v * math.sin(pose[2] + w * dt / 2) * dt, w * dt]
        )
        odometry.update(angles, dt)
    return pose


def test_encoder_odometry_is_exact_for_the_nominal_base():
    odometry = EncoderOdometry(1, OdometryProfile(rate_hz=40.0, drift_per_m=0.0), np.random.default_rng(0))
    odometry.reset(np.zeros((1, 3)), np.zeros((1, 2)))
    truth = _drive(odometry, (NOMINAL_WHEEL_RADIUS_M,) * 2, NOMINAL_WHEEL_SEPARATION_M, 0.3, 0.2)
    np.testing.assert_allclose(odometry.pose[0], truth, atol=1e-9)


def test_wrong_radii_and_separation_become_drift_and_heading_drift():
    odometry = EncoderOdometry(1, OdometryProfile(rate_hz=40.0, drift_per_m=0.0), np.random.default_rng(0))
    odometry.reset(np.zeros((1, 3)), np.zeros((1, 2)))
    truth = _drive(odometry, (0.0335, 0.0345), 0.287, 0.3, 0.0)  # the base truly drives straight 3 m
    assert abs(truth[1]) < 1e-9 and truth[0] == pytest.approx(3.0)
    # the driver integrates with 0.034 m wheels: the left one reads long, the right one short -> a turn
    expected_heading = NOMINAL_WHEEL_RADIUS_M * (3.0 / 0.0345 - 3.0 / 0.0335) / NOMINAL_WHEEL_SEPARATION_M
    assert odometry.pose[0, 2] == pytest.approx(expected_heading, rel=1e-6)
    assert abs(odometry.pose[0, 1]) > 0.05


def test_encoder_ticks_quantize_the_wheel_angles():
    odometry = EncoderOdometry(1, OdometryProfile(rate_hz=40.0, drift_per_m=0.0, encoder_ticks_per_rev=100), None)
    tick = 2 * math.pi / 100
    np.testing.assert_allclose(odometry.read_angles(np.array([[2.5 * tick, -0.5 * tick]])), [[2 * tick, -tick]])


# -- clock and link -------------------------------------------------------------------------------


def test_stamps_are_in_the_robot_clock():
    clock = RobotClock(ClockProfile(offset_s=0.035, drift_ppm=40.0), epoch_ns=10**18)
    assert clock.stamp(10**18) == 10**18 + 35 * MS
    assert clock.stamp(10**18 + 100 * 10**9) == 10**18 + 100 * 10**9 + 35 * MS + 4 * MS  # 40 ppm of 100 s


def _runs(lost: list[bool]) -> list[int]:
    runs, count = [], 0
    for x in [*lost, False]:
        if x:
            count += 1
        elif count:
            runs.append(count)
            count = 0
    return runs


@pytest.mark.parametrize("burst_len", [1.0, 4.0])
def test_losses_come_in_bursts_of_the_stated_mean_length_at_the_stated_rate(burst_len):
    loss = BurstLoss(0.05, burst_len, np.random.default_rng(3))
    lost = [loss.lost("/robot_1/scan") for _ in range(200_000)]
    assert np.mean(lost) == pytest.approx(0.05, rel=0.1)
    assert np.mean(_runs(lost)) == pytest.approx(burst_len / (1 - 0.05) if burst_len == 1 else burst_len, rel=0.1)


# -- profile keys ---------------------------------------------------------------------------------


def test_old_profiles_stay_valid_and_take_the_ideal_values():
    _, harsh = load_profile("harsh")
    assert harsh.base.wheel_radius_left_m == NOMINAL_WHEEL_RADIUS_M and harsh.clock.drift_ppm == 0.0
    assert harsh.lidar.blocked_sectors_rad == () and harsh.network.burst_len == 1.0
    _, lab = load_profile_for("lab", load_scenario("obstacles"))
    assert lab.lidar.motion_distortion and lab.odometry.encoder_ticks_per_rev == 1560 and lab.map.wall_offset_m > 0


@pytest.mark.parametrize(
    ("edit", "key"),
    [
        (lambda p: p["base"].update(wheel_radius_left_m=-0.03), "base.wheel_radius_left_m"),
        (lambda p: p["lidar"].update(blocked_sectors_rad=[[0.0, 7.0]]), "lidar.blocked_sectors_rad[0]"),
        (lambda p: p["lidar"].update(blocked_sectors_rad=[[1.0, 0.5]]), "lidar.blocked_sectors_rad[0]"),
        (lambda p: p["lidar"].update(mount_xy_m=[0.05]), "lidar.mount_xy_m"),
        (lambda p: p["clock"].update(skew=1), "clock.skew"),
        (lambda p: p["network"].update(burst_len=0.5), "network.burst_len"),
    ],
)
def test_bad_profile_values_are_named(tmp_path, edit, key):
    import yaml

    _, lab = load_profile("lab")
    from pipeline.mappings import to_mapping

    data = to_mapping(lab)
    edit(data)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_profile(path)
    assert str(path) in str(err.value) and key in str(err.value)


def test_more_box_offsets_than_boxes_is_refused_naming_the_key():
    with pytest.raises(ConfigError, match=r"(?s)lab\.yaml.*map\.box_offsets_m.*at most one offset per box"):
        load_profile_for("lab", load_scenario("empty"))
    assert isinstance(load_profile_for("lab", load_scenario("obstacles"))[1], RealityProfile)
