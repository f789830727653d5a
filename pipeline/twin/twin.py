"""The hardware twin: N robots' drivers on ROS 2 topics, on physics and sensors of its own.

It does not use the training simulator: the robots are wheel-level MuJoCo bases
(:mod:`pipeline.twin.physics`: two driven wheels with motors that lag, have a deadband and an
acceleration limit, wheel-ground friction with slip, in a room whose boxes and walls stand where
the profile's ``map`` puts them), and the sensors are the twin's own (:mod:`pipeline.twin.sensors`).

The driver of each robot turns its latest ``cmd_vel`` (zero after `DRIVER_TIMEOUT_NS` without one,
as robot drivers do) into wheel speeds with the NOMINAL wheel radius and separation, after the
profile's actuation delay, first-order lag and gains. Physics advances in `PHYSICS_STEP_S` steps;
each stream is published at its own rate, not on a common tick: odometry (encoder ticks, stamped
in the robot's clock) at ``odometry.rate_hz``, scans when a sweep completes (``lidar.rate_hz``,
each beam taken at its own time when the profile asks for motion distortion), ground truth at
`TRUTH_RATE_HZ` (motion capture, on the host's clock) and, when time is scaled, ``/clock`` every
`CLOCK_PERIOD_S`. Each outgoing message is lost (in bursts) or delayed by up to its jitter.
``/mrl/reset`` puts every robot back at its start and is answered on ``/mrl/reset_done``.
"""

from __future__ import annotations

import heapq
import itertools
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.core.evader import Evader
from pipeline.core.layouts import draw_layout
from pipeline.core.scan import ScanGeometry
from pipeline.core.scenario import Scenario
from pipeline.core.timebase import NS_PER_S, scale_kept
from pipeline.messages import convert as C
from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.ros.clock import Clock, ScaledClock
from pipeline.ros.fleet import Fleet
from pipeline.ros.transport import Publisher, Transport
from pipeline.twin.physics import BaseParams, FleetPhysics
from pipeline.twin.profile import NOMINAL_WHEEL_RADIUS_M, NOMINAL_WHEEL_SEPARATION_M, ActuationProfile, RealityProfile
from pipeline.twin.sensors import (
    LIDAR_RANGE_MAX_M,
    LIDAR_RANGE_MIN_M,
    BurstLoss,
    EncoderOdometry,
    LidarSweep,
    RobotClock,
)

PHYSICS_STEP_S = 0.002
TRUTH_RATE_HZ = 50.0
CLOCK_PERIOD_S = 0.02
DRIVER_TIMEOUT_NS = 500_000_000
MAX_WAKE_NS = 20_000_000
"""The loop wakes at least this often (twin time) to take resets and commands."""


@dataclass
class EpisodeTiming:
    """How the twin kept its clock through one episode: the time scale asked, the twin and host times it began and
    ended at, the twin time it jumped over (host stalls) and the most it ran behind its clock."""

    episode: int
    asked_scale: float
    start_ns: int
    host_start_ns: int
    end_ns: int = 0
    host_end_ns: int = 0
    jumped_ns: int = 0
    lag_max_ns: int = 0

    def end(self, end_ns: int, host_end_ns: int) -> None:
        self.end_ns, self.host_end_ns = end_ns, host_end_ns

    @property
    def realized_scale(self) -> float:
        """Twin seconds simulated (not jumped over) per host second."""
        host = self.host_end_ns - self.host_start_ns
        return (self.end_ns - self.start_ns - self.jumped_ns) / host if host > 0 else math.nan

    @property
    def kept(self) -> bool:
        """The twin kept the time scale asked: no more than `REALIZED_MARGIN` short of it, never `LAG_LIMIT_NS`
        behind its clock."""
        return scale_kept(self.asked_scale, self.realized_scale, self.lag_max_ns)

    def as_mapping(self) -> dict[str, object]:
        return {
            "episode": self.episode,
            "time_scale_asked": self.asked_scale,
            "time_scale_realized": round(self.realized_scale, 4),
            "jumped_s": self.jumped_ns / NS_PER_S,
            "lag_max_s": self.lag_max_ns / NS_PER_S,
            "kept": self.kept,
        }


STALL_JUMP_NS = 1_000_000_000
"""A host stall longer than this (twin time) is jumped over: the robots stand still through it and the jump is
recorded (`HardwareTwin.jumps`). Shorter stalls are caught up step by step (sensors taken at their own times,
published late, as a slow link would deliver them), so the world's physics keeps the clock's time: a world that
froze for every busy moment of the host would read its drive's gains short by the frozen share."""
BEAM_BATCH_NS = 10_000_000
"""Lidar beams due are cast in batches this far apart (twin time), each from the pose at its batch: at 0.4 m/s
and up to 1 rad/s that is within 4 mm and 10 mrad of each beam's own pose, small against a 125 ms sweep's
distortion, at a fifth of the ray casts' cost."""


@dataclass(frozen=True)
class Silence:
    """Fault injection: robot `robot` stops publishing `after_s` seconds of twin time after the first
    reset, for `duration_s` seconds (for good when None)."""

    robot: str
    after_s: float
    duration_s: float | None = None


class LossyLink:
    """Publishes with the profile's loss (in bursts, per topic) and delay jitter (a background thread keeps the
    messages in order of their due times)."""

    def __init__(
        self, clock: Clock, loss_prob: float, jitter_s: float, rng: np.random.Generator, burst_len: float = 1.0
    ) -> None:
        self.clock = clock
        self.loss = BurstLoss(loss_prob, burst_len, rng)
        self.jitter_ns = int(jitter_s * NS_PER_S)
        self.rng = rng
        self._heap: list[tuple[int, int, Publisher, Any]] = []
        self._counter = itertools.count()
        self._cv = threading.Condition()
        self._stop = threading.Event()
        self.sent = 0
        self.lost = 0
        self.deliveries: list[tuple[str, int, int]] | None = None
        """Where a list (``--link-record``): per stamped message handed on, (topic, header stamp ns, the clock's
        reading when it was handed on ns): the delivery the link realized, read at the sender."""
        self._thread = threading.Thread(target=self._run, name="twin-link", daemon=True)
        if self.jitter_ns > 0:
            self._thread.start()

    def send(self, pub: Publisher, msg: Any, reliable: bool = False) -> None:
        if not reliable and self.loss.lost(pub.spec.name if hasattr(pub, "spec") else str(id(pub))):
            self.lost += 1
            return
        self.sent += 1
        if self.jitter_ns <= 0 or reliable:
            pub.publish(msg)
            if not reliable:
                self._note(pub, msg)
            return
        due = self.clock.now_ns() + int(self.rng.uniform(0, self.jitter_ns))
        with self._cv:
            heapq.heappush(self._heap, (due, next(self._counter), pub, msg))
            self._cv.notify()

    def _run(self) -> None:
        while not self._stop.is_set():
            with self._cv:
                while not self._heap and not self._stop.is_set():
                    self._cv.wait(0.05)
                if self._stop.is_set():
                    return
                due = self._heap[0][0]
            if not self.clock.sleep_until(due, self._stop):
                return
            with self._cv:
                ready = []
                now = self.clock.now_ns()
                while self._heap and self._heap[0][0] <= now:
                    ready.append(heapq.heappop(self._heap))
            for _, _, pub, msg in ready:
                if not pub.closed:
                    pub.publish(msg)
                    self._note(pub, msg)

    def _note(self, pub: Publisher, msg: Any) -> None:
        """Keep the delivery of a stamped message where deliveries are recorded."""
        if self.deliveries is None:
            return
        header = getattr(msg, "header", None)
        if header is None:
            return
        stamp = int(header.stamp.sec) * NS_PER_S + int(header.stamp.nanosec)
        self.deliveries.append((pub.spec.name if hasattr(pub, "spec") else str(id(pub)), stamp, self.clock.now_ns()))

    def deliveries_arrays(self) -> dict[str, np.ndarray]:
        """The recorded deliveries: ``topic`` (str), ``stamp_ns`` and ``handed_ns`` (int64), ``jitter_s``."""
        rows = list(self.deliveries or [])
        return {
            "topic": np.array([r[0] for r in rows], dtype=str),
            "stamp_ns": np.array([r[1] for r in rows], dtype=np.int64),
            "handed_ns": np.array([r[2] for r in rows], dtype=np.int64),
            "jitter_s": np.asarray(self.jitter_ns / NS_PER_S, dtype=np.float64),
        }

    def write_deliveries(self, path: str) -> None:
        """The recorded deliveries as a NumPy archive (`deliveries_arrays`)."""
        np.savez_compressed(path, allow_pickle=False, **self.deliveries_arrays())

    def close(self) -> None:
        self._stop.set()
        with self._cv:
            self._cv.notify_all()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)


def fleet_physics(scenario: Scenario, profile: RealityProfile) -> FleetPhysics:
    """The twin's physics of `scenario` with the reality of `profile`: its base, map offsets and floor, at the
    twin's physics step."""
    base = profile.base
    return FleetPhysics(
        scenario,
        BaseParams(
            wheel_radius_left_m=base.wheel_radius_left_m,
            wheel_radius_right_m=base.wheel_radius_right_m,
            wheel_separation_m=base.wheel_separation_m,
            mass_kg=base.mass_kg,
            motor_time_constant_s=base.motor_time_constant_s,
            deadband_radps=base.deadband_radps,
            max_wheel_accel_radps2=base.max_wheel_accel_radps2,
            friction=base.friction,
        ),
        box_offsets_m=np.array(profile.map.box_offsets_m, dtype=float).reshape(-1, 2),
        wall_offset_m=profile.map.wall_offset_m,
        timestep_s=PHYSICS_STEP_S,
    )


class BaseDriver:
    """The robots' drivers: delay, first-order lag and gains on (v, w), then wheel speeds by the nominal geometry."""

    def __init__(self, n: int, actuation: ActuationProfile) -> None:
        self.actuation = actuation
        self.delay_ns = round(actuation.delay_s * NS_PER_S)
        self.history: deque[tuple[int, np.ndarray]] = deque()
        self.effective = np.zeros((n, 2))
        self.n = n

    def reset(self) -> None:
        self.history.clear()
        self.effective = np.zeros((self.n, 2))

    def wheel_targets(self, t_ns: int, commands: np.ndarray, dt_s: float) -> np.ndarray:
        """(n, 2) wheel speeds (rad/s, left and right) for the commands (v m/s, w rad/s) received by `t_ns`."""
        self.history.append((t_ns, np.array(commands, dtype=float)))
        due = t_ns - self.delay_ns
        current = np.zeros((self.n, 2))
        while self.history and self.history[0][0] <= due:
            current = self.history.popleft()[1]
            if self.history and self.history[0][0] <= due:
                continue
            self.history.appendleft((due, current))
            break
        a = self.actuation
        alpha = 1.0 - math.exp(-dt_s / a.time_constant_s) if a.time_constant_s > 0 else 1.0
        self.effective += alpha * (current - self.effective)
        v = self.effective[:, 0] * a.linear_gain
        w = self.effective[:, 1] * a.angular_gain
        half = NOMINAL_WHEEL_SEPARATION_M / 2
        return np.stack([(v - w * half) / NOMINAL_WHEEL_RADIUS_M, (v + w * half) / NOMINAL_WHEEL_RADIUS_M], axis=1)


LIDAR_UNIT_STREAM = 0x4C494441
"""Seeds each robot's lidar unit with the twin's seed, apart from the episodes' streams."""


class HardwareTwin:
    """Plays the drivers of `fleet`'s robots in `scenario` with the reality of `profile`."""

    def __init__(
        self,
        fleet: Fleet,
        scenario: Scenario,
        profile: RealityProfile,
        transport: Transport,
        clock: Clock,
        seed: int = 0,
        publish_clock: bool = False,
        silence: Silence | None = None,
        log: Callable[[str], None] = print,
    ) -> None:
        if scenario.n_robots != len(fleet.robots):
            raise ValueError(
                f"the fleet has {len(fleet.robots)} robots, scenario {scenario.name!r} {scenario.n_robots}"
            )
        self.fleet = fleet
        self.scenario = scenario
        self.profile = profile
        self.transport = transport
        self.clock = clock
        self.seed = seed
        self.publish_clock = publish_clock
        self.silence = silence
        self.log = log
        self.store = message_store()
        self.physics = fleet_physics(scenario, profile)
        self.step_ns = round(self.physics.timestep_s * NS_PER_S)
        self.evader = Evader(scenario) if scenario.target is not None else None
        """A pursuit's target, stepped with the motion capture's rate and published on /target/ground_truth."""
        self.namespaces = [r.namespace for r in fleet.robots]
        n = len(self.namespaces)
        self.driver = BaseDriver(n, profile.actuation)
        self.rng = np.random.default_rng(seed + 1)
        self.link = LossyLink(
            clock,
            profile.network.loss_prob,
            profile.network.jitter_s,
            np.random.default_rng(seed + 2),
            profile.network.burst_len,
        )
        self._cmd = np.zeros((n, 2))
        self._cmd_ns = np.full(n, -(2**62), dtype=np.int64)
        self._inbox: deque[tuple[int, int, float, float]] = deque()
        self.applied: list[tuple[int, int, float, float]] | None = None
        """Where a list (``--link-record``): each command as the driver took it, (robot index, the time it took effect
        on the twin's clock ns, v, w): the commands the drive really had, for a replay of it."""
        """Commands received and not yet in effect: (receive time, robot, v, w); physics takes each one at
        its receive time, never earlier."""
        self._lock = threading.Lock()
        self._reset_request: tuple[int, int] | None = None
        self.ticks = 0
        self.jumps: list[tuple[int, int]] = []
        """Host stalls longer than `STALL_JUMP_NS` jumped over: (twin time the jump started, ns skipped)."""
        self.stall: tuple[float, float] | None = None
        """Fault injection: (host seconds, twin seconds after the first reset) of one host stall."""
        self.timing: list[EpisodeTiming] = []
        """Per episode (from one reset to the next, the last to the twin's end): how well the twin kept its clock."""
        self._timing: EpisodeTiming | None = None
        self._silenced_at_ns: int | None = None
        self._first_reset_ns: int | None = None
        self._scale_asked: float | None = None
        """A time scale asked for (`ask_scale`), taken at the next reset (at once before the first)."""
        self.on_pace: Callable[[dict[str, float]], None] | None = None
        """Where set: called every `pace_every_s` host seconds with how the twin keeps its clock (`pace`)."""
        self.pace_every_s = 0.5
        self._jumped_total_ns = 0
        self._lag_since_ns = 0
        now = clock.now_ns()
        self.robot_clock = RobotClock(profile.clock, now)
        self.scan_geometry = ScanGeometry(
            profile.lidar.beams, 0.0, 2 * math.pi / profile.lidar.beams, LIDAR_RANGE_MIN_M, LIDAR_RANGE_MAX_M
        )
        self._begin_episode(now, seed)
        self.pubs: dict[str, dict[str, Publisher]] = {}
        for robot in fleet.robots:
            topics = robot.topics()
            self.pubs[robot.namespace] = {k: transport.publisher(topics[k]) for k in ("scan", "odom", "ground_truth")}
        self.target_pub = transport.publisher(T.TARGET_TRUTH) if self.evader is not None else None
        self.clock_pub = transport.publisher(T.FLEET_TOPICS["clock"]) if publish_clock else None
        self.reset_pub = transport.publisher(T.FLEET_TOPICS["reset_done"])
        self.subs = [
            transport.subscribe(robot.topics()["cmd_vel"], self._on_cmd(i)) for i, robot in enumerate(fleet.robots)
        ]
        self.subs.append(transport.subscribe(T.FLEET_TOPICS["reset"], self._on_reset))

    def _begin_episode(self, now_ns: int, episode_seed: int) -> None:
        """Robots at their starts, sensors restarted, with random streams of their own for this episode."""
        streams = np.random.SeedSequence([self.seed, episode_seed]).spawn(len(self.namespaces) + 1)
        layout = draw_layout(self.scenario, episode_seed)  # the runner draws the same one from the same seed
        self.physics.use_layout(layout)
        self.physics.reset(layout.starts)
        if self.evader is not None:
            self.evader.reset(layout)  # the episode's layout: its target start and boxes
            self.physics.set_target(self.evader.xy)
            self.last_evader_ns = now_ns
        self.driver.reset()
        self.physics_ns = now_ns
        self.odometry = EncoderOdometry(len(self.namespaces), self.profile.odometry, np.random.default_rng(streams[-1]))
        self.odometry.reset(layout.starts, self.physics.wheel_angles())
        self.lidars = [
            LidarSweep(self.profile.lidar, np.random.default_rng(streams[i]), now_ns, self._lidar_unit(i))
            for i in range(len(streams) - 1)
        ]
        self.next_odom_ns = now_ns
        self.odom_period_ns = round(NS_PER_S / self.profile.odometry.rate_hz)
        self.next_truth_ns = now_ns
        self.truth_period_ns = round(NS_PER_S / TRUTH_RATE_HZ)
        self.last_odom_ns = now_ns

    def _lidar_unit(self, i: int) -> np.random.Generator:
        """What robot i's lidar unit is made of (its beams' angle errors and noise factors): the same every episode."""
        return np.random.default_rng([self.seed, LIDAR_UNIT_STREAM, i])

    def close_timing(self) -> None:
        """End the episode's timing record (at the next reset, or when the twin stops)."""
        if self._timing is not None:
            self._timing.end(self.physics_ns, time.monotonic_ns())
            self.timing.append(self._timing)
            self._timing = None

    def write_record(self, path: str) -> None:
        """What the twin realized, as a NumPy archive: the link's deliveries (`LossyLink.deliveries_arrays`) and the
        commands as the driver took them: ``cmd_robot`` (namespace), ``cmd_ns`` (when each took effect, the twin's
        clock), ``cmd_v`` and ``cmd_w``; the host stalls jumped over (`jumps`): ``jump_ns`` and ``jump_skipped_ns``."""
        applied = list(self.applied or [])
        np.savez_compressed(
            path,
            allow_pickle=False,
            **self.link.deliveries_arrays(),
            cmd_robot=np.array([self.namespaces[r[0]] for r in applied], dtype=str),
            cmd_ns=np.array([r[1] for r in applied], dtype=np.int64),
            cmd_v=np.array([r[2] for r in applied], dtype=float),
            cmd_w=np.array([r[3] for r in applied], dtype=float),
            jump_ns=np.array([j[0] for j in self.jumps], dtype=np.int64),
            jump_skipped_ns=np.array([j[1] for j in self.jumps], dtype=np.int64),
        )

    def _on_cmd(self, index: int) -> Callable[[Any, Any, int], None]:
        def callback(spec: Any, msg: Any, receive_ns: int) -> None:
            v, w = C.twist_command(msg)
            if not (math.isfinite(v) and math.isfinite(w)):
                return  # a driver ignores non-finite commands
            with self._lock:
                self._inbox.append((self.clock.now_ns(), index, v, w))

        return callback

    def _on_reset(self, spec: Any, msg: Any, receive_ns: int) -> None:
        if msg.done:
            return
        with self._lock:
            self._reset_request = (int(msg.episode), int(msg.seed))

    def _commands(self, now_ns: int) -> np.ndarray:
        """Each robot's latest command received by `now_ns` (zero once older than the driver's timeout)."""
        with self._lock:
            while self._inbox and self._inbox[0][0] <= now_ns:
                t, index, v, w = self._inbox.popleft()
                self._cmd[index] = (v, w)
                self._cmd_ns[index] = t
                if self.applied is not None:
                    self.applied.append((index, t, v, w))
            fresh = (now_ns - self._cmd_ns) < DRIVER_TIMEOUT_NS
            return np.where(fresh[:, None], self._cmd, 0.0)

    def _handle_reset(self, now_ns: int) -> None:
        with self._lock:
            request, self._reset_request = self._reset_request, None
            if request is None:
                return
            self._cmd[:] = 0.0
            self._cmd_ns[:] = -(2**62)
            self._inbox.clear()
        episode, seed = request
        self.close_timing()
        self._take_scale()
        self._timing = EpisodeTiming(episode, self.clock.scale, now_ns, time.monotonic_ns())
        self._begin_episode(now_ns, seed)
        if self._first_reset_ns is None:
            self._first_reset_ns = now_ns
        self.link.send(self.reset_pub, C.reset_request(now_ns, episode, seed, True, store=self.store), reliable=True)

    def ask_scale(self, scale: float) -> None:
        """Run at `scale` from the next episode on (from now, before the first): the deployment lowers it when the
        host cannot keep what it asked (``--time-scale auto``). Any thread."""
        if not (math.isfinite(scale) and scale > 0) or not isinstance(self.clock, ScaledClock):
            raise ValueError(f"time scale {scale!r}: must be above 0, on a scaled clock")
        with self._lock:
            self._scale_asked = scale

    def _take_scale(self) -> None:
        with self._lock:
            scale, self._scale_asked = self._scale_asked, None
        if scale is not None and isinstance(self.clock, ScaledClock) and scale != self.clock.scale:
            self.clock.rescale(scale)

    def pace(self) -> dict[str, float]:
        """How the twin keeps its clock, cumulative: its time (ns), the time it jumped over in host stalls (ns), the
        host's monotonic time (ns), the most it ran behind since the last call (ns), the time scale it runs at."""
        lag, self._lag_since_ns = self._lag_since_ns, 0
        return {
            "twin_ns": float(self.physics_ns),
            "jumped_ns": float(self._jumped_total_ns),
            "host_ns": float(time.monotonic_ns()),
            "lag_ns": float(lag),
            "scale": float(self.clock.scale),
        }

    def _silenced(self, ns: str, now_ns: int) -> bool:
        s = self.silence
        if s is None or s.robot != ns or self._first_reset_ns is None:
            return False
        since = now_ns - self._first_reset_ns
        return since >= s.after_s * NS_PER_S and (s.duration_s is None or since < (s.after_s + s.duration_s) * NS_PER_S)

    # -- physics and sensors ---------------------------------------------------------------

    def _advance(self, until_ns: int) -> None:
        """Physics steps up to `until_ns`; lidar beams taken at their times; complete sweeps published."""
        dt = self.physics.timestep_s
        while self.physics_ns + self.step_ns <= until_ns:
            targets = self.driver.wheel_targets(self.physics_ns, self._commands(self.physics_ns), dt)
            self.physics.set_wheel_targets(targets)
            self.physics.step(1)
            self.physics_ns += self.step_ns
            if self.physics_ns % BEAM_BATCH_NS < self.step_ns or any(
                self.physics_ns >= lidar.end_ns for lidar in self.lidars
            ):
                self._take_beams(self.physics_ns)

    def _take_beams(self, now_ns: int) -> None:
        poses = None
        for i, lidar in enumerate(self.lidars):
            k = lidar.due(now_ns)
            if len(k):
                poses = self.physics.poses() if poses is None else poses
                origin, heading = lidar.pose_of_lidar(poses[i])
                true = self.physics.cast(i, origin, lidar.world_angles(heading, k))
                lidar.measure(k, true, self.physics.last_surfaces)
            if lidar.complete and now_ns >= lidar.end_ns:
                self._publish_scan(i, lidar)
                lidar.restart(lidar.end_ns)

    def _publish_scan(self, i: int, lidar: LidarSweep) -> None:
        ns = self.namespaces[i]
        if self._silenced(ns, lidar.end_ns) or lidar.dropped():
            return
        period_s = lidar.period_ns / NS_PER_S
        msg = C.laser_scan(
            self.robot_clock.stamp(lidar.start_ns),
            f"{ns}/laser",
            lidar.ranges.copy(),
            self.scan_geometry,
            period_s,
            self.store,
            time_increment_s=period_s / lidar.beams if self.profile.lidar.motion_distortion else 0.0,
        )
        self.link.send(self.pubs[ns]["scan"], msg)

    def step(self, now: int | None = None) -> None:
        """Advance to `now` (the clock's time by default) and publish every stream that is due."""
        now = self.clock.now_ns() if now is None else now
        self._handle_reset(now)
        self.ticks += 1
        self._advance(now)
        t = self.physics_ns
        if t >= self.next_truth_ns:
            truth = self.physics.poses()
            for i, ns in enumerate(self.namespaces):
                if not self._silenced(ns, t):
                    msg = C.pose_stamped(t, "map", truth[i], store=self.store)
                    self.link.send(self.pubs[ns]["ground_truth"], msg)
            if self.evader is not None and self.target_pub is not None:
                xy = self.evader.step((t - self.last_evader_ns) / NS_PER_S, truth[:, :2])
                self.last_evader_ns = t
                self.physics.set_target(xy)
                pose = np.array([xy[0], xy[1], self.evader.heading_rad])
                self.link.send(self.target_pub, C.pose_stamped(t, "map", pose, store=self.store))
            self.next_truth_ns += self.truth_period_ns * max(1, (t - self.next_truth_ns) // self.truth_period_ns + 1)
        if t >= self.next_odom_ns:
            self.odometry.update(self.physics.wheel_angles(), (t - self.last_odom_ns) / NS_PER_S)
            self.last_odom_ns = t
            stamp = self.robot_clock.stamp(t)
            for i, ns in enumerate(self.namespaces):
                if not self._silenced(ns, t):
                    vel = (float(self.odometry.velocity[i, 0]), float(self.odometry.velocity[i, 1]))
                    msg = C.odometry(stamp, ns, self.odometry.pose[i], vel, store=self.store)
                    self.link.send(self.pubs[ns]["odom"], msg)
            self.next_odom_ns += self.odom_period_ns * max(1, (t - self.next_odom_ns) // self.odom_period_ns + 1)
        if self.clock_pub is not None:
            self.clock_pub.publish(C.clock(now, store=self.store))

    def next_wake_ns(self) -> int:
        """The next time a stream is due (or `MAX_WAKE_NS` from now, to take resets and commands)."""
        due = [self.next_truth_ns, self.next_odom_ns, *(lidar.end_ns for lidar in self.lidars)]
        if self.clock_pub is not None:
            due.append(self.physics_ns + round(CLOCK_PERIOD_S * NS_PER_S))
        return min(min(due), self.physics_ns + MAX_WAKE_NS)

    def run(self, stop: threading.Event) -> None:
        """Run until `stop` is set, waking when a stream is due."""
        paced = time.monotonic()
        while not stop.is_set():
            if self._first_reset_ns is None:
                self._take_scale()  # no episode yet: a scale asked for applies at once
            if self.on_pace is not None and time.monotonic() - paced >= self.pace_every_s:
                paced = time.monotonic()
                self.on_pace(self.pace())
            wake = max(self.next_wake_ns(), self.physics_ns + self.step_ns)
            if not self.clock.sleep_until(wake, stop):
                break
            first = self._first_reset_ns
            if self.stall is not None and first is not None and wake - first >= self.stall[1] * NS_PER_S:
                seconds, self.stall = self.stall[0], None
                time.sleep(seconds)  # the host gives the twin no time: as a busy machine does
            behind = self.clock.now_ns() - wake
            skipped = 0
            if behind > STALL_JUMP_NS:  # the host stalled for long: jump, or catching up would run away
                skipped = (behind // self.step_ns) * self.step_ns
                self.jumps.append((self.physics_ns, skipped))
                self.physics_ns += skipped
                self._jumped_total_ns += skipped
            self._lag_since_ns = max(self._lag_since_ns, behind)
            if self._timing is not None:
                self._timing.lag_max_ns = max(self._timing.lag_max_ns, behind)
                self._timing.jumped_ns += skipped
            self.step(wake + skipped)  # the time it jumped to: a reset taken now starts the episode there

    def close(self) -> None:
        self.link.close()
        for sub in self.subs:
            sub.close()
        for pubs in self.pubs.values():
            for pub in pubs.values():
                pub.close()
        if self.clock_pub is not None:
            self.clock_pub.close()
        if self.target_pub is not None:
            self.target_pub.close()
