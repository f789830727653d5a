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
from pipeline.twin.sensors import (
    LIDAR_RANGE_MAX_M,
    MAST_RANGE_M,
    BurstLoss,
    EncoderOdometry,
    LidarSweep,
    RobotClock,
)

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


def sweeps(profile: LidarProfile, true_m: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """(n, beams) ranges of `n` sweeps of the same true ranges."""
    sweep = LidarSweep(profile, np.random.default_rng(seed))
    out = []
    for _ in range(n):
        sweep.restart(0)
        sweep.measure(np.arange(sweep.beams), true_m)
        out.append(sweep.ranges.copy())
    return np.array(out)


def test_ranges_come_in_the_profile_s_steps_and_the_noise_keeps_its_spread():
    true = np.linspace(0.5, 5.0, 360)
    step = 0.002
    ranges = sweeps(lidar(noise_sigma_m=0.003, range_step_m=step), true, 60)
    units = ranges / step
    assert np.abs(units - np.round(units)).max() < 1e-6  # every range on the lattice
    assert len(np.unique(np.round(units[:, 100]))) > 3  # and still noisy
    spread = float(np.std(ranges - true[None, :]))
    assert spread == pytest.approx(math.sqrt(0.003**2 + step**2 / 12), rel=0.05)
    continuous = sweeps(lidar(noise_sigma_m=0.003), true, 5)
    assert np.abs(continuous / step - np.round(continuous / step)).max() > 0.1


@pytest.mark.parametrize(("convention", "reads"), [("inf", math.inf), ("zero", 0.0), ("max", LIDAR_RANGE_MAX_M)])
def test_a_beam_without_a_return_reads_the_driver_s_convention(convention, reads):
    true = np.concatenate([np.full(180, 2.0), np.full(180, 9.0)])  # beyond range: no return
    ranges = sweeps(lidar(no_return=convention, dropout_prob=0.1), true, 20)
    assert (ranges[:, 180:] == reads).all()
    dropped = ranges[:, :180] == reads
    assert 0.05 < dropped.mean() < 0.15 and (ranges[:, :180][~dropped] == 2.0).all()


def test_no_return_as_nan():
    ranges = sweeps(lidar(no_return="nan"), np.full(360, 9.0), 1)
    assert np.isnan(ranges).all()


def test_mixed_pixels_lie_between_the_surfaces_of_a_depth_edge_and_nowhere_else():
    true = np.where(np.arange(360) % 20 < 10, 1.0, 3.0)  # 36 depth edges per sweep
    ranges = sweeps(lidar(mixed_pixel_prob=0.5), true, 40)
    between = (ranges > 1.0) & (ranges < 3.0)
    edge = true != np.roll(true, 1)  # the first beam's neighbour is the last of the sweep before
    assert not between[:, ~edge].any() and not between[0, 0]  # (none before the first sweep)
    assert between[1:, edge].mean() == pytest.approx(0.5, abs=0.06)


def test_beam_noise_differs_per_beam_with_mean_square_one():
    ranges = sweeps(lidar(noise_sigma_m=0.01, beam_noise_spread=0.4), np.full(360, 2.0), 200)
    per_beam = ranges.std(axis=0)
    assert per_beam.max() / per_beam.min() > 2.0  # uneven
    assert math.sqrt(float(np.mean(per_beam**2))) == pytest.approx(0.01, rel=0.1)
    again = sweeps(lidar(noise_sigma_m=0.01, beam_noise_spread=0.4), np.full(360, 2.0), 200)
    assert np.corrcoef(per_beam, again.std(axis=0))[0, 1] > 0.9  # fixed per unit (same seed)


def test_beams_point_off_their_stated_angles_by_the_profile_s_jitter():
    sweep = LidarSweep(lidar(beam_angle_jitter_rad=0.002), np.random.default_rng(3))
    off = sweep.angles - 2 * math.pi * np.arange(360) / 360
    assert float(np.std(off)) == pytest.approx(0.002, rel=0.15)
    assert (LidarSweep(lidar(), np.random.default_rng(3)).angles == 2 * math.pi * np.arange(360) / 360).all()


def test_the_sweep_period_wanders_and_scans_are_dropped_at_the_profile_s_rates():
    sweep = LidarSweep(lidar(rate_wander=0.02, scan_drop_prob=0.1), np.random.default_rng(4))
    periods, drops = [], 0
    for _ in range(2000):
        periods.append(sweep.period_ns)
        drops += sweep.dropped()
        sweep.restart(sweep.end_ns)
    rel = np.array(periods) / (125 * MS)
    assert float(np.mean(rel)) == pytest.approx(1.0, abs=0.002) and float(np.std(rel)) == pytest.approx(0.02, rel=0.1)
    assert drops / 2000 == pytest.approx(0.1, abs=0.02)
    steady = LidarSweep(lidar(), np.random.default_rng(4))
    assert steady.period_ns == 125 * MS and not any(steady.dropped() for _ in range(100))


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
        (lambda p: p["lidar"].update(no_return="none"), "lidar.no_return"),
        (lambda p: p["lidar"].update(range_step_m=-0.001), "lidar.range_step_m"),
        (lambda p: p["lidar"].update(scan_drop_prob=1.0), "lidar.scan_drop_prob"),
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
