"""From raw sensor data to policy observations: the one path used by sim, twin and robots.

A world hands over each robot's LaserScan-shaped ranges with their geometry and its odometry
pose; the builder reduces the scans to the policy's beams, builds the layout's vector, and clips
it to the observation bounds of the scenario's room. Nothing else builds observations.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.core.observation import ObservationLayout
from pipeline.core.scan import Reduction, ScanGeometry, reduce_scan
from pipeline.core.scenario import Scenario


@dataclass(frozen=True)
class Observed:
    """Reduced ranges (n_robots, n_beams) in metres and observations (n_robots, layout.size) float32."""

    ranges: np.ndarray
    obs: np.ndarray


class ObservationBuilder:
    """Builds observations of `layout` for the robots of `scenario` (goals, room bounds)."""

    def __init__(
        self,
        scenario: Scenario,
        layout: ObservationLayout,
        range_min_m: float,
        range_max_m: float,
        reduction: Reduction = "sector_min",
    ) -> None:
        self.scenario = scenario
        self.layout = layout
        self.range_min_m = range_min_m
        self.range_max_m = range_max_m
        self.reduction: Reduction = reduction
        room = scenario.room
        self.low, self.high = layout.bounds(
            (room.x_min_m, room.x_max_m), (room.y_min_m, room.y_max_m), range_min_m, range_max_m
        )

    def reduce(
        self, scans: np.ndarray | Sequence[np.ndarray], geometry: ScanGeometry | Sequence[ScanGeometry]
    ) -> np.ndarray:
        """(n_robots, n_beams) policy ranges from every robot's scan; one geometry for all or one per robot."""
        n = self.layout.n_beams
        if isinstance(geometry, ScanGeometry):
            return reduce_scan(
                np.asarray(scans), geometry, n, self.range_min_m, self.range_max_m, self.reduction
            ).reshape(-1, n)
        return np.stack(
            [
                reduce_scan(np.asarray(s), g, n, self.range_min_m, self.range_max_m, self.reduction)
                for s, g in zip(scans, geometry, strict=True)
            ]
        )

    def build(
        self,
        scans: np.ndarray | Sequence[np.ndarray],
        geometry: ScanGeometry | Sequence[ScanGeometry],
        odom_pose: np.ndarray,
    ) -> Observed:
        """Observations from scans and odometry poses (n_robots, 3) x, y (m), yaw (rad)."""
        ranges = self.reduce(scans, geometry)
        obs = self.layout.build(odom_pose, ranges, self.scenario.goals)
        return Observed(ranges=ranges, obs=np.clip(obs, self.low, self.high))
