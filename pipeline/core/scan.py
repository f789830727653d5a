"""Reduce a LaserScan-shaped input of any beam count to the policy's N beams.

Semantics follow sensor_msgs/LaserScan and REP 117: a finite value outside
[range_min, range_max] is invalid; +inf means no return within range (free space, reported
as the policy's range_max); -inf means an object closer than range_min (reported as the
policy's range_min); NaN is an erroneous reading and carries no information.

The policy's beam k points at angle ``2 pi k / N`` in the robot frame (k = 0 straight ahead,
counter-clockwise). ``pick`` takes the source beam nearest to that angle; ``sector_min``
takes the nearest valid return among the source beams closer in angle to it than to any other
policy beam (and within +-pi/N of it) (the safe choice
for collision avoidance with sparse beams). A target with no valid source reading reports
range_max (nothing seen).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np

from pipeline.core.errors import ScanError

Reduction = Literal["pick", "sector_min"]


@dataclass(frozen=True)
class ScanGeometry:
    """The angular layout of a source scan (radians) and its valid range (metres)."""

    n_beams: int
    angle_min_rad: float
    angle_increment_rad: float
    range_min_m: float
    range_max_m: float

    def check(self) -> None:
        if self.n_beams < 1:
            raise ScanError(f"a scan needs at least one beam, got {self.n_beams}")
        if not (math.isfinite(self.angle_min_rad) and math.isfinite(self.angle_increment_rad)):
            raise ScanError(
                f"scan angles must be finite, got angle_min={self.angle_min_rad}, "
                f"angle_increment={self.angle_increment_rad}"
            )
        if self.angle_increment_rad == 0.0 and self.n_beams > 1:
            raise ScanError("angle_increment is 0 with more than one beam")
        if not (0.0 <= self.range_min_m < self.range_max_m):
            raise ScanError(
                f"scan range limits must satisfy 0 <= range_min < range_max, got "
                f"range_min={self.range_min_m}, range_max={self.range_max_m}"
            )


@lru_cache(maxsize=64)
def _plan(n_src: int, angle_min: float, inc: float, n_out: int, method: Reduction) -> tuple[np.ndarray, ...]:
    """Index tables mapping source beams to policy beams, cached per geometry."""
    src_angles = angle_min + inc * np.arange(n_src)
    out_angles = 2 * np.pi * np.arange(n_out) / n_out
    # signed angular difference in (-pi, pi] between every target and every source beam
    diff = (src_angles[None, :] - out_angles[:, None] + np.pi) % (2 * np.pi) - np.pi
    if method == "pick":
        return (np.argmin(np.abs(diff), axis=1),)
    # each source beam belongs to the sector of its nearest policy beam (ties: the lower index),
    # provided it lies within half a sector of it (a partial field of view leaves sectors empty)
    nearest = np.argmin(np.abs(diff), axis=0)
    within = np.abs(diff[nearest, np.arange(n_src)]) <= np.pi / n_out + 1e-12
    member = np.zeros((n_out, n_src), dtype=bool)
    member[nearest[within], np.flatnonzero(within)] = True
    return (member,)


@lru_cache(maxsize=64)
def _sectors(n_src: int, angle_min: float, inc: float, n_out: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`sector_min`'s table as runs: (the member source beams, sector by sector; where each non-empty sector's run
    starts in them; (n_out,) which sectors have a member), cached per geometry."""
    (member,) = _plan(n_src, angle_min, inc, n_out, "sector_min")
    _, members = np.nonzero(member)  # row-major: sector by sector
    counts = member.sum(axis=1)
    filled = counts > 0
    starts = (np.cumsum(counts) - counts)[filled]
    for table in (members, starts, filled):
        table.setflags(write=False)  # shared by every caller of this geometry
    return members, starts, filled


def uncovered_beams(geometry: ScanGeometry, n_beams: int) -> list[int]:
    """The policy beams (indices) that no beam of a scan with `geometry` falls within half a sector of.

    A scan with fewer beams or a narrower field of view than the policy was trained on leaves these
    directions blind: `sector_min` reports them as "nothing seen" and `pick` repeats a neighbour.
    """
    geometry.check()
    (member,) = _plan(
        geometry.n_beams, float(geometry.angle_min_rad), float(geometry.angle_increment_rad), n_beams, "sector_min"
    )
    return [int(k) for k in np.flatnonzero(~member.any(axis=1))]


def reduce_scan(
    ranges: np.ndarray,
    geometry: ScanGeometry,
    n_beams: int,
    range_min_m: float,
    range_max_m: float,
    method: Reduction = "sector_min",
) -> np.ndarray:
    """Policy ranges (n_beams,) or (batch, n_beams) in metres from source ranges (..., geometry.n_beams).

    The output lies in [range_min_m, range_max_m] (the policy's limits) and holds no inf or NaN.
    """
    geometry.check()
    if n_beams < 1:
        raise ScanError(f"the policy needs at least one beam, got n_beams={n_beams}")
    arr = np.asarray(ranges, dtype=np.float64)
    if arr.shape[-1:] != (geometry.n_beams,):
        raise ScanError(f"scan has {arr.shape[-1] if arr.ndim else 0} ranges but its geometry says {geometry.n_beams}")
    # normalise to REP 117 classes in one pass: a finite value outside the source's limits is invalid and an invalid
    # one (or NaN) means "nothing seen within range" for a min, as +inf does; -inf is an object closer than range_min
    finite = np.isfinite(arr)
    clean = np.where(
        finite,
        np.where((arr < geometry.range_min_m) | (arr > geometry.range_max_m), np.inf, arr),
        np.where(np.isneginf(arr), range_min_m, np.inf),
    )
    plan = (geometry.n_beams, float(geometry.angle_min_rad), float(geometry.angle_increment_rad), n_beams)
    if method == "pick":
        (table,) = _plan(*plan, method)
        out = clean[..., table]
    elif method == "sector_min":
        members, starts, filled = _sectors(*plan)
        out = np.full((*arr.shape[:-1], n_beams), np.inf)
        if len(members):  # each sector's least return, over its own beams only (a min is exact in any order)
            out[..., filled] = np.minimum.reduceat(clean[..., members], starts, axis=-1)
    else:
        raise ScanError(f"unknown reduction {method!r}; allowed: 'pick', 'sector_min'")
    return np.minimum(np.maximum(np.where(np.isinf(out) & (out > 0), range_max_m, out), range_min_m), range_max_m)
