"""Emitter and receiver buffers against a controllable clock."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from pipeline.core.scan import ScanGeometry
from pipeline.ros.buffers import (
    EmitterBuffer,
    PoseSample,
    ReceiverBuffer,
    ScanSample,
    TimingEvent,
    VelocityLimits,
)
from pipeline.ros.clock import ScaledClock

MS = 1_000_000


class ManualClock:
    scale = 1.0

    def __init__(self, t_ns: int = 0) -> None:
        self.t = t_ns

    def now_ns(self) -> int:
        return self.t

    def sleep_until(self, t_ns: int, stop: threading.Event | None = None) -> bool:
        self.t = max(self.t, t_ns)
        return True


@pytest.fixture
def emitter():
    clock = ManualClock()
    sent: list[tuple[int, str, float, float]] = []
    events: list[TimingEvent] = []
    limits = {"robot_1": VelocityLimits(0.4, 0.2), "robot_2": VelocityLimits(0.3, 0.2)}
    em = EmitterBuffer(limits, lambda r, c: sent.append((clock.t, r, *c)), clock, on_timing=events.append)
    return em, clock, sent, events


def test_every_robot_is_sent_in_the_same_tick(emitter):
    em, _, sent, events = emitter
    em.command_all(0, np.array([[0.1, 0.05], [0.2, -0.1]]))
    em.tick(0)
    assert [(r, v, w) for _, r, v, w in sent] == [("robot_1", 0.1, 0.05), ("robot_2", 0.2, -0.1)]
    ticks = [e for e in events if e.kind == "tick"]
    sends = [e for e in events if e.kind == "send"]
    assert len(ticks) == 1 and {e.tick for e in sends} == {ticks[0].tick}
    assert [e.topic for e in sends] == ["/robot_1/cmd_vel", "/robot_2/cmd_vel"]
    assert all(e.source_stamp_ns == 0 for e in sends)


def test_command_valid_for_its_window_then_watchdog_zero(emitter):
    em, clock, sent, _ = emitter
    em.command("robot_1", 10 * MS, 0.3, 0.1)
    for t in (0, 10 * MS, 60 * MS, 109 * MS, 110 * MS, 200 * MS):
        clock.t = t
        em.tick()
    r1 = [(t, v, w) for t, r, v, w in sent if r == "robot_1"]
    # before its stamp: zero; inside [10, 110) ms: the command; from 110 ms: zero again
    assert r1 == [
        (0, 0.0, 0.0),
        (10 * MS, 0.3, 0.1),
        (60 * MS, 0.3, 0.1),
        (109 * MS, 0.3, 0.1),
        (110 * MS, 0.0, 0.0),
        (200 * MS, 0.0, 0.0),
    ]
    # a robot never commanded gets zero on every tick
    assert all(v == 0.0 and w == 0.0 for _, r, v, w in sent if r == "robot_2")


def test_newer_command_replaces_older_and_future_commands_wait(emitter):
    em, _, _, _ = emitter
    em.command("robot_1", 0, 0.1, 0.0)
    em.command("robot_1", 50 * MS, 0.2, 0.0)
    em.command("robot_1", 100 * MS, 0.3, 0.0)
    got = []
    for t in (20 * MS, 60 * MS, 120 * MS):
        em.tick(t)
        got.append(em.last_sent["robot_1"][0])
    assert got == [0.1, 0.2, 0.3]


def test_commands_are_clamped_to_each_robots_limits(emitter):
    em, _, _, _ = emitter
    em.command_all(0, np.array([[1.0, -1.0], [-1.0, 0.5]]))
    sent = em.tick(0)
    assert sent == {"robot_1": (0.4, -0.2), "robot_2": (-0.3, 0.2)}


def test_stop_sends_zero_to_everyone(emitter):
    em, _, sent, _ = emitter
    em.command_all(0, np.array([[0.3, 0.1], [0.2, 0.1]]))
    em.tick(0)
    em.stop(send_zero=True)
    assert [(r, v, w) for _, r, v, w in sent[-2:]] == [("robot_1", 0.0, 0.0), ("robot_2", 0.0, 0.0)]


def test_halt_sends_zero_now_off_the_grid_and_the_next_tick_stays_zero(emitter):
    """An abort stops every robot at once: zero commands go out before the next tick, their sends are reported
    with tick 0 and no tick event (the grid's jitter is untouched), and the queued commands are gone."""
    em, clock, sent, events = emitter
    em.command_all(0, np.array([[0.3, 0.1], [0.2, -0.1]]))
    em.tick(0)
    clock.t = 5 * MS  # between ticks
    assert em.halt() == {"robot_1": (0.0, 0.0), "robot_2": (0.0, 0.0)}
    assert [(t, r, v, w) for t, r, v, w in sent[-2:]] == [(5 * MS, "robot_1", 0.0, 0.0), (5 * MS, "robot_2", 0.0, 0.0)]
    halted = [e for e in events if e.kind == "send"][-2:]
    assert [e.tick for e in halted] == [0, 0] and [e.local_ns for e in halted] == [5 * MS, 5 * MS]
    assert [e.tick for e in events if e.kind == "tick"] == [1]
    em.tick(20 * MS)  # the command of stamp 0 would still be valid: halt forgot it
    assert [(r, v, w) for _, r, v, w in sent[-2:]] == [("robot_1", 0.0, 0.0), ("robot_2", 0.0, 0.0)]


def test_clear_waits_for_a_tick_in_flight():
    """A tick that chose its commands before clear() sends and records them before clear() returns, so
    nothing recorded after clear() carries an old command (an abort's zero commands come after it)."""
    clock = ManualClock()
    sending, release = threading.Event(), threading.Event()
    recorded: list[tuple[str, float]] = []

    def publish(robot: str, command: tuple[float, float]) -> None:
        sending.set()
        release.wait(5.0)

    em = EmitterBuffer(
        {"robot_1": VelocityLimits(0.4, 0.2)}, publish, clock, on_sent=lambda r, v, w, t: recorded.append(("sent", v))
    )
    em.command_all(0, np.array([[0.3, 0.1]]))
    ticking = threading.Thread(target=em.tick, args=(0,))
    ticking.start()
    assert sending.wait(5.0)
    cleared = threading.Thread(target=lambda: (em.clear(), recorded.append(("cleared", 0.0))))
    cleared.start()
    cleared.join(0.2)
    assert cleared.is_alive()  # still waiting for the tick that is sending
    release.set()
    ticking.join(5.0)
    cleared.join(5.0)
    assert recorded == [("sent", 0.3), ("cleared", 0.0)]
    em.tick(10 * MS)
    assert recorded[-1] == ("sent", 0.0)


def test_background_ticks_follow_the_grid():
    clock = ManualClock(1_000 * MS)
    sent: list[int] = []
    em = EmitterBuffer({"robot_1": VelocityLimits(0.4, 0.2)}, lambda r, c: sent.append(clock.t), clock)
    em.start()
    while len(sent) < 10:
        pass
    em.stop(send_zero=False)
    periods = np.diff(sent[:10])
    assert np.all(periods == 20 * MS)


def geometry() -> ScanGeometry:
    return ScanGeometry(4, 0.0, np.pi / 2, 0.05, 5.0)


def test_receiver_latest_ages_and_stale_robots():
    events: list[TimingEvent] = []
    rx = ReceiverBuffer(
        ["robot_1", "robot_2"], capacity=4, scan_stale_ns=300 * MS, odom_stale_ns=100 * MS, on_timing=events.append
    )
    for k in range(6):
        t = k * 20 * MS
        rx.add_odom("robot_1", PoseSample(t - 1 * MS, t, np.array([k, 0.0, 0.0])))
    rx.add_scan("robot_1", ScanSample(90 * MS, 95 * MS, np.ones(4), geometry()))
    rx.add_odom("robot_2", PoseSample(0, 0, np.zeros(3)))
    state = rx.joint_state(110 * MS)
    r1 = state.robots["robot_1"]
    assert r1.odom is not None and r1.odom.pose[0] == 5 and r1.odom_age_ns == 10 * MS
    assert r1.scan_age_ns == 15 * MS
    assert set(state.stale) == {"robot_2"}
    assert "no scan" in state.stale["robot_2"] and "odometry 110 ms old" in state.stale["robot_2"]
    # data received after the control time is not used for it
    earlier = rx.joint_state(50 * MS)
    assert earlier.robots["robot_1"].odom is not None and earlier.robots["robot_1"].odom.pose[0] == 2
    # the ring is bounded
    assert rx.latest("odom", "robot_1", 0) is None
    receives = [e for e in events if e.kind == "receive"]
    assert len(receives) == 8 and receives[0].topic == "/robot_1/odom" and receives[0].source_stamp_ns == -MS
    rx.clear()
    assert set(rx.joint_state(110 * MS).stale) == {"robot_1", "robot_2"}


def test_ground_truth_staleness_only_when_required():
    rx = ReceiverBuffer(["robot_1"], truth_stale_ns=50 * MS)
    rx.add_scan("robot_1", ScanSample(0, 0, np.ones(4), geometry()))
    rx.add_odom("robot_1", PoseSample(0, 0, np.zeros(3)))
    assert "no ground truth" in rx.joint_state(10 * MS).stale["robot_1"]
    rx.add_truth("robot_1", PoseSample(0, 0, np.zeros(3)))
    assert rx.joint_state(10 * MS).complete
    assert "ground truth 60 ms old" in rx.joint_state(60 * MS).stale["robot_1"]


def test_scaled_clock_runs_faster_and_follows_clock_messages():
    clock = ScaledClock(4.0, sim_start_ns=0, wall_start_ns=1_000 * MS)
    assert clock.wall_deadline(400 * MS) == 1_100 * MS
    clock.follow(10_000 * MS, wall_ns=2_000 * MS)
    assert clock.wall_deadline(10_400 * MS) == 2_100 * MS
    with pytest.raises(ValueError):
        ScaledClock(0.0)
