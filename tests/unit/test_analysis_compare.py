"""compare() on constructed episodes tables against numbers computed independently (scipy, textbook formulas)."""

from __future__ import annotations

import math

import numpy as np
import polars as pl
import pytest
from scipy import stats as sps

from pipeline.analysis.compare import compare, metric_key
from pipeline.analysis.errors import TableError
from pipeline.core.stats import newcombe_interval, two_proportion_z_test, wilson_interval


def table(outcomes: list[tuple[bool, bool]], times: list[float], aborted: tuple[int, ...] = ()) -> pl.DataFrame:
    """Episodes of two robots; outcomes[e] = (robot_1 succeeded, robot_2 succeeded); failures collide, except in
    aborted episodes, where a robot that had not arrived simply had not arrived yet.

    Successful robots take the next value of `times` as their time to goal.
    """
    rows = []
    clock = iter(times)
    for e, pair in enumerate(outcomes):
        for robot, ok in zip(("robot_1", "robot_2"), pair, strict=True):
            rows.append(
                {
                    "session": "s",
                    "episode": e,
                    "robot": robot,
                    "success": ok,
                    "reached": ok,
                    "collided": not ok and e not in aborted,
                    "timeout": False,
                    "aborted": e in aborted,
                    "time_to_goal_s": next(clock) if ok else None,
                    "team_success": all(pair) and e not in aborted,
                }
            )
    return pl.DataFrame(rows)


def wilson_scipy(k: int, n: int) -> tuple[float, float]:
    ci = sps.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    return float(ci.low), float(ci.high)


SIM = [(True, True)] * 15 + [(True, False)] * 3 + [(False, True)] * 2  # robot 35/40, team 15/20
REAL = [(True, True)] * 6 + [(True, False)] * 6 + [(False, False)] * 6 + [(True, False)] * 2  # last 2 aborted
SIM_TIMES = list(np.linspace(8.0, 12.0, 35))
REAL_TIMES = list(np.linspace(9.0, 16.0, 20))


@pytest.fixture(scope="module")
def result():
    return compare(table(SIM, SIM_TIMES), table(REAL, REAL_TIMES, aborted=(18, 19)))


def test_rates_and_wilson_intervals(result):
    m = result.metrics
    assert m["sim/robot_trials"] == 40 and m["sim/robot_successes"] == 35
    # every episode is a trial: the aborted ones' robots count, robot_1 (arrived before the abort) as a success
    assert m["real/robot_trials"] == 40 and m["real/robot_successes"] == 20
    assert m["real/aborted_episodes"] == 2 and m["real/episodes"] == 20
    assert m["sim/robot_success"] == 35 / 40 and m["real/robot_success"] == 0.5
    assert m["real/robot_success_completed"] == 18 / 36 and m["real/team_success_completed"] == 6 / 18
    low, high = wilson_scipy(18, 36)
    assert (m["real/robot_success_completed_ci_low"], m["real/robot_success_completed_ci_high"]) == pytest.approx(
        (low, high), abs=1e-12
    )
    for key, (k, n) in {"sim/robot_success": (35, 40), "real/robot_success": (20, 40)}.items():
        low, high = wilson_scipy(k, n)
        assert m[f"{key}_ci_low"] == pytest.approx(low, abs=1e-12)
        assert m[f"{key}_ci_high"] == pytest.approx(high, abs=1e-12)
    assert m["sim/team_success"] == 15 / 20 and m["real/team_success"] == 6 / 20  # the aborted episodes' teams fail
    low, high = wilson_scipy(6, 20)
    assert (m["real/team_success_ci_low"], m["real/team_success_ci_high"]) == pytest.approx((low, high), abs=1e-12)
    assert m["sim/collision_rate"] == 5 / 40 and m["real/collision_rate"] == 18 / 40
    assert m["sim/robot_1_success"] == 18 / 20 and m["real/robot_2_success"] == 6 / 20


def test_success_gap_tests(result):
    m = result.metrics
    assert m["gap/robot_success"] == pytest.approx(35 / 40 - 0.5)
    fisher = sps.fisher_exact([[35, 5], [20, 20]], alternative="two-sided").pvalue
    assert m["gap/robot_success_p_value"] == pytest.approx(fisher, rel=1e-12)
    p1, p2 = 35 / 40, 20 / 40
    pooled = (35 + 20) / 80
    z = (p1 - p2) / math.sqrt(pooled * (1 - pooled) * (1 / 40 + 1 / 40))
    assert m["gap/robot_success_z_p_value"] == pytest.approx(2 * sps.norm.sf(abs(z)), rel=1e-9)
    l1, u1 = wilson_scipy(35, 40)
    l2, u2 = wilson_scipy(20, 40)
    low = (p1 - p2) - math.sqrt((p1 - l1) ** 2 + (u2 - p2) ** 2)
    high = (p1 - p2) + math.sqrt((u1 - p1) ** 2 + (p2 - l2) ** 2)
    assert (m["gap/robot_success_ci_low"], m["gap/robot_success_ci_high"]) == pytest.approx((low, high), abs=1e-12)
    team = sps.fisher_exact([[15, 5], [6, 14]], alternative="two-sided").pvalue
    assert m["gap/team_success_p_value"] == pytest.approx(team, rel=1e-12)
    assert m["gap/collision_rate"] == pytest.approx(5 / 40 - 18 / 40)
    gaps = result.gaps
    assert gaps["metric"].to_list() == ["robot_success", "team_success", "collision_rate", "mean_time_to_goal_s"]
    assert gaps["test"].to_list() == ["fisher_exact"] * 3 + ["mann_whitney_u"]


def test_time_to_goal(result):
    m = result.metrics
    sim = np.array(SIM_TIMES)
    real = np.array(REAL_TIMES)  # robot_1 of the aborted episodes had arrived: its times count
    assert m["sim/mean_time_to_goal_s"] == pytest.approx(sim.mean())
    low, high = sps.t.interval(0.95, len(sim) - 1, loc=sim.mean(), scale=sps.sem(sim))
    assert (m["sim/mean_time_to_goal_s_ci_low"], m["sim/mean_time_to_goal_s_ci_high"]) == pytest.approx((low, high))
    assert m["real/goals"] == 20 and m["real/median_time_to_goal_s"] == pytest.approx(np.median(real))
    p = sps.mannwhitneyu(sim, real, alternative="two-sided").pvalue
    assert m["gap/mean_time_to_goal_s_p_value"] == pytest.approx(p)
    assert m["gap/mean_time_to_goal_s"] == pytest.approx(sim.mean() - real.mean())
    welch = sps.ttest_ind(sim, real, equal_var=False).confidence_interval(0.95)
    assert (m["gap/mean_time_to_goal_s_ci_low"], m["gap/mean_time_to_goal_s_ci_high"]) == pytest.approx(
        (welch.low, welch.high)
    )


def test_frames_have_one_row_per_group_and_robot(result):
    assert result.groups.select("world", "label").rows() == [("sim", ""), ("real", "")]
    assert result.robots.select("world", "robot").rows() == [
        ("sim", "robot_1"),
        ("sim", "robot_2"),
        ("real", "robot_1"),
        ("real", "robot_2"),
    ]
    real_1 = result.robots.row(2, named=True)
    assert (real_1["robot_successes"], real_1["robot_trials"]) == (14, 20)


def test_labels_key_the_metrics_and_only_shared_labels_are_compared():
    sim = {"nominal": table(SIM, SIM_TIMES), "calibrated": table(SIM, SIM_TIMES)}
    real = {"nominal": table(REAL, REAL_TIMES)}
    out = compare(sim, real)
    assert "sim/nominal/robot_success" in out.metrics and "sim/calibrated/robot_success" in out.metrics
    assert "gap/nominal/robot_success_p_value" in out.metrics
    assert not any(k.startswith("gap/calibrated") for k in out.metrics)
    assert set(out.gaps["label"]) == {"nominal"}
    only_sim = compare(sim, None)
    assert only_sim.gaps.is_empty() and only_sim.groups.height == 2


def test_pairs_of_two_labels_are_compared_under_both_names(result):
    sim, real = {"simrun": table(SIM, SIM_TIMES)}, {"fleet": table(REAL, REAL_TIMES, aborted=(18, 19))}
    out = compare(sim, real, pairs=[("simrun", "fleet")])
    assert set(out.gaps["label"]) == {"simrun vs fleet"}
    assert out.metrics["gap/simrun vs fleet/robot_success"] == result.metrics["gap/robot_success"] == 35 / 40 - 0.5
    assert out.metrics["sim/simrun/robot_success"] == 35 / 40 and out.metrics["real/fleet/robot_success"] == 0.5
    assert compare(sim, real).gaps.is_empty()  # by default only shared labels are compared
    with pytest.raises(TableError, match=r"real label 'nominal': is compared but has no table \(labels: \['fleet'\]\)"):
        compare(sim, real, pairs=[("simrun", "nominal")])


def test_metric_keys_have_one_separator():
    assert metric_key("real", "", "send_skew_p99_ms") == "real/send_skew_p99_ms"
    assert metric_key("real/", "x") == metric_key("real", "/x") == "real/x"
    assert metric_key("gap", "nominal", "robot_success") == "gap/nominal/robot_success"


def test_degenerate_groups():
    perfect = table([(True, True)] * 5, [10.0] * 10)
    out = compare(perfect, perfect)
    m = out.metrics
    assert m["gap/robot_success"] == 0.0 and m["gap/robot_success_p_value"] == 1.0
    assert m["gap/robot_success_z_p_value"] == 1.0 and m["sim/robot_success_ci_high"] == 1.0
    assert m["sim/collision_rate_ci_low"] == 0.0
    none = table([(False, False)] * 3, [])
    out = compare(none, perfect)
    assert math.isnan(out.metrics["sim/mean_time_to_goal_s"]) and math.isnan(out.metrics["gap/mean_time_to_goal_s"])
    assert math.isnan(out.metrics["gap/mean_time_to_goal_s_p_value"])


def test_missing_columns_are_named():
    with pytest.raises(TableError, match=r"real table 'nominal': lacks column\(s\) collided, aborted"):
        compare({}, {"nominal": table(SIM, SIM_TIMES).drop("collided", "aborted")})


def test_small_statistics():
    assert wilson_interval(0, 0) == (0.0, 1.0)
    assert all(math.isnan(v) for v in newcombe_interval(1, 0, 1, 2))
    assert all(math.isnan(v) for v in two_proportion_z_test(1, 2, 0, 0))
    low, high = newcombe_interval(7, 10, 7, 10)
    assert low < 0 < high and low == pytest.approx(-high)


def test_episodes_that_did_not_keep_the_clock_are_no_trials_and_are_counted_apart():
    """A deployment whose twin fell behind its clock in two episodes (both robots failed there): those episodes
    measure the host, not the policy; the rates are over the other episodes, as if the two had not run, and the two
    are counted apart. The simulator's table has no such column: nothing is left out of it."""
    outcomes = [(True, True)] * 8 + [(False, False)] * 2 + [(True, False)] * 2
    times = list(np.linspace(9.0, 12.0, 18))
    real = table(outcomes, times).with_columns(clock_kept=pl.col("episode").is_in([8, 9]).not_())
    kept_only = table([(True, True)] * 8 + [(True, False)] * 2, times)
    both = compare(table(SIM, SIM_TIMES), real)
    plain = compare(table(SIM, SIM_TIMES), kept_only)
    assert both.metrics[metric_key("real", "", "clock_not_kept_episodes")] == 2
    assert both.metrics[metric_key("real", "", "episodes")] == 10
    assert both.metrics[metric_key("sim", "", "clock_not_kept_episodes")] == 0
    for name in ("robot_success", "team_success", "collision_rate", "robot_success_ci_low", "mean_time_to_goal_s"):
        assert both.metrics[metric_key("real", "", name)] == plain.metrics[metric_key("real", "", name)], name
    assert both.gaps.equals(plain.gaps)
