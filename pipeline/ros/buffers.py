"""Timestamped emitter and receiver buffers between the policy loop and the fleet's topics.

**EmitterBuffer**: one timestamped command queue per robot. A single tick every `tick_period_ns`
(20 ms) sends every robot's current command in the same tick. A command is valid for its
execution window [stamp, stamp + validity) (100 ms by default; the bundled fleets add one tick of
grace, 120 ms, so a control step a little late never leaves a gap); a robot without a valid command gets zero
velocity (the watchdog). Velocities are clamped to each robot's limits before they leave.

**ReceiverBuffer**: per robot a bounded ring of timestamped scans, odometry and ground truth.
``joint_state(t)`` gives every robot's latest data at control time t with its age and names the
robots whose data is missing or older than the staleness limits, instead of reusing old data.

Both report every send, receive and tick as a :class:`TimingEvent`, so jitter and skew can be
measured from the recording. Times are integer nanoseconds of the deploy clock.
"""

from __future__ import annotations

import os
import threading
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from pipeline.core.scan import ScanGeometry
from pipeline.ros.clock import Clock

TimingKind = Literal["send", "receive", "tick", "control", "stale"]


@dataclass(frozen=True)
class TimingEvent:
    """One send, receive, emitter tick or control step: local time, the message's own stamp, counters."""

    kind: TimingKind
    robot: str
    topic: str
    local_ns: int
    source_stamp_ns: int = 0
    seq: int = 0
    tick: int = 0


TimingSink = Callable[[TimingEvent], None]


def _ignore(_: TimingEvent) -> None:
    pass


@dataclass(frozen=True)
class VelocityLimits:
    """A robot's velocity limits: |v| <= v_max_mps, |w| <= w_max_radps."""

    v_max_mps: float
    w_max_radps: float


@dataclass(frozen=True)
class Command:
    """A velocity command for one robot, valid from `stamp_ns` for the emitter's validity window."""

    stamp_ns: int
    v_mps: float
    w_radps: float


Publish = Callable[[str, Any], None]
"""Sends a prepared command (see Prepare) to the robot's cmd_vel."""
Prepare = Callable[[str, float, float], Any]
"""Everything of sending (robot, v m/s, w rad/s) that can be done before the tick's sends."""
Planned = tuple[str, float, float, int, Any]
"""One command of a tick: robot, v, w, the stamp it was queued with (0: none), the message ready to publish."""


def _as_is(robot: str, v: float, w: float) -> Any:
    return (v, w)


Sent = Callable[[str, float, float, int], None]
"""Told (robot, v m/s, w rad/s, send time ns) after a tick's sends, e.g. to record them."""


def _nothing_sent(robot: str, v: float, w: float, t_ns: int) -> None:
    pass


class EmitterBuffer:
    """Per-robot command queues flushed together on a fixed tick."""

    def __init__(
        self,
        limits: Mapping[str, VelocityLimits],
        publish: Publish,
        clock: Clock,
        tick_period_ns: int = 20_000_000,
        validity_ns: int = 100_000_000,
        on_timing: TimingSink = _ignore,
        topics: Mapping[str, str] | None = None,
        on_sent: Sent = _nothing_sent,
        prepare: Prepare = _as_is,
    ) -> None:
        if tick_period_ns <= 0 or validity_ns <= 0:
            raise ValueError("tick period and validity must be positive")
        self.robots = tuple(limits)
        self.limits = dict(limits)
        self.publish = publish
        self.clock = clock
        self.tick_period_ns = tick_period_ns
        self.validity_ns = validity_ns
        self.on_timing = on_timing
        self.on_sent = on_sent
        self.prepare = prepare
        self.topics = dict(topics or {r: f"/{r}/cmd_vel" for r in self.robots})
        self._queues: dict[str, deque[Command]] = {r: deque(maxlen=64) for r in self.robots}
        self._lock = threading.Lock()
        self._sending = threading.RLock()
        """Held for a whole tick (choice, sends, their records): clear() waits for a tick in flight."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.ticks = 0
        self._seq = 0
        self.last_sent: dict[str, tuple[float, float]] = {r: (0.0, 0.0) for r in self.robots}
        self.error: BaseException | None = None
        self.grid_origin_ns = 0
        self.realtime = False
        """Whether the tick thread got a real-time scheduling priority (needs CAP_SYS_NICE or an rtprio limit)."""

    def command(self, robot: str, stamp_ns: int, v_mps: float, w_radps: float) -> None:
        """Queue a command for `robot` valid from `stamp_ns`."""
        with self._lock:
            self._queues[robot].append(Command(int(stamp_ns), float(v_mps), float(w_radps)))

    def command_all(self, stamp_ns: int, commands: np.ndarray) -> None:
        """Queue (n_robots, 2) commands (v, w), rows in robot order, all valid from `stamp_ns`."""
        with self._lock:
            for robot, (v, w) in zip(self.robots, np.asarray(commands, dtype=np.float64), strict=True):
                self._queues[robot].append(Command(int(stamp_ns), float(v), float(w)))

    def clear(self) -> None:
        """Forget every queued command: the next tick sends zero velocity to every robot.

        Returns after any tick in flight has sent and recorded its commands, so whatever is recorded
        after clear() returns was chosen after it.
        """
        with self._sending, self._lock:
            for q in self._queues.values():
                q.clear()

    def halt(self) -> dict[str, tuple[float, float]]:
        """Forget every queued command and send zero velocity to every robot now, off the tick grid.

        An abort stops the fleet at once rather than at the next tick. The sends are recorded like a
        tick's but carry tick 0 and make no tick event, so the grid's jitter is not disturbed.
        """
        with self._sending:
            self.clear()
            planned = [(robot, 0.0, 0.0, 0, self.prepare(robot, 0.0, 0.0)) for robot in self.robots]
            return self._send(planned, self.clock.now_ns(), 0)

    def current(self, robot: str, now_ns: int) -> Command | None:
        """The newest command of `robot` whose window contains `now_ns`; older ones are dropped."""
        q = self._queues[robot]
        best: Command | None = None
        while q and q[0].stamp_ns <= now_ns:
            best = q.popleft()
        if best is not None and now_ns - best.stamp_ns < self.validity_ns:
            q.appendleft(best)  # still valid: keep it for the next ticks of its window
            return best
        return None

    def clamp(self, robot: str, v: float, w: float) -> tuple[float, float]:
        lim = self.limits[robot]
        return (
            float(np.clip(v, -lim.v_max_mps, lim.v_max_mps)),
            float(np.clip(w, -lim.w_max_radps, lim.w_max_radps)),
        )

    def tick(self, now_ns: int | None = None) -> dict[str, tuple[float, float]]:
        """Send every robot's current command (zero when none is valid); returns what was sent.

        All sends of a tick go out back to back; their timing and recording follow afterwards.
        """
        with self._sending:
            return self._tick(now_ns)

    def _tick(self, now_ns: int | None) -> dict[str, tuple[float, float]]:
        t = self.clock.now_ns() if now_ns is None else now_ns
        self.ticks += 1
        tick = self.ticks
        with self._lock:
            chosen = {r: self.current(r, t) for r in self.robots}
        planned = []
        for robot in self.robots:
            cmd = chosen[robot]
            v, w = (0.0, 0.0) if cmd is None else self.clamp(robot, cmd.v_mps, cmd.w_radps)
            planned.append((robot, v, w, 0 if cmd is None else cmd.stamp_ns, self.prepare(robot, v, w)))
        return self._send(planned, t, tick)

    def _send(self, planned: list[Planned], t: int, tick: int) -> dict[str, tuple[float, float]]:
        """Publish the planned commands back to back, then report them (a tick event unless `tick` is 0)."""
        times = []
        for robot, _, _, _, ready in planned:
            self.publish(robot, ready)
            times.append(self.clock.now_ns())
        if tick:
            self.on_timing(TimingEvent("tick", "", "", t, tick=tick))
        sent = {}
        for (robot, v, w, stamp, _), sent_ns in zip(planned, times, strict=True):
            self._seq += 1
            self.on_timing(TimingEvent("send", robot, self.topics[robot], sent_ns, stamp, self._seq, tick))
            self.on_sent(robot, v, w, sent_ns)
            sent[robot] = (v, w)
        self.last_sent = sent
        return sent

    def start(self) -> None:
        """Tick on the grid `grid_origin_ns` + k * period in a background thread until stop()."""
        if self._thread is not None:
            return
        self._stop.clear()
        self.grid_origin_ns = self.clock.now_ns()
        self._thread = threading.Thread(target=self._run, name="emitter", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.realtime = _try_realtime_priority()
        try:
            next_t = self.grid_origin_ns
            while not self._stop.is_set():
                if not self.clock.sleep_until(next_t, self._stop):
                    break
                self.tick()
                next_t += self.tick_period_ns
                now = self.clock.now_ns()
                if now - next_t > self.tick_period_ns:  # fell behind by more than a tick: skip, do not burst
                    next_t += ((now - next_t) // self.tick_period_ns) * self.tick_period_ns
        except BaseException as exc:  # surfaced to the runner, which stops the robots
            self.error = exc

    def stop(self, send_zero: bool = True) -> None:
        """Stop ticking; with `send_zero`, clear the queues and send one last zero command to every robot."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if send_zero:
            self.clear()
            self.tick()


def _try_realtime_priority(priority: int = 10) -> bool:
    """Ask the OS to run the calling thread under SCHED_FIFO so ticks wake on time under load; False if refused."""
    if not hasattr(os, "sched_setscheduler"):
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError):
        return False
    return True


@dataclass(frozen=True)
class ReceivedSample:
    """One received sample: the robot's stamp, our receive time, and its content."""

    stamp_ns: int
    receive_ns: int


@dataclass(frozen=True)
class ScanSample(ReceivedSample):
    ranges: np.ndarray
    geometry: ScanGeometry


@dataclass(frozen=True)
class PoseSample(ReceivedSample):
    pose: np.ndarray  # (3,) x, y (m), yaw (rad)
    velocity: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class RobotState:
    """A robot's latest data at control time; ages are control time minus receive time (ns)."""

    scan: ScanSample | None
    odom: PoseSample | None
    truth: PoseSample | None
    scan_age_ns: int | None
    odom_age_ns: int | None
    truth_age_ns: int | None


@dataclass(frozen=True)
class JointState:
    """Every robot's latest data at control time `t_ns`, and who is stale (missing or too old)."""

    t_ns: int
    robots: dict[str, RobotState]
    stale: dict[str, str] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        return not self.stale


Channel = Literal["scan", "odom", "truth"]


class ReceiverBuffer:
    """Bounded rings of each robot's scans, odometry and ground truth."""

    def __init__(
        self,
        robots: Sequence[str],
        capacity: int = 32,
        scan_stale_ns: int = 500_000_000,
        odom_stale_ns: int = 200_000_000,
        truth_stale_ns: int | None = None,
        on_timing: TimingSink = _ignore,
    ) -> None:
        self.robots = tuple(robots)
        self.scan_stale_ns = scan_stale_ns
        self.odom_stale_ns = odom_stale_ns
        self.truth_stale_ns = truth_stale_ns
        self.on_timing = on_timing
        self._lock = threading.Lock()
        self._rings: dict[Channel, dict[str, deque[ReceivedSample]]] = {
            c: {r: deque(maxlen=capacity) for r in self.robots} for c in ("scan", "odom", "truth")
        }
        self.counts: dict[Channel, dict[str, int]] = {
            c: dict.fromkeys(self.robots, 0) for c in ("scan", "odom", "truth")
        }

    def _add(self, channel: Channel, robot: str, sample: ReceivedSample, topic: str) -> None:
        with self._lock:
            self._rings[channel][robot].append(sample)
            self.counts[channel][robot] += 1
            seq = self.counts[channel][robot]
        self.on_timing(TimingEvent("receive", robot, topic, sample.receive_ns, sample.stamp_ns, seq))

    def add_scan(self, robot: str, sample: ScanSample, topic: str = "") -> None:
        self._add("scan", robot, sample, topic or f"/{robot}/scan")

    def add_odom(self, robot: str, sample: PoseSample, topic: str = "") -> None:
        self._add("odom", robot, sample, topic or f"/{robot}/odom")

    def add_truth(self, robot: str, sample: PoseSample, topic: str = "") -> None:
        self._add("truth", robot, sample, topic or f"/{robot}/ground_truth")

    def clear(self) -> None:
        """Forget everything received (e.g. after a reset, so old poses cannot leak into a new episode)."""
        with self._lock:
            for rings in self._rings.values():
                for ring in rings.values():
                    ring.clear()

    def latest(self, channel: Channel, robot: str, at_ns: int | None = None) -> ReceivedSample | None:
        """The newest sample of `robot` on `channel` received at or before `at_ns` (any if None)."""
        with self._lock:
            ring = self._rings[channel][robot]
            for sample in reversed(ring):
                if at_ns is None or sample.receive_ns <= at_ns:
                    return sample
        return None

    def joint_state(self, t_ns: int) -> JointState:
        """Every robot's latest data at control time `t_ns`, with ages and the stale robots named."""
        robots: dict[str, RobotState] = {}
        stale: dict[str, str] = {}
        for r in self.robots:
            scan = self.latest("scan", r, t_ns)
            odom = self.latest("odom", r, t_ns)
            truth = self.latest("truth", r, t_ns)

            def age(s: ReceivedSample | None) -> int | None:
                return None if s is None else t_ns - s.receive_ns

            state = RobotState(
                scan=scan if isinstance(scan, ScanSample) else None,
                odom=odom if isinstance(odom, PoseSample) else None,
                truth=truth if isinstance(truth, PoseSample) else None,
                scan_age_ns=age(scan),
                odom_age_ns=age(odom),
                truth_age_ns=age(truth),
            )
            robots[r] = state
            reasons = []
            if state.scan is None:
                reasons.append("no scan")
            elif state.scan_age_ns is not None and state.scan_age_ns > self.scan_stale_ns:
                reasons.append(f"scan {state.scan_age_ns / 1e6:.0f} ms old")
            if state.odom is None:
                reasons.append("no odometry")
            elif state.odom_age_ns is not None and state.odom_age_ns > self.odom_stale_ns:
                reasons.append(f"odometry {state.odom_age_ns / 1e6:.0f} ms old")
            if self.truth_stale_ns is not None:
                if state.truth is None:
                    reasons.append("no ground truth")
                elif state.truth_age_ns is not None and state.truth_age_ns > self.truth_stale_ns:
                    reasons.append(f"ground truth {state.truth_age_ns / 1e6:.0f} ms old")
            if reasons:
                stale[r] = ", ".join(reasons)
        return JointState(t_ns=t_ns, robots=robots, stale=stale)
