"""Episode outcomes and their summary, shared by sim evaluation and deployment.

Every episode counts. An aborted episode (a robot blind past the fleet's outage limit, a driver or
twin gone, a foreign writer on the domain, an operator's stop, a recording cut inside it) is a trial
like any other: its robots succeed only if they had reached their goal without colliding before the
abort, and its team fails. The rates over the completed episodes alone stand beside the headline
rates under names that say so (``*_completed``).

A robot's path length is measured one way wherever it is reported (an episode's result, its
session's episodes.csv, the analysis of its recording): along its poses at the episode's control
steps (:func:`path_times_ns`, :func:`path_lengths_m`). The control grid is the one resolution a
simulated and a real episode share; summing motion capture at its own rate would count its noise
and every message the network delivered out of order as distance travelled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pipeline.core.stats import wilson_interval

ABORT_KINDS = ("outage", "fault", "clash", "interrupted", "cut_off")
"""Why an episode was aborted: a robot blind past the outage limit; a driver, twin or emitter gone; a writer the
run did not discover on the domain; an operator's stop (Ctrl-C, SIGTERM); a recording that stops inside it."""


@dataclass(frozen=True)
class EpisodeResult:
    """One episode; per-robot arrays are (n_robots,)."""

    episode: int
    seed: int
    steps: int
    reached: np.ndarray
    collided: np.ndarray
    time_to_goal_s: np.ndarray  # nan where the goal was not reached
    path_length_m: np.ndarray  # :func:`path_lengths_m` of the trajectory
    team_success: bool
    trajectory: np.ndarray
    """(n_samples, n_robots, 3) poses at control steps 0, 1, ... (ground truth where there is one): steps + 1 of
    them, or one more when an abort stopped the episode in a step the judge did not finish."""
    aborted: bool = False
    abort_reason: str = ""
    abort_kind: str = ""
    """One of :data:`ABORT_KINDS` when aborted, else empty."""
    stale_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(n_robots,) seconds each robot spent stale (standing still for want of fresh data); empty: none measured."""
    time_scale_asked: float = math.nan
    """The time scale the twin was asked to keep in the episode (NaN: no twin)."""
    time_scale_realized: float = math.nan
    """Twin seconds simulated per host second through the episode (NaN: not measured, no twin)."""
    control_late_p95: float = math.nan
    """How late the runner's control steps woke, the 95th percentile as a share of the control period (NaN: not
    measured)."""
    clock_kept: bool = True
    """False where the hardware twin fell behind its clock, or the runner's control steps woke later than
    :data:`~pipeline.core.timebase.CONTROL_LATE_LIMIT`: the episode does not measure the policy."""

    def __post_init__(self) -> None:
        if self.aborted and self.abort_kind not in ABORT_KINDS:
            raise ValueError(f"abort_kind {self.abort_kind!r} is not one of {ABORT_KINDS}")
        if not self.aborted and self.abort_kind:
            raise ValueError("abort_kind is only set on aborted episodes")

    @property
    def success(self) -> np.ndarray:
        """(n_robots,) reached the goal without colliding (before the abort, for an aborted episode)."""
        return np.asarray(self.reached & ~self.collided)

    @property
    def team(self) -> bool:
        """The team succeeded: every robot in its goal, and the episode was not aborted."""
        return bool(self.team_success and not self.aborted)

    @property
    def stale_per_robot_s(self) -> np.ndarray:
        """(n_robots,) stale seconds, zeros where none were measured."""
        return self.stale_s if self.stale_s.size else np.zeros(len(self.reached))


def path_times_ns(start_ns: int, period_ns: int, steps: int, end_ns: int | None = None) -> np.ndarray:
    """(steps + 1,) int64 times (ns) of an episode's control steps 0..steps, where its path is sampled (each robot's
    newest pose received at or before the time): step k at ``start_ns + k * period_ns`` (the grid the control loop
    keeps, not the moment a late step ran), none after `end_ns` (an episode cut short inside a step samples that
    step at its end)."""
    times = int(start_ns) + int(period_ns) * np.arange(max(int(steps), 0) + 1, dtype=np.int64)
    return times if end_ns is None else np.minimum(times, np.int64(end_ns))


def path_lengths_m(poses: np.ndarray) -> np.ndarray:
    """(n_robots,) metres travelled along `poses` (n_samples, n_robots, >= 2; x, y in metres first): the straight
    steps between a robot's consecutive samples, summed exactly (``math.fsum``, so the result does not depend on
    the array's layout). A sample with a NaN coordinate (no pose known at that step) is skipped."""
    xy = np.asarray(poses, dtype=np.float64)[..., :2]
    out = np.zeros(xy.shape[1])
    for i in range(xy.shape[1]):
        track = xy[:, i]
        track = track[np.isfinite(track).all(axis=1)]
        if len(track) > 1:
            out[i] = math.fsum(np.hypot(np.diff(track[:, 0]), np.diff(track[:, 1])).tolist())
    return out


def _rates(prefix: str, k: int, n: int, out: dict[str, float]) -> None:
    low, high = wilson_interval(k, n) if n else (float("nan"), float("nan"))
    out[prefix] = k / n if n else float("nan")
    out[f"{prefix}_ci_low"] = low
    out[f"{prefix}_ci_high"] = high


def summarize(results: list[EpisodeResult], prefix: str = "eval") -> dict[str, float]:
    """Robot- and team-level success over every episode with 95 % Wilson intervals, and beside them the same rates
    over the completed (not aborted) episodes only (``*_completed``; NaN when none completed); aborted episodes by
    kind, stale seconds per robot, collisions and time to goal. Where a deployment measured how it kept its clock (the
    runner's control steps; a hardware twin's time scale): the episodes where it did not (``clock_not_kept_episodes``,
    which measure the host, not the policy), the latest control steps and the least time scale realized, and the
    rates over the episodes where it did (``*_clock_kept``)."""
    if not results:
        raise ValueError("no episodes to summarise")
    success = np.stack([r.success for r in results])
    collided = np.stack([r.collided for r in results])
    team = np.array([r.team for r in results])
    aborted = np.array([r.aborted for r in results])
    stale = np.stack([r.stale_per_robot_s for r in results])
    times = np.concatenate([r.time_to_goal_s[r.success] for r in results])
    out: dict[str, float] = {
        "episodes": float(len(results)),
        "aborted_episodes": float(aborted.sum()),
        "completed_episodes": float((~aborted).sum()),
    }
    for kind in ABORT_KINDS:
        out[f"aborted_{kind}"] = float(sum(r.abort_kind == kind for r in results))
    _rates("robot_success", int(success.sum()), int(success.size), out)
    _rates("team_success", int(team.sum()), int(team.size), out)
    done = success[~aborted]
    _rates("robot_success_completed", int(done.sum()), int(done.size), out)
    _rates("team_success_completed", int(team[~aborted].sum()), int((~aborted).sum()), out)
    realized = np.array([r.time_scale_realized for r in results])
    late = np.array([r.control_late_p95 for r in results])
    if np.isfinite(realized).any() or np.isfinite(late).any():  # the episodes that kept the clock measure the policy
        kept = np.array([r.clock_kept for r in results])
        out["clock_not_kept_episodes"] = float((~kept).sum())
        out["clock_kept_episodes"] = float(kept.sum())
        if np.isfinite(late).any():
            out["control_late_p95_max"] = float(np.nanmax(late))
    if np.isfinite(realized).any():
        out["time_scale_realized_min"] = float(np.nanmin(realized))
        asked = np.array([r.time_scale_asked for r in results])
        if np.isfinite(asked).any():  # the scales asked (several where --time-scale auto lowered it)
            out["time_scale_asked_min"] = float(np.nanmin(asked))
            out["time_scale_asked_max"] = float(np.nanmax(asked))
    if "clock_kept_episodes" in out:
        _rates("robot_success_clock_kept", int(success[kept].sum()), int(success[kept].size), out)
        _rates("team_success_clock_kept", int(team[kept].sum()), int(kept.sum()), out)
    out["collision_rate"] = float(collided.mean())
    out["mean_time_to_goal_s"] = float(times.mean()) if times.size else float("nan")
    out["stale_s"] = float(stale.sum())
    for i in range(success.shape[1]):
        out[f"robot_{i + 1}_success"] = float(success[:, i].mean())
        out[f"robot_{i + 1}_stale_s"] = float(stale[:, i].sum())
    return {f"{prefix}/{k}": v for k, v in out.items()}
