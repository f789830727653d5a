"""Reality profile files: what the twin's robots, sensors, clocks, room and network are really like.

The keys (units in the names; those marked * are optional and default to the ideal value)::

    lidar:     {beams, rate_hz, noise_sigma_m, dropout_prob, bias_m, mount_yaw_rad,
                noise_per_m*, mount_xy_m*: [dx, dy], blocked_sectors_rad*: [[from, to], ...],
                motion_distortion*: bool}
    actuation: {delay_s, time_constant_s, linear_gain, angular_gain}
    odometry:  {rate_hz, drift_per_m, encoder_ticks_per_rev*}
    network:   {loss_prob, jitter_s, burst_len*}
    base*:     {wheel_radius_left_m, wheel_radius_right_m, wheel_separation_m, mass_kg,
                motor_time_constant_s, deadband_radps, max_wheel_accel_radps2, friction}
    clock*:    {offset_s, drift_ppm}
    map*:      {box_offsets_m: [[dx, dy], ...], wall_offset_m}

Lidar noise is ``noise_sigma_m + noise_per_m * range`` (1 sigma); blocked sectors are angles in the
lidar's frame (radians, from < to, each narrower than 2 pi) where the robot's mast returns nothing
usable; with ``motion_distortion`` each beam is taken at its own time within the sweep. Odometry
integrates wheel encoder ticks with the nominal SPARK wheel radius and separation, so the base's
true radii and separation turn into drift. Stamps are in the robot's clock: ``offset_s`` ahead of
the host, running ``drift_ppm`` parts per million fast. Boxes and walls stand where ``map`` puts
them, not where the scenario's map says. Losses come in bursts of ``burst_len`` messages on average
(1: independent). ``max_wheel_accel_radps2: null`` is no limit.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from pipeline.core.reality import (
    NOMINAL_WHEEL_RADIUS_M,
    NOMINAL_WHEEL_SEPARATION_M,
    ActuationProfile,
    BaseProfile,
    ClockProfile,
    LidarProfile,
    MapProfile,
    NetworkProfile,
    OdometryProfile,
    RealityProfile,
)
from pipeline.core.scenario import Scenario
from pipeline.errors import ConfigError, ConfigProblem
from pipeline.mappings import from_mapping, read_yaml

__all__ = [
    "NOMINAL_WHEEL_RADIUS_M",
    "NOMINAL_WHEEL_SEPARATION_M",
    "ActuationProfile",
    "BaseProfile",
    "ClockProfile",
    "LidarProfile",
    "MapProfile",
    "NetworkProfile",
    "OdometryProfile",
    "RealityProfile",
    "bundled_profiles",
    "load_profile",
    "load_profile_for",
    "profile_path",
]
"""The schema lives in :mod:`pipeline.core.reality`; this module finds and loads the profile files."""


def bundled_profiles() -> tuple[str, ...]:
    folder = resources.files("pipeline.twin") / "profiles"
    return tuple(sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml")))


def profile_path(spec: str | Path) -> Path:
    text = str(spec)
    if text in bundled_profiles():
        return Path(str(resources.files("pipeline.twin") / "profiles" / f"{text}.yaml"))
    path = Path(text)
    if not path.suffix and not path.exists():
        raise ConfigError(
            "<profile>",
            [
                ConfigProblem(
                    "profile", text, "a bundled profile (" + ", ".join(bundled_profiles()) + ") or a YAML path"
                )
            ],
        )
    return path


def load_profile(spec: str | Path) -> tuple[str, RealityProfile]:
    """(name, profile) from a bundled name or a YAML path; ConfigError names the file and key."""
    path = profile_path(spec)
    return path.stem, from_mapping(RealityProfile, read_yaml(path), str(path))


def load_profile_for(spec: str | Path, scenario: Scenario) -> tuple[str, RealityProfile]:
    """`load_profile`, then the checks that need the room (one box offset per box at most)."""
    name, profile = load_profile(spec)
    problems = profile.problems_in(len(scenario.obstacles))
    if problems:
        raise ConfigError(str(profile_path(spec)), [ConfigProblem(*p) for p in problems])
    return name, profile
