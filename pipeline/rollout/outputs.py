"""Files an evaluation writes: metrics JSON (for dvc metrics), per-episode CSV (both from pipeline.record.results),
a paths picture."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from pipeline.core.episode import EpisodeResult
from pipeline.core.layouts import draw_layout
from pipeline.core.scenario import Scenario
from pipeline.record.results import write_episodes, write_metrics
from pipeline.sim.render import TopDownRenderer

__all__ = ["write_episodes", "write_metrics", "write_paths_picture"]


def write_paths_picture(
    path: Path, scenario: Scenario, results: list[EpisodeResult], count: int = 4, random_layouts: bool = False
) -> None:
    """A PNG with the paths of the first `count` episodes side by side (each in its own layout with
    `random_layouts`)."""
    tiles = [
        TopDownRenderer(draw_layout(scenario, r.seed) if random_layouts else scenario, px_per_m=60.0).render_paths(
            r.trajectory
        )
        for r in results[:count]
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(tiles, axis=1)).save(path)
