"""The floor under the wheels: did they slip, and what does that say about its friction.

Each robot-episode's odometry (wheel travel read with the nominal wheels, scaled to the calibrated ones) and its true
poses are cut into windows of `WINDOW_S`. A window slips where the wheels' travel and the body's disagree by more
than `SLIP_SHARE` of the travel (and `SLIP_FLOOR_M` / `SLIP_FLOOR_RAD`), forward or in the turn. A slipping window
whose body still moves is the floor giving way (traction); one whose body stands is a push against something.

The body's acceleration per window (the change of its forward speed and its centripetal part v w) is what the
floor had to transmit. The friction coefficient itself is never identified: the traction force is friction times
the weight on the driven wheels, and the recording does not tell that share (the casters carry the rest). So
``base.friction`` is reported unidentified with what the recording does say: without slip, the largest acceleration
the floor transmitted (friction is at least that over g); with slip, the acceleration at which it gave way.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.calibration.estimates import Estimate
from pipeline.calibration.odometry import OdometryEpisode, continuous_stretches, pose_increments
from pipeline.core.timebase import NS_PER_S

G_MPS2 = 9.81
WINDOW_S = 0.2
"""Length of the windows that wheel and body travel are compared over (s)."""
SLIP_SHARE = 0.25
SLIP_FLOOR_M = 0.012
SLIP_FLOOR_RAD = 0.06
MOVING_MPS = 0.03
"""A body slower than this in a slipping window stands (a push against something), it does not slide."""
MIN_SLIPS = 5
"""Slipping windows of a moving body needed to read the acceleration where the floor gives way."""
TRANSMITTED_QUANTILE = 0.99


@dataclass(frozen=True)
class FloorFit:
    """``base.friction`` (never identified; its reason says what the recording shows), the windows looked at, the
    ones where the wheels slipped under a moving body and against something, and the accelerations (m/s^2)."""

    friction: Estimate
    windows: int
    slipping: int
    pushing: int
    transmitted_mps2: float | None
    slip_mps2: float | None


def _windows(episode: OdometryEpisode) -> list[tuple[int, int]]:
    """(first, last) sample of each window of `WINDOW_S` inside one stretch of continuous truth."""
    piece = continuous_stretches(episode)
    t = episode.t_ns
    out: list[tuple[int, int]] = []
    begin = 0
    for i in range(1, len(t)):
        if piece[i] != piece[begin]:
            begin = i
        elif t[i] - t[begin] >= WINDOW_S * NS_PER_S:
            out.append((begin, i))
            begin = i
    return out


def _episode_windows(episode: OdometryEpisode, wheel_scale: float) -> np.ndarray:
    """(k, 5) per window: wheel travel (m), body travel (m), wheel turn, body turn (rad), duration (s); consecutive
    windows of one stretch follow each other."""
    bounds = _windows(episode)
    if not bounds:
        return np.zeros((0, 5))
    fo, _, to = pose_increments(episode.odom)
    ft, _, tt = pose_increments(episode.truth)
    cum = [np.r_[0.0, np.cumsum(x)] for x in (fo * wheel_scale, ft, to * wheel_scale, tt)]
    rows = [[c[b] - c[a] for c in cum] + [float(episode.t_ns[b] - episode.t_ns[a]) / NS_PER_S] for a, b in bounds]
    return np.asarray(rows, dtype=float)


def estimate_floor(episodes: Sequence[OdometryEpisode], wheel_scale: float = 1.0) -> FloorFit:
    """What the recording says about the floor (see the module's description). `wheel_scale`: the calibrated mean
    wheel radius over the nominal one the odometry reads its wheels with (1 where unknown)."""
    slips: list[float] = []
    transmitted: list[float] = []
    windows = driving = slipping = pushing = 0
    for episode in episodes:
        w = _episode_windows(episode, wheel_scale)
        if len(w) < 3:
            continue
        wheel, body, wheel_turn, body_turn, dt = w.T
        v = body / dt
        omega = body_turn / dt
        # the change of forward speed between neighbouring windows, and the turn's centripetal part
        accel = np.zeros(len(w))
        accel[1:-1] = (v[2:] - v[:-2]) / (dt[2:] / 2 + dt[1:-1] + dt[:-2] / 2)
        total = np.hypot(accel, v * omega)
        slip = (np.abs(wheel - body) > np.maximum(SLIP_SHARE * np.abs(wheel), SLIP_FLOOR_M)) | (
            np.abs(wheel_turn - body_turn) > np.maximum(SLIP_SHARE * np.abs(wheel_turn), SLIP_FLOOR_RAD)
        )
        inner = np.zeros(len(w), dtype=bool)
        inner[1:-1] = True
        # a window next to a slipping one shares its speed estimate: neither says what the floor transmitted
        near = slip | np.r_[False, slip[:-1]] | np.r_[slip[1:], False]
        moving = np.abs(v) >= MOVING_MPS
        windows += len(w)
        driving += int(np.sum(moving))
        slipping += int(np.sum(slip & moving))
        pushing += int(np.sum(slip & ~moving))
        slips += total[slip & moving & inner].tolist()
        transmitted += total[~near & inner].tolist()
    top = float(np.quantile(transmitted, TRANSMITTED_QUANTILE)) if transmitted else None
    slip_at = float(np.median(slips)) if len(slips) >= MIN_SLIPS else None
    if top is None:
        reason = f"no windows of {WINDOW_S:g} s of odometry and truth to compare the wheels' travel with the body's"
    elif driving == 0:
        reason = (
            f"robots must drive for the floor to show anything: no body moved faster than {MOVING_MPS:g} m/s in "
            f"{windows} windows of {WINDOW_S:g} s"
        )
    elif slip_at is None:
        reason = (
            f"the wheels did not slip under a moving body in {windows} windows of {WINDOW_S:g} s ({pushing} slipped "
            f"pushing against something): the floor transmitted up to {top:.2f} m/s^2 (the "
            f"{TRANSMITTED_QUANTILE * 100:.0f}th percentile over the windows), so friction is at least "
            f"{top / G_MPS2:.2f} (more where the casters carry weight); hard starts or fast turns on this floor would "
            "show where it gives way"
        )
    else:
        reason = (
            f"the wheels slipped under a moving body in {slipping} of {windows} windows of {WINDOW_S:g} s, at a "
            f"median acceleration of {slip_at:.2f} m/s^2 (up to {top:.2f} m/s^2 passed without slip): friction is "
            f"about {slip_at / G_MPS2:.2f} over the share of the weight on the driven wheels, which the recording "
            "does not give"
        )
    return FloorFit(Estimate.unidentifiable(reason, "", windows), windows, slipping, pushing, top, slip_at)
