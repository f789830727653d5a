"""Kalman/RTS smoothing of ground-truth poses: smoothed pose and velocity of a robot at any time.

Each axis (x, y and the unwrapped yaw) follows a constant-velocity model driven by white
acceleration (filterpy's ``Q_discrete_white_noise``); a forward Kalman filter over the measured
poses is followed by a Rauch-Tung-Striebel backward pass (filterpy's ``KalmanFilter.batch_filter``
and ``rts_smoother``), with the time step taken from the stamps, so lost messages are bridged.
A gap longer than `max_gap_s` or a jump faster than `max_jump_mps` (a reset teleports the robot)
starts a new track: nothing is smoothed across it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from pipeline.core.timebase import NS_PER_S


@dataclass(frozen=True)
class SmootherNoise:
    """Measurement noise (m, rad) and process noise (white acceleration, m/s^2 and rad/s^2) of the smoother."""

    position_sigma_m: float = 0.002
    yaw_sigma_rad: float = 0.004
    accel_sigma_mps2: float = 3.0
    angular_accel_sigma_radps2: float = 3.0


@dataclass(frozen=True)
class Track:
    """One smoothed stretch of ground truth.

    `t_ns` (n,) sample times (int ns, the recording's clock); `pose` (n, 3) x, y (m) and unwrapped
    yaw (rad); `velocity` (n, 3) vx, vy (m/s, map frame) and yaw rate (rad/s); `velocity_std` (n, 3)
    their posterior standard deviations.
    """

    t_ns: np.ndarray
    pose: np.ndarray
    velocity: np.ndarray
    velocity_std: np.ndarray

    @property
    def start_ns(self) -> int:
        return int(self.t_ns[0])

    @property
    def end_ns(self) -> int:
        return int(self.t_ns[-1])

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / NS_PER_S

    def body_velocity(self) -> np.ndarray:
        """(n, 2) forward speed (m/s) and yaw rate (rad/s) in the robot's frame."""
        yaw = self.pose[:, 2]
        forward = np.cos(yaw) * self.velocity[:, 0] + np.sin(yaw) * self.velocity[:, 1]
        return np.stack([forward, self.velocity[:, 2]], axis=1)

    def at(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose (m, 3) and velocity (m, 3) at times `t_ns` (m,) within the track (NaN outside).

        Poses follow a cubic Hermite curve through the smoothed poses and velocities; velocities are
        interpolated linearly.
        """
        t = np.asarray(t_ns, dtype=np.int64)
        pose = np.full((len(t), 3), np.nan)
        vel = np.full((len(t), 3), np.nan)
        inside = (t >= self.t_ns[0]) & (t <= self.t_ns[-1])
        if not inside.any() or len(self.t_ns) < 2:
            if len(self.t_ns) == 1:
                same = t == self.t_ns[0]
                pose[same], vel[same] = self.pose[0], self.velocity[0]
            return pose, vel
        ti = t[inside]
        k = np.clip(np.searchsorted(self.t_ns, ti, side="right") - 1, 0, len(self.t_ns) - 2)
        h = (self.t_ns[k + 1] - self.t_ns[k]) / NS_PER_S
        s = ((ti - self.t_ns[k]) / NS_PER_S / h)[:, None]
        h = h[:, None]
        p0, p1 = self.pose[k], self.pose[k + 1]
        v0, v1 = self.velocity[k], self.velocity[k + 1]
        h00 = 2 * s**3 - 3 * s**2 + 1
        h10 = s**3 - 2 * s**2 + s
        h01 = -2 * s**3 + 3 * s**2
        h11 = s**3 - s**2
        pose[inside] = h00 * p0 + h10 * h * v0 + h01 * p1 + h11 * h * v1
        vel[inside] = (1 - s) * v0 + s * v1
        return pose, vel


@dataclass(frozen=True)
class Trajectory:
    """A robot's smoothed ground truth: tracks in time order (gaps and resets between them)."""

    tracks: tuple[Track, ...]

    def at(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose (m, 3) and velocity (m, 3) at times `t_ns` (m,); NaN where no track covers a time."""
        t = np.asarray(t_ns, dtype=np.int64)
        pose = np.full((len(t), 3), np.nan)
        vel = np.full((len(t), 3), np.nan)
        for track in self.tracks:
            sel = (t >= track.start_ns) & (t <= track.end_ns)
            if sel.any():
                pose[sel], vel[sel] = track.at(t[sel])
        return pose, vel

    def track_index(self, t_ns: np.ndarray) -> np.ndarray:
        """(m,) index of the track covering each time, -1 where none does."""
        t = np.asarray(t_ns, dtype=np.int64)
        out = np.full(len(t), -1)
        for i, track in enumerate(self.tracks):
            out[(t >= track.start_ns) & (t <= track.end_ns)] = i
        return out


def _transition(dt: float) -> np.ndarray:
    """Transition F (6 x 6; state x, vx, y, vy, yaw, yaw rate) of a step of dt seconds."""
    F = np.eye(6)
    F[0, 1] = F[2, 3] = F[4, 5] = dt
    return F


def _process_noise(dt: float, noise: SmootherNoise) -> np.ndarray:
    """Process noise Q (6 x 6) of a step of dt seconds: white acceleration per axis."""
    Q = np.zeros((6, 6))
    if dt <= 0:
        return Q
    unit = Q_discrete_white_noise(2, dt=dt, var=1.0)
    variances = (noise.accel_sigma_mps2**2, noise.accel_sigma_mps2**2, noise.angular_accel_sigma_radps2**2)
    for axis, var in enumerate(variances):
        Q[2 * axis : 2 * axis + 2, 2 * axis : 2 * axis + 2] = unit * var
    return Q


def smooth_track(t_ns: np.ndarray, pose: np.ndarray, noise: SmootherNoise | None = None) -> Track:
    """RTS-smoothed track through poses (n, 3) (x m, y m, yaw rad) at strictly increasing times `t_ns` (n,)."""
    noise = noise or SmootherNoise()
    t = np.asarray(t_ns, dtype=np.int64)
    z = np.array(pose, dtype=np.float64)
    z[:, 2] = np.unwrap(z[:, 2])
    n = len(t)
    kf = KalmanFilter(dim_x=6, dim_z=3)
    kf.H = np.zeros((3, 6))
    kf.H[0, 0] = kf.H[1, 2] = kf.H[2, 4] = 1.0
    kf.R = np.diag([noise.position_sigma_m**2, noise.position_sigma_m**2, noise.yaw_sigma_rad**2])
    kf.x = np.array([z[0, 0], 0.0, z[0, 1], 0.0, z[0, 2], 0.0])
    kf.P = np.diag([noise.position_sigma_m**2, 1.0, noise.position_sigma_m**2, 1.0, noise.yaw_sigma_rad**2, 1.0])
    dts = np.diff(t, prepend=t[0]) / NS_PER_S
    q_cache: dict[int, np.ndarray] = {}
    Fs: list[np.ndarray] = []
    Qs: list[np.ndarray] = []
    for dt in dts:
        key = round(float(dt) * 1e4)  # process noise per 0.1 ms of step length
        if key not in q_cache:
            q_cache[key] = _process_noise(key / 1e4, noise)
        Fs.append(_transition(float(dt)))
        Qs.append(q_cache[key])
    means, covs, _, _ = kf.batch_filter(list(z), Fs=Fs, Qs=Qs)
    xs, ps, _, _ = kf.rts_smoother(means, covs, Fs=Fs, Qs=Qs)
    xs = np.asarray(xs).reshape(n, 6)
    ps = np.asarray(ps)
    velocity_std = np.sqrt(np.stack([ps[:, 1, 1], ps[:, 3, 3], ps[:, 5, 5]], axis=1))
    return Track(t, xs[:, [0, 2, 4]].copy(), xs[:, [1, 3, 5]].copy(), velocity_std)


def split_points(t_ns: np.ndarray, pose: np.ndarray, max_gap_s: float, max_jump_mps: float) -> np.ndarray:
    """Indices where a new track starts: after a gap longer than `max_gap_s` or a jump faster than `max_jump_mps`."""
    dt = np.diff(t_ns) / NS_PER_S
    step = np.hypot(np.diff(pose[:, 0]), np.diff(pose[:, 1]))
    fast = step > max_jump_mps * np.maximum(dt, 1e-3)
    return np.flatnonzero((dt > max_gap_s) | fast) + 1


def smooth_trajectory(
    t_ns: np.ndarray,
    pose: np.ndarray,
    noise: SmootherNoise | None = None,
    max_gap_s: float = 0.3,
    max_jump_mps: float = 3.0,
    windows: Sequence[tuple[int, int]] | None = None,
    min_samples: int = 3,
) -> Trajectory:
    """Smoothed tracks of a robot's ground truth (n, 3) at times `t_ns` (n,), split at gaps and jumps.

    Samples are sorted and duplicates dropped first; with `windows` ((start_ns, end_ns) pairs, e.g.
    episodes) only samples inside a window are used and no track crosses a window's edge. Tracks of
    fewer than `min_samples` samples are dropped.
    """
    t = np.asarray(t_ns, dtype=np.int64)
    p = np.asarray(pose, dtype=np.float64)
    order = np.argsort(t, kind="stable")
    t, p = t[order], p[order]
    keep = np.ones(len(t), dtype=bool)
    keep[1:] = np.diff(t) > 0
    t, p = t[keep], p[keep]
    pieces: list[tuple[np.ndarray, np.ndarray]] = []
    spans = windows if windows is not None else [(int(t[0]), int(t[-1]))] if len(t) else []
    for start, end in spans:
        sel = (t >= start) & (t <= end)
        ts, ps = t[sel], p[sel]
        if len(ts) == 0:
            continue
        cuts = split_points(ts, ps, max_gap_s, max_jump_mps)
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(ts)], strict=True):
            pieces.append((ts[a:b], ps[a:b]))
    tracks = [smooth_track(ts, ps, noise) for ts, ps in pieces if len(ts) >= min_samples]
    return Trajectory(tuple(tracks))
