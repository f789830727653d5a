"""Settings of the calibration: what to estimate, the smoother's noise, and the data selection thresholds."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from pipeline.errors import ConfigError, ConfigProblem
from pipeline.mappings import from_mapping, merge, setting, to_mapping

Part = Literal["lidar", "actuation", "odometry", "network"]
PARTS: tuple[Part, ...] = ("lidar", "actuation", "odometry", "network")


@dataclass(frozen=True)
class CalibrationSettings:
    """How the calibration reads recordings; every threshold carries its unit in its name."""

    parts: tuple[Part, ...] = setting(PARTS, min_len=1)
    """The groups of the reality profile to estimate; a recording must hold the topics they need."""
    scenario: str = setting("", allow_empty=True)
    """The scenario the recordings must come from (a bundled name or a YAML path); empty: the recordings' own."""
    pose_source: Literal["auto", "ground_truth", "scans"] = setting("auto")
    """Where the robots' poses come from: motion capture (``/<ns>/ground_truth``), localization from their scans
    and odometry against the map (``scans``), or ``auto``: ground truth where every robot has it, else scans."""
    map_file: str = setting("", allow_empty=True)
    """A ROS map_server map (YAML) to localize in; empty: the scenario's walls and boxes."""
    pool: bool = setting(False, optional=True)
    """Pool recordings of different kinds (sim, twin, real) or of different robots; without it they are refused."""
    initial_pose: tuple[float, ...] = setting(())
    """x, y (m), yaw (rad) of the (single) robot at the start of the recording, for localization; empty: global."""
    truth_position_sigma_m: float = setting(0.002, gt=0.0, le=1.0)
    """Measurement noise of ground-truth positions assumed by the smoother."""
    truth_yaw_sigma_rad: float = setting(0.004, gt=0.0, le=1.0)
    """Measurement noise of ground-truth headings assumed by the smoother."""
    truth_accel_sigma_mps2: float = setting(3.0, gt=0.0, le=100.0)
    """Process noise of the constant-velocity model: white acceleration of this spread per axis."""
    truth_angular_accel_sigma_radps2: float = setting(3.0, gt=0.0, le=100.0)
    """Process noise of the constant-velocity model on the heading."""
    truth_max_gap_s: float = setting(0.3, gt=0.0, le=10.0)
    """A gap in ground truth longer than this splits a track (nothing is smoothed across it)."""
    truth_max_jump_mps: float = setting(3.0, gt=0.0)
    """Consecutive ground-truth poses implying a faster motion split a track (a reset teleports the robot)."""
    stationary_speed_mps: float = setting(0.005, gt=0.0)
    """A robot stands still while its smoothed speed stays below this..."""
    stationary_yaw_rate_radps: float = setting(0.01, gt=0.0)
    """...and its smoothed yaw rate below this..."""
    stationary_min_s: float = setting(1.0, gt=0.0)
    """...for at least this long (a stationary span)."""
    lidar_range_margin_m: float = setting(0.3, ge=0.0)
    """Beams whose cast range lies within this of the scan's range limits are not used."""
    lidar_max_incidence_rad: float = setting(math.radians(60.0), gt=0.0, lt=math.pi / 2)
    """Beams hitting a surface at more than this angle from its normal (grazing) are not used."""
    lidar_edge_rad: float = setting(0.02, ge=0.0, le=0.5)
    """Beams whose neighbours within this angle hit another surface (corners, box edges) are not used."""
    lidar_robot_margin_m: float = setting(0.1, ge=0.0)
    """Beams passing closer than this to another robot's body are not used."""
    lidar_mount_search_rad: float = setting(math.pi, gt=0.0, le=math.pi)
    """Half-width of the mounting-yaw search around 0."""
    actuation_delay_max_s: float = setting(1.0, gt=0.0, le=5.0)
    """Largest command delay searched."""
    actuation_min_linear_mps: float = setting(0.05, gt=0.0)
    """Linear commands must reach this for the linear gain to be identifiable."""
    actuation_min_angular_radps: float = setting(0.05, gt=0.0)
    """Turning commands must reach this for the angular gain to be identifiable."""
    actuation_min_steps: int = setting(5, ge=1)
    """At least this many command steps (changes larger than the thresholds above) are needed for delay and lag."""
    actuation_contact_margin_m: float = setting(0.03, ge=0.0)
    """Samples where the robot is closer than this to a wall, box or another robot are left out (contacts)."""
    actuation_min_track_s: float = setting(1.0, gt=0.0)
    """Contact-free stretches shorter than this are not used."""
    command_timeout_s: float = setting(0.5, gt=0.0)
    """A command older than this no longer acts (robot drivers stop after a timeout)."""
    odometry_min_distance_m: float = setting(0.5, gt=0.0)
    """An episode must cover this distance for its odometry scale error and heading drift."""
    odometry_min_turn_rad: float = setting(0.5, gt=0.0)
    """An episode must turn this much in total for its odometry yaw-rate scale error."""
    network_max_gap_s: float = setting(0.5, gt=0.0)
    """Gaps between stamps longer than this are pauses, not lost messages."""
    bootstrap: int = setting(200, ge=20, le=100_000)
    """Bootstrap resamples for the uncertainties that have no closed form."""
    seed: int = setting(0, ge=0)
    """Seed of the bootstrap."""


def calibration_settings(
    data: Mapping[str, Any] | None = None, source: str = "<calibration settings>"
) -> CalibrationSettings:
    """The defaults with the keys of `data` replaced; bad keys or values raise ConfigError naming `source`."""
    settings = from_mapping(CalibrationSettings, merge(to_mapping(CalibrationSettings()), dict(data or {})), source)
    pose = settings.initial_pose
    if len(pose) not in (0, 3) or not all(math.isfinite(v) for v in pose):
        raise ConfigError(
            source, [ConfigProblem("initial_pose", list(pose), "[x_m, y_m, yaw_rad] (three finite numbers) or empty")]
        )
    return settings
