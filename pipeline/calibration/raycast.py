"""2-D ray casting in a scenario's known map: the room's walls, its boxes, and robots as circles.

The lidar's plane cuts every wall, box and robot body (they stand on the floor and are taller than
the sensor), so the map is a set of line segments (the room's inner wall faces, each box's four
faces) plus one circle per other robot. A cast returns, per ray, the range to the first surface,
which surface it is, and the cosine of the angle between the ray and that surface's normal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.core.scenario import Scenario, box_corners

NO_SURFACE = -1
ROBOT_SURFACE = -2
"""Surface id of a hit on another robot's body."""


@dataclass(frozen=True)
class RayHits:
    """Per ray: `range_m` to the first surface (+inf if none), `surface` id (NO_SURFACE if none,
    ROBOT_SURFACE for a robot body, else the segment's index), `cos_incidence` (|cos| of the angle
    between the ray and the surface normal; 0 where nothing is hit). All have the rays' shape."""

    range_m: np.ndarray
    surface: np.ndarray
    cos_incidence: np.ndarray


@dataclass(frozen=True)
class MapGeometry:
    """Static line segments of a map: endpoints `a`, `b` (k, 2) in metres, unit normals (k, 2), names (k,)."""

    a: np.ndarray
    b: np.ndarray
    normal: np.ndarray
    names: tuple[str, ...]
    robot_radius_m: float

    @staticmethod
    def from_scenario(scenario: Scenario) -> MapGeometry:
        """The room's inner wall faces and every box's faces."""
        room = scenario.room
        x0, x1, y0, y1 = room.x_min_m, room.x_max_m, room.y_min_m, room.y_max_m
        corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
        a_list = [corners[i] for i in range(4)]
        b_list = [corners[(i + 1) % 4] for i in range(4)]
        names = ["wall_south", "wall_east", "wall_north", "wall_west"]
        for k, box in enumerate(scenario.obstacles):
            c = box_corners(box)
            for i in range(4):
                a_list.append(c[i])
                b_list.append(c[(i + 1) % 4])
                names.append(f"box_{k}_face_{i}")
        a = np.array(a_list, dtype=np.float64)
        b = np.array(b_list, dtype=np.float64)
        e = b - a
        normal = np.stack([-e[:, 1], e[:, 0]], axis=1) / np.hypot(e[:, 0], e[:, 1])[:, None]
        return MapGeometry(a, b, normal, tuple(names), float(scenario.radii.max()))

    def cast(self, origin: np.ndarray, angle_rad: np.ndarray) -> RayHits:
        """Rays from `origin` (..., 2) (m) at map-frame angles `angle_rad` (..., m) (rad) against the static map.

        `origin` broadcasts against the rays: pass (n, 1, 2) for n origins with m rays each.
        """
        o = np.asarray(origin, dtype=np.float64)
        ang = np.asarray(angle_rad, dtype=np.float64)
        d = np.stack([np.cos(ang), np.sin(ang)], axis=-1)
        o = np.broadcast_to(o, d.shape)
        shape = ang.shape
        o2 = o.reshape(-1, 1, 2)
        d2 = d.reshape(-1, 1, 2)
        e = (self.b - self.a)[None]
        ao = self.a[None] - o2
        denom = d2[..., 0] * e[..., 1] - d2[..., 1] * e[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (ao[..., 0] * e[..., 1] - ao[..., 1] * e[..., 0]) / denom
            s = (ao[..., 0] * d2[..., 1] - ao[..., 1] * d2[..., 0]) / denom
        valid = (np.abs(denom) > 1e-12) & (t > 1e-9) & (s >= 0.0) & (s <= 1.0)
        t = np.where(valid, t, np.inf)
        idx = np.argmin(t, axis=1)
        rng = t[np.arange(len(t)), idx]
        hit = np.isfinite(rng)
        surface = np.where(hit, idx, NO_SURFACE)
        cos = np.where(hit, np.abs(np.einsum("rk,rk->r", d2[:, 0], self.normal[idx])), 0.0)
        return RayHits(rng.reshape(shape), surface.reshape(shape), cos.reshape(shape))

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """Distance (m) from each of `points` (n, 2) to the nearest wall or box face."""
        p = np.asarray(points, dtype=np.float64)[:, None, :]
        e = (self.b - self.a)[None]
        t = np.clip(((p - self.a[None]) * e).sum(-1) / (e * e).sum(-1), 0.0, 1.0)
        closest = self.a[None] + t[..., None] * e
        return np.asarray(np.hypot(*(p - closest).transpose(2, 0, 1)).min(axis=1))


def cast_circles(
    origin: np.ndarray,
    angle_rad: np.ndarray,
    centers: np.ndarray,
    radius_m: float,
    reach_m: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Ranges (m) to the first of the circles and the ray's closest approach (m) to any circle centre.

    `origin` (2,) and `angle_rad` (m,) define m rays; `centers` (k, 2) are circle centres of radius
    `radius_m`. Returns (range (m,), +inf where no circle is hit; closest approach (m,) of the ray's
    first `reach_m` (m,) metres (the whole forward ray if None), +inf with no circles).
    """
    o = np.asarray(origin, dtype=np.float64)
    ang = np.asarray(angle_rad, dtype=np.float64)
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
    if len(c) == 0:
        inf = np.full(ang.shape, np.inf)
        return inf, inf.copy()
    d = np.stack([np.cos(ang), np.sin(ang)], axis=-1)[:, None, :]
    oc = (o[None, None, :] - c[None]).astype(np.float64)
    b = (d * oc).sum(-1)
    cc = (oc * oc).sum(-1) - radius_m * radius_m
    disc = b * b - cc
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(disc)
    t = np.where((disc >= 0) & (t > 0), t, np.inf)
    along = np.maximum(-b, 0.0)
    if reach_m is not None:
        along = np.minimum(along, np.asarray(reach_m, dtype=np.float64)[:, None])
    closest = np.sqrt(np.maximum((oc * oc).sum(-1) - 2 * along * (-b) + along * along, 0.0))
    return t.min(axis=1), closest.min(axis=1)


def wrap(angle_rad: np.ndarray | float) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return np.asarray((np.asarray(angle_rad) + math.pi) % (2 * math.pi) - math.pi)
