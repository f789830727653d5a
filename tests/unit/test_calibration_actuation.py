"""The actuation fit recovers delay, time constant and gains of a simulated first-order system."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.calibration.actuation import CommandTimeline, VelocityTrack, estimate_actuation
from pipeline.calibration.options import CalibrationSettings

NS = 1_000_000_000
SETTINGS = CalibrationSettings(bootstrap=60, actuation_delay_max_s=0.5)


def simulate(
    rng: np.random.Generator,
    delay_s: float,
    tau_s: float,
    gains: tuple[float, float],
    duration_s: float = 15.0,
    turning: bool = True,
    noise: float = 0.003,
    start_s: float = 100.0,
    limits: tuple[float, float] = (math.inf, math.inf),
    v_levels: tuple[float, ...] = (0.0, 0.1, 0.2, 0.3, 0.4),
) -> tuple[np.ndarray, np.ndarray, CommandTimeline]:
    """Truth sample times (ns), achieved (v, w) at them with noise, and the commands as sent every 20 ms.

    The base follows ``gain * command`` cut at +-`limits` (its top speeds)."""
    h = 0.001
    t = start_s + np.arange(0, duration_s, h)
    # a new command every 0.1 s, sent (repeated) on a 20 ms grid
    steps = rng.integers(0, len(v_levels), size=int(duration_s / 0.1) + 1)
    v_choices = np.array(v_levels)
    w_levels = np.array([0.0, -0.2, -0.1, 0.1, 0.2]) if turning else np.zeros(5)
    w_steps = rng.integers(0, 5, size=len(steps))
    send = start_s + np.arange(0, duration_s, 0.02)
    k = np.minimum((np.round(send - start_s, 6) / 0.1).astype(int), len(steps) - 1)
    cmd = np.stack([v_choices[steps[k]], w_levels[w_steps[k]]], axis=1)
    timeline = CommandTimeline(np.round(send * NS).astype(np.int64), cmd)
    acting = timeline.at(np.round((t - delay_s) * NS).astype(np.int64), timeout_s=0.5)
    y = np.zeros((len(t), 2))
    top = np.array(limits)
    a = math.exp(-h / tau_s)
    for i in range(1, len(t)):
        y[i] = a * y[i - 1] + (1 - a) * np.clip(acting[i - 1] * np.array(gains), -top, top)
    sample = np.arange(0, len(t), 20)
    achieved = y[sample] + rng.normal(0, noise, size=(len(sample), 2))
    return np.round(t[sample] * NS).astype(np.int64), achieved, timeline


def tracks(rng: np.random.Generator, n: int, **kw: object) -> list[VelocityTrack]:
    out = []
    for i in range(n):
        t, y, cmd = simulate(rng, **kw)  # type: ignore[arg-type]
        out.append(VelocityTrack(f"robot_{i % 3 + 1}", f"episode {i}", t, y, cmd))
    return out


@pytest.mark.parametrize(("delay", "tau", "gains"), [(0.05, 0.15, (0.95, 0.9)), (0.15, 0.35, (0.8, 0.75))])
def test_delay_lag_and_gains_are_recovered(delay, tau, gains):
    rng = np.random.default_rng(0)
    fit = estimate_actuation(tracks(rng, 6, delay_s=delay, tau_s=tau, gains=gains), SETTINGS, rng)
    assert fit.delay_s.ok and fit.time_constant_s.ok and fit.linear_gain.ok and fit.angular_gain.ok
    assert fit.delay_s.value == pytest.approx(delay, abs=0.005)
    assert fit.time_constant_s.value == pytest.approx(tau, rel=0.05)
    assert fit.linear_gain.value == pytest.approx(gains[0], rel=0.02)
    assert fit.angular_gain.value == pytest.approx(gains[1], rel=0.02)
    # uncertainties from the bootstrap over robot-episodes, with intervals around the estimates
    for est in (fit.delay_s, fit.time_constant_s, fit.linear_gain, fit.angular_gain):
        assert est.std_error is not None and est.std_error > 0
        assert est.interval is not None and est.interval[0] <= est.value <= est.interval[1]
        assert "bootstrap over 6 robot-episodes" in est.method
    assert fit.example is not None and fit.residual_rms is not None and fit.residual_rms[0] < 0.01


def test_without_turning_commands_the_angular_gain_is_unidentifiable():
    rng = np.random.default_rng(1)
    fit = estimate_actuation(tracks(rng, 4, delay_s=0.1, tau_s=0.2, gains=(0.9, 0.8), turning=False), SETTINGS, rng)
    assert fit.angular_gain.status == "unidentifiable"
    assert fit.angular_gain.reason == "no turning commands above 0.05 rad/s"
    assert fit.linear_gain.ok and fit.linear_gain.value == pytest.approx(0.9, rel=0.02)
    assert fit.delay_s.ok and fit.delay_s.value == pytest.approx(0.1, abs=0.005)


def test_robots_that_never_move_leave_everything_unidentifiable():
    rng = np.random.default_rng(2)
    t = np.arange(0, 5, 0.02)
    still = VelocityTrack(
        "robot_1",
        "episode 0",
        (t * NS).astype(np.int64),
        np.zeros((len(t), 2)),
        CommandTimeline(np.array([0]), np.zeros((1, 2))),
    )
    fit = estimate_actuation([still], SETTINGS, rng)
    for est in (fit.delay_s, fit.time_constant_s, fit.linear_gain, fit.angular_gain):
        assert est.status == "unidentifiable"
        assert "no linear commands above 0.05 m/s" in est.reason and "no turning commands" in est.reason
    assert estimate_actuation([], SETTINGS, rng).delay_s.reason.startswith("no contact-free stretch")


def test_commands_stop_acting_after_the_timeout():
    timeline = CommandTimeline(np.array([0, NS]), np.array([[0.3, 0.1], [0.2, 0.0]]))
    acting = timeline.at(np.array([-1, 0, NS // 2, NS - 1, NS, 2 * NS]), timeout_s=0.5)
    np.testing.assert_allclose(acting[:, 0], [0.0, 0.3, 0.3, 0.0, 0.2, 0.0])


def test_a_base_that_saturates_has_a_speed_limit_not_a_smaller_gain():
    # commands up to 0.4 m/s, a base that never goes beyond 0.25 m/s: a limit of 0.25, the gain 0.95 below it
    covered = 0
    trials = 6
    for seed in range(trials):
        rng = np.random.default_rng(100 + seed)
        data = tracks(rng, 6, delay_s=0.08, tau_s=0.2, gains=(0.95, 0.9), limits=(0.25, math.inf))
        fit = estimate_actuation(data, SETTINGS, rng)
        linear, angular = fit.speed_limits
        assert linear is not None and linear.saturated and linear.limit.value is not None
        assert linear.limit.value == pytest.approx(0.25, rel=0.005)
        assert linear.commanded_max == pytest.approx(0.4) and linear.saturated_share > 0.1
        assert linear.limit.interval is not None and linear.limit.unit == "m/s"
        covered += linear.limit.interval[0] <= 0.25 <= linear.limit.interval[1]
        assert fit.linear_gain.value == pytest.approx(0.95, rel=0.005)
        assert fit.delay_s.value == pytest.approx(0.08, abs=0.005)
        assert fit.time_constant_s.value == pytest.approx(0.2, rel=0.05)
        assert angular is not None and not angular.saturated and "no speed limit up to" in angular.sentence()
        assert any(note.startswith("linear speed limit 0.25") for note in fit.notes)
    # the 95 % interval of the limit holds the true one (6 robot-episodes per fit: allow one miss)
    assert covered >= trials - 1


def test_a_base_below_its_limit_shows_none_and_keeps_its_fit():
    rng = np.random.default_rng(7)
    data = tracks(rng, 6, delay_s=0.08, tau_s=0.2, gains=(0.95, 0.9))
    fit = estimate_actuation(data, SETTINGS, np.random.default_rng(7))
    assert all(limit is not None and not limit.saturated for limit in fit.speed_limits)
    assert fit.linear_gain.value == pytest.approx(0.95, rel=0.005)
    # a limit above every command changes nothing: the base never reached it
    rng = np.random.default_rng(7)
    high = tracks(rng, 6, delay_s=0.08, tau_s=0.2, gains=(0.95, 0.9), limits=(0.5, 0.5))
    again = estimate_actuation(high, SETTINGS, np.random.default_rng(7))
    assert again.linear_gain.value == fit.linear_gain.value and again.delay_s.value == fit.delay_s.value


KEYBOARD = (0.0, 0.5)
"""A keyboard's forward commands: stop or 0.5 m/s."""


def test_one_commanded_speed_into_a_capped_base_is_ambiguous_and_the_limit_is_kept():
    """Every forward command 0.5 m/s or 0, the base capped at 0.31 m/s: a gain of 0.62 and the nominal gain up to
    0.31 m/s explain the recording alike. Both are named, the limit is kept (commands below it act as nominal),
    the gain is no setting, and what would separate them is said."""
    rng = np.random.default_rng(11)
    fit = estimate_actuation(
        tracks(rng, 6, delay_s=0.1, tau_s=0.2, gains=(1.0, 1.0), limits=(0.31, math.inf), v_levels=KEYBOARD),
        SETTINGS,
        rng,
    )
    assert not fit.linear_gain.ok and "one commanded speed" in fit.linear_gain.reason
    assert fit.angular_gain.ok and fit.angular_gain.value == pytest.approx(1.0, rel=0.03)
    limit = fit.speed_limits[0]
    assert limit is not None and limit.saturated and limit.limit.value == pytest.approx(0.31, rel=0.03)
    assert limit.limit.interval is not None and limit.limit.interval[0] <= 0.31 <= limit.limit.interval[1]
    (ambiguity,) = [a for a in fit.ambiguities if a.keys[0] == "actuation.linear_gain"]
    assert fit.ambiguous_gain(0) and not fit.ambiguous_gain(1)
    assert "gain of 0.6" in ambiguity.readings[0] and "limit of 0.31" in ambiguity.readings[1]
    assert ambiguity.kept.startswith("the limit") and "several linear speeds" in ambiguity.separate


def test_a_true_gain_at_one_commanded_speed_reads_the_same_and_is_not_claimed():
    """The same recording made by a base with gain 0.62 and no limit: indistinguishable, so the same two readings."""
    rng = np.random.default_rng(11)
    fit = estimate_actuation(
        tracks(rng, 6, delay_s=0.1, tau_s=0.2, gains=(0.62, 1.0), v_levels=KEYBOARD), SETTINGS, rng
    )
    assert not fit.linear_gain.ok and fit.ambiguous_gain(0)
    limit = fit.speed_limits[0]
    assert limit is not None and limit.limit.value == pytest.approx(0.31, rel=0.03)


def test_several_commanded_speeds_separate_a_limit_from_a_gain():
    """Commands at several speeds below and above the cap: the knee is found, the gain is the base's below it, and
    nothing is ambiguous."""
    rng = np.random.default_rng(11)
    levels = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
    fit = estimate_actuation(
        tracks(rng, 6, delay_s=0.1, tau_s=0.2, gains=(1.0, 1.0), limits=(0.31, math.inf), v_levels=levels),
        SETTINGS,
        rng,
    )
    assert fit.linear_gain.ok and fit.linear_gain.value == pytest.approx(1.0, rel=0.03)
    limit = fit.speed_limits[0]
    assert limit is not None and limit.saturated and limit.limit.value == pytest.approx(0.31, rel=0.05)
    assert not [a for a in fit.ambiguities if a.keys[0] == "actuation.linear_gain"]
    assert fit.response_s.ok and fit.response_s.value == pytest.approx(0.3, abs=0.03)
