"""The physical quantities of a robot's reality, each defined once: its name, unit, domain and meaning.

The simulator's world sections (:mod:`pipeline.params`: ``world.lidar``, ``world.actuation``...), the hardware twin's
reality profiles (:mod:`pipeline.core.reality`) and calibration's bounds (:func:`pipeline.core.reality.profile_bounds`)
take a quantity's domain from here, so the three agree by construction: a lidar's range bias is the same quantity,
with the same bounds, whether the simulator plays it, the twin plays it or calibration estimates it.

A domain is an interval: `low` and `high` inclusive unless `low_open` / `high_open` (a probability of 1, a gain of 0
are no value the quantity can take). Where the simulator and the twin take the same quantity with different defaults
(the simulator's are an ideal robot's, a profile names every key it needs), :meth:`Quantity.setting` gives each its
own default with the one domain.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from pipeline.mappings import setting


@dataclass(frozen=True)
class Quantity:
    """One physical quantity: `name` (its key in both the simulator's section and the profile's), `unit`, its
    domain [`low`, `high`] (ends open where said) and what it means."""

    name: str
    unit: str
    low: float
    high: float
    meaning: str
    low_open: bool = False
    high_open: bool = False
    per_element: bool = False
    """A list of values (``mount_xy_m``): the domain is each element's."""

    def bounds(self) -> dict[str, float | None]:
        """The domain as a setting's bounds (``ge``/``gt``, ``le``/``lt``)."""
        return {
            "ge": None if self.low_open else self.low,
            "gt": self.low if self.low_open else None,
            "le": None if self.high_open else self.high,
            "lt": self.high if self.high_open else None,
        }

    def setting(
        self,
        default: Any = dataclasses.MISSING,
        *,
        optional: bool = False,
        min_len: int | None = None,
        max_len: int | None = None,
    ) -> Any:
        """A dataclass field of this quantity: its domain's bounds, `default` (none: a key that must be given)."""
        b = self.bounds()
        return setting(
            default, ge=b["ge"], gt=b["gt"], le=b["le"], lt=b["lt"], min_len=min_len, max_len=max_len, optional=optional
        )


# -- the lidar -------------------------------------------------------------------------------------------------
NOISE_SIGMA_M = Quantity("noise_sigma_m", "m", 0.0, 1.0, "the range noise's standard deviation at zero range")
NOISE_PER_M = Quantity("noise_per_m", "m/m", 0.0, 0.2, "the range noise's growth with range (sigma + per_m x range)")
DROPOUT_PROB = Quantity(
    "dropout_prob", "probability", 0.0, 1.0, "a beam returning nothing (a lidar that never returns is none)",
    high_open=True,
)  # fmt: skip
BIAS_M = Quantity("bias_m", "m", -0.5, 0.5, "added to every range")
MOUNT_YAW_RAD = Quantity("mount_yaw_rad", "rad", -3.15, 3.15, "the lidar's mounting yaw on the robot")
MOUNT_XY_M = Quantity(
    "mount_xy_m", "m", -0.3, 0.3, "where the beams start in the robot's frame (forward, left)", per_element=True
)
RANGE_STEP_M = Quantity("range_step_m", "m", 0.0, 0.05, "ranges reported in steps of this (0: continuous)")
BEAM_NOISE_SPREAD = Quantity(
    "beam_noise_spread", "log-sd", 0.0, 1.0, "each beam's noise scaled by a factor exp(s z - s^2), fixed per beam"
)
MIXED_PIXEL_PROB = Quantity(
    "mixed_pixel_prob", "probability", 0.0, 1.0, "at a depth edge, a return between the near and the far surface"
)
SCAN_DROP_PROB = Quantity(
    "scan_drop_prob", "probability", 0.0, 1.0, "a whole scan lost in the lidar's driver (USB), before the network",
    high_open=True,
)  # fmt: skip

# -- the drive -------------------------------------------------------------------------------------------------
DELAY_S = Quantity("delay_s", "s", 0.0, 1.0, "from a command to its effect at the wheels")
TIME_CONSTANT_S = Quantity(
    "time_constant_s", "s", 0.0, 2.0, "the first-order lag of the body's velocity", low_open=True
)
LINEAR_GAIN = Quantity("linear_gain", "1", 0.0, 5.0, "forward speed realized per speed commanded", low_open=True)
ANGULAR_GAIN = Quantity("angular_gain", "1", 0.0, 5.0, "turn rate realized per rate commanded", low_open=True)
DEADBAND_RADPS = Quantity("deadband_radps", "rad/s", 0.0, 50.0, "wheel speeds below this do not turn the wheel")
WHEEL_RADIUS_M = Quantity("wheel_radius_m", "m", 0.0, 0.5, "a wheel's radius", low_open=True)
WHEEL_SEPARATION_M = Quantity("wheel_separation_m", "m", 0.0, 2.0, "between the wheels' contact points", low_open=True)

# -- odometry, network, clock ----------------------------------------------------------------------------------
DRIFT_PER_M = Quantity("drift_per_m", "m/m", 0.0, 1.0, "odometry's position error per metre travelled")
LOSS_PROB = Quantity(
    "loss_prob", "probability", 0.0, 1.0, "a message lost on the network (each stream)", high_open=True
)
BURST_LEN = Quantity("burst_len", "messages", 1.0, 1000.0, "the mean length of a run of lost messages (1: independent)")
JITTER_S = Quantity("jitter_s", "s", 0.0, 1.0, "a message's delay varies by up to this")
CLOCK_OFFSET_S = Quantity(
    "offset_s", "s", -1e9, 1e9, "the robots' clock ahead of the host's (a robot without time sync reads its boot)"
)
CLOCK_DRIFT_PPM = Quantity("drift_ppm", "ppm", -1e4, 1e4, "the robots' clock running fast, parts per million")

SHARED: dict[str, tuple[str, str, Quantity]] = {
    f"{group}.{key}": (section, sim_key, q)
    for section, sim_key, group, key, q in (
        ("lidar", "noise_sigma_m", "lidar", "noise_sigma_m", NOISE_SIGMA_M),
        ("lidar", "noise_per_m", "lidar", "noise_per_m", NOISE_PER_M),
        ("lidar", "dropout_prob", "lidar", "dropout_prob", DROPOUT_PROB),
        ("lidar", "bias_m", "lidar", "bias_m", BIAS_M),
        ("lidar", "mount_yaw_rad", "lidar", "mount_yaw_rad", MOUNT_YAW_RAD),
        ("lidar", "mount_xy_m", "lidar", "mount_xy_m", MOUNT_XY_M),
        ("lidar", "range_step_m", "lidar", "range_step_m", RANGE_STEP_M),
        ("lidar", "beam_noise_spread", "lidar", "beam_noise_spread", BEAM_NOISE_SPREAD),
        ("lidar", "mixed_pixel_prob", "lidar", "mixed_pixel_prob", MIXED_PIXEL_PROB),
        ("lidar", "scan_drop_prob", "lidar", "scan_drop_prob", SCAN_DROP_PROB),
        ("actuation", "delay_s", "actuation", "delay_s", DELAY_S),
        ("actuation", "time_constant_s", "actuation", "time_constant_s", TIME_CONSTANT_S),
        ("actuation", "linear_gain", "actuation", "linear_gain", LINEAR_GAIN),
        ("actuation", "angular_gain", "actuation", "angular_gain", ANGULAR_GAIN),
        ("actuation", "deadband_radps", "base", "deadband_radps", DEADBAND_RADPS),
        ("actuation", "wheel_radius_m", "base", "wheel_radius_left_m", WHEEL_RADIUS_M),
        ("actuation", "wheel_radius_m", "base", "wheel_radius_right_m", WHEEL_RADIUS_M),
        ("actuation", "wheel_separation_m", "base", "wheel_separation_m", WHEEL_SEPARATION_M),
        ("odometry", "drift_per_m", "odometry", "drift_per_m", DRIFT_PER_M),
        ("network", "loss_prob", "network", "loss_prob", LOSS_PROB),
        ("network", "burst_len", "network", "burst_len", BURST_LEN),
        ("network", "jitter_s", "network", "jitter_s", JITTER_S),
        ("network", "clock_offset_s", "clock", "offset_s", CLOCK_OFFSET_S),
        ("network", "clock_drift_ppm", "clock", "drift_ppm", CLOCK_DRIFT_PPM),
    )
}
"""The quantities the simulator's world (``world.<section>.<key>``) and the reality profile (``<group>.<key>``, the
dict's key) both take: (the simulator's section, its key, the quantity)."""
