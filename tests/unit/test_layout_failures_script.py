"""benchmarks/layout_failures.py: the first contact of a collision and the sorting of failed robot-episodes."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from layout_failures import first_contact, later_arrivals, sort_failures

from pipeline.core.episode import EpisodeResult
from pipeline.core.scenario import load_scenario
from pipeline.params import WorldConfig
from pipeline.policy.scripted import GoToGoalController
from pipeline.rollout.sim import evaluate
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim

ROOT = Path(__file__).resolve().parents[2]


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
    assert sorted_["stalled_at"] == {"open space": 1}
    # robot_3 standing with 0.1 m between its body and the box at (2.5, 2.9) is held up by that box
    trajectory[:, 2] = [2.5 - 0.15 - 0.165 - 0.1, 2.9, 0.0]
    stuck = replace(result, reached=np.array([False, False, False]), time_to_goal_s=np.full(3, np.nan))
    stuck = replace(stuck, trajectory=trajectory)
    sorted_ = sort_failures(scenario, [stuck], 0.02, 0.1)
    assert sorted_["timeouts"] == 2 and sorted_["stalled_at"] == {"open space": 1, "box": 1}


def _result(seed: int, reached: list[bool], collided: list[bool], times: list[float]) -> EpisodeResult:
    n = len(reached)
    return EpisodeResult(
        episode=0,
        seed=seed,
        steps=10,
        reached=np.array(reached),
        collided=np.array(collided),
        time_to_goal_s=np.array(times),
        path_length_m=np.zeros(n),
        team_success=all(reached),
        trajectory=np.zeros((11, n, 3)),
    )


def test_later_arrivals_counts_the_timeouts_that_were_only_slow() -> None:
    nan = float("nan")
    limited = [
        _result(1, [True, False, False], [False, False, True], [20.0, nan, nan]),
        _result(2, [False, False, True], [False, False, False], [nan, nan, 30.0]),
    ]
    longer = [
        # robot 2 timed out and arrives at 41 s; robot 3 collided (not a timeout) and stays so
        _result(1, [True, True, False], [False, False, True], [20.0, 41.0, nan]),
        # robot 1 arrives at 60 s, robot 2 never; robot 3 as before
        _result(2, [True, False, True], [False, False, False], [60.0, nan, 30.0]),
    ]
    later = later_arrivals(limited, longer, 35.0)
    assert later["timeouts"] == 3 and later["reached_later"] == 2
    assert later["later_median_s"] == pytest.approx(50.5)
    assert later["agree"] == 6 and later["robot_episodes"] == 6
    # a longer run that reached a goal before the limit where the limited one did not disagrees there
    longer[1] = _result(2, [True, False, True], [False, False, False], [12.0, nan, 30.0])
    assert later_arrivals(limited, longer, 35.0)["agree"] == 5
    with pytest.raises(ValueError, match="same episodes"):
        later_arrivals(limited, longer[:1], 35.0)


def test_a_longer_step_limit_replays_the_same_episodes_up_to_the_limit() -> None:
    """Real worlds: the scripted controller (no clock in its observation) with 80 and 350 steps; every outcome
    by 8 s is the same, and the timeouts that arrive later are counted from the longer run itself."""
    scenario, world = make_world(world=replace(WorldConfig(), scenario="obstacles", observation="rich", max_steps=80))
    controller = GoToGoalController(world.layout(), world.codec())
    short = evaluate(MultiRobotSim(scenario, world), controller, 3, 7, progress=False)
    long = evaluate(MultiRobotSim(scenario, replace(world, max_steps=350)), controller, 3, 7, progress=False)
    later = later_arrivals(short, long, 8.0)
    assert later["agree"] == later["robot_episodes"] == 9
    timeouts = [(k, i) for k, r in enumerate(short) for i in np.flatnonzero(~r.reached & ~r.collided)]
    assert later["timeouts"] == len(timeouts) > 0
    assert later["reached_later"] == sum(bool(long[k].reached[i]) for k, i in timeouts)
