"""The lidar from its scans alone: a bag with nothing but a scan topic (no odometry, no map, no poses).

A sensor that stands still sees the same ranges scan after scan, up to its noise: the median change of the beams'
ranges from one scan to the next is then at the noise's level, and tens of millimetres while the robot moves. Runs of
scans whose median change stays within `STILL_FACTOR` times the recording's quietest level (its `LEVEL_PERCENTILE`th
percentile, at most `MAX_STILL_LEVEL_M`) for at least `min_s` are still spans. In them, each beam's spread about its
own mean is the noise, read with the same estimators as a recording with poses
(:mod:`pipeline.calibration.lidar_noise`): the range step, the noise and its growth with range with their bounded
intervals and trade-off, the beams' own spread; the driver's no-return convention; the sweep's rate and wander from
the stamps. Beams are left out at depth edges (a neighbour's mean range more than 0.1 m away: mixed pixels) and where
something moves in view (a mean that moves between the span's halves, or a spread `OUTLIER_SPREAD` times the beams'
median). What needs a map or poses (bias, mounting, dropouts against what should have returned, mixed pixels, the
room) is not estimated.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.calibration.calibrate import Calibration, Source
from pipeline.calibration.errors import CalibrationError
from pipeline.calibration.estimates import Estimate
from pipeline.calibration.keys import NEGLIGIBLE
from pipeline.calibration.lidar import (
    DEPTH_EDGE_M,
    LidarFit,
    NoiseFit,
    ScanSpan,
    _no_return_convention,
    _within_span_noise,
    valid_returns,
)
from pipeline.calibration.lidar_noise import range_step
from pipeline.calibration.localize import PoseSource
from pipeline.calibration.network import rate_estimate, rate_wander_estimate
from pipeline.calibration.options import CalibrationSettings
from pipeline.core.timebase import NS_PER_S
from pipeline.record.bags import bag_sha256

STILL_FACTOR = 2.0
LEVEL_PERCENTILE = 2.0
"""The recording's quietest scan-to-scan change: this percentile of the scans' median changes."""
OUTLIER_SPREAD = 5.0
"""A beam whose spread within a span is this many times the beams' median is seeing something move."""
MAX_STILL_LEVEL_M = 0.02
"""A recording whose quietest scan-to-scan change is above this never stood still."""
DRIFT_SIGMAS = 4.0


@dataclass(frozen=True)
class ScanOnlyLidar:
    """What the scans alone tell of the lidar."""

    still_spans: tuple[tuple[int, int, int], ...]
    """(start ns, end ns, scans) of each still span."""
    range_step_m: Estimate
    noise: NoiseFit
    rate_hz: Estimate
    rate_wander: Estimate
    no_return: str | None
    notes: tuple[str, ...] = field(default_factory=tuple)


def still_runs(ranges: np.ndarray, stamps_ns: np.ndarray, valid: np.ndarray, min_s: float) -> list[tuple[int, int]]:
    """[first, last] scan indices of each run of still scans lasting at least `min_s`."""
    both = valid[1:] & valid[:-1]
    change = np.abs(np.diff(np.where(valid, ranges, 0.0), axis=0))
    with np.errstate(invalid="ignore"):
        median = np.array([np.median(c[b]) if b.any() else np.inf for c, b in zip(change, both, strict=True)])
    finite = median[np.isfinite(median)]
    if not len(finite):
        return []
    level = float(np.percentile(finite, LEVEL_PERCENTILE))
    if level > MAX_STILL_LEVEL_M:
        return []
    quiet = np.concatenate([[False], median <= STILL_FACTOR * max(level, 1e-6)])  # scan i is still w.r.t. i - 1
    runs: list[tuple[int, int]] = []
    i = 0
    while i < len(quiet):
        if not quiet[i]:
            i += 1
            continue
        j = i
        while j + 1 < len(quiet) and quiet[j + 1]:
            j += 1
        first = i - 1  # the scan before the first quiet change is still too
        if (stamps_ns[j] - stamps_ns[first]) / NS_PER_S >= min_s:
            runs.append((first, j))
        i = j + 1
    return runs


def lidar_from_scans(
    ranges: np.ndarray,
    stamps_ns: np.ndarray,
    angle_min_rad: float,
    angle_increment_rad: float,
    range_min_m: float,
    range_max_m: float,
    settings: CalibrationSettings | None = None,
    robot: str = "robot",
) -> ScanOnlyLidar:
    """The lidar's keys from (n, beams) `ranges` stamped `stamps_ns` (one sensor, scans in order)."""
    settings = settings or CalibrationSettings()
    rng = np.random.default_rng(settings.seed)
    ranges = np.asarray(ranges, dtype=np.float64)
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    beams = ranges.shape[1]
    angles = angle_min_rad + angle_increment_rad * np.arange(beams)
    probe = ScanSpan(robot, "all", 0, 0, np.zeros(3), angles, ranges, range_min_m, range_max_m, np.zeros((0, 0, 2)))
    valid = valid_returns(ranges, probe)
    rate = rate_estimate([stamps_ns])
    wander = rate_wander_estimate([stamps_ns])
    runs = still_runs(ranges, stamps_ns, valid, settings.stationary_min_s)
    missing = {
        "inf": int(np.isposinf(ranges).sum()),
        "nan": int(np.isnan(ranges).sum()),
        "zero": int((ranges == 0.0).sum()),
        "max": int((ranges == np.float32(range_max_m)).sum()),
    }
    convention, convention_note = _no_return_convention(missing)
    notes = [convention_note]
    if not runs:
        reason = (
            f"the scans never stood still for >= {settings.stationary_min_s:g} s (their median change from scan to "
            "scan)"
        )
        empty = NoiseFit(Estimate.unidentifiable(reason, "m"), Estimate.unidentifiable(reason, "m/m"))
        return ScanOnlyLidar((), Estimate.unidentifiable(reason, "m"), empty, rate, wander, convention, tuple(notes))
    spans: list[ScanSpan] = []
    masks: list[np.ndarray] = []
    changes: list[np.ndarray] = []
    for k, (a, b) in enumerate(runs):
        r = ranges[a : b + 1]
        v = valid[a : b + 1]
        others = np.zeros((len(r), 0, 2))
        spans.append(
            ScanSpan(robot, f"still {k}", int(stamps_ns[a]), int(stamps_ns[b]), np.zeros(3), angles, r, range_min_m,
                     range_max_m, others)
        )  # fmt: skip
        count = v.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(count > 0, np.where(v, r, 0.0).sum(axis=0) / np.maximum(count, 1), np.nan)
        both = np.isfinite(mean) & np.isfinite(np.roll(mean, 1)) & np.isfinite(np.roll(mean, -1))
        filled = np.where(np.isfinite(mean), mean, 0.0)
        smooth = both & (np.abs(filled - np.roll(filled, 1)) <= DEPTH_EDGE_M)
        smooth &= np.abs(filled - np.roll(filled, -1)) <= DEPTH_EDGE_M
        half = len(r) // 2
        first, second = (np.where(v[s], r[s], np.nan) for s in (slice(0, half), slice(half, None)))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a beam without returns in one half: NaN, left out
            drift = np.abs(np.nanmean(first, axis=0) - np.nanmean(second, axis=0))
            spread = np.nanstd(np.where(v, r, np.nan), axis=0)
        typical = float(np.nanmedian(spread[smooth])) if smooth.any() else 0.0
        calm = spread <= OUTLIER_SPREAD * max(typical, 1e-4)  # a beam much noisier than the rest sees something move
        steady = calm & np.isfinite(drift) & (drift <= DRIFT_SIGMAS * max(typical, 1e-4) / np.sqrt(max(half, 1)))
        masks.append(np.broadcast_to((smooth & steady)[None, :], r.shape))
        changes.append(np.diff(np.where(v, r, 0.0), axis=0)[v[1:] & v[:-1]])
    step = range_step(np.concatenate(changes))
    step_m = float(step.value) if step.ok and step.value else 0.0
    noise = _within_span_noise(spans, masks, rng, settings, 0.0, step_m)
    still_s = sum((stamps_ns[b] - stamps_ns[a]) / NS_PER_S for a, b in runs)
    rel = (stamps_ns - stamps_ns[0]) / NS_PER_S
    where = ", ".join(f"{rel[a]:.1f}-{rel[b]:.1f} s" for a, b in runs)
    notes.insert(0, f"{len(runs)} still span(s) found from the scans alone ({where}), {still_s:.1f} s, "
                    f"{sum(b - a + 1 for a, b in runs)} scans")  # fmt: skip
    notes += list(noise.notes)
    spans_info = tuple((int(stamps_ns[a]), int(stamps_ns[b]), b - a + 1) for a, b in runs)
    return ScanOnlyLidar(spans_info, step, noise, rate, wander, convention, tuple(notes))


def scan_only_summary(fit: ScanOnlyLidar) -> list[tuple[str, Estimate]]:
    """(key, estimate) of every key the scans alone gave, in the reality profile's names."""
    out: list[tuple[str, Estimate]] = [
        ("lidar.rate_hz", fit.rate_hz),
        ("lidar.rate_wander", fit.rate_wander),
        ("lidar.range_step_m", fit.range_step_m),
        ("lidar.noise_sigma_m", fit.noise.sigma),
        ("lidar.noise_per_m", fit.noise.per_m),
        ("lidar.beam_noise_spread", fit.noise.beam_spread),
    ]
    if fit.noise.at_range is not None:
        at_m, est = fit.noise.at_range
        out.append((f"noise at {at_m:.2f} m", est))
    return [(k, e.flagged(0.0, NEGLIGIBLE.get(k, 0.0)) if k.startswith("lidar.") else e) for k, e in out]


LASER_SCAN = "sensor_msgs/msg/LaserScan"
DRIVE_TYPES = frozenset({"nav_msgs/msg/Odometry", "geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"})
"""A bag with any of these has odometry or commands: the whole calibration reads it, not the scans alone."""


@dataclass(frozen=True)
class ScanTopic:
    """One LaserScan topic of a bag: (n, beams) `ranges` (m), (n,) header `stamps_ns`, the first scan's layout."""

    topic: str
    ranges: np.ndarray
    stamps_ns: np.ndarray
    angle_min_rad: float
    angle_increment_rad: float
    range_min_m: float
    range_max_m: float
    skipped: int = 0
    """Scans left out for another beam count than the first's."""


def _reader(path: Path) -> Any:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    return AnyReader([path], default_typestore=get_typestore(Stores.ROS1_NOETIC))


def scans_only(path: Path) -> bool:
    """Whether the bag at `path` (ROS 1 bag, rosbag2 folder) holds a LaserScan topic and no odometry or commands;
    False for anything rosbags cannot open (an MCAP of this project's: the whole calibration reads it)."""
    try:
        with _reader(path) as reader:
            types = {c.msgtype for c in reader.connections}
    except Exception:  # rosbags' readers raise assertions and struct errors too: the importer names the problem
        return False
    return LASER_SCAN in types and not (types & DRIVE_TYPES)


def read_scan_topic(path: Path, topic: str | None = None) -> ScanTopic:
    """The scans of one LaserScan topic of the bag (the first, or `topic`), in recording order.

    Raises:
        CalibrationError: no such topic (the bag's topics named), or no scan in it.
    """
    with _reader(path) as reader:
        scans = [c for c in reader.connections if c.msgtype == LASER_SCAN and (topic is None or c.topic == topic)]
        if not scans:
            found = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})) or "none"
            wanted = f"LaserScan topic {topic}" if topic else "LaserScan topic"
            raise CalibrationError(str(path), f"no {wanted}; its topics: {found}")
        chosen = scans[0].topic
        ranges: list[np.ndarray] = []
        stamps: list[int] = []
        first: Any = None
        skipped = 0
        for conn, _, raw in reader.messages(connections=[c for c in scans if c.topic == chosen]):
            msg = reader.deserialize(raw, conn.msgtype)
            first = first or msg
            if len(msg.ranges) != len(first.ranges):
                skipped += 1
                continue
            ranges.append(np.asarray(msg.ranges, dtype=np.float64))
            stamps.append(int(msg.header.stamp.sec) * NS_PER_S + int(msg.header.stamp.nanosec))
    if first is None or len(first.ranges) == 0:
        raise CalibrationError(str(path), f"{chosen} holds no scan with beams")
    return ScanTopic(
        chosen,
        np.array(ranges),
        np.array(stamps, dtype=np.int64),
        float(first.angle_min),
        float(first.angle_increment),
        float(first.range_min),
        float(first.range_max),
        skipped,
    )


NEEDS_POSES = ("lidar.dropout_prob", "lidar.bias_m", "lidar.mount_yaw_rad", "lidar.mixed_pixel_prob")
"""Keys the scans alone do not tell: they need where the beams should have ended (a map and poses)."""


def calibrate_scans(path: Path, settings: CalibrationSettings, topic: str | None = None) -> Calibration:
    """The calibration a bag of scans alone gives: the lidar's keys of :func:`lidar_from_scans` (the rest named
    unidentifiable, with the reason), its notes, the bag's own SHA-256 (a folder's: its files' in name order)."""
    scans = read_scan_topic(path, topic)
    fit = lidar_from_scans(
        scans.ranges,
        scans.stamps_ns,
        scans.angle_min_rad,
        scans.angle_increment_rad,
        scans.range_min_m,
        scans.range_max_m,
        settings,
    )
    span_s = (scans.stamps_ns[-1] - scans.stamps_ns[0]) / NS_PER_S if len(scans.stamps_ns) > 1 else 0.0
    head = (
        f"scans alone: {scans.topic}, {len(scans.ranges)} scans of {scans.ranges.shape[1]} beams over {span_s:.1f} s "
        f"(range {scans.range_min_m:g}-{scans.range_max_m:g} m); the bag has no odometry or commands, so no poses: "
        "the actuation, odometry and network parts and what needs a map are not estimated"
    )
    notes = [head, *fit.notes]
    if scans.skipped:
        notes.append(f"{scans.skipped} scans with another beam count than the first's left out")
    reason = "needs where the beams should end (poses in a map): the bag has scans alone"
    values = {k: e for k, e in scan_only_summary(fit) if k.startswith("lidar.")}
    for key in NEEDS_POSES:
        values[key] = Estimate.unidentifiable(reason, "")
    lidar = LidarFit(
        noise_sigma_m=values["lidar.noise_sigma_m"],
        dropout_prob=values["lidar.dropout_prob"],
        bias_m=values["lidar.bias_m"],
        mount_yaw_rad=values["lidar.mount_yaw_rad"],
        noise_per_m=values["lidar.noise_per_m"],
        notes=tuple(notes),
        range_step_m=values["lidar.range_step_m"],
        beam_noise_spread=values["lidar.beam_noise_spread"],
        noise_at_range=fit.noise.at_range,
        noise_correlation=fit.noise.correlation,
        no_return=fit.no_return,
        spans=len(fit.still_spans),
        stationary_s=sum((b - a) / NS_PER_S for a, b, _ in fit.still_spans),
    )
    source = Source(str(path), {}, 0, "real", ("robot",), bag_sha256(path))
    return Calibration(
        settings.scenario,
        (source,),
        values,
        lidar=lidar,
        settings=dataclasses.replace(settings, parts=("lidar",)),
        pose_source=PoseSource("none"),
    )
