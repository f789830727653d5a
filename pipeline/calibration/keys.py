"""Calibration's keys: the reality profile's keys calibration estimates, the simulator settings they become, the
physical ranges an estimate must keep, the drive chain's effective values and when an estimate is weakly determined.

What :mod:`pipeline.calibration.calibrate` writes and :mod:`pipeline.calibration.steps` fills; derived from the shared
quantities (:data:`pipeline.core.quantities.SHARED`) where the simulator and the twin share a parameter.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from pipeline.calibration.estimates import Estimate
from pipeline.calibration.wheels import NOMINAL_WHEEL_RADIUS_M, WheelFit
from pipeline.core.quantities import SHARED
from pipeline.core.reality import bounds_of, profile_setting
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


REAL_LIDAR_KEYS = ("range_step_m", "beam_noise_spread", "mixed_pixel_prob", "scan_drop_prob")
"""What real lidars have that the simulator adds only when told. Each enters the calibrated world only where its
estimate is ``ok``: a ``weak`` one (an interval wider than its value) is left out, the simulator keeps params.yaml's
value. Measured on the lab twin (no mixed pixels): a weak mixed-pixel estimate (0.037 [0.021, 0.081]) in the
calibrated world trained policies that collided at a box corner on the twin in two trainings of two (robot success
0.673, 0.667), and without it 1.000 (benchmarks/results/loop/lab_checks/)."""


def _simulated(left_out: tuple[str, ...]) -> dict[str, str]:
    """Profile key -> the simulator setting (``<section>.<key>``) it becomes, for the shared quantities
    (:data:`pipeline.core.quantities.SHARED`) outside the simulator's network section, less `left_out`: grouped in
    :data:`PROFILE_KEYS`' order of groups, in SHARED's order within a group."""
    groups = list(PROFILE_KEYS)
    pairs = [
        (key, f"{section}.{sim_key}")
        for key, (section, sim_key, _) in SHARED.items()
        if section != "network" and key not in left_out
    ]
    return dict(sorted(pairs, key=lambda pair: groups.index(pair[0].split(".")[0])))


NETWORK_RATE_SOURCES: dict[str, str] = {"scan_rate_hz": "lidar.rate_hz", "odom_rate_hz": "odometry.rate_hz"}
"""The simulator's message rates (``world.network``) and the sensors' rates they take. No shared quantity: the
simulator's rate may be 0 (one message per control step), a sensor's is above 0."""
NETWORK_SOURCES: dict[str, str] = {
    **NETWORK_RATE_SOURCES,
    **{sim_key: key for key, (section, sim_key, _) in SHARED.items() if section == "network"},
}
"""The simulator's network keys (``world.network``) and the estimates they take: the rates at which scans and odometry
arrive, how they are lost and jittered, and the robots' clock; the calibrated round trains on them, randomized
within their intervals (the clock keys, which move only the sensors' stamps, at their values). Calibrated ranges are
kept inside the bounds of their simulator setting (:func:`world_bounds`)."""


PHYSICAL_LEFT_OUT = ("lidar.noise_per_m", "lidar.mount_xy_m", *(f"lidar.{k}" for k in REAL_LIDAR_KEYS))
"""Shared quantities outside :data:`PHYSICAL_KEYS`: ``lidar.noise_per_m``, which reads slightly negative where noise
does not grow with range, is drawn at 0 instead; ``lidar.mount_xy_m`` is estimated per component
(``lidar.mount_xy_m[0]``), never under its own key; what real lidars add (:data:`REAL_LIDAR_KEYS`) enters the
calibrated world only where its estimate is ``ok``."""
PHYSICAL_KEYS: dict[str, str] = _simulated(PHYSICAL_LEFT_OUT)
"""Estimates that become simulator settings, and the setting (``world.<key>``) they become: an estimate's physical
range is the reality profile's bounds of its key within that setting's (:func:`physical_ranges`). The network's are
:data:`NETWORK_SOURCES`."""

RANDOMIZED_LEFT_OUT = (
    "lidar.mount_xy_m",
    *(f"lidar.{k}" for k in REAL_LIDAR_KEYS),
    "base.wheel_radius_left_m",
    "base.wheel_radius_right_m",
    "base.wheel_separation_m",
    "clock.offset_s",
    "clock.drift_ppm",
)
"""Shared quantities whose estimates training does not draw from: the simulator's randomization has no range of them
(:class:`pipeline.params.RandomizeConfig`). The wheels' radii and separation reach it as the arc they give
(``actuation.yaw_rate_per_mps``, drawn on its own); the clock keys are set at their values."""
RANDOMIZED_SOURCES: dict[str, str] = {
    **{setting_key: key for key, setting_key in _simulated(RANDOMIZED_LEFT_OUT).items()},
    **{f"network.{k}": v for k, v in NETWORK_SOURCES.items() if v not in RANDOMIZED_LEFT_OUT},
}
"""The simulator settings (``world.<key>``) that :meth:`Calibration.randomize_ranges` draws around an estimate, and
the estimate's profile key."""


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
