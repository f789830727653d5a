"""The reality profile's schema: what robots, sensors, clocks, room and network are really like.

Defined once, below the simulator, the twin and calibration: the twin plays a profile (:mod:`pipeline.twin.profile`
loads the files), calibration estimates its keys within these bounds, and the simulator's settings take them.

The keys (units in the names; those marked * are optional and default to the ideal value)::

    lidar:     {beams, rate_hz, noise_sigma_m, dropout_prob, bias_m, mount_yaw_rad,
                noise_per_m*, mount_xy_m*: [dx, dy], blocked_sectors_rad*: [[from, to], ...],
                motion_distortion*: bool, range_step_m*, beam_noise_spread*, mixed_pixel_prob*,
                no_return*: inf | zero | max | nan, beam_angle_jitter_rad*, rate_wander*, scan_drop_prob*}
    actuation: {delay_s, time_constant_s, linear_gain, angular_gain}
    odometry:  {rate_hz, drift_per_m, encoder_ticks_per_rev*}
    network:   {loss_prob, jitter_s, burst_len*}
    base*:     {wheel_radius_left_m, wheel_radius_right_m, wheel_separation_m, mass_kg,
                motor_time_constant_s, deadband_radps, max_wheel_accel_radps2, friction}
    clock*:    {offset_s, drift_ppm}
    map*:      {box_offsets_m: [[dx, dy], ...], wall_offset_m}

Lidar noise is ``noise_sigma_m + noise_per_m * range`` (1 sigma); blocked sectors are angles in the
lidar's frame (radians, from < to, each narrower than 2 pi) where the robot's mast returns nothing
usable; with ``motion_distortion`` each beam is taken at its own time within the sweep. What real 2-D lidars
add (their datasheets and drivers state it): ranges reported in steps of ``range_step_m`` (0: continuous); each
beam's noise scaled by a factor of mean square 1, fixed per beam (log-normal with log-sd ``beam_noise_spread``: the
receiver's response and what each beam sees differ); at a depth edge (a beam whose true range differs from its
neighbour's by more than 0.1 m) a return between the near and the far surface with probability
``mixed_pixel_prob``; a beam without a return reading +inf, 0, the range maximum or NaN as the driver's
``no_return`` convention says; beams pointing off their stated angles by N(0, ``beam_angle_jitter_rad``), fixed per
unit; each sweep's period off the nominal by N(0, ``rate_wander``) relative; whole scans lost in the driver (USB)
with probability ``scan_drop_prob``. Odometry
integrates wheel encoder ticks with the nominal SPARK wheel radius and separation, so the base's
true radii and separation turn into drift. Stamps are in the robot's clock: ``offset_s`` ahead of
the host, running ``drift_ppm`` parts per million fast. Boxes and walls stand where ``map`` puts
them, not where the scenario's map says. Losses come in bursts of ``burst_len`` messages on average
(1: independent). ``max_wheel_accel_radps2: null`` is no limit.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass, fields
from typing import Any, Literal

from pipeline.core import quantities as Q
from pipeline.core.scenario import SPARK_WHEEL_RADIUS_M, SPARK_WHEEL_SEPARATION_M
from pipeline.mappings import setting

NOMINAL_WHEEL_RADIUS_M = SPARK_WHEEL_RADIUS_M
NOMINAL_WHEEL_SEPARATION_M = SPARK_WHEEL_SEPARATION_M
"""The SPARK's wheels as its driver knows them: odometry integrates encoder ticks with these."""


@dataclass(frozen=True)
class LidarProfile:
    beams: int = setting(ge=4, le=4096)
    rate_hz: float = setting(gt=0.0, le=100.0)
    noise_sigma_m: float = Q.NOISE_SIGMA_M.setting()
    dropout_prob: float = Q.DROPOUT_PROB.setting()
    bias_m: float = Q.BIAS_M.setting()
    mount_yaw_rad: float = Q.MOUNT_YAW_RAD.setting()
    noise_per_m: float = Q.NOISE_PER_M.setting(0.0, optional=True)
    mount_xy_m: tuple[float, ...] = Q.MOUNT_XY_M.setting((0.0, 0.0), min_len=2, max_len=2, optional=True)
    blocked_sectors_rad: tuple[tuple[float, ...], ...] = setting((), ge=-7.0, le=7.0, optional=True)
    motion_distortion: bool = setting(False, optional=True)
    range_step_m: float = Q.RANGE_STEP_M.setting(0.0, optional=True)
    beam_noise_spread: float = Q.BEAM_NOISE_SPREAD.setting(0.0, optional=True)
    mixed_pixel_prob: float = Q.MIXED_PIXEL_PROB.setting(0.0, optional=True)
    no_return: Literal["inf", "zero", "max", "nan"] = setting("inf", optional=True)
    beam_angle_jitter_rad: float = setting(0.0, ge=0.0, le=0.05, optional=True)
    rate_wander: float = setting(0.0, ge=0.0, le=0.2, optional=True)
    scan_drop_prob: float = Q.SCAN_DROP_PROB.setting(0.0, optional=True)

    def check(self) -> list[tuple[str, object, str]]:
        bad: list[tuple[str, object, str]] = []
        for k, sector in enumerate(self.blocked_sectors_rad):
            where = f"blocked_sectors_rad[{k}]"
            if len(sector) != 2:
                bad.append((where, list(sector), "a pair [from, to] of angles (rad)"))
            elif not sector[0] < sector[1]:
                bad.append((where, list(sector), "from < to"))
            elif sector[1] - sector[0] >= 2 * math.pi:
                bad.append((where, list(sector), "a sector narrower than 2 pi"))
        return bad


@dataclass(frozen=True)
class ActuationProfile:
    delay_s: float = Q.DELAY_S.setting()
    time_constant_s: float = Q.TIME_CONSTANT_S.setting()
    linear_gain: float = Q.LINEAR_GAIN.setting()
    angular_gain: float = Q.ANGULAR_GAIN.setting()


@dataclass(frozen=True)
class OdometryProfile:
    rate_hz: float = setting(gt=0.0, le=1000.0)
    drift_per_m: float = Q.DRIFT_PER_M.setting()
    encoder_ticks_per_rev: int | None = setting(None, ge=1, le=1_000_000, optional=True)
    """None: exact wheel angles."""


@dataclass(frozen=True)
class NetworkProfile:
    loss_prob: float = Q.LOSS_PROB.setting()
    jitter_s: float = Q.JITTER_S.setting()
    burst_len: float = Q.BURST_LEN.setting(1.0, optional=True)


@dataclass(frozen=True)
class BaseProfile:
    """The drive base: true wheel radii and separation, mass, motors (lag, deadband, acceleration limit), grip."""

    wheel_radius_left_m: float = Q.WHEEL_RADIUS_M.setting(NOMINAL_WHEEL_RADIUS_M, optional=True)
    wheel_radius_right_m: float = Q.WHEEL_RADIUS_M.setting(NOMINAL_WHEEL_RADIUS_M, optional=True)
    wheel_separation_m: float = Q.WHEEL_SEPARATION_M.setting(NOMINAL_WHEEL_SEPARATION_M, optional=True)
    mass_kg: float = setting(5.0, gt=0.0, le=500.0, optional=True)
    motor_time_constant_s: float = setting(0.0, ge=0.0, le=2.0, optional=True)
    deadband_radps: float = Q.DEADBAND_RADPS.setting(0.0, optional=True)
    max_wheel_accel_radps2: float | None = setting(None, gt=0.0, le=10_000.0, optional=True)
    friction: float = setting(1.0, gt=0.0, le=5.0, optional=True)


@dataclass(frozen=True)
class ClockProfile:
    """The robots' clock against the host's: an offset and a rate error."""

    offset_s: float = Q.CLOCK_OFFSET_S.setting(0.0, optional=True)
    drift_ppm: float = Q.CLOCK_DRIFT_PPM.setting(0.0, optional=True)


@dataclass(frozen=True)
class MapProfile:
    """Where the room really is: each box moved by [dx, dy] (in the scenario's box order), walls moved outward."""

    box_offsets_m: tuple[tuple[float, ...], ...] = setting((), ge=-0.5, le=0.5, optional=True)
    wall_offset_m: float = setting(0.0, ge=-0.3, le=0.3, optional=True)

    def check(self) -> list[tuple[str, object, str]]:
        return [
            (f"box_offsets_m[{k}]", list(offset), "a pair [dx, dy] (m)")
            for k, offset in enumerate(self.box_offsets_m)
            if len(offset) != 2
        ]


@dataclass(frozen=True)
class RealityProfile:
    """What the twin's robots are really like; `name` is the file's stem."""

    lidar: LidarProfile = setting()
    actuation: ActuationProfile = setting()
    odometry: OdometryProfile = setting()
    network: NetworkProfile = setting()
    base: BaseProfile = setting(BaseProfile(), optional=True)
    clock: ClockProfile = setting(ClockProfile(), optional=True)
    map: MapProfile = setting(MapProfile(), optional=True)

    def problems_in(self, n_boxes: int) -> list[tuple[str, object, str]]:
        """Problems (key, value, allowed) of this profile in a room with `n_boxes` boxes."""
        if len(self.map.box_offsets_m) > n_boxes:
            return [
                (
                    "map.box_offsets_m",
                    [list(o) for o in self.map.box_offsets_m],
                    f"at most one offset per box of the scenario ({n_boxes})",
                )
            ]
        return []


def profile_setting(key: str) -> Any:
    """The dataclass field of the profile key ``group.name`` (e.g. ``lidar.bias_m``); KeyError for another key."""
    group, _, name = key.partition(".")
    section = typing.get_type_hints(RealityProfile).get(group)
    found = None if section is None else next((f for f in fields(section) if f.name == name), None)
    if found is None:
        raise KeyError(key)
    return found


def profile_bounds(key: str) -> tuple[float, float]:
    """(low, high) of the profile key ``group.name``: what a real robot can have (open ends as infinities; an
    exclusive bound as the nearest float inside it)."""
    meta = profile_setting(key).metadata
    return bounds_of(meta)


def bounds_of(meta: Any) -> tuple[float, float]:
    """(low, high) of a setting's metadata: inclusive bounds as they are, exclusive ones as the nearest float inside,
    missing ones as infinities."""
    low, high = -math.inf, math.inf
    if meta.get("ge") is not None:
        low = float(meta["ge"])
    elif meta.get("gt") is not None:
        low = math.nextafter(float(meta["gt"]), math.inf)
    if meta.get("le") is not None:
        high = float(meta["le"])
    elif meta.get("lt") is not None:
        high = math.nextafter(float(meta["lt"]), -math.inf)
    return low, high
