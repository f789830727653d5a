"""The calibration: deployment recordings in, estimates of the reality profile with uncertainties out.

:func:`calibrate` reads one or more session recordings of the same scenario, smooths every robot's
ground truth, and hands each estimator its data:

- lidar: scans taken during stationary spans (:mod:`pipeline.calibration.lidar`);
- actuation: commanded vs achieved velocity on contact-free stretches (:mod:`pipeline.calibration.actuation`);
- odometry: odometry vs truth per robot and episode (:mod:`pipeline.calibration.odometry`);
- network: stamp gaps and delivery delays of the sensor topics (:mod:`pipeline.calibration.network`).

Uncertainties that resample data do so over sessions' robots, episodes and spans, pooled across
the recordings.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from pipeline.calibration.actuation import ActuationFit, CommandTimeline, VelocityTrack, estimate_actuation
from pipeline.calibration.errors import CalibrationError, ScenarioMismatchError
from pipeline.calibration.estimates import Estimate
from pipeline.calibration.lidar import LidarFit, ScanSpan, estimate_lidar, stationary_spans
from pipeline.calibration.network import NetworkFit, StampStream, estimate_network, rate_estimate
from pipeline.calibration.odometry import OdometryEpisode, OdometryFit, estimate_odometry
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.raycast import MapGeometry
from pipeline.calibration.recording import SessionData, read_session
from pipeline.calibration.smoothing import SmootherNoise, Trajectory, smooth_trajectory
from pipeline.core.scenario import Scenario

PROFILE_KEYS: dict[str, tuple[str, ...]] = {
    "lidar": ("beams", "rate_hz", "noise_sigma_m", "dropout_prob", "bias_m", "mount_yaw_rad"),
    "actuation": ("delay_s", "time_constant_s", "linear_gain", "angular_gain"),
    "odometry": ("rate_hz", "drift_per_m"),
    "network": ("loss_prob", "jitter_s"),
}
"""The reality profile's keys, in its order."""


@dataclass(frozen=True)
class Source:
    """One calibrated recording: its path and its ``session`` metadata."""

    path: str
    session: dict[str, str]
    episodes: int


@dataclass(frozen=True)
class Calibration:
    """Estimates of the reality profile from recordings of one scenario.

    `values` maps the profile's dotted keys (``lidar.noise_sigma_m``, ...) to their estimates; the
    fits keep what the report plots. Parts not asked for are absent.
    """

    scenario: str
    sources: tuple[Source, ...]
    values: dict[str, Estimate]
    lidar: LidarFit | None = None
    actuation: ActuationFit | None = None
    odometry: OdometryFit | None = None
    network: NetworkFit | None = None
    settings: CalibrationSettings = field(default_factory=CalibrationSettings)

    def estimate(self, key: str) -> Estimate:
        """The estimate of a dotted profile key, e.g. ``actuation.delay_s``; KeyError if it was not asked for."""
        return self.values[key]

    def profile(self) -> dict[str, dict[str, float | int]]:
        """The identified values in the reality profile's layout (unidentifiable keys are absent)."""
        out: dict[str, dict[str, float | int]] = {}
        for group, keys in PROFILE_KEYS.items():
            for key in keys:
                est = self.values.get(f"{group}.{key}")
                if est is not None and est.ok and est.value is not None:
                    value: float | int = round(est.value) if key == "beams" else _short(est.value)
                    out.setdefault(group, {})[key] = value
        return out

    def unidentified(self) -> dict[str, str]:
        """Dotted keys that the data cannot determine, with the reason."""
        return {k: e.reason for k, e in self.values.items() if not e.ok}

    def world_overrides(self) -> dict[str, dict[str, float | int]]:
        """Simulator settings (keys of ``pipeline.params.WorldConfig``) for training on top of params.yaml's ``world``.

        Only identified values appear; the simulated lidar gets the real beam count (its scan is reduced
        to the policy's beams as the real one is) and sees the real robot bodies.
        """
        out: dict[str, dict[str, float | int]] = {}

        def put(group: str, key: str, source: str) -> None:
            est = self.values.get(source)
            if est is not None and est.ok and est.value is not None:
                out.setdefault(group, {})[key] = round(est.value) if key == "sim_beams" else _short(est.value)

        for key in ("noise_sigma_m", "dropout_prob", "bias_m", "mount_yaw_rad"):
            put("lidar", key, f"lidar.{key}")
        put("lidar", "sim_beams", "lidar.beams")
        if "lidar" in out:
            out["lidar"]["robot_radius_seen_m"] = 0.0
        for key in PROFILE_KEYS["actuation"]:
            put("actuation", key, f"actuation.{key}")
        put("odometry", "drift_per_m", "odometry.drift_per_m")
        return out


def _short(x: float) -> float:
    return float(f"{x:.6g}")


def _trajectories(data: SessionData, settings: CalibrationSettings) -> dict[str, Trajectory]:
    noise = SmootherNoise(
        settings.truth_position_sigma_m,
        settings.truth_yaw_sigma_rad,
        settings.truth_accel_sigma_mps2,
        settings.truth_angular_accel_sigma_radps2,
    )
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


def _episode_of(data: SessionData, t_ns: int) -> int:
    for e in data.episodes:
        if e.start_ns <= t_ns <= e.end_ns:
            return e.episode
    return -1


def _others(data: SessionData, trajectories: dict[str, Trajectory], robot: str, t_ns: np.ndarray) -> np.ndarray:
    """(len(t_ns), k, 2) positions of the other robots at times `t_ns` (NaN where unknown)."""
    others = [trajectories[r.name].at(t_ns)[0][:, :2] for r in data.robots if r.name != robot]
    if not others:
        return np.zeros((len(t_ns), 0, 2))
    return np.stack(others, axis=1)


def _scan_spans(
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
                label = f"{tag}/{robot.name}/episode {_episode_of(data, start)}"
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
                        _others(data, trajectories, robot.name, scans.time.t_ns[sel]),
                    )
                )
    return spans


def _velocity_tracks(
    tag: str,
    data: SessionData,
    trajectories: dict[str, Trajectory],
    geometry: MapGeometry,
    settings: CalibrationSettings,
) -> list[VelocityTrack]:
    out: list[VelocityTrack] = []
    radius = data.scenario.robot.radius_m
    margin = settings.actuation_contact_margin_m
    for robot in data.robots:
        cmd = robot.commands
        if cmd is None or len(cmd.t_ns) == 0:
            continue
        timeline = CommandTimeline(cmd.t_ns, np.stack([cmd.v, cmd.w], axis=1))
        for track in trajectories[robot.name].tracks:
            free = geometry.clearance(track.pose[:, :2]) > radius + margin
            others = _others(data, trajectories, robot.name, track.t_ns)
            if others.shape[1]:
                dist = np.hypot(others[..., 0] - track.pose[:, None, 0], others[..., 1] - track.pose[:, None, 1])
                free &= ~np.any(dist < 2 * radius + margin, axis=1)
            edges = np.diff(np.r_[0, free.astype(np.int8), 0])
            body = track.body_velocity()
            for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
                if b - a < 3:
                    continue
                cluster = f"{tag}/{robot.name}/episode {_episode_of(data, int(track.t_ns[a]))}"
                out.append(VelocityTrack(robot.name, cluster, track.t_ns[a:b], body[a:b], timeline))
    return out


def _odometry_episodes(tag: str, data: SessionData, trajectories: dict[str, Trajectory]) -> list[OdometryEpisode]:
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


def _network_streams(tag: str, data: SessionData) -> list[StampStream]:
    out: list[StampStream] = []
    windows = tuple(data.windows)
    for robot in data.robots:
        times = [
            (f"/{robot.name}/{kind}", s.time) for kind, s in (("ground_truth", robot.truth), ("odom", robot.odom)) if s
        ]
        if robot.scans is not None:
            times.append((f"/{robot.name}/scan", robot.scans.time))
        out += [StampStream(f"{tag} {topic}", t.stamp_ns, t.log_ns, windows) for topic, t in times]
    return out


def calibrate(
    recordings: str | Path | Sequence[str | Path], settings: CalibrationSettings | None = None
) -> Calibration:
    """Estimate the reality profile from session recordings (MCAP) of one scenario.

    Args:
        recordings: one recording or several of the same scenario (and fleet); their data are pooled.
        settings: what to estimate and how (defaults: every part, the recordings' scenario).

    Raises:
        MissingTopicError: a recording lacks a topic a requested part needs (it is named).
        ScenarioMismatchError: a recording comes from another scenario than `settings.scenario`
            or than the first recording.
        CalibrationError: a recording cannot be used (no episodes, robots that do not match the scenario...).
        LogReadError: a file is missing, not MCAP or damaged beyond salvage.
    """
    settings = settings or CalibrationSettings()
    paths = [recordings] if isinstance(recordings, (str, Path)) else list(recordings)
    if not paths:
        raise CalibrationError("<calibrate>", "no recording given")
    parts = tuple(dict.fromkeys(settings.parts))
    rng = np.random.default_rng(settings.seed)
    expected = settings.scenario or None
    sessions: list[SessionData] = []
    scenario: Scenario | None = None
    for path in paths:
        data = read_session(path, parts, expected if scenario is None else scenario)
        if scenario is not None and data.scenario.name != scenario.name:
            raise ScenarioMismatchError(str(path), data.scenario.name, scenario.name)
        scenario = data.scenario
        sessions.append(data)
    assert scenario is not None
    geometry = MapGeometry.from_scenario(scenario)
    spans: list[ScanSpan] = []
    tracks: list[VelocityTrack] = []
    episodes: list[OdometryEpisode] = []
    streams: list[StampStream] = []
    scan_stamps: list[np.ndarray] = []
    odom_stamps: list[np.ndarray] = []
    beams: list[int] = []
    for k, data in enumerate(sessions):
        tag = f"recording {k}" if len(sessions) > 1 else "recording"
        trajectories = _trajectories(data, settings)
        if "lidar" in parts:
            spans += _scan_spans(tag, data, trajectories, settings)
            for robot in data.robots:
                if robot.scans is not None and len(robot.scans.ranges):
                    beams.append(robot.scans.beams)
                    scan_stamps.append(robot.scans.time.stamp_ns)
        if "actuation" in parts:
            tracks += _velocity_tracks(tag, data, trajectories, geometry, settings)
        if "odometry" in parts:
            episodes += _odometry_episodes(tag, data, trajectories)
            odom_stamps += [r.odom.time.stamp_ns for r in data.robots if r.odom is not None]
        if "network" in parts:
            streams += _network_streams(tag, data)
    values: dict[str, Estimate] = {}
    lidar = actuation = odometry = network = None
    if "lidar" in parts:
        lidar = estimate_lidar(geometry, spans, settings, rng)
        if beams:
            counts = np.bincount(beams)
            values["lidar.beams"] = Estimate.of(
                float(counts.argmax()), 0.0, None, "beams", "beam count of the scans", len(beams)
            )
        else:
            values["lidar.beams"] = Estimate.unidentifiable("no scan recorded", "beams")
        values["lidar.rate_hz"] = rate_estimate(scan_stamps)
        for key in ("noise_sigma_m", "dropout_prob", "bias_m", "mount_yaw_rad"):
            values[f"lidar.{key}"] = getattr(lidar, key)
    if "actuation" in parts:
        actuation = estimate_actuation(tracks, settings, rng)
        for key in PROFILE_KEYS["actuation"]:
            values[f"actuation.{key}"] = getattr(actuation, key)
    if "odometry" in parts:
        values["odometry.rate_hz"] = rate_estimate(odom_stamps)
        odometry = estimate_odometry(episodes, settings)
        inferred = tuple(note for d in sessions for note in d.notes)
        odometry = replace(odometry, notes=inferred + odometry.notes)
        values["odometry.drift_per_m"] = odometry.drift_per_m
    if "network" in parts:
        network = estimate_network(streams, settings, rng)
        values["network.loss_prob"] = network.loss_prob
        values["network.jitter_s"] = network.jitter_s
    sources = tuple(Source(str(d.path), dict(d.session), len(d.episodes)) for d in sessions)
    return Calibration(scenario.name, sources, values, lidar, actuation, odometry, network, settings)
