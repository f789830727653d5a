"""Odometry drift per metre from odometry vs smoothed ground truth, per robot and episode.

The simulator's odometry model (and the twin's) draws, per robot and episode, a distance scale
error s, a yaw-rate scale error k and a heading drift per metre h, each from N(0, drift_per_m):
between two odometry messages the odometry moves (1 + s) times the true distance and turns
(1 + k) times the true turn plus h times the true distance. So per episode:

- s = odometry distance / true distance - 1 (needs `odometry_min_distance_m` of travel);
- k and h by least squares of the heading error (odometry turn - true turn) on the true turn and
  the true distance (k needs `odometry_min_turn_rad` of total turning, h the distance).

Both work on chunks of `CHUNK_S` seconds rather than on single intervals between messages: a
chunk's true displacement and turn are differences of two smoothed poses, so errors of the
smoothed truth (timing jitter, motion-capture noise) enter only at the chunk's ends and do not
pile up along the path or leak into the regressors (which would bias k and h towards -1 and 0).
A jump of the odometry that no motion explains (its driver restarting; see
:func:`pipeline.calibration.recording.pose_jumps`) also separates chunks, as a gap in the truth does.
Chunks whose distance or heading residual about the episode's draws is far beyond the others' (`OUTLIER_CUT`
robust spreads) and a large share of their own motion (`DRIFT_SHARE`) are left out and the draws taken again:
a robot turned or moved by a push (another robot, a wall it grazed) without its wheels, or wheels spinning against
a wall, is not the drift a simulator draws, and one such chunk can read an episode's yaw-scale error as -100 %.
Distances are chord lengths of the chunks for both odometry and truth, so the chord-vs-arc
shortening cancels in the ratio; the distance regressor of h is the odometry's own path length
over the chunk divided by (1 + s).

drift_per_m is the spread of those draws around zero: sigma_hat^2 = mean(draw^2) - mean(se^2)
(the draws' own estimation variance removed), with a 95 % interval from the chi distribution
(n sigma_hat^2 / sigma^2 ~ chi-square with n degrees of freedom).

A robot whose draws centre away from zero (wheels or a separation unlike the ones its odometry integrates with, so
that every episode's scale and yaw-scale errors share a part) is outside that model. drift_per_m then stays the
root mean square about zero (what a simulator of zero-mean draws needs to err as much), and its interval is widened
to also hold the random spread about the components' means (pooled, draws with outlying standard errors left out),
with a note naming the means: the interval admits that the model class is wrong.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.calibration.estimates import MAD_TO_SIGMA, Z_95, Estimate, chi_interval, counted
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.recording import pose_jumps
from pipeline.core.timebase import NS_PER_S

MIN_DRAWS = 3
CHUNK_S = 0.5
"""Length of the chunks that increments are summed over (s)."""


@dataclass(frozen=True)
class OdometryEpisode:
    """One robot's odometry and true poses (n, 3) (x m, y m, yaw rad) at the same times `t_ns` (n,) in one episode.

    `piece` (n,) numbers the stretches of continuous truth (None: one stretch); nothing is compared
    across a gap between two stretches, nor across a jump of the odometry.
    """

    robot: str
    label: str
    t_ns: np.ndarray
    odom: np.ndarray
    truth: np.ndarray
    piece: np.ndarray | None = None


@dataclass(frozen=True)
class EpisodeDrift:
    """Per-episode draws (None where not identifiable), their standard errors, distance (m) and turn (rad) covered."""

    robot: str
    label: str
    distance_m: float
    turn_rad: float
    scale_error: float | None
    yaw_scale_error: float | None
    heading_drift_per_m: float | None
    yaw_scale_se: float
    heading_drift_se: float
    error_curve: tuple[np.ndarray, np.ndarray]
    """(distance travelled m, position error m) along the episode, odometry aligned with truth at its start."""
    disturbed_chunks: int = 0
    """Chunks left out: a push or a spinning wheel, not the odometry's drift."""


@dataclass(frozen=True)
class OdometryFit:
    """drift_per_m and the per-episode draws it comes from."""

    drift_per_m: Estimate
    episodes: tuple[EpisodeDrift, ...]
    component_rms: dict[str, float]
    notes: tuple[str, ...] = ()


def pose_increments(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Forward and left displacement (m) in the previous pose's frame and the turn (rad) between consecutive poses."""
    d = np.diff(pose[:, :2], axis=0)
    c, s = np.cos(pose[:-1, 2]), np.sin(pose[:-1, 2])
    forward = c * d[:, 0] + s * d[:, 1]
    left = -s * d[:, 0] + c * d[:, 1]
    turn = np.angle(np.exp(1j * np.diff(pose[:, 2])))
    return forward, left, turn


def _aligned_error(odom: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance travelled (m) and position error (m) of odometry moved onto the truth's first pose."""
    dyaw = truth[0, 2] - odom[0, 2]
    c, s = math.cos(dyaw), math.sin(dyaw)
    rel = odom[:, :2] - odom[0, :2]
    moved = truth[0, :2] + np.stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]], axis=1)
    error = np.hypot(*(moved - truth[:, :2]).T)
    travelled = np.r_[0.0, np.cumsum(np.hypot(*np.diff(truth[:, :2], axis=0).T))]
    return travelled, error


def chunk_bounds(t_ns: np.ndarray, piece: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last pose indices of consecutive chunks of about CHUNK_S seconds, none crossing pieces."""
    starts: list[int] = []
    ends: list[int] = []
    begin = 0
    for i in range(1, len(t_ns) + 1):
        if i == len(t_ns) or piece[i] != piece[begin]:
            if i - 1 > begin:
                starts.append(begin)
                ends.append(i - 1)
            begin = i
        elif t_ns[i] - t_ns[begin] >= CHUNK_S * NS_PER_S:
            starts.append(begin)
            ends.append(i)
            begin = i
    return np.asarray(starts, dtype=np.int64), np.asarray(ends, dtype=np.int64)


def continuous_stretches(episode: OdometryEpisode) -> np.ndarray:
    """(n,) stretch numbers: the episode's pieces of continuous truth, cut again where the odometry jumps."""
    piece = episode.piece if episode.piece is not None else np.zeros(len(episode.t_ns), dtype=np.int64)
    restarts = np.zeros(len(piece), dtype=np.int64)
    restarts[pose_jumps(episode.t_ns, episode.odom)] = 1
    if not restarts.any():
        return piece
    changed = np.r_[0, (np.diff(piece) != 0).astype(np.int64)] | restarts
    return np.cumsum(changed)


def episode_drift(
    episode: OdometryEpisode, settings: CalibrationSettings, unseen_yaw_per_m: float = 0.0
) -> EpisodeDrift:
    """The draws of one robot-episode (see the module's description), without the chunks a push or a spinning wheel
    made (:func:`_undisturbed`). `unseen_yaw_per_m`: the arc of unequal wheels per metre driven (signed: forward
    driving turns the base one way, reversing the other), which the odometry does not see; it is taken out of each
    chunk's heading error before the draws are fitted."""
    piece = continuous_stretches(episode)
    a, b = chunk_bounds(episode.t_ns, piece)
    same = piece[1:] == piece[:-1]
    fo, lo, to = pose_increments(episode.odom)
    _, _, tt = pose_increments(episode.truth)
    cum_to = np.r_[0.0, np.cumsum(np.where(same, to, 0.0))]
    cum_tt = np.r_[0.0, np.cumsum(np.where(same, tt, 0.0))]
    cum_path = np.r_[0.0, np.cumsum(np.where(same, np.hypot(fo, lo), 0.0))]
    cum_forward = np.r_[0.0, np.cumsum(np.where(same, fo, 0.0))]
    chunks = _DriftChunks(
        chord_o=np.hypot(*(episode.odom[b, :2] - episode.odom[a, :2]).T),
        chord_t=np.hypot(*(episode.truth[b, :2] - episode.truth[a, :2]).T),
        turn_o=cum_to[b] - cum_to[a],
        turn_t=cum_tt[b] - cum_tt[a],
        path_o=cum_path[b] - cum_path[a],
        forward_o=cum_forward[b] - cum_forward[a],
        arc_per_m=unseen_yaw_per_m,
    )
    # the first cut is about odometry without drift: a push that turned the robot most of an episode's turning would
    # otherwise pull the least-squares draws onto itself and hide among their residuals
    kept = _undisturbed(chunks, _NO_DRIFT)
    if not kept.any():
        kept = np.ones(len(a), dtype=bool)
    for _ in range(OUTLIER_ITERATIONS):
        fit = _draws(chunks, kept, settings)
        new = _undisturbed(chunks, fit)
        if np.array_equal(new, kept) or not new.any():
            break
        kept = new
    fit = _draws(chunks, kept, settings)
    curve = _aligned_error(episode.odom, episode.truth)
    return EpisodeDrift(
        episode.robot,
        episode.label,
        fit.distance_m,
        fit.turn_rad,
        fit.scale,
        fit.yaw_scale,
        fit.heading,
        fit.yaw_scale_se,
        fit.heading_se,
        curve,
        int(np.sum(~kept)),
    )


OUTLIER_CUT = 8.0
"""Chunks whose distance or heading residual exceeds this many robust spreads are left out: a push turned or moved
the robot without its wheels, or its wheels spun against a wall; neither is the odometry's drift."""
DRIFT_SHARE = 0.4
"""A chunk whose odometry errs by less than this share of its own motion (distance; turn plus path for the heading)
is always kept: that is drift (five spreads of the harshest bundled profile's draws), whatever the other chunks do.
Without it a robot whose odometry reads 17 % long, driving half of its chunks and creeping through the rest, had
its driving cut as outlying against the creeping chunks' small residuals."""
MIN_SPREAD_M = 1e-4
MIN_SPREAD_RAD = 1e-4
"""Floors of the robust spreads of the chunks' residuals (about one encoder tick)."""
OUTLIER_ITERATIONS = 10


@dataclass(frozen=True)
class _DriftChunks:
    """Per chunk: odometry and true chord (m), odometry and true turn (rad), odometry path length (m), odometry's
    signed forward path (m, reversing negative); the arc per metre of unequal wheels that the odometry misses."""

    chord_o: np.ndarray
    chord_t: np.ndarray
    turn_o: np.ndarray
    turn_t: np.ndarray
    path_o: np.ndarray
    forward_o: np.ndarray
    arc_per_m: float = 0.0

    def heading(self, scale: float | None) -> tuple[np.ndarray, np.ndarray]:
        """(the odometry's heading error with the unseen arc taken out, the true turn the odometry sees) per chunk.

        Unequal wheels turn the base by `arc_per_m` per metre driven, signed (reversing turns it back), and the
        odometry does not count it: its turn is (1 + k) (turn - arc forward) + h path. Taken about a constant, the
        arc lands in each episode's heading drift in proportion to its share of reversing (slope 2 arc: on a
        calibration drive with an arc of 0.094 rad/m the heading draws spread 1.4 times the drawn drift)."""
        arc = self.arc_per_m * self.forward_o / (1.0 + (scale or 0.0))
        return self.turn_o - self.turn_t + arc, self.turn_t - arc


@dataclass(frozen=True)
class _DrawFit:
    distance_m: float
    turn_rad: float
    scale: float | None
    yaw_scale: float | None
    heading: float | None
    yaw_scale_se: float
    heading_se: float
    coef: np.ndarray
    columns: tuple[str, ...]


_NO_DRIFT = _DrawFit(0.0, 0.0, 0.0, None, None, 0.0, 0.0, np.zeros(0), ())
"""Odometry without drift: what the first cut of an episode's chunks is made about."""


def _regressors(chunks: _DriftChunks, scale: float | None, columns: tuple[str, ...]) -> np.ndarray:
    """(n, len(columns)) the true turn and the true path length (the odometry's over 1 + s) of each chunk."""
    path_t = chunks.path_o / (1.0 + (scale or 0.0))
    available = {"turn": chunks.heading(scale)[1], "path": path_t}
    return np.stack([available[c] for c in columns], axis=1) if columns else np.zeros((len(path_t), 0))


def _draws(chunks: _DriftChunks, kept: np.ndarray, settings: CalibrationSettings) -> _DrawFit:
    """s from the kept chunks' chords, k and h by least squares of their heading errors (see the module)."""
    distance = float(chunks.chord_t[kept].sum())
    turn = float(np.abs(chunks.turn_t[kept]).sum())
    use_s = distance >= settings.odometry_min_distance_m
    scale = float(chunks.chord_o[kept].sum() / distance - 1.0) if use_s else None
    use_k = turn >= settings.odometry_min_turn_rad
    columns = (("turn",) if use_k else ()) + (("path",) if use_s else ())
    err = chunks.heading(scale)[0][kept]
    k = h = None
    k_se = h_se = 0.0
    coef = np.zeros(len(columns))
    if columns and len(err) > len(columns):
        x = _regressors(chunks, scale, columns)[kept]
        coef, *_ = np.linalg.lstsq(x, err, rcond=None)
        dof = max(len(err) - x.shape[1], 1)
        resid = err - x @ coef
        cov = np.linalg.pinv(x.T @ x) * float(resid @ resid) / dof
        ses = np.sqrt(np.diag(cov))
        if use_k:
            k, k_se = float(coef[0]), float(ses[0])
        if use_s:
            h, h_se = float(coef[-1]), float(ses[-1])
    else:
        columns = ()
    return _DrawFit(distance, turn, scale, k, h, k_se, h_se, np.asarray(coef), columns)


def _undisturbed(chunks: _DriftChunks, fit: _DrawFit) -> np.ndarray:
    """(n,) the chunks whose distance and heading residuals about the episode's draws lie within `OUTLIER_CUT` robust
    spreads (the moving chunks' median absolute residual times `MAD_TO_SIGMA`) or within `DRIFT_SHARE` of the chunk's
    own motion."""
    distance = chunks.chord_o - (1.0 + (fit.scale or 0.0)) * chunks.chord_t
    heading = chunks.heading(fit.scale)[0] - _regressors(chunks, fit.scale, fit.columns) @ fit.coef
    moving = (chunks.chord_o > 0) | (chunks.turn_o != 0)
    if not moving.any():
        return np.ones(len(distance), dtype=bool)
    spread_d = max(MAD_TO_SIGMA * float(np.median(np.abs(distance[moving]))), MIN_SPREAD_M)
    spread_h = max(MAD_TO_SIGMA * float(np.median(np.abs(heading[moving]))), MIN_SPREAD_RAD)
    own_d = DRIFT_SHARE * np.maximum(chunks.chord_o, chunks.chord_t)
    own_h = DRIFT_SHARE * (np.maximum(np.abs(chunks.turn_o), np.abs(chunks.turn_t)) + chunks.path_o)
    close_d = np.abs(distance) <= np.maximum(OUTLIER_CUT * spread_d, own_d)
    close_h = np.abs(heading) <= np.maximum(OUTLIER_CUT * spread_h, own_h)
    return np.asarray(close_d & close_h)


def estimate_odometry(
    episodes: Sequence[OdometryEpisode], settings: CalibrationSettings, unseen_yaw_per_m: float = 0.0
) -> OdometryFit:
    """drift_per_m (per metre; the spread of the per-episode scale, yaw-scale and heading-drift errors).

    `unseen_yaw_per_m`: the arc per metre of unequal wheels (see :func:`pipeline.calibration.calibrate.arc_per_m`),
    which the simulator's odometry leaves out of its turn by itself (-arc per metre driven, signed); each chunk's
    heading error is taken about it (:meth:`_DriftChunks.heading`), so the spread is what the simulator must still
    draw."""
    drifts = tuple(episode_drift(e, settings, unseen_yaw_per_m) for e in episodes if len(e.odom) >= 3)
    entries: list[tuple[str, float, float]] = []  # (component, draw, its standard error)
    for d in drifts:
        if d.scale_error is not None:
            entries.append(("scale_error", d.scale_error, 0.0))
        if d.yaw_scale_error is not None:
            entries.append(("yaw_scale_error", d.yaw_scale_error, d.yaw_scale_se))
        if d.heading_drift_per_m is not None:
            entries.append(("heading_drift_per_m", d.heading_drift_per_m, d.heading_drift_se))
    far = _far_draws(entries)
    draws = [v for (_, v, _), out in zip(entries, far, strict=True) if not out]
    variances = [se * se for (_, _, se), out in zip(entries, far, strict=True) if not out]
    components: dict[str, list[float]] = {"scale_error": [], "yaw_scale_error": [], "heading_drift_per_m": []}
    component_se: dict[str, list[float]] = {k: [] for k in components}
    for (key, value, se), out in zip(entries, far, strict=True):
        if not out:
            components[key].append(value)
            component_se[key].append(se)
    rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in components.items() if v}
    n = len(draws)
    disturbed = sum(d.disturbed_chunks for d in drifts)
    notes: tuple[str, ...] = (
        f"{counted(len(drifts), 'robot-episode')}, {counted(n, 'draw')}; {counted(disturbed, 'chunk')} left out as "
        "pushes or spinning wheels",
    )
    if far.any():
        left = ", ".join(f"{key} {value:+.3f}" for (key, value, _), out in zip(entries, far, strict=True) if out)
        notes += (
            f"{int(far.sum())} draw(s) beyond {DRAW_CUT:g} robust spreads of all draws left out ({left}): an "
            "episode's odometry error that far out is not a draw of the simulator's zero-mean model (a push or slip "
            "spread over its chunks)",
        )
    if n < MIN_DRAWS:
        reason = (
            f"only {n} per-episode odometry errors (need {MIN_DRAWS}): robots must drive >= "
            f"{settings.odometry_min_distance_m:g} m or turn >= {settings.odometry_min_turn_rad:g} rad in an episode"
        )
        return OdometryFit(Estimate.unidentifiable(reason, "per m", n), drifts, rms, notes)
    x = np.asarray(draws)
    sigma = math.sqrt(max(float(np.mean(x * x) - np.mean(variances)), 0.0))
    low, high = chi_interval(sigma, n)
    se = sigma / math.sqrt(2 * n)
    method = f"chi distribution of {n} zero-mean draws"
    spread_fit = _spread_about_means(components, component_se)
    if spread_fit is not None:
        means, random_sigma, (r_low, r_high), kept = spread_fit
        notes += (
            "the per-episode errors do not centre on zero ("
            + ", ".join(f"{k} mean {v:+.4f}" for k, v in means.items())
            + "): a systematic odometry error the simulator's zero-mean draws do not have; drift_per_m stays "
            f"their root mean square about zero ({sigma:.4g}), the random part alone is {random_sigma:.4g} "
            f"[{r_low:.4g}, {r_high:.4g}] over {kept} draws, and the interval holds both",
        )
        low, high = min(low, r_low), max(high, r_high)
        se = max(se, (high - low) / (2 * Z_95))
        method += "; widened to the spread about the components' means (a systematic error the model lacks)"
    estimate = Estimate.of(sigma, se, (low, high), "per m", method, n)
    return OdometryFit(estimate, drifts, rms, notes)


DRAW_CUT = 5.0
"""A draw farther from zero than this many robust spreads of all draws (median absolute draw x `MAD_TO_SIGMA`, its own
standard error added in quadrature) is left out: a normal draw lies that far once in about two million. On a
calibration drive's recording one robot-episode read a yaw-scale error of -24 % for a drawn drift of 3 %; counted,
it lifted drift_per_m from 0.037 to 0.045."""


def _far_draws(entries: Sequence[tuple[str, float, float]]) -> np.ndarray:
    """(n,) the draws of `entries` (component, draw, standard error) beyond `DRAW_CUT` robust spreads; none where too
    few would be left."""
    x = np.array([v for _, v, _ in entries], dtype=float)
    se = np.array([e for _, _, e in entries], dtype=float)
    if len(x) == 0:
        return np.zeros(0, dtype=bool)
    robust = MAD_TO_SIGMA * float(np.median(np.abs(x)))
    far = np.abs(x) > DRAW_CUT * np.sqrt(robust * robust + se * se)
    return far if int((~far).sum()) >= MIN_DRAWS else np.zeros(len(x), dtype=bool)


SYSTEMATIC_Z = 3.0
"""A component's mean counts as systematic where it lies this many standard errors from zero."""
OUTLIER_SE = 5.0
"""Draws whose own standard error exceeds this many times their component's median carry too little to count in
the random spread (a short or colliding episode's regression)."""


def _spread_about_means(
    components: dict[str, list[float]], component_se: dict[str, list[float]]
) -> tuple[dict[str, float], float, tuple[float, float], int] | None:
    """Where a component's draws centre away from zero (a systematic error: wheels or separation unlike the odometry's
    nominal ones), the components' means, the random spread about them (pooled over the components, the draws' own
    estimation variance removed, draws with outlying standard errors left out), its 95 % chi interval and the draws
    it counts. None where no component's mean is systematic."""
    means: dict[str, float] = {}
    residuals: list[np.ndarray] = []
    variances: list[np.ndarray] = []
    systematic = False
    for name, values in components.items():
        v = np.asarray(values, dtype=float)
        se = np.asarray(component_se[name], dtype=float)
        if len(v) < MIN_DRAWS:
            continue
        typical = float(np.median(se))
        keep = se <= OUTLIER_SE * typical if typical > 0 else np.ones(len(v), dtype=bool)
        v, se = v[keep], se[keep]
        if len(v) < MIN_DRAWS:
            continue
        mean = float(np.mean(v))
        sd = float(np.std(v, ddof=1))
        means[name] = mean
        systematic |= abs(mean) > SYSTEMATIC_Z * sd / math.sqrt(len(v)) and sd > 0
        residuals.append(v - mean)
        variances.append(se**2)
    if not systematic or not residuals:
        return None
    r = np.concatenate(residuals)
    dof = len(r) - len(residuals)
    if dof < MIN_DRAWS:
        return None
    sigma = math.sqrt(max(float(np.sum(r * r)) / dof - float(np.mean(np.concatenate(variances))), 0.0))
    return means, sigma, chi_interval(sigma, dof), len(r)
