"""Calibration's estimators behind one interface: each :class:`Step` names the part it belongs to (and the parts it
needs beside it), the streams of :class:`~pipeline.calibration.streams.Gathered` it reads, and fits into the shared
:class:`Context` (the estimates by key, the fits the report plots). :data:`STEPS` is the registry, in the order the
steps run (later ones read what earlier ones set; they draw from one random generator in that order).
:func:`pipeline.calibration.calibrate.calibrate` gathers what the steps asked for and runs them; adding an estimator is
a module with its fit and a step here.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np

from pipeline.calibration.actuation import ActuationFit, VelocityTrack, estimate_actuation
from pipeline.calibration.clock import ClockFit, estimate_clock
from pipeline.calibration.estimates import Estimate
from pipeline.calibration.floor import estimate_floor
from pipeline.calibration.keys import (
    DRIVE_MODEL,
    EFFECTIVE_DRIVE,
    EFFECTIVE_REASON,
    LIDAR_FIT_KEYS,
    PROFILE_KEYS,
    EffectiveValue,
    _flag_weak,
    arc_per_m,
    within_physical_ranges,
)
from pipeline.calibration.lidar import LidarFit, estimate_lidar
from pipeline.calibration.motors import MotorFit, estimate_motors
from pipeline.calibration.network import (
    NetworkFit,
    StampStream,
    estimate_network,
    rate_estimate,
    rate_wander_estimate,
)
from pipeline.calibration.odometry import OdometryFit, estimate_odometry
from pipeline.calibration.options import CalibrationSettings, Part
from pipeline.calibration.randomization import RandomizationFit, fit_randomization
from pipeline.calibration.recording import SessionData
from pipeline.calibration.streams import Gathered, Sessions, odometry_period_s, wheel_episodes
from pipeline.calibration.wheels import NOMINAL_WHEEL_RADIUS_M, WheelFit, estimate_wheels


@dataclass
class Fits:
    """Each part's fit, None where the part was not asked for."""

    lidar: LidarFit | None = None
    actuation: ActuationFit | None = None
    odometry: OdometryFit | None = None
    network: NetworkFit | None = None
    wheels: WheelFit | None = None
    clock: ClockFit | None = None
    motors: MotorFit | None = None
    randomization: RandomizationFit | None = None


def _lidar_values(lidar: LidarFit, data: Gathered) -> dict[str, Estimate]:
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
    values: dict[str, Estimate], data: Gathered, sessions: list[SessionData], settings: CalibrationSettings
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


@dataclass
class Context:
    """What the steps share: the recordings as read and tagged, the streams gathered for them, the settings and the
    random generator (drawn from in the steps' order), and what the steps fill: the estimates by key, the drive
    chain's effective values and each part's fit."""

    read: Sessions
    tagged: list[tuple[str, SessionData]]
    data: Gathered
    settings: CalibrationSettings
    rng: np.random.Generator
    values: dict[str, Estimate] = field(default_factory=dict)
    effective: dict[str, EffectiveValue] = field(default_factory=dict)
    found: Fits = field(default_factory=Fits)


class Step(Protocol):
    """One estimator as calibration runs it."""

    @property
    def label(self) -> str:
        """What the progress line says while it runs."""
        ...

    @property
    def parts(self) -> tuple[Part, ...]:
        """The parts that must all be asked for (a step of two parts runs only with both)."""
        ...

    @property
    def reads(self) -> tuple[str, ...]:
        """The streams of :data:`~pipeline.calibration.streams.STREAM_NAMES` it reads."""
        ...

    def run(self, ctx: Context) -> None:
        """Fit, and put the estimates and the fit into `ctx`."""
        ...


@dataclass(frozen=True)
class LidarStep:
    """The lidar's noise, dropouts, bias, mounting and real-lidar artefacts, and the map's walls and boxes, from still
    scan spans (and the noise again from scans while driving): :func:`~pipeline.calibration.lidar.estimate_lidar`."""

    label: str = "lidar"
    parts: tuple[Part, ...] = ("lidar",)
    reads: tuple[str, ...] = ("spans", "moving", "scans")

    def run(self, ctx: Context) -> None:
        ctx.found.lidar = estimate_lidar(ctx.read.geometry, ctx.data.spans, ctx.settings, ctx.rng, ctx.data.moving)
        ctx.values.update(_lidar_values(ctx.found.lidar, ctx.data))
        if any(s.kind == "localized" for s in ctx.read.pose_sources):
            ctx.values.update(_localized_lidar_values(ctx.values, ctx.read.sessions))


@dataclass(frozen=True)
class ActuationStep:
    """The drive's delay, lag and gains from commanded against achieved body velocity on contact-free tracks
    (:func:`~pipeline.calibration.actuation.estimate_actuation`), and the chain's effective values."""

    label: str = "actuation"
    parts: tuple[Part, ...] = ("actuation",)
    reads: tuple[str, ...] = ("tracks",)

    def run(self, ctx: Context) -> None:
        found = ctx.found.actuation = estimate_actuation(ctx.data.tracks, ctx.settings, ctx.rng)
        ctx.values.update({f"actuation.{key}": getattr(found, key) for key in PROFILE_KEYS["actuation"]})
        ctx.values = within_physical_ranges(ctx.values)
        ctx.effective = _effective_drive(found, ctx.values)
        for name in ctx.effective:
            key = EFFECTIVE_DRIVE[name][0]
            if key is not None and ctx.values[key].ok:
                ctx.values[key] = Estimate.unidentifiable(EFFECTIVE_REASON.format(name=name), ctx.values[key].unit)


@dataclass(frozen=True)
class OdometryStep:
    """The wheels' radii and separation, the floor's friction and the odometry's drift, from odometry against the
    truth per robot and episode (:mod:`~pipeline.calibration.wheels`, :mod:`~pipeline.calibration.odometry`)."""

    label: str = "odometry and wheels"
    parts: tuple[Part, ...] = ("odometry",)
    reads: tuple[str, ...] = ("episodes", "odom_stamps")

    def run(self, ctx: Context) -> None:
        ctx.found.wheels, ctx.found.odometry = _odometry_fits(ctx.values, ctx.data, ctx.read.sessions, ctx.settings)


@dataclass(frozen=True)
class MotorsStep:
    """The motors' deadband, acceleration limit and lag, and the driver's delay and lag read at the wheels, from
    wheel speeds under the commands (:func:`~pipeline.calibration.motors.estimate_motors`)."""

    label: str = "motors"
    parts: tuple[Part, ...] = ("odometry", "actuation")
    reads: tuple[str, ...] = ("tracks", "odom_stamps")

    def run(self, ctx: Context) -> None:
        episodes = [e for tag, d in ctx.tagged for e in wheel_episodes(tag, d, ctx.data.tracks)]
        found = ctx.found.motors = estimate_motors(
            episodes, odometry_period_s(ctx.data.odom_stamps), ctx.settings, ctx.rng
        )
        ctx.values["base.deadband_radps"] = found.deadband_radps
        ctx.values["base.max_wheel_accel_radps2"] = found.max_wheel_accel_radps2
        ctx.values["base.motor_time_constant_s"] = found.motor_time_constant_s
        # the drive as the robot has it, read at the wheels: the driver's delay and lag where the transients tell them
        for key, est in (
            ("actuation.delay_s", found.delay_s),
            ("actuation.time_constant_s", found.driver_time_constant_s),
        ):
            if est.ok:
                ctx.values[key] = est


@dataclass(frozen=True)
class RandomizationStep:
    """The spread of the drive's parameters that the recorded transitions ask for
    (:func:`~pipeline.calibration.randomization.fit_randomization`)."""

    label: str = "randomization ranges"
    parts: tuple[Part, ...] = ("actuation",)
    reads: tuple[str, ...] = ("tracks",)

    def run(self, ctx: Context) -> None:
        start = _randomization_start(ctx.values, ctx.effective, ctx.found.actuation)
        ctx.found.randomization = _fitted_randomization(start, ctx.data.tracks, ctx.settings)


@dataclass(frozen=True)
class NetworkStep:
    """The network's loss, bursts and jitter, the lidar driver's lost scans, and the robots' clocks, from the stamps
    of the sensor topics (:mod:`~pipeline.calibration.network`, :mod:`~pipeline.calibration.clock`)."""

    label: str = "network and clock"
    parts: tuple[Part, ...] = ("network",)
    reads: tuple[str, ...] = ("streams",)

    def run(self, ctx: Context) -> None:
        ctx.found.network, ctx.found.clock = _network_fits(
            ctx.values, ctx.data.streams, ctx.tagged, ctx.read.sessions, ctx.settings, ctx.rng
        )


STEPS: tuple[Step, ...] = (
    LidarStep(),
    ActuationStep(),
    OdometryStep(),
    MotorsStep(),
    RandomizationStep(),
    NetworkStep(),
)
"""The registry of calibration's steps, in the order they run."""


def wanted(parts: Collection[Part]) -> list[Step]:
    """The steps whose parts are all in `parts`, in :data:`STEPS`' order."""
    return [step for step in STEPS if all(part in parts for part in step.parts)]


def finish(values: dict[str, Estimate]) -> dict[str, Estimate]:
    """After every step: the sensors' rates on the host's clock (the robots' clock drift taken out), every estimate
    within its physical range, and the weakly determined flagged."""
    values = dict(values)
    for key in ("lidar.rate_hz", "odometry.rate_hz"):
        if key in values:
            values[key] = _host_rate(values[key], values.get("clock.drift_ppm"))
    values = within_physical_ranges(values)
    return {key: _flag_weak(key, est) for key, est in values.items()}
