"""benchmarks/layout_failures.py: the first contact of a collision and the sorting of failed robot-episodes."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from layout_failures import first_contact, sort_failures  # noqa: E402

from pipeline.core.episode import EpisodeResult  # noqa: E402
from pipeline.core.scenario import load_scenario  # noqa: E402


def _reversing_into_the_box(steps: int = 40) -> np.ndarray:
    """robot_1 faces west at (2.0, 1.0) and backs east at 0.3 m/s into the box at (2.5, 1.0); the others stand."""
    scenario = load_scenario("obstacles")
    trajectory = np.repeat(scenario.starts[None].astype(float), steps + 1, axis=0)
    trajectory[:, 0] = [2.0, 1.0, math.pi]
    trajectory[:, 0, 0] = np.minimum(2.0 + 0.03 * np.arange(steps + 1), 2.2)
    return trajectory


def test_first_contact_names_what_was_hit_and_how() -> None:
    scenario = load_scenario("obstacles")
    what, step, forward, bearing = first_contact(scenario, _reversing_into_the_box(), 0, 0.02, 0.1)
    # the body's gap to the box edge (x = 2.35) drops under 0.02 m at x = 2.18, step 6
    assert (what, step) == ("box", 6)
    assert forward == pytest.approx(-0.3)
    assert abs(bearing) == pytest.approx(180.0)
    # a robot that never comes near anything has no contact
    assert first_contact(scenario, _reversing_into_the_box(), 1, 0.02, 0.1)[0] == "unknown"


def test_failures_are_sorted_into_collisions_and_timeouts() -> None:
    scenario = load_scenario("obstacles")
    trajectory = _reversing_into_the_box()
    result = EpisodeResult(
        episode=0,
        seed=0,
        steps=len(trajectory) - 1,
        reached=np.array([False, False, True]),
        collided=np.array([True, False, False]),
        time_to_goal_s=np.array([np.nan, np.nan, 3.0]),
        path_length_m=np.zeros(3),
        team_success=False,
        trajectory=trajectory,
    )
    sorted_ = sort_failures(scenario, [result], 0.02, 0.1)
    assert sorted_["robot_episodes"] == 3
    assert sorted_["collisions"] == 1 and sorted_["hit"] == {"box": 1}
    assert sorted_["reversing"] == 1 and sorted_["in_first_3_s"] == 1 and sorted_["side_on"] == 0
    # robot_2 stood at its start, 3 m from its goal, for the whole episode
    assert sorted_["timeouts"] == 1 and sorted_["timeouts_stalled"] == 1 and sorted_["timeouts_within_0_6_m"] == 0
