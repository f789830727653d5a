"""Episode summaries: rates over finished episodes with Wilson intervals; aborted episodes are not trials."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.core.episode import EpisodeResult, summarize
from pipeline.core.stats import wilson_interval


def episode(k: int, reached: list[bool], collided: list[bool], aborted: bool = False) -> EpisodeResult:
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
    )


def test_rates_intervals_and_aborted_episodes():
    results = [
        episode(0, [True, True], [False, False]),
        episode(1, [True, False], [False, True]),
        episode(2, [False, False], [False, False], aborted=True),
    ]
    m = summarize(results, prefix="real")
    assert m["real/episodes"] == 3 and m["real/aborted_episodes"] == 1
    assert m["real/robot_success"] == pytest.approx(3 / 4)
    assert (m["real/robot_success_ci_low"], m["real/robot_success_ci_high"]) == pytest.approx(wilson_interval(3, 4))
    assert m["real/team_success"] == pytest.approx(1 / 2)
    assert m["real/collision_rate"] == pytest.approx(1 / 4)
    assert m["real/mean_time_to_goal_s"] == pytest.approx((1 + 1 + 2) / 3)
    assert m["real/robot_2_success"] == pytest.approx(1 / 2)


def test_only_aborted_episodes_give_counts_without_rates():
    m = summarize([episode(0, [False], [False], aborted=True)])
    assert m == {"eval/episodes": 1.0, "eval/aborted_episodes": 1.0}
    with pytest.raises(ValueError):
        summarize([])
