"""Replay of recordings: the policy on recorded observations, and recorded commands in the simulator.

``action_agreement``: re-run an exported policy on a recording's ``/mrl/observation`` and compare
with the recorded ``/mrl/action`` (same file, same robots): did the deployed graph act as the
exported one does?

``open_loop_divergence``: take each finished episode's recorded ``cmd_vel`` (as sent) and its first
ground-truth poses, drive the simulated world open loop with those commands at their send
times, and measure how far the simulated robots drift from the recorded ground truth over time.
The episodes are the windows of :mod:`pipeline.record.episodes` closed by their ``end`` event
(``finished``); aborted and unfinished ones are left out.
A simulator whose actuation matches the fleet's stays close for longer: this is how calibration
is checked beyond its own fit.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pipeline.analysis.errors import ReplayError
from pipeline.core.scenario import Scenario
from pipeline.messages import convert as C
from pipeline.params import RandomizeConfig, WorldConfig, world_config
from pipeline.policy.protocol import Policy
from pipeline.record import McapLog
from pipeline.record.episodes import EPISODE_TOPIC, read_episode_windows
from pipeline.record.session import session_info
from pipeline.sim.open_loop import Track, open_loop_errors
from pipeline.sim.world import SimWorld

REPLAY_TICK_S = 0.02


@dataclass(frozen=True)
class Agreement:
    """How often the policy, re-run on the recorded observations, gives the recorded action."""

    steps: int
    agreement: float
    max_abs_diff: float


def check_scenario(log: McapLog, expected: str | None, what: str) -> None:
    """Refuse a recording made in another scenario than `expected` (files without session metadata pass)."""
    recorded = session_info(log.metadata()).scenario
    if expected and recorded and recorded != expected:
        raise ReplayError(f"{log.path}: recorded in scenario {recorded!r}, but {what} is for {expected!r}")


def action_agreement(path: Path, runtime: Policy, tolerance: float = 1e-5) -> Agreement:
    """Re-run `runtime` on every recorded control step of `path`; steps need an observation for every robot."""
    log = McapLog(path)
    check_scenario(log, runtime.spec.scenario.name, f"policy {runtime.name}")
    topics = log.topics()
    for needed in ("/mrl/observation", "/mrl/action"):
        if needed not in topics:
            raise ReplayError(f"{path}: no {needed} topic to replay")
    robots = list(runtime.robots)
    obs: dict[tuple[int, int], dict[str, np.ndarray]] = defaultdict(dict)
    act: dict[tuple[int, int], dict[str, np.ndarray]] = defaultdict(dict)
    for m in log.messages(["/mrl/observation", "/mrl/action"]):
        key = (int(m.msg.episode), int(m.msg.step))
        if m.topic == "/mrl/observation":
            obs[key][m.msg.robot] = np.asarray(m.msg.values, dtype=np.float32)
        else:
            act[key][m.msg.robot] = np.asarray(m.msg.policy_output, dtype=np.float64)
    steps, agree, worst = 0, 0, 0.0
    for key, per_robot in sorted(obs.items()):
        if set(per_robot) != set(robots) or set(act.get(key, {})) != set(robots):
            continue
        x = np.stack([per_robot[r] for r in robots])
        got = np.asarray(runtime.actions(x), dtype=np.float64).reshape(len(robots), -1)
        want = np.stack([act[key][r] for r in robots]).reshape(len(robots), -1)
        diff = float(np.abs(got - want).max())
        worst = max(worst, diff)
        agree += int(diff <= tolerance)
        steps += 1
    if steps == 0:
        raise ReplayError(f"{path}: no control step has an observation and an action for every robot {robots}")
    return Agreement(steps=steps, agreement=agree / steps, max_abs_diff=worst)


@dataclass(frozen=True)
class Divergence:
    """Position error (m) of the open-loop simulation against recorded ground truth, by time since episode start."""

    times_s: np.ndarray  # (k,)
    mean_error_m: np.ndarray  # (k,) mean over episodes and robots
    p90_error_m: np.ndarray  # (k,)
    episodes: int

    def at(self, t_s: float) -> float:
        """Mean error (m) at `t_s` seconds after the start (nan past the recorded horizon)."""
        if len(self.times_s) == 0 or t_s > self.times_s[-1]:
            return float("nan")
        return float(np.interp(t_s, self.times_s, self.mean_error_m))


def finished_episodes(log: McapLog) -> list[tuple[int, int]]:
    """(start, end) log times (ns) of every finished episode of `log`, the ones open-loop replay uses."""
    if EPISODE_TOPIC not in log.topics():
        return []
    return [
        (w.start_ns, w.end_ns) for w in read_episode_windows(log) if w.outcome == "finished" and w.end_ns is not None
    ]


def open_loop_divergence(
    path: Path, scenario: Scenario, world: WorldConfig, horizon_s: float = 10.0, max_episodes: int = 20
) -> Divergence:
    """Drive `world` open loop with each recorded episode's commands; error against recorded ground truth."""
    log = McapLog(path)
    check_scenario(log, scenario.name, "the replay world")
    names = scenario.robot_names
    topics = log.topics()
    for ns in names:
        for kind in ("cmd_vel", "ground_truth"):
            if f"/{ns}/{kind}" not in topics:
                raise ReplayError(f"{path}: no /{ns}/{kind} topic; open-loop replay needs commands and ground truth")
    # the world's own values, not a randomized draw: replay asks how far the point estimates carry
    replay_world = world_config(
        {"control_period_s": REPLAY_TICK_S, "max_steps": 100_000, "lidar": {"noise_sigma_m": 0.0}},
        base=replace(world, randomize=RandomizeConfig()),
    )
    sim = SimWorld(scenario, replay_world)
    n_ticks = int(horizon_s / REPLAY_TICK_S)
    errors = []
    for start_ns, end_ns in finished_episodes(log)[:max_episodes]:
        truth: dict[str, list[tuple[int, np.ndarray]]] = defaultdict(list)
        cmds: dict[str, list[tuple[int, tuple[float, float]]]] = defaultdict(list)
        wanted = [f"/{ns}/{k}" for ns in names for k in ("cmd_vel", "ground_truth")]
        for m in log.messages(wanted, start_ns=start_ns, end_ns=end_ns):
            ns = m.topic.split("/")[1]
            if m.topic.endswith("ground_truth"):
                truth[ns].append((m.log_time_ns, C.planar_pose(m.msg.pose)))
            else:
                cmds[ns].append((m.log_time_ns, C.twist_command(m.msg)))
        if any(not truth[ns] for ns in names):
            continue
        t0 = max(truth[ns][0][0] for ns in names)
        first = np.stack([next(p for t, p in truth[ns] if t >= t0) for ns in names])
        commands = [
            Track(np.array([t for t, _ in cmds[ns]], dtype=np.int64), np.array([c for _, c in cmds[ns]]).reshape(-1, 2))
            for ns in names
        ]
        poses = [
            Track(np.array([t for t, _ in truth[ns]], dtype=np.int64), np.stack([p for _, p in truth[ns]]))
            for ns in names
        ]
        errors.append(open_loop_errors(sim, first, commands, poses, t0, end_ns, n_ticks, REPLAY_TICK_S)[0])
    if not errors:
        raise ReplayError(f"{path}: no finished episode with ground truth for every robot")
    stack = np.stack(errors)  # (episodes, ticks, robots)
    flat = stack.transpose(1, 0, 2).reshape(n_ticks, -1)
    valid = ~np.all(np.isnan(flat), axis=1)
    times = (np.arange(1, n_ticks + 1) * REPLAY_TICK_S)[valid]
    return Divergence(
        times_s=times,
        mean_error_m=np.nanmean(flat[valid], axis=1),
        p90_error_m=np.nanpercentile(flat[valid], 90, axis=1),
        episodes=len(errors),
    )


RESIDUAL_TIMES_S = (1.0, 2.0, 5.0, 10.0)


def _cell(d: Divergence, t: float) -> str:
    return f"{d.at(t):.3f} m ({float(np.interp(t, d.times_s, d.p90_error_m)):.3f} m)"


def residual_lines(nominal: Divergence, calibrated: Divergence) -> list[str]:
    """Markdown lines: the open-loop replay error the nominal and the calibrated simulator leave over time."""
    lines = [
        "| replay horizon | nominal simulator, mean (p90) | calibrated simulator, mean (p90) |",
        "|---|---|---|",
    ]
    for t in RESIDUAL_TIMES_S:
        if t > float(calibrated.times_s[-1]) + 1e-9:
            break

        lines.append(f"| {t:g} s | {_cell(nominal, t)} | {_cell(calibrated, t)} |")
    return lines
