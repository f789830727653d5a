"""Files an evaluation writes: metrics JSON (for dvc metrics), per-episode CSV, a paths picture."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
from PIL import Image

from pipeline.core.episode import EpisodeResult
from pipeline.core.scenario import Scenario
from pipeline.sim.render import TopDownRenderer


def write_metrics(path: Path, metrics: dict[str, float]) -> None:
    """JSON with NaN written as null (JSON has no NaN)."""
    clean = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in metrics.items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(clean, indent=2, sort_keys=True) + "\n", encoding="utf-8")


def write_episodes(path: Path, results: list[EpisodeResult]) -> None:
    """One row per (episode, robot): seed, success, collision, time to goal, path length."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(
            [
                "episode",
                "seed",
                "robot",
                "success",
                "reached",
                "collided",
                "time_to_goal_s",
                "path_length_m",
                "steps",
                "team_success",
            ]
        )
        for r in results:
            for i in range(len(r.reached)):
                t = r.time_to_goal_s[i]
                out.writerow(
                    [
                        r.episode,
                        r.seed,
                        f"robot_{i + 1}",
                        int(r.success[i]),
                        int(r.reached[i]),
                        int(r.collided[i]),
                        "" if np.isnan(t) else f"{t:.3f}",
                        f"{r.path_length_m[i]:.4f}",
                        r.steps,
                        int(r.team_success),
                    ]
                )


def write_paths_picture(path: Path, scenario: Scenario, results: list[EpisodeResult], count: int = 4) -> None:
    """A PNG with the paths of the first `count` episodes side by side."""
    renderer = TopDownRenderer(scenario, px_per_m=60.0)
    tiles = [renderer.render_paths(r.trajectory) for r in results[:count]]
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(tiles, axis=1)).save(path)
