"""Reality profiles drawn at random from stated ranges: realities the project never tuned for.

Benchmarks score calibration and sim-to-real transfer on profiles drawn here (seeded), so the
ranges are stated once, in `PROFILE_RANGES`; the README lists them. Each value is drawn uniformly
from its [low, high]; integers and choices as noted. Every drawn profile is read back through
:func:`pipeline.mappings.from_mapping`, so it obeys the profile's own rules.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from pipeline.mappings import from_mapping
from pipeline.twin.profile import NOMINAL_WHEEL_RADIUS_M, NOMINAL_WHEEL_SEPARATION_M, RealityProfile

PROFILE_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "lidar": {
        "rate_hz": (6.0, 12.0),
        "noise_sigma_m": (0.005, 0.03),
        "dropout_prob": (0.0, 0.04),
        "bias_m": (-0.02, 0.03),
        "mount_yaw_rad": (-0.05, 0.05),
        "noise_per_m": (0.0, 0.008),
        "mount_x_m": (-0.03, 0.08),
        "mount_y_m": (-0.02, 0.02),
        "blocked_centre_rad": (math.pi - 0.3, math.pi + 0.3),
        "blocked_width_rad": (0.0, 0.6),
    },
    "actuation": {
        "delay_s": (0.0, 0.12),
        "time_constant_s": (0.05, 0.2),
        "linear_gain": (0.85, 1.05),
        "angular_gain": (0.8, 1.1),
    },
    "odometry": {"rate_hz": (20.0, 50.0), "drift_per_m": (0.005, 0.03)},
    "network": {"loss_prob": (0.0, 0.05), "jitter_s": (0.0, 0.015), "burst_len": (1.0, 5.0)},
    "base": {
        "wheel_radius_left_m": (0.97 * NOMINAL_WHEEL_RADIUS_M, 1.02 * NOMINAL_WHEEL_RADIUS_M),
        "wheel_radius_right_m": (0.97 * NOMINAL_WHEEL_RADIUS_M, 1.02 * NOMINAL_WHEEL_RADIUS_M),
        "wheel_separation_m": (0.99 * NOMINAL_WHEEL_SEPARATION_M, 1.04 * NOMINAL_WHEEL_SEPARATION_M),
        "mass_kg": (4.0, 8.0),
        "motor_time_constant_s": (0.02, 0.1),
        "deadband_radps": (0.0, 1.0),
        "max_wheel_accel_radps2": (15.0, 60.0),
        "friction": (0.6, 1.2),
    },
    "clock": {"offset_s": (-0.1, 0.1), "drift_ppm": (-100.0, 100.0)},
    "map": {"box_offset_m": (-0.04, 0.04), "wall_offset_m": (-0.02, 0.03)},
}
"""[low, high] of every drawn value. Fixed: 360 beams, motion distortion on; the encoder has one of
`ENCODER_TICKS` ticks per revolution; the blocked sector (the mast) is [centre - width / 2, centre + width / 2],
none when narrower than 0.05 rad."""
ENCODER_TICKS = (512, 1024, 1560, 4096)
RANGE_STEPS_M = (0.00025, 0.0005, 0.001, 0.002)
"""The range resolutions of 2-D lidars' datasheets and drivers (RPLIDAR 0.25 mm, Hokuyo URG/UST and SICK TiM 1 mm,
LDS-01 and some RPLIDAR drivers' output 2 mm...)."""
NO_RETURN_CONVENTIONS = ("inf", "zero", "max", "nan")
"""What drivers publish for a beam without a return (REP 117's +inf; 0 from urg_node and others; the range maximum;
NaN)."""
WIDE_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    **PROFILE_RANGES,
    "lidar": {**PROFILE_RANGES["lidar"], "noise_sigma_m": (0.001, 0.02)},
    "lidar_real": {
        "beam_noise_spread": (0.0, 0.4),
        "mixed_pixel_prob": (0.0, 0.5),
        "beam_angle_jitter_rad": (0.0, 0.002),
        "rate_wander": (0.0, 0.03),
        "scan_drop_prob": (0.0, 0.02),
    },
    "actuation": {**PROFILE_RANGES["actuation"], "delay_s": (0.02, 0.15), "time_constant_s": (0.05, 0.3)},
    "network": {"loss_prob": (0.0, 0.06), "jitter_s": (0.0, 0.02), "burst_len": (1.0, 6.0)},
    "base": {**PROFILE_RANGES["base"], "friction": (0.3, 1.0)},
    "clock": {"offset_s": (-1.0, 1.0), "drift_ppm": (-100.0, 100.0)},
}
"""Ranges that span the robots labs have (a used base with a slow driver and slipping wheels, an unsynchronized
clock, a lossy link) and the lidars they have (``lidar_real``: ranges in one of `RANGE_STEPS_M`, noise that differs
per beam, mixed pixels at depth edges, one of `NO_RETURN_CONVENTIONS`, uneven beam angles, a wandering sweep rate,
scans lost in the driver; noise from 1 mm): what a calibration must stay honest on. `PROFILE_RANGES` stays as it was,
so a ``drawn:SEED`` profile of an earlier result is drawn the same."""


def draw_profile_mapping(
    seed: int, n_boxes: int, ranges: dict[str, dict[str, tuple[float, float]]] = PROFILE_RANGES
) -> dict[str, Any]:
    """A profile (plain mapping, as in a profile YAML file) drawn from `ranges` with `seed`, for a room with
    `n_boxes` boxes."""
    rng = np.random.default_rng(seed)

    def u(group: str, key: str) -> float:
        low, high = ranges[group][key]
        return float(f"{rng.uniform(low, high):.6g}")

    lidar: dict[str, Any] = {
        "beams": 360,
        "rate_hz": u("lidar", "rate_hz"),
        "noise_sigma_m": u("lidar", "noise_sigma_m"),
        "dropout_prob": u("lidar", "dropout_prob"),
        "bias_m": u("lidar", "bias_m"),
        "mount_yaw_rad": u("lidar", "mount_yaw_rad"),
        "noise_per_m": u("lidar", "noise_per_m"),
        "mount_xy_m": [u("lidar", "mount_x_m"), u("lidar", "mount_y_m")],
        "motion_distortion": True,
    }
    centre, width = u("lidar", "blocked_centre_rad"), u("lidar", "blocked_width_rad")
    lidar["blocked_sectors_rad"] = (
        [[round(centre - width / 2, 4), round(centre + width / 2, 4)]] if width >= 0.05 else []
    )
    out: dict[str, Any] = {
        "lidar": lidar,
        "actuation": {k: u("actuation", k) for k in ranges["actuation"]},
        "odometry": {
            "rate_hz": u("odometry", "rate_hz"),
            "drift_per_m": u("odometry", "drift_per_m"),
            "encoder_ticks_per_rev": int(rng.choice(ENCODER_TICKS)),
        },
        "network": {k: u("network", k) for k in ranges["network"]},
        "base": {k: u("base", k) for k in ranges["base"]},
        "clock": {k: u("clock", k) for k in ranges["clock"]},
        "map": {
            "box_offsets_m": [[u("map", "box_offset_m"), u("map", "box_offset_m")] for _ in range(n_boxes)],
            "wall_offset_m": u("map", "wall_offset_m"),
        },
    }
    if "lidar_real" in ranges:  # drawn last: the values above stay those of the same seed without it
        lidar.update({k: u("lidar_real", k) for k in ranges["lidar_real"]})
        lidar["range_step_m"] = float(rng.choice(RANGE_STEPS_M))
        lidar["no_return"] = str(rng.choice(NO_RETURN_CONVENTIONS))
    return out


def draw_profile(seed: int, n_boxes: int) -> RealityProfile:
    """`draw_profile_mapping`, read as a RealityProfile (so it obeys the profile's rules)."""
    return from_mapping(RealityProfile, draw_profile_mapping(seed, n_boxes), f"<drawn profile {seed}>")
