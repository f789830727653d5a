"""The calibration: deployment recordings in, estimates of the reality profile with uncertainties out.

:func:`calibrate` reads one or more session recordings of the same scenario, smooths every robot's
ground truth, and hands each estimator its data:

- lidar: scans taken during stationary spans, and the noise again from scans while driving
  (:mod:`pipeline.calibration.lidar`);
- actuation: commanded vs achieved velocity on contact-free stretches (:mod:`pipeline.calibration.actuation`);
- odometry: odometry vs truth per robot and episode (:mod:`pipeline.calibration.odometry`);
- odometry also gives the true wheel radii and separation (:mod:`pipeline.calibration.wheels`);
- network: stamp gaps and delivery delays of the sensor topics (:mod:`pipeline.calibration.network`),
  and each robot's clock against the recorder's from the stamps of its own sensors
  (:mod:`pipeline.calibration.clock`).

Uncertainties that resample data do so over sessions' robots, episodes and spans, pooled across
the recordings.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from pipeline.calibration.actuation import ActuationFit, SpeedLimit, VelocityTrack
from pipeline.calibration.clock import ClockFit
from pipeline.calibration.errors import CalibrationError, ScenarioMismatchError
from pipeline.calibration.estimates import Estimate, six_digits
from pipeline.calibration.gains import GainAgreement, deadband_gains, drive_gains
from pipeline.calibration.keys import (
    EFFECTIVE_DRIVE,
    MIN_RANDOMIZE_HALF_WIDTH,
    NETWORK_SOURCES,
    PHYSICAL_KEYS,
    PROFILE_KEYS,
    RANDOMIZED_SOURCES,
    REAL_LIDAR_KEYS,
    EffectiveValue,
    _arc_half_width,
    arc_per_m,
    split_key,
    world_bounds,
)
from pipeline.calibration.lidar import LidarFit
from pipeline.calibration.localize import MIN_INLIERS, OccupancyMap, PoseSource, localize_robot, map_agreement
from pipeline.calibration.motors import MotorFit
from pipeline.calibration.network import (
    NetworkFit,
)
from pipeline.calibration.odometry import OdometryFit
from pipeline.calibration.options import CalibrationSettings, Part
from pipeline.calibration.randomization import RandomizationFit
from pipeline.calibration.raycast import MapGeometry
from pipeline.calibration.recording import SessionData, read_session
from pipeline.calibration.smoothing import Trajectory
from pipeline.calibration.steps import Context, finish, wanted
from pipeline.calibration.streams import Sessions, gather, smoothed_poses
from pipeline.calibration.wheels import NOMINAL_WHEEL_RADIUS_M, NOMINAL_WHEEL_SEPARATION_M, WheelFit
from pipeline.core.scenario import Scenario


@dataclass(frozen=True)
class Source:
    """One calibrated recording: its path, its ``session`` metadata, its kind (sim, twin, real), its robots, the
    SHA-256 of its bytes, and what salvaging it lost ('' for a file read as written)."""

    path: str
    session: dict[str, str]
    episodes: int
    kind: str = ""
    robots: tuple[str, ...] = ()
    sha256: str = ""
    salvage: str = ""


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
    wheels: WheelFit | None = None
    clock: ClockFit | None = None
    motors: MotorFit | None = None
    randomization: RandomizationFit | None = None
    pose_source: PoseSource = field(default_factory=lambda: PoseSource("ground_truth"))
    effective: dict[str, EffectiveValue] = field(default_factory=dict)
    """Values of the simulator's model that stand for several of the robot's properties together (the drive
    chain's delay and lag), by name; see :data:`EFFECTIVE_DRIVE`."""
    deadband_gains: tuple[float, float] | None = None
    """The body-velocity gains (linear, angular) that the simulator's drive with :meth:`body_gains` and the deadband
    gives over the recorded commands (what the body-velocity fit would read in it); None without body gains."""
    drive_gains: tuple[float, float] | None = None
    """The gains (linear, angular) the simulator takes with the deadband: over the recorded commands they move its
    body as the body-velocity fit read it (:func:`pipeline.calibration.gains.drive_gains`); None without body
    gains."""

    def simulator_estimate(self, key: str) -> Estimate | None:
        """The estimate the simulator's setting for profile key `key` takes: the effective value where the profile
        key is not measured apart (the drive's delay and lag), else the key's own."""
        for name, (setting_of, _stands_for, _model) in EFFECTIVE_DRIVE.items():
            if name in self.effective and setting_of == key:
                return self.effective[name].estimate
        return self.values.get(key)

    def estimate(self, key: str) -> Estimate:
        """The estimate of a dotted profile key, e.g. ``actuation.delay_s``; KeyError if it was not asked for."""
        return self.values[key]

    def profile(self) -> dict[str, dict[str, object]]:
        """The identified values in the reality profile's layout (unidentifiable keys are absent; a pair with one
        component identified keeps the other at its ideal value 0; blocked lidar sectors when seen)."""
        out: dict[str, dict[str, object]] = {}
        pairs: dict[tuple[str, str], dict[tuple[int, ...], float]] = {}
        for key, est in self.values.items():
            if not (est.ok and est.value is not None):
                continue
            group, name, indices = split_key(key)
            if indices:
                pairs.setdefault((group, name), {})[indices] = six_digits(est.value)
            else:
                value: float | int = round(est.value) if name == "beams" else six_digits(est.value)
                out.setdefault(group, {})[name] = value
        for (group, name), parts in pairs.items():
            if len(next(iter(parts))) == 1:
                out.setdefault(group, {})[name] = [parts.get((i,), 0.0) for i in range(2)]
            else:
                n = max(k[0] for k in parts) + 1
                out.setdefault(group, {})[name] = [[parts.get((b, i), 0.0) for i in range(2)] for b in range(n)]
        if self.lidar is not None and self.lidar.blocked_sectors_rad:
            out.setdefault("lidar", {})["blocked_sectors_rad"] = [list(s) for s in self.lidar.blocked_sectors_rad]
        if self.lidar is not None and self.lidar.no_return is not None:
            out.setdefault("lidar", {})["no_return"] = self.lidar.no_return
        order = list(PROFILE_KEYS)
        return {g: out[g] for g in sorted(out, key=lambda g: order.index(g) if g in order else len(order))}

    def arc_per_m(self) -> float | None:
        """Yaw rate (rad/s) per m/s that unequal wheels add to a straight command (see `arc_per_m`)."""
        return arc_per_m(self.values)

    def body_gains(self) -> tuple[float, float] | None:
        """(linear, angular) gains for a simulator that applies the deadband: the wheel chain's gains (free of the
        deadband, which the body-velocity fit folds into smaller gains) at body level, through the calibrated
        mean wheel radius and separation (nominal where unidentified). None unless the deadband is identified."""
        deadband = self.values.get("base.deadband_radps")
        if self.motors is None or self.motors.gains is None or deadband is None or not deadband.ok:
            return None

        def known(key: str, nominal: float) -> float:
            est = self.values.get(key)
            return float(est.value) if est is not None and est.ok and est.value is not None else nominal

        radius = (
            known("base.wheel_radius_left_m", NOMINAL_WHEEL_RADIUS_M)
            + known("base.wheel_radius_right_m", NOMINAL_WHEEL_RADIUS_M)
        ) / 2
        separation = known("base.wheel_separation_m", NOMINAL_WHEEL_SEPARATION_M)
        linear, angular = self.motors.gains
        scale = radius / NOMINAL_WHEEL_RADIUS_M
        return linear * scale, angular * scale * NOMINAL_WHEEL_SEPARATION_M / separation

    def simulator_gains(self) -> tuple[float, float] | None:
        """(linear, angular) gains the simulator takes with the deadband: :attr:`drive_gains`, else the wheel chain's
        (:meth:`body_gains`); None unless the deadband is identified."""
        return self.drive_gains if self.drive_gains is not None else self.body_gains()

    def gain_agreement(self) -> list[GainAgreement]:
        """Per channel, the body-velocity fit's gain beside the gain the wheel chain's gain with the deadband shows
        over the same commands (the two readings of one robot, reconciled or not), and the simulator's gain."""
        gains, simulator = self.body_gains(), self.simulator_gains()
        if gains is None or simulator is None or self.deadband_gains is None:
            return []
        out = []
        for c, channel in enumerate(("linear", "angular")):
            est = self.values.get(f"actuation.{channel}_gain")
            if est is None or not est.ok or est.value is None or est.interval is None:
                continue
            if not math.isfinite(self.deadband_gains[c]):
                continue
            out.append(GainAgreement(channel, est, gains[c], self.deadband_gains[c], simulator[c]))
        return out

    def speed_limits(self) -> list[SpeedLimit]:
        """The channels where the base saturated (a top speed below what was commanded)."""
        if self.actuation is None:
            return []
        return [limit for limit in self.actuation.speed_limits if limit is not None and limit.saturated]

    def unidentified(self) -> dict[str, str]:
        """Dotted keys that the data cannot determine, with the reason."""
        return {k: e.reason for k, e in self.values.items() if not e.ok}

    def world_overrides(self) -> dict[str, dict[str, object]]:
        """Simulator settings (keys of ``pipeline.params.WorldConfig``) for training on top of params.yaml's ``world``.

        Only identified values appear; the simulated lidar gets the real beam count (its scan is reduced
        to the policy's beams as the real one is) and sees the real robot bodies.
        """
        out: dict[str, dict[str, object]] = {}

        def put(group: str, key: str, source: str) -> None:
            est = self.simulator_estimate(source)
            if est is not None and est.ok and est.value is not None:
                out.setdefault(group, {})[key] = round(est.value) if key == "sim_beams" else six_digits(est.value)

        def put_physical(source: str) -> None:
            group, key = PHYSICAL_KEYS[source].split(".")
            put(group, key, source)

        for source in PHYSICAL_KEYS:
            if source.startswith("lidar."):
                put_physical(source)
        per_m = self.values.get("lidar.noise_per_m")
        if per_m is not None and per_m.ok and per_m.value is not None:
            out.setdefault("lidar", {})["noise_per_m"] = six_digits(min(max(per_m.value, 0.0), 0.2))
        mount = [self.values.get(f"lidar.mount_xy_m[{i}]") for i in range(2)]
        if all(m is not None and m.ok and m.value is not None for m in mount):
            xy = [six_digits(m.value) for m in mount if m and m.value is not None]
            out.setdefault("lidar", {})["mount_xy_m"] = xy
        put("lidar", "sim_beams", "lidar.beams")
        for key in REAL_LIDAR_KEYS:  # what real lidars add, so the calibrated round trains with it: ok ones only
            est = self.values.get(f"lidar.{key}")
            if est is not None and est.status == "ok":
                put("lidar", key, f"lidar.{key}")
        if self.lidar is not None and self.lidar.no_return is not None:
            out.setdefault("lidar", {})["no_return"] = self.lidar.no_return
        if "lidar" in out:
            out["lidar"]["robot_radius_seen_m"] = 0.0
        for source in PHYSICAL_KEYS:
            if source.startswith("actuation."):
                put_physical(source)
        gains = self.simulator_gains()
        if gains is not None:
            for c, name in enumerate(("linear_gain", "angular_gain")):
                if self.actuation is None or not self.actuation.ambiguous_gain(c):  # a limit's reading is kept there
                    out.setdefault("actuation", {})[name] = six_digits(gains[c])
        arc = self.arc_per_m()
        if arc is not None:
            out.setdefault("actuation", {})["yaw_rate_per_mps"] = six_digits(arc)
        put_physical("base.deadband_radps")
        for limit in self.speed_limits():
            key = "max_linear_mps" if limit.channel == "linear" else "max_angular_radps"
            if limit.limit.value is not None:
                out.setdefault("actuation", {})[key] = six_digits(limit.limit.value)
        put_physical("odometry.drift_per_m")
        for key, source in NETWORK_SOURCES.items():
            put("network", key, source)  # within their ranges: the estimates are checked (within_physical_ranges)
        ranges = self.randomize_ranges()
        if ranges:
            out["randomize"] = dict(ranges)
        return out

    def randomize_ranges(self) -> dict[str, dict[str, list[float]]]:
        """Domain randomization for training on this calibration: each identified key is drawn from its 95 %
        interval, widened to at least `MIN_RANDOMIZE_HALF_WIDTH` of its value on each side (a model fitted to
        one lab's recording explains it only so well), kept inside the key's bounds. Keys left out keep
        params.yaml's ranges."""
        out: dict[str, dict[str, list[float]]] = {}
        for world_key, source in RANDOMIZED_SOURCES.items():
            est = self.simulator_estimate(source)
            if est is None or not est.ok or est.value is None or est.interval is None:
                continue
            lo, hi = est.interval
            value = est.value
            gains = self.simulator_gains()
            if gains is not None and world_key in ("actuation.linear_gain", "actuation.angular_gain"):
                # centred on the simulator's gain with the deadband, as wide as the body-velocity fit's interval
                value = gains[0] if world_key.endswith("linear_gain") else gains[1]
                lo, hi = value - (est.value - lo), value + (hi - est.value)
            half = MIN_RANDOMIZE_HALF_WIDTH * abs(value)
            lo, hi = min(lo, value - half), max(hi, value + half)
            group, name = world_key.split(".")
            low_bound, high_bound = world_bounds(world_key)
            fitted = self.randomization.ranges().get(name) if self.randomization and group == "actuation" else None
            if fitted is not None:  # widened to the spread that the recorded transitions ask for
                lo, hi = min(lo, fitted[0]), max(hi, fitted[1])
            lo, hi = max(lo, low_bound), min(hi, high_bound)
            # an interval below the bound: [b, b]
            out.setdefault(group, {})[name] = [six_digits(lo), six_digits(max(hi, lo))]
        arc = self.arc_per_m()
        if arc is not None:
            half = max(abs(arc) * MIN_RANDOMIZE_HALF_WIDTH, _arc_half_width(self.values, self.wheels))
            out.setdefault("actuation", {})["yaw_rate_per_mps"] = [six_digits(arc - half), six_digits(arc + half)]
        return out


def _checked_map(data: SessionData, map_file: str) -> PoseSource:
    """A map given for a recording with motion capture: checked against the scans at the captured poses, refused
    by name where they do not lie on it (another place, or another frame than the motion capture's)."""
    grid = OccupancyMap.from_map_server(map_file)
    scores = [
        map_agreement(grid, r.truth.time.t_ns, r.truth.pose, r.scans, r.lidar_mount)
        for r in data.robots
        if r.truth is not None and r.scans is not None and len(r.truth.pose) > 1
    ]
    scores = [s for s in scores if math.isfinite(s)]
    if not scores:
        raise CalibrationError(map_file, f"cannot be checked: {data.path} has no scans at its motion capture's poses")
    score = float(np.median(scores))
    if score < MIN_INLIERS:
        raise CalibrationError(
            map_file,
            f"not the room of {data.path}: at its motion capture's poses {100 * score:.0f} % of the scans' endpoints "
            f"lie on this map (need {100 * MIN_INLIERS:.0f} %); a map of another place, or in another frame than the "
            "motion capture's (poses come from the motion capture; the map is only checked)",
        )
    return PoseSource("ground_truth", Path(map_file).name, map_score=score)


def _localized(
    data: SessionData, settings: CalibrationSettings, floor: OccupancyMap | None = None
) -> tuple[SessionData, PoseSource]:
    """`data` with each robot's poses localized from its scans and odometry in the map (`floor` when already read)."""
    where = str(data.path)
    if floor is not None:
        grid = floor
    elif settings.map_file:
        grid = OccupancyMap.from_map_server(settings.map_file)
    else:
        grid = OccupancyMap.from_scenario(data.scenario)
    initial = np.asarray(settings.initial_pose, dtype=np.float64) if settings.initial_pose else None
    if initial is not None and len(data.robots) != 1:
        raise CalibrationError(where, f"an initial pose is for one robot; the recording has {len(data.robots)}")
    robots = []
    infos = []
    for robot in data.robots:
        mount = np.asarray(robot.lidar_mount if robot.lidar_mount is not None else (0.0, 0.0, 0.0))
        series, info = localize_robot(grid, robot, data.windows, mount, initial, where)
        robots.append(replace(robot, truth=series))
        infos.append(info)
    return replace(data, robots=tuple(robots)), PoseSource("localized", grid.source, tuple(infos))


@dataclass(frozen=True)
class DriveRecord:
    """What the drive fit reads from recordings: per recording its data (episodes, commands) and the robots'
    smoothed poses, and the contact-free velocity tracks pooled over them (what :func:`estimate_actuation` takes)."""

    sessions: tuple[SessionData, ...]
    trajectories: tuple[dict[str, Trajectory], ...]
    tracks: tuple[VelocityTrack, ...]


def drive_record(
    recordings: str | Path | Sequence[str | Path], settings: CalibrationSettings | None = None
) -> DriveRecord:
    """The drive fit's input from `recordings`, read as :func:`calibrate` reads them for its actuation part (for
    a benchmark that fits the same tracks with other achieved velocities, such as a reality's own drive replayed)."""
    settings = replace(settings or CalibrationSettings(), parts=("actuation",))
    paths = [recordings] if isinstance(recordings, (str, Path)) else list(recordings)
    read = _read_sessions(paths, settings.parts, settings)
    tagged = _tagged(read)
    data = gather(tagged, read.pose_sources, ("tracks",), settings, read.geometry)
    trajectories = tuple(
        smoothed_poses(d, settings, source) for (_, d), source in zip(tagged, read.pose_sources, strict=True)
    )
    return DriveRecord(tuple(read.sessions), trajectories, tuple(data.tracks))


def calibrate(
    recordings: str | Path | Sequence[str | Path],
    settings: CalibrationSettings | None = None,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """Estimate the reality profile from session recordings (MCAP) of one scenario: read them, gather the streams the
    wanted steps read (:mod:`pipeline.calibration.streams`), run the steps (:data:`pipeline.calibration.steps.STEPS`)
    and keep every estimate within its physical range.

    Args:
        recordings: one recording or several of the same scenario (and fleet); their data are pooled.
        settings: what to estimate and how (defaults: every part, the recordings' scenario).
        progress: told each stage as it starts, with the seconds so far (``"lidar (12 s)"``).

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
    began = time.perf_counter()

    def stage(what: str) -> None:
        if progress is not None:
            progress(f"{what} ({time.perf_counter() - began:.0f} s)")

    stage(f"reading {len(paths)} recording{'s' if len(paths) != 1 else ''}")
    read = _read_sessions(paths, parts, settings)
    tagged = _tagged(read)
    steps = wanted(parts)
    data = gather(tagged, read.pose_sources, {name for step in steps for name in step.reads}, settings, read.geometry)
    ctx = Context(read, tagged, data, settings, rng)
    for step in steps:
        stage(step.label)
        step.run(ctx)
    values = finish(ctx.values)
    stage("done")
    found = ctx.found
    calibration = Calibration(
        read.scenario.name,
        _sources(read.sessions),
        values,
        found.lidar,
        found.actuation,
        found.odometry,
        found.network,
        settings,
        wheels=found.wheels,
        clock=found.clock,
        motors=found.motors,
        randomization=found.randomization,
        pose_source=_merged(read.pose_sources),
        effective=ctx.effective,
    )
    gains, deadband = calibration.body_gains(), values.get("base.deadband_radps")
    if gains is None or deadband is None or deadband.value is None:
        return calibration
    fitted = (_fitted_gain(values.get("actuation.linear_gain")), _fitted_gain(values.get("actuation.angular_gain")))
    return replace(
        calibration,
        deadband_gains=deadband_gains(data.tracks, gains, deadband.value, settings.command_timeout_s),
        drive_gains=drive_gains(data.tracks, fitted, gains, deadband.value, settings.command_timeout_s),
    )


def _fitted_gain(est: Estimate | None) -> float:
    """The body-velocity fit's gain where it is identified, else NaN (the wheel chain's stands)."""
    return float(est.value) if est is not None and est.ok and est.value is not None else math.nan


def _tagged(read: Sessions) -> list[tuple[str, SessionData]]:
    """Each recording with the tag its streams carry ("recording", or "recording k" of several)."""
    return [(f"recording {k}" if len(read.sessions) > 1 else "recording", d) for k, d in enumerate(read.sessions)]


def _read_sessions(
    paths: Sequence[str | Path],
    parts: tuple[Part, ...],
    settings: CalibrationSettings,
    before_localizing: Callable[[SessionData], None] | None = None,
) -> Sessions:
    """Read every recording (one scenario; poolable, checked before any long work) and localize the ones without
    motion capture. A map given without a scenario (a building of the user's) stands in for a recording that names
    none, and the lidar and contacts are fitted against the map's own faces."""
    expected = settings.scenario or None
    sessions: list[SessionData] = []
    scenario: Scenario | None = None
    pose_sources: list[PoseSource] = []
    floor = OccupancyMap.from_map_server(settings.map_file) if settings.map_file and not expected else None
    fallback = floor.scenario(f"map {Path(settings.map_file).name}", 1) if floor is not None else None
    for path in paths:
        data = read_session(
            path, parts, expected if scenario is None else scenario, settings.pose_source, fallback=fallback
        )
        if scenario is not None and data.scenario.name != scenario.name:
            raise ScenarioMismatchError(str(path), data.scenario.name, scenario.name)
        scenario = data.scenario
        check_poolable([*sessions[:1], data], settings.pool)  # before any long work
        if before_localizing is not None:
            before_localizing(data)
        if data.pose_source == "scans":
            data, source = _localized(data, settings, floor)
        elif settings.map_file and scenario is not fallback:
            source = _checked_map(data, settings.map_file)
        else:
            source = PoseSource("ground_truth")
        sessions.append(data)
        pose_sources.append(source)
    if scenario is None:
        raise CalibrationError("<calibrate>", "no recording given")
    geometry = (
        floor.geometry(float(scenario.radii.max()))
        if floor is not None and scenario is fallback
        else MapGeometry.from_scenario(scenario)
    )
    return Sessions(sessions, pose_sources, scenario, geometry)


def localized_recordings(
    recordings: Sequence[str | Path],
    map_file: str | Path,
    scenario: str = "",
    initial_pose: Sequence[float] = (),
    before_localizing: Callable[[SessionData], None] | None = None,
) -> tuple[list[SessionData], Scenario]:
    """The recordings as calibration reads them for their drive (commands, scans, odometry), each robot's poses
    localized in the map_server map `map_file` where the recording has no motion capture; and the scenario they
    drove in (the map's stand-in room when none is named); `initial_pose` as for calibration. `before_localizing`
    sees each recording as read, before the long localization (it raises to stop)."""
    settings = CalibrationSettings(
        map_file=str(map_file), parts=("actuation",), scenario=scenario, initial_pose=tuple(initial_pose)
    )
    read = _read_sessions(recordings, ("actuation",), settings, before_localizing)
    return read.sessions, read.scenario


def _sources(sessions: list[SessionData]) -> tuple[Source, ...]:
    return tuple(
        Source(
            str(d.path),
            dict(d.session.fields),
            len(d.episodes),
            d.kind,
            tuple(r.name for r in d.robots),
            _sha256(d.path),
            d.salvage,
        )
        for d in sessions
    )


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def check_poolable(sessions: Sequence[SessionData], pool: bool) -> None:
    """Refuse to pool recordings of different kinds (sim, twin, real) or of different robots unless `pool`."""
    if pool or len(sessions) < 2:
        return
    first = sessions[0]
    robots = tuple(r.name for r in first.robots)
    for other in sessions[1:]:
        if other.kind != first.kind:
            raise CalibrationError(
                str(other.path),
                f"a {other.kind} recording, but {first.path} is a {first.kind} recording: pooling them would mix "
                "two worlds into one estimate; calibrate them apart, or pool them on purpose (--pool)",
            )
        theirs = tuple(r.name for r in other.robots)
        if theirs != robots:
            raise CalibrationError(
                str(other.path),
                f"robots {', '.join(theirs)}, but {first.path} has {', '.join(robots)}: pooling them would mix "
                "different robots into one estimate; calibrate them apart, or pool them on purpose (--pool)",
            )


def _merged(sources: Sequence[PoseSource]) -> PoseSource:
    """One account of the recordings' pose sources: localized if any was, with every localized robot."""
    localized = [s for s in sources if s.kind == "localized"]
    if not localized:
        checked = [s for s in sources if s.map]
        return checked[0] if checked else PoseSource("ground_truth")
    maps = sorted({s.map for s in localized})
    return PoseSource("localized", ", ".join(maps), tuple(r for s in localized for r in s.robots))
