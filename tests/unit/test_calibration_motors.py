"""Deadband and acceleration limit of the wheel motors from synthetic robot-episodes with a known wheel chain."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from pipeline.calibration.actuation import CommandTimeline, VelocityTrack
from pipeline.calibration.estimates import Estimate, bootstrap
from pipeline.calibration.gains import GAIN_AGREEMENT_TOLERANCE, GainAgreement, deadband_gains, drive_gains
from pipeline.calibration.motors import (
    WheelEpisode,
    _refine,
    _samples,
    _transient_costs,
    _widened,
    estimate_motors,
    small_sample_factor,
    wheel_speeds,
)
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.wheels import NOMINAL_WHEEL_RADIUS_M, NOMINAL_WHEEL_SEPARATION_M

NS = 1_000_000_000
PHYSICS_S = 0.0025
ODOM_S = 0.025
TICKS_PER_REV = 1560
SETTINGS = CalibrationSettings(bootstrap=100)


def episode(
    rng: np.random.Generator,
    cluster: str,
    deadband: float,
    accel: float | None,
    gains: tuple[float, float] = (0.95, 0.9),
    delay_s: float = 0.08,
    driver_lag_s: float = 0.12,
    motor_lag_s: float = 0.06,
    seconds: float = 12.0,
    w_max: float = 0.2,
    policy: bool = False,
    command_phase_s: float = 0.0,
) -> WheelEpisode:
    """A robot-episode of excitation phases (stand, turn, arc, straight, each held 0.6-2 s, commands at 10 Hz)
    through the wheel chain (delay, driver lag, gains, deadband, slew limit, motor lag) integrated at 2.5 ms;
    odometry from encoder ticks every 25 ms. With `policy`, commands that change every 0.1 s as a policy's
    do (small changes, and in three steps of ten a jump to any speed and turn rate), so none is ever held. The
    commands are sent `command_phase_s` after each tenth of a second."""
    t_cmd, values = [], []
    t = 0.0
    v, w = 0.0, 0.0
    while policy and t < seconds:
        jump = rng.random() < 0.3
        v = float(rng.uniform(0.0, 0.4) if jump else np.clip(v + rng.normal(0.0, 0.03), 0.0, 0.4))
        w = float(rng.uniform(-w_max, w_max) if jump else np.clip(w + rng.normal(0.0, 0.03), -w_max, w_max))
        t_cmd.append(t)
        values.append((v, w))
        t += 0.1
    while t < seconds:
        phase = rng.choice(["stand", "turn", "arc", "straight"])
        hold = rng.uniform(0.6, 2.0)
        if phase == "turn":
            cmd = (0.0, rng.choice([-1, 1]) * rng.uniform(0.08, 1.0) * w_max)
        elif phase == "arc":
            cmd = (rng.uniform(0.1, 0.4), rng.uniform(-1, 1) * w_max)
        elif phase == "straight":
            cmd = (rng.uniform(0.1, 0.4), 0.0)
        else:
            cmd = (0.0, 0.0)
        for k in range(int(hold / 0.1)):
            t_cmd.append(t + k * 0.1)
            values.append(cmd)
        t += int(hold / 0.1) * 0.1
    t_cmd_ns = np.round((np.asarray(t_cmd) + command_phase_s) * NS).astype(np.int64)
    timeline = CommandTimeline(t_cmd_ns, np.asarray(values, dtype=float))
    n = int(seconds / PHYSICS_S)
    times_ns = np.round(np.arange(n) * PHYSICS_S * NS).astype(np.int64)
    u = timeline.at(times_ns - round(delay_s * NS), 0.5)
    driver, setpoint, wheel, angle = np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2)
    a_driver = 1 - math.exp(-PHYSICS_S / driver_lag_s)
    a_motor = 1 - math.exp(-PHYSICS_S / motor_lag_s)
    every = round(ODOM_S / PHYSICS_S)
    per_tick = 2 * math.pi / TICKS_PER_REV
    odom_t, odom_w = [], []
    last = np.zeros(2)
    for k in range(n):
        driver += a_driver * (u[k] - driver)
        target = wheel_speeds(np.array([driver[0] * gains[0]]), np.array([driver[1] * gains[1]]))[0]
        target[np.abs(target) < deadband] = 0.0
        if accel is None:
            setpoint = target
        else:
            setpoint = setpoint + np.clip(target - setpoint, -accel * PHYSICS_S, accel * PHYSICS_S)
        wheel += a_motor * (setpoint - wheel)
        angle += wheel * PHYSICS_S
        if (k + 1) % every == 0:
            ticks = np.floor(angle / per_tick) * per_tick
            odom_t.append(times_ns[k] + round(PHYSICS_S * NS))
            odom_w.append((ticks - last) / ODOM_S)
            last = ticks
    t_ns = np.asarray(odom_t, dtype=np.int64)
    return WheelEpisode("robot", cluster, 0, t_ns, np.asarray(odom_w), np.ones(len(t_ns), dtype=bool), timeline)


def covers(est, truth: float) -> bool:
    return est.ok and est.interval[0] <= truth <= est.interval[1]


def test_a_lab_motor_deadband_and_acceleration_limit_are_recovered():
    rng = np.random.default_rng(0)
    episodes = [episode(rng, f"episode {k}", deadband=0.6, accel=25.0) for k in range(8)]
    fit = estimate_motors(episodes, ODOM_S, SETTINGS, np.random.default_rng(1))
    assert fit.deadband_radps.value == pytest.approx(0.6, abs=0.1) and covers(fit.deadband_radps, 0.6)
    accel = fit.max_wheel_accel_radps2
    assert accel.value == pytest.approx(25.0, rel=0.15) and covers(accel, 25.0)
    assert fit.gains == pytest.approx((0.95, 0.9), rel=0.03)


def test_motors_without_deadband_or_limit():
    """No deadband reads as one near 0; no limit is unidentifiable with the bound the data give."""
    rng = np.random.default_rng(2)
    episodes = [episode(rng, f"episode {k}", deadband=0.0, accel=None) for k in range(8)]
    fit = estimate_motors(episodes, ODOM_S, SETTINGS, np.random.default_rng(3))
    assert fit.deadband_radps.ok and fit.deadband_radps.value <= 0.1 and fit.deadband_radps.interval[0] == 0.0
    assert not fit.max_wheel_accel_radps2.ok and "no limit binds" in fit.max_wheel_accel_radps2.reason


def test_a_deadband_is_unidentifiable_without_small_commands():
    """Commands that never ask a wheel for less than the deadband grid's top cannot tell a deadband."""
    rng = np.random.default_rng(4)
    episodes = []
    for k in range(4):
        e = episode(rng, f"episode {k}", deadband=0.6, accel=25.0)
        big = np.where(np.abs(e.commands.values) > 0, e.commands.values, 0.0)
        big[:, 0] = np.where(big[:, 0] != 0, 0.4, 0.0)
        big[:, 1] = 0.0  # straight runs at 0.4 m/s only: every wheel command is 11.8 rad/s or 0
        straight = CommandTimeline(e.commands.t_ns, big)
        episodes.append(WheelEpisode(e.robot, e.cluster, e.start_ns, e.t_ns, e.wheels, e.free, straight))
    fit = estimate_motors(episodes, ODOM_S, SETTINGS, np.random.default_rng(5))
    assert not fit.deadband_radps.ok and "shows only there" in fit.deadband_radps.reason


def test_a_limit_is_recovered_from_a_policys_commands_that_leave_the_deadband_open():
    """A policy never holds a command: the deadband is unidentifiable and held commands leave every deadband from 0
    to the grid's top open. The transients choose one; the limit's interval still holds the truth."""
    rng = np.random.default_rng(8)
    episodes = [episode(rng, f"episode {k}", deadband=0.5, accel=25.0, policy=True) for k in range(8)]
    fit = estimate_motors(episodes, ODOM_S, SETTINGS, np.random.default_rng(9))
    assert not fit.deadband_radps.ok
    accel = fit.max_wheel_accel_radps2
    # within two steps of the limit grid (10 % each); the arbitrary deadband the transients had before read 31.6
    assert covers(accel, 25.0) and accel.value == pytest.approx(25.0, rel=0.2), accel
    assert "deadband for them 0.5 rad/s" in fit.notes[0]


def test_a_limit_between_the_first_passs_values_does_not_hold_the_delay_at_the_edge_of_the_second():
    """A slow limit (23.6 rad/s^2, between the first pass's 20 and 40) bent its delay to 60-80 ms for a 30 ms one;
    the second pass, 10 ms either side, then read 40 ms with the motors' lag short (85 ms, interval up to 98 ms, for
    100). Its window now moves until the least cost lies two steps inside it."""
    rng = np.random.default_rng(3)
    episodes = [
        episode(rng, f"episode {k}", 0.5, 23.6, delay_s=0.03, driver_lag_s=0.18, motor_lag_s=0.1) for k in range(10)
    ]
    fit = estimate_motors(episodes, ODOM_S, SETTINGS, np.random.default_rng(0))
    assert fit.delay_s.value == pytest.approx(0.03, abs=0.005) and covers(fit.delay_s, 0.03), fit.delay_s
    assert covers(fit.motor_time_constant_s, 0.1), fit.motor_time_constant_s
    assert covers(fit.max_wheel_accel_radps2, 23.6), fit.max_wheel_accel_radps2


def test_too_few_episodes_are_unidentifiable():
    rng = np.random.default_rng(6)
    fit = estimate_motors([episode(rng, "only", 0.6, 25.0)], ODOM_S, SETTINGS, np.random.default_rng(7))
    assert not fit.deadband_radps.ok and not fit.max_wheel_accel_radps2.ok and "needs 2" in fit.deadband_radps.reason


def continuous_episode(rng: np.random.Generator, delay_s: float, lags_s: tuple[float, float]) -> WheelEpisode:
    """Commands changed at arbitrary times (every 0.3-1.2 s) through a delay and two lags in series, integrated at
    0.1 ms (as good as continuous); odometry every 25 ms, from an arbitrary phase, the exact mean wheel speed over
    its period."""
    h, seconds = 1e-4, 20.0
    t = np.cumsum(rng.uniform(0.3, 1.2, 30))
    t = t[t < seconds - 1.0]
    values = np.stack([rng.uniform(0.0, 0.4, len(t)), rng.uniform(-0.2, 0.2, len(t))], axis=1)
    timeline = CommandTimeline(np.round(t * NS).astype(np.int64), values)
    fine = np.arange(0.0, seconds, h)
    u = timeline.at(np.round((fine - delay_s) * NS).astype(np.int64), 5.0)
    wheels = wheel_speeds(u[:, 0], u[:, 1])
    for tau in lags_s:
        a = math.exp(-h / tau)
        wheels = lfilter([1.0 - a], [1.0, -a], wheels, axis=0)
    travelled = np.cumsum(wheels, axis=0) * h
    stamps = np.arange(1.0 + rng.uniform(0.0, ODOM_S), seconds - 0.1, ODOM_S)
    end, span = np.round(stamps / h).astype(int), round(ODOM_S / h)
    achieved = (travelled[end] - travelled[end - span]) / ODOM_S
    ok = np.ones(len(stamps), dtype=bool)
    return WheelEpisode("robot", "episode", 0, np.round(stamps * NS).astype(np.int64), achieved, ok, timeline)


@pytest.mark.parametrize("delay_s", [0.03, 0.05, 0.07, 0.11])
def test_the_transients_time_a_delay_within_half_a_step_of_the_chain(delay_s):
    """The chain is simulated in 10 ms steps, each stage taking its input's value at a step's end as held through
    the step and the wheels' mean over an odometry period read from end-of-step values: the commands and the
    windows are placed so that the delay that fits best is the true one (these read 10-15 ms long before)."""
    episode = continuous_episode(np.random.default_rng(int(delay_s * 1000)), delay_s, (0.1, 0.05))
    delays = np.round(np.arange(0.0, 0.15, 0.005), 3)
    costs = _transient_costs(
        episode, 0.0, (1.0, 1.0), ODOM_S, 5.0, delays, np.array([np.inf]), np.array([0.15]), np.array([1 / 3])
    )
    assert delays[int(np.argmin(costs[:, 0, 0, 0]))] == pytest.approx(delay_s, abs=0.0051)


@pytest.mark.parametrize("delay_s", [0.03, 0.037, 0.045])
def test_the_refinement_reads_a_delay_and_lags_between_the_grids_values(delay_s):
    """Commands changed at arbitrary times through a delay between the grid's 10 ms steps and lags of 0.1 and
    0.043 s (between the grid's values): least squares from a grid point, on a chain in 2 ms steps whose inputs are
    the command's mean over each step, reads the delay within 1.5 ms (the second lag takes the first's value at a
    step's end as held through the step, half a step early, as a drive's control loop does) and the lags within
    2 %. Without a deadband or a limit the two lags commute, so only the pair is asked for."""
    episodes = [continuous_episode(np.random.default_rng(20 + k), delay_s, (0.1, 0.043)) for k in range(3)]
    samples = [_samples(e, (1.0, 1.0), ODOM_S, 5.0) for e in episodes]
    fit = _refine(samples, 0.0, (round(delay_s, 2), 0.114, 0.038, math.inf))
    assert fit.values[0] == pytest.approx(delay_s, abs=0.0015)
    assert sorted(np.exp(fit.values[1:3])) == pytest.approx([0.043, 0.1], rel=0.02)


def test_the_motors_lag_is_read_between_the_grids_values():
    """A motor lag of 28 ms behind a driver lag of 95 ms: the grid's total lags (12 % apart) and the motors' share
    of them (in twelfths) read 43 ms [37, 50] ms, the truth outside; least squares between the grid's values reads
    it within 10 % and the interval holds it."""
    rng = np.random.default_rng(1)
    episodes = [
        episode(
            rng, f"c{k}", 0.006, 30.1, delay_s=0.061, driver_lag_s=0.095, motor_lag_s=0.028, seconds=20.0, w_max=1.0
        )
        for k in range(10)
    ]
    fit = estimate_motors(episodes, ODOM_S, SETTINGS, np.random.default_rng(0))
    assert fit.motor_time_constant_s.value == pytest.approx(0.028, rel=0.1), fit.motor_time_constant_s
    assert covers(fit.motor_time_constant_s, 0.028), fit.motor_time_constant_s
    assert fit.driver_time_constant_s.value == pytest.approx(0.095, rel=0.1), fit.driver_time_constant_s
    assert fit.delay_s.value == pytest.approx(0.061, abs=0.005), fit.delay_s
    assert "between the grid's values" in fit.notes[0]


def test_the_small_sample_factor_makes_a_ten_cluster_bootstrap_cover_95_percent():
    """The lags' intervals rest on a bootstrap over the 10 robot-episodes the transients use. A percentile bootstrap
    over 10 clusters is too narrow: for a lag whose log varies between robot-episodes (a lognormal cluster mean,
    400 trials) its interval covers the truth 91 % of the time; stretched by the small-sample factor, 95 %."""
    assert small_sample_factor(10) == pytest.approx(1.2166, abs=1e-3)
    assert small_sample_factor(1000) == pytest.approx(1.0, abs=2e-3)
    rng = np.random.default_rng(7)
    truth = 0.05
    plain = widened = 0
    for _ in range(400):
        lags = truth * np.exp(rng.normal(0.0, 0.3, 10))  # each robot-episode's lag
        value = float(np.exp(np.mean(np.log(lags))))
        logs = np.log(lags)
        draws = bootstrap(lambda c, logs=logs: np.array([np.exp(c @ logs / c.sum())]), 10, 200, rng)[:, 0]
        lo, hi = np.percentile(draws, [2.5, 97.5])
        plain += lo <= truth <= hi
        lo, hi = _widened(value, float(lo), float(hi), 10)
        widened += lo <= truth <= hi
    assert plain <= 0.92 * 400 and widened >= 0.94 * 400, (plain, widened)


def _track(commands: np.ndarray) -> VelocityTrack:
    t_ns = np.arange(len(commands), dtype=np.int64) * 100_000_000
    return VelocityTrack("robot_1", "e0", t_ns, np.zeros((len(commands), 2)), CommandTimeline(t_ns, commands))


def test_without_a_deadband_the_simulators_drive_reads_its_own_gains():
    rng = np.random.default_rng(3)
    commands = np.column_stack([rng.uniform(0, 0.3, 200), rng.uniform(-1.5, 1.5, 200)])
    assert deadband_gains([_track(commands)], (0.9, 0.8), 0.0, 0.5) == pytest.approx((0.9, 0.8), rel=1e-12)


def test_a_deadband_lowers_the_body_gain_by_the_share_of_speed_under_it():
    """Pure turns: each wheel's rim speed is w * b / 2; half the commands leave both wheels under the deadband."""
    half_rim = NOMINAL_WHEEL_SEPARATION_M / 2
    deadband = 1.0  # rad/s at the wheel: 0.034 m/s at the rim
    under = 0.5 * deadband * NOMINAL_WHEEL_RADIUS_M / half_rim  # a turn whose wheels stay under it
    over = 4.0 * deadband * NOMINAL_WHEEL_RADIUS_M / half_rim
    commands = np.array([[0.0, under], [0.0, -under], [0.0, over], [0.0, -over]] * 10)
    _, angular = deadband_gains([_track(commands)], (1.0, 1.0), deadband, 0.5)
    assert angular == pytest.approx(over**2 / (over**2 + under**2), rel=1e-12)


def test_gains_read_two_ways_agree_within_the_interval_and_its_stated_slack():
    fit = Estimate("ok", 0.80, 0.005, (0.79, 0.81), "ratio")
    assert GainAgreement("angular", fit, 0.85, 0.80, 0.85).agrees
    assert GainAgreement("angular", fit, 0.85, 0.81 * (1 + GAIN_AGREEMENT_TOLERANCE) - 1e-3, 0.85).agrees
    far = GainAgreement("angular", fit, 0.95, 0.90, 0.85)
    assert not far.agrees and "differ" in far.sentence() and "0.900" in far.sentence()


def test_the_simulators_gains_move_its_body_as_the_body_velocity_fit_read_it():
    """A drive with gains (0.8, 0.75) and a 0.6 rad/s deadband: the body-velocity fit reads the smaller gains that
    drive shows over the commands. From wheel-chain gains 5 % off, the simulator's gains come back to the drive's own,
    and with them its drive reproduces the fit's reading; without a deadband they are the fit's."""
    rng = np.random.default_rng(11)
    commands = np.column_stack([rng.uniform(-0.03, 0.1, 400), rng.uniform(-0.4, 0.4, 400)])  # many near the deadband
    tracks = [_track(commands)]
    truth, deadband = (0.8, 0.75), 0.6
    read = deadband_gains(tracks, truth, deadband, 0.5)
    assert read is not None and read[1] < 0.97 * truth[1]  # the deadband takes speed away from the turns
    found = drive_gains(tracks, read, (0.84, 0.71), deadband, 0.5)
    assert found == pytest.approx(truth, rel=1e-9)
    assert deadband_gains(tracks, found, deadband, 0.5) == pytest.approx(read, rel=1e-9)
    assert drive_gains(tracks, (0.79, 0.74), (0.7, 0.7), 0.0, 0.5) == pytest.approx((0.79, 0.74), rel=1e-12)
    # a channel the fit did not read keeps the wheel chain's gain
    assert drive_gains(tracks, (math.nan, read[1]), (0.84, 0.71), deadband, 0.5)[0] == 0.84
