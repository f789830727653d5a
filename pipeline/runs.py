"""How a run is built and reported, once for the dvc stages and the ``mrl`` verbs: the deployment request, a
deployment with its live view, and the summary lines of a deployment and of a simulated evaluation.

The stages take their settings from params.yaml, the verbs from their options; both end up in the same config
classes (:mod:`pipeline.params`) and pass them here. Nothing here imports the simulator: a deployment runs without it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.record.live import live_view
from pipeline.record.results import Rate, session_metrics
from pipeline.rollout.deployment import DeployRequest, check_clock_kept, deploy_session

if TYPE_CHECKING:
    from pipeline.params import DeployConfig
    from pipeline.policy.protocol import Policy
    from pipeline.rollout.deployment import DeploymentOutcome
    from pipeline.ros.fleet import Fleet


def operator_reset(episode: int) -> None:
    """Ask the operator to put the robots at their start poses (the deploy runner's reset on real fleets)."""
    input(f"deploy: put every robot at its start pose for episode {episode}, then press Enter ")


def deploy_request(cfg: DeployConfig, out: Path, params_text: str | None = None) -> DeployRequest:
    """The session settings of `cfg`, recorded to `out`/session.mcap with `params_text` (the params file) if given."""
    return DeployRequest(
        episodes=cfg.episodes,
        seed=cfg.seed,
        recording=out / "session.mcap",
        time_scale=cfg.time_scale,
        profile=cfg.profile,
        chunk_size_bytes=cfg.chunk_size_bytes,
        params_text=params_text or "",
    )


def run_deployment(
    runtime: Policy,
    fleet: Fleet,
    cfg: DeployConfig,
    out: Path,
    params_text: str | None = None,
    *,
    live: bool,
    live_port: int,
    live_label: str,
) -> DeploymentOutcome:
    """A deployment of `runtime` on `fleet` into `out` (served live when `live`), its summary printed."""
    request = deploy_request(cfg, out, params_text)
    with live_view(live, live_port, live_label) as view:
        outcome = deploy_session(runtime, fleet, cfg.fleet, request, out, confirm_reset=operator_reset, live=view)
    print(f"deploy: {deploy_summary(outcome, fleet.target, out)}")
    check_clock_kept(outcome, out)
    return outcome


def eval_summary(metrics: Mapping[str, float], episodes: int, out: Path, conditions: str = "") -> str:
    """A line on a finished evaluation: robot success with its 95 % interval, team success, where it went."""
    where = f" ({conditions})" if conditions else ""
    return (
        f"robot success {metrics['eval/robot_success']:.3f} "
        f"[{metrics['eval/robot_success_ci_low']:.3f}, {metrics['eval/robot_success_ci_high']:.3f}], "
        f"team success {metrics['eval/team_success']:.3f} over {episodes} episodes{where} -> {out}"
    )


def deploy_summary(outcome: DeploymentOutcome, target: str, out: Path) -> str:
    """Lines on a finished deployment: success over every episode with 95 % intervals, the completed-only rate beside
    it, aborted episodes by reason, stale seconds per robot, where it went."""
    kept = f"; earlier sessions kept beside it: {', '.join(p.name for p in outcome.kept)}" if outcome.kept else ""
    clock = ""
    m = outcome.metrics
    if "real/clock_not_kept_episodes" in m:
        behind = int(m["real/clock_not_kept_episodes"])
        how = []
        if "real/time_scale_realized_min" in m:
            low, high = m.get("real/time_scale_asked_min", math.nan), m.get("real/time_scale_asked_max", math.nan)
            asked = f"{low:g}x asked" if low == high else f"{low:g}x to {high:g}x asked"
            how.append(f"{asked}, least time scale realized {m['real/time_scale_realized_min']:.2f}")
        if "real/control_late_p95_max" in m:
            how.append(f"control steps at most {m['real/control_late_p95_max']:.2f} of a period late")
        clock = (
            f"; the deployment kept its clock in every episode ({'; '.join(how)})"
            if behind == 0
            else f"; the deployment did not keep its clock in {behind} episode(s) ({'; '.join(how)}): not the "
            "policy's results"
        )
    return f"{session_summary(outcome.metrics, 'real')} on {target} ({outcome.profile}){clock} -> {out}{kept}"


def session_summary(metrics: dict[str, float], world: str) -> str:
    """What happened in a session, from its metrics (``<world>/...``, read by
    :func:`pipeline.record.results.session_metrics`): episodes, aborted (and why), robot and team success over every
    episode with 95 % intervals, the completed-only rate, stale seconds per robot."""
    m = session_metrics(metrics, f"the session's {world} metrics", world)

    def rate(r: Rate) -> str:
        return f"{r.value:.3f} [{r.ci_low:.3f}, {r.ci_high:.3f}]"

    why = ", ".join(f"{n} {kind}" for kind, n in m.aborted_by_kind.items() if n > 0)
    stale = ", ".join(f"robot_{i + 1} {s:.1f} s" for i, s in enumerate(m.stale_s_each))
    return (
        f"{m.episodes} episodes, {m.aborted_episodes} aborted{f' ({why})' if why else ''}: "
        f"robot success {rate(m.robot_success)}, team success {rate(m.team_success)} over every episode; "
        f"completed episodes only {m.robot_success_completed.value:.3f} robot, "
        f"{m.team_success_completed.value:.3f} team; stale {stale or 'none'}"
    )
