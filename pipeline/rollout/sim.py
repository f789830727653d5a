"""Run episodes of a policy in the simulated world and summarise robot- and team-level success."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.core.episode import EpisodeResult, summarize
from pipeline.core.scenario import Scenario
from pipeline.core.timebase import NS_PER_S
from pipeline.mappings import to_mapping
from pipeline.mdp import MdpDefinition
from pipeline.messages import convert as C
from pipeline.messages import topics as T
from pipeline.params import EvalSimConfig, WorldConfig
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.protocol import Policy
from pipeline.record.live import LiveView
from pipeline.record.results import SessionFolder, write_episodes, write_metrics
from pipeline.record.rosbag2 import write_rosbag2_metadata
from pipeline.record.session import SessionLog, clock_metadata, dumps, session_metadata
from pipeline.rollout.errors import EvaluationInterrupted
from pipeline.rollout.outputs import write_paths_picture
from pipeline.rollout.tally import EpisodeTally
from pipeline.sim.env import MultiRobotSim

EPISODE_GAP_NS = NS_PER_S
"""Simulated time between two recorded episodes, so each starts on a fresh second."""

ActionFunction = Callable[[np.ndarray], np.ndarray]
"""Maps observations (n_robots, obs_size) to actions for the action codec: a :class:`Policy`'s ``actions``, a
scripted controller, a model in training."""


def robot_stamp(t_ns: int, world: WorldConfig) -> int:
    """The robots' clock at controller time `t_ns` (``world.network.clock_offset_s`` ahead, running
    ``clock_drift_ppm`` fast): what their sensor messages are stamped with; never before zero."""
    net = world.network
    return max(0, t_ns + round(net.clock_offset_s * NS_PER_S) + round(t_ns * net.clock_drift_ppm * 1e-6))


def _record_state(log: SessionLog, sim: MultiRobotSim, t_ns: int) -> None:
    world = sim.world
    stamp = robot_stamp(t_ns, world.world)  # the episode's draw
    for i, ns in enumerate(sim.scenario.robot_names):
        log.scan(t_ns, ns, sim.raw_scan[i], world.scan_geometry, stamp_ns=stamp)
        log.odom(
            t_ns, ns, world.odometry.pose[i], (float(sim.last_cmd[i, 0]), float(sim.last_cmd[i, 1])), stamp_ns=stamp
        )
        log.ground_truth(t_ns, ns, world.truth[i])
    target = world.target_xy
    if target is not None:  # a pursuit's target, as motion capture on a fleet shows it
        pose = np.array([target[0], target[1], world.evader.heading_rad if world.evader is not None else 0.0])
        log.message(T.TARGET_TRUTH, C.pose_stamped(t_ns, "map", pose, store=log.store), t_ns, t_ns)
    log.tf(t_ns, world.odometry.pose, world.truth)


def run_episode(
    sim: MultiRobotSim,
    policy: ActionFunction,
    seed: int,
    episode: int = 0,
    log: SessionLog | None = None,
    t0_ns: int = 0,
    layout_name: str = "",
) -> EpisodeResult:
    """One episode of `policy` from reset(seed) to the end (all done or the step limit).

    With `log`, every message of the session layout is recorded at simulated times from `t0_ns`.
    """
    obs = sim.reset(seed)
    names = sim.scenario.robot_names
    period_ns = round(sim.world_config.control_period_s * NS_PER_S)
    tally = EpisodeTally(episode, seed, names, sim.world_config.control_period_s)
    tally.start(sim.world.truth)
    step = 0
    stale_steps = np.zeros(len(names))
    was_stale = sim.stale.copy()
    since = np.zeros(len(names), dtype=np.int64)
    if log is not None:
        log.start_episode(t0_ns, episode, seed)
        log.map(t0_ns, sim.episode_layout)
        _record_state(log, sim, t0_ns)
    while True:
        t_ns = t0_ns + step * period_ns
        actions = policy(obs)
        result = sim.step(actions)
        step += 1
        if log is not None:
            out = np.asarray(actions)
            for i, ns in enumerate(names):
                cmd = (float(sim.last_cmd[i, 0]), float(sim.last_cmd[i, 1]))
                log.observation(t_ns, episode, step - 1, ns, layout_name, obs[i])
                log.action(t_ns, episode, step - 1, ns, out[i], cmd)
                log.cmd_vel(t_ns, ns, *cmd)
            _record_state(log, sim, t_ns + period_ns)
        tally.log_events(log, t_ns + period_ns, step, result.judge)
        stale_steps += sim.stale
        if log is not None and (sim.stale != was_stale).any():
            for i in (int(k) for k in np.flatnonzero(sim.stale != was_stale)):
                if sim.stale[i]:
                    since[i] = step
                    log.event(t_ns + period_ns, episode, step, "stale", names[i], "no fresh scan or odometry")
                else:
                    seconds = (step - since[i]) * sim.world_config.control_period_s
                    log.event(t_ns + period_ns, episode, step, "fresh", names[i], f"{seconds:.3f} s stale")
        was_stale = sim.stale.copy()
        obs = result.obs
        tally.stepped(sim.world.truth)  # the pose recorded at this step's time
        tally.judged(result.judge, sim.judge.steps)
        if result.judge.done.all() or result.judge.truncated:
            break
    if log is not None:
        log.event(t0_ns + step * period_ns, episode, step, "end", detail=tally.outcome())
    return tally.result(sim.judge, stale_s=stale_steps * sim.world_config.control_period_s)


def evaluate(
    sim: MultiRobotSim,
    policy: ActionFunction,
    episodes: int,
    seed: int,
    progress: bool = True,
    log: SessionLog | None = None,
    layout_name: str = "",
) -> list[EpisodeResult]:
    """`episodes` episodes with seeds seed, seed+1, ...; shows a progress bar when `progress`.

    On KeyboardInterrupt the episode under way is recorded as aborted and the episodes finished so
    far are returned in the exception's `results` attribute (EvaluationInterrupted).
    """
    results: list[EpisodeResult] = []
    bar = tqdm(range(episodes), desc="eval_sim", unit="ep", disable=not progress, mininterval=1.0)
    t0 = 0
    period_ns = round(sim.world_config.control_period_s * NS_PER_S)
    try:
        for k in bar:
            result = run_episode(sim, policy, seed + k, k, log, t0, layout_name)
            results.append(result)
            t0 += result.steps * period_ns + EPISODE_GAP_NS
            robot = np.mean([r.success.mean() for r in results])
            bar.set_postfix(robot_success=f"{robot:.3f}")
    except KeyboardInterrupt:
        if log is not None:
            log.event(t0 + sim.judge.steps * period_ns, len(results), sim.judge.steps, "abort", detail="interrupted")
        raise EvaluationInterrupted(results) from None
    finally:
        bar.close()
    return results


def check_world_fits(runtime: Policy, scenario: Scenario, world: WorldConfig) -> None:
    """Refuse a world whose robots, layout or MDP (observation, actions, timing, episode end; :class:`MdpDefinition`)
    differ from the one the policy was trained in: the same outputs would mean other commands or other
    outcomes. Reward settings may differ: evaluation reports outcomes, not returns."""
    runtime.check_fits(scenario.robot_names, world.layout(), world.actions.kind)
    differences = runtime.spec.mdp.differences(MdpDefinition.of(world), reward=False)
    if differences:
        raise PolicyMismatch(
            runtime.name,
            [
                f"the world it was trained in (policy.json) and params.yaml's differ: {'; '.join(differences)}",
                "evaluate in the world it was trained in, or retrain in this one",
            ],
        )


def evaluate_policy(
    scenario: Scenario,
    world: WorldConfig,
    runtime: Policy,
    cfg: EvalSimConfig,
    recording: Path,
    params_text: str = "",
    progress: bool = True,
    live: LiveView | None = None,
) -> tuple[list[EpisodeResult], dict[str, float]]:
    """Evaluate an exported policy in the simulated world, recording the session to `recording` (and
    serving it to `live`, a Foxglove live view, as it runs).

    The policy is refused if it does not fit the world (robots, layout, beams, action kind). The
    recording is opened (and its path checked) before any episode runs and closed on every exit.
    """
    check_world_fits(runtime, scenario, world)
    sim = MultiRobotSim(scenario, world)
    log = None
    if cfg.record:
        session = session_metadata(
            "sim",
            scenario.name,
            scenario.robot_names,
            world.control_period_s,
            runtime.document,
            profile="sim",
            extra=clock_metadata(None),
        )
        documents = {
            "params": params_text,
            "scenario": dumps(to_mapping(scenario)),
            "world": dumps(to_mapping(world)),
            "policy": dumps(runtime.document),
        }
        log = SessionLog(recording, scenario.robot_names, session, documents, chunk_size=cfg.chunk_size_bytes)
        if live is not None:
            live.attach(log.recorder)
    try:
        results = evaluate(sim, runtime.actions, cfg.episodes, cfg.seed, progress, log, runtime.layout.name)
    finally:
        if log is not None:
            log.close()
    return results, summarize(results, prefix="eval")


SESSION_FILES = ("session.mcap", "metadata.yaml", "episodes.csv", "metrics.json", "paths.png")
"""The files of an evaluation's output folder; all of them describe the same session."""


def evaluate_session(
    scenario: Scenario,
    world: WorldConfig,
    runtime: Policy,
    cfg: EvalSimConfig,
    out_dir: Path,
    params_text: str = "",
    progress: bool = True,
    live: LiveView | None = None,
) -> tuple[list[EpisodeResult], dict[str, float]]:
    """`evaluate_policy` into `out_dir` (session.mcap with its rosbag2 metadata.yaml, episodes.csv,
    metrics.json, paths.png), staged and moved into place together (see pipeline.record.results)."""
    folder = SessionFolder(out_dir, owned=SESSION_FILES).open()
    recording = folder.staged("session.mcap")
    failure: EvaluationInterrupted | None = None
    try:
        results, metrics = evaluate_policy(scenario, world, runtime, cfg, recording, params_text, progress, live)
    except EvaluationInterrupted as exc:
        if not exc.results:
            if recording.exists():
                folder.keep_as_interrupted()
            else:
                folder.discard()
            raise
        failure, results, metrics = exc, exc.results, summarize(exc.results, prefix="eval")
    except BaseException:
        folder.discard()
        raise
    write_metrics(folder.staged("metrics.json"), metrics)
    write_episodes(folder.staged("episodes.csv"), results)
    random_layouts = scenario.layouts is not None and world.layouts == "random"
    write_paths_picture(folder.staged("paths.png"), scenario, results, random_layouts=random_layouts)
    if cfg.record:
        write_rosbag2_metadata(recording)
    folder.publish()
    if failure is not None:
        raise failure
    return results, metrics
