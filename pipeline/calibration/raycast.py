"""2-D ray casting in a scenario's known map: the room's walls, its boxes, and robots as circles.

The lidar's plane cuts every wall, box and robot body (they stand on the floor and are taller than
the sensor), so the map is a set of line segments (the room's inner wall faces, each box's four
faces) plus one circle per other robot. A cast returns, per ray, the range to the first surface,
which surface it is, and the cosine of the angle between the ray and that surface's normal.

Memory does not grow with rays x segments. A room (a few dozen faces) is cast against every segment, in batches
of at most `PAIRS_PER_BATCH` ray-segment pairs. A building (a map_server map: thousands of cell-edge faces) is cast
through a uniform grid of cells that lists the segments crossing each (Amanatides and Woo's traversal, all rays of
a batch stepping together): a ray tests only the segments of the cells it passes until it hits one inside the cell
it is in. The grid is the structure that keeps both the memory and the time of a ray near what its own length
needs, and numpy runs it without a compiled extension; both paths compute a hit with the same arithmetic.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from pipeline.core.scenario import Scenario, box_corners

PAIRS_PER_BATCH = 2_000_000
"""Ray-segment pairs evaluated at once (about 100 MB of float64 temporaries)."""
GRID_FROM_SEGMENTS = 256
"""Maps with more segments than this are cast through the cell grid."""
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

    @functools.cached_property
    def grid(self) -> SegmentGrid:
        """The cell grid of the segments (built on first use)."""
        return SegmentGrid.of(self.a, self.b)

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
        o2 = o.reshape(-1, 2)
        d2 = d.reshape(-1, 2)
        rng = np.full(len(d2), np.inf)
        idx = np.zeros(len(d2), dtype=np.int64)
        k = len(self.a)
        if k > GRID_FROM_SEGMENTS:
            batch = max(PAIRS_PER_BATCH // 64, 1)
            for lo in range(0, len(d2), batch):
                sl = slice(lo, lo + batch)
                rng[sl], idx[sl] = self.grid.cast(self.a, self.b, o2[sl], d2[sl])
        else:
            batch = max(PAIRS_PER_BATCH // max(k, 1), 1)
            for lo in range(0, len(d2), batch):
                sl = slice(lo, lo + batch)
                rng[sl], idx[sl] = _first_hits(self.a, self.b, o2[sl], d2[sl])
        hit = np.isfinite(rng)
        surface = np.where(hit, idx, NO_SURFACE)
        cos = np.where(hit, np.abs(np.einsum("rk,rk->r", d2, self.normal[idx])), 0.0)
        return RayHits(rng.reshape(shape), surface.reshape(shape), cos.reshape(shape))

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """Distance (m) from each of `points` (n, 2) to the nearest wall or box face (in batches of at most
        `PAIRS_PER_BATCH` point-segment pairs)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        out = np.empty(len(pts))
        e = (self.b - self.a)[None]
        batch = max(PAIRS_PER_BATCH // max(len(self.a), 1), 1)
        for lo in range(0, len(pts), batch):
            p = pts[lo : lo + batch, None, :]
            t = np.clip(((p - self.a[None]) * e).sum(-1) / (e * e).sum(-1), 0.0, 1.0)
            closest = self.a[None] + t[..., None] * e
            out[lo : lo + batch] = np.hypot(*(p - closest).transpose(2, 0, 1)).min(axis=1)
        return out


def _pair_hits(a: np.ndarray, b: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Ray parameter t of each ray (o, d) (n, 2) against the segment (a, b) (n, 2) paired with it; inf for a miss."""
    # component by component: every product is of contiguous (or small broadcast) arrays, about twice as fast as
    # strided views into (..., 2) differences, with the same arithmetic
    ex, ey = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    aox, aoy = a[..., 0] - o[..., 0], a[..., 1] - o[..., 1]
    dx, dy = d[..., 0], d[..., 1]
    denom = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (aox * ey - aoy * ex) / denom
        s = (aox * dy - aoy * dx) / denom
    valid = (np.abs(denom) > 1e-12) & (t > 1e-9) & (s >= 0.0) & (s <= 1.0)
    return np.where(valid, t, np.inf)


def _first_hits(a: np.ndarray, b: np.ndarray, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Range and segment index of the first of all segments (k, 2) each ray (n, 2) hits (inf and 0 for none)."""
    t = _pair_hits(a[None], b[None], o[:, None, :], d[:, None, :])
    idx = np.argmin(t, axis=1)
    return t[np.arange(len(t)), idx], idx


@dataclass(frozen=True)
class SegmentGrid:
    """Segments listed per cell of a uniform grid over them: cell (i, j) of side `cell_m` from `origin`, its segments
    `members[start[c]:start[c + 1]]` with c = i * ny + j: every cell a segment passes through (sampled at an eighth
    of a cell, the cells beside a corner it turns listed too) and the cells next to a sample within 1 % of a cell of
    their border, so that no crossing is missed."""

    origin: np.ndarray
    cell_m: float
    nx: int
    ny: int
    start: np.ndarray
    members: np.ndarray

    @staticmethod
    def of(a: np.ndarray, b: np.ndarray) -> SegmentGrid:
        lo = np.minimum(a.min(axis=0), b.min(axis=0)) - 1e-6
        hi = np.maximum(a.max(axis=0), b.max(axis=0)) + 1e-6
        span = hi - lo
        # about four segments per cell on average, no finer than 0.25 m
        cell = max(float(np.sqrt(span[0] * span[1] * 4.0 / max(len(a), 1))), 0.25)
        nx, ny = int(np.ceil(span[0] / cell)) + 1, int(np.ceil(span[1] / cell)) + 1
        length = np.hypot(*(b - a).T)
        steps = np.maximum(np.ceil(length / (cell / 8)).astype(np.int64), 1)
        seg = np.repeat(np.arange(len(a)), steps + 1)
        frac = np.concatenate([np.linspace(0.0, 1.0, n + 1) for n in steps])
        pts = (a[seg] + frac[:, None] * (b - a)[seg] - lo) / cell
        cells = np.floor(pts).astype(np.int64)
        near = 1.0 / 100
        cell_parts, seg_parts = [cells], [seg]
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                if dx == dy == 0:
                    continue
                pick = _near_mask(pts, cells, dx, dy, near)
                cell_parts.append(cells[pick] + np.array([dx, dy]))
                seg_parts.append(seg[pick])
        # a step between two samples that changes both the row and the column passes through one of the two cells
        # beside the corner: both are listed
        turn = np.flatnonzero(np.all(cells[1:] != cells[:-1], axis=1) & (seg[1:] == seg[:-1]))
        cell_parts += [
            np.stack([cells[turn, 0], cells[turn + 1, 1]], 1),
            np.stack([cells[turn + 1, 0], cells[turn, 1]], 1),
        ]
        seg_parts += [seg[turn], seg[turn]]
        all_cells = np.concatenate(cell_parts)
        all_segs = np.concatenate(seg_parts)
        keep = (all_cells[:, 0] >= 0) & (all_cells[:, 0] < nx) & (all_cells[:, 1] >= 0) & (all_cells[:, 1] < ny)
        flat = all_cells[keep, 0] * ny + all_cells[keep, 1]
        unique = np.unique(np.stack([flat, all_segs[keep]], axis=1), axis=0)
        start = np.searchsorted(unique[:, 0], np.arange(nx * ny + 1))
        return SegmentGrid(lo, cell, nx, ny, start.astype(np.int64), unique[:, 1].astype(np.int64))

    def cast(self, a: np.ndarray, b: np.ndarray, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Range and segment index of the first segment each ray (o, d) (n, 2) hits, cell by cell."""
        n = len(o)
        rng = np.full(n, np.inf)
        idx = np.zeros(n, dtype=np.int64)
        size = np.array([self.nx, self.ny]) * self.cell_m
        rel = o - self.origin
        # where each ray enters the grid's box (slab method), and the cell it starts in
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t0 = np.where(d != 0, (0.0 - rel) * inv, -np.inf)
            t1 = np.where(d != 0, (size - rel) * inv, np.inf)
        inside_now = np.all((rel >= 0) & (rel < size), axis=1)
        t_near = np.maximum(np.minimum(t0, t1).max(axis=1), 0.0)
        t_far = np.maximum(t0, t1).min(axis=1)
        active = inside_now | (t_near <= t_far)
        t_enter = np.where(inside_now, 0.0, t_near)
        p = rel + d * (t_enter + 1e-9)[:, None]
        cell = np.clip(np.floor(p / self.cell_m).astype(np.int64), 0, [self.nx - 1, self.ny - 1])
        step = np.where(d >= 0, 1, -1)
        with np.errstate(divide="ignore", invalid="ignore"):
            boundary = (cell + (step > 0)) * self.cell_m
            t_max = np.where(d != 0, (boundary - rel) / d, np.inf)
            t_delta = np.where(d != 0, self.cell_m / np.abs(d), np.inf)
        rays = np.flatnonzero(active)
        while len(rays):
            c = cell[rays, 0] * self.ny + cell[rays, 1]
            counts = self.start[c + 1] - self.start[c]
            t_exit = t_max[rays].min(axis=1)
            if counts.any():
                owner = np.repeat(np.arange(len(rays)), counts)
                offsets = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
                segs = self.members[np.repeat(self.start[c], counts) + offsets]
                r = rays[owner]
                t = _pair_hits(a[segs], b[segs], o[r], d[r])
                t = np.where(t <= t_exit[owner] + 1e-9, t, np.inf)
                # per ray: the least t, the lowest segment index among equal ones (as a cast against all segments)
                order = np.lexsort((segs, t, owner))
                first = np.ones(len(order), bool)
                first[1:] = owner[order][1:] != owner[order][:-1]
                best = order[first]
                found = np.isfinite(t[best])
                hit_rays = r[best][found]
                rng[hit_rays] = t[best][found]
                idx[hit_rays] = segs[best][found]
                done = np.zeros(len(rays), bool)
                done[owner[best][found]] = True
            else:
                done = np.zeros(len(rays), bool)
            # step the rest into the next cell; those leaving the grid are done (no hit)
            axis = np.argmin(t_max[rays], axis=1)
            cell[rays, axis] += step[rays, axis]
            t_max[rays, axis] += t_delta[rays, axis]
            out = (cell[rays, 0] < 0) | (cell[rays, 0] >= self.nx) | (cell[rays, 1] < 0) | (cell[rays, 1] >= self.ny)
            rays = rays[~done & ~out]
        return rng, idx


def _near_mask(pts: np.ndarray, cells: np.ndarray, dx: int, dy: int, near: float) -> np.ndarray:
    """Samples within `near` (in cells) of their cell's border towards (dx, dy)."""
    fx = pts[:, 0] - cells[:, 0]
    fy = pts[:, 1] - cells[:, 1]
    close_x = (fx < near) if dx < 0 else (fx > 1 - near) if dx > 0 else np.ones(len(pts), bool)
    close_y = (fy < near) if dy < 0 else (fy > 1 - near) if dy > 0 else np.ones(len(pts), bool)
    return np.asarray(close_x & close_y)


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
