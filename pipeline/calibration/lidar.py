"""Lidar noise, dropout, bias, mounting, blocked sectors and the room's true geometry from scans taken while
robots stood still.

While a robot stands still its smoothed true pose is exact and the scan's timing does not matter,
so every beam can be compared with the range cast in the known map from that pose. Beams are used
only where the comparison is clean: the cast range lies well inside the sensor's limits, the beam
meets its surface at a moderate angle (not grazing), its angular neighbours hit the same surface
(no corners or box edges), and it passes no other robot.

0. Blocked sectors: beams (by index in the scan) without a valid return in at least
   `BLOCKED_SHARE` of the scans of at least `BLOCKED_MIN_SPANS` spans are blocked by the robot
   itself (a mast); they are reported as sectors of the lidar's frame and used for nothing else.
1. Mounting yaw: a 1-D search over the offset added to every beam angle, minimising a robust
   (truncated absolute) cost of the residuals of the per-span mean scans, first on a coarse grid
   over the search range, then on a fine grid.
2. Geometry: Huber-weighted Gauss-Newton on the mounting (yaw, forward and left offset of the beams'
   origin), the range bias, how far the walls stand outward of the map and where each box really
   is (dx, dy): a wall or box face moved by D lengthens a beam that meets it at t by D . n / (u . n)
   (n its normal, u the beam's direction), so the map's terms are linear. Parameters that too few
   beams see are unidentifiable. Uncertainties: the widest of the formula for independent beams, a
   bootstrap over viewpoints (stationary spans whose poses lie within a few centimetres: they see the
   same surfaces at the same angles, so what the model leaves unexplained there is shared by them;
   single spans where fewer than five viewpoints exist) and a cluster-robust sandwich over the
   viewpoints, each with Student's t on the viewpoints' degrees of freedom (few-cluster inference),
   so what the model leaves unexplained between viewpoints widens them.
3. Dropout probability: the share of usable beams without a valid return (+inf, NaN, or outside
   the scan's range limits).
4. Noise: the spread of each beam's returns about its own mean within a span. This leaves out
   everything static (map, mounting, bias), which the geometry fit handles, so it is the sensor's
   own noise; its growth with range comes from a line fitted to the clipped spreads in range bins
   (``sigma = noise_sigma_m + noise_per_m * range``).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from pipeline.calibration.estimates import MAD_TO_SIGMA, Z_95, Estimate, binomial_estimate, bootstrap, counted, spread
from pipeline.calibration.lidar_noise import (
    NOISE_BOUNDS,
    NoiseBins,
    beam_spread,
    correlation,
    dispersion,
    fit_noise,
    log_add,
    log_widen,
    profile_intervals,
    range_step,
)
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.raycast import MapGeometry, cast_circles, wrap
from pipeline.calibration.smoothing import Track
from pipeline.core.stats import wilson_interval
from pipeline.core.timebase import NS_PER_S

MIN_SPANS_FOR_BOOTSTRAP = 5
MIN_BEAMS = 200
"""Fewer usable beams than this leave noise, bias and dropout unidentifiable."""
CLIP_SIGMAS = 4.0
COARSE_STEP_RAD = math.radians(0.5)
COARSE_BEAMS = 90
"""The coarse search over the whole circle casts about this many beams of each span (every k-th): it only has to
land within the fine search's reach, and casting every beam at 720 offsets was most of the lidar fit's time."""
FINE_STEP_RAD = math.radians(0.02)
FINE_HALF_WIDTH_RAD = math.radians(0.75)
TRUNCATION_M = 0.25
"""Residuals count at most this much in the coarse yaw search's cost."""
MAX_YAW_STD_ERROR_RAD = 0.05
"""A mounting yaw less certain than this is reported unidentifiable."""
STILL_AVERAGE_S = 0.5
"""Smoothed velocities are averaged over this long before the stationarity thresholds apply."""
GAUSS_NEWTON_STEPS = 6
HUBER_K = 2.0
"""Huber weights down-weight span-mean residuals beyond this many robust standard deviations."""
BLOCKED_SHARE = 0.9
BLOCKED_MIN_SPANS = 3
MIN_MAP_BEAMS = 30
"""A wall or box offset seen by fewer clean beams than this is unidentifiable."""
RANGE_BIN_M = 0.5
MIN_BIN_SAMPLES = 50
EDGE_OWN_M = 0.08
"""An edge beam's returns within this of its cast range read its own surface."""
SPAN_OUTLIER_SCALES = 5.0
"""A still return further than this many robust scales from its beam's median in the span is left out of the beam's
mean there (see :func:`_span_inliers`); its deviation stays for the noise's clipped moments to judge."""
MAPPED_EDGE_SHARE = 0.2
"""A depth-edge beam counts toward the mixed pixels only where at least this share of its still returns lie on one of
the two surfaces the map has there (mixed pixels are at most half of an edge beam's returns: the drawn realities go to
0.5)."""
BEAM_ANGLE_ERROR_RAD = 0.002
"""How far a beam may point off its stated angle (a tenth of a degree: the angular accuracy 2-D lidars' datasheets
give); unidentified from still scans, it widens the mounting yaw's interval."""
DEPTH_EDGE_M = 0.1
"""Beams whose cast ranges differ by more than this straddle a depth edge (where mixed pixels are)."""
MOUNT_XY_MAX_SE_M = 0.03
"""A mounting offset less certain than this is reported unidentifiable."""


@dataclass(frozen=True)
class ScanSpan:
    """The scans of one robot during one stationary span.

    `pose` (3,) x, y (m), yaw (rad) of the robot; `beam_angles_rad` (beams,) beam angles in the scan's
    frame as the scan message states them; `ranges` (n_scans, beams) as measured (m); `others`
    (n_scans, k, 2) the other robots' positions (m) at each scan (NaN where unknown).
    """

    robot: str
    label: str
    start_ns: int
    end_ns: int
    pose: np.ndarray
    beam_angles_rad: np.ndarray
    ranges: np.ndarray
    range_min_m: float
    range_max_m: float
    others: np.ndarray

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / NS_PER_S


@dataclass(frozen=True)
class LidarFit:
    """The lidar estimates and what the report plots: residuals (m) of valid returns, the clip limits."""

    noise_sigma_m: Estimate
    dropout_prob: Estimate
    bias_m: Estimate
    mount_yaw_rad: Estimate
    residuals_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Still returns less their cast in the calibrated map (mounting, walls and boxes as fitted)."""
    residual_ranges_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """The cast range of each residual (m): the noise it carries is noise_sigma_m + noise_per_m x this."""
    noise_per_m: Estimate = field(default_factory=lambda: Estimate.unidentifiable("not estimated", "m/m"))
    mount_x_m: Estimate = field(default_factory=lambda: Estimate.unidentifiable("not estimated", "m"))
    mount_y_m: Estimate = field(default_factory=lambda: Estimate.unidentifiable("not estimated", "m"))
    wall_offset_m: Estimate = field(default_factory=lambda: Estimate.unidentifiable("not estimated", "m"))
    box_offsets_m: tuple[tuple[Estimate, Estimate], ...] = ()
    blocked_sectors_rad: tuple[tuple[float, float], ...] = ()
    noise_curve: tuple[np.ndarray, np.ndarray] | None = None
    """(range bin centres m, clipped within-span spread m) the noise line is fitted to."""
    spans: int = 0
    stationary_s: float = 0.0
    beams_used: int = 0
    yaw_cost: tuple[np.ndarray, np.ndarray] | None = None
    notes: tuple[str, ...] = ()
    residual_spectrum: ResidualSpectrum | None = None
    range_step_m: Estimate = field(default_factory=lambda: Estimate.unidentifiable("not estimated", "m"))
    beam_noise_spread: Estimate = field(default_factory=lambda: Estimate.unidentifiable("not estimated", "log-sd"))
    mixed_pixel_prob: Estimate = field(default_factory=lambda: Estimate.unidentifiable("not estimated", "probability"))
    noise_at_range: tuple[float, Estimate] | None = None
    """(the median range seen (m), the noise there): what the data determine where intercept and slope trade off."""
    noise_correlation: float = math.nan
    no_return: str | None = None
    """The driver's convention for a beam without a return, as the recording shows it (inf, zero, max, nan)."""
    noise_driving: NoiseFit | None = None
    """The noise from scans while driving against the map (None where the recording had none)."""


SPECTRUM_OUTLIER_M = 0.05
"""A beam's span-mean residual further than this from its span's median is something not on the map."""


@dataclass(frozen=True)
class ResidualSpectrum:
    """Power of the span-mean scan residual (measured - cast at the fitted parameters) over the beam angle, per
    angular frequency (cycles per revolution), averaged over spans; and what the fitted noise alone gives there
    (each beam's span mean holds noise sigma(range)^2 / scans). Power above the noise at low frequencies is
    structure the calibrated map and sensor model do not explain (a box not where it is cast, a wall that bends,
    a mounting error); at high frequencies, beam-to-beam effects (motion distortion, edges)."""

    cycles: np.ndarray
    power_m2: np.ndarray
    noise_m2: np.ndarray
    spans: int
    left_out: int = 0
    """Beam means further than `SPECTRUM_OUTLIER_M` from their span's median (another robot, a person), left out."""

    def bands(self) -> list[tuple[int, int, float, float]]:
        """(first cycle, last cycle, residual power, noise power) summed over octave bands of angular frequency."""
        out = []
        lo = 1
        top = int(self.cycles[-1]) if len(self.cycles) else 0
        while lo <= top:
            hi = min(2 * lo - 1, top)
            sel = (self.cycles >= lo) & (self.cycles <= hi)
            out.append((lo, hi, float(self.power_m2[sel].sum()), float(self.noise_m2[sel].sum())))
            lo *= 2
        return out


def residual_spectrum(
    span_means: list[tuple[np.ndarray, np.ndarray, np.ndarray]], noise_sigma_m: float, noise_per_m: float
) -> ResidualSpectrum | None:
    """The spectrum of span-mean residuals: per span (mean residual per beam (nan where none), scans per beam,
    cast range per beam), each demeaned over its beams and zero where missing."""
    powers, noises = [], []
    n_beams = None
    left_out = 0
    for mean, count, cast in span_means:
        have = np.isfinite(mean) & (count > 0)
        if have.sum() < 8 or (n_beams is not None and len(mean) != n_beams):
            continue
        centre = float(np.median(mean[have]))
        far = have & (np.abs(np.where(have, mean, centre) - centre) > SPECTRUM_OUTLIER_M)
        left_out += int(far.sum())
        have &= ~far
        n_beams = len(mean)
        x = np.where(have, mean - np.mean(mean[have]), 0.0)
        powers.append(np.abs(np.fft.rfft(x)) ** 2 / n_beams)
        var = np.where(have, (noise_sigma_m + noise_per_m * np.where(have, cast, 0.0)) ** 2 / np.maximum(count, 1), 0)
        noises.append(np.full(n_beams // 2 + 1, var.sum() / n_beams))  # white: the same at every frequency
    if not powers or n_beams is None:
        return None
    cycles = np.arange(n_beams // 2 + 1)
    power = np.mean(powers, axis=0)
    noise = np.mean(noises, axis=0)
    return ResidualSpectrum(cycles[1:], power[1:], noise[1:], len(powers), left_out)


def stationary_spans(
    track: Track, speed_mps: float, yaw_rate_radps: float, min_s: float, average_s: float = STILL_AVERAGE_S
) -> list[tuple[int, int]]:
    """(start_ns, end_ns) of the stretches of `track` whose speed and yaw rate stay below the thresholds for at
    least `min_s` seconds; the smoothed velocities are averaged over `average_s` first (noise of the truth)."""
    vel = track.velocity
    if len(track.t_ns) > 1 and average_s > 0:
        dt = float(np.median(np.diff(track.t_ns))) / NS_PER_S
        k = max(1, round(average_s / dt)) if dt > 0 else 1
        kernel = np.ones(k) / k
        pad = [(k // 2, k - 1 - k // 2)]
        vel = np.stack(
            [np.convolve(np.pad(vel[:, i], pad, mode="edge"), kernel, mode="valid") for i in range(3)], axis=1
        )
    still = (np.hypot(vel[:, 0], vel[:, 1]) < speed_mps) & (np.abs(vel[:, 2]) < yaw_rate_radps)
    out: list[tuple[int, int]] = []
    edges = np.diff(np.r_[0, still.astype(np.int8), 0])
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        start, end = int(track.t_ns[a]), int(track.t_ns[b - 1])
        if (end - start) / NS_PER_S >= min_s:
            out.append((start, end))
    return out


def valid_returns(r: np.ndarray, span: ScanSpan) -> np.ndarray:
    """Which ranges are returns: finite and within [range_min, range_max). A range of exactly the maximum is a
    driver's "no return" (drivers write +inf, NaN, 0 or the maximum for it; the first three fall outside already)."""
    return np.asarray(np.isfinite(r) & (r >= span.range_min_m) & (r < span.range_max_m), dtype=bool)


def _unidentifiable(reason: str, notes: Sequence[str] = (), **kw: object) -> LidarFit:
    return LidarFit(
        Estimate.unidentifiable(reason, "m"),
        Estimate.unidentifiable(reason, "probability"),
        Estimate.unidentifiable(reason, "m"),
        Estimate.unidentifiable(reason, "rad"),
        notes=tuple(notes),
        **kw,  # type: ignore[arg-type]
    )


def _span_means(span: ScanSpan) -> tuple[np.ndarray, np.ndarray]:
    """Per beam: mean of the valid returns over the span's scans (m) and how many there were; returns far off the
    beam's median (:func:`_span_inliers`: a mixed pixel, something passing through the beam) are left out."""
    r = span.ranges
    valid = _span_inliers(r, valid_returns(r, span), 0.0)
    count = valid.sum(axis=0)
    total = np.where(valid, r, 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return mean, count


def _coarse_cost(
    geometry: MapGeometry, spans: Sequence[ScanSpan], means: Sequence[np.ndarray], offsets: np.ndarray
) -> np.ndarray:
    """Robust cost (mean truncated absolute residual about the median) of each yaw offset."""
    cost = np.zeros(len(offsets))
    residuals: list[np.ndarray] = []
    for span, mean in zip(spans, means, strict=True):
        rng, _, _ = _cast_span(geometry, span, offsets)
        inside = (rng > span.range_min_m) & (rng < span.range_max_m)
        residuals.append(np.where(inside & np.isfinite(mean)[None, :], mean[None, :] - rng, np.nan))
    r = np.concatenate(residuals, axis=1)
    med = np.nanmedian(r, axis=1)
    trunc = np.minimum(np.abs(r - med[:, None]), TRUNCATION_M)
    cost = np.nanmean(trunc, axis=1)
    cost[np.sum(np.isfinite(r), axis=1) < 10] = np.inf
    return np.asarray(cost)


def _usable(
    geometry: MapGeometry,
    span: ScanSpan,
    yaw: float,
    settings: CalibrationSettings,
    edge_rad: float,
    mount_xy: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """(beams,) beams whose cast at mount yaw `yaw` (from the mounting at `mount_xy`) is clean: inside the range
    margins, not grazing, not at an edge."""
    offs = np.array([yaw - edge_rad, yaw, yaw + edge_rad])
    rng, surface, cos = _cast_span(geometry, span, offs, mount_xy)
    margin = settings.lidar_range_margin_m
    ok = (rng[1] > span.range_min_m + margin) & (rng[1] < span.range_max_m - margin)
    ok &= cos[1] >= math.cos(settings.lidar_max_incidence_rad)
    ok &= (surface[0] == surface[1]) & (surface[2] == surface[1]) & (surface[1] >= 0)
    return np.asarray(ok)


def _robot_free(span: ScanSpan, yaw: float, reach: np.ndarray, radius_m: float, margin_m: float) -> np.ndarray:
    """(n_scans, beams) beams passing no other robot within `margin_m` of its body (up to `reach` m)."""
    n_scans, beams = span.ranges.shape
    free = np.ones((n_scans, beams), dtype=bool)
    angles = span.pose[2] + span.beam_angles_rad + yaw
    for i in range(n_scans):
        others = span.others[i]
        others = others[np.all(np.isfinite(others), axis=1)]
        if len(others) == 0:
            continue
        _, closest = cast_circles(span.pose[:2], angles, others, radius_m, reach)
        free[i] = closest > radius_m + margin_m
    return free


def blocked_beams(spans: Sequence[ScanSpan]) -> dict[int, np.ndarray]:
    """Per scan layout (beam count): (beams,) mask of the beams that the robot itself blocks.

    A beam is blocked where it has no valid return in at least `BLOCKED_SHARE` of the scans of each of
    at least `BLOCKED_MIN_SPANS` spans (different poses), so a beam that only points out of range from
    some poses is not.
    """
    votes: dict[int, np.ndarray] = {}
    seen: dict[int, int] = {}
    for span in spans:
        n = span.ranges.shape[1]
        r = span.ranges
        valid = valid_returns(r, span)
        dark = (~valid).mean(axis=0) >= BLOCKED_SHARE
        votes[n] = votes.get(n, np.zeros(n, dtype=np.int64)) + dark
        seen[n] = seen.get(n, 0) + 1
    out = {}
    for n, v in votes.items():
        need = max(BLOCKED_MIN_SPANS, math.ceil(BLOCKED_SHARE * seen[n]))
        out[n] = v >= need if seen[n] >= BLOCKED_MIN_SPANS else np.zeros(n, dtype=bool)
    return out


def blocked_sectors(mask: np.ndarray, angles_rad: np.ndarray) -> tuple[tuple[float, float], ...]:
    """Sectors [from, to] (rad, in the scan's frame) covered by the runs of blocked beams of `mask`."""
    n = len(mask)
    if not mask.any():
        return ()
    if mask.all():
        return ((float(angles_rad[0]), float(angles_rad[0] + 2 * math.pi - 1e-6)),)
    inc = float(angles_rad[1] - angles_rad[0]) if n > 1 else 2 * math.pi
    first = int(np.flatnonzero(~mask)[0])
    order = np.roll(np.arange(n), -first)  # start at an open beam so runs do not wrap
    out = []
    k = 0
    while k < n:
        if mask[order[k]]:
            j = k
            while j + 1 < n and mask[order[j + 1]]:
                j += 1
            a = float(angles_rad[order[k]]) - inc / 2
            b = a + (j - k + 1) * inc
            out.append((round(a, 4), round(b, 4)))
            k = j + 1
        else:
            k += 1
    return tuple(out)


def _origin(span: ScanSpan, mount_xy: tuple[float, float]) -> np.ndarray:
    x, y, yaw = span.pose
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([x + c * mount_xy[0] - s * mount_xy[1], y + s * mount_xy[0] + c * mount_xy[1]])


def _cast_span(
    geometry: MapGeometry, span: ScanSpan, yaw_offsets: np.ndarray, mount_xy: tuple[float, float] = (0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Static casts of the span's beams for each mount yaw offset: (range, surface, cos) each (n_offsets, beams)."""
    angles = span.pose[2] + span.beam_angles_rad[None, :] + np.asarray(yaw_offsets)[:, None]
    hits = geometry.cast(_origin(span, mount_xy)[None, None, :], angles)
    return hits.range_m, hits.surface, hits.cos_incidence


@dataclass(frozen=True)
class _Design:
    """The geometry fit's parameters: yaw, mount x, mount y, bias, wall offset, then (dx, dy) per box."""

    n_boxes: int
    wall_of: np.ndarray
    """(segments,) +1 for a room wall, 0 for a box face."""
    box_of: np.ndarray
    """(segments,) the box a face belongs to, -1 for walls."""
    outward: np.ndarray
    """(segments, 2) unit normals pointing away from the room's inside (walls) or out of the box (faces)."""

    @property
    def size(self) -> int:
        return 5 + 2 * self.n_boxes

    @staticmethod
    def of(geometry: MapGeometry) -> _Design:
        n_seg = len(geometry.names)
        wall_of = np.array([1.0 if n.startswith("wall_") else 0.0 for n in geometry.names])
        box_of = np.array([int(n.split("_")[1]) if n.startswith("box_") else -1 for n in geometry.names])
        mid = (geometry.a + geometry.b) / 2
        centre = mid[wall_of > 0].mean(axis=0) if wall_of.any() else np.zeros(2)
        outward = geometry.normal.copy()
        for k in range(n_seg):
            ref = centre if wall_of[k] > 0 else mid[box_of == box_of[k]].mean(axis=0)
            if np.dot(mid[k] - ref, outward[k]) < 0:
                outward[k] = -outward[k]
        n_boxes = int(box_of.max()) + 1 if (box_of >= 0).any() else 0
        return _Design(n_boxes, wall_of, box_of, outward)

    def moved(self, geometry: MapGeometry, p: np.ndarray) -> MapGeometry:
        """`geometry` with the walls moved outward by p[4] and box b's faces by (p[5 + 2b], p[6 + 2b])."""
        shift = self.outward * (self.wall_of * p[4])[:, None]
        for b in range(self.n_boxes):
            shift[self.box_of == b] = p[5 + 2 * b : 7 + 2 * b]
        return dataclasses.replace(geometry, a=geometry.a + shift, b=geometry.b + shift)

    def map_columns(self, surface: np.ndarray, angles: np.ndarray) -> np.ndarray:
        """(beams, 1 + 2 n_boxes) derivative of each beam's range by the wall offset and each box's (dx, dy)."""
        out = np.zeros((len(surface), 1 + 2 * self.n_boxes))
        hit = surface >= 0
        seg = surface[hit]
        u = np.stack([np.cos(angles[hit]), np.sin(angles[hit])], axis=1)
        n = self.outward[seg]
        un = np.einsum("ij,ij->i", u, n)
        un = np.where(np.abs(un) < 1e-6, np.sign(un) * 1e-6 + (un == 0) * 1e-6, un)
        cols = np.zeros((int(hit.sum()), out.shape[1]))
        # a wall moved outward by w: its points move by w n (n outward), the range grows by w (n . n) / (u . n)
        cols[:, 0] = self.wall_of[seg] / un
        box = self.box_of[seg]
        for b in range(self.n_boxes):
            mine = box == b
            cols[mine, 1 + 2 * b] = n[mine, 0] / un[mine]
            cols[mine, 2 + 2 * b] = n[mine, 1] / un[mine]
        out[hit] = cols
        return out


@dataclass(frozen=True)
class _Geometry:
    """The geometry fit: parameters, their standard errors and intervals, how many beams see each."""

    params: np.ndarray
    std_error: np.ndarray
    interval: np.ndarray
    """(size, 2)"""
    seen: np.ndarray
    method: str
    beams: int
    reason: str = ""


def _coarse_yaw(
    geometry: MapGeometry, spans: Sequence[ScanSpan], mean_ranges: Sequence[np.ndarray], settings: CalibrationSettings
) -> tuple[float, tuple[np.ndarray, np.ndarray]]:
    """The mounting yaw of the robust coarse and fine searches, and the cost curve."""
    order = np.argsort([-s.ranges.shape[0] for s in spans])[:12]
    strides = [max(1, len(spans[i].beam_angles_rad) // COARSE_BEAMS) for i in order]
    sub = [
        dataclasses.replace(spans[i], beam_angles_rad=spans[i].beam_angles_rad[::k], ranges=spans[i].ranges[:, ::k])
        for i, k in zip(order, strides, strict=True)
    ]
    sub_means = [mean_ranges[i][::k] for i, k in zip(order, strides, strict=True)]
    half = settings.lidar_mount_search_rad
    if half >= math.pi - 1e-9:
        coarse = np.arange(-math.pi, math.pi, COARSE_STEP_RAD)
    else:
        coarse = np.arange(-half, half + 1e-12, COARSE_STEP_RAD)
    costs = np.concatenate(
        [_coarse_cost(geometry, sub, sub_means, chunk) for chunk in np.array_split(coarse, max(1, len(coarse) // 60))]
    )
    best = float(coarse[int(np.argmin(costs))])
    fine = best + np.arange(-FINE_HALF_WIDTH_RAD, FINE_HALF_WIDTH_RAD + 1e-12, FINE_STEP_RAD)
    fine_costs = _coarse_cost(geometry, spans, mean_ranges, fine)
    yaw = float(fine[int(np.argmin(fine_costs))])
    return yaw, (np.r_[coarse, fine], np.r_[costs, fine_costs])


def _normal_equations(
    geometry: MapGeometry,
    design: _Design,
    spans: Sequence[ScanSpan],
    means: Sequence[tuple[np.ndarray, np.ndarray]],
    sets: Sequence[np.ndarray],
    p: np.ndarray,
    faces: Sequence[np.ndarray] | None = None,
    max_incidence_rad: float = math.pi / 2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per clean beam at parameters `p`: residual of the span-mean range to the model (m), Jacobian rows,
    weight (scans), span index and the beam (its robot's lidar and its index in the scan); plus how many beams see
    each parameter. With `faces` (per span, the surface each beam meets in the mapped room), a beam that meets
    another surface in the moved room, more slanted than `max_incidence_rad`, is left out: a box moved a few
    centimetres shows a beam its corner's other face at a graze, whose range then moves by metres per metre of the
    box, and a wrong step would hold itself."""
    h_yaw, h_xy = 1e-4, 1e-4
    yaw, mx, my = float(p[0]), float(p[1]), float(p[2])
    room = design.moved(geometry, p)
    res, jac, weight, owner, beam = [], [], [], [], []
    units: dict[str, int] = {}
    for k, (span, (mean, count), use) in enumerate(zip(spans, means, sets, strict=True)):
        if not use.any():
            continue
        rng3, surf3, cos3 = _cast_span(room, span, np.array([yaw - h_yaw, yaw, yaw + h_yaw]), (mx, my))
        rx = _cast_span(room, span, np.array([yaw]), (mx + h_xy, my))[0][0]
        ry = _cast_span(room, span, np.array([yaw]), (mx, my + h_xy))[0][0]
        # a beam that the moved room lets through a corner, or onto another face, says nothing here
        use = use & np.isfinite(rng3).all(axis=0) & np.isfinite(rx) & np.isfinite(ry)
        use &= (surf3[0] == surf3[1]) & (surf3[2] == surf3[1])
        if faces is not None:
            use &= (surf3[1] == faces[k]) | (cos3[1] >= math.cos(max_incidence_rad))
        if not use.any():
            continue
        angles = span.pose[2] + span.beam_angles_rad + yaw
        cols = design.map_columns(surf3[1], angles)[use]
        model = rng3[1, use] + p[3]
        rows = np.zeros((int(use.sum()), design.size))
        rows[:, 0] = (rng3[2, use] - rng3[0, use]) / (2 * h_yaw)
        rows[:, 1] = (rx[use] - rng3[1, use]) / h_xy
        rows[:, 2] = (ry[use] - rng3[1, use]) / h_xy
        rows[:, 3] = 1.0
        rows[:, 4:] = cols
        res.append(mean[use] - model)
        jac.append(rows)
        weight.append(count[use].astype(np.float64))
        owner.append(np.full(int(use.sum()), k))
        beam.append(units.setdefault(span.robot, len(units)) * 100_000 + np.flatnonzero(use))
    r, j = np.concatenate(res), np.concatenate(jac)
    seen = (np.abs(j) > 1e-9).sum(axis=0)
    return r, j, np.concatenate(weight), np.concatenate(owner), np.concatenate(beam), seen


def _fit_geometry(
    geometry: MapGeometry,
    spans: Sequence[ScanSpan],
    means: Sequence[tuple[np.ndarray, np.ndarray]],
    blocked: dict[int, np.ndarray],
    yaw0: float,
    settings: CalibrationSettings,
    rng: np.random.Generator,
) -> _Geometry:
    """Huber-weighted Gauss-Newton on mounting, bias and the room's geometry (see the module's description)."""
    design = _Design.of(geometry)
    size = design.size
    p = np.zeros(size)
    p[0] = yaw0
    edge = settings.lidar_edge_rad + 2 * FINE_STEP_RAD + 0.01
    sets, faces = [], []
    for span, (_, count) in zip(spans, means, strict=True):
        use = _usable(geometry, span, yaw0, settings, edge) & (count > 0) & ~blocked[span.ranges.shape[1]]
        rng0, surf0, _ = _cast_span(geometry, span, np.array([yaw0]))
        free = _robot_free(span, yaw0, rng0[0], geometry.robot_radius_m, settings.lidar_robot_margin_m).all(axis=0)
        sets.append(use & free)
        faces.append(surf0[0])
    total = sum(int(s.sum()) for s in sets)
    nan = np.full(size, np.nan)
    if total < 20:
        return _Geometry(p, nan, np.full((size, 2), np.nan), np.zeros(size), "", total, "fewer than 20 clean beams")
    a = np.zeros((len(spans), size, size))
    g = np.zeros((len(spans), size))
    r = w = np.zeros(0)
    who = np.zeros(0, dtype=np.int64)
    beam_of = np.zeros(0, dtype=np.int64)
    seen = np.zeros(size)
    ridge = np.eye(size) * 1e-9
    for _ in range(GAUSS_NEWTON_STEPS):
        r, j, w, who, beam_of, seen = _normal_equations(
            geometry, design, spans, means, sets, p, faces, settings.lidar_max_incidence_rad
        )
        scale = MAD_TO_SIGMA * float(np.median(np.abs(r - np.median(r)) * np.sqrt(w))) + 1e-6
        delta = HUBER_K * scale / np.sqrt(w)
        w = w * np.minimum(1.0, delta / np.maximum(np.abs(r), 1e-12))
        a = np.zeros((len(spans), size, size))
        g = np.zeros((len(spans), size))
        np.add.at(a, who, w[:, None, None] * j[:, :, None] * j[:, None, :])
        np.add.at(g, who, (w * r)[:, None] * j)
        step = np.linalg.solve(a.sum(axis=0) + ridge, g.sum(axis=0))
        p = p + step
        if np.all(np.abs(step[:3]) < 1e-7) and np.all(np.abs(step[3:]) < 1e-6):
            break
    A = a.sum(axis=0) + ridge
    # sandwich covariance: each beam's own residual, so noise that grows with range is not pooled away
    inv = np.linalg.inv(A)
    wr = (w * r)[:, None] * j
    meat = wr.T @ wr
    n_beams = len(r)
    cov = inv @ meat @ inv * (n_beams / max(n_beams - size, 1))
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    interval = np.stack([p - Z_95 * se, p + Z_95 * se], axis=1)
    method = "Gauss-Newton sandwich standard error (independent beams)"
    clusters = _Clusters.of(spans, np.array([bool(s.any()) for s in sets]))
    if clusters.count >= MIN_SPANS_FOR_BOOTSTRAP:
        base = p.copy()
        a_c, g_c = clusters.sum(a), clusters.sum(g)

        def stat(counts: np.ndarray) -> np.ndarray:
            Ab = np.tensordot(counts, a_c, axes=1) + ridge
            gb = np.tensordot(counts, g_c, axes=1)
            try:
                return base + np.linalg.solve(Ab, gb)
            except np.linalg.LinAlgError:
                return np.full(size, np.nan)

        samples = bootstrap(stat, clusters.count, settings.bootstrap, rng)
        for k in range(size):
            boot_se, (lo, hi) = clusters.widen(p[k], samples[:, k])
            if math.isfinite(boot_se):
                # the wider of the bootstrap over clusters and the formula for independent beams
                se[k] = max(se[k], boot_se)
                interval[k] = (min(lo, p[k] - Z_95 * se[k]), max(hi, p[k] + Z_95 * se[k]))
        method = clusters.method
    n_views = clusters.views
    if n_views >= 2:
        # and at least a cluster-robust sandwich over the viewpoints with Student's t (V - 1 d.o.f.)
        _at_least_sandwich(clusters.view_of[who], n_views, wr, inv, p, se, interval)
        method += f"; at least a cluster-robust sandwich over {n_views} viewpoints (t, {n_views - 1} d.o.f.)"
    # and over the beams: what is the beam's own (an angle off its stated one, a range offset of its own) is shared
    # by every span it is used in, whatever the viewpoint
    _, by_beam = np.unique(beam_of, return_inverse=True)
    n_beam = int(by_beam.max()) + 1 if len(by_beam) else 0
    if n_beam >= 2:
        _at_least_sandwich(by_beam, n_beam, wr, inv, p, se, interval)
        method += f"; at least a cluster-robust sandwich over {n_beam} beams"
        _with_angle_prior(by_beam, n_beam, w[:, None] * j * j[:, :1], inv, p, se, interval)
        method += f"; widened for beams off their stated angles (up to {BEAM_ANGLE_ERROR_RAD:g} rad each)"
    return _Geometry(p, se, interval, seen, method, total)


def _with_angle_prior(
    cluster: np.ndarray, n: int, wa: np.ndarray, inv: np.ndarray, p: np.ndarray, se: np.ndarray, interval: np.ndarray
) -> None:
    """Widen `se` and `interval` (in place, all but the yaw's: :func:`_with_beam_angle_errors` widens it) for beams
    off their stated angles, which no still scan identifies: each beam's error (one per beam, shared by every span it
    is used in; `BEAM_ANGLE_ERROR_RAD` as its standard deviation, the prior) moves its ranges by the range's
    derivative by the angle, and through the fit every parameter; its spread is added in quadrature. `wa`: each
    beam row's weight x Jacobian row x the row's derivative by the angle; `cluster` (rows,) its beam. A box seen
    at a slant by a few dozen beams moves by a millimetre under errors the residuals of so few beams do not show."""
    per_beam = np.zeros((n, wa.shape[1]))
    np.add.at(per_beam, cluster, wa)
    sd = BEAM_ANGLE_ERROR_RAD * np.sqrt(np.maximum(np.diag(inv @ (per_beam.T @ per_beam) @ inv), 0.0))
    for k in range(1, len(p)):
        lo, hi = interval[k]
        interval[k] = (p[k] - math.hypot(p[k] - lo, Z_95 * sd[k]), p[k] + math.hypot(hi - p[k], Z_95 * sd[k]))
        se[k] = math.hypot(se[k], sd[k])


def _at_least_sandwich(
    cluster: np.ndarray, n: int, wr: np.ndarray, inv: np.ndarray, p: np.ndarray, se: np.ndarray, interval: np.ndarray
) -> None:
    """Widen `se` and `interval` (in place) to at least a cluster-robust sandwich over `n` clusters (`cluster`: each
    beam row's) with Student's t on n - 1 degrees of freedom; `wr` the weighted score rows, `inv` the bread."""
    rows, size = wr.shape
    scores = np.zeros((n, size))
    np.add.at(scores, cluster, wr)
    meat = scores.T @ scores * (n / (n - 1)) * ((rows - 1) / max(rows - size, 1))
    se_c = np.sqrt(np.maximum(np.diag(inv @ meat @ inv), 0.0))
    t = float(stats.t.ppf(0.975, n - 1))
    for k in range(size):
        if t * se_c[k] > max(p[k] - interval[k, 0], interval[k, 1] - p[k]):
            se[k] = max(se[k], se_c[k])
            interval[k] = (min(interval[k, 0], p[k] - t * se_c[k]), max(interval[k, 1], p[k] + t * se_c[k]))


VIEWPOINT_M = 0.05
VIEWPOINT_RAD = 0.05
"""Stationary spans whose poses lie this close (position, heading) share a viewpoint."""


@dataclass(frozen=True)
class _Clusters:
    """What the bootstraps over stationary spans draw. Spans at one pose see the same surfaces at the same angles,
    so what the model leaves unexplained there is shared by them: the clusters are viewpoints where there are at
    least `MIN_SPANS_FOR_BOOTSTRAP` of them, else single spans, and Student's t counts the viewpoints' degrees of
    freedom either way (few-cluster inference)."""

    view_of: np.ndarray
    """(spans,) each used span's viewpoint, -1 for the others (`_viewpoints`)."""
    cluster_of: np.ndarray
    """(spans,) each used span's cluster (a viewpoint or the span itself), -1 for the others."""
    count: int
    views: int
    what: str

    @staticmethod
    def of(spans: Sequence[ScanSpan], used: np.ndarray) -> _Clusters:
        view_of = _viewpoints(spans, used)
        views = int(view_of.max()) + 1 if used.any() else 0
        if views >= MIN_SPANS_FOR_BOOTSTRAP:
            return _Clusters(view_of, view_of, views, views, "viewpoints")
        cluster_of = np.where(used, np.cumsum(used) - 1, -1)
        return _Clusters(view_of, cluster_of, int(used.sum()), views, "stationary spans")

    @property
    def dof(self) -> int:
        return max(min(self.count, self.views) - 1, 1)

    @property
    def method(self) -> str:
        return f"few-cluster t ({self.dof} d.o.f.) on a bootstrap over {self.count} {self.what}"

    def sum(self, per_span: np.ndarray) -> np.ndarray:
        """(count, ...) `per_span` (spans, ...) summed over each cluster's spans."""
        out = np.zeros((self.count, *per_span.shape[1:]))
        used = self.cluster_of >= 0
        np.add.at(out, self.cluster_of[used], per_span[used])
        return out

    def widen(self, value: float, samples: np.ndarray) -> tuple[float, tuple[float, float]]:
        """Standard error and 95 % interval about `value` from bootstrap `samples` over the clusters: a bootstrap over
        G clusters reads the variance (G - 1) / G short, and a normal quantile is too small for a variance estimated
        from few values; both widen it (NaN where too few samples are finite)."""
        boot_se, (lo, hi) = spread(samples)
        inflate = math.sqrt(self.count / (self.count - 1))
        few = inflate * float(stats.t.ppf(0.975, self.dof)) / Z_95
        shift = value - float(np.nanmedian(samples)) if math.isfinite(boot_se) else 0.0
        return boot_se * inflate, (value - few * (value - lo - shift), value + few * (hi + shift - value))


def _viewpoints(spans: Sequence[ScanSpan], used: np.ndarray) -> np.ndarray:
    """(spans,) the viewpoint of each used span (-1 for the others): a span joins the first viewpoint whose first
    span's pose lies within `VIEWPOINT_M` and `VIEWPOINT_RAD` of its own."""
    firsts: list[np.ndarray] = []
    out = np.full(len(spans), -1, dtype=np.int64)
    for i, span in enumerate(spans):
        if not used[i]:
            continue
        for v, pose in enumerate(firsts):
            near = math.hypot(*(span.pose[:2] - pose[:2])) < VIEWPOINT_M
            if near and abs(float(wrap(span.pose[2] - pose[2]))) < VIEWPOINT_RAD:
                out[i] = v
                break
        else:
            out[i] = len(firsts)
            firsts.append(span.pose)
    return out


def _geometry_estimate(fit: _Geometry, k: int, unit: str, max_se: float | None = None, what: str = "") -> Estimate:
    if fit.reason:
        return Estimate.unidentifiable(fit.reason, unit, fit.beams)
    if fit.seen[k] < MIN_MAP_BEAMS:
        return Estimate.unidentifiable(f"{what} is seen by {int(fit.seen[k])} clean beams (need {MIN_MAP_BEAMS})", unit)
    se = float(fit.std_error[k])
    if max_se is not None and not se < max_se:
        return Estimate.unidentifiable(f"{what} is uncertain by {se:.3g} {unit}", unit, int(fit.seen[k]))
    lo, hi = fit.interval[k]
    return Estimate.of(float(fit.params[k]), se, (float(lo), float(hi)), unit, fit.method, int(fit.seen[k]))


@dataclass(frozen=True)
class NoiseFit:
    """The noise's estimates and what the report says of them."""

    sigma: Estimate
    per_m: Estimate
    curve: tuple[np.ndarray, np.ndarray] | None = None
    at_range: tuple[float, Estimate] | None = None
    """(the median range seen (m), the noise there): the combination of intercept and slope the data determine."""
    correlation: float = math.nan
    """Of intercept and slope (NaN without a slope)."""
    dispersion: float = 1.0
    beam_spread: Estimate = field(default_factory=lambda: Estimate.unidentifiable("not estimated", "log-sd"))
    notes: tuple[str, ...] = ()


def _span_inliers(r: np.ndarray, valid: np.ndarray, step_m: float) -> np.ndarray:
    """(n_scans, beams) the valid returns within `SPAN_OUTLIER_SCALES` robust scales (1.4826 x the median absolute
    deviation, at least the range step and 0.5 mm) of their beam's median over the span: what its mean is taken
    over. A mixed pixel or something passing through the beam, a metre off in one scan of 50, would move the mean
    of every other return of the beam by 2 cm: the beam's noise read too high, and its spread over beams."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a beam without a valid return: no median, no inliers
        seen = np.where(valid, r, np.nan)
        median = np.nanmedian(seen, axis=0)
        mad = np.nanmedian(np.abs(seen - median[None, :]), axis=0)
    scale = np.maximum(1.4826 * np.nan_to_num(mad), max(step_m, 0.0005))
    near = np.abs(np.where(valid, r, 0.0) - np.nan_to_num(median)[None, :]) <= SPAN_OUTLIER_SCALES * scale
    return np.asarray(valid & near, dtype=bool)


def _within_span_noise(
    spans: Sequence[ScanSpan],
    masks: Sequence[np.ndarray],
    rng: np.random.Generator,
    settings: CalibrationSettings,
    bias_m: float = 0.0,
    step_m: float = 0.0,
) -> NoiseFit:
    """noise_sigma_m and noise_per_m from each beam's spread about its own mean within a span, against the distance
    the beam travelled: its mean range less the lidar's range bias `bias_m` (the noise grows with the true distance;
    against the measured range the line's intercept moves by -noise_per_m x bias, about 1 % of the noise on drawn
    lidars); ranges in steps of `step_m` (:mod:`pipeline.calibration.lidar_noise` says how)."""
    dev: list[np.ndarray] = []
    rng_of: list[np.ndarray] = []
    who: list[np.ndarray] = []
    beam_of: list[np.ndarray] = []
    inflated: list[np.ndarray] = []
    robots: dict[str, int] = {}
    for k, (span, mask) in enumerate(zip(spans, masks, strict=True)):
        r = span.ranges
        valid = valid_returns(r, span) & mask
        inlier = _span_inliers(r, valid, step_m)
        n = inlier.sum(axis=0)
        keep = n >= 2
        if not keep.any():
            continue
        mean = np.where(inlier, r, 0.0).sum(axis=0) / np.maximum(n, 1)
        inflation = n / np.maximum(n - 1, 1)
        d = (np.where(valid, r, mean[None, :]) - mean[None, :]) * np.sqrt(inflation)[None, :]
        sel = valid & keep[None, :]
        dev.append(d[sel])
        inflated.append(np.broadcast_to(inflation[None, :], r.shape)[sel])
        rng_of.append(np.broadcast_to(mean[None, :] - bias_m, r.shape)[sel])
        who.append(np.full(int(sel.sum()), k))
        lidar_unit = robots.setdefault(span.robot, len(robots))  # each robot's lidar is a unit of its own
        beam_of.append(np.broadcast_to(lidar_unit * 100_000 + np.arange(r.shape[1])[None, :], r.shape)[sel])
    if not dev:
        reason = "no beam returned twice within a stationary span"
        return NoiseFit(Estimate.unidentifiable(reason, "m"), Estimate.unidentifiable(reason, "m/m"))
    d, R, owner, beam = np.concatenate(dev), np.concatenate(rng_of), np.concatenate(who), np.concatenate(beam_of)
    return _noise_fit(
        d,
        R,
        owner,
        len(spans),
        lambda used: _Clusters.of(spans, used),
        rng,
        settings,
        step_m,
        beam=(beam, np.concatenate(inflated)),
    )


def _noise_fit(
    d: np.ndarray,
    R: np.ndarray,
    owner: np.ndarray,
    n_owners: int,
    clusters_of: Callable[[np.ndarray], _Clusters],
    rng: np.random.Generator,
    settings: CalibrationSettings,
    step_m: float,
    beam: tuple[np.ndarray, np.ndarray] | None = None,
    at_m: float | None = None,
    rel_sd: float = 0.0,
) -> NoiseFit:
    """The noise line from deviations `d` (m, each one return's, of variance noise(R)^2 + step^2 / 12) at true
    ranges `R` (m), owned by `n_owners` spans or scans (`owner`) that `clusters_of` (their used mask) groups for the
    bootstrap; the beams' spread where `beam` names each deviation's beam and its n / (n - 1) (the mean of its span's
    n returns taken out and the deviation scaled back up); the determined noise at `at_m` (default: the median range
    seen).

    In steps: the clipped moments per range bin and owner (:func:`_binned_sums`), the line by maximum likelihood,
    its intervals by a bootstrap over the owners' clusters or the profile likelihood (:func:`_noise_intervals`), the
    beams' spread (:func:`_beam_spread_estimate`), then each estimate in its domain and the notes."""
    bins = np.floor(R / RANGE_BIN_M).astype(np.int64)
    binned = _binned_sums(d, R, bins, owner, n_owners)
    if binned is None:
        reason = f"fewer than {MIN_BIN_SAMPLES} repeated returns in any {RANGE_BIN_M:g} m range bin"
        return NoiseFit(Estimate.unidentifiable(reason, "m"), Estimate.unidentifiable(reason, "m/m"))
    sums, loose = binned
    correction = truncation_correction(CLIP_SIGMAS)
    total = sums.sum(axis=0)
    every = NoiseBins.of(total, correction)
    if not np.any(every.var > 1e-18):  # below a nanometre: rounding of the mean, not noise
        reason = (
            "every beam read the same range in every still scan: the noise is below what the driver reports "
            "(no range step seen either), not measured"
        )
        return NoiseFit(Estimate.unidentifiable(reason, "m"), Estimate.unidentifiable(reason, "m/m"))
    slope = every.spans_range and float(np.ptp(every.range_m)) >= RANGE_BIN_M
    full = fit_noise(every, step_m, slope)
    phi = dispersion(every, full, step_m)
    at_m = every.median_range() if at_m is None else at_m
    curve = (every.range_m, np.sqrt(every.var))
    n_dev = int(total[:, 0].sum())
    clusters = clusters_of(sums[:, :, 0].sum(axis=1) > 0)
    values = [float(full[0]), float(full[1]), float(full[0]) + (float(full[1]) if slope else 0.0) * at_m]
    intervals, ses, widen, corr, method = _noise_intervals(
        every, full, values, step_m, phi, at_m, slope, clusters, sums, correction, settings, rng
    )
    spread_est, rel_sd = _beam_spread_estimate(beam, loose, d, R, full, slope, step_m, rel_sd)
    ests = []
    for k, unit in ((0, "m"), (1, "m/m"), (2, "m")):
        value = values[k]
        if not math.isfinite(value):
            reason = f"the stationary spans' returns cover less than {RANGE_BIN_M:g} m of range"
            ests.append(Estimate.unidentifiable(reason, unit, n_dev))
            continue
        lo, hi = intervals[k]
        if not (math.isfinite(lo) and math.isfinite(hi)):
            ests.append(Estimate.unidentifiable("too few stationary spans to tell its uncertainty", unit, n_dev))
            continue
        lo, hi = log_add(value, log_widen(value, (lo, hi), widen), rel_sd)
        bound = NOISE_BOUNDS["noise_per_m" if k == 1 else "noise_sigma_m"][1] + (k == 2) * at_m * 0.2
        hi = min(hi, bound)
        se = max(float(ses[k]) * widen, (hi - lo) / (2 * Z_95)) if math.isfinite(ses[k]) else (hi - lo) / (2 * Z_95)
        ests.append(Estimate.of(value, se, (lo, hi), unit, method, n_dev))
    at_range = (at_m, ests[2]) if ests[2].ok else None
    notes = _noise_notes(every, ests, step_m, slope, corr, at_m, at_range is not None)
    return NoiseFit(ests[0], ests[1], curve, at_range, corr, phi, spread_est, tuple(notes))


def _binned_sums(
    d: np.ndarray, R: np.ndarray, bins: np.ndarray, owner: np.ndarray, n_owners: int
) -> tuple[np.ndarray, np.ndarray] | None:
    """Per owner and range bin (of at least MIN_BIN_SAMPLES returns): the count, sum and sum of squares of the
    deviations within the bin's clip, and the sum of their ranges (n_owners, bins, 4); and the deviations within
    three clips (gross outliers out, a noisy beam's tails in: for the beams' spread). None without such a bin."""
    rows = []  # (bin, half-width of the clip)
    for b in np.unique(bins):
        sel = bins == b
        if sel.sum() < MIN_BIN_SAMPLES:
            continue
        _, _, half = clipped_moments(d[sel])
        rows.append((b, half))
    if not rows:
        return None
    sums = np.zeros((n_owners, len(rows), 4))
    loose = np.zeros(len(d), dtype=bool)
    for i, (b, half) in enumerate(rows):
        sel = (bins == b) & (np.abs(d) <= half)
        loose |= (bins == b) & (np.abs(d) <= 3 * half)
        np.add.at(sums[:, i, 0], owner[sel], 1.0)
        np.add.at(sums[:, i, 1], owner[sel], d[sel])
        np.add.at(sums[:, i, 2], owner[sel], d[sel] ** 2)
        np.add.at(sums[:, i, 3], owner[sel], R[sel])
    return sums, loose


def _noise_intervals(
    every: NoiseBins,
    full: np.ndarray,
    values: list[float],
    step_m: float,
    phi: float,
    at_m: float,
    slope: bool,
    clusters: _Clusters,
    sums: np.ndarray,
    correction: float,
    settings: CalibrationSettings,
    rng: np.random.Generator,
) -> tuple[list[tuple[float, float]], list[float], float, float, str]:
    """The 95 % intervals and standard errors of (noise_sigma_m, noise_per_m, the noise at `at_m`), the widening
    still to apply, the first two's correlation and the method's words: a bootstrap over the owners' clusters where
    there are enough (each interval kept in its domain, >= 0), else the profile likelihood."""
    widen = math.sqrt(phi)
    if clusters.count >= MIN_SPANS_FOR_BOOTSTRAP:
        cluster_sums = clusters.sum(sums)

        def stat(c: np.ndarray) -> np.ndarray:
            f = fit_noise(NoiseBins.of(np.tensordot(c, cluster_sums, axes=1), correction), step_m, slope)
            return np.array([f[0], f[1], f[0] + (f[1] if slope else 0.0) * at_m])

        samples = bootstrap(stat, clusters.count, settings.bootstrap, rng)
        inflate = math.sqrt(clusters.count / (clusters.count - 1))
        widen *= inflate * float(stats.t.ppf(0.975, clusters.dof)) / Z_95
        intervals = []
        ses = []
        for k in range(3):
            boot_se, (lo, hi) = spread(samples[:, k])
            shift = values[k] - float(np.nanmedian(samples[:, k])) if math.isfinite(boot_se) else 0.0
            intervals.append((max(lo + shift, 0.0), max(hi + shift, values[k])))
            ses.append(boot_se * inflate)
        good = np.all(np.isfinite(samples[:, :2]), axis=1)
        varied = slope and good.sum() > 2 and np.std(samples[good, 0]) > 0 and np.std(samples[good, 1]) > 0
        corr = float(np.corrcoef(samples[good, 0], samples[good, 1])[0, 1]) if varied else math.nan
        method = f"maximum likelihood (both >= 0), {clusters.method}"
    else:
        intervals = list(profile_intervals(every, full, step_m, phi, at_m))
        ses = [(hi - lo) / (2 * Z_95) for lo, hi in intervals]
        widen = 1.0  # the profile's threshold holds the dispersion already
        corr = correlation(every, full, step_m)
        method = (
            f"maximum likelihood (both >= 0), profile-likelihood interval ({clusters.count} stationary span(s): too "
            "few to resample)"
        )
    if phi > 1.05:
        method += f"; widened for the bins' dispersion about the fit ({phi:.2f} x sampling)"
    return intervals, ses, widen, corr, method


def _beam_spread_estimate(
    beam: tuple[np.ndarray, np.ndarray] | None,
    loose: np.ndarray,
    d: np.ndarray,
    R: np.ndarray,
    full: np.ndarray,
    slope: bool,
    step_m: float,
    rel_sd: float,
) -> tuple[Estimate, float]:
    """The beams' spread about the fitted noise line (where `beam` names each deviation's beam), and the relative
    error (1 sigma) the noise's intervals then take: `rel_sd`, or the spread's own where that is larger (the beams
    seen carry a mean square of their factors that the profile's is not)."""
    per_beam = (
        beam_spread(
            [(beam[0][loose], d[loose], R[loose], beam[1][loose])],
            lambda x: float(full[0]) + (float(full[1]) if slope else 0.0) * x,
            step_m,
        )
        if beam is not None
        else (math.nan, math.nan, (math.nan, math.nan), 0)
    )
    spread_est = (
        Estimate.of(
            per_beam[0],
            per_beam[1],
            per_beam[2],
            "log-sd",
            "per-beam noise over the fitted line, over sampling (bootstrap over beams)",
            per_beam[3],
        )
        if math.isfinite(per_beam[0])
        else Estimate.unidentifiable(f"only {per_beam[3]} beams returned 20 times or more while still", "log-sd")
    )
    if math.isfinite(per_beam[0]) and per_beam[3] > 0:
        rel_sd = max(rel_sd, unit_spread(per_beam[2][1], per_beam[3]))
    return spread_est, rel_sd


def _noise_notes(
    every: NoiseBins,
    ests: list[Estimate],
    step_m: float,
    slope: bool,
    corr: float,
    at_m: float,
    determined_at_range: bool,
) -> list[str]:
    """What the noise fit says in words: the range step taken out (or the noise below it), and the trade-off of the
    intercept against the growth with the noise the data determine, or that the ranges span too little for a
    growth."""
    notes: list[str] = []
    step_var = step_m**2 / 12
    if step_m > 0:
        pooled = float(np.sum(every.n * every.var) / np.sum(every.n))
        if pooled < 2 * step_var:
            notes.append(
                f"the noise is below the range step ({step_m * 1e3:.3g} mm): the returns' spread "
                f"({math.sqrt(pooled) * 1e3:.3g} mm) is mostly the rounding's ({math.sqrt(step_var) * 1e3:.3g} mm), "
                "so the noise is bounded, not measured"
            )
        else:
            notes.append(
                f"ranges in steps of {step_m * 1e3:.3g} mm: the rounding's step^2 / 12 taken out of the variance"
            )
    if slope and math.isfinite(corr) and ests[0].ok and ests[1].ok and determined_at_range:
        lo, hi = ests[2].interval or (math.nan, math.nan)
        notes.append(
            f"noise_sigma_m and noise_per_m trade off (correlation {corr:+.2f}); what the data determine is the noise "
            f"at {at_m:.2f} m, the median range seen: {float(ests[2].value or 0.0) * 1e3:.3g} mm "
            f"[{lo * 1e3:.3g}, {hi * 1e3:.3g}]"
        )
    elif not slope:
        notes.append(
            f"the still returns' ranges span less than {RANGE_BIN_M:g} m: the noise is one value, its growth with "
            "range is not determined"
        )
    return notes


MOVING_MIN_COS = 0.95
"""Scans while driving: beams this near square to their surface (cos of the incidence), where an angle error moves
the range least."""
MOVING_DEVIATION_SCALE = math.sqrt(1.5)
"""A beam's residual less the mean of its neighbours' has 1.5 times a residual's variance (equal noise)."""


def _moving_noise(
    room: MapGeometry,
    moving: Sequence[ScanSpan],
    yaw: float,
    mount_xy: tuple[float, float],
    blocked: dict[int, np.ndarray],
    settings: CalibrationSettings,
    rng: np.random.Generator,
    step_m: float,
    at_m: float | None,
    unit_rel_sd: float = 0.0,
) -> tuple[NoiseFit, int]:
    """The noise from scans while driving, against the fitted room: each scan's residual (range less the cast from
    its pose) less the mean of its two neighbours' residuals, where the three beams meet one surface clear of edges
    and robots. An error of the pose, the mounting or the map moves neighbouring beams' residuals alike and leaves
    this out; what the still spans cannot see and this does is the beams' angle errors (a fixed error of a beam's
    angle moves its range on a slanted surface): beams near square to their surface only, the lower bounds widened
    for the rest. `unit_rel_sd`: the relative spread of the noise of the robots' lidars about the profile's (their
    beams' factors, from the still spans). Bootstrap over robot-episodes. Returns the fit and the scans used."""
    dev: list[np.ndarray] = []
    rng_of: list[np.ndarray] = []
    who: list[np.ndarray] = []
    slant: list[np.ndarray] = []  # dr / dtheta = range x tan(incidence) (m/rad)
    labels: dict[str, int] = {}
    owner_label: list[int] = []
    for k, span in enumerate(moving):
        n = span.ranges.shape[1]
        use = _usable(room, span, yaw, settings, settings.lidar_edge_rad, mount_xy)
        use &= ~blocked.get(n, np.zeros(n, dtype=bool))
        cast, surface, cos = _cast_span(room, span, np.array([yaw]), mount_xy)
        free = _robot_free(span, yaw, cast[0], room.robot_radius_m, settings.lidar_robot_margin_m)[0]
        r = span.ranges[0].astype(np.float64)
        ok = use & free & valid_returns(span.ranges, span)[0] & (cos[0] >= MOVING_MIN_COS)
        e = np.where(ok, np.where(ok, r, 0.0) - np.where(ok, cast[0], 0.0), 0.0)  # no arithmetic on inf
        mid = ok[1:-1] & ok[:-2] & ok[2:] & (surface[0, 1:-1] == surface[0, :-2]) & (surface[0, 1:-1] == surface[0, 2:])
        owner_label.append(labels.setdefault(span.label, len(labels)))
        if not mid.any():
            continue
        d = (e[1:-1] - (e[:-2] + e[2:]) / 2)[mid] / MOVING_DEVIATION_SCALE
        dev.append(d)
        rng_of.append(cast[0, 1:-1][mid])
        slant.append((cast[0, 1:-1] * np.sqrt(1.0 / np.maximum(cos[0, 1:-1], 1e-6) ** 2 - 1.0))[mid])
        who.append(np.full(len(d), k))
    if not dev:
        reason = "no three neighbouring beams met one surface clear of edges and robots in the scans while driving"
        return NoiseFit(Estimate.unidentifiable(reason, "m"), Estimate.unidentifiable(reason, "m/m")), 0
    label_of = np.array(owner_label)

    def clusters_of(used: np.ndarray) -> _Clusters:
        # a cluster per robot-episode: its scans share the robot's unit and the episode's map errors
        present = np.unique(label_of[used])
        index = np.full(len(labels), -1)
        index[present] = np.arange(len(present))
        cluster_of = np.where(used, index[label_of], -1)
        return _Clusters(cluster_of, cluster_of, len(present), len(present), "robot-episodes driving")

    owner = np.concatenate(who)
    fit = _noise_fit(
        np.concatenate(dev),
        np.concatenate(rng_of),
        owner,
        len(moving),
        clusters_of,
        rng,
        settings,
        step_m,
        at_m=at_m,
        rel_sd=unit_rel_sd,
    )
    # beams off their stated angles add (dr/dtheta x angle error)^2 here and nowhere in the still spans: the lower
    # bounds admit angle errors up to the bound real lidars state
    angle_sd = BEAM_ANGLE_ERROR_RAD * float(np.sqrt(np.mean(np.concatenate(slant) ** 2)))

    def lowered(est: Estimate) -> Estimate:
        if not est.ok or est.interval is None:
            return est
        lo, hi = est.interval
        return dataclasses.replace(est, interval=(math.sqrt(max(lo**2 - angle_sd**2, 0.0)), hi))

    fit = dataclasses.replace(
        fit,
        sigma=lowered(fit.sigma),
        at_range=(fit.at_range[0], lowered(fit.at_range[1])) if fit.at_range is not None else None,
        notes=(
            *fit.notes,
            f"beams within {math.degrees(math.acos(MOVING_MIN_COS)):.0f} deg of square to their surface; the lower "
            f"bound admits beam angle errors up to {BEAM_ANGLE_ERROR_RAD * 1e3:g} mrad ({angle_sd * 1e3:.2g} mm here)",
        ),
    )
    return fit, len(np.unique(owner))


def unit_spread(s_hi: float, beams: int) -> float:
    """The relative spread of a lidar's noise about its profile's where `beams` beams carry factors exp(s z - s^2)
    with s up to `s_hi`: their mean square's sampling spread, halved for the noise's scale."""
    return math.sqrt(math.expm1(4 * s_hi**2)) / (2 * math.sqrt(beams)) if beams > 0 else 0.0


def _noise_agreement(still: NoiseFit, driving: NoiseFit, scans: int) -> str:
    """The note that says whether the noise from scans while driving agrees with the still spans' (at one range)."""
    if driving.at_range is None or not driving.at_range[1].ok:
        why = driving.at_range[1].reason if driving.at_range is not None else driving.sigma.reason
        return f"noise from {scans} scans while driving against the map: not determined ({why})"
    at_m, moved = driving.at_range
    v, (lo, hi) = float(moved.value or 0.0), moved.interval or (math.nan, math.nan)
    head = (
        f"noise from {scans} scans while driving against the map (a beam against its neighbours): "
        f"{v * 1e3:.3g} mm [{lo * 1e3:.3g}, {hi * 1e3:.3g}] at {at_m:.2f} m"
    )
    if still.at_range is None or not still.at_range[1].ok:
        return head + "; the still spans give none to compare"
    s_est = still.at_range[1]
    s_v, (s_lo, s_hi) = float(s_est.value or 0.0), s_est.interval or (math.nan, math.nan)
    if lo <= s_hi and s_lo <= hi:
        return head + f": agrees with the still spans' {s_v * 1e3:.3g} mm [{s_lo * 1e3:.3g}, {s_hi * 1e3:.3g}]"
    side = "more" if v > s_v else "less"
    return (
        head + f": DISAGREES with the still spans' {s_v * 1e3:.3g} mm [{s_lo * 1e3:.3g}, {s_hi * 1e3:.3g}] "
        f"({v / s_v if s_v > 0 else math.inf:.2f} x); driving reads {side}"
        + (
            " (beams off their stated angles, a scan taken while turning, or a map unlike the room add to it)"
            if side == "more"
            else " (a still span whose returns moved: something moving in view, a robot that was not quite still)"
        )
    )


def clipped_moments(
    residuals: np.ndarray, sigmas: float = CLIP_SIGMAS, iterations: int = 5
) -> tuple[float, float, float]:
    """Mean, standard deviation (corrected for the clipping) and clip half-width of `residuals` clipped at
    `sigmas` standard deviations about the mean.

    Starts from the median and the scaled median absolute deviation.
    """
    r = np.asarray(residuals, dtype=np.float64)
    centre = float(np.median(r))
    scale = MAD_TO_SIGMA * float(np.median(np.abs(r - centre)))
    correction = truncation_correction(sigmas)
    for _ in range(iterations):
        half = sigmas * max(scale, 1e-9)
        kept = r[np.abs(r - centre) <= half]
        if len(kept) < 2:
            break
        centre = float(kept.mean())
        scale = float(kept.std(ddof=1)) * correction
    return centre, scale, sigmas * max(scale, 1e-9)


def truncation_correction(sigmas: float) -> float:
    """Factor turning the std of a normal sample truncated at +-`sigmas` back into the normal's sigma."""
    mass = 2 * stats.norm.cdf(sigmas) - 1
    var = 1 - 2 * sigmas * stats.norm.pdf(sigmas) / mass
    return 1.0 / math.sqrt(var)


def dropout_estimate(drops: np.ndarray, trials: np.ndarray) -> Estimate:
    """The dropout probability from each stationary span's dropouts and usable beams: the pooled share, with a
    design-effect Wilson interval. The ratio's cluster-robust variance over the spans (at least the binomial one)
    gives the design effect where dropouts cluster in some spans; the Wilson interval is taken on the counts divided
    by it, with Student's t on the spans' degrees of freedom. (A percentile bootstrap over the spans covered the
    truth of the coverage benchmark's robots on 16 of 20, each miss a dropout count 1.9-2.5 binomial standard errors
    off.)"""
    used = trials > 0
    k = int(used.sum())
    d, t = drops[used], trials[used]
    events, n = float(d.sum()), float(t.sum())
    p = events / n
    binomial = max(p * (1 - p), 1.0 / n) / n
    robust = k / (k - 1) * float(np.sum((d - p * t) ** 2)) / n**2 if k > 1 else binomial
    effect = max(robust / binomial, 1.0)
    z = float(stats.t.ppf(0.975, k - 1)) if k > 1 else Z_95
    interval = wilson_interval(events / effect, n / effect, z)
    method = (
        f"share of usable beams over {k} stationary spans: design effect {effect:.2f} (cluster-robust over the "
        f"binomial variance, at least 1), Wilson interval on the counts divided by it with Student's t on {k - 1} "
        "degrees of freedom"
    )
    return Estimate.of(p, math.sqrt(binomial * effect), interval, "probability", method, int(n))


def estimate_lidar(
    geometry: MapGeometry,
    spans: Sequence[ScanSpan],
    settings: CalibrationSettings,
    rng: np.random.Generator,
    moving: Sequence[ScanSpan] = (),
) -> LidarFit:
    """Noise (sigma m and growth m/m), dropout probability, bias (m), mounting (yaw rad, x and y m), blocked
    sectors and the room's true walls and boxes from stationary `spans`; the noise again from scans while driving
    (`moving`, one scan each, at its pose), compared with the still spans' or, without still spans, alone."""
    spans = [s for s in spans if s.ranges.shape[0] > 0]
    moving_rng = np.random.default_rng([settings.seed, 59])  # the still estimates' draws stay as they were
    if not spans:
        return _without_still_spans(geometry, moving, settings, moving_rng)
    stationary_s = float(sum(s.duration_s for s in spans))
    blocked = blocked_beams(spans)
    sectors: tuple[tuple[float, float], ...] = ()
    for span in spans:
        mask = blocked[span.ranges.shape[1]]
        if mask.any():
            sectors = blocked_sectors(mask, span.beam_angles_rad)
            break
    means = [_span_means(s) for s in spans]
    yaw0, curve = _coarse_yaw(geometry, spans, [m for m, _ in means], settings)
    geo = _fit_geometry(geometry, spans, means, blocked, yaw0, settings, rng)
    yaw_est = _geometry_estimate(geo, 0, "rad", MAX_YAW_STD_ERROR_RAD, "the mounting yaw")
    yaw = float(geo.params[0]) if yaw_est.ok else yaw0
    if yaw_est.ok:
        wrapped = float(wrap(yaw))
        lo, hi = yaw_est.interval or (math.nan, math.nan)
        yaw_est = dataclasses.replace(yaw_est, value=wrapped, interval=(lo + wrapped - yaw, hi + wrapped - yaw))
    mount_x = _geometry_estimate(geo, 1, "m", MOUNT_XY_MAX_SE_M, "the mounting's forward offset")
    mount_y = _geometry_estimate(geo, 2, "m", MOUNT_XY_MAX_SE_M, "the mounting's left offset")
    mount_xy = (float(geo.params[1]), float(geo.params[2])) if mount_x.ok and mount_y.ok else (0.0, 0.0)
    bias_geo = _geometry_estimate(geo, 3, "m", None, "the range bias")
    walls = _geometry_estimate(geo, 4, "m", None, "the walls' offset")
    n_boxes = (geo.params.size - 5) // 2
    boxes = tuple(
        (
            _geometry_estimate(geo, 5 + 2 * b, "m", None, f"box {b}'s x"),
            _geometry_estimate(geo, 6 + 2 * b, "m", None, f"box {b}'s y"),
        )
        for b in range(n_boxes)
    )
    # per-scan residuals and dropouts at the fitted mounting over the clean, unblocked beams
    per_span_res: list[np.ndarray] = []
    per_span_rng: list[np.ndarray] = []
    span_means: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    room = _Design.of(geometry).moved(geometry, np.where(np.isfinite(geo.params), geo.params, 0.0))
    masks: list[np.ndarray] = []
    drops = np.zeros(len(spans))
    trials = np.zeros(len(spans))
    edges: list[tuple[np.ndarray, ...]] = []  # (returns, own surface, near, far, beam) at depth edges
    unmapped_edges = 0
    changes: list[np.ndarray] = []
    missing = {"inf": 0, "nan": 0, "zero": 0, "max": 0}
    for k, span in enumerate(spans):
        # clean beams of the room as fitted, cast from the fitted mounting: a box corner a few centimetres off its
        # mapped place, beside a robot that stands against it, reads closer than the range minimum to beams that the
        # map sends past it, and those counted as dropouts (0.0120 for 0.0116 on a calibration drive)
        use = _usable(room, span, yaw, settings, settings.lidar_edge_rad, mount_xy) & ~blocked[span.ranges.shape[1]]
        cast, _, _ = _cast_span(geometry, span, np.array([yaw]), mount_xy)
        fitted, fitted_surface, _ = _cast_span(room, span, np.array([yaw]), mount_xy)  # in the room the fit moved
        # another robot hides a beam up to the further of the map's surface and the fitted room's: past a box corner
        # that the map places a few centimetres over, the beam sees the robot beyond it
        reach = np.fmax(cast[0], fitted[0])
        free = _robot_free(span, yaw, reach, geometry.robot_radius_m, settings.lidar_robot_margin_m)
        mask = free & use[None, :]
        masks.append(mask)
        r = span.ranges
        valid = valid_returns(r, span)
        trials[k] = mask.sum()
        drops[k] = (mask & ~valid).sum()
        kept = mask & valid
        count = kept.sum(axis=0)
        cast_kept = np.where(kept, fitted[0][None, :], 0.0)  # no arithmetic on the casts of beams not kept (inf)
        per_span_res.append((np.where(kept, r, 0.0) - cast_kept)[kept])  # against the calibrated map: noise left
        per_span_rng.append(np.broadcast_to(fitted[0][None, :], r.shape)[kept])
        with np.errstate(invalid="ignore", divide="ignore"):
            span_mean = np.where(count > 0, np.where(kept, r - fitted[0][None, :], 0.0).sum(axis=0) / count, np.nan)
        span_means.append((span_mean, count, fitted[0]))
        both = valid[1:] & valid[:-1]
        changes.append(np.diff(np.where(valid, r, 0.0), axis=0)[both])
        unblocked = ~blocked[span.ranges.shape[1]]
        _count_missing(r[:, unblocked], span.range_max_m, missing)
        found, unmapped = _depth_edges(fitted[0], fitted_surface[0], free, valid, r, unblocked, k)
        unmapped_edges += unmapped
        if found is not None:
            edges.append(found)
    n_trials = int(trials.sum())
    yaw_est = _with_beam_angle_errors(yaw_est, masks)
    notes = [
        f"{counted(len(spans), 'stationary span')}, {stationary_s:.1f} s, "
        f"{counted(sum(s.ranges.shape[0] for s in spans), 'scan')}"
    ]
    if sectors:
        shown = ", ".join(f"[{a:.2f}, {b:.2f}]" for a, b in sectors)
        notes.append(f"beams blocked by the robot itself in {shown} rad (left out)")
    if n_trials < MIN_BEAMS:
        reason = f"only {n_trials} usable beams in {len(spans)} stationary spans (need {MIN_BEAMS})"
        fit = _unidentifiable(reason, notes, spans=len(spans), stationary_s=stationary_s, beams_used=n_trials)
        return dataclasses.replace(fit, mount_yaw_rad=yaw_est, yaw_cost=curve, blocked_sectors_rad=sectors)
    residuals = np.concatenate(per_span_res)
    bias_value = float(bias_geo.value) if bias_geo.ok and bias_geo.value is not None else 0.0
    step = range_step(np.concatenate(changes) if changes else np.zeros(0))
    step_m = float(step.value) if step.ok and step.value else 0.0
    noise = _within_span_noise(spans, masks, rng, settings, bias_value, step_m)
    notes += list(noise.notes)
    driving: NoiseFit | None = None
    if moving:
        at_m = noise.at_range[0] if noise.at_range is not None else None
        spread = noise.beam_spread
        unit_sd = (
            unit_spread(spread.interval[1], spread.n) if spread.ok and spread.interval is not None and spread.n else 0.0
        )
        driving, used = _moving_noise(room, moving, yaw, mount_xy, blocked, settings, moving_rng, step_m, at_m, unit_sd)
        notes.append(_noise_agreement(noise, driving, used))
        notes += [n for n in driving.notes if n.startswith("beams within")]
        if not noise.sigma.ok and driving.sigma.ok:
            notes.append(
                "the still spans tell no noise: noise_sigma_m and noise_per_m come from the scans while driving"
            )
            noise = dataclasses.replace(driving, beam_spread=noise.beam_spread, notes=noise.notes)
    sigma_est, per_m_est, noise_curve = noise.sigma, noise.per_m, noise.curve
    no_return, convention_note = _no_return_convention(missing)
    notes.append(convention_note)
    spacing = float(np.median(np.abs(np.diff(spans[0].beam_angles_rad)))) if spans[0].beam_angles_rad.size > 1 else 0.0
    mixed = _mixed_pixels(edges, noise, spacing)
    if unmapped_edges:
        notes.append(
            f"{counted(unmapped_edges, 'edge beam')} of still spans returned mostly from neither of the map's surfaces "
            "there (something the map lacks): left out of the mixed pixels"
        )
    spans_used = int(np.sum(trials > 0))
    if spans_used >= MIN_SPANS_FOR_BOOTSTRAP:
        drop_est = dropout_estimate(drops, trials)
    else:
        drop_est = binomial_estimate(int(drops.sum()), n_trials)
    spectrum = (
        residual_spectrum(span_means, float(sigma_est.value or 0.0), float(per_m_est.value or 0.0))
        if sigma_est.ok
        else None
    )
    return LidarFit(
        residual_spectrum=spectrum,
        noise_sigma_m=sigma_est,
        dropout_prob=drop_est,
        bias_m=bias_geo,
        mount_yaw_rad=yaw_est,
        residuals_m=residuals,
        residual_ranges_m=np.concatenate(per_span_rng),
        spans=len(spans),
        stationary_s=stationary_s,
        beams_used=n_trials,
        yaw_cost=curve,
        notes=tuple(notes),
        noise_per_m=per_m_est,
        mount_x_m=mount_x,
        mount_y_m=mount_y,
        wall_offset_m=walls,
        box_offsets_m=boxes,
        blocked_sectors_rad=sectors,
        noise_curve=noise_curve,
        range_step_m=step,
        beam_noise_spread=noise.beam_spread,
        mixed_pixel_prob=mixed,
        noise_at_range=noise.at_range,
        noise_correlation=noise.correlation,
        no_return=no_return,
        noise_driving=driving,
    )


def _without_still_spans(
    geometry: MapGeometry, moving: Sequence[ScanSpan], settings: CalibrationSettings, rng: np.random.Generator
) -> LidarFit:
    """:func:`estimate_lidar` with no still span: the geometry unidentified, the noise from the scans while driving
    (`moving`) against the map alone where there are any."""
    reason = (
        f"robots never stood still for >= {settings.stationary_min_s:g} s while scanning: the bias, mounting and map "
        "are read from still spans only"
    )
    fit = _unidentifiable(reason)
    if not moving:
        return fit
    alone, used = _moving_noise(geometry, moving, 0.0, (0.0, 0.0), blocked_beams(moving), settings, rng, 0.0, None)
    note = (
        f"no still span: the noise comes from {used} scans while driving against the map only (a beam against "
        "its neighbours; at the nominal mounting; the range step is read from still scans, so not taken out)"
    )
    return dataclasses.replace(
        fit,
        noise_sigma_m=alone.sigma,
        noise_per_m=alone.per_m,
        noise_at_range=alone.at_range,
        noise_correlation=alone.correlation,
        noise_curve=alone.curve,
        noise_driving=alone,
        notes=(*fit.notes, note, *alone.notes),
    )


def _count_missing(seen: np.ndarray, range_max_m: float, missing: dict[str, int]) -> None:
    """Add the returns of `seen` (a span's unblocked beams) that each driver convention reads as no return."""
    missing["inf"] += int(np.isposinf(seen).sum())
    missing["nan"] += int(np.isnan(seen).sum())
    missing["zero"] += int((seen == 0.0).sum())
    missing["max"] += int((seen == np.float32(range_max_m)).sum())


def _depth_edges(
    here: np.ndarray,
    surface: np.ndarray,
    free: np.ndarray,
    valid: np.ndarray,
    r: np.ndarray,
    unblocked: np.ndarray,
    k: int,
) -> tuple[tuple[np.ndarray, ...] | None, int]:
    """The returns of span `k` at the fitted room's depth edges, for the mixed pixels: (returns, the beam's own
    surface, the near and the far surface, the beam's number in its span), or None where the span has none; and how
    many edge beams returned mostly from neither surface (something the map lacks, left out).

    `here`, `surface`: each beam's cast range and surface in the fitted room; `free`, `valid`: (scans, beams) beams
    clear of other robots and valid returns; `r`: the span's ranges; `unblocked`: beams the robot itself does not
    block. An edge beam meets another surface than the previous beam, nearer or farther by more than DEPTH_EDGE_M,
    both clear of robots and of the mast."""
    before = np.roll(here, 1)
    both_cast = np.isfinite(here) & np.isfinite(before)
    gap = np.abs(np.where(both_cast, here, 0.0) - np.where(both_cast, before, 0.0))
    other = surface != np.roll(surface, 1)  # a smooth surface seen at a slant is no edge
    jump = both_cast & other & (gap > DEPTH_EDGE_M) & unblocked
    jump &= np.roll(unblocked, 1)
    clear = free & np.roll(free, 1, axis=1) & jump[None, :] & valid
    cols = np.flatnonzero(clear.sum(axis=0) >= 3)
    if not len(cols):
        return None, 0
    seen_at = np.where(clear[:, cols], r[:, cols], np.nan)
    # the beam's own surface: of the two cast surfaces the one nearer its median return (a beam a little off its
    # stated angle sees the other one throughout), refined by its returns near it (a box a few centimetres off its
    # mapped place, unidentified, moves it)
    lo_m, hi_m = np.minimum(here, before)[cols], np.maximum(here, before)[cols]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a beam with no return near: its cast stays
        median = np.nanmedian(seen_at, axis=0)
        side = np.where(np.abs(median - lo_m) <= np.abs(median - hi_m), lo_m, hi_m)
        near_own = np.abs(seen_at - side[None, :]) < EDGE_OWN_M
        refined = np.nanmedian(np.where(near_own, seen_at, np.nan), axis=0)
    centre = np.where(np.isfinite(refined), refined, side)
    # a beam that mostly returns from neither surface sees something the fitted map lacks (a robot standing where
    # the others' poses do not place it, an object): its steady returns are no mixed pixels
    on_map = (np.abs(seen_at - lo_m[None, :]) < EDGE_OWN_M) | (np.abs(seen_at - hi_m[None, :]) < EDGE_OWN_M)
    mapped = on_map.sum(axis=0) >= MAPPED_EDGE_SHARE * np.isfinite(seen_at).sum(axis=0)
    keep = np.isfinite(seen_at) & mapped[None, :]
    found = (
        seen_at[keep],
        np.broadcast_to(centre[None, :], seen_at.shape)[keep],
        np.broadcast_to(lo_m[None, :], seen_at.shape)[keep],
        np.broadcast_to(hi_m[None, :], seen_at.shape)[keep],
        np.broadcast_to((k * 100_000 + cols)[None, :], seen_at.shape)[keep],  # the beam in its span
    )
    return found, int((~mapped).sum())


def _with_beam_angle_errors(yaw: Estimate, masks: Sequence[np.ndarray]) -> Estimate:
    """The mounting yaw's interval widened for beams off their stated angles, which no still scan identifies: the
    fit reads the mean of the used beams' angle errors as yaw, so up to `BEAM_ANGLE_ERROR_RAD` per beam moves it by
    about that over the square root of the beams used (added in quadrature, 95 %)."""
    if not yaw.ok or yaw.value is None or yaw.interval is None or not masks:
        return yaw
    used = np.zeros(masks[0].shape[1], dtype=bool)
    for mask in masks:
        if mask.shape[1] == len(used):
            used |= mask.any(axis=0)
    count = max(int(used.sum()), 1)
    extra = Z_95 * BEAM_ANGLE_ERROR_RAD / math.sqrt(count)
    lo, hi = yaw.interval
    down = math.hypot(yaw.value - lo, extra)
    up = math.hypot(hi - yaw.value, extra)
    se = math.hypot(yaw.std_error or 0.0, extra / Z_95)
    method = (
        f"{yaw.method}; widened for beams off their stated angles (up to {BEAM_ANGLE_ERROR_RAD:g} rad, {count} beams)"
    )
    return dataclasses.replace(yaw, interval=(yaw.value - down, yaw.value + up), std_error=se, method=method)


def _no_return_convention(missing: dict[str, int]) -> tuple[str | None, str]:
    """The driver's convention for a beam without a return (the most common of +inf, NaN, 0 and the range maximum
    among the still scans' unblocked beams) and a note with the counts."""
    total = sum(missing.values())
    counts = ", ".join(f"{k} {v}" for k, v in missing.items())
    if total == 0:
        return None, "no beam without a return while still: the driver's no-return convention not seen"
    kind = max(missing, key=lambda k: missing[k])
    return kind, f"beams without a return read {kind} ({counts}; all read as no return)"


def _mixed_pixels(edges: Sequence[tuple[np.ndarray, ...]], noise: NoiseFit, spacing_rad: float = 0.0) -> Estimate:
    """The probability that a beam at a depth edge returns between the near and the far surface (a mixed pixel),
    from the still returns at the fitted room's depth edges: a return further than a margin (4 noise sigmas at its
    range, for the noisiest beams) from the beam's own surface (the cast surface nearer its median return, refined by
    its returns near it) and from the other surface, between the two, is mixed; a mixed return spread evenly over
    the gap lands that far from both with probability 1 - (both margins) / gap, which turns the count into a
    probability (the edge beams' counts as :func:`dropout_estimate` takes the spans': a Wilson interval on the counts
    divided by their design effect)."""
    unit = "probability"
    if not edges:
        return Estimate.unidentifiable("no depth edge of the room seen clear of robots while still", unit)
    r, centre, near, far, beam = (np.concatenate([e[k] for e in edges]) for k in range(5))
    sigma = noise.sigma.value if noise.sigma.ok and noise.sigma.value is not None else 0.01
    per_m = noise.per_m.value if noise.per_m.ok and noise.per_m.value is not None else 0.0
    spread = noise.beam_spread.value if noise.beam_spread.ok and noise.beam_spread.value is not None else 0.0
    # the other surface: a return there is the beam seeing past (or short of) the edge, a robot still but for a
    # millimetre's sway moves the edge across it; no mixed pixel
    other = np.where(np.abs(centre - near) <= np.abs(centre - far), far, near)
    margin = CLIP_SIGMAS * (sigma + per_m * centre) * math.exp(3 * spread) + 0.005
    margin_other = CLIP_SIGMAS * (sigma + per_m * other) * math.exp(3 * spread) + 0.005
    inner = (np.abs(r - centre) > margin) & (np.abs(r - other) > margin_other) & (r > near - 0.02) & (r < far + 0.02)
    share = np.clip(1 - (margin + margin_other) / np.maximum(far - near, 1e-9), 0.0, 1.0)
    trials = float(share.sum())
    if trials < 20:
        return Estimate.unidentifiable(f"only {len(r)} still returns at depth edges wide enough to tell", unit, len(r))
    # per edge beam (and span): its mixed returns and its effective trials; beams that differ (one a little off its
    # stated angle sees one surface throughout, never both) spread them beyond the binomial: the design effect
    _, which = np.unique(beam, return_inverse=True)
    events = np.bincount(which, weights=inner.astype(np.float64))
    tries = np.bincount(which, weights=share)
    # the noise's own tail: a return that is no mixed pixel lands beyond the margin toward the gap with the normal
    # tail probability there (a beam's noise factor exp(s z - s^2) averaged over z): the count's background, taken
    # out of the count (each beam's in proportion); 0 stays in the interval while the background can give the count
    nodes, node_weights = np.polynomial.hermite_e.hermegauss(9)
    factor = np.exp(spread * nodes - spread**2)
    sd = np.maximum((sigma + per_m * centre)[:, None] * factor[None, :], 1e-9)
    tail = stats.norm.sf(margin[:, None] / sd) @ (node_weights / node_weights.sum())
    background = float(tail.sum())
    count = int(inner.sum())
    net = events * (max(count - background, 0.0) / count if count else 0.0)
    est = dropout_estimate(np.minimum(net, tries), tries)
    method = (
        f"returns off their beam's surface toward the other, of {len(r)} still returns at {len(tries)} edge beams, "
        "over the share of the gap a mixed return lands in; " + est.method.split(": ", 1)[1]
    )
    method += f"; {count} found, {background:.2g} expected of the noise's tail (taken out)"
    if est.interval is not None and float(stats.poisson.sf(count - 1, background)) > 0.025:
        est = dataclasses.replace(est, interval=(0.0, est.interval[1]))
        method += ", no more than it can give: 0 in the interval"
    # an edge within a beam's angle error of it lies on the other side of that beam than the map says: the beam never
    # straddles it and dilutes the count (up to 2 x the error over the beam spacing of the edge beams)
    shifted = min(2 * BEAM_ANGLE_ERROR_RAD / spacing_rad, 0.5) if spacing_rad > 0 else 0.0
    if est.interval is not None and shifted > 0:
        lo, hi = est.interval
        est = dataclasses.replace(est, interval=(lo, min(hi / (1 - shifted), 1.0)))
        method += f"; its upper end divided by {1 - shifted:.2f} for edges that beams off their angle do not straddle"
    return dataclasses.replace(est, method=method, n=len(r))
