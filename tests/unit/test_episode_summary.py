"""Episode summaries: rates over every episode with Wilson intervals; aborted episodes fail the robots that had not
arrived, and the completed-only rates stand beside."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.core.episode import EpisodeResult, path_lengths_m, path_times_ns, summarize
from pipeline.core.stats import wilson_interval


def episode(
    k: int, reached: list[bool], collided: list[bool], aborted: bool = False, stale: list[float] | None = None
) -> EpisodeResult:
    r = np.array(reached)
    return EpisodeResult(
        episode=k,
        seed=k,
        steps=10,
        reached=r,
        collided=np.array(collided),
        time_to_goal_s=np.where(r, 1.0 + k, np.nan),
        path_length_m=np.ones(len(r)),
        team_success=bool(r.all() and not any(collided)),
        trajectory=np.zeros((11, len(r), 3)),
        aborted=aborted,
        abort_kind="outage" if aborted else "",
        stale_s=np.array(stale if stale is not None else [0.0] * len(r)),
    )


def test_rates_count_every_episode_and_the_completed_rate_stands_beside():
    results = [
        episode(0, [True, True], [False, False]),
        episode(1, [True, False], [False, True]),
        episode(2, [True, False], [False, False], aborted=True, stale=[0.0, 5.2]),  # robot_1 arrived before
    ]
    m = summarize(results, prefix="real")
    assert m["real/episodes"] == 3 and m["real/aborted_episodes"] == 1 and m["real/completed_episodes"] == 2
    assert m["real/aborted_outage"] == 1 and m["real/aborted_fault"] == 0
    assert m["real/robot_success"] == pytest.approx(4 / 6)
    assert (m["real/robot_success_ci_low"], m["real/robot_success_ci_high"]) == pytest.approx(wilson_interval(4, 6))
    assert m["real/team_success"] == pytest.approx(1 / 3)
    assert m["real/robot_success_completed"] == pytest.approx(3 / 4)
    assert m["real/team_success_completed"] == pytest.approx(1 / 2)
    assert m["real/collision_rate"] == pytest.approx(1 / 6)
    assert m["real/mean_time_to_goal_s"] == pytest.approx((1 + 1 + 2 + 3) / 4)
    assert m["real/robot_1_success"] == pytest.approx(1.0) and m["real/robot_2_success"] == pytest.approx(1 / 3)
    assert m["real/robot_2_stale_s"] == pytest.approx(5.2) and m["real/stale_s"] == pytest.approx(5.2)


def test_only_aborted_episodes_give_zero_success_not_missing_rates():
    m = summarize([episode(0, [False], [False], aborted=True)])
    assert m["eval/episodes"] == 1 and m["eval/aborted_episodes"] == 1
    assert m["eval/robot_success"] == 0.0 and m["eval/team_success"] == 0.0
    assert math.isnan(m["eval/robot_success_completed"])
    with pytest.raises(ValueError):
        summarize([])


def test_an_aborted_team_fails_even_when_its_flag_says_otherwise():
    flagged = episode(0, [True, True], [False, False], aborted=True)
    assert flagged.team is False
    assert summarize([flagged])["eval/team_success"] == 0.0
    with pytest.raises(ValueError, match="abort_kind"):
        EpisodeResult(
            0, 0, 1, np.ones(1, bool), np.zeros(1, bool), np.ones(1), np.ones(1), True, np.zeros((2, 1, 3)), True
        )


def test_a_path_is_sampled_on_the_control_grid_up_to_the_episodes_end():
    assert path_times_ns(1_000, 100, 3).tolist() == [1_000, 1_100, 1_200, 1_300]
    assert path_times_ns(1_000, 100, 3, end_ns=1_250).tolist() == [1_000, 1_100, 1_200, 1_250]
    assert path_times_ns(1_000, 100, 0).tolist() == [1_000]


def test_path_lengths_skip_unknown_poses_and_do_not_depend_on_the_array_layout():
    poses = np.array(
        [
            [[0.0, 0.0, 0.0], [2.0, 2.0, 0.0]],
            [[3.0, 4.0, 1.0], [2.0, 2.0, 0.5]],
            [[np.nan, np.nan, np.nan], [2.0, 2.0, 0.0]],  # robot_1's pose unknown at this step
            [[3.0, 8.0, 0.0], [2.0, 2.0, 0.0]],
        ]
    )
    assert path_lengths_m(poses).tolist() == [9.0, 0.0]  # turning in place travels nothing
    rng = np.random.default_rng(3)
    walk = np.cumsum(rng.normal(0.0, 0.01, size=(351, 3, 3)), axis=0)
    each = [path_lengths_m(walk[:, i : i + 1, :2].copy())[0] for i in range(3)]
    assert path_lengths_m(walk).tolist() == each == path_lengths_m(np.asfortranarray(walk)).tolist()
    assert path_lengths_m(walk[:1]).tolist() == [0.0, 0.0, 0.0]
