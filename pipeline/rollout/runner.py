"""The deploy runner: an exported policy driving a fleet over ROS 2 topics, every message recorded.

Per control period (the policy's, 0.1 s) it reads every robot's latest scan, odometry and ground
truth from the receiver buffer, builds the observation with the MDP parts the policy was trained
with (:func:`pipeline.mdp.mdp_parts` of its spec), asks the policy runtime, and queues the decoded
commands in the emitter buffer, which sends them on its own 20 ms tick. Success is judged by the
same episode judge as in sim, and counted by the same tally (:mod:`pipeline.rollout.tally`).

Its parts, each with tests of its own: the transport side (:mod:`pipeline.rollout.link`: what is
heard and said, all of it recorded), the reset handshake (:mod:`pipeline.rollout.handshake`), the
staleness rule and odometry rebasing (:mod:`pipeline.rollout.watch`). A robot whose data is stale
stands still (zero commands; ``stale`` and ``fresh`` events bound the interval) while the others drive
on and the episode's time keeps running; one blind past the fleet's outage limit aborts the episode (an
``abort`` event naming it) and the next episode starts. A dying twin or driver, Ctrl-C or an emitter
failure stop every robot, count the episode under way as aborted (its robots fail unless they had
arrived), close the recording and raise DeployAborted with every episode run, that one included.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from tqdm import tqdm

from pipeline.core.episode import EpisodeResult, path_times_ns
from pipeline.core.layouts import draw_layout
from pipeline.core.network import observed_scans, stand_still
from pipeline.core.scan import uncovered_beams
from pipeline.core.scenario import Scenario
from pipeline.core.timebase import CONTROL_LATE_LIMIT, NS_PER_S
from pipeline.errors import MrlError
from pipeline.mdp import mdp_parts
from pipeline.messages import topics as T
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.protocol import Policy
from pipeline.record.session import SessionLog
from pipeline.rollout.errors import DeployAborted, FleetConflict, FleetNotReady
from pipeline.rollout.handshake import ResetHandshake
from pipeline.rollout.link import FleetLink, LatestSamples, odom_sample, scan_sample
from pipeline.rollout.pace import AutoScale
from pipeline.rollout.tally import EpisodeTally
from pipeline.rollout.watch import OdometryFrame, StalenessWatch
from pipeline.ros.buffers import PoseSample, ScanSample, TimingEvent
from pipeline.ros.clock import Clock, ScaledClock
from pipeline.ros.fleet import Fleet
from pipeline.ros.transport import Transport

__all__ = ["DeployRunner", "odom_sample", "scan_sample", "stale_rows"]

STRAYS_EVERY = 10
"""Control steps between two look-ups of the writers matched on the fleet's topics (DDS calls per subscription, kept
off most steps of the control loop); a stray's messages are counted at every step."""


def stale_rows(namespaces: list[str], stale: dict[str, str]) -> np.ndarray:
    """(n_robots,) True for the robots whose data is stale: they stand still."""
    return np.array([name in stale for name in namespaces], dtype=bool)


class DeployRunner:
    """Runs episodes of `runtime` on `fleet` (robots in scenario order) and records them to `log`."""

    def __init__(
        self,
        runtime: Policy,
        fleet: Fleet,
        scenario: Scenario,
        transport: Transport,
        clock: Clock,
        log: SessionLog,
        fleet_alive: Callable[[], str | None] = lambda: None,
        confirm_reset: Callable[[int], None] | None = None,
        fleet_participant: str = "",
    ) -> None:
        """`fleet_participant`: the participant whose writers are the fleet (the twin this run started); '' for
        robots, whose writers are whichever one publishes each robot topic."""
        self.runtime = runtime
        self.fleet_participant = fleet_participant
        self.fleet = fleet
        self.scenario = scenario
        self.transport = transport
        self.clock = clock
        self.log = log
        self.fleet_alive = fleet_alive
        self.namespaces = [r.namespace for r in fleet.robots]
        self._episode = 0
        self._step = 0
        self._t_start = 0
        self.mdp = mdp_parts(scenario, runtime.spec.world)  # the MDP the policy was trained in
        self.builder = self.mdp.observer
        self.judge = self.mdp.judge
        self.layout = scenario
        """The current episode's layout: drawn from its seed when the fleet's scenario has layouts ranges, as the
        twin draws it (:mod:`pipeline.core.layouts`)."""
        self.period_ns = self.mdp.period_ns
        self.use_truth = fleet.timing.use_ground_truth
        self.observe_truth = self.mdp.definition.observed_pose == "ground_truth"
        self.stale_scan = runtime.spec.world.network.stale_scan
        """What the policy observes of a stale robot's scan, as in the world it was trained in."""
        self.handshake = ResetHandshake(
            lambda episode, seed: self.link.publish_reset(episode, seed),
            fleet.timing.reset_timeout_s,
            self._check_alive,
            confirm_reset,
        )
        self.pursuit = scenario.pursuit
        self.link = FleetLink(fleet, transport, clock, log, self.handshake.confirmed, target=self.pursuit)
        self.receiver = self.link.receiver
        self.emitter = self.link.emitter
        self.staleness = StalenessWatch(round(fleet.timing.outage_limit_s * NS_PER_S), self.namespaces)
        self._tally: EpisodeTally | None = None
        """The episode under way (between its start event and its result), None between episodes."""
        self._fatal: DeployAborted | None = None
        self.late_ns: list[int] = []
        """How late each control step of the episode under way woke, on the fleet's clock (ns)."""
        self.late_by_episode: dict[int, float] = {}
        """Per episode run: its control steps' lateness, the 95th percentile as a share of the control period."""
        self.pacer: AutoScale | None = None
        """Where the time scale is ``auto``: told when each episode starts and ends, it lowers the scale."""
        """Set when an episode ended on a fault that stops the deployment (a twin or driver gone, the emitter)."""
        self.samples = LatestSamples(self.namespaces, self.use_truth)
        self.odometry = OdometryFrame(len(self.namespaces))

    @property
    def unrecorded_before_clock(self) -> int:
        return self.link.unrecorded_before_clock

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
        if self.pursuit and not self.transport.wait_for_match(T.TARGET_TRUTH, 1, max(0.0, deadline - time.monotonic())):
            missing.append(f"the pursuit's target ({T.TARGET_TRUTH.name})")
        if self.fleet.target == "twin" and not (
            self.transport.wait_for_match(T.FLEET_TOPICS["reset"], 1, max(0.0, deadline - time.monotonic()))
            and self.transport.wait_for_match(T.FLEET_TOPICS["reset_done"], 1, max(0.0, deadline - time.monotonic()))
        ):
            missing.append("the twin's reset handler (/mrl/reset)")
        if isinstance(self.clock, ScaledClock) and not self.transport.wait_for_match(
            T.FLEET_TOPICS["clock"], 1, max(0.0, deadline - time.monotonic())
        ):
            missing.append("the fleet's clock (/clock)")
        if missing:
            raise FleetNotReady(
                f"robots did not appear within {timeout_s:g} s: {', '.join(missing)}; check that they run, the "
                f"fleet's domain id ({self.fleet.network.domain_id}) and its network peers"
            )
        self._lock_writers(deadline, timeout_s)
        if isinstance(self.clock, ScaledClock):
            while not self.clock.anchored:
                if time.monotonic() > deadline:
                    raise FleetNotReady(f"no /clock message within {timeout_s:g} s although the fleet's time is scaled")
                time.sleep(0.01)
        self._check_scans(deadline, timeout_s)

    def _robot_topics(self) -> list[str]:
        return [
            spec.name
            for robot in self.fleet.robots
            for kind, spec in robot.topics().items()
            if kind != "cmd_vel" and (kind != "ground_truth" or self.use_truth)
        ]

    def _lock_writers(self, deadline: float, timeout_s: float) -> None:
        """Hear only the fleet's writers: the twin's when this run started one (once each robot topic has it), else
        the ones discovered now. Each robot topic must have exactly one, and no other writer may be there (another
        robot, twin or run on the domain). Nothing heard before is recorded or used."""
        topics = self._robot_topics()
        while True:
            found = self.link.writers(self.fleet_participant)
            missing = [t for t in topics if found.get(t, (0, 0))[0] == 0]
            if not missing or not self.fleet_participant:
                break
            if time.monotonic() > deadline:
                raise FleetNotReady(
                    f"the twin this run started did not appear within {timeout_s:g} s on {', '.join(missing)}"
                )
            self._check_alive()
            time.sleep(0.01)
        others = {t: n for t, (_, n) in found.items() if n}
        counts = self.link.lock_writers(self.fleet_participant)
        crowded = {topic: counts.get(topic, 0) for topic in topics if counts.get(topic, 0) > 1}
        crowded.update(others)
        if crowded:
            raise FleetConflict(
                self.fleet.network.domain,
                [f"{n} publishers on {topic}" for topic, n in sorted(crowded.items())],
                "each robot's topics must have one publisher; another robot, twin or run on this domain uses the "
                "same namespaces: stop it, or give the fleet file another network.domain_id (mrl deploy --domain-id)",
            )

    def _clash(self, strays: bool) -> str | None:
        """A writer this run did not discover, publishing on the fleet's topics (or, with `strays`, matched on
        them): what and where."""
        foreign = self.link.foreign()
        strays_seen = self.link.strays() if strays else {}
        if not foreign and not strays_seen:
            return None
        seen = [f"{n} message(s) on {topic}" for topic, n in sorted(foreign.items())]
        seen += [f"{n} new writer(s) on {topic}" for topic, n in sorted(strays_seen.items())]
        return (
            f"a writer this run did not discover is on DDS domain {self.fleet.network.domain_id}: {'; '.join(seen)} "
            "(dropped, never recorded); another robot, twin or run uses the fleet's topics: stop it, or give the "
            "fleet file another network.domain_id (mrl deploy --domain-id)"
        )

    def _check_scans(self, deadline: float, timeout_s: float) -> None:
        """Wait for every robot's first scan; refuse lidars that leave some of the policy's beams blind,
        naming each such robot in fleet order."""
        n_beams = self.builder.layout.n_beams
        first: dict[str, ScanSample] = {}
        while len(first) < len(self.fleet.robots):
            for robot in self.fleet.robots:
                sample = self.receiver.latest("scan", robot.namespace)
                if isinstance(sample, ScanSample):
                    first.setdefault(robot.namespace, sample)
            if len(first) < len(self.fleet.robots):
                self._check_alive()
                if time.monotonic() > deadline:
                    pending = [r for r in self.fleet.robots if r.namespace not in first]
                    names = ", ".join(f"{r.name} ({r.topics()['scan'].name})" for r in pending)
                    raise FleetNotReady(f"no scan received within {timeout_s:g} s from {names}")
                time.sleep(0.01)
        problems = []
        for robot in self.fleet.robots:
            g = first[robot.namespace].geometry
            blind = uncovered_beams(g, n_beams)
            if blind:
                start, end = (
                    np.degrees(g.angle_min_rad),
                    np.degrees(g.angle_min_rad + g.angle_increment_rad * (g.n_beams - 1)),
                )
                problems.append(
                    f"it reads {n_beams} lidar beams around the robot, but {robot.topics()['scan'].name} "
                    f"has {g.n_beams} beams from {start:.0f} to {end:.0f} deg, which leave {len(blind)} "
                    f"of them without a return (policy beams {blind})"
                )
        if problems:
            raise PolicyMismatch(self.runtime.name, problems)

    def _check_alive(self) -> None:
        problem = self.fleet_alive()
        if problem:
            raise DeployAborted(problem, [])

    # -- episodes --------------------------------------------------------------------------

    def _reset(self, episode: int, seed: int) -> None:
        """The handshake, then fresh data from every robot; odometry is rebased onto the layout's starts."""
        self.layout = draw_layout(self.scenario, seed)
        self.mdp.use_layout(self.layout)
        self.emitter.clear()
        self.handshake.request(episode, seed)
        timeout_s = self.fleet.timing.reset_timeout_s
        reset_ns = self.clock.now_ns()
        self.receiver.clear()
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.receiver.joint_state(self.clock.now_ns())
            target = self.link.target() if self.pursuit else None
            target_fresh = not self.pursuit or (target is not None and target[1] >= reset_ns)
            if (
                state.complete
                and target_fresh
                and all(s.odom is not None and s.odom.receive_ns >= reset_ns for s in state.robots.values())
            ):
                break
            if time.monotonic() > deadline:
                stale = [f"{r}: {why}" for r, why in state.stale.items()]
                if not target_fresh:
                    stale.append(f"no pose of the target on {T.TARGET_TRUTH.name}")
                raise FleetNotReady(
                    f"no fresh data after the reset of episode {episode} within {timeout_s:g} s: " + "; ".join(stale)
                )
            self._check_alive()
            time.sleep(0.005)
        self.samples.clear()
        # the fresh data the reset found are the episode's first samples: a twin that falls behind its clock right
        # after (a busy host) withholds newer ones as stale at the first control step, and the robots then stand
        # still as at any stale step (an outage past its limit), not a fleet that never sent anything
        self.samples.arrays(state)
        self.staleness.reset()
        odom = np.stack([state.robots[ns].odom.pose for ns in self.namespaces])  # type: ignore[union-attr]
        self.odometry.rebase(self.layout.starts, odom)

    def _track(self) -> None:
        """A pursuit's goals are where motion capture last saw its target."""
        target = self.link.target() if self.pursuit else None
        if target is not None:
            self.mdp.track(target[0])

    def next_control_time(self, now_ns: int) -> int:
        """The first control time at or after `now_ns` on the grid half an emitter tick before the ticks.

        Control steps fall midway between emitter ticks, so a command stamped with its control time
        is in place for the next tick even when the step runs a little late, and each command covers
        the ticks of its period exactly.
        """
        origin = self.emitter.grid_origin_ns - self.emitter.tick_period_ns // 2
        k = -((origin - now_ns) // self.period_ns)
        return origin + k * self.period_ns

    def _path_poses(self, at_ns: int, previous: np.ndarray) -> np.ndarray:
        """(n_robots, 3) the episode's path at a control step: each robot's newest ground truth (odometry in the map
        frame, for a fleet without motion capture) received at or before `at_ns`, as the recording's analysis reads it
        back; `previous` stands in for a robot whose ring holds nothing that old."""
        found = [self.receiver.latest("truth" if self.use_truth else "odom", ns, at_ns) for ns in self.namespaces]
        have = np.array([isinstance(s, PoseSample) for s in found])
        raw = np.stack([s.pose if isinstance(s, PoseSample) else np.zeros(3) for s in found])
        poses = np.array(previous, dtype=float, copy=True)
        poses[have] = (raw if self.use_truth else self.odometry.to_map(raw))[have]
        return poses

    def run_episode(self, episode: int, seed: int) -> EpisodeResult:
        self._episode, self._step = episode, 0
        self._reset(episode, seed)
        t_start = self.next_control_time(self.clock.now_ns())
        self._t_start = t_start
        self.clock.sleep_until(t_start)
        self.log.start_episode(t_start, episode, seed)
        self.log.map(t_start, self.layout)
        _, _, odom_raw, truth = self.samples.arrays(self.receiver.joint_state(t_start))
        odom = self.odometry.to_map(odom_raw)
        self._track()
        self.judge.reset(truth if truth is not None else odom)
        self.builder.forget()
        tally = EpisodeTally(episode, seed, self.namespaces, self.mdp.definition.control_period_s)
        tally.start(truth if truth is not None else odom)
        self._tally = tally
        done = np.zeros(len(self.namespaces), dtype=bool)
        step = 0
        next_t = t_start
        aborted, reason, kind = False, "", ""
        clash = self._clash(strays=True)
        if clash:  # heard between the episodes: no episode of this run may take data from another writer
            self._fatal = DeployAborted(clash, [])
            cut = self._cut_short(clash, "clash")
            assert cut is not None  # the tally above is the episode under way
            return cut
        while True:
            self._step = step
            if not self.clock.sleep_until(next_t):
                break
            t = self.clock.now_ns()
            self.late_ns.append(t - next_t)  # how late this control step woke (the fleet's time)
            if step > 0:  # the path at this step's time on the control grid, whatever happens in the step
                tally.stepped(self._path_poses(next_t, tally.poses[-1]))
            self.link.timing(TimingEvent("control", "", "", t, tick=step))
            problem, kind = self.fleet_alive(), "fault"
            if problem is None and self.emitter.error is not None:
                problem = f"the emitter failed: {self.emitter.error!r}"
            if problem is None:
                # new writers are looked up every STRAYS_EVERY steps; their messages are counted as they arrive
                problem, kind = self._clash(strays=step % STRAYS_EVERY == 0), "clash"
            if problem:
                self.emitter.clear()
                self.log.event(self.clock.now_ns(), episode, step, "abort", detail=problem)
                self.emitter.halt()
                self._fatal = DeployAborted(problem, [])
                aborted, reason = True, problem
                break
            state = self.receiver.joint_state(t)
            for name in self.namespaces:
                if name in state.stale:
                    self.link.timing(TimingEvent("stale", name, state.stale[name], t, tick=step))
            change = self.staleness.update(t, state.stale)
            for name, why in change.began.items():
                self.log.event(t, episode, step, "stale", name, why)
            for name, seconds in change.ended.items():
                self.log.event(t, episode, step, "fresh", name, f"{seconds:.3f} s stale")
            if change.outage:
                self.emitter.clear()  # waits for a tick in flight: every command recorded after the event is zero
                t_abort = self.clock.now_ns()
                limit = self.fleet.timing.outage_limit_s
                for name, why in change.outage.items():
                    self.log.event(t_abort, episode, step, "abort", name, f"blind for {limit:g} s: {why}")
                self.emitter.halt()  # the fleet stops now, not at the next tick
                reason = "; ".join(f"{r}: blind for {limit:g} s ({why})" for r, why in change.outage.items())
                aborted, kind = True, "outage"
                break
            stale = stale_rows(self.namespaces, state.stale)
            scans, geoms, odom_raw, truth = self.samples.arrays(state)
            scans = observed_scans(scans, stale, self.stale_scan)  # the simulator's rule, the same function
            odom = self.odometry.to_map(odom_raw)
            self._track()
            observed = self.builder.build(scans, geoms, truth if self.observe_truth and truth is not None else odom)
            if step > 0:
                judged = self.judge.step(odom, truth, observed.ranges)
                tally.log_events(self.log, t, step, judged)
                tally.judged(judged, self.judge.steps)
                done = judged.done
                if judged.done.all() or judged.truncated:
                    break
            actions = self.runtime.actions(observed.obs)
            commands = self.runtime.codec.decode(actions)
            commands[done] = 0.0
            # a robot whose data is stale stands still until it is fresh again (or blind past the outage limit)
            stand_still(commands, stale)
            self.emitter.command_all(next_t, commands)
            self.builder.remember(commands)
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
        self.log.event(t_end, episode, step, "end", detail=tally.outcome(aborted))
        self._tally = None
        result = tally.result(self.judge, aborted, reason, kind, self.staleness.stale_s(t_end))
        if not self.late_ns:
            return result
        late = float(np.percentile(self.late_ns, 95)) / self.period_ns
        self.late_by_episode[episode] = late
        return replace(result, control_late_p95=late, clock_kept=late <= CONTROL_LATE_LIMIT)

    def _cut_short(self, why: str, kind: str) -> EpisodeResult | None:
        """The episode under way, if any, ended now as aborted (`kind`), with an ``abort`` and an ``end`` event."""
        tally, self._tally = self._tally, None
        if tally is None:
            return None
        t = self.clock.now_ns()
        while tally.sampled_steps < self._step:  # the step it stopped in: at its time, or now if that comes first
            at = int(path_times_ns(self._t_start, self.period_ns, tally.sampled_steps + 1, t)[-1])
            tally.stepped(self._path_poses(at, tally.poses[-1]))
        self.log.event(t, self._episode, self._step, "abort", detail=why)
        self.log.event(t, self._episode, self._step, "end", detail="aborted")
        return tally.result(self.judge, True, why, kind, self.staleness.stale_s(t))

    def run(self, episodes: int, seed: int, progress: bool = True) -> list[EpisodeResult]:
        """Run `episodes` episodes with seeds seed, seed+1, ...; the emitter ticks throughout. At ``auto`` (a
        pacer), an episode in which the twin did not keep its clock, or the control steps woke past their limit, is
        followed by one more (the next seed), up to :meth:`AutoScale.reruns_for` of them: the marked episode stays.

        Raises DeployAborted with every episode run (the one a fault or Ctrl-C cut short counted as aborted)
        when the deployment cannot go on."""
        results: list[EpisodeResult] = []
        reruns = AutoScale.reruns_for(episodes) if self.pacer is not None else 0
        total = episodes
        bar = tqdm(total=episodes, desc="deploy", unit="ep", disable=not progress, mininterval=1.0)
        self._fatal = None
        self.emitter.start()
        try:
            k = 0
            while k < total:
                if self.pacer is not None:
                    self.pacer.episode_started()
                self.late_ns = []
                results.append(self.run_episode(k, seed + k))
                bar.update(1)
                if self.pacer is not None:
                    last = results[-1]
                    behind = self.pacer.after_episode(k, outage=last.abort_kind == "outage", late=last.control_late_p95)
                    if (behind or not last.clock_kept) and total - episodes < reruns:
                        total += 1
                        bar.total = total
                        print(
                            f"deploy: episode {k} did not keep its clock (marked, not the policy's): one more episode "
                            f"in its place ({total - episodes} of at most {reruns})",
                            file=sys.stderr,
                            flush=True,
                        )
                if self._fatal is not None:
                    raise self._fatal
                rate = np.mean([r.success.mean() for r in results])
                bar.set_postfix(robot_success=f"{rate:.3f}", aborted=sum(r.aborted for r in results))
                k += 1
        except DeployAborted as exc:
            cut = self._cut_short(exc.reason, "fault")
            raise DeployAborted(exc.reason, results + ([cut] if cut else []), exc.interrupted) from None
        except MrlError as exc:  # e.g. a reset the fleet never confirmed: the episodes run still count
            self.emitter.halt()
            cut = self._cut_short(str(exc), "fault")
            raise DeployAborted(str(exc), results + ([cut] if cut else [])) from exc
        except KeyboardInterrupt:
            self.emitter.halt()
            cut = self._cut_short("interrupted", "interrupted")
            if cut is None:
                self.log.event(self.clock.now_ns(), self._episode, self._step, "abort", detail="interrupted")
            raise DeployAborted("interrupted", results + ([cut] if cut else []), interrupted=True) from None
        finally:
            bar.close()
            self.emitter.stop(send_zero=True)
        return results

    def close(self) -> None:
        self.link.close()
