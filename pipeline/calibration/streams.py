"""What calibration's estimators read from recordings: the recordings as read (:class:`Sessions`), each robot's
smoothed poses, and the streams cut from them (still scan spans, scans while driving, contact-free velocity tracks,
odometry episodes, wheel episodes, stamp streams), pooled over the recordings (:class:`Gathered`) for the streams the
estimators asked for (:func:`gather`, by the names of :class:`Gathered`'s fields).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field

import numpy as np

from pipeline.calibration.actuation import CommandTimeline, VelocityTrack
from pipeline.calibration.lidar import ScanSpan, stationary_spans
from pipeline.calibration.localize import PoseSource
from pipeline.calibration.motors import WheelEpisode, wheel_speeds
from pipeline.calibration.network import (
    StampStream,
)
from pipeline.calibration.odometry import OdometryEpisode
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.raycast import MapGeometry
from pipeline.calibration.recording import SessionData
from pipeline.calibration.smoothing import SmootherNoise, Trajectory, smooth_trajectory
from pipeline.core.scenario import Scenario
from pipeline.core.timebase import NS_PER_S


@dataclass
class Sessions:
    """The recordings as read (poses localized where they come from scans), their scenario and the map's geometry."""

    sessions: list[SessionData]
    pose_sources: list[PoseSource]
    scenario: Scenario
    geometry: MapGeometry


@dataclass
class Gathered:
    """What each part's estimator reads, pooled over the recordings."""

    spans: list[ScanSpan] = field(default_factory=list)
    moving: list[ScanSpan] = field(default_factory=list)
    """One per scan while driving (:func:`moving_scans`)."""
    tracks: list[VelocityTrack] = field(default_factory=list)
    episodes: list[OdometryEpisode] = field(default_factory=list)
    streams: list[StampStream] = field(default_factory=list)
    scan_stamps: list[np.ndarray] = field(default_factory=list)
    odom_stamps: list[np.ndarray] = field(default_factory=list)
    beams: list[int] = field(default_factory=list)


def smoothed_poses(
    data: SessionData, settings: CalibrationSettings, source: PoseSource | None = None
) -> dict[str, Trajectory]:
    position, yaw = settings.truth_position_sigma_m, settings.truth_yaw_sigma_rad
    if source is not None and source.robots:  # localized poses: the matches' own spread
        stds = np.array([r.median_std for r in source.robots])
        position = max(position, float(np.median(stds[:, :2])))
        yaw = max(yaw, float(np.median(stds[:, 2])))
    noise = SmootherNoise(position, yaw, settings.truth_accel_sigma_mps2, settings.truth_angular_accel_sigma_radps2)
    out = {}
    for robot in data.robots:
        truth = robot.truth
        if truth is None or len(truth.pose) == 0:
            out[robot.name] = Trajectory(())
            continue
        out[robot.name] = smooth_trajectory(
            truth.time.t_ns,
            truth.pose,
            noise,
            settings.truth_max_gap_s,
            settings.truth_max_jump_mps,
            windows=data.windows,
        )
    return out


def episode_of(data: SessionData, t_ns: int) -> int:
    for e in data.episodes:
        if e.start_ns <= t_ns <= e.end_ns:
            return e.episode
    return -1


def others_at(data: SessionData, trajectories: dict[str, Trajectory], robot: str, t_ns: np.ndarray) -> np.ndarray:
    """(len(t_ns), k, 2) positions of the other robots at times `t_ns` (NaN where unknown)."""
    others = [trajectories[r.name].at(t_ns)[0][:, :2] for r in data.robots if r.name != robot]
    if not others:
        return np.zeros((len(t_ns), 0, 2))
    return np.stack(others, axis=1)


def scan_spans(
    tag: str, data: SessionData, trajectories: dict[str, Trajectory], settings: CalibrationSettings
) -> list[ScanSpan]:
    spans: list[ScanSpan] = []
    for robot in data.robots:
        scans = robot.scans
        if scans is None or len(scans.ranges) == 0:
            continue
        for track in trajectories[robot.name].tracks:
            for start, end in stationary_spans(
                track, settings.stationary_speed_mps, settings.stationary_yaw_rate_radps, settings.stationary_min_s
            ):
                sel = np.flatnonzero((scans.time.t_ns >= start) & (scans.time.t_ns <= end))
                if len(sel) == 0:
                    continue
                first = int(sel[0])
                same = (scans.angle_min_rad[sel] == scans.angle_min_rad[first]) & (
                    scans.angle_increment_rad[sel] == scans.angle_increment_rad[first]
                )
                sel = sel[same]
                pose, _ = track.at(np.array([start, (start + end) // 2, end]))
                centre = pose[1].copy()
                centre[2] = math.atan2(np.sin(pose[:, 2]).mean(), np.cos(pose[:, 2]).mean())
                angles = scans.angle_min_rad[first] + scans.angle_increment_rad[first] * np.arange(scans.beams)
                label = f"{tag}/{robot.name}/episode {episode_of(data, start)}"
                spans.append(
                    ScanSpan(
                        robot.name,
                        label,
                        start,
                        end,
                        centre,
                        angles,
                        scans.ranges[sel],
                        float(scans.range_min_m[first]),
                        float(scans.range_max_m[first]),
                        others_at(data, trajectories, robot.name, scans.time.t_ns[sel]),
                    )
                )
    return spans


MOVING_SCANS_PER_ROBOT = 600
"""Scans while driving read per robot and recording for the noise (evenly over its driving; more add little)."""


def moving_scans(
    tag: str, data: SessionData, trajectories: dict[str, Trajectory], settings: CalibrationSettings
) -> list[ScanSpan]:
    """Each robot's scans while it drives (outside its stationary spans), one `ScanSpan` per scan at the pose of
    its time, labelled by robot and episode: the noise from scans against the map (:func:`estimate_lidar`)."""
    out: list[ScanSpan] = []
    for robot in data.robots:
        scans = robot.scans
        if scans is None or len(scans.ranges) == 0:
            continue
        t = scans.time.t_ns
        moving = np.zeros(len(t), dtype=bool)
        for track in trajectories[robot.name].tracks:
            inside = (t >= track.start_ns) & (t <= track.end_ns)
            for start, end in stationary_spans(
                track, settings.stationary_speed_mps, settings.stationary_yaw_rate_radps, settings.stationary_min_s
            ):
                inside &= ~((t >= start) & (t <= end))
            moving |= inside
        sel = np.flatnonzero(moving)
        if len(sel) == 0:
            continue
        sel = sel[np.unique(np.linspace(0, len(sel) - 1, min(len(sel), MOVING_SCANS_PER_ROBOT)).round().astype(int))]
        pose, _ = trajectories[robot.name].at(t[sel])
        others = others_at(data, trajectories, robot.name, t[sel])
        for j, i in enumerate(sel):
            if not np.all(np.isfinite(pose[j])):
                continue
            angles = scans.angle_min_rad[i] + scans.angle_increment_rad[i] * np.arange(scans.beams)
            out.append(
                ScanSpan(
                    robot.name,
                    f"{tag}/{robot.name}/episode {episode_of(data, int(t[i]))}",
                    int(t[i]),
                    int(t[i]),
                    pose[j],
                    angles,
                    scans.ranges[i : i + 1],
                    float(scans.range_min_m[i]),
                    float(scans.range_max_m[i]),
                    others[j : j + 1],
                )
            )
    return out


def velocity_tracks(
    tag: str,
    data: SessionData,
    trajectories: dict[str, Trajectory],
    geometry: MapGeometry,
    settings: CalibrationSettings,
) -> list[VelocityTrack]:
    out: list[VelocityTrack] = []
    radius = float(data.scenario.radii.max())
    margin = settings.actuation_contact_margin_m
    for robot in data.robots:
        cmd = robot.commands
        if cmd is None or len(cmd.t_ns) == 0:
            continue
        timeline = CommandTimeline(cmd.t_ns, np.stack([cmd.v, cmd.w], axis=1))
        for track in trajectories[robot.name].tracks:
            free = geometry.clearance(track.pose[:, :2]) > radius + margin
            others = others_at(data, trajectories, robot.name, track.t_ns)
            if others.shape[1]:
                dist = np.hypot(others[..., 0] - track.pose[:, None, 0], others[..., 1] - track.pose[:, None, 1])
                free &= ~np.any(dist < 2 * radius + margin, axis=1)
            edges = np.diff(np.r_[0, free.astype(np.int8), 0])
            body = track.body_velocity()
            for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
                if b - a < 3:
                    continue
                cluster = f"{tag}/{robot.name}/episode {episode_of(data, int(track.t_ns[a]))}"
                out.append(VelocityTrack(robot.name, cluster, track.t_ns[a:b], body[a:b], timeline))
    return out


def wheel_episodes(tag: str, data: SessionData, tracks: Sequence[VelocityTrack]) -> list[WheelEpisode]:
    """Each robot-episode's odometry as wheel speeds, free where a contact-free track of it covers the sample."""
    out: list[WheelEpisode] = []
    for robot in data.robots:
        odom, cmd = robot.odom, robot.commands
        if odom is None or odom.velocity is None or cmd is None or len(cmd.t_ns) == 0:
            continue
        timeline = CommandTimeline(cmd.t_ns, np.stack([cmd.v, cmd.w], axis=1))
        for episode in data.episodes:
            sel = (odom.time.t_ns >= episode.start_ns) & (odom.time.t_ns <= episode.end_ns)
            if sel.sum() < 3:
                continue
            cluster = f"{tag}/{robot.name}/episode {episode.episode}"
            t = odom.time.t_ns[sel]
            free = np.zeros(len(t), dtype=bool)
            for track in tracks:
                if track.cluster == cluster:
                    free |= (t >= track.t_ns[0]) & (t <= track.t_ns[-1])
            velocity = odom.velocity[sel]
            wheels = wheel_speeds(velocity[:, 0], velocity[:, 1])
            out.append(WheelEpisode(robot.name, cluster, int(episode.start_ns), t, wheels, free, timeline))
    return out


def odometry_period_s(stamps: Sequence[np.ndarray]) -> float:
    """The odometry's period (s): the median step of its stamps."""
    diffs = [np.diff(np.asarray(s, dtype=np.int64)) for s in stamps if len(s) > 1]
    steps = np.concatenate(diffs) if diffs else np.zeros(0, dtype=np.int64)
    steps = steps[steps > 0]
    return float(np.median(steps)) / NS_PER_S if len(steps) else 0.025


def odometry_episodes(tag: str, data: SessionData, trajectories: dict[str, Trajectory]) -> list[OdometryEpisode]:
    out: list[OdometryEpisode] = []
    for robot in data.robots:
        odom = robot.odom
        if odom is None or len(odom.pose) == 0:
            continue
        trajectory = trajectories[robot.name]
        for episode in data.episodes:
            sel = (odom.time.t_ns >= episode.start_ns) & (odom.time.t_ns <= episode.end_ns)
            t = odom.time.t_ns[sel]
            truth, _ = trajectory.at(t)
            ok = np.all(np.isfinite(truth), axis=1)
            if ok.sum() < 3:
                continue
            label = f"{tag}/{robot.name}/episode {episode.episode}"
            piece = trajectory.track_index(t[ok])
            out.append(OdometryEpisode(robot.name, label, t[ok], odom.pose[sel][ok], truth[ok], piece))
    return out


def network_streams(tag: str, data: SessionData) -> list[StampStream]:
    out: list[StampStream] = []
    windows = tuple(data.windows)
    for robot in data.robots:
        truth = robot.truth if data.pose_source == "ground_truth" else None  # localized poses ride on odom's stamps
        times = [(f"/{robot.name}/{kind}", s.time) for kind, s in (("ground_truth", truth), ("odom", robot.odom)) if s]
        if robot.scans is not None:
            times.append((f"/{robot.name}/scan", robot.scans.time))
        out += [StampStream(f"{tag} {topic}", t.stamp_ns, t.log_ns, windows) for topic, t in times]
    return out


STREAM_NAMES = ("spans", "moving", "scans", "tracks", "episodes", "odom_stamps", "streams")
"""The streams an estimator may read (:attr:`pipeline.calibration.steps.Step.reads`); ``scans`` is the scans' beam
counts and stamps (:attr:`Gathered.beams`, :attr:`Gathered.scan_stamps`), the others :class:`Gathered`'s fields."""


def gather(
    tagged: list[tuple[str, SessionData]],
    pose_sources: list[PoseSource],
    reads: Collection[str],
    settings: CalibrationSettings,
    geometry: MapGeometry,
) -> Gathered:
    """The streams `reads` names (of `STREAM_NAMES`) of every recording, pooled in the recordings' order."""
    unknown = sorted(set(reads) - set(STREAM_NAMES))
    if unknown:
        raise ValueError(f"streams {', '.join(unknown)}: not among {', '.join(STREAM_NAMES)}")
    out = Gathered()
    for (tag, data), source in zip(tagged, pose_sources, strict=True):
        trajectories = smoothed_poses(data, settings, source)
        if "spans" in reads:
            out.spans += scan_spans(tag, data, trajectories, settings)
        if "moving" in reads:
            out.moving += moving_scans(tag, data, trajectories, settings)
        if "scans" in reads:
            for robot in data.robots:
                if robot.scans is not None and len(robot.scans.ranges):
                    out.beams.append(robot.scans.beams)
                    out.scan_stamps.append(robot.scans.time.stamp_ns)
        if "tracks" in reads:
            out.tracks += velocity_tracks(tag, data, trajectories, geometry, settings)
        if "episodes" in reads:
            out.episodes += odometry_episodes(tag, data, trajectories)
        if "odom_stamps" in reads:
            out.odom_stamps += [r.odom.time.stamp_ns for r in data.robots if r.odom is not None]
        if "streams" in reads:
            out.streams += network_streams(tag, data)
    return out
