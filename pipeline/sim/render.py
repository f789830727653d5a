"""Top-down RGB pictures of the world drawn with numpy: no display or OpenGL needed.

Room floor and walls, boxes, goal squares, robots with their heading, and lidar rays to their
hits, at `px_per_m` pixels per metre. Image rows run from the room's north (top) to south.
"""

from __future__ import annotations

import itertools
import math
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from pipeline.core.scenario import Scenario, box_corners

if TYPE_CHECKING:
    from pipeline.sim.env import MultiRobotSim

ROBOT_COLOURS = np.array(
    [[217, 51, 51], [51, 115, 217], [51, 179, 77], [217, 153, 26], [153, 77, 204], [26, 179, 179]], dtype=np.uint8
)
FLOOR, WALL, BOX, RAY = (235, 235, 235), (90, 90, 90), (230, 128, 26), (250, 200, 60)


class TopDownRenderer:
    """Draws one scenario; the static picture (room, boxes, goals) is drawn once."""

    def __init__(self, scenario: Scenario, px_per_m: float = 100.0, margin_px: int = 16) -> None:
        self.scenario = scenario
        self.scale = px_per_m
        room = scenario.room
        self.margin = margin_px
        self.width = math.ceil((room.x_max_m - room.x_min_m) * px_per_m) + 2 * margin_px
        self.height = math.ceil((room.y_max_m - room.y_min_m) * px_per_m) + 2 * margin_px
        cols, rows = np.meshgrid(np.arange(self.width) + 0.5, np.arange(self.height) + 0.5)
        self._world_x = room.x_min_m + (cols - margin_px) / px_per_m
        self._world_y = room.y_max_m - (rows - margin_px) / px_per_m
        self.background = self._static()

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """(n, 2) world metres -> (n, 2) pixel (col, row) floats."""
        room = self.scenario.room
        col = (xy[:, 0] - room.x_min_m) * self.scale + self.margin
        row = (room.y_max_m - xy[:, 1]) * self.scale + self.margin
        return np.stack([col, row], axis=1)

    def _static(self) -> np.ndarray:
        s, room = self.scenario, self.scenario.room
        img = np.empty((self.height, self.width, 3), dtype=np.uint8)
        img[:] = WALL
        x, y = self._world_x, self._world_y
        inside = (x >= room.x_min_m) & (x <= room.x_max_m) & (y >= room.y_min_m) & (y <= room.y_max_m)
        img[inside] = FLOOR
        half = s.goal_size_m / 2
        for i, (gx, gy) in enumerate(s.goals):
            colour = ROBOT_COLOURS[i % len(ROBOT_COLOURS)].astype(np.float64)
            square = (np.abs(x - gx) <= half) & (np.abs(y - gy) <= half)
            img[square] = (0.35 * colour + 0.65 * 255).astype(np.uint8)
        for box in s.obstacles:
            img[self._polygon_mask(box_corners(box))] = BOX
        return img

    def _polygon_mask(self, corners: np.ndarray) -> np.ndarray:
        """Pixels inside a convex polygon given counter-clockwise (4, 2) corners in metres."""
        mask = np.ones(self._world_x.shape, dtype=bool)
        for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True):
            cross = (b[0] - a[0]) * (self._world_y - a[1]) - (b[1] - a[1]) * (self._world_x - a[0])
            mask &= cross >= 0
        return mask

    def _line(self, img: np.ndarray, p0: np.ndarray, p1: np.ndarray, colour: tuple[int, int, int] | np.ndarray) -> None:
        n = int(max(abs(p1[0] - p0[0]), abs(p1[1] - p0[1]))) + 1
        t = np.linspace(0.0, 1.0, n)
        cols = np.clip((p0[0] + t * (p1[0] - p0[0])).astype(int), 0, self.width - 1)
        rows = np.clip((p0[1] + t * (p1[1] - p0[1])).astype(int), 0, self.height - 1)
        img[rows, cols] = colour

    def render(self, truth: np.ndarray, ranges: np.ndarray | None = None) -> np.ndarray:
        """(height, width, 3) uint8 picture of robots at `truth` (n, 3) with lidar `ranges` (n, beams) m."""
        img = self.background.copy()
        radii = self.scenario.radii
        centres = self.to_pixels(truth[:, :2])
        if ranges is not None:
            beams = ranges.shape[1]
            angles = 2 * math.pi * np.arange(beams) / beams
            for i, pose in enumerate(truth):
                hit = np.isfinite(ranges[i])
                a = pose[2] + angles[hit]
                ends = pose[None, :2] + ranges[i, hit, None] * np.stack([np.cos(a), np.sin(a)], axis=1)
                for end in self.to_pixels(ends):
                    self._line(img, centres[i], end, RAY)
        for i, pose in enumerate(truth):
            colour = ROBOT_COLOURS[i % len(ROBOT_COLOURS)]
            r = float(radii[i])
            disc = np.hypot(self._world_x - pose[0], self._world_y - pose[1]) <= r
            img[disc] = colour
            nose = pose[:2] + r * np.array([math.cos(pose[2]), math.sin(pose[2])])
            self._line(img, centres[i], self.to_pixels(nose[None])[0], (0, 0, 0))
        return img

    def render_paths(self, trajectories: np.ndarray) -> np.ndarray:
        """The background with each robot's path (steps, n_robots, 3) and its final pose drawn."""
        img = self.render(trajectories[-1])
        for i in range(trajectories.shape[1]):
            colour = ROBOT_COLOURS[i % len(ROBOT_COLOURS)]
            pix = self.to_pixels(trajectories[:, i, :2])
            for a, b in itertools.pairwise(pix):
                self._line(img, a, b, colour)
        return img


@lru_cache(maxsize=8)
def _renderer(scenario: Scenario) -> TopDownRenderer:
    return TopDownRenderer(scenario)


def render_top_down(sim: MultiRobotSim) -> np.ndarray:
    """The current picture of a running sim (ground-truth poses, last simulated scan)."""
    return _renderer(sim.scenario).render(sim.world.truth, sim.raw_scan)
