"""The deploy runner's side of the transport: what it hears and what it says, each message recorded.

It hears every robot's scan, odometry and (if the fleet has it) ground truth, the twin's reset
confirmations and, under a scaled clock, ``/clock``; each message is recorded as it arrives, on the
session's clock, and kept in the receiver buffer. It says commands through the emitter, which sends
them on its own tick and records each one sent, and reset requests. Under a scaled clock, messages
that arrive before the first ``/clock`` are neither recorded nor used (they would be on another
clock than the rest of the recording); their count goes to the ``unrecorded`` metadata record.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from pipeline.core.timebase import NS_PER_S
from pipeline.messages import convert as C
from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.record.session import SessionLog
from pipeline.rollout.errors import FleetNotReady
from pipeline.ros.buffers import (
    EmitterBuffer,
    JointState,
    PoseSample,
    ReceiverBuffer,
    ScanSample,
    TimingEvent,
    VelocityLimits,
)
from pipeline.ros.clock import Clock, ScaledClock
from pipeline.ros.fleet import Fleet
from pipeline.ros.transport import Transport


def scan_sample(msg: Any, receive_ns: int) -> ScanSample:
    """A LaserScan as the receiver keeps it: float64 ranges and the scan's geometry."""
    return ScanSample(
        C.time_ns(msg.header.stamp), receive_ns, np.asarray(msg.ranges, dtype=np.float64), C.scan_geometry(msg)
    )


def odom_sample(msg: Any, receive_ns: int) -> PoseSample:
    """An Odometry message as the receiver keeps it: planar pose and body velocity."""
    vel = (float(msg.twist.twist.linear.x), float(msg.twist.twist.angular.z))
    return PoseSample(C.time_ns(msg.header.stamp), receive_ns, C.planar_pose(msg.pose.pose), vel)


class FleetLink:
    """Subscriptions, publishers, receiver and emitter of one deployment; `on_reset_done(episode, seed)`
    is called (transport thread) when the fleet confirms a reset."""

    def __init__(
        self,
        fleet: Fleet,
        transport: Transport,
        clock: Clock,
        log: SessionLog,
        on_reset_done: Callable[[int, int], None],
        target: bool = False,
    ) -> None:
        """`target`: a pursuit; its target's motion-capture pose is heard and recorded too."""
        self.fleet = fleet
        self.clock = clock
        self.log = log
        self.on_reset_done = on_reset_done
        self.store = message_store()
        self.namespaces = [r.namespace for r in fleet.robots]
        self.unrecorded_before_clock = 0
        self.unrecorded_before_lock = 0
        """Messages heard before the fleet's writers were locked (:meth:`lock_writers`): neither recorded nor used."""
        self._locked = False
        timing = fleet.timing
        self.use_truth = timing.use_ground_truth
        self.receiver = ReceiverBuffer(
            self.namespaces,
            scan_stale_ns=round(timing.scan_stale_s * NS_PER_S),
            odom_stale_ns=round(timing.odom_stale_s * NS_PER_S),
            truth_stale_ns=round(timing.truth_stale_s * NS_PER_S) if self.use_truth else None,
            on_timing=self.timing,
        )
        limits = {r.namespace: VelocityLimits(r.v_max_mps, r.w_max_radps) for r in fleet.robots}
        self._cmd_pubs = {r.namespace: transport.publisher(r.topics()["cmd_vel"]) for r in fleet.robots}
        self.emitter = EmitterBuffer(
            limits,
            self._send,
            clock,
            tick_period_ns=round(timing.tick_period_s * NS_PER_S),
            validity_ns=round(timing.command_validity_s * NS_PER_S),
            on_timing=self.timing,
            on_sent=self._sent,
            prepare=self._prepare,
        )
        self._reset_pub = transport.publisher(T.FLEET_TOPICS["reset"])
        self._subs = []
        for robot in fleet.robots:
            topics = robot.topics()
            self._subs.append(transport.subscribe(topics["scan"], self._on_scan(robot.namespace)))
            self._subs.append(transport.subscribe(topics["odom"], self._on_odom(robot.namespace)))
            if self.use_truth:
                self._subs.append(transport.subscribe(topics["ground_truth"], self._on_truth(robot.namespace)))
        self._target: tuple[np.ndarray, int] | None = None
        self._target_lock = threading.Lock()
        if target:
            self._subs.append(transport.subscribe(T.TARGET_TRUTH, self._on_target))
        self._subs.append(transport.subscribe(T.FLEET_TOPICS["reset_done"], self._on_reset_done))
        if isinstance(clock, ScaledClock):
            self._subs.append(transport.subscribe(T.FLEET_TOPICS["clock"], self._on_clock))

    # -- saying ----------------------------------------------------------------------------

    def timing(self, e: TimingEvent) -> None:
        self.log.timing(e.local_ns, e.kind, e.robot, e.topic, e.source_stamp_ns, e.seq, e.tick)

    def publish_reset(self, episode: int, seed: int) -> None:
        t = self.clock.now_ns()
        msg = C.reset_request(t, episode, seed, False, store=self.store)
        self._reset_pub.publish(msg)
        self.log.message("/mrl/reset", msg, t, t)

    def _prepare(self, ns: str, v: float, w: float) -> Any:
        return self._cmd_pubs[ns].prepare(C.twist(v, w, store=self.store))

    def _send(self, ns: str, prepared: Any) -> None:
        self._cmd_pubs[ns].publish_prepared(prepared)

    def _sent(self, ns: str, v: float, w: float, t_ns: int) -> None:
        self.log.message(f"/{ns}/cmd_vel", C.twist(v, w, store=self.store), t_ns)

    # -- hearing (transport thread) --------------------------------------------------------

    # -- the fleet's writers ---------------------------------------------------------------

    def writers(self, participant: str = "") -> dict[str, tuple[int, int]]:
        """Per topic: (writers of `participant`, writers of anyone else) matched now; with no `participant`, every
        writer counts as the fleet's."""
        out = {}
        for sub in self._subs:
            every = sub.writers()
            own = sub.writers(participant) if participant else every
            out[sub.spec.name] = (len(own), len(every - own))
        return out

    def lock_writers(self, participant: str = "") -> dict[str, int]:
        """From now on hear only the writers matched now on each topic (the fleet this run discovered; with
        `participant`, only that participant's, e.g. the twin this run started): samples of any other writer on
        the domain are dropped and counted (:meth:`foreign`). Returns the writers accepted per topic."""
        counts = {}
        for sub in self._subs:
            writers = sub.writers(participant)
            sub.accept_only(writers)
            counts[sub.spec.name] = len(writers)
        self._locked = True
        return counts

    def foreign(self) -> dict[str, int]:
        """Per topic, the samples dropped because a writer this run did not discover sent them (non-zero only)."""
        return {sub.spec.name: sub.foreign for sub in self._subs if sub.foreign}

    def strays(self) -> dict[str, int]:
        """Per topic, writers matched now that this run did not discover (non-zero only)."""
        out = {}
        for sub in self._subs:
            n = len(sub.strays())
            if n:
                out[sub.spec.name] = n
        return out

    def _on_timeline(self) -> bool:
        """False until the session clock exists (under a scaled clock, before the first ``/clock``) and until the
        fleet's writers are locked: nothing heard before is recorded or used."""
        if not self._locked:
            self.unrecorded_before_lock += 1
            return False
        if isinstance(self.clock, ScaledClock) and not self.clock.anchored:
            self.unrecorded_before_clock += 1
            return False
        return True

    def _on_scan(self, ns: str) -> Callable[[Any, Any, int], None]:
        def callback(spec: Any, msg: Any, receive_ns: int) -> None:
            if not self._on_timeline():
                return
            now = self.clock.now_ns()
            sample = scan_sample(msg, now)
            self.log.message(spec.name, msg, now, sample.stamp_ns)
            self.receiver.add_scan(ns, sample, spec.name)

        return callback

    def _on_odom(self, ns: str) -> Callable[[Any, Any, int], None]:
        def callback(spec: Any, msg: Any, receive_ns: int) -> None:
            if not self._on_timeline():
                return
            now = self.clock.now_ns()
            sample = odom_sample(msg, now)
            self.log.message(spec.name, msg, now, sample.stamp_ns)
            self.receiver.add_odom(ns, sample, spec.name)

        return callback

    def _on_truth(self, ns: str) -> Callable[[Any, Any, int], None]:
        def callback(spec: Any, msg: Any, receive_ns: int) -> None:
            if not self._on_timeline():
                return
            now = self.clock.now_ns()
            stamp = C.time_ns(msg.header.stamp)
            self.log.message(spec.name, msg, now, stamp)
            self.receiver.add_truth(ns, PoseSample(stamp, now, C.planar_pose(msg.pose)), spec.name)

        return callback

    def _on_target(self, spec: Any, msg: Any, receive_ns: int) -> None:
        if not self._on_timeline():
            return
        now = self.clock.now_ns()
        self.log.message(T.TARGET_TRUTH, msg, now, C.time_ns(msg.header.stamp))
        with self._target_lock:
            self._target = (C.planar_pose(msg.pose)[:2].copy(), now)

    def target(self) -> tuple[np.ndarray, int] | None:
        """A pursuit's target: its latest position (2,) and when it was heard (session ns); None before any."""
        with self._target_lock:
            return None if self._target is None else (self._target[0].copy(), self._target[1])

    def _on_clock(self, spec: Any, msg: Any, receive_ns: int) -> None:
        if not self._locked:
            self.unrecorded_before_lock += 1
            return
        t = C.time_ns(msg.clock)
        clock = self.clock
        if isinstance(clock, ScaledClock):
            # logged at our reading when it arrived, stamped with its value: their difference is how far our copy
            # of the fleet's time had wandered, which calibration takes out of the robots' clock drift
            reading = clock.now_ns() if clock.anchored else t
            clock.follow(t, receive_ns)
            self.log.message(spec.name, msg, reading, t)

    def _on_reset_done(self, spec: Any, msg: Any, receive_ns: int) -> None:
        if not self._on_timeline():
            return
        self.log.message(spec.name, msg, self.clock.now_ns(), C.time_ns(msg.header.stamp))
        if msg.done:
            self.on_reset_done(int(msg.episode), int(msg.seed))

    def close(self) -> None:
        unrecorded = {}
        if self.unrecorded_before_clock:
            unrecorded["before_first_clock"] = str(self.unrecorded_before_clock)
        if self.unrecorded_before_lock:
            unrecorded["before_writers_locked"] = str(self.unrecorded_before_lock)
        foreign = self.foreign()
        if foreign:
            unrecorded["foreign"] = ", ".join(f"{topic}: {n}" for topic, n in sorted(foreign.items()))
        if unrecorded:
            self.log.add_metadata("unrecorded", unrecorded)
        for sub in self._subs:
            sub.close()
        for pub in self._cmd_pubs.values():
            pub.close()
        self._reset_pub.close()


class LatestSamples:
    """Every robot's latest scan, odometry and ground truth within an episode.

    A robot whose sample is missing at a control step (stale data is withheld by the receiver) keeps
    its last sample of the episode; one that has sent none since the episode's reset stops the episode
    with the topic named (FleetNotReady).
    """

    def __init__(self, namespaces: list[str], use_truth: bool) -> None:
        self.namespaces = namespaces
        self.use_truth = use_truth
        self._last: dict[str, dict[str, Any]] = {}

    def clear(self) -> None:
        self._last = {}

    def arrays(self, state: JointState) -> tuple[list[np.ndarray], list[Any], np.ndarray, np.ndarray | None]:
        """(scans, scan geometries, odometry poses (n, 3) in odometry's frame, ground truth (n, 3) or None)."""
        missing = []
        for ns in self.namespaces:
            s = state.robots[ns]
            last = self._last.setdefault(ns, {})
            for kind, sample in (("scan", s.scan), ("odom", s.odom), ("ground_truth", s.truth)):
                if sample is not None:
                    last[kind] = sample
                elif (kind != "ground_truth" or self.use_truth) and kind not in last:
                    missing.append(f"/{ns}/{kind}")
        if missing:
            raise FleetNotReady(f"no message since the episode's reset on {', '.join(missing)}")
        scans, geoms, odom, truth = [], [], [], []
        for ns in self.namespaces:
            last = self._last[ns]
            scans.append(last["scan"].ranges)
            geoms.append(last["scan"].geometry)
            odom.append(last["odom"].pose)
            if self.use_truth:
                truth.append(last["ground_truth"].pose)
        return scans, geoms, np.stack(odom), np.stack(truth) if self.use_truth else None
