"""The deploy runner: an exported policy driving a fleet over ROS 2 topics, every message recorded.

Per control period (the policy's, 0.1 s) it reads every robot's latest scan, odometry and ground
truth from the receiver buffer, builds the observation with the same core builder as the
simulator, asks the policy runtime, and queues the decoded commands in the emitter buffer,
which sends them on its own 20 ms tick. Success is judged by the same episode judge as in sim.

Episodes start with a reset handshake (the twin answers on ``/mrl/reset_done``; on real robots
an operator confirms). A robot whose data goes stale aborts the episode (zero commands, an
``abort`` event naming it); a dying twin, Ctrl-C or an emitter failure stop every robot, mark the
episode aborted, close the recording and raise DeployAborted.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from tqdm import tqdm

from pipeline.core.episode import EpisodeResult
from pipeline.core.judge import EpisodeJudge, RewardWeights
from pipeline.core.observation import ObservationBuilder
from pipeline.core.scan import uncovered_beams
from pipeline.core.scenario import Scenario
from pipeline.core.timebase import NS_PER_S
from pipeline.errors import MrlError
from pipeline.messages import convert as C
from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record.session import SessionLog
from pipeline.rollout.errors import DeployAborted, FleetNotReady
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


def _compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Planar pose composition a (+) b for (n, 3) arrays."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.stack(
        [
            a[:, 0] + c * b[:, 0] - s * b[:, 1],
            a[:, 1] + s * b[:, 0] + c * b[:, 1],
            np.angle(np.exp(1j * (a[:, 2] + b[:, 2]))),
        ],
        axis=1,
    )


def _inverse(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.stack([-c * a[:, 0] - s * a[:, 1], s * a[:, 0] - c * a[:, 1], -a[:, 2]], axis=1)


def observation_builder(runtime: PolicyRuntime, scenario: Scenario) -> ObservationBuilder:
    """The core observation builder with the lidar limits and reduction the policy was trained with."""
    lidar = runtime.meta["noise"]["lidar"]
    return ObservationBuilder(
        scenario, runtime.layout, float(lidar["range_min_m"]), float(lidar["range_max_m"]), lidar["reduction"]
    )


def scan_sample(msg: Any, receive_ns: int) -> ScanSample:
    """A LaserScan as the receiver keeps it: float64 ranges and the scan's geometry."""
    return ScanSample(
        C.time_ns(msg.header.stamp), receive_ns, np.asarray(msg.ranges, dtype=np.float64), C.scan_geometry(msg)
    )


def odom_sample(msg: Any, receive_ns: int) -> PoseSample:
    """An Odometry message as the receiver keeps it: planar pose and body velocity."""
    vel = (float(msg.twist.twist.linear.x), float(msg.twist.twist.angular.z))
    return PoseSample(C.time_ns(msg.header.stamp), receive_ns, C.planar_pose(msg.pose.pose), vel)


class DeployRunner:
    """Runs episodes of `runtime` on `fleet` (robots in scenario order) and records them to `log`."""

    def __init__(
        self,
        runtime: PolicyRuntime,
        fleet: Fleet,
        scenario: Scenario,
        transport: Transport,
        clock: Clock,
        log: SessionLog,
        fleet_alive: Callable[[], str | None] = lambda: None,
        confirm_reset: Callable[[int], None] | None = None,
    ) -> None:
        self.runtime = runtime
        self.fleet = fleet
        self.scenario = scenario
        self.transport = transport
        self.clock = clock
        self.log = log
        self.fleet_alive = fleet_alive
        self.confirm_reset = confirm_reset
        self.store = message_store()
        self.namespaces = [r.namespace for r in fleet.robots]
        self._episode = 0
        self._step = 0
        self.unrecorded_before_clock = 0
        meta = runtime.meta
        self.builder = observation_builder(runtime, scenario)
        judge = meta.get("judge", {})
        self.period_ns = round(float(meta.get("control_period_s", 0.1)) * NS_PER_S)
        self.max_steps = int(judge.get("max_steps", meta.get("max_steps", 350)))
        weights = RewardWeights(**judge["reward"]) if "reward" in judge else RewardWeights()
        self.judge = EpisodeJudge(
            scenario,
            weights,
            self.max_steps,
            float(judge.get("collision_margin_m", 0.02)),
            judge.get("progress_distance", "euclidean"),
        )
        timing = fleet.timing
        self.use_truth = timing.use_ground_truth
        self.abort_after_ns = round(timing.abort_after_s * NS_PER_S)
        self.receiver = ReceiverBuffer(
            self.namespaces,
            scan_stale_ns=round(timing.scan_stale_s * NS_PER_S),
            odom_stale_ns=round(timing.odom_stale_s * NS_PER_S),
            truth_stale_ns=round(timing.truth_stale_s * NS_PER_S) if self.use_truth else None,
            on_timing=self._timing,
        )
        limits = {r.namespace: VelocityLimits(r.v_max_mps, r.w_max_radps) for r in fleet.robots}
        self._cmd_pubs = {r.namespace: transport.publisher(r.topics()["cmd_vel"]) for r in fleet.robots}
        self.emitter = EmitterBuffer(
            limits,
            self._send,
            clock,
            tick_period_ns=round(timing.tick_period_s * NS_PER_S),
            validity_ns=round(timing.command_validity_s * NS_PER_S),
            on_timing=self._timing,
            on_sent=self._sent,
            prepare=self._prepare,
        )
        self._reset_pub = transport.publisher(T.FLEET_TOPICS["reset"])
        self._reset_done: dict[int, int] = {}
        self._reset_cv = threading.Condition()
        self._subs = []
        for robot in fleet.robots:
            topics = robot.topics()
            self._subs.append(transport.subscribe(topics["scan"], self._on_scan(robot.namespace)))
            self._subs.append(transport.subscribe(topics["odom"], self._on_odom(robot.namespace)))
            if self.use_truth:
                self._subs.append(transport.subscribe(topics["ground_truth"], self._on_truth(robot.namespace)))
        self._subs.append(transport.subscribe(T.FLEET_TOPICS["reset_done"], self._on_reset_done))
        if isinstance(clock, ScaledClock):
            self._subs.append(transport.subscribe(T.FLEET_TOPICS["clock"], self._on_clock))
        self._origin = np.zeros((len(self.namespaces), 3))
        self._last_known: dict[str, dict[str, Any]] = {}

    # -- transport callbacks (transport thread) --------------------------------------------

    def _timing(self, e: TimingEvent) -> None:
        self.log.timing(e.local_ns, e.kind, e.robot, e.topic, e.source_stamp_ns, e.seq, e.tick)

    def _prepare(self, ns: str, v: float, w: float) -> Any:
        return self._cmd_pubs[ns].prepare(C.twist(v, w, store=self.store))

    def _send(self, ns: str, prepared: Any) -> None:
        self._cmd_pubs[ns].publish_prepared(prepared)

    def _sent(self, ns: str, v: float, w: float, t_ns: int) -> None:
        self.log.message(f"/{ns}/cmd_vel", C.twist(v, w, store=self.store), t_ns)

    def _on_timeline(self) -> bool:
        """False until the session clock exists: under a scaled clock, before the first ``/clock``.

        Messages received before then are neither recorded nor used (they would be logged on another
        clock than the rest of the recording); the count goes to the ``unrecorded`` metadata record.
        """
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

    def _on_clock(self, spec: Any, msg: Any, receive_ns: int) -> None:
        t = C.time_ns(msg.clock)
        clock = self.clock
        if isinstance(clock, ScaledClock):
            clock.follow(t, receive_ns)
            self.log.message(spec.name, msg, t)

    def _on_reset_done(self, spec: Any, msg: Any, receive_ns: int) -> None:
        if not self._on_timeline():
            return
        self.log.message(spec.name, msg, self.clock.now_ns(), C.time_ns(msg.header.stamp))
        if msg.done:
            with self._reset_cv:
                self._reset_done[int(msg.episode)] = int(msg.seed)
                self._reset_cv.notify_all()

    # -- set-up ----------------------------------------------------------------------------

    def wait_for_fleet(self, timeout_s: float) -> None:
        """Wait until every robot's topics are matched (and /clock runs, when time is scaled)."""
        deadline = time.monotonic() + timeout_s
        missing: list[str] = []
        for robot in self.fleet.robots:
            topics = robot.topics()
            needed = [topics["scan"], topics["odom"], topics["cmd_vel"]]
            if self.use_truth:
                needed.append(topics["ground_truth"])
            for spec in needed:
                left = max(0.0, deadline - time.monotonic())
                if not self.transport.wait_for_match(spec, 1, left):
                    missing.append(f"{robot.name} ({spec.name})")
                    break
            self._check_alive()
        if self.fleet.target == "twin" and not self.transport.wait_for_match(
            T.FLEET_TOPICS["reset"], 1, max(0.0, deadline - time.monotonic())
        ):
            missing.append("the twin's reset handler (/mrl/reset)")
        if missing:
            raise FleetNotReady(
                f"robots did not appear within {timeout_s:g} s: {', '.join(missing)}; check that they run, the "
                f"fleet's domain id ({self.fleet.network.domain_id}) and its network peers"
            )
        if isinstance(self.clock, ScaledClock):
            while not self.clock.anchored:
                if time.monotonic() > deadline:
                    raise FleetNotReady(f"no /clock message within {timeout_s:g} s although the fleet's time is scaled")
                time.sleep(0.01)
        self._check_scans(deadline, timeout_s)

    def _check_scans(self, deadline: float, timeout_s: float) -> None:
        """Wait for every robot's first scan; refuse a lidar that leaves some of the policy's beams blind."""
        n_beams = self.builder.layout.n_beams
        pending = list(self.fleet.robots)
        while pending:
            for robot in list(pending):
                sample = self.receiver.latest("scan", robot.namespace)
                if not isinstance(sample, ScanSample):
                    continue
                pending.remove(robot)
                g = sample.geometry
                blind = uncovered_beams(g, n_beams)
                if blind:
                    first, last = (
                        np.degrees(g.angle_min_rad),
                        np.degrees(g.angle_min_rad + g.angle_increment_rad * (g.n_beams - 1)),
                    )
                    raise PolicyMismatch(
                        self.runtime.name,
                        [
                            f"it reads {n_beams} lidar beams around the robot, but {robot.topics()['scan'].name} "
                            f"has {g.n_beams} beams from {first:.0f} to {last:.0f} deg, which leave {len(blind)} "
                            f"of them without a return (policy beams {blind})"
                        ],
                    )
            if pending:
                self._check_alive()
                if time.monotonic() > deadline:
                    names = ", ".join(f"{r.name} ({r.topics()['scan'].name})" for r in pending)
                    raise FleetNotReady(f"no scan received within {timeout_s:g} s from {names}")
                time.sleep(0.01)

    def _check_alive(self) -> None:
        problem = self.fleet_alive()
        if problem:
            raise DeployAborted(problem, [])

    # -- episodes --------------------------------------------------------------------------

    def _reset(self, episode: int, seed: int) -> None:
        timeout_s = self.fleet.timing.reset_timeout_s
        self.emitter.clear()
        if self.confirm_reset is not None:
            self.confirm_reset(episode)
        else:
            t = self.clock.now_ns()
            msg = C.reset_request(t, episode, seed, False, store=self.store)
            self._reset_pub.publish(msg)
            self.log.message("/mrl/reset", msg, t, t)
            deadline = time.monotonic() + timeout_s
            with self._reset_cv:
                while episode not in self._reset_done:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise FleetNotReady(
                            f"the fleet did not confirm the reset of episode {episode} within {timeout_s:g} s"
                        )
                    self._reset_cv.wait(min(left, 0.1))
                    self._check_alive()
        reset_ns = self.clock.now_ns()
        self.receiver.clear()
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.receiver.joint_state(self.clock.now_ns())
            if state.complete and all(
                s.odom is not None and s.odom.receive_ns >= reset_ns for s in state.robots.values()
            ):
                break
            if time.monotonic() > deadline:
                raise FleetNotReady(
                    f"no fresh data after the reset of episode {episode} within {timeout_s:g} s: "
                    + "; ".join(f"{r}: {why}" for r, why in state.stale.items())
                )
            self._check_alive()
            time.sleep(0.005)
        self._last_known = {}
        odom = np.stack([state.robots[ns].odom.pose for ns in self.namespaces])  # type: ignore[union-attr]
        # odometry may count from anywhere: rebase it so that it starts at the known start poses
        self._origin = _compose(self.scenario.starts, _inverse(odom))

    def _arrays(self, state: JointState) -> tuple[list[np.ndarray], list[Any], np.ndarray, np.ndarray | None]:
        """Every robot's scan, scan geometry, odometry (map frame) and ground truth at `state`.

        A robot whose sample is missing (stale robots stand still) keeps its last sample of the episode;
        one that has sent none since the reset stops the episode with the topic named.
        """
        missing = []
        for ns in self.namespaces:
            s = state.robots[ns]
            last = self._last_known.setdefault(ns, {})
            for kind, sample in (("scan", s.scan), ("odom", s.odom), ("ground_truth", s.truth)):
                if sample is not None:
                    last[kind] = sample
                elif (kind != "ground_truth" or self.use_truth) and kind not in last:
                    missing.append(f"/{ns}/{kind}")
        if missing:
            raise FleetNotReady(f"no message since the episode's reset on {', '.join(missing)}")
        scans, geoms, odom, truth = [], [], [], []
        for ns in self.namespaces:
            last = self._last_known[ns]
            scans.append(last["scan"].ranges)
            geoms.append(last["scan"].geometry)
            odom.append(last["odom"].pose)
            if self.use_truth:
                truth.append(last["ground_truth"].pose)
        odom_map = _compose(self._origin, np.stack(odom))
        return scans, geoms, odom_map, np.stack(truth) if self.use_truth else None

    def next_control_time(self, now_ns: int) -> int:
        """The first control time at or after `now_ns` on the grid half an emitter tick before the ticks.

        Control steps fall midway between emitter ticks, so a command stamped with its control time
        is in place for the next tick even when the step runs a little late, and each command covers
        the ticks of its period exactly.
        """
        origin = self.emitter.grid_origin_ns - self.emitter.tick_period_ns // 2
        k = -((origin - now_ns) // self.period_ns)
        return origin + k * self.period_ns

    def run_episode(self, episode: int, seed: int) -> EpisodeResult:
        self._episode, self._step = episode, 0
        self._reset(episode, seed)
        n = len(self.namespaces)
        t_start = self.next_control_time(self.clock.now_ns())
        self.clock.sleep_until(t_start)
        self.log.start_episode(t_start, episode, seed)
        self.log.map(t_start, self.scenario)
        state = self.receiver.joint_state(t_start)
        scans, geoms, odom, truth = self._arrays(state)
        self.judge.reset(truth if truth is not None else odom)
        poses = [truth if truth is not None else odom]
        arrival = np.full(n, np.nan)
        done = np.zeros(n, dtype=bool)
        step = 0
        next_t = t_start
        aborted, reason = False, ""
        judged = None
        stale_since: dict[str, int] = {}
        while True:
            self._step = step
            if not self.clock.sleep_until(next_t):
                break
            t = self.clock.now_ns()
            self._timing(TimingEvent("control", "", "", t, tick=step))
            problem = self.fleet_alive()
            if problem:
                self.emitter.clear()
                self.log.event(t, episode, step, "abort", detail=problem)
                raise DeployAborted(problem, [])
            if self.emitter.error is not None:
                raise DeployAborted(f"the emitter failed: {self.emitter.error!r}", [])
            state = self.receiver.joint_state(t)
            for name in self.namespaces:
                if name in state.stale:
                    stale_since.setdefault(name, t)
                    self._timing(TimingEvent("stale", name, state.stale[name], t, tick=step))
                else:
                    stale_since.pop(name, None)
            silent = {r: why for r, why in state.stale.items() if t - stale_since[r] >= self.abort_after_ns}
            if silent:
                self.emitter.clear()
                for name, why in silent.items():
                    self.log.event(t, episode, step, "abort", name, why)
                aborted, reason = True, "; ".join(f"{r}: {why}" for r, why in silent.items())
                break
            scans, geoms, odom, truth = self._arrays(state)
            observed = self.builder.build(scans, geoms, odom)
            if step > 0:
                judged = self.judge.step(odom, truth, observed.ranges)
                for index, event in judged.events:
                    self.log.event(t, episode, step, event, "" if index < 0 else self.namespaces[index])
                new = judged.reached & np.isnan(arrival)
                arrival[new] = step * self.period_ns / NS_PER_S
                done = judged.done
                poses.append(truth if truth is not None else odom)
                if judged.done.all() or judged.truncated:
                    break
            actions = self.runtime.actions(observed.obs)
            commands = self.runtime.codec.decode(actions)
            commands[done] = 0.0
            # a robot whose data is stale stands still until it is fresh again (or the episode aborts)
            commands[[name in state.stale for name in self.namespaces]] = 0.0
            self.emitter.command_all(next_t, commands)
            for i, ns in enumerate(self.namespaces):
                self.log.observation(t, episode, step, ns, self.runtime.layout.name, observed.obs[i])
                self.log.action(
                    t, episode, step, ns, np.atleast_1d(actions[i]), (float(commands[i, 0]), float(commands[i, 1]))
                )
            self.log.tf(t, odom, truth)
            step += 1
            next_t += self.period_ns
        self.emitter.clear()
        t_end = self.clock.now_ns()
        reached = self.judge.reached.copy()
        collided = self.judge.collided.copy()
        team = bool(judged.team_success) if judged is not None else False
        outcome = "aborted" if aborted else ("team_success" if team else "incomplete")
        self.log.event(t_end, episode, step, "end", detail=outcome)
        traj = np.stack(poses)
        d = np.diff(traj[:, :, :2], axis=0)
        return EpisodeResult(
            episode=episode,
            seed=seed,
            steps=self.judge.steps,
            reached=reached,
            collided=collided,
            time_to_goal_s=arrival,
            path_length_m=np.hypot(d[..., 0], d[..., 1]).sum(axis=0),
            team_success=team,
            trajectory=traj,
            aborted=aborted,
            abort_reason=reason,
        )

    def run(self, episodes: int, seed: int, progress: bool = True) -> list[EpisodeResult]:
        """Run `episodes` episodes with seeds seed, seed+1, ...; the emitter ticks throughout."""
        results: list[EpisodeResult] = []
        bar = tqdm(range(episodes), desc="deploy", unit="ep", disable=not progress, mininterval=1.0)
        self.emitter.start()
        try:
            for k in bar:
                results.append(self.run_episode(k, seed + k))
                rate = np.mean([r.success.mean() for r in results])
                bar.set_postfix(robot_success=f"{rate:.3f}", aborted=sum(r.aborted for r in results))
        except DeployAborted as exc:
            raise DeployAborted(exc.reason, results, exc.interrupted) from None
        except MrlError as exc:  # e.g. a reset the fleet never confirmed: the finished episodes still count
            raise DeployAborted(str(exc), results) from exc
        except KeyboardInterrupt:
            self.log.event(self.clock.now_ns(), self._episode, self._step, "abort", detail="interrupted")
            raise DeployAborted("interrupted", results, interrupted=True) from None
        finally:
            bar.close()
            self.emitter.stop(send_zero=True)
        return results

    def close(self) -> None:
        if self.unrecorded_before_clock:
            self.log.add_metadata("unrecorded", {"before_first_clock": str(self.unrecorded_before_clock)})
        for sub in self._subs:
            sub.close()
        for pub in self._cmd_pubs.values():
            pub.close()
        self._reset_pub.close()
