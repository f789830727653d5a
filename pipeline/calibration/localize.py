"""Poses without motion capture: each robot localized against the map from its scans and odometry.

The map is an occupancy grid (:class:`OccupancyMap`): rasterized from a scenario (walls and boxes)
or read from a ROS ``map_server`` map (YAML + image: ``image``, ``resolution``, ``origin``,
``negate``, ``occupied_thresh``, ``free_thresh``, ``mode``), as SLAM tools write them. Its distance
field (metres from each cell to the nearest occupied one, bilinear) is the likelihood field scans
are matched in.

Per scan, the laser's pose is the one that brings the scan's endpoints onto occupied cells: robust
least squares (soft-L1 on the distance, scale `MATCH_SCALE_M`) from a prior. The first scan of an
episode gets its prior from ``initial_pose`` when given, else from global localization: every free
cell at every `GLOBAL_YAW_STEPS`-th heading scored by the fraction of endpoints within
`INLIER_M` of an obstacle, the best few refined; a pose far from the best (over
`AMBIGUOUS_DISTANCE_M` or `AMBIGUOUS_TURN_RAD`) that matches within `AMBIGUOUS_MARGIN` of its score
makes it ambiguous: both are then tracked through the next `FOLLOW_SCANS` scans, and the one whose
matches stay better by that margin wins (a nearly symmetric room seen from one spot is told apart
as the robot drives); the result is refused as ambiguous when they stay as good. Later scans take
the previous match moved by the odometry between the two. A match whose inlier fraction is under
`MIN_INLIERS` is not used (the odometry carries the pose through it); an episode whose matches
fall under it more than half the time is refused.

The robot's pose at each odometry message is the odometry composed with the map<-odom correction
the matches imply, smoothed by a local linear fit over `CORRECTION_SIGMA_S` (the odometry's
short-term smoothness, the matches' long-term truth: a complementary filter), and the base pose is
the laser's composed with the inverse of the laser's mounting (``/tf_static``'s base_link -> laser
when the recording has it, else the centre of the base). Each match reports its own uncertainty:
the covariance of the least-squares fit scaled by its residual variance, times the
number of endpoints per independent one (`CORRELATED_BEAMS`, neighbouring beams see the same wall).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy import ndimage, optimize

from pipeline.calibration.errors import CalibrationError
from pipeline.calibration.raycast import MapGeometry, wrap
from pipeline.calibration.recording import MessageTimes, PoseSeries, RobotData
from pipeline.core.scenario import Point2D, Pose2D, RobotSpec, Room, Scenario, box_corners, load_scenario

MAP_RESOLUTION_M = 0.02
"""Cell size of a map rasterized from a scenario."""
MATCH_SCALE_M = 0.05
"""Soft-L1 scale of the endpoint distances: endpoints farther than this from the map count less."""
INLIER_M = 0.08
"""An endpoint within this of an occupied cell agrees with the map (the match score is the fraction that do)."""
MIN_INLIERS = 0.7
"""A match with fewer agreeing endpoints is not used."""
MIN_ENDPOINTS = 20
"""A scan with fewer finite ranges is not matched."""
MATCH_BEAMS = 180
"""Endpoints used per match (evenly spaced over the scan's valid beams)."""
GLOBAL_BEAMS = 60
"""Endpoints scored per candidate pose in global localization."""
GLOBAL_STEP_M = 0.1
"""Spacing of the candidate positions in global localization."""
GLOBAL_YAW_STEPS = 72
"""Candidate headings in global localization (5 degrees apart)."""
GLOBAL_REFINE = 12
"""Best candidates refined by the local match."""
AMBIGUOUS_MARGIN = 0.03
"""A distinct pose whose inlier fraction is within this of the best makes the result ambiguous."""
FOLLOW_SCANS = 40
"""Scans after an ambiguous first one that each candidate start is tracked through to tell them apart."""
AMBIGUOUS_DISTANCE_M = 0.5
AMBIGUOUS_TURN_RAD = 0.5
CORRELATED_BEAMS = 10.0
"""Endpoints per independent one in a match's uncertainty (neighbouring beams share a wall's error)."""
CORRECTION_SIGMA_S = 0.5
"""Time scale over which the matches correct the odometry (Gaussian weights of a local linear fit)."""
ROBOT_CLEARANCE_M = 0.12
"""Candidate positions keep at least this from occupied cells (the robot's body)."""


MAX_MAP_CELLS = 40_000_000
"""Largest map image taken, checked from the image's header before it is decoded: 28 times the building benchmark's
60 x 60 m floor at 5 cm (1.4 M cells), which calibrated with its 10-minute bag at a peak of 340 MiB
(benchmarks/results/calibration_scale/)."""


@dataclass(frozen=True)
class OccupancyMap:
    """A 2-D occupancy grid: `occupied` (rows along +y from the origin, columns along +x), `resolution_m`
    per cell, `origin` (x, y, yaw) of cell (0, 0)'s outer corner in the map frame; `known` marks cells
    that are free or occupied (map_server's unknown cells are neither)."""

    occupied: np.ndarray
    resolution_m: float
    origin: tuple[float, float, float]
    source: str
    known: np.ndarray | None = None
    _field: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @staticmethod
    def from_scenario(scenario: Scenario, resolution_m: float = MAP_RESOLUTION_M) -> OccupancyMap:
        """The room's walls (one cell thick on their inner faces) and boxes of `scenario`, with a margin outside."""
        room = scenario.room
        margin = 4 * resolution_m
        x0, y0 = room.x_min_m - margin, room.y_min_m - margin
        w = math.ceil((room.x_max_m - room.x_min_m + 2 * margin) / resolution_m)
        h = math.ceil((room.y_max_m - room.y_min_m + 2 * margin) / resolution_m)
        xs = x0 + (np.arange(w) + 0.5) * resolution_m
        ys = y0 + (np.arange(h) + 0.5) * resolution_m
        gx, gy = np.meshgrid(xs, ys)
        inside = (gx > room.x_min_m) & (gx < room.x_max_m) & (gy > room.y_min_m) & (gy < room.y_max_m)
        occupied = ~inside
        for box in scenario.obstacles:
            c = box_corners(box)
            occupied |= _in_polygon(gx, gy, np.asarray(c, dtype=np.float64))
        return OccupancyMap(occupied, resolution_m, (x0, y0, 0.0), f"scenario {scenario.name!r}")

    @staticmethod
    def from_map_server(path: str | Path) -> OccupancyMap:
        """A ``map_server`` map: its YAML file, which names the image (PGM, PNG, ...) beside it."""
        p = Path(path)
        where = str(p)
        try:
            meta = yaml.safe_load(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            raise CalibrationError(where, f"cannot read the map file: {exc}") from exc
        if not isinstance(meta, dict):
            raise CalibrationError(where, "a map_server map file is a mapping with image, resolution and origin")
        missing = [k for k in ("image", "resolution", "origin") if k not in meta]
        if missing:
            raise CalibrationError(where, f"missing key(s) {', '.join(missing)} (a map_server map names them)")
        try:
            resolution = float(meta["resolution"])
            origin = [float(v) for v in meta["origin"]]
            negate = int(meta.get("negate", 0))
            occ_t = float(meta.get("occupied_thresh", 0.65))
            free_t = float(meta.get("free_thresh", 0.25))
        except (TypeError, ValueError, OverflowError) as exc:
            raise CalibrationError(where, f"resolution, origin, negate and thresholds must be numbers: {exc}") from exc
        mode = str(meta.get("mode", "trinary"))
        finite = all(math.isfinite(v) for v in (resolution, occ_t, free_t, *origin))
        if not finite or resolution <= 0 or len(origin) != 3 or not 0 <= free_t < occ_t <= 1 or negate not in (0, 1):
            raise CalibrationError(
                where,
                "resolution must be > 0, origin [x, y, yaw], 0 <= free_thresh < occupied_thresh <= 1, negate 0 or 1",
            )
        if mode not in ("trinary", "scale", "raw"):
            raise CalibrationError(where, f"mode {mode!r} is not one of trinary, scale, raw")
        image_path = Path(str(meta["image"]))
        if not image_path.is_absolute():
            image_path = p.parent / image_path
        try:
            from PIL import Image

            with Image.open(image_path) as img:
                cells = img.size[0] * img.size[1]  # from the header: checked before the image is decoded
                if cells > MAX_MAP_CELLS:
                    raise CalibrationError(
                        where,
                        f"its image {image_path.name} is {img.size[0]} x {img.size[1]} cells ({cells / 1e6:.0f} M), "
                        f"more than the {MAX_MAP_CELLS / 1e6:.0f} M cells calibration takes (its memory grows with the "
                        "cells); crop it to the floor the robots drove, or coarsen the resolution",
                    )
                pixels = np.asarray(img.convert("L"), dtype=np.float64)
        except (OSError, ValueError, Image.DecompressionBombError) as exc:
            raise CalibrationError(where, f"cannot read the map image {image_path}: {exc}") from exc
        if mode == "raw":
            occupied = pixels >= 100 * occ_t
            known = pixels <= 100
        else:
            occ = pixels / 255.0 if negate else (255.0 - pixels) / 255.0
            occupied = occ > occ_t
            known = occupied | (occ < free_t)
        # image row 0 is the top of the map (largest y): flip to rows along +y
        return OccupancyMap(
            occupied[::-1].copy(),
            resolution,
            (origin[0], origin[1], origin[2]),
            f"map_server map {p.name}",
            known[::-1].copy(),
        )

    def write_map_server(self, yaml_path: str | Path) -> Path:
        """Write this map as ``map_server`` does (trinary PGM beside `yaml_path`); returns the YAML path."""
        p = Path(yaml_path)
        image = p.with_suffix(".pgm")
        pixels = np.where(self.occupied, 0, 254).astype(np.uint8)
        if self.known is not None:
            pixels[~self.known] = 205
        rows = pixels[::-1]
        header = f"P5\n{rows.shape[1]} {rows.shape[0]}\n255\n".encode("ascii")
        image.write_bytes(header + rows.tobytes())
        meta = {
            "image": image.name,
            "mode": "trinary",
            "resolution": float(self.resolution_m),
            "origin": [float(v) for v in self.origin],
            "negate": 0,
            "occupied_thresh": 0.65,
            "free_thresh": 0.25,
        }
        p.write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")
        return p

    def geometry(self, robot_radius_m: float) -> MapGeometry:
        """The map's obstacle faces seen from known free space, as segments for ray casting: every cell edge between
        an occupied and a free cell, runs along a row or column merged into one segment (named wall_<k>)."""
        occ = self.occupied
        free = ~occ if self.known is None else (self.known & ~occ)
        res = self.resolution_m
        ends: list[tuple[float, float, float, float]] = []

        def runs(mask: np.ndarray) -> list[tuple[int, int, int]]:
            """(line, first, last) of each run of True along the second axis of `mask`."""
            out = []
            padded = np.pad(mask.astype(np.int8), ((0, 0), (1, 1)))
            for line in np.flatnonzero(mask.any(axis=1)):
                d = np.diff(padded[line])
                out += [
                    (int(line), int(a), int(b) - 1)
                    for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True)
                ]
            return out

        # faces between rows r and r + 1 (at v = (r + 1) res) and between columns c and c + 1, in cells, oriented
        # so that free space lies on their left (the left normal points into free space, as a room's walls')
        for r, c0, c1 in runs(occ[:-1] & free[1:]):
            ends.append((c0, r + 1, c1 + 1, r + 1))
        for r, c0, c1 in runs(free[:-1] & occ[1:]):
            ends.append((c1 + 1, r + 1, c0, r + 1))
        for c, r0, r1 in runs((occ[:, :-1] & free[:, 1:]).T):
            ends.append((c + 1, r1 + 1, c + 1, r0))
        for c, r0, r1 in runs((free[:, :-1] & occ[:, 1:]).T):
            ends.append((c + 1, r0, c + 1, r1 + 1))
        if not ends:
            raise CalibrationError(
                self.source, "the map has no obstacle next to free space: nothing for a lidar to see"
            )
        cells = np.asarray(ends, dtype=np.float64) * res
        ox, oy, oyaw = self.origin
        cs, sn = math.cos(oyaw), math.sin(oyaw)

        def to_map(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            return np.stack([ox + cs * u - sn * v, oy + sn * u + cs * v], axis=1)

        a, b = to_map(cells[:, 0], cells[:, 1]), to_map(cells[:, 2], cells[:, 3])
        e = b - a
        normal = np.stack([-e[:, 1], e[:, 0]], axis=1) / np.hypot(e[:, 0], e[:, 1])[:, None]
        names = tuple(f"wall_{k}" for k in range(len(a)))
        return MapGeometry(a, b, normal, names, robot_radius_m)

    def scenario(self, name: str, robots: int) -> Scenario:
        """A stand-in scenario for a map without one: a room over the map's known cells, `robots` SPARKs (the
        bundled scenarios' shape), no boxes (the map's obstacles are in :meth:`geometry`)."""
        spark = load_scenario("empty").robot
        rows, cols = np.nonzero(self.occupied | (self.known if self.known is not None else ~self.occupied))
        corners = (
            np.array(
                [
                    [cols.min(), rows.min()],
                    [cols.max() + 1, rows.min()],
                    [cols.min(), rows.max() + 1],
                    [cols.max() + 1, rows.max() + 1],
                ],
                dtype=np.float64,
            )
            * self.resolution_m
        )
        ox, oy, oyaw = self.origin
        cs, sn = math.cos(oyaw), math.sin(oyaw)
        xs = ox + cs * corners[:, 0] - sn * corners[:, 1]
        ys = oy + sn * corners[:, 0] + cs * corners[:, 1]
        room = Room(float(xs.min()), float(xs.max()), float(ys.min()), float(ys.max()))
        centre = Pose2D(float(xs.mean()), float(ys.mean()), 0.0)
        spec = RobotSpec(centre, Point2D(centre.x_m, centre.y_m))
        return Scenario(name, room, spark, tuple(spec for _ in range(max(robots, 1))))

    # -- the distance field ---------------------------------------------------------------------

    def _distance(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if "d" not in self._field:
            # signed distance to the obstacles' boundary (cell faces): positive in free space, negative inside
            res = self.resolution_m
            outside = ndimage.distance_transform_edt(~self.occupied) * res - 0.5 * res
            inside = ndimage.distance_transform_edt(self.occupied) * res - 0.5 * res
            d = np.where(self.occupied, -inside, outside)
            gy, gx = np.gradient(d, self.resolution_m)
            self._field["d"] = (d, gx, gy)
        return self._field["d"]  # type: ignore[no-any-return]

    def to_cells(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (row, column) cell-centre coordinates of map-frame `points` (..., 2)."""
        ox, oy, oyaw = self.origin
        dx, dy = points[..., 0] - ox, points[..., 1] - oy
        c, s = math.cos(oyaw), math.sin(oyaw)
        u, v = c * dx + s * dy, -s * dx + c * dy
        return v / self.resolution_m - 0.5, u / self.resolution_m - 0.5

    def distance_only(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) from map-frame `points` (n, 2) to the nearest obstacle boundary (negative inside)."""
        d, _, _ = self._distance()
        r, c = self.to_cells(points)
        return np.asarray(ndimage.map_coordinates(d, np.stack([r, c]), order=1, mode="constant", cval=float(d.max())))

    def distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (m) from map-frame `points` (n, 2) to the nearest obstacle boundary, and its gradient."""
        d, gx, gy = self._distance()
        r, c = self.to_cells(points)
        coords = np.stack([r, c])
        value = ndimage.map_coordinates(d, coords, order=1, mode="constant", cval=float(d.max()))
        grad_u = ndimage.map_coordinates(gx, coords, order=1, mode="constant", cval=0.0)
        grad_v = ndimage.map_coordinates(gy, coords, order=1, mode="constant", cval=0.0)
        oyaw = self.origin[2]
        cs, sn = math.cos(oyaw), math.sin(oyaw)
        grad = np.stack([cs * grad_u - sn * grad_v, sn * grad_u + cs * grad_v], axis=-1)
        return value, grad

    def free_positions(self, step_m: float, clearance_m: float) -> np.ndarray:
        """Map-frame positions (k, 2) on a `step_m` grid in known free space at least `clearance_m` from obstacles."""
        d, _, _ = self._distance()
        stride = max(1, round(step_m / self.resolution_m))
        rows, cols = np.mgrid[0 : d.shape[0] : stride, 0 : d.shape[1] : stride]
        ok = d[rows, cols] >= clearance_m
        if self.known is not None:
            ok &= self.known[rows, cols]
        else:  # a scenario map: only inside the room (cells reachable from the room's centre)
            ok &= self._inside()[rows, cols]
        u = (cols[ok] + 0.5) * self.resolution_m
        v = (rows[ok] + 0.5) * self.resolution_m
        ox, oy, oyaw = self.origin
        c, s = math.cos(oyaw), math.sin(oyaw)
        return np.stack([ox + c * u - s * v, oy + s * u + c * v], axis=1)

    def _inside(self) -> np.ndarray:
        if "inside" not in self._field:
            labels, _ = ndimage.label(~self.occupied)
            border = set(np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))) - {0}
            self._field["inside"] = (labels > 0) & ~np.isin(labels, list(border))
        return self._field["inside"]  # type: ignore[no-any-return]


def _in_polygon(x: np.ndarray, y: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Points inside the convex polygon `corners` (k, 2), either winding."""
    e0, e1 = corners[1] - corners[0], corners[2] - corners[1]
    sign = 1.0 if e0[0] * e1[1] - e0[1] * e1[0] > 0 else -1.0
    inside = np.ones(x.shape, dtype=bool)
    k = len(corners)
    for i in range(k):
        a, b = corners[i], corners[(i + 1) % k]
        cross = (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])
        inside &= sign * cross >= 0
    return inside


# -- scan matching ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Match:
    """One scan matched to the map: the laser's pose (x, y, yaw), its covariance (3, 3), the inlier fraction."""

    pose: np.ndarray
    covariance: np.ndarray
    score: float
    endpoints: int


def scan_points(ranges: np.ndarray, angle_min: float, increment: float, beams: int) -> np.ndarray:
    """Laser-frame endpoints (k, 2) of up to `beams` evenly spaced finite ranges."""
    r = np.asarray(ranges, dtype=np.float64)
    idx = np.flatnonzero(np.isfinite(r) & (r > 0))
    if len(idx) > beams:
        idx = idx[np.linspace(0, len(idx) - 1, beams).round().astype(int)]
    a = angle_min + idx * increment
    return np.stack([r[idx] * np.cos(a), r[idx] * np.sin(a)], axis=1)


def _transform(pose: np.ndarray, pts: np.ndarray) -> np.ndarray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.stack([pose[0] + c * pts[:, 0] - s * pts[:, 1], pose[1] + s * pts[:, 0] + c * pts[:, 1]], axis=1)


def match_scan(grid: OccupancyMap, pts: np.ndarray, prior: np.ndarray) -> Match:
    """The laser pose near `prior` that best puts the endpoints `pts` (laser frame) on the map."""

    def residual(x: np.ndarray) -> np.ndarray:
        return grid.distance_only(_transform(x, pts))

    def jacobian(x: np.ndarray) -> np.ndarray:
        _, g = grid.distance(_transform(x, pts))
        c, s = math.cos(x[2]), math.sin(x[2])
        dpx = -s * pts[:, 0] - c * pts[:, 1]
        dpy = c * pts[:, 0] - s * pts[:, 1]
        return np.stack([g[:, 0], g[:, 1], g[:, 0] * dpx + g[:, 1] * dpy], axis=1)

    fit = optimize.least_squares(
        residual, np.asarray(prior, dtype=np.float64), jac=jacobian, loss="soft_l1", f_scale=MATCH_SCALE_M,
        x_scale=np.array([0.05, 0.05, 0.05]), max_nfev=40,
    )  # fmt: skip
    pose = fit.x.copy()
    pose[2] = math.remainder(pose[2], 2 * math.pi)
    d = np.abs(fit.fun)
    inl = d < INLIER_M
    j = fit.jac[inl] if inl.sum() >= 3 else fit.jac
    sigma2 = float(np.mean(np.minimum(d[inl] if inl.any() else d, INLIER_M) ** 2))
    try:
        cov = np.linalg.inv(j.T @ j) * sigma2 * CORRELATED_BEAMS
    except np.linalg.LinAlgError:
        cov = np.diag([np.inf, np.inf, np.inf])
    return Match(pose, cov, float(np.mean(inl)), len(pts))


@dataclass(frozen=True)
class GlobalResult:
    """Global localization of one scan: the best laser pose, its match, and the runner-up distinct pose."""

    match: Match
    runner_up: Match | None

    @property
    def ambiguous(self) -> bool:
        return self.runner_up is not None and self.runner_up.score >= self.match.score - AMBIGUOUS_MARGIN


def global_localize(grid: OccupancyMap, pts: np.ndarray) -> GlobalResult:
    """The laser pose anywhere in the map's free space that best explains `pts`, and the best distinct rival."""
    positions = grid.free_positions(GLOBAL_STEP_M, ROBOT_CLEARANCE_M)
    if len(positions) == 0:
        raise CalibrationError(grid.source, "the map has no free space to localize in")
    sub = pts[np.linspace(0, len(pts) - 1, min(GLOBAL_BEAMS, len(pts))).round().astype(int)]
    yaws = np.arange(GLOBAL_YAW_STEPS) * 2 * math.pi / GLOBAL_YAW_STEPS
    c, s = np.cos(yaws), np.sin(yaws)
    rx = c[:, None] * sub[None, :, 0] - s[:, None] * sub[None, :, 1]  # (yaws, beams)
    ry = s[:, None] * sub[None, :, 0] + c[:, None] * sub[None, :, 1]
    scores = np.empty((len(positions), len(yaws)))
    chunk = 256
    for i in range(0, len(positions), chunk):
        p = positions[i : i + chunk]
        world = np.stack([p[:, None, None, 0] + rx[None], p[:, None, None, 1] + ry[None]], axis=-1)
        d = grid.distance_only(world.reshape(-1, 2))
        scores[i : i + chunk] = (np.abs(d.reshape(len(p), len(yaws), -1)) < 2 * INLIER_M).mean(axis=2)
    flat = np.argsort(scores, axis=None)[::-1]
    candidates: list[Match] = []
    for k in flat:
        pi, yi = divmod(int(k), len(yaws))
        prior = np.array([positions[pi, 0], positions[pi, 1], yaws[yi]])
        if any(_distinct(prior, m.pose) is False for m in candidates):
            continue  # a neighbour of a pose already refined
        candidates.append(match_scan(grid, pts, prior))
        if len(candidates) >= GLOBAL_REFINE:
            break
    candidates.sort(key=lambda m: m.score, reverse=True)
    best = candidates[0]
    rivals = [m for m in candidates[1:] if _distinct(m.pose, best.pose)]
    return GlobalResult(best, rivals[0] if rivals else None)


def _distinct(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(
        math.hypot(a[0] - b[0], a[1] - b[1]) > AMBIGUOUS_DISTANCE_M
        or abs(math.remainder(a[2] - b[2], 2 * math.pi)) > AMBIGUOUS_TURN_RAD
    )


# -- tracking a robot through an episode ----------------------------------------------------------


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose a (+) b for poses (..., 3)."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [a[..., 0] + c * b[..., 0] - s * b[..., 1], a[..., 1] + s * b[..., 0] + c * b[..., 1], a[..., 2] + b[..., 2]],
        axis=-1,
    )


def inverse(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([-c * a[..., 0] - s * a[..., 1], s * a[..., 0] - c * a[..., 1], -a[..., 2]], axis=-1)


def interpolate_poses(t: np.ndarray, src_t: np.ndarray, src: np.ndarray) -> np.ndarray:
    """Poses `src` (n, 3) at times `src_t` linearly interpolated (yaw unwrapped) at `t`, held at the ends."""
    yaw = np.unwrap(src[:, 2])
    return np.stack([np.interp(t, src_t, src[:, 0]), np.interp(t, src_t, src[:, 1]), np.interp(t, src_t, yaw)], axis=1)


@dataclass(frozen=True)
class Track:
    """One robot through one episode: base poses at the odometry's times and the matches behind them."""

    t_ns: np.ndarray
    pose: np.ndarray
    match_t_ns: np.ndarray
    match_pose: np.ndarray
    match_score: np.ndarray
    match_std: np.ndarray
    """(k, 3) standard deviations of x, y (m) and yaw (rad) of the used matches."""
    start: str
    """How the first pose was found: 'initial pose' or 'global (inliers a, runner-up b)'."""


def track_episode(
    grid: OccupancyMap,
    scan_t: np.ndarray,
    scans: Sequence[np.ndarray],
    odom_t: np.ndarray,
    odom: np.ndarray,
    mount: np.ndarray,
    initial_pose: np.ndarray | None,
    where: str,
) -> Track:
    """Localize one robot in one episode: `scans` (laser-frame endpoints) at `scan_t`, odometry poses at `odom_t`.

    `mount` is the laser's pose on the base (x, y, yaw); `initial_pose` the base's pose at the first scan.
    """
    if len(scans) == 0 or len(odom_t) < 2:
        raise CalibrationError(where, "no scans or odometry to localize from")
    odom_at_scan = interpolate_poses(scan_t, odom_t, odom)
    usable = [i for i, p in enumerate(scans) if len(p) >= MIN_ENDPOINTS]
    if not usable:
        raise CalibrationError(where, f"no scan has {MIN_ENDPOINTS} finite ranges to localize from")
    first = usable[0]
    if initial_pose is not None:
        prior = compose(np.asarray(initial_pose, dtype=np.float64), mount)
        start_match = match_scan(grid, scans[first], prior)
        start = "initial pose"
    else:
        found = global_localize(grid, scans[first])
        start_match = found.match
        runner = found.runner_up.score if found.runner_up is not None else 0.0
        start = f"global (inliers {start_match.score:.2f}, runner-up {runner:.2f})"
        if start_match.score >= MIN_INLIERS and found.ambiguous:
            assert found.runner_up is not None
            # one scan of a nearly symmetric room fits two poses; the next scans, taken as the robot moves and
            # carried by its odometry, see what tells them apart (a box on one side only)
            rivals = (found.match, found.runner_up)
            followed = [_follow(grid, scans, usable, odom_at_scan, mount, m.pose) for m in rivals]
            best = int(np.argmax(followed))
            if len(usable) > 3 and followed[best] < MIN_INLIERS:  # neither start carries the next scans: no place
                raise CalibrationError(
                    where,
                    f"the scans do not match the map: the first scan fits it at {_fmt(found.match.pose)} and at "
                    f"{_fmt(found.runner_up.pose)} (inliers {found.match.score:.2f} and {found.runner_up.score:.2f}), "
                    f"and the next {FOLLOW_SCANS} scans, carried by the odometry, keep {followed[0]:.0%} and "
                    f"{followed[1]:.0%} of their endpoints on it (at least {MIN_INLIERS:.0%} needed); is this the map "
                    "of the building the robot drove in?",
                )
            if followed[best] - followed[1 - best] < AMBIGUOUS_MARGIN:
                raise CalibrationError(
                    where,
                    "global localization is ambiguous: the scan fits the map at "
                    f"{_fmt(found.match.pose)} (inliers {found.match.score:.2f}) and at {_fmt(found.runner_up.pose)} "
                    f"(inliers {found.runner_up.score:.2f}), and the next {FOLLOW_SCANS} scans do not tell them apart "
                    f"(mean inliers {followed[0]:.2f} and {followed[1]:.2f}); "
                    "give the start with --initial-pose x,y,yaw",
                )
            start_match = rivals[best]
            start = (
                f"global over {FOLLOW_SCANS} scans (mean inliers {followed[best]:.2f}, the first scan's rival "
                f"{followed[1 - best]:.2f})"
            )
    if start_match.score < MIN_INLIERS:
        raise CalibrationError(
            where,
            f"the scans do not match the map: at best {start_match.score:.0%} of the endpoints lie within "
            f"{INLIER_M * 100:.0f} cm of an obstacle at {_fmt(start_match.pose)} (at least {MIN_INLIERS:.0%} needed); "
            "is this the map of the building the robot drove in?",
        )
    laser = start_match.pose
    used_t, used_pose, used_score, used_std = [scan_t[first]], [laser], [start_match.score], [_std(start_match)]
    failed = 0
    previous = first
    for i in usable[1:]:
        step = compose(inverse(odom_at_scan[previous]), odom_at_scan[i])
        previous = i
        prior = compose(compose(laser, inverse(mount)), compose(step, mount))
        m = match_scan(grid, scans[i], prior)
        if m.score < MIN_INLIERS or not np.all(np.isfinite(m.covariance)):
            failed += 1
            laser = prior
            continue
        laser = m.pose
        used_t.append(scan_t[i])
        used_pose.append(m.pose)
        used_score.append(m.score)
        used_std.append(_std(m))
    if failed > len(usable) / 2:
        raise CalibrationError(
            where,
            f"{failed} of {len(usable)} scans do not match the map (inlier fraction under {MIN_INLIERS:.0%}); "
            "the map or the initial pose is wrong",
        )
    mt = np.asarray(used_t, dtype=np.int64)
    base = compose(np.asarray(used_pose), inverse(mount)[None])
    # map <- odom correction at each match, interpolated to the odometry's times
    odom_at_match = interpolate_poses(mt, odom_t, odom)
    correction = compose(base, inverse(odom_at_match))
    corr = smooth_correction(odom_t, mt, correction, CORRECTION_SIGMA_S)
    pose = compose(corr, odom)
    pose[:, 2] = wrap(pose[:, 2])
    return Track(odom_t, pose, mt, base, np.asarray(used_score), np.asarray(used_std), start)


def _follow(
    grid: OccupancyMap,
    scans: Sequence[np.ndarray],
    usable: Sequence[int],
    odom_at_scan: np.ndarray,
    mount: np.ndarray,
    laser: np.ndarray,
) -> float:
    """Mean inlier fraction of the first `FOLLOW_SCANS` usable scans, tracked by odometry and matching from the laser
    pose `laser` at the first of them."""
    scores = []
    previous = usable[0]
    for i in usable[1 : 1 + FOLLOW_SCANS]:
        step = compose(inverse(odom_at_scan[previous]), odom_at_scan[i])
        previous = i
        prior = compose(compose(laser, inverse(mount)), compose(step, mount))
        m = match_scan(grid, scans[i], prior)
        scores.append(m.score)
        laser = m.pose if m.score >= MIN_INLIERS and np.all(np.isfinite(m.covariance)) else prior
    return float(np.mean(scores)) if scores else 0.0


def smooth_correction(t_ns: np.ndarray, match_t_ns: np.ndarray, correction: np.ndarray, sigma_s: float) -> np.ndarray:
    """The map<-odom correction (x, y, yaw) at `t_ns`: a local linear fit (Gaussian weights of `sigma_s`) of the
    matches' corrections, so the pose keeps the odometry's short-term smoothness and the matches' long-term truth."""
    c = correction.copy()
    c[:, 2] = np.unwrap(c[:, 2])
    if len(match_t_ns) == 1:
        return np.repeat(c, len(t_ns), axis=0)
    out = np.empty((len(t_ns), 3))
    tm = (match_t_ns - match_t_ns[0]) / 1e9
    to = (np.asarray(t_ns) - match_t_ns[0]) / 1e9
    for start in range(0, len(to), 512):
        dt = tm[None, :] - to[start : start + 512, None]  # (chunk, matches)
        w = np.exp(-0.5 * (dt / sigma_s) ** 2) + 1e-12
        s0, s1, s2 = w.sum(1), (w * dt).sum(1), (w * dt * dt).sum(1)
        det = s0 * s2 - s1 * s1
        for j in range(3):
            y0, y1 = (w * c[None, :, j]).sum(1), (w * dt * c[None, :, j]).sum(1)
            level = np.where(det > 1e-12 * s0 * s0, (s2 * y0 - s1 * y1) / np.where(det > 0, det, 1.0), y0 / s0)
            out[start : start + 512, j] = level
    return out


def _std(m: Match) -> np.ndarray:
    return np.sqrt(np.maximum(np.diag(m.covariance), 0.0))


def _fmt(pose: np.ndarray) -> str:
    return f"({pose[0]:.2f} m, {pose[1]:.2f} m, {math.degrees(pose[2]):.0f} deg)"


# -- a whole recording ----------------------------------------------------------------------------


@dataclass(frozen=True)
class RobotLocalization:
    """How one robot's poses were found: matches used, their median inlier fraction and standard deviations."""

    robot: str
    matches: int
    scans: int
    median_score: float
    median_std: tuple[float, float, float]
    starts: tuple[str, ...]


@dataclass(frozen=True)
class PoseSource:
    """Where a calibration's poses came from: ``ground_truth`` (motion capture) or ``localized`` (scans + odometry)."""

    kind: str
    map: str = ""
    robots: tuple[RobotLocalization, ...] = ()
    map_score: float = math.nan
    """With motion capture and a map given: the fraction of scan endpoints on the map at the captured poses."""

    @property
    def median_score(self) -> float:
        scores = [r.median_score for r in self.robots]
        return float(np.median(scores)) if scores else float("nan")

    def sentence(self) -> str:
        """What the poses were, for the report and the command's output ('' for motion capture alone)."""
        if self.kind == "localized":
            return (
                f"poses localized from scans and odometry in the {self.map} (median match score "
                f"{self.median_score:.2f}: the fraction of scan endpoints on the map), not motion capture"
            )
        if self.kind == "ground_truth" and self.map:
            return (
                f"poses from motion capture; the map {self.map} checked against them: {100 * self.map_score:.0f} % "
                "of the scans' endpoints lie on it"
            )
        if self.kind == "none":
            return "no poses: the bag has scans alone"
        return ""

    def to_mapping(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind}
        if self.kind == "ground_truth" and self.map:
            out["map_checked"] = {"map": self.map, "endpoints_on_map": round(self.map_score, 4)}
        if self.kind == "localized":
            out["map"] = self.map
            out["match_score"] = round(self.median_score, 4)
            out["robots"] = {
                r.robot: {
                    "matches": r.matches,
                    "scans": r.scans,
                    "match_score": round(r.median_score, 4),
                    "std_x_m": round(r.median_std[0], 5),
                    "std_y_m": round(r.median_std[1], 5),
                    "std_yaw_rad": round(r.median_std[2], 5),
                    "starts": list(r.starts),
                }
                for r in self.robots
            }
        return out


def localize_robot(
    grid: OccupancyMap,
    robot: RobotData,
    windows: Sequence[tuple[int, int]],
    mount: np.ndarray,
    initial_pose: np.ndarray | None,
    where: str,
) -> tuple[PoseSeries, RobotLocalization]:
    """A robot's base poses (a PoseSeries at its odometry's times) localized per episode window, and how."""
    scans, odom = robot.scans, robot.odom
    if scans is None or odom is None or len(scans.ranges) == 0 or len(odom.pose) < 2:
        raise CalibrationError(where, f"robot {robot.name!r}: localization needs its /scan and /odom")
    keep_t: list[np.ndarray] = []
    keep_pose: list[np.ndarray] = []
    scores: list[np.ndarray] = []
    stds: list[np.ndarray] = []
    starts: list[str] = []
    n_scans = 0
    start_prior = initial_pose
    for k, (w0, w1) in enumerate(windows):
        s_idx = np.flatnonzero((scans.time.t_ns >= w0) & (scans.time.t_ns <= w1))
        o_idx = np.flatnonzero((odom.time.t_ns >= w0) & (odom.time.t_ns <= w1))
        if len(s_idx) == 0 or len(o_idx) < 2:
            continue
        pts = [
            scan_points(scans.ranges[i], scans.angle_min_rad[i], scans.angle_increment_rad[i], MATCH_BEAMS)
            for i in s_idx
        ]
        here = f"{where}: robot {robot.name!r}, episode window {k}"
        track = None
        if start_prior is not None and initial_pose is None:
            # the operator put the robot back where the previous episode started: try that first
            try:
                track = track_episode(grid, scans.time.t_ns[s_idx], pts, odom.time.t_ns[o_idx], odom.pose[o_idx],
                                      mount, start_prior, here)  # fmt: skip
                track = replace(track, start="previous episode's start")
            except CalibrationError:
                track = None
        if track is None:
            track = track_episode(
                grid, scans.time.t_ns[s_idx], pts, odom.time.t_ns[o_idx], odom.pose[o_idx], mount,
                initial_pose if k == 0 else None, here,
            )  # fmt: skip
        start_prior = track.pose[0] if initial_pose is None else None
        keep_t.append(o_idx)
        keep_pose.append(track.pose)
        scores.append(track.match_score)
        stds.append(track.match_std)
        starts.append(track.start)
        n_scans += len(s_idx)
    if not keep_t:
        raise CalibrationError(where, f"robot {robot.name!r}: no episode holds both scans and odometry")
    idx = np.concatenate(keep_t)
    t = odom.time
    series = PoseSeries(
        MessageTimes(t.t_ns[idx], t.stamp_ns[idx], t.log_ns[idx], t.offset_ns), np.concatenate(keep_pose)
    )
    sc = np.concatenate(scores)
    sd = np.concatenate(stds)
    med = np.median(sd, axis=0)
    info = RobotLocalization(
        robot.name, len(sc), n_scans, float(np.median(sc)), (float(med[0]), float(med[1]), float(med[2])), tuple(starts)
    )
    return series, info


MAP_CHECK_SCANS = 40
"""Scans per robot, evenly over the recording, that check a map against the motion capture."""


def map_agreement(grid: OccupancyMap, truth_t_ns: np.ndarray, truth: np.ndarray, scans: Any, mount: Any) -> float:
    """The median over up to `MAP_CHECK_SCANS` scans of the fraction of their endpoints within `INLIER_M` of the
    map's occupied cells, each scan put at the captured pose of its time (and the laser's mounting, where known):
    near 1 for the map of the room the robot drove in, low for another place or another frame."""
    t = scans.time.t_ns
    inside = (t >= truth_t_ns[0]) & (t <= truth_t_ns[-1])
    idx = np.flatnonzero(inside)
    if len(idx) == 0:
        return math.nan
    idx = idx[np.unique(np.linspace(0, len(idx) - 1, min(len(idx), MAP_CHECK_SCANS)).round().astype(int))]
    poses = interpolate_poses(t[idx], truth_t_ns, truth)
    laser = np.asarray(mount if mount is not None else (0.0, 0.0, 0.0), dtype=np.float64)
    fractions = []
    for i, pose in zip(idx, poses, strict=True):
        pts = scan_points(scans.ranges[i], float(scans.angle_min_rad[i]), float(scans.angle_increment_rad[i]), 200)
        if len(pts) < 10:
            continue
        d = grid.distance_only(_transform(compose(pose, laser), pts))
        fractions.append(float(np.mean(np.abs(d) < INLIER_M)))
    return float(np.median(fractions)) if fractions else math.nan
