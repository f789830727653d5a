"""What the rclpy robot shares with the C++ stand-ins (``tests/peers/common/robot_world.hpp``), in Python: the room
and boxes it drives in, the lidar it ray-casts, the unicycle it moves, the command-line flags and the log lines the
tests read (``tests/peers/drivers.py``'s ``read_log``).

--log FILE lines::

    cmd <receive unix ns> <linear.x as float.hex> <angular.z as float.hex>
    scan <stamp sec> <stamp nanosec> <ranges as float.hex of their float32 value, space separated>
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TextIO

import numpy as np

STEP_S = 0.005
"""The longest step the unicycle integrates in one go (the C++ stand-ins' loop period)."""


class FlagError(ValueError):
    """A world flag's value that does not parse; its message says what the flag takes."""


@dataclass(frozen=True)
class Box:
    """An obstacle: centre (m), half sizes (m), yaw (rad)."""

    x_m: float
    y_m: float
    half_x_m: float
    half_y_m: float
    yaw_rad: float


@dataclass
class World:
    """The room, its boxes, the robot's start and the sensor rates (robot_world.hpp's ``World``)."""

    ns: str | None = None
    """The ``--ns`` option; None: the node's namespace comes from ``--ros-args -r __ns:=...`` (or is the root)."""
    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    x_min_m: float = 0.0
    y_min_m: float = 0.0
    x_max_m: float = 4.0
    y_max_m: float = 6.0
    radius_m: float = 0.165
    boxes: list[Box] = field(default_factory=list)
    beams: int = 360
    scan_hz: float = 10.0
    odom_hz: float = 50.0
    truth_hz: float = 50.0
    range_max_m: float = 12.0
    range_min_m: float = 0.12
    log: str = ""


def _numbers(flag: str, text: str, n: int) -> list[float]:
    parts = text.split(",")
    try:
        if len(parts) == n:
            return [float(p) for p in parts]
    except ValueError:
        pass
    raise FlagError(f"{flag} takes {n} comma-separated numbers")


def _positive(flag: str, text: str, kind: type[int] | type[float]) -> float:
    try:
        value = kind(text)
    except ValueError:
        value = 0
    if not value > 0:
        raise FlagError(f"{flag} takes a positive {'integer' if kind is int else 'number'}")
    return value


def world_flag(world: World, flag: str, value: str) -> bool:
    """Takes one of the shared flags into `world`: True if `flag` is one of them; FlagError for a bad value."""
    if flag == "--ns":
        world.ns = value
    elif flag == "--start":
        world.x_m, world.y_m, world.yaw_rad = _numbers(flag, value, 3)
    elif flag == "--room":
        world.x_min_m, world.y_min_m, world.x_max_m, world.y_max_m = _numbers(flag, value, 4)
    elif flag == "--box":
        world.boxes.append(Box(*_numbers(flag, value, 5)))
    elif flag == "--beams":
        world.beams = int(_positive(flag, value, int))
    elif flag == "--scan-hz":
        world.scan_hz = _positive(flag, value, float)
    elif flag == "--odom-hz":
        world.odom_hz = _positive(flag, value, float)
    elif flag == "--truth-hz":
        world.truth_hz = _positive(flag, value, float)
    elif flag == "--log":
        world.log = value
    else:
        return False
    return True


def _slab(px: float, py: float, ux: np.ndarray, uy: np.ndarray, hx: float, hy: float, inside: bool) -> np.ndarray:
    """Per ray (px, py) + t (ux, uy) in a rectangle's frame (centred, half sizes hx, hy): the t > 0 where it leaves
    (`inside`) or enters the rectangle; +inf where it does not."""
    t0 = np.full(ux.shape, -np.inf)
    t1 = np.full(ux.shape, np.inf)
    hits = np.ones(ux.shape, dtype=bool)
    for p, u, h in ((px, ux, hx), (py, uy, hy)):
        parallel = np.abs(u) < 1e-12
        if abs(p) > h:
            hits &= ~parallel
        with np.errstate(divide="ignore", invalid="ignore"):  # parallel rays: their a, b are not used
            a = (-h - p) / u
            b = (h - p) / u
            t0 = np.where(parallel, t0, np.maximum(t0, np.minimum(a, b)))
            t1 = np.where(parallel, t1, np.minimum(t1, np.maximum(a, b)))
    t = t1 if inside else t0
    return np.where(hits & (t0 <= t1) & (t > 0), t, np.inf)


def scan_ranges(world: World, x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
    """The ranges (beams,) float32 in metres of a full-circle scan from the pose, beam 0 at yaw - pi; beyond
    ``range_max_m`` is +inf."""
    angles = yaw_rad - math.pi + 2 * math.pi * np.arange(world.beams) / world.beams
    dx, dy = np.cos(angles), np.sin(angles)
    cx, cy = 0.5 * (world.x_min_m + world.x_max_m), 0.5 * (world.y_min_m + world.y_max_m)
    half_x, half_y = 0.5 * (world.x_max_m - world.x_min_m), 0.5 * (world.y_max_m - world.y_min_m)
    best = _slab(x_m - cx, y_m - cy, dx, dy, half_x, half_y, inside=True)
    for b in world.boxes:
        c, s = math.cos(-b.yaw_rad), math.sin(-b.yaw_rad)
        px, py = x_m - b.x_m, y_m - b.y_m
        hit = _slab(c * px - s * py, s * px + c * py, c * dx - s * dy, s * dx + c * dy, b.half_x_m, b.half_y_m, False)
        best = np.minimum(best, hit)
    return np.where(best > world.range_max_m, np.inf, best).astype(np.float32)


@dataclass
class Unicycle:
    """The robot's motion: ground truth (x, y, th) in the room, kept off the walls, and the odometry's own integration
    (ox, oy, oth) of the same motion from where it started."""

    x: float
    y: float
    th: float
    ox: float = 0.0
    oy: float = 0.0
    oth: float = 0.0

    def step(self, world: World, v_mps: float, w_radps: float, dt_s: float) -> None:
        nx = self.x + v_mps * math.cos(self.th) * dt_s
        ny = self.y + v_mps * math.sin(self.th) * dt_s
        nx = min(max(nx, world.x_min_m + world.radius_m), world.x_max_m - world.radius_m)
        ny = min(max(ny, world.y_min_m + world.radius_m), world.y_max_m - world.radius_m)
        moved = math.hypot(nx - self.x, ny - self.y)
        self.x, self.y, self.th = nx, ny, math.remainder(self.th + w_radps * dt_s, 2 * math.pi)
        self.ox += moved * math.cos(self.oth)
        self.oy += moved * math.sin(self.oth)
        self.oth = math.remainder(self.oth + w_radps * dt_s, 2 * math.pi)

    def move(self, world: World, v_mps: float, w_radps: float, duration_s: float) -> None:
        """`duration_s` of motion at (v, w), in steps of at most :data:`STEP_S`."""
        if duration_s <= 0:
            return
        n = max(1, math.ceil(duration_s / STEP_S - 1e-9))
        for _ in range(n):
            self.step(world, v_mps, w_radps, duration_s / n)


def log_command(log: TextIO, receive_ns: int, v_mps: float, w_radps: float) -> None:
    log.write(f"cmd {receive_ns} {float(v_mps).hex()} {float(w_radps).hex()}\n")
    log.flush()


def log_scan(log: TextIO, sec: int, nanosec: int, ranges: np.ndarray) -> None:
    log.write(f"scan {sec} {nanosec} {' '.join(float(r).hex() for r in ranges.astype(np.float32))}\n")
    log.flush()
