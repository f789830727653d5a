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

import contextlib
import dataclasses
import hashlib
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.calibration.actuation import ActuationFit, CommandTimeline, SpeedLimit, VelocityTrack, estimate_actuation
from pipeline.calibration.clock import ClockFit, estimate_clock
from pipeline.calibration.errors import CalibrationError, ScenarioMismatchError
from pipeline.calibration.estimates import Estimate, six_digits
from pipeline.calibration.floor import estimate_floor
from pipeline.calibration.gains import GainAgreement, deadband_gains
from pipeline.calibration.lidar import LidarFit, ScanSpan, estimate_lidar, stationary_spans
from pipeline.calibration.localize import MIN_INLIERS, OccupancyMap, PoseSource, localize_robot, map_agreement
from pipeline.calibration.motors import MotorFit, WheelEpisode, estimate_motors, wheel_speeds
from pipeline.calibration.network import (
    NetworkFit,
    StampStream,
    estimate_network,
    rate_estimate,
    rate_wander_estimate,
)
from pipeline.calibration.odometry import OdometryEpisode, OdometryFit, estimate_odometry
from pipeline.calibration.options import CalibrationSettings, Part
from pipeline.calibration.randomization import RandomizationFit, fit_randomization
from pipeline.calibration.raycast import MapGeometry
from pipeline.calibration.recording import SessionData, read_session
from pipeline.calibration.smoothing import SmootherNoise, Trajectory, smooth_trajectory
from pipeline.calibration.wheels import NOMINAL_WHEEL_RADIUS_M, NOMINAL_WHEEL_SEPARATION_M, WheelFit, estimate_wheels
from pipeline.core.reality import bounds_of, profile_setting
from pipeline.core.scenario import Scenario
from pipeline.core.timebase import NS_PER_S
from pipeline.mappings import bounds_text, in_bounds
from pipeline.params import WorldConfig

LIDAR_FIT_KEYS = ("noise_sigma_m", "dropout_prob", "bias_m", "mount_yaw_rad", "noise_per_m")
PROFILE_KEYS: dict[str, tuple[str, ...]] = {
    "lidar": (
        "beams",
        "rate_hz",
        *LIDAR_FIT_KEYS,
        "range_step_m",
        "beam_noise_spread",
        "mixed_pixel_prob",
        "beam_angle_jitter_rad",
        "rate_wander",
        "scan_drop_prob",
    ),
    "actuation": ("delay_s", "time_constant_s", "linear_gain", "angular_gain"),
    "odometry": ("rate_hz", "drift_per_m"),
    "network": ("loss_prob", "jitter_s", "burst_len"),
    "base": (
        "wheel_radius_left_m",
        "wheel_radius_right_m",
        "wheel_separation_m",
        "deadband_radps",
        "max_wheel_accel_radps2",
        "motor_time_constant_s",
        "friction",
    ),
    "clock": ("offset_s", "drift_ppm"),
    "map": ("wall_offset_m",),
}
"""The reality profile's scalar keys, in its order. Pairs are estimated per component, as
``lidar.mount_xy_m[0]`` and ``map.box_offsets_m[k][1]`` (see :func:`split_key`)."""


MIN_RANDOMIZE_HALF_WIDTH = 0.1
"""Training on a calibration draws each identified key within at least +-10 % of its value."""
NETWORK_SOURCES: dict[str, str] = {
    "scan_rate_hz": "lidar.rate_hz",
    "odom_rate_hz": "odometry.rate_hz",
    "loss_prob": "network.loss_prob",
    "burst_len": "network.burst_len",
    "jitter_s": "network.jitter_s",
    "clock_offset_s": "clock.offset_s",
    "clock_drift_ppm": "clock.drift_ppm",
}
"""The simulator's network keys (``world.network``) and the estimates they take: the rates at which scans and odometry
arrive, how they are lost and jittered, and the robots' clock; the calibrated round trains on them, randomized
within their intervals (the clock keys, which move only the sensors' stamps, at their values). Calibrated ranges are
kept inside the bounds of their simulator setting (:func:`world_bounds`)."""


PHYSICAL_KEYS: dict[str, str] = {
    **{f"lidar.{k}": f"lidar.{k}" for k in ("noise_sigma_m", "dropout_prob", "bias_m", "mount_yaw_rad")},
    **{f"actuation.{k}": f"actuation.{k}" for k in ("delay_s", "time_constant_s", "linear_gain", "angular_gain")},
    "odometry.drift_per_m": "odometry.drift_per_m",
    "base.deadband_radps": "actuation.deadband_radps",
    "base.wheel_radius_left_m": "actuation.wheel_radius_m",
    "base.wheel_radius_right_m": "actuation.wheel_radius_m",
    "base.wheel_separation_m": "actuation.wheel_separation_m",
}
"""Estimates that become simulator settings, and the setting (``world.<key>``) they become: an estimate's physical
range is the reality profile's bounds of its key within that setting's (:func:`physical_ranges`;
``lidar.noise_per_m``, which reads slightly negative where noise does not grow with range, is drawn at 0 instead)."""


def _setting_meta(world_key: str) -> Mapping[str, Any]:
    """The metadata (bounds) of the simulator setting ``world.<world_key>``, e.g. ``network.loss_prob``."""
    group, name = world_key.split(".")
    return next(f.metadata for f in fields(getattr(WorldConfig(), group)) if f.name == name)


def world_bounds(world_key: str) -> tuple[float, float]:
    """(low, high) of the simulator setting ``world.<world_key>`` (open ends as infinities, an exclusive bound as the
    nearest float inside it)."""
    return bounds_of(_setting_meta(world_key))


def physical_ranges(key: str, world_key: str) -> list[Mapping[str, Any]]:
    """The bounds estimate `key` must keep: the reality profile's of the key (what a robot can have) and the simulator
    setting's it becomes (the setting's alone for a key the profile does not have)."""
    ranges = [_setting_meta(world_key)]
    with contextlib.suppress(KeyError):
        ranges.append(profile_setting(key).metadata)
    return ranges


def within_physical_ranges(values: dict[str, Estimate]) -> dict[str, Estimate]:
    """`values` with every estimate that lies outside its physical range, or whose 95 % interval is wider than that
    range, made unidentifiable, the reason carrying the raw figure: what the data cannot show is not a setting (the
    simulator keeps its nominal value), and the other keys stand."""
    out = dict(values)
    for key, world_key in {**PHYSICAL_KEYS, **{v: f"network.{k}" for k, v in NETWORK_SOURCES.items()}}.items():
        est = out.get(key)
        if est is None or not est.ok or est.value is None:
            continue
        ranges = physical_ranges(key, world_key)
        low = max(bounds_of(m)[0] for m in ranges)
        high = min(bounds_of(m)[1] for m in ranges)
        raw = f"{est.value:.6g} {est.unit}".strip()
        allowed = " and ".join(dict.fromkeys(bounds_text(m) for m in ranges))
        if not all(in_bounds(est.value, m) for m in ranges):
            reason = f"the estimate {raw} lies outside its physical range ({allowed})"
        elif est.interval is not None and est.interval[1] - est.interval[0] > high - low:
            reason = f"the estimate {raw} has a 95 % interval wider than its whole physical range ({allowed})"
        else:
            continue
        out[key] = Estimate.unidentifiable(f"{reason}: the data cannot show it", est.unit, est.n)
    return out


def arc_per_m(values: dict[str, Estimate]) -> float | None:
    """Yaw rate (rad/s) per m/s that unequal wheels add to a straight command: (r_right - r_left) / (r_nominal b).

    None unless both radii and the separation are identified."""
    keys = ("base.wheel_radius_left_m", "base.wheel_radius_right_m", "base.wheel_separation_m")
    est = [values.get(k) for k in keys]
    if not all(e is not None and e.ok and e.value is not None for e in est):
        return None
    left, right, sep = (float(e.value) for e in est if e is not None and e.value is not None)
    return (right - left) / (NOMINAL_WHEEL_RADIUS_M * sep)


def _arc_half_width(values: dict[str, Estimate], wheels: WheelFit | None = None) -> float:
    """Half-width of the arc per metre: its own interval from the wheel fit where there is one (the radii's
    common errors cancel in it), else over the corners of the wheel radii's and separation's intervals."""
    own = wheels.arc_per_m if wheels is not None else None
    if own is not None and own.ok and own.interval is not None:
        return (own.interval[1] - own.interval[0]) / 2
    ivs = [
        values[k].interval for k in ("base.wheel_radius_left_m", "base.wheel_radius_right_m", "base.wheel_separation_m")
    ]
    if any(i is None for i in ivs):
        return 0.0
    corners = [
        (right - left) / (NOMINAL_WHEEL_RADIUS_M * b)
        for left in ivs[0] or ()
        for right in ivs[1] or ()
        for b in ivs[2] or ()
    ]
    return (max(corners) - min(corners)) / 2


def split_key(key: str) -> tuple[str, str, tuple[int, ...]]:
    """(group, name, indices) of a dotted estimate key.

    ``map.box_offsets_m[1][0]`` is ("map", "box_offsets_m", (1, 0)).
    """
    group, rest = key.split(".", 1)
    name, _, tail = rest.partition("[")
    indices = tuple(int(i) for i in ("[" + tail).replace("]", "").split("[")[1:]) if tail else ()
    return group, name, indices


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
class EffectiveValue:
    """A value of the simulator's model that stands for several properties of the robot together: what it is, the
    profile keys it stands for, and the model it belongs to (never written under one of those keys)."""

    estimate: Estimate
    stands_for: tuple[str, ...]
    model: str

    def as_mapping(self) -> dict[str, Any]:
        return {**self.estimate.as_mapping(), "stands_for": list(self.stands_for), "model": self.model}


DRIVE_MODEL = (
    "the simulator's drive: a pure delay, then one first-order lag on the commanded body velocity "
    "(world.actuation.delay_s, time_constant_s)"
)
EFFECTIVE_DRIVE: dict[str, tuple[str | None, tuple[str, ...], str]] = {
    "drive_delay_s": ("actuation.delay_s", ("actuation.delay_s",), "world.actuation.delay_s"),
    "drive_lag_s": (
        "actuation.time_constant_s",
        ("actuation.time_constant_s", "base.motor_time_constant_s", "base.max_wheel_accel_radps2"),
        "world.actuation.time_constant_s",
    ),
    "drive_response_s": (
        None,
        ("actuation.delay_s", "actuation.time_constant_s", "base.motor_time_constant_s"),
        "delay + lag of the simulator's drive: the mean time a command takes to act",
    ),
}
"""The drive chain's effective values: (the profile key whose simulator setting takes it, None for a quantity no setting
takes; the profile keys it stands for; the simulator's setting or quantity). A robot's body velocity follows its
commands through the driver's delay and lag, the motors' own lag and their acceleration limit in series; the
body-velocity fit sees the chain as the simulator models it."""
EFFECTIVE_REASON = (
    "not measured apart: the body velocity follows the commands through the driver's and the motors' lags in series "
    "(and their acceleration limit); the chain's effective value, which the simulator takes, is effective.{name}"
)


REAL_LIDAR_KEYS = ("range_step_m", "beam_noise_spread", "mixed_pixel_prob", "scan_drop_prob")
"""What real lidars have that the simulator adds only when told. Each enters the calibrated world only where its
estimate is ``ok``: a ``weak`` one (an interval wider than its value) is left out, the simulator keeps params.yaml's
value. Measured on the lab twin (no mixed pixels): a weak mixed-pixel estimate (0.037 [0.021, 0.081]) in the
calibrated world trained policies that collided at a box corner on the twin in two trainings of two (robot success
0.673, 0.667), and without it 1.000 (benchmarks/results/loop/lab_checks/)."""


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

    def gain_agreement(self) -> list[GainAgreement]:
        """Per channel, the body-velocity fit's gain beside the gain the simulator's drive (the wheel chain's gain
        with the deadband) shows over the same commands: the two readings of one robot, reconciled or not."""
        gains = self.body_gains()
        if gains is None or self.deadband_gains is None:
            return []
        out = []
        for c, channel in enumerate(("linear", "angular")):
            est = self.values.get(f"actuation.{channel}_gain")
            if est is None or not est.ok or est.value is None or est.interval is None:
                continue
            if not math.isfinite(self.deadband_gains[c]):
                continue
            out.append(GainAgreement(channel, est, gains[c], self.deadband_gains[c]))
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

        for key in ("noise_sigma_m", "dropout_prob", "bias_m", "mount_yaw_rad"):
            put("lidar", key, f"lidar.{key}")
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
        for key in PROFILE_KEYS["actuation"]:
            put("actuation", key, f"actuation.{key}")
        gains = self.body_gains()
        if gains is not None:
            for c, name in enumerate(("linear_gain", "angular_gain")):
                if self.actuation is None or not self.actuation.ambiguous_gain(c):  # a limit's reading is kept there
                    out.setdefault("actuation", {})[name] = six_digits(gains[c])
        arc = self.arc_per_m()
        if arc is not None:
            out.setdefault("actuation", {})["yaw_rate_per_mps"] = six_digits(arc)
        put("actuation", "deadband_radps", "base.deadband_radps")
        for limit in self.speed_limits():
            key = "max_linear_mps" if limit.channel == "linear" else "max_angular_radps"
            if limit.limit.value is not None:
                out.setdefault("actuation", {})[key] = six_digits(limit.limit.value)
        put("odometry", "drift_per_m", "odometry.drift_per_m")
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
        sources = {f"lidar.{k}": f"lidar.{k}" for k in ("noise_sigma_m", "noise_per_m", "dropout_prob", "bias_m")}
        sources["lidar.mount_yaw_rad"] = "lidar.mount_yaw_rad"
        sources.update({f"actuation.{k}": f"actuation.{k}" for k in PROFILE_KEYS["actuation"]})
        sources["odometry.drift_per_m"] = "odometry.drift_per_m"
        sources["actuation.deadband_radps"] = "base.deadband_radps"
        sources.update({f"network.{k}": v for k, v in NETWORK_SOURCES.items() if not k.startswith("clock_")})
        for world_key, source in sources.items():
            est = self.simulator_estimate(source)
            if est is None or not est.ok or est.value is None or est.interval is None:
                continue
            lo, hi = est.interval
            value = est.value
            gains = self.body_gains()
            if gains is not None and world_key in ("actuation.linear_gain", "actuation.angular_gain"):
                # centred on the wheel chain's gain, as wide as the body-velocity fit's interval
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


def _trajectories(
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


MOVING_SCANS_PER_ROBOT = 600
"""Scans while driving read per robot and recording for the noise (evenly over its driving; more add little)."""


def _moving_scans(
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
        others = _others(data, trajectories, robot.name, t[sel])
        for j, i in enumerate(sel):
            if not np.all(np.isfinite(pose[j])):
                continue
            angles = scans.angle_min_rad[i] + scans.angle_increment_rad[i] * np.arange(scans.beams)
            out.append(
                ScanSpan(
                    robot.name,
                    f"{tag}/{robot.name}/episode {_episode_of(data, int(t[i]))}",
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


def _velocity_tracks(
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


def _wheel_episodes(tag: str, data: SessionData, tracks: Sequence[VelocityTrack]) -> list[WheelEpisode]:
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


def _odometry_period_s(stamps: Sequence[np.ndarray]) -> float:
    """The odometry's period (s): the median step of its stamps."""
    diffs = [np.diff(np.asarray(s, dtype=np.int64)) for s in stamps if len(s) > 1]
    steps = np.concatenate(diffs) if diffs else np.zeros(0, dtype=np.int64)
    steps = steps[steps > 0]
    return float(np.median(steps)) / NS_PER_S if len(steps) else 0.025


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
        truth = robot.truth if data.pose_source == "ground_truth" else None  # localized poses ride on odom's stamps
        times = [(f"/{robot.name}/{kind}", s.time) for kind, s in (("ground_truth", truth), ("odom", robot.odom)) if s]
        if robot.scans is not None:
            times.append((f"/{robot.name}/scan", robot.scans.time))
        out += [StampStream(f"{tag} {topic}", t.stamp_ns, t.log_ns, windows) for topic, t in times]
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
    tagged = [(f"recording {k}" if len(read.sessions) > 1 else "recording", d) for k, d in enumerate(read.sessions)]
    data = _gather(tagged, read.pose_sources, settings.parts, settings, read.geometry)
    trajectories = tuple(
        _trajectories(d, settings, source) for (_, d), source in zip(tagged, read.pose_sources, strict=True)
    )
    return DriveRecord(tuple(read.sessions), trajectories, tuple(data.tracks))


def calibrate(
    recordings: str | Path | Sequence[str | Path],
    settings: CalibrationSettings | None = None,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """Estimate the reality profile from session recordings (MCAP) of one scenario.

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
    tagged = [(f"recording {k}" if len(read.sessions) > 1 else "recording", d) for k, d in enumerate(read.sessions)]
    data = _gather(tagged, read.pose_sources, parts, settings, read.geometry)
    values: dict[str, Estimate] = {}
    effective: dict[str, EffectiveValue] = {}
    found = _Fits()
    if "lidar" in parts:
        stage("lidar")
        found.lidar = estimate_lidar(read.geometry, data.spans, settings, rng, data.moving)
        values.update(_lidar_values(found.lidar, data))
        if any(s.kind == "localized" for s in read.pose_sources):
            values.update(_localized_lidar_values(values, read.sessions))
    if "actuation" in parts:
        stage("actuation")
        found.actuation = estimate_actuation(data.tracks, settings, rng)
        values.update({f"actuation.{key}": getattr(found.actuation, key) for key in PROFILE_KEYS["actuation"]})
        values = within_physical_ranges(values)
        effective = _effective_drive(found.actuation, values)
        for name in effective:
            key = EFFECTIVE_DRIVE[name][0]
            if key is not None and values[key].ok:
                values[key] = Estimate.unidentifiable(EFFECTIVE_REASON.format(name=name), values[key].unit)
    if "odometry" in parts:
        stage("odometry and wheels")
        found.wheels, found.odometry = _odometry_fits(values, data, read.sessions, settings)
    if "odometry" in parts and "actuation" in parts:
        stage("motors")
        wheel_episodes = [e for tag, d in tagged for e in _wheel_episodes(tag, d, data.tracks)]
        found.motors = estimate_motors(wheel_episodes, _odometry_period_s(data.odom_stamps), settings, rng)
        values["base.deadband_radps"] = found.motors.deadband_radps
        values["base.max_wheel_accel_radps2"] = found.motors.max_wheel_accel_radps2
        values["base.motor_time_constant_s"] = found.motors.motor_time_constant_s
        # the drive as the robot has it, read at the wheels: the driver's delay and lag where the transients tell them
        for key, est in (
            ("actuation.delay_s", found.motors.delay_s),
            ("actuation.time_constant_s", found.motors.driver_time_constant_s),
        ):
            if est.ok:
                values[key] = est
    if "actuation" in parts:
        stage("randomization ranges")
        found.randomization = _fitted_randomization(
            _randomization_start(values, effective, found.actuation), data.tracks, settings
        )
    if "network" in parts:
        stage("network and clock")
        found.network, found.clock = _network_fits(values, data.streams, tagged, read.sessions, settings, rng)
    for key in ("lidar.rate_hz", "odometry.rate_hz"):
        if key in values:
            values[key] = _host_rate(values[key], values.get("clock.drift_ppm"))
    values = within_physical_ranges(values)
    values = {key: _flag_weak(key, est) for key, est in values.items()}
    stage("done")
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
        effective=effective,
    )
    gains, deadband = calibration.body_gains(), values.get("base.deadband_radps")
    if gains is None or deadband is None or deadband.value is None:
        return calibration
    return replace(
        calibration,
        deadband_gains=deadband_gains(data.tracks, gains, deadband.value, settings.command_timeout_s),
    )


@dataclass
class _Sessions:
    """The recordings as read (poses localized where they come from scans), their scenario and the map's geometry."""

    sessions: list[SessionData]
    pose_sources: list[PoseSource]
    scenario: Scenario
    geometry: MapGeometry


@dataclass
class _Gathered:
    """What each part's estimator reads, pooled over the recordings."""

    spans: list[ScanSpan] = field(default_factory=list)
    moving: list[ScanSpan] = field(default_factory=list)
    """One per scan while driving (:func:`_moving_scans`)."""
    tracks: list[VelocityTrack] = field(default_factory=list)
    episodes: list[OdometryEpisode] = field(default_factory=list)
    streams: list[StampStream] = field(default_factory=list)
    scan_stamps: list[np.ndarray] = field(default_factory=list)
    odom_stamps: list[np.ndarray] = field(default_factory=list)
    beams: list[int] = field(default_factory=list)


@dataclass
class _Fits:
    """Each part's fit, None where the part was not asked for."""

    lidar: LidarFit | None = None
    actuation: ActuationFit | None = None
    odometry: OdometryFit | None = None
    network: NetworkFit | None = None
    wheels: WheelFit | None = None
    clock: ClockFit | None = None
    motors: MotorFit | None = None
    randomization: RandomizationFit | None = None


def _read_sessions(
    paths: Sequence[str | Path],
    parts: tuple[Part, ...],
    settings: CalibrationSettings,
    before_localizing: Callable[[SessionData], None] | None = None,
) -> _Sessions:
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
    return _Sessions(sessions, pose_sources, scenario, geometry)


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


def _gather(
    tagged: list[tuple[str, SessionData]],
    pose_sources: list[PoseSource],
    parts: tuple[Part, ...],
    settings: CalibrationSettings,
    geometry: MapGeometry,
) -> _Gathered:
    """The scan spans, velocity tracks, odometry episodes and stamp streams of every recording, for the parts asked."""
    out = _Gathered()
    for (tag, data), source in zip(tagged, pose_sources, strict=True):
        trajectories = _trajectories(data, settings, source)
        if "lidar" in parts:
            out.spans += _scan_spans(tag, data, trajectories, settings)
            out.moving += _moving_scans(tag, data, trajectories, settings)
            for robot in data.robots:
                if robot.scans is not None and len(robot.scans.ranges):
                    out.beams.append(robot.scans.beams)
                    out.scan_stamps.append(robot.scans.time.stamp_ns)
        if "actuation" in parts:
            out.tracks += _velocity_tracks(tag, data, trajectories, geometry, settings)
        if "odometry" in parts:
            out.episodes += _odometry_episodes(tag, data, trajectories)
            out.odom_stamps += [r.odom.time.stamp_ns for r in data.robots if r.odom is not None]
        if "network" in parts:
            out.streams += _network_streams(tag, data)
    return out


def _lidar_values(lidar: LidarFit, data: _Gathered) -> dict[str, Estimate]:
    """The lidar's and the map's keys from the lidar fit, the beam count and the scans' rate."""
    values: dict[str, Estimate] = {}
    if data.beams:
        counts = np.bincount(data.beams)
        values["lidar.beams"] = Estimate.of(
            float(counts.argmax()), 0.0, None, "beams", "beam count of the scans", len(data.beams)
        )
    else:
        values["lidar.beams"] = Estimate.unidentifiable("no scan recorded", "beams")
    values["lidar.rate_hz"] = rate_estimate(data.scan_stamps)
    values["lidar.rate_wander"] = rate_wander_estimate(data.scan_stamps)
    for key in (*LIDAR_FIT_KEYS, "range_step_m", "beam_noise_spread", "mixed_pixel_prob"):
        values[f"lidar.{key}"] = getattr(lidar, key)
    values["lidar.beam_angle_jitter_rad"] = Estimate.unidentifiable(
        "a beam a few milliradians off its stated angle moves its range by range x tan(incidence) x the error: below "
        "the noise except at grazing incidence, and grazing beams are left out",
        "rad",
    )
    values["lidar.mount_xy_m[0]"] = lidar.mount_x_m
    values["lidar.mount_xy_m[1]"] = lidar.mount_y_m
    values["map.wall_offset_m"] = lidar.wall_offset_m
    for b, (dx, dy) in enumerate(lidar.box_offsets_m):
        values[f"map.box_offsets_m[{b}][0]"] = dx
        values[f"map.box_offsets_m[{b}][1]"] = dy
    return values


def _localized_lidar_values(values: dict[str, Estimate], sessions: list[SessionData]) -> dict[str, Estimate]:
    """What poses localized from the same scans cannot tell apart: the mounting (given by /tf_static where the
    recording has it) and a range bias against walls standing farther out."""
    out: dict[str, Estimate] = {}
    mounts = [r.lidar_mount for d in sessions for r in d.robots]
    keys = ("lidar.mount_xy_m[0]", "lidar.mount_xy_m[1]", "lidar.mount_yaw_rad")
    if all(m is not None for m in mounts):
        # the robot description's mounting, used by the localization: given, not estimated
        given = np.array(mounts, dtype=np.float64).mean(axis=0)
        for k, key in enumerate(keys):
            v = float(given[k])
            out[key] = Estimate.of(v, 0.0, (v, v), values[key].unit, "from /tf_static", len(mounts))
    else:
        reason = (
            "the poses were localized from the same scans (a mounting offset moves the localized pose with "
            "it) and the recording has no /tf_static base_link -> laser transform"
        )
        for key in keys:
            out[key] = Estimate.unidentifiable(reason, values[key].unit)
    bias, wall = values["lidar.bias_m"], values["map.wall_offset_m"]
    total = (
        f" (together they read {bias.value + wall.value:+.4f} m)"
        if bias.ok and wall.ok and bias.value is not None and wall.value is not None
        else ""
    )
    reason = (
        "from poses localized in the map, a range bias and walls standing farther out read the same "
        f"(the localized pose cannot move away from every wall at once){total}"
    )
    for key in ("lidar.bias_m", "map.wall_offset_m"):
        out[key] = Estimate.unidentifiable(reason, values[key].unit)
    return out


def _effective_drive(actuation: ActuationFit, values: dict[str, Estimate]) -> dict[str, EffectiveValue]:
    """The drive chain's delay, lag and response time as the simulator's model takes them (checked against the
    simulator's ranges: outside them, not a setting)."""
    out: dict[str, EffectiveValue] = {}
    for name, (setting_of, stands_for, model) in EFFECTIVE_DRIVE.items():
        estimate = values[setting_of] if setting_of is not None else actuation.response_s
        out[name] = EffectiveValue(estimate, stands_for, f"{model}; {DRIVE_MODEL}")
    return out


def _randomization_start(
    values: dict[str, Estimate], effective: dict[str, EffectiveValue], actuation: ActuationFit | None
) -> dict[str, Estimate]:
    """The estimates the domain randomization's fit starts from: the simulator's drive values (the effective delay
    and lag, the gains) with their bootstrap standard errors, before the misfit widens them."""
    out = dict(values)
    for name, value in effective.items():
        setting_of = EFFECTIVE_DRIVE[name][0]
        if setting_of is not None:
            out[setting_of] = value.estimate
    if actuation is not None:
        for name, se in actuation.bootstrap_se.items():
            key = f"actuation.{name}"
            if key in out and out[key].ok:
                out[key] = replace(out[key], std_error=se)
    return out


def _odometry_fits(
    values: dict[str, Estimate], data: _Gathered, sessions: list[SessionData], settings: CalibrationSettings
) -> tuple[WheelFit, OdometryFit]:
    """The wheels and the odometry's drift (what the simulator must still draw beyond the unequal wheels' arc), into
    `values`."""
    values["odometry.rate_hz"] = rate_estimate(data.odom_stamps)
    wheels = estimate_wheels(data.episodes, settings)
    values["base.wheel_radius_left_m"] = wheels.radius_left_m
    values["base.wheel_radius_right_m"] = wheels.radius_right_m
    values["base.wheel_separation_m"] = wheels.separation_m
    odometry = estimate_odometry(data.episodes, settings, arc_per_m(values) or 0.0)
    radii = (wheels.radius_left_m, wheels.radius_right_m)
    scale = (
        sum(float(r.value) for r in radii if r.value is not None) / (2 * NOMINAL_WHEEL_RADIUS_M)
        if all(r.ok and r.value is not None for r in radii)
        else 1.0
    )
    values["base.friction"] = estimate_floor(data.episodes, scale).friction
    inferred = tuple(note for d in sessions for note in d.notes)
    odometry = replace(odometry, notes=inferred + odometry.notes)
    values["odometry.drift_per_m"] = odometry.drift_per_m
    return wheels, odometry


def _fitted_randomization(
    values: dict[str, Estimate], tracks: list[VelocityTrack], settings: CalibrationSettings
) -> RandomizationFit | None:
    """The spread of the drive's parameters that the recorded transitions ask for (long tracks only)."""
    long_tracks = [t for t in tracks if t.duration_s >= settings.actuation_min_track_s]
    deadband = values.get("base.deadband_radps")
    known = deadband is not None and deadband.ok and deadband.value is not None
    return fit_randomization(
        long_tracks,
        values,
        settings.command_timeout_s,
        settings.seed,
        float(deadband.value) if known and deadband is not None and deadband.value is not None else 0.0,
        arc_per_m(values) or 0.0,
    )


def _network_fits(
    values: dict[str, Estimate],
    streams: list[StampStream],
    tagged: list[tuple[str, SessionData]],
    sessions: list[SessionData],
    settings: CalibrationSettings,
    rng: np.random.Generator,
) -> tuple[NetworkFit, ClockFit]:
    """Loss, bursts and jitter of the robots' messages and their clock, into `values`."""
    network = estimate_network(streams, settings, rng)
    scans = [s for s in streams if s.topic.endswith("/scan")]
    others = [s for s in streams if not s.topic.endswith("/scan")]
    if scans and others:
        # a scan lost in the lidar's driver (USB) is a loss on the scan topics alone: the network's loss and bursts
        # come from the other topics, the scans' excess is the driver's
        wire = estimate_network(others, settings, rng)
        network = dataclasses.replace(network, loss_prob=wire.loss_prob, burst_len=wire.burst_len)
        values["lidar.scan_drop_prob"] = scan_drop_estimate(estimate_network(scans, settings, rng), wire)
    else:
        values["lidar.scan_drop_prob"] = Estimate.unidentifiable(
            "no topic besides the scans to tell the network's losses from the driver's", "probability"
        )
    values["network.loss_prob"] = network.loss_prob
    values["network.jitter_s"] = network.jitter_s
    values["network.burst_len"] = network.burst_len
    own = _own_clock_streams(streams)
    clock = estimate_clock(own, settings, _followed_clocks(tagged, own))
    values["clock.offset_s"] = _offset_on_followed_clock(clock.offset_s, sessions)
    values["clock.drift_ppm"] = clock.drift_ppm
    return network, clock


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


def _followed_clocks(tagged: Sequence[tuple[str, SessionData]], robots: Mapping[str, object]) -> dict[str, StampStream]:
    """For each robot (keyed as `_own_clock_streams` keys it) recorded on a time-scaled fleet's clock, that
    recording's ``/clock`` messages as a stream (stamp = value, log = the recorder's reading)."""
    out: dict[str, StampStream] = {}
    for tag, data in tagged:
        if data.followed_clock is None or len(data.followed_clock[0]) == 0:
            continue
        values, logs = data.followed_clock
        stream = StampStream(f"{tag} /clock", values, logs, tuple(data.windows))
        for robot in robots:
            if robot.startswith(f"{tag} /"):
                out[robot] = stream
    return out


def _offset_on_followed_clock(offset: Estimate, sessions: Sequence[SessionData]) -> Estimate:
    """The clock offset, unless the recorder kept time by a published clock (``/clock``, a time-scaled twin):
    that copy of the robots' time lags by part of its period, so receipt may even precede the sample and the
    one-way bound no longer bounds."""
    followed = [d for d in sessions if d.session.clock == "ros_clock"]
    if not followed or not offset.ok or offset.value is None:
        return offset
    rate = followed[0].session.fields.get("clock_rate", "?")
    reason = (
        f"the recorder followed a published /clock (rate {rate}), which lags "
        f"the robots' time by part of its period: one-way stamps put the offset near {offset.value:.3f} s but "
        "cannot bound it (the drift is measured with the copy's own wander taken out)"
    )
    return Estimate.unidentifiable(reason, offset.unit, offset.n)


UNMEASURED_DRIFT_PPM = 200.0
"""A robot clock's rate error assumed at most this when the recording cannot tell it."""


def _flag_weak(key: str, est: Estimate) -> Estimate:
    """`est` flagged ``weak`` where its key is a scale, a probability or a rate (its profile bound below is >= 0)
    and its interval is wider than its value."""
    group, name, _ = split_key(key)
    try:
        meta = profile_setting(f"{group}.{name}").metadata
    except KeyError:
        return est
    low = bounds_of(meta)[0]
    return est.flagged(low, NEGLIGIBLE.get(key, 0.0)) if low >= 0 else est


NEGLIGIBLE = {
    "lidar.rate_wander": 0.001,
    "lidar.range_step_m": 1e-5,
    "lidar.scan_drop_prob": 0.001,
    "lidar.dropout_prob": 0.001,
    "lidar.mixed_pixel_prob": 0.001,
    "network.loss_prob": 0.001,
}
"""Per key, a value this near its lower bound is as good as none (a period spread of 0.1 %, ranges finer than 10 um,
one message in a thousand): an interval that lies wholly within it determines the key, it is not weak."""


def scan_drop_estimate(scans: NetworkFit, wire: NetworkFit) -> Estimate:
    """The probability that the lidar's driver loses a whole scan: the scan topics' loss beyond the other topics'
    (1 - (1 - p_scan) / (1 - p_wire)), its interval from the two intervals' far ends (conservative, within [0, 1))."""
    a, b = scans.loss_prob, wire.loss_prob
    unit = "probability"
    if not (a.ok and b.ok and a.value is not None and b.value is not None and a.interval and b.interval):
        return Estimate.unidentifiable("the scans' or the other topics' loss is not identified", unit)

    def excess(p_scan: float, p_wire: float) -> float:
        return min(max(1 - (1 - p_scan) / (1 - p_wire), 0.0), 1.0) if p_wire < 1 else 0.0

    value = excess(a.value, b.value)
    lo, hi = excess(a.interval[0], b.interval[1]), excess(a.interval[1], b.interval[0])
    se = (hi - lo) / (2 * 1.959963984540054)
    method = "loss on the scan topics beyond the other topics' (the driver's), from the two losses' intervals"
    return Estimate.of(value, se, (lo, max(hi, value)), unit, method, a.n)


def _host_rate(rate: Estimate, drift: Estimate | None) -> Estimate:
    """A sending rate measured on the robot's stamps, on the host's clock: a robot clock running `drift` fast
    stretches every stamped period by (1 + drift). The interval takes the drift's own interval (or
    +-`UNMEASURED_DRIFT_PPM` when the drift is unknown) on top of the rate's."""
    if not rate.ok or rate.value is None:
        return rate
    if drift is not None and drift.ok and drift.value is not None and drift.interval is not None:
        d, (d_lo, d_hi) = drift.value * 1e-6, (drift.interval[0] * 1e-6, drift.interval[1] * 1e-6)
        how = "robot clock's drift taken out"
    else:
        d, d_lo, d_hi = 0.0, -UNMEASURED_DRIFT_PPM * 1e-6, UNMEASURED_DRIFT_PPM * 1e-6
        how = f"robot clock's drift unknown: +-{UNMEASURED_DRIFT_PPM:g} ppm"
    lo, hi = rate.interval if rate.interval is not None else (rate.value, rate.value)
    value = rate.value * (1 + d)
    interval = (lo * (1 + d_lo), hi * (1 + d_hi))
    se = max(rate.std_error or 0.0, (interval[1] - interval[0]) / (2 * 1.959963984540054))
    return Estimate.of(value, se, interval, rate.unit, f"{rate.method}; {how}", rate.n)


def _own_clock_streams(streams: Sequence[StampStream]) -> dict[str, list[StampStream]]:
    """Per recording and robot, the topics its own clock stamps (scan, odom; not the motion capture's ground truth)."""
    out: dict[str, list[StampStream]] = {}
    for stream in streams:
        where, _, topic = stream.topic.rpartition(" ")
        parts = topic.strip("/").split("/")
        if len(parts) >= 2 and parts[-1] in ("scan", "odom"):
            out.setdefault(f"{where} /{'/'.join(parts[:-1])}".strip(), []).append(stream)
    return out
