"""``--time-scale auto``'s decisions (pipeline.rollout.pace) on a host of known capacity: a reporter thread plays
the twin's pace lines as a twin that can simulate `capacity` seconds per host second would send them."""

from __future__ import annotations

import threading
import time

import pytest

from pipeline.errors import InvalidMeasurement
from pipeline.rollout import pace
from pipeline.rollout.pace import AutoScale, Pace, kept, next_scale, realized
from pipeline.ros.clock import ScaledClock


def test_the_realized_scale_leaves_out_the_time_jumped_over():
    reports = [Pace(0.0, 0.0, 0.0, 0.0, 4.0), Pace(8e9, 2e9, 2e9, 3e8, 4.0)]
    got, lag = realized(reports)
    assert got == pytest.approx(3.0) and lag == 3e8
    assert realized(reports[:1])[0] != realized(reports[:1])[0]  # NaN from one report


@pytest.mark.parametrize(
    ("asked", "got", "lag_ns", "expected"),
    [(3.0, 2.9, 0.0, True), (3.0, 2.8, 0.0, False), (3.0, 3.0, 1.5e9, False), (1.0, float("nan"), 0.0, True)],
)
def test_kept_follows_the_twins_own_rule(asked, got, lag_ns, expected):
    assert kept(asked, got, lag_ns) is expected


def test_the_next_scale_is_a_step_below_with_headroom():
    assert next_scale(2.7, 6.0) == 1.0  # 0.5 x 2.7 = 1.35, down to the half step
    assert next_scale(5.9, 6.0) == 2.5
    assert next_scale(9.0, 4.0) == 3.5  # at least a step below the scale not kept
    assert next_scale(1.1, 1.5) == 0.5  # below 1: the caller keeps 1


class Host:
    """Sends a pace report every `every_s` as a twin with `capacity` would: min(asked, capacity) per host second."""

    def __init__(self, capacity: float, every_s: float) -> None:
        self.capacity, self.every_s = capacity, every_s
        self.asked = pace.CAPACITY_SCALE
        self.paces: list[Pace] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def ask(self, scale: float) -> None:
        self.asked = scale

    def _run(self) -> None:
        twin, last = 0.0, time.monotonic_ns()
        while not self.stop.wait(self.every_s):
            now = time.monotonic_ns()
            rate = min(self.asked, self.capacity)
            twin += (now - last) * rate
            lag = 0.0 if rate >= self.asked else 2e8
            self.paces.append(Pace(twin, 0.0, float(now), lag, self.asked))
            last = now


@pytest.fixture
def quick(monkeypatch):
    monkeypatch.setattr(pace, "PROBE_S", 0.4)
    monkeypatch.setattr(pace, "PACE_EVERY_S", 0.05)


@pytest.mark.parametrize(("capacity", "chosen"), [(30.0, 6.0), (9.0, 4.5), (2.7, 1.0), (1.3, 1.0)])
def test_the_probe_asks_for_half_the_capacity_the_host_gives_the_twin(quick, capacity, chosen):
    host = Host(capacity, 0.05)
    clock = ScaledClock(pace.CAPACITY_SCALE)
    try:
        auto = AutoScale(host.paces, host.ask, clock)
        scale = auto.probe()
    finally:
        host.stop.set()
    assert scale == chosen and host.asked == chosen and clock.scale == chosen
    assert auto.capacity == pytest.approx(min(capacity, pace.CAPACITY_SCALE), rel=0.1)
    assert f"the episodes start at {chosen:g}x" in auto.said()


def test_a_host_that_cannot_keep_1x_is_refused_by_name(quick):
    host = Host(0.7, 0.05)
    try:
        with pytest.raises(InvalidMeasurement, match=r"cannot keep even 1x"):
            AutoScale(host.paces, host.ask, ScaledClock(pace.CAPACITY_SCALE)).probe()
    finally:
        host.stop.set()


def test_an_episode_the_twin_did_not_keep_lowers_the_scale_for_the_next(quick):
    host = Host(9.0, 0.05)
    lines: list[str] = []
    auto = AutoScale(host.paces, host.ask, ScaledClock(4.0), 4.0, say=lines.append)
    try:
        auto.episode_started()
        time.sleep(0.3)
        assert auto.after_episode(0) is False
        assert auto.scale == 4.0 and not lines  # kept: unchanged
        host.capacity = 2.5
        auto.episode_started()
        time.sleep(0.4)
        assert auto.after_episode(1) is True  # not kept: the runner runs one more in its place
    finally:
        host.stop.set()
    assert auto.scale == 1.0 and host.asked == 1.0 and auto.lowered[0][:2] == (1, 4.0)
    assert "the twin fell behind in episode 1" in lines[0]


def test_an_episode_a_robots_outage_aborted_lowers_the_scale_though_the_twin_kept_it(quick):
    host = Host(30.0, 0.05)
    lines: list[str] = []
    auto = AutoScale(host.paces, host.ask, ScaledClock(4.0), 4.0, say=lines.append)
    try:
        auto.episode_started()
        time.sleep(0.3)
        assert auto.after_episode(3, outage=True) is False  # the twin kept its clock: the episode is the policy's
    finally:
        host.stop.set()
    assert auto.scale == 2.0 and "a robot's outage aborted episode 3 at 4x" in lines[0]


def test_a_fleet_gone_quiet_is_put_on_the_host_only_where_the_twin_fell_behind():
    from pipeline.rollout.pace import behind_note

    every = 0.5e9
    kept_up = [Pace(i * every * 3, 0.0, i * every, 1e7, 3.0) for i in range(11)]
    assert behind_note(kept_up, now_ns=kept_up[-1].host_ns + 1e8) == ""
    slow = [Pace(i * every * 1.2, 0.0, i * every, 1.5e9, 3.0) for i in range(11)]
    note = behind_note(slow, now_ns=slow[-1].host_ns + 1e8)
    assert "fell behind its clock (realized 1.20x of 3x" in note and "the robots are not at fault" in note
    silent = behind_note(kept_up, now_ns=kept_up[-1].host_ns + 4e9)
    assert "has not run for 4.0 s" in silent
    assert behind_note([]) == ""


def test_reruns_at_auto_are_a_tenth_of_the_episodes_and_at_least_two():
    assert [AutoScale.reruns_for(n) for n in (1, 3, 20, 50, 200)] == [2, 2, 2, 5, 20]


def test_control_steps_that_woke_late_lower_the_scale(quick):
    host = Host(30.0, 0.05)
    lines: list[str] = []
    auto = AutoScale(host.paces, host.ask, ScaledClock(5.0), 5.0, say=lines.append)
    try:
        auto.episode_started()
        time.sleep(0.3)
        auto.after_episode(0, late=0.1)  # within the limit: kept
        assert auto.scale == 5.0 and not lines
        auto.episode_started()
        time.sleep(0.3)
        auto.after_episode(1, late=0.6)
    finally:
        host.stop.set()
    assert auto.scale == 2.5 and "the control steps of episode 1 woke 0.60 of a period late" in lines[0]
