"""A deployment session: fleet up (starting the hardware twin when the fleet says so), runner, recording.

Everything opened here is closed on every exit path: robots get zero velocity, the MCAP is
finalized, the transport and the twin process are shut down.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from pipeline.core.episode import EpisodeResult, summarize
from pipeline.core.scenario import Scenario, load_scenario
from pipeline.core.timebase import CONTROL_LATE_LIMIT, REALIZED_MARGIN
from pipeline.errors import InvalidMeasurement, MrlError, RuntimeFault
from pipeline.mappings import to_mapping
from pipeline.messages import topics as T
from pipeline.messages.topics import TopicSpec
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.protocol import Policy
from pipeline.record import McapLog
from pipeline.record.live import LiveView
from pipeline.record.results import SessionFolder, write_episodes, write_metrics
from pipeline.record.rosbag2 import write_rosbag2_metadata
from pipeline.record.session import (
    CONTROL_TIMING_META,
    TWIN_TIMING_META,
    SessionLog,
    clock_metadata,
    dumps,
    session_metadata,
)
from pipeline.rollout.errors import DeployAborted, FleetConfigMismatch, FleetConflict, FleetNotReady
from pipeline.rollout.pace import AUTO_START_SCALE, PACE_EVERY_S, AutoScale, behind_note
from pipeline.rollout.runner import DeployRunner
from pipeline.rollout.twin_process import TWIN_START_TIMEOUT_S, TwinProcess, read_timing, stop_twin, with_timing
from pipeline.ros.clock import Clock, ScaledClock, WallClock
from pipeline.ros.domains import NoFreeDomainError, lease_free_domain, lock_path, try_lease
from pipeline.ros.fleet import Fleet
from pipeline.ros.ros1 import private_master
from pipeline.ros.transport import NetworkSettings, Transport, open_transport

SWITCH_INTERVAL_S = 0.00005


@dataclass(frozen=True)
class DeployRequest:
    """One deployment session's settings beyond the fleet file."""

    episodes: int
    seed: int
    recording: Path
    time_scale: float | Literal["auto"] = 0.0
    """Twin time scale, or ``auto`` (:mod:`pipeline.rollout.pace`); 0 keeps the fleet file's."""
    profile: str = ""
    """Twin reality profile; empty keeps the fleet file's."""
    chunk_size_bytes: int = 1_048_576
    params_text: str = ""
    progress: bool = True


STRAY_WATCH_S = 1.0
"""How long the domain is watched for robots that are already there before the twin is started."""
SETTLE_S = 0.3
"""Time for late discovery replies before publishers per topic are counted."""


def check_policy_fits_fleet(runtime: Policy, fleet: Fleet, scenario: Scenario) -> None:
    """Refuse a policy trained for other robots, another layout, beam count or scenario, or that commands
    more than a robot's velocity limits (its commands would be clamped: another action space)."""
    runtime.check_fits(fleet.names, runtime.layout)
    problems = []
    trained = runtime.spec.scenario
    if trained.name != scenario.name:
        # a policy trained on layouts drawn per episode may drive any other layout of the same room and robots
        beyond = trained.beyond_layout(scenario)
        if trained.layouts is None and not beyond:
            beyond = [
                "it was trained on one fixed layout; a policy trained on layouts ranges may drive another layout "
                "of its room and robots"
            ]
        if beyond:
            where = f"it was trained in scenario {trained.name!r}, the fleet drives in {scenario.name!r}"
            problems.append(f"{where} ({'; '.join(beyond)})")
    if scenario.layouts is not None and runtime.layout.name == "paper":
        problems.append(
            f"scenario {scenario.name!r} draws a layout per episode and the policy's observation ('paper') has no goal"
        )
    if scenario.pursuit and not fleet.timing.use_ground_truth:
        problems.append(
            f"scenario {scenario.name!r} is a pursuit: the policy needs the target's pose from motion capture "
            f"({T.TARGET_TRUTH.name}), and the fleet has none (timing.use_ground_truth is false)"
        )
    if runtime.spec.mdp.observed_pose == "ground_truth" and not fleet.timing.use_ground_truth:
        problems.append(
            "the policy observes the robots' ground-truth poses (world.observed_pose: ground_truth), and the fleet "
            "has no motion capture (timing.use_ground_truth is false)"
        )
    if scenario.pursuit and runtime.layout.name == "paper":
        problems.append(f"scenario {scenario.name!r} is a pursuit and the policy's observation ('paper') has no goal")
    if scenario.layouts is not None and fleet.target == "robots":
        problems.append(
            f"scenario {scenario.name!r} draws a layout per episode: on real robots someone would have to move the "
            "boxes before every episode (deploy its fixed layout with a scenario without layouts ranges)"
        )
    codec = runtime.codec
    limits = codec.limits(len(fleet.robots)) if len(codec.robot_limits) in (0, len(fleet.robots)) else None
    for i, robot in enumerate(fleet.robots):
        v, w = (codec.v_max_mps, codec.w_max_radps) if limits is None else (float(limits[i, 0]), float(limits[i, 1]))
        where = "world.actions.v_max_mps, w_max_radps" if not codec.robot_limits else f"its scenario's {robot.name}"
        if v > robot.v_max_mps + 1e-9 or w > robot.w_max_radps + 1e-9:
            problems.append(
                f"it commands {robot.name} up to {v:g} m/s and {w:g} rad/s (policy.json "
                f"{where}), the fleet limits {robot.name} to {robot.v_max_mps:g} m/s "
                f"and {robot.w_max_radps:g} rad/s (fleet file robots[{robot.name}].v_max_mps, w_max_radps): its "
                "commands would be clamped; retrain with world.actions within the fleet's limits"
            )
        elif runtime.layout.name == "rich_limits" and (
            abs(v - robot.v_max_mps) > 1e-9 or abs(w - robot.w_max_radps) > 1e-9
        ):
            problems.append(
                f"{robot.name} was trained with limits {v:g} m/s and {w:g} rad/s, which its observation carries; "
                f"the fleet gives it {robot.v_max_mps:g} m/s and {robot.w_max_radps:g} rad/s (fleet file "
                f"robots[{robot.name}]): its observation would be wrong"
            )
    if problems:
        raise PolicyMismatch(runtime.name, problems)


def _publishers(transport: Transport, specs: list[TopicSpec]) -> dict[str, int]:
    return {spec.name: transport.matched_count(spec) for spec in specs}


def check_domain_is_free(transport: Transport, fleet: Fleet, watch_s: float = STRAY_WATCH_S) -> None:
    """Before the twin starts: refuse a domain where the fleet's robots (or a twin) already publish."""
    specs = [r.topics()["scan"] for r in fleet.robots] + [r.topics()["odom"] for r in fleet.robots]
    specs.append(T.FLEET_TOPICS["reset_done"])
    subs = [transport.subscribe(spec, lambda *_: None) for spec in specs]
    try:
        deadline = time.monotonic() + watch_s
        seen: dict[str, int] = {}
        while time.monotonic() < deadline:
            seen = {k: n for k, n in _publishers(transport, specs).items() if n}
            if seen:
                time.sleep(SETTLE_S)
                seen = {k: n for k, n in _publishers(transport, specs).items() if n}
                break
            time.sleep(0.05)
    finally:
        for sub in subs:
            sub.close()
    if seen:
        raise FleetConflict(
            fleet.network.domain,
            [f"{n} publisher(s) on {topic}" for topic, n in sorted(seen.items())],
            "robots this deployment did not start (a twin left running, or another user on this domain); stop "
            "them, or give the fleet file another network.domain_id",
        )


def check_one_publisher_each(transport: Transport, fleet: Fleet) -> None:
    """After discovery: every robot's scan and odometry come from exactly one publisher."""
    time.sleep(SETTLE_S)
    specs = [r.topics()["scan"] for r in fleet.robots] + [r.topics()["odom"] for r in fleet.robots]
    crowded = {k: n for k, n in _publishers(transport, specs).items() if n > 1}
    if crowded:
        raise FleetConflict(
            fleet.network.domain,
            [f"{n} publishers on {topic}" for topic, n in sorted(crowded.items())],
            "each robot's topics must have one publisher; another robot or twin on this domain uses the same "
            "namespaces: stop it, or give the fleet file another network.domain_id",
        )


def deploy_policy(
    runtime: Policy,
    fleet: Fleet,
    fleet_source: str,
    request: DeployRequest,
    confirm_reset: Callable[[int], None] | None = None,
    twin_extra_args: list[str] | None = None,
    live: LiveView | None = None,
) -> tuple[list[EpisodeResult], str]:
    """Run a deployment session; returns the episodes and the reality profile name ('robots' on hardware).

    Everything that can be checked is checked before the recording is created: the policy against the
    fleet, the domain for robots already there, and the twin's own inputs (it reports ready only after
    reading its fleet, profile and scenario).
    """
    scenario = load_scenario(fleet.scenario, len(fleet.robots))
    # a thread that wants the interpreter waits at most this long: the emitter's tick stays on time
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    check_policy_fits_fleet(runtime, fleet, scenario)
    with ExitStack() as stack:
        pinned = fleet.network.domain_id is not None
        fleet = _leased_domain(fleet, stack)
        note = ""
        if request.progress and fleet.transport != "ros1":
            how = "the fleet file's" if pinned else "a free one of this machine's"
            note = f"deploy: DDS domain {fleet.network.domain} ({how}), held for this run"
        settings = fleet.network_settings(fleet_source, on_this_host=True)
        if _needs_own_master(fleet, settings):
            # a ROS 1 twin fleet without a master brings its own, as it brings its twin; the twin process and this
            # one find it through ROS_MASTER_URI
            uri = stack.enter_context(private_master())
            stack.enter_context(_environment("ROS_MASTER_URI", uri))
            settings = replace(settings, master_uri=uri)
        return _deploy(
            runtime, fleet, fleet_source, request, scenario, settings, confirm_reset, twin_extra_args, live, note
        )


def _leased_domain(fleet: Fleet, stack: ExitStack) -> Fleet:
    """`fleet` on the DDS domain this deployment holds for as long as it runs (:mod:`pipeline.ros.domains`): a
    free one where the fleet file gives none and the twin plays the robots, else the file's. Another deployment on
    this machine holding a pinned domain is refused by name before anything starts. ROS 1 has no domains."""
    if fleet.transport == "ros1":
        return fleet
    pinned = fleet.network.domain_id
    if pinned is None and fleet.target == "twin":
        try:
            lease = lease_free_domain()
        except NoFreeDomainError as exc:
            raise RuntimeFault(str(exc)) from exc
    else:
        domain = 0 if pinned is None else pinned
        held = try_lease(domain)
        if held is None:
            raise FleetConflict(
                domain,
                [f"another deployment on this machine (its lease: {lock_path(domain)})"],
                "wait for it to finish, or give the fleet file another network.domain_id (mrl deploy --domain-id); "
                "a twin fleet without one takes a free domain",
            )
        lease = held
    stack.callback(lease.release)
    return replace(fleet, network=replace(fleet.network, domain_id=lease.domain_id))


def _needs_own_master(fleet: Fleet, settings: NetworkSettings) -> bool:
    """A ROS 1 fleet played by the twin whose fleet file and environment name no master."""
    return (
        fleet.transport == "ros1"
        and fleet.target == "twin"
        and not settings.master_uri
        and not os.environ.get("ROS_MASTER_URI")
    )


@contextmanager
def _environment(name: str, value: str) -> Iterator[None]:
    saved = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = saved


def _deploy(
    runtime: Policy,
    fleet: Fleet,
    fleet_source: str,
    request: DeployRequest,
    scenario: Scenario,
    settings: NetworkSettings,
    confirm_reset: Callable[[int], None] | None,
    twin_extra_args: list[str] | None,
    live: LiveView | None,
    domain_note: str = "",
) -> tuple[list[EpisodeResult], str]:
    twin: TwinProcess | None = None
    profile = "robots"
    scale = 1.0
    auto = False
    timing: dict[int, dict[str, Any]] = {}
    timing_dir: str | None = None
    transport = None
    log = None
    runner = None
    try:
        transport = open_transport(fleet.transport, settings)
        if domain_note:  # the transport is up: what could be refused before anything moves was
            print(domain_note, file=sys.stderr, flush=True)
        if fleet.target == "twin":
            check_domain_is_free(transport, fleet)
            profile = request.profile or fleet.twin.profile
            asked = request.time_scale or fleet.twin.time_scale
            auto = asked == "auto"
            scale = AUTO_START_SCALE if asked == "auto" else float(asked)
            timing_dir = tempfile.mkdtemp(prefix="mrl-twin-timing-")
            timing_file = Path(timing_dir) / "timing.json"
            extra = [*(twin_extra_args or []), "--timing-record", str(timing_file)]
            extra += ["--pace", repr(PACE_EVERY_S)]  # how it keeps its clock: for auto, and to tell a busy host
            twin = TwinProcess(fleet_source, profile, scale, fleet.twin.seed, extra, fleet.network.domain_id)
            profile = Path(profile).stem
            twin.wait_ready(TWIN_START_TIMEOUT_S)
        clock: Clock = ScaledClock(scale) if scale != 1.0 or auto else WallClock()
        session = session_metadata(
            "real",
            scenario.name,
            [r.namespace for r in fleet.robots],
            runtime.spec.world.control_period_s,
            runtime.document,
            profile=profile,
            extra={
                "target": fleet.target,
                "transport": fleet.transport,
                **({"domain_id": str(fleet.network.domain)} if fleet.transport != "ros1" else {}),
                "time_scale": "auto" if auto else repr(scale),
                "fleet": fleet_source,
                **clock_metadata(scale),
                **({"clock_rate": "auto"} if auto else {}),
                **runtime.session_extra,
            },
        )
        documents = {
            "params": request.params_text,
            "scenario": dumps(to_mapping(scenario)),
            "fleet": dumps(to_mapping(fleet)),
            "policy": dumps(runtime.document),
        }
        log = SessionLog(
            request.recording, [r.namespace for r in fleet.robots], session, documents, request.chunk_size_bytes
        )
        log.announce_events(transport.publisher(T.FLEET_TOPICS["episode"]).publish)  # for recorders of the network
        if live is not None:
            live.attach(log.recorder)
        runner = DeployRunner(
            runtime,
            fleet,
            scenario,
            transport,
            clock,
            log,
            fleet_alive=(twin.problem if twin is not None else lambda: None),
            fleet_participant=twin.participant if twin is not None else "",
            confirm_reset=confirm_reset if fleet.target == "robots" else None,
        )
        runner.wait_for_fleet(fleet.timing.discovery_timeout_s)
        check_one_publisher_each(transport, fleet)
        if auto and twin is not None and isinstance(clock, ScaledClock):
            pacer = AutoScale(twin.paces, twin.ask_scale, clock, scale)
            scale = pacer.probe()
            print(f"deploy: time scale auto: {pacer.said()}", file=sys.stderr, flush=True)
            runner.pacer = pacer
        try:
            results = runner.run(request.episodes, request.seed, request.progress)
        except DeployAborted as exc:
            if twin is not None:  # the episodes run are marked as the twin kept its clock in them
                stop_twin(twin)
                exc.results = with_timing(exc.results, read_timing(timing_file))
            raise
    except (DeployAborted, FleetNotReady) as exc:
        note = behind_note(twin.paces) if twin is not None else ""
        if not note:  # a fleet that went silent on a host that kept the twin's clock: the fleet's fault, as said
            raise
        if isinstance(exc, DeployAborted):
            raise DeployAborted(f"{exc.reason}; {note}", exc.results, exc.interrupted) from exc
        raise FleetNotReady(f"{exc}; {note}") from exc
    finally:
        if runner is not None:
            runner.close()
        if twin is not None:  # its record of the clock is written as it stops, and goes into the recording
            stop_twin(twin)
            if log is not None:
                timing = read_timing(timing_file)
                log.add_metadata(TWIN_TIMING_META, {str(k): json.dumps(r) for k, r in timing.items()})
        if timing_dir is not None:  # read or not (a deployment stopped by a fault), it goes
            shutil.rmtree(timing_dir, ignore_errors=True)
        if runner is not None and log is not None and runner.late_by_episode:
            late = {str(k): repr(v) for k, v in runner.late_by_episode.items()}
            log.add_metadata(CONTROL_TIMING_META, late)
        if log is not None:
            log.close()
        if transport is not None:
            transport.close()
    if twin is not None:
        results = with_timing(results, timing)
    return results, profile


SESSION_FILES = ("session.mcap", "metadata.yaml", "episodes.csv", "metrics.json")
"""The files of a deployment's output folder; all of them describe the same session."""


@dataclass(frozen=True)
class DeploymentOutcome:
    """A finished (or partly finished) deployment: its episodes, metrics and the files now in place."""

    results: list[EpisodeResult]
    profile: str
    metrics: dict[str, float]
    files: list[Path]
    kept: list[Path] = field(default_factory=list)
    """Earlier sessions kept aside in the output folder (``previous-*``, ``interrupted-*``), oldest first."""


def check_scenario_agrees(world_scenario: str, params_source: str, fleet: Fleet, fleet_source: str) -> None:
    """Refuse a deployment whose params `world.scenario` names another map than the fleet file drives in."""
    ours = load_scenario(world_scenario)
    theirs = load_scenario(fleet.scenario, len(fleet.robots))
    if ours.name != theirs.name:
        raise FleetConfigMismatch(
            f"{params_source}: world.scenario is {world_scenario!r} (scenario {ours.name!r}), but the fleet "
            f"{fleet_source!r} drives in {fleet.scenario!r} (scenario {theirs.name!r}); the fleet file's "
            "`scenario` is the map the robots are in: make the two agree"
        )


def _holds_an_episode(recording: Path) -> bool:
    if not recording.exists() or recording.stat().st_size == 0:
        return False
    try:
        return McapLog(recording).message_counts().get("/mrl/episode", 0) > 0
    except MrlError:
        return False


def deploy_session(
    runtime: Policy,
    fleet: Fleet,
    fleet_source: str,
    request: DeployRequest,
    out_dir: Path,
    confirm_reset: Callable[[int], None] | None = None,
    twin_extra_args: list[str] | None = None,
    live: LiveView | None = None,
) -> DeploymentOutcome:
    """A deployment into `out_dir`: session.mcap (+ rosbag2 metadata.yaml), episodes.csv and metrics.json.

    The session is recorded in a staging folder and moved into place with its results when at least
    one episode ran; a deployment that stops partway publishes the episodes run (the one cut short counted
    as aborted, its robots failed unless they had arrived) and then raises DeployAborted. One that stops
    before its first episode leaves `out_dir` as it was (an episode under way is kept in
    ``interrupted-<time>``, the staging folder of a killed run too).
    """
    scenario = load_scenario(fleet.scenario, len(fleet.robots))
    check_policy_fits_fleet(runtime, fleet, scenario)
    folder = SessionFolder(out_dir, owned=SESSION_FILES).open()
    staged = replace(request, recording=folder.staged("session.mcap"))
    failure: DeployAborted | None = None
    try:
        results, profile = deploy_policy(runtime, fleet, fleet_source, staged, confirm_reset, twin_extra_args, live)
    except DeployAborted as exc:
        if not exc.results:
            _drop(folder)
            raise
        failure, results, profile = exc, exc.results, ""
    except BaseException:
        _drop(folder)
        raise
    metrics = summarize(results, prefix="real")
    metrics["real/requested_episodes"] = float(request.episodes)
    write_metrics(folder.staged("metrics.json"), metrics)
    write_episodes(folder.staged("episodes.csv"), results)
    write_rosbag2_metadata(folder.staged("session.mcap"))
    files = folder.publish()
    if failure is not None:
        previous = f"; the previous session is kept in {folder.kept_previous}" if folder.kept_previous else ""
        raise DeployAborted(
            f"{failure.reason}; the {len(results)} episode(s) run (the last counted as aborted where it was cut short) "
            f"are in {out_dir}{previous}",
            results,
            failure.interrupted,
        ) from failure
    return DeploymentOutcome(results, profile, metrics, files, folder.kept())


def check_clock_kept(outcome: DeploymentOutcome, out_dir: Path) -> None:
    """After a deployment's files are in place: InvalidMeasurement where the deployment did not keep its clock in
    some episodes (the twin fell behind, or the control steps woke late: they measure the host, not the policy),
    naming how many, why and the rate over the others; unless, at ``auto``, the episodes run in their place kept it
    in as many episodes as were asked (said on stderr: the marked ones stay in the session, counted apart)."""
    metrics = outcome.metrics
    behind = int(metrics.get("real/clock_not_kept_episodes", 0.0))
    if behind:
        missed = [r for r in outcome.results if not r.clock_kept]
        why = clock_missed(missed)
        kept = len(outcome.results) - behind
        if kept >= int(metrics.get("real/requested_episodes", len(outcome.results))):
            # at auto, an episode run again in the place of each: the policy is measured in as many as were asked
            print(
                f"deploy: in {behind} of {len(outcome.results)} episode(s) the deployment did not keep its clock "
                f"({why}): marked in {out_dir}, not the policy's; as many more ran at a lower time scale, {kept} "
                f"episodes kept it (robot success over them: {metrics['real/robot_success_clock_kept']:.3f})",
                file=sys.stderr,
                flush=True,
            )
            return
        raise InvalidMeasurement(
            f"in {behind} of {len(outcome.results)} episode(s) the deployment did not keep its clock ({why}): the "
            "host was too busy; those episodes measure the host, not the policy (robot success over the others: "
            f"{metrics['real/robot_success_clock_kept']:.3f}); the session is in {out_dir}: run again with a lower "
            "--time-scale (or auto) or on a quieter host"
        )


def clock_missed(missed: list[EpisodeResult]) -> str:
    """Why episodes did not keep their clock: the twin's time scale realized and the control steps' lateness."""
    parts = []
    twin = [r for r in missed if r.time_scale_realized < r.time_scale_asked * (1 - REALIZED_MARGIN)]
    if twin or any(math.isfinite(r.time_scale_realized) for r in missed):
        low = min((r.time_scale_realized for r in missed), default=math.nan)
        asked = "/".join(f"{a:g}" for a in sorted({r.time_scale_asked for r in missed}, reverse=True))
        parts.append(f"least time scale the twin realized {low:.2f} for {asked} asked")
    late = [r.control_late_p95 for r in missed if r.control_late_p95 > CONTROL_LATE_LIMIT]
    if late:
        parts.append(
            f"control steps of {len(late)} woke up to {max(late):.2f} of a period late (95th percentile; limit "
            f"{CONTROL_LATE_LIMIT:g})"
        )
    return "; ".join(parts) or "the twin ran more than a second behind"


def _drop(folder: SessionFolder) -> None:
    """No episode finished: keep a recording that holds an episode under way, discard one that does not."""
    if _holds_an_episode(folder.staged("session.mcap")):
        folder.keep_as_interrupted()
    else:
        folder.discard()
