"""The convergence criterion (every robot over the threshold for a full window) and the learning-curve CSV."""

from __future__ import annotations

import csv

import numpy as np

from pipeline.learn.common.progress import ConvergenceTracker, LearningCurve
from pipeline.learn.common.worlds import EpisodeRecord


def feed(tracker: ConvergenceTracker, rows: list[list[int]]) -> list[bool]:
    return [tracker.update(np.array(r, dtype=bool)) for r in rows]


def test_needs_a_full_window_before_it_can_hold():
    tracker = ConvergenceTracker(n_robots=2, window=5, threshold=0.5)
    holds = feed(tracker, [[1, 1]] * 5)
    assert holds == [False, False, False, False, True]
    assert tracker.converged_at == 5


def test_every_robot_must_be_over_the_threshold():
    tracker = ConvergenceTracker(n_robots=3, window=4, threshold=0.5)
    # robot 3 succeeds in 2 of 4 (= 0.5, not over it); the others always
    holds = feed(tracker, [[1, 1, 0], [1, 1, 1], [1, 1, 1], [1, 1, 0]])
    assert not any(holds) and tracker.converged_at is None
    np.testing.assert_allclose(tracker.rates(), [1.0, 1.0, 0.5])
    # a success replacing the window's oldest failure makes it 3 of 4
    assert tracker.update(np.array([1, 1, 1], dtype=bool))
    assert tracker.converged_at == 5


def test_the_reference_setting_needs_17_of_20():
    tracker = ConvergenceTracker(n_robots=1)
    assert (tracker.window, tracker.threshold) == (20, 0.8)
    sixteen = [[0]] * 4 + [[1]] * 16
    assert not any(feed(tracker, sixteen))
    assert tracker.update(np.array([1], dtype=bool))  # the oldest failure leaves the window: 17 of 20
    assert tracker.converged_at == 21


def test_converged_at_keeps_the_first_episode_after_a_relapse():
    tracker = ConvergenceTracker(n_robots=1, window=2, threshold=0.5)
    holds = feed(tracker, [[1], [1], [0], [0], [1], [1]])
    assert holds == [False, True, False, False, False, True]
    assert tracker.converged_at == 2


def test_learning_curve_rows(tmp_path):
    path = tmp_path / "curve.csv"
    curve = LearningCurve(path, ("robot_1", "robot_2"))
    record = EpisodeRecord(
        world=3,
        seed=17,
        steps=120,
        returns=np.array([1.5, -0.25]),
        reached=np.array([True, True]),
        collided=np.array([False, True]),
        team_success=False,
    )
    curve.add(7, 960, record, window_rate=0.45)
    curve.close()
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == 1
    row = rows[0]
    assert row["episode"] == "7" and row["world_steps"] == "960" and row["world"] == "3" and row["seed"] == "17"
    assert float(row["return_robot_1"]) == 1.5 and float(row["return_robot_2"]) == -0.25
    # reached but collided is not a success
    assert row["success_robot_1"] == "1" and row["success_robot_2"] == "0"
    assert row["team_success"] == "0" and float(row["robot_success"]) == 0.5
    assert float(row["robot_success_window"]) == 0.45
