"""The twin's sensors, clocks and links, written for the twin alone (nothing here comes from the simulator).

- :class:`LidarSweep`: a spinning 2D lidar. Beam k of a sweep that starts at t0 is taken at
  t0 + k / (beams * rate_hz) when the profile asks for motion distortion (at the sweep's start
  otherwise), from the lidar's pose at that moment: the base pose composed with the mounting offset
  (x, y, yaw). Noise grows with range (sigma = noise_sigma_m + noise_per_m * r), plus a bias;
  dropouts read +inf (no return), beams in a blocked sector read the mast's distance (below
  range_min: invalid), beyond range_max no return. As a real 2-D lidar: ranges in steps of
  ``range_step_m``; a per-beam noise factor (mean square 1, fixed per unit); mixed pixels at depth
  edges (a return between the near and the far surface); no return read as the driver's convention
  (+inf, 0, range_max or NaN); beams off their stated angles (fixed per unit); each sweep's period
  wandering about the nominal one; whole scans lost in the driver (:meth:`LidarSweep.dropped`).
- :class:`EncoderOdometry`: wheel encoder ticks integrated with the NOMINAL wheel radius and
  separation, so the base's true radii and separation become drift, as on a real robot; on top,
  per episode, a scale error, a yaw-rate scale error and a heading drift per metre, each drawn
  from N(0, drift_per_m).
- :class:`RobotClock`: stamps in the robot's clock, ``offset_s`` ahead and ``drift_ppm`` fast.
- :class:`BurstLoss`: message loss in bursts (a two-state Gilbert-Elliott chain per stream with
  the profile's loss probability as its stationary loss rate and ``burst_len`` as its mean burst
  length; ``burst_len`` 1 loses each message independently).
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.core.timebase import NS_PER_S
from pipeline.twin.profile import (
    NOMINAL_WHEEL_RADIUS_M,
    NOMINAL_WHEEL_SEPARATION_M,
    ClockProfile,
    LidarProfile,
    OdometryProfile,
)

LIDAR_RANGE_MIN_M = 0.12
LIDAR_RANGE_MAX_M = 8.0
"""The twin's lidar: a 360-degree scanner measuring 0.12 to 8 m."""
MAST_RANGE_M = 0.04
"""What a beam in a blocked sector reads: the mast, closer than the lidar's minimum range."""
DEPTH_EDGE_M = 0.1
"""A beam that hits another surface than the previous beam, nearer or farther by more than this, straddles a depth
edge."""
NO_RETURN = {"inf": math.inf, "zero": 0.0, "max": LIDAR_RANGE_MAX_M, "nan": math.nan}
"""What a beam without a return reads, per the profile's ``no_return`` convention."""


def wrap(a: np.ndarray | float) -> np.ndarray:
    return np.angle(np.exp(1j * np.asarray(a, dtype=float)))


class LidarSweep:
    """One robot's lidar: `beams` beams per sweep, `rate_hz` sweeps per second, starting at `t0_ns`."""

    def __init__(
        self, profile: LidarProfile, rng: np.random.Generator, t0_ns: int = 0, unit: np.random.Generator | None = None
    ) -> None:
        """`unit` draws what is fixed per lidar unit (its beams' angle errors and noise factors; `rng` where None):
        the twin gives each robot's lidar the same unit in every episode."""
        self.profile = profile
        self.rng = rng
        made = rng if unit is None else unit
        self.beams = profile.beams
        self.nominal_period_ns = round(NS_PER_S / profile.rate_hz)
        self.period_ns = self.nominal_period_ns
        self.angles = 2 * math.pi * np.arange(self.beams) / self.beams  # in the lidar's frame
        # what differs per unit is drawn only where the profile asks for it (a profile without it keeps its streams)
        if profile.beam_angle_jitter_rad > 0:
            self.angles = self.angles + made.normal(0.0, profile.beam_angle_jitter_rad, self.beams)
        self.noise_factor = np.ones(self.beams)
        if profile.beam_noise_spread > 0:
            s = profile.beam_noise_spread
            self.noise_factor = np.exp(s * made.standard_normal(self.beams) - s * s)  # E[factor^2] = 1
        self.blocked = np.zeros(self.beams, dtype=bool)
        for start, end in profile.blocked_sectors_rad:
            rel = np.mod(self.angles - start, 2 * math.pi)
            self.blocked |= rel <= (end - start)
        self.mount = np.array([profile.mount_xy_m[0], profile.mount_xy_m[1], profile.mount_yaw_rad])
        # the beam before the next one taken (across sweeps: the first beam's neighbour is the last): its true range
        # and what it hit
        self._previous_true = math.nan
        self._previous_surface = -2
        self.restart(t0_ns)

    def restart(self, t0_ns: int) -> None:
        self.start_ns = t0_ns
        self.ranges = np.full(self.beams, np.inf)
        self.taken = 0
        wander = self.profile.rate_wander
        if wander > 0:
            factor = 1.0 + wander * float(np.clip(self.rng.standard_normal(), -4.0, 4.0))
            self.period_ns = round(self.nominal_period_ns * factor)

    def dropped(self) -> bool:
        """Whether the sweep just completed is lost in the driver (never published)."""
        p = self.profile.scan_drop_prob
        return p > 0 and bool(self.rng.random() < p)

    def beam_time_ns(self, k: np.ndarray | int) -> np.ndarray:
        """When beam k of the current sweep is taken."""
        if not self.profile.motion_distortion:
            return np.zeros_like(np.asarray(k)) + self.start_ns
        return self.start_ns + (np.asarray(k) * self.period_ns) // self.beams

    def due(self, until_ns: int) -> np.ndarray:
        """Indices of the beams of this sweep taken at or before `until_ns` and not taken yet."""
        if self.taken >= self.beams:
            return np.arange(0)
        if not self.profile.motion_distortion:
            return np.arange(self.taken, self.beams) if until_ns >= self.start_ns else np.arange(0)
        k = np.arange(self.taken, self.beams)
        return k[self.beam_time_ns(k) <= until_ns]

    def pose_of_lidar(self, base_pose: np.ndarray) -> tuple[np.ndarray, float]:
        """(origin xy, heading) of the lidar for a base pose (x, y, yaw)."""
        c, s = math.cos(base_pose[2]), math.sin(base_pose[2])
        dx, dy, dyaw = self.mount
        return np.array([base_pose[0] + c * dx - s * dy, base_pose[1] + s * dx + c * dy]), float(base_pose[2] + dyaw)

    def world_angles(self, heading: float, k: np.ndarray) -> np.ndarray:
        return np.asarray(heading + self.angles[k], dtype=float)

    def measure(self, k: np.ndarray, true_m: np.ndarray, surfaces: np.ndarray | None = None) -> None:
        """Store the measured ranges of beams `k` from their true ranges (and what each hit: a depth edge is a change
        of surface; without `surfaces`, any change of range beyond `DEPTH_EDGE_M`)."""
        p = self.profile
        true = np.asarray(true_m, dtype=float)
        out = true.copy()
        if p.mixed_pixel_prob > 0 and len(k):
            # a beam straddling a depth edge (another surface, nearer or farther) returns somewhere between the two
            before = np.concatenate([[self._previous_true], true[:-1]])
            both = np.isfinite(true) & np.isfinite(before)
            edge = both & (np.abs(np.where(both, true, 0.0) - np.where(both, before, 0.0)) > DEPTH_EDGE_M)
            if surfaces is not None:
                hit = np.asarray(surfaces)[: len(k)]
                edge &= hit != np.concatenate([[self._previous_surface], hit[:-1]])
                self._previous_surface = int(hit[-1])
            mixed = edge & (self.rng.random(out.shape) < p.mixed_pixel_prob)
            if mixed.any():
                near, far = np.minimum(true, before), np.maximum(true, before)
                out = np.where(mixed, near + self.rng.random(out.shape) * (far - near), out)
            self._previous_true = float(true[-1])
        finite = np.isfinite(out)
        sigma = (p.noise_sigma_m + p.noise_per_m * np.where(finite, out, 0.0)) * self.noise_factor[k]
        noise = self.rng.normal(0.0, 1.0, size=out.shape) * sigma
        out = np.where(finite, out + p.bias_m + noise, np.inf)
        if p.range_step_m > 0:
            out = np.where(finite, np.round(out / p.range_step_m) * p.range_step_m, out)
        out = np.where(finite & (out > LIDAR_RANGE_MAX_M), np.inf, out)
        if p.dropout_prob > 0:
            out = np.where(self.rng.random(out.shape) < p.dropout_prob, np.inf, out)
        out = np.maximum(out, 0.0)
        if p.no_return != "inf":
            out = np.where(np.isinf(out), NO_RETURN[p.no_return], out)
        self.ranges[k] = np.where(self.blocked[k], MAST_RANGE_M, out)
        self.taken = int(k[-1]) + 1 if len(k) else self.taken

    @property
    def complete(self) -> bool:
        return self.taken >= self.beams

    @property
    def end_ns(self) -> int:
        return self.start_ns + self.period_ns


class EncoderOdometry:
    """Odometry of `n` robots from wheel angles, integrated with the nominal wheel geometry."""

    def __init__(self, n: int, profile: OdometryProfile, rng: np.random.Generator) -> None:
        self.n = n
        self.profile = profile
        self.rng = rng
        self.ticks_per_rev = profile.encoder_ticks_per_rev
        self.pose = np.zeros((n, 3))
        self.velocity = np.zeros((n, 2))
        self._last = np.zeros((n, 2))
        self._errors = np.zeros((3, n))

    def read_angles(self, wheel_angles: np.ndarray) -> np.ndarray:
        """What the encoders report: whole ticks (the angle of the last tick passed), or exact angles."""
        if self.ticks_per_rev is None:
            return np.asarray(wheel_angles, dtype=float).copy()
        per_tick = 2 * math.pi / self.ticks_per_rev
        return np.floor(np.asarray(wheel_angles) / per_tick) * per_tick

    def reset(self, poses: np.ndarray, wheel_angles: np.ndarray) -> None:
        """Odometry starts at `poses` (the driver is told where it stands) with the encoders as they read now."""
        self.pose = np.array(poses, dtype=float)
        self.velocity = np.zeros((self.n, 2))
        self._last = self.read_angles(wheel_angles)
        d = self.profile.drift_per_m
        self._errors = self.rng.normal(0.0, d, size=(3, self.n)) if d > 0 else np.zeros((3, self.n))

    def update(self, wheel_angles: np.ndarray, dt_s: float) -> None:
        """Integrate the encoders' change since the last update (midpoint rule)."""
        now = self.read_angles(wheel_angles)
        dphi = now - self._last
        self._last = now
        r, sep = NOMINAL_WHEEL_RADIUS_M, NOMINAL_WHEEL_SEPARATION_M
        ds = r * (dphi[:, 0] + dphi[:, 1]) / 2
        dth = r * (dphi[:, 1] - dphi[:, 0]) / sep
        scale, yaw_scale, heading_per_m = self._errors
        ds = ds * (1 + scale)
        dth = dth * (1 + yaw_scale) + heading_per_m * np.abs(ds)
        mid = self.pose[:, 2] + dth / 2
        self.pose[:, 0] += ds * np.cos(mid)
        self.pose[:, 1] += ds * np.sin(mid)
        self.pose[:, 2] = wrap(self.pose[:, 2] + dth)
        if dt_s > 0:
            self.velocity = np.stack([ds / dt_s, dth / dt_s], axis=1)


class RobotClock:
    """The robots' clock: host time `host_ns` reads ``host_ns + offset + (host_ns - epoch) * drift``."""

    def __init__(self, profile: ClockProfile, epoch_ns: int) -> None:
        self.offset_ns = round(profile.offset_s * NS_PER_S)
        self.drift = profile.drift_ppm * 1e-6
        self.epoch_ns = epoch_ns

    def stamp(self, host_ns: int) -> int:
        return host_ns + self.offset_ns + round((host_ns - self.epoch_ns) * self.drift)


class BurstLoss:
    """Loss in bursts: a good/bad chain per stream; stationary loss `loss_prob`, mean burst `burst_len`."""

    def __init__(self, loss_prob: float, burst_len: float, rng: np.random.Generator) -> None:
        self.p = loss_prob
        self.rng = rng
        self.independent = burst_len <= 1.0 or loss_prob <= 0.0
        self.leave_bad = 1.0 / burst_len
        self.enter_bad = min(1.0, loss_prob * self.leave_bad / (1.0 - loss_prob)) if loss_prob < 1 else 1.0
        self._bad: dict[str, bool] = {}

    def lost(self, stream: str) -> bool:
        """Whether the next message of `stream` is lost."""
        if self.p <= 0:
            return False
        if self.independent:
            return bool(self.rng.random() < self.p)
        bad = self._bad.get(stream)
        if bad is None:
            bad = bool(self.rng.random() < self.p)  # start in the stationary distribution
        else:
            bad = bool(self.rng.random() >= self.leave_bad) if bad else bool(self.rng.random() < self.enter_bad)
        self._bad[stream] = bad
        return bad
