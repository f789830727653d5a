"""The hardware twin: N robots' drivers on ROS 2 topics, with physics, noise, delay and loss of its own.

Every tick (20 ms of twin time) it applies each robot's latest ``cmd_vel`` (zero after
`DRIVER_TIMEOUT_NS` without one, as robot drivers do), advances MuJoCo, and publishes odometry
(at the profile's rate), ground truth (every tick, like motion capture), scans (at the lidar's
rate, `beams` rays over 360 degrees, turned by the mounting yaw) and, when time is scaled,
``/clock``. Each outgoing message is lost with the profile's probability or delayed by up to
its jitter. ``/mrl/reset`` puts every robot back at its start and is answered on
``/mrl/reset_done``.
"""

from __future__ import annotations

import heapq
import itertools
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.core.scan import ScanGeometry
from pipeline.core.scenario import Scenario
from pipeline.core.timebase import NS_PER_S
from pipeline.messages import convert as C
from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.params import WorldConfig, world_config
from pipeline.ros.clock import Clock
from pipeline.ros.fleet import Fleet
from pipeline.ros.transport import Publisher, Transport
from pipeline.sim.world import SimWorld
from pipeline.twin.profile import RealityProfile

TICK_S = 0.02
PHYSICS_STEP_S = 0.005
DRIVER_TIMEOUT_NS = 500_000_000
LIDAR_RANGE_MIN_M = 0.12
LIDAR_RANGE_MAX_M = 8.0
"""The twin's lidar: a 360-degree scanner measuring 0.12 to 8 m."""


def twin_world(profile: RealityProfile) -> WorldConfig:
    """The simulated physics and sensors of the twin's robots, from its reality profile."""
    lidar = profile.lidar
    return world_config(
        {
            "control_period_s": TICK_S,
            "physics_timestep_s": PHYSICS_STEP_S,
            "max_steps": 100_000,
            "lidar": {
                "beams": lidar.beams,
                "sim_beams": lidar.beams,
                "range_min_m": LIDAR_RANGE_MIN_M,
                "range_max_m": LIDAR_RANGE_MAX_M,
                "noise_sigma_m": lidar.noise_sigma_m,
                "dropout_prob": lidar.dropout_prob,
                "bias_m": lidar.bias_m,
                "robot_radius_seen_m": 0.0,
                "mount_yaw_rad": lidar.mount_yaw_rad,
            },
            "actuation": {
                "delay_s": profile.actuation.delay_s,
                "time_constant_s": profile.actuation.time_constant_s,
                "linear_gain": profile.actuation.linear_gain,
                "angular_gain": profile.actuation.angular_gain,
            },
            "odometry": {"drift_per_m": profile.odometry.drift_per_m},
        },
        source="<reality profile>",
    )


@dataclass(frozen=True)
class Silence:
    """Fault injection: robot `robot` stops publishing `after_s` seconds of twin time after the first
    reset, for `duration_s` seconds (for good when None)."""

    robot: str
    after_s: float
    duration_s: float | None = None


class LossyLink:
    """Publishes with the profile's loss probability and delay jitter (a background thread keeps order by due time)."""

    def __init__(self, clock: Clock, loss_prob: float, jitter_s: float, rng: np.random.Generator) -> None:
        self.clock = clock
        self.loss_prob = loss_prob
        self.jitter_ns = int(jitter_s * NS_PER_S)
        self.rng = rng
        self._heap: list[tuple[int, int, Publisher, Any]] = []
        self._counter = itertools.count()
        self._cv = threading.Condition()
        self._stop = threading.Event()
        self.sent = 0
        self.lost = 0
        self._thread = threading.Thread(target=self._run, name="twin-link", daemon=True)
        if self.jitter_ns > 0:
            self._thread.start()

    def send(self, pub: Publisher, msg: Any, reliable: bool = False) -> None:
        if not reliable and self.loss_prob > 0 and self.rng.random() < self.loss_prob:
            self.lost += 1
            return
        self.sent += 1
        if self.jitter_ns <= 0 or reliable:
            pub.publish(msg)
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

    def close(self) -> None:
        self._stop.set()
        with self._cv:
            self._cv.notify_all()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)


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
        self.world = SimWorld(scenario, twin_world(profile))
        self.world.reset(seed)
        self.rng = np.random.default_rng(seed + 1)
        self.link = LossyLink(
            clock, profile.network.loss_prob, profile.network.jitter_s, np.random.default_rng(seed + 2)
        )
        self.namespaces = [r.namespace for r in fleet.robots]
        n = len(self.namespaces)
        self._cmd = np.zeros((n, 2))
        self._cmd_ns = np.full(n, -(2**62), dtype=np.int64)
        self._lock = threading.Lock()
        self._reset_request: tuple[int, int] | None = None
        self.ticks = 0
        self._silenced_at_ns: int | None = None
        self._first_reset_ns: int | None = None
        rate = 1.0 / TICK_S
        self.odom_every = max(1, round(rate / profile.odometry.rate_hz))
        self.scan_every = max(1, round(rate / profile.lidar.rate_hz))
        self.scan_geometry = ScanGeometry(
            profile.lidar.beams, 0.0, 2 * math.pi / profile.lidar.beams, LIDAR_RANGE_MIN_M, LIDAR_RANGE_MAX_M
        )
        self.pubs: dict[str, dict[str, Publisher]] = {}
        for robot in fleet.robots:
            topics = robot.topics()
            self.pubs[robot.namespace] = {k: transport.publisher(topics[k]) for k in ("scan", "odom", "ground_truth")}
        self.clock_pub = transport.publisher(T.FLEET_TOPICS["clock"]) if publish_clock else None
        self.reset_pub = transport.publisher(T.FLEET_TOPICS["reset_done"])
        self.subs = [
            transport.subscribe(robot.topics()["cmd_vel"], self._on_cmd(i)) for i, robot in enumerate(fleet.robots)
        ]
        self.subs.append(transport.subscribe(T.FLEET_TOPICS["reset"], self._on_reset))

    def _on_cmd(self, index: int) -> Callable[[Any, Any, int], None]:
        def callback(spec: Any, msg: Any, receive_ns: int) -> None:
            v, w = C.twist_command(msg)
            if not (math.isfinite(v) and math.isfinite(w)):
                return  # a driver ignores non-finite commands
            with self._lock:
                self._cmd[index] = (v, w)
                self._cmd_ns[index] = self.clock.now_ns()

        return callback

    def _on_reset(self, spec: Any, msg: Any, receive_ns: int) -> None:
        if msg.done:
            return
        with self._lock:
            self._reset_request = (int(msg.episode), int(msg.seed))

    def _commands(self, now_ns: int) -> np.ndarray:
        with self._lock:
            fresh = (now_ns - self._cmd_ns) < DRIVER_TIMEOUT_NS
            return np.where(fresh[:, None], self._cmd, 0.0)

    def _handle_reset(self, now_ns: int) -> None:
        with self._lock:
            request, self._reset_request = self._reset_request, None
            if request is None:
                return
            self._cmd[:] = 0.0
            self._cmd_ns[:] = -(2**62)
        episode, seed = request
        self.world.reset(int(np.random.SeedSequence([self.seed, seed]).generate_state(1)[0]))
        if self._first_reset_ns is None:
            self._first_reset_ns = now_ns
        self.link.send(self.reset_pub, C.reset_request(now_ns, episode, seed, True, store=self.store), reliable=True)

    def _silenced(self, ns: str, now_ns: int) -> bool:
        s = self.silence
        if s is None or s.robot != ns or self._first_reset_ns is None:
            return False
        since = now_ns - self._first_reset_ns
        return since >= s.after_s * NS_PER_S and (s.duration_s is None or since < (s.after_s + s.duration_s) * NS_PER_S)

    def step(self) -> None:
        """One twin tick at time t: messages out describing the state at t, then commands in and physics to t + tick."""
        now = self.clock.now_ns()
        self._handle_reset(now)
        self.ticks += 1
        self._publish(now)
        self.world.step(self._commands(now))

    def _publish(self, now: int) -> None:
        truth = self.world.truth
        odom_pose = self.world.odometry.pose
        velocity = self.world.body_velocity()
        scans = self.world.scan() if self.ticks % self.scan_every == 0 else None
        for i, ns in enumerate(self.namespaces):
            if self._silenced(ns, now):
                continue
            pubs = self.pubs[ns]
            self.link.send(pubs["ground_truth"], C.pose_stamped(now, "map", truth[i], store=self.store))
            if self.ticks % self.odom_every == 0:
                vel = (float(velocity[i, 0]), float(velocity[i, 1]))
                self.link.send(pubs["odom"], C.odometry(now, ns, odom_pose[i], vel, store=self.store))
            if scans is not None:
                msg = C.laser_scan(
                    now, f"{ns}/laser", scans[i], self.scan_geometry, 1.0 / self.profile.lidar.rate_hz, self.store
                )
                self.link.send(pubs["scan"], msg)
        if self.clock_pub is not None:
            self.clock_pub.publish(C.clock(now, store=self.store))

    def run(self, stop: threading.Event) -> None:
        """Tick every TICK_S of twin time until `stop` is set."""
        period = round(TICK_S * NS_PER_S)
        next_t = self.clock.now_ns()
        while not stop.is_set():
            if not self.clock.sleep_until(next_t, stop):
                break
            self.step()
            next_t += period
            behind = self.clock.now_ns() - next_t
            if behind > 5 * period:  # the host stalled: do not replay the missed ticks in a burst
                next_t += (behind // period) * period

    def close(self) -> None:
        self.link.close()
        for sub in self.subs:
            sub.close()
        for pubs in self.pubs.values():
            for pub in pubs.values():
                pub.close()
        if self.clock_pub is not None:
            self.clock_pub.close()
        self.reset_pub.close()
