"""Obstacle-aware distance to a goal: the length of the shortest free path through the known map.

The reward's progress term measures progress along this path, so driving around a box toward the
goal is progress while pushing straight at the box is not. The field is computed once per
scenario and goal on a grid (8-connected Dijkstra over cells whose centre keeps the robot's
radius clear of walls and boxes) and read with bilinear interpolation. Other robots move and
are not part of the map.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from pipeline.core.scenario import Scenario, box_clearance


class DistanceField:
    """Shortest free-path distance (m) from any point of the room to one goal point."""

    def __init__(
        self,
        scenario: Scenario,
        goal_xy: np.ndarray,
        resolution_m: float = 0.05,
        radius_m: float | None = None,
        margin_m: float = 0.0,
    ) -> None:
        """`radius_m`: the body kept clear of walls and boxes (default: the scenario's robot).

        `margin_m`: the path keeps this much more clearance where it can (an inflated map, as a costmap's
        inflation); where the inflated map cuts a part of the room off from the goal, the field is the
        plain map's."""
        room = scenario.room
        self.resolution_m = resolution_m
        self.x0, self.y0 = room.x_min_m, room.y_min_m
        nx = math.ceil((room.x_max_m - room.x_min_m) / resolution_m) + 1
        ny = math.ceil((room.y_max_m - room.y_min_m) / resolution_m) + 1
        xs = self.x0 + resolution_m * np.arange(nx)
        ys = self.y0 + resolution_m * np.arange(ny)
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        points = np.stack([gx.ravel(), gy.ravel()], axis=1)
        radius = scenario.robot.radius_m if radius_m is None else radius_m
        clear = np.minimum.reduce(
            [
                points[:, 0] - room.x_min_m,
                room.x_max_m - points[:, 0],
                points[:, 1] - room.y_min_m,
                room.y_max_m - points[:, 1],
            ]
        )
        for box in scenario.obstacles:
            clear = np.minimum(clear, box_clearance(box, points))
        goal = np.asarray(goal_xy, dtype=np.float64)
        plain = (clear >= radius).reshape(nx, ny)
        field = self._field(clear.reshape(nx, ny) >= radius + margin_m, goal, gx, gy) if margin_m > 0 else None
        if field is None or not np.isfinite(field[plain]).all():
            field = self._field(plain, goal, gx, gy)
        self.values = field
        gx_, gy_ = np.gradient(field, resolution_m)
        # the free path leaves each point against the gradient of the distance
        self.directions = np.arctan2(-gy_, -gx_)
        self.unit = np.stack([np.cos(self.directions), np.sin(self.directions)], axis=-1)

    def _field(self, free: np.ndarray, goal: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        """Free-path distances to `goal` over the cells `free` (nx, ny); other cells take their nearest free
        cell's value plus the distance to it (nan where no free path reaches the goal)."""
        resolution_m = self.resolution_m
        # the goal's cell and the free cells around it are sources at their straight-line distance
        dist_to_goal = np.hypot(gx - goal[0], gy - goal[1])
        source = free & (dist_to_goal <= max(2 * resolution_m, 1e-9))
        if not source.any():
            source = free & (dist_to_goal == dist_to_goal[free].min()) if free.any() else free
        field = self._dijkstra(free, source, dist_to_goal)
        # occupied cells take their nearest free cell's value plus the distance to it
        if (~free).any() and free.any():
            gap, (ix, iy) = ndimage.distance_transform_edt(~free, return_indices=True)
            field = np.where(free, field, field[ix, iy] + gap * resolution_m)
        return np.asarray(field)

    def _dijkstra(self, free: np.ndarray, source: np.ndarray, straight: np.ndarray) -> np.ndarray:
        nx, ny = free.shape
        index = np.arange(nx * ny).reshape(nx, ny)
        rows, cols, weights = [], [], []
        for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1), (2, 1), (1, 2), (2, -1), (1, -2)):
            i0, i1 = max(0, -dx), nx - max(0, dx)
            j0, j1 = max(0, -dy), ny - max(0, dy)
            ok = free[i0:i1, j0:j1] & free[i0 + dx : i1 + dx, j0 + dy : j1 + dy]
            rows.append(index[i0:i1, j0:j1][ok])
            cols.append(index[i0 + dx : i1 + dx, j0 + dy : j1 + dy][ok])
            weights.append(np.full(int(ok.sum()), self.resolution_m * math.hypot(dx, dy)))
        # a virtual source node (index n) joined to every source cell by its straight-line distance
        n = nx * ny
        src = index[source]
        rows.append(np.full(len(src), n))
        cols.append(src)
        weights.append(straight[source] + 1e-12)
        r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
        graph = coo_matrix((w, (r, c)), shape=(n + 1, n + 1)).tocsr()
        dist = dijkstra(graph, directed=False, indices=n)
        out = dist[:n].reshape(nx, ny)
        return np.where(np.isfinite(out), out, np.nan)

    def direction(self, xy: np.ndarray) -> np.ndarray:
        """Heading (rad) of the shortest free path at points (n, 2): where a robot there should drive."""
        ix, iy, tx, ty = _cells(self.x0, self.y0, self.resolution_m, self.values.shape, xy)
        u = self.unit
        v = _blend(lambda i, j: u[i, j], ix, iy, tx[:, None], ty[:, None])
        return np.asarray(np.arctan2(v[:, 1], v[:, 0]))

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """Distances (m) at points (n, 2), bilinearly interpolated; points outside the room are clamped."""
        ix, iy, tx, ty = _cells(self.x0, self.y0, self.resolution_m, self.values.shape, xy)
        v = self.values
        return np.asarray(_blend(lambda i, j: v[i, j], ix, iy, tx, ty))


_LAST_CELL = 1.000001
"""Grid positions are clamped this far below the grid's size: inside the last cell, its far corner still on the grid."""


def _cells(
    x0: float, y0: float, resolution_m: float, shape: tuple[int, ...], xy: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Grid cell (ix, iy) of each point (n, 2) and its position inside the cell (tx, ty in [0, 1)); clamped."""
    p = np.asarray(xy, dtype=np.float64)
    nx, ny = shape[0], shape[1]
    fx = np.minimum(np.maximum((p[:, 0] - x0) / resolution_m, 0.0), nx - _LAST_CELL)
    fy = np.minimum(np.maximum((p[:, 1] - y0) / resolution_m, 0.0), ny - _LAST_CELL)
    ix, iy = fx.astype(int), fy.astype(int)
    return ix, iy, fx - ix, fy - iy


def _blend(
    take: Callable[[np.ndarray, np.ndarray], np.ndarray],
    ix: np.ndarray,
    iy: np.ndarray,
    tx: np.ndarray,
    ty: np.ndarray,
) -> np.ndarray:
    """Bilinear interpolation of the grid values `take(i, j)` at the four corners of each cell."""
    return np.asarray(
        take(ix, iy) * (1 - tx) * (1 - ty)
        + take(ix + 1, iy) * tx * (1 - ty)
        + take(ix, iy + 1) * (1 - tx) * ty
        + take(ix + 1, iy + 1) * tx * ty
    )


def _blend_scalar(flat: np.ndarray, ny: int, ix: int, iy: int, tx: float, ty: float) -> float:
    """:func:`_blend` of one point of a grid (nx, ny) held flat (row-major): its operations, in its order, in
    Python floats."""
    k = ix * ny + iy
    take = flat.item
    return float(
        take(k) * (1 - tx) * (1 - ty)
        + take(k + ny) * tx * (1 - ty)
        + take(k + 1) * (1 - tx) * ty
        + take(k + ny + 1) * tx * ty
    )


class GoalFields:
    """Every robot's own distance field at once: robot i's distance and path heading at its position.

    A judge reads them every control step for a handful of robots, where numpy's per-call cost is most of the work:
    :meth:`distance` and :meth:`direction` take each robot's cell and blend its corners in Python floats, the
    same operations in the same order as :func:`_cells` and :func:`_blend` (so the same numbers to the bit; the
    heading's arctan2 is numpy's on the blended vectors, as before). :meth:`distance_arrays` and
    :meth:`direction_arrays` are the vectorised reading, for many points and as the reference."""

    def __init__(self, fields: list[DistanceField] | tuple[DistanceField, ...]) -> None:
        first = fields[0]
        self.resolution_m = first.resolution_m
        self.x0, self.y0 = first.x0, first.y0
        self.values = np.stack([f.values for f in fields])  # (n, nx, ny)
        self.unit = np.stack([f.unit for f in fields])  # (n, nx, ny, 2)
        nx, ny = self.values.shape[1:]
        self._x_top, self._y_top = nx - _LAST_CELL, ny - _LAST_CELL
        self._ny = ny
        self._rows = [
            (
                np.ravel(f.values),
                np.ascontiguousarray(f.unit[..., 0]).ravel(),
                np.ascontiguousarray(f.unit[..., 1]).ravel(),
            )
            for f in fields
        ]

    def _cell(self, x: float, y: float) -> tuple[int, int, float, float] | None:
        """:func:`_cells` of one point in Python floats; None where it is not finite (the arrays' reading)."""
        if not (math.isfinite(x) and math.isfinite(y)):
            return None
        fx = min(max((x - self.x0) / self.resolution_m, 0.0), self._x_top)
        fy = min(max((y - self.y0) / self.resolution_m, 0.0), self._y_top)
        ix, iy = int(fx), int(fy)
        return ix, iy, fx - ix, fy - iy

    def distance(self, xy: np.ndarray) -> np.ndarray:
        """(n,) robot i's free-path distance (m) to its goal from point xy[i]."""
        points = np.asarray(xy, dtype=np.float64)
        if points.shape != (len(self._rows), 2):
            return self.distance_arrays(points)
        out = []
        for (x, y), (values, _, _) in zip(points.tolist(), self._rows, strict=True):
            cell = self._cell(x, y)
            if cell is None:
                return self.distance_arrays(points)
            out.append(_blend_scalar(values, self._ny, *cell))
        return np.array(out)

    def direction(self, xy: np.ndarray) -> np.ndarray:
        """(n,) heading (rad) of robot i's free path to its goal at point xy[i]."""
        points = np.asarray(xy, dtype=np.float64)
        if points.shape != (len(self._rows), 2):
            return self.direction_arrays(points)
        ux, uy = [], []
        for (x, y), (_, unit_x, unit_y) in zip(points.tolist(), self._rows, strict=True):
            cell = self._cell(x, y)
            if cell is None:
                return self.direction_arrays(points)
            ux.append(_blend_scalar(unit_x, self._ny, *cell))
            uy.append(_blend_scalar(unit_y, self._ny, *cell))
        return np.asarray(np.arctan2(np.array(uy), np.array(ux)))

    def distance_arrays(self, xy: np.ndarray) -> np.ndarray:
        """:meth:`distance`, vectorised."""
        ix, iy, tx, ty = _cells(self.x0, self.y0, self.resolution_m, self.values.shape[1:], xy)
        r, v = np.arange(len(ix)), self.values
        return np.asarray(_blend(lambda i, j: v[r, i, j], ix, iy, tx, ty))

    def direction_arrays(self, xy: np.ndarray) -> np.ndarray:
        """:meth:`direction`, vectorised."""
        ix, iy, tx, ty = _cells(self.x0, self.y0, self.resolution_m, self.values.shape[1:], xy)
        r, u = np.arange(len(ix)), self.unit
        v = _blend(lambda i, j: u[r, i, j], ix, iy, tx[:, None], ty[:, None])
        return np.asarray(np.arctan2(v[:, 1], v[:, 0]))

    def ahead(self, xy: np.ndarray, goal_xy: np.ndarray, distance_m: float, step_m: float = 0.05) -> np.ndarray:
        """(n, 2) the point `distance_m` along robot i's free path from xy[i], or its goal (n, 2) if that is nearer:
        the path is followed down the field in steps of `step_m`."""
        p = np.array(xy, dtype=np.float64)
        goal = np.asarray(goal_xy, dtype=np.float64)
        for _ in range(max(1, round(distance_m / step_m))):
            at_goal = np.hypot(*(goal - p).T) <= step_m
            heading = self.direction(p)
            p = np.where(at_goal[:, None], goal, p + step_m * np.stack([np.cos(heading), np.sin(heading)], axis=1))
        return p
