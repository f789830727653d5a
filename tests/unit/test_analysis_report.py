"""Figures and the report folder: files written, PNGs of sensible sizes, metrics JSON without NaN."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest
from PIL import Image

from pipeline.analysis.errors import AnalysisError, TableError
from pipeline.analysis.gap_report import LabelledSession, markdown_table, write_report
from pipeline.analysis.plots import (
    Rate,
    plot_learning_curves,
    plot_success_rates,
    plot_trajectories,
    trajectories_figure,
)
from tests.unit.test_analysis_tables import write_session


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("report")
    return write_session(folder / "sim.mcap"), write_session(folder / "real.mcap", ground_truth=False)


def write_curve(path: Path, episodes: int = 60) -> Path:
    robots = ("robot_1", "robot_2")
    with path.open("w", newline="") as f:
        out = csv.writer(f)
        out.writerow(
            ["episode", "world_steps", "world", "seed", "length"]
            + [f"return_{r}" for r in robots]
            + [f"success_{r}" for r in robots]
            + ["team_success", "robot_success", "robot_success_window"]
        )
        for e in range(episodes):
            s1, s2 = int(e % 3 != 0), int(e > episodes // 2)
            out.writerow([e + 1, 200 * (e + 1), e % 4, e, 200, e * 0.5, e * 0.25, s1, s2, s1 * s2, (s1 + s2) / 2, 0.5])
    return path


def assert_png(path: Path, min_width: int, min_height: int) -> None:
    assert path.is_file() and path.stat().st_size > 10_000
    with Image.open(path) as image:
        assert image.format == "PNG"
        assert image.size[0] >= min_width and image.size[1] >= min_height


def test_report_folder(recordings, tmp_path):
    sim, real = recordings
    curve = write_curve(tmp_path / "curve.csv")
    out = tmp_path / "report"
    report = write_report(
        out,
        [("nominal", "sim", sim), LabelledSession("nominal", "real", real)],
        {"sac": curve},
        "Noise sigma 0.012 m (fit).",
    )
    assert report.markdown == out / "report.md" and report.metrics == out / "metrics.json"
    assert set(report.figures) == {"success_rates", "trajectories", "learning_curves"}
    assert_png(out / "success_rates.png", 600, 300)
    assert_png(out / "trajectories.png", 600, 400)
    assert_png(out / "learning_curves.png", 600, 300)
    text = report.markdown.read_text()
    for needle in (
        "![success rates](success_rates.png)",
        "![trajectories](trajectories.png)",
        "![learning curves](learning_curves.png)",
        "## Calibration",
        "Noise sigma 0.012 m (fit).",
        "| world | label | episodes | aborted |",
        "fisher_exact",
    ):
        assert needle in text
    raw = report.metrics.read_text()
    assert "NaN" not in raw
    metrics = json.loads(raw)
    # every episode counts: two complete and three aborted episodes of two robots
    assert metrics["sim/nominal/robot_trials"] == 10 and metrics["sim/nominal/aborted_episodes"] == 3
    assert metrics["sim/nominal/robot_success_completed"] is not None
    assert "gap/nominal/robot_success_p_value" in metrics
    assert metrics["gap/nominal/robot_success"] == 0.0
    assert "## Deployment timing" not in text  # the real recording has no /mrl/timing
    assert metrics.keys() == report.comparison.metrics.keys()
    for key, value in report.comparison.metrics.items():
        assert metrics[key] == (None if math.isnan(value) else value)
    assert report.episodes.height == 20 and set(report.episodes["label"]) == {"nominal"}


def test_report_shows_deployment_timing(recordings, tmp_path):
    sim, _ = recordings
    real = write_session(tmp_path / "timed.mcap", ground_truth=False, timing=True)
    report = write_report(tmp_path / "report", [("nominal", "sim", sim), ("nominal", "real", real)])
    text = report.markdown.read_text()
    assert "## Deployment timing" in text
    row = next(line for line in text.splitlines() if line.startswith("| real nominal |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[2] == "20.000" and cells[3] == "0.000" and cells[4] == "0.050" and cells[5] == "5.0"
    metrics = json.loads(report.metrics.read_text())
    assert metrics["real/nominal/send_skew_p99_ms"] == pytest.approx(0.05)
    assert metrics["real/nominal/state_age_p99_ms"] == pytest.approx(5.0)
    assert metrics["real/nominal/stale_records"] == 0
    assert not any(key.startswith("sim/nominal/tick") for key in metrics)
    assert set(metrics) - set(report.comparison.metrics) == {
        f"real/nominal/{name}"
        for name in ("tick_jitter_p99_ms", "send_skew_p99_ms", "state_age_p99_ms", "stale_records")
    }


def test_timing_metrics_of_an_unlabelled_session_have_one_separator(recordings, tmp_path):
    sim, _ = recordings
    real = write_session(tmp_path / "timed.mcap", ground_truth=False, timing=True)
    report = write_report(tmp_path / "report", [("", "sim", sim), ("", "real", real)])
    metrics = json.loads(report.metrics.read_text())
    assert not [key for key in metrics if "//" in key]
    assert metrics["real/send_skew_p99_ms"] == pytest.approx(0.05) and metrics["real/stale_records"] == 0
    assert "| real |" in report.markdown.read_text()  # the timing row names the session without a trailing blank


def test_a_pair_of_labels_is_compared_and_must_share_a_scenario(recordings, tmp_path):
    sim, real = recordings
    pair = [("simrun", "sim", sim), ("fleet", "real", real)]
    report = write_report(tmp_path / "pair", pair, pairs=[("simrun", "fleet")])
    metrics = json.loads(report.metrics.read_text())
    assert metrics["gap/simrun vs fleet/robot_success"] == 0.0
    assert "| simrun vs fleet | robot_success |" in report.markdown.read_text()
    other = write_session(tmp_path / "boxes.mcap", ground_truth=False, scenario_name="obstacles")
    with pytest.raises(AnalysisError, match=r"boxes\.mcap: recorded in scenario 'obstacles', but .*sim\.mcap"):
        write_report(tmp_path / "out", [("simrun", "sim", sim), ("boxes", "real", other)], pairs=[("simrun", "boxes")])
    with pytest.raises(AnalysisError, match="real label 'nominal' is to be compared, but no real session has it"):
        write_report(tmp_path / "out", pair, pairs=[("simrun", "nominal")])


def test_warnings_head_the_report(recordings, tmp_path):
    sim, _ = recordings
    report = write_report(tmp_path / "out", [("", "sim", sim)], warnings=["both inputs are the same file (x.mcap)"])
    text = report.markdown.read_text()
    assert text.index("## Warnings") < text.index("## Sessions")
    assert "- **Warning:** both inputs are the same file (x.mcap)" in text
    assert "## Warnings" not in write_report(tmp_path / "plain", [("", "sim", sim)]).markdown.read_text()


def test_trajectory_axes_are_labelled_in_metres(recordings):
    sim, real = recordings
    figure = trajectories_figure([("sim", sim), ("real", real)], episodes=2)
    shown = [ax for ax in figure.axes if ax.axison]
    assert len(shown) == 4
    for ax in shown:
        assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (m)", "y (m)")


def test_sessions_of_one_label_from_different_scenarios_are_refused(recordings, tmp_path):
    sim, _ = recordings
    other = write_session(tmp_path / "boxes.mcap", ground_truth=False, scenario_name="obstacles")
    with pytest.raises(AnalysisError, match=r"boxes\.mcap: recorded in scenario 'obstacles', but .*sim\.mcap"):
        write_report(tmp_path / "out", [("nominal", "sim", sim), ("nominal", "real", other)])
    # under different labels they may differ
    report = write_report(tmp_path / "out", [("empty room", "sim", sim), ("boxes", "real", other)])
    assert report.markdown.is_file()


def test_undefined_metrics_are_null(tmp_path):
    one_goal = [(3, 4, [(2, "goal", "robot_1"), (3, "collision", "robot_2")], [(4, "end", "incomplete")])]
    sim = write_session(tmp_path / "one.mcap", episodes=one_goal)
    report = write_report(tmp_path / "out", [("", "sim", sim)])
    metrics = json.loads(report.metrics.read_text())
    assert metrics["sim/mean_time_to_goal_s"] == pytest.approx(0.2)
    assert metrics["sim/mean_time_to_goal_s_ci_low"] is None and metrics["sim/robot_success"] == 0.5
    assert "## Sim vs real" not in report.markdown.read_text()


def test_report_refuses_bad_sessions(recordings, tmp_path):
    sim, _ = recordings
    with pytest.raises(AnalysisError, match="world 'lab' of session 'nominal' is not sim or real"):
        write_report(tmp_path, [("nominal", "lab", sim)])
    with pytest.raises(AnalysisError, match="no sessions"):
        write_report(tmp_path, [])


def test_learning_curve_files_are_checked(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("episode,world_steps\n1,200\n")
    with pytest.raises(TableError, match=r"bad\.csv: lacks column\(s\) robot_success, team_success"):
        plot_learning_curves([bad], tmp_path / "curves.png")
    with pytest.raises(TableError, match=r"gone\.csv: no such training-curve file"):
        plot_learning_curves([tmp_path / "gone.csv"], tmp_path / "curves.png")
    assert_png(plot_learning_curves([write_curve(tmp_path / "run.csv", 10)], tmp_path / "one.png"), 500, 300)


def test_success_rates_and_trajectories_stand_alone(recordings, tmp_path):
    panels = {"robot-level": [Rate("sim", 9, 10), Rate("real", 0, 0)], "team-level": [Rate("sim", 3, 5)]}
    assert_png(plot_success_rates(panels, tmp_path / "rates.png"), 600, 300)
    sim, real = recordings
    path = plot_trajectories([("sim", sim), ("real (odometry)", real)], tmp_path / "paths.png", episodes=[1, 4])
    assert_png(path, 600, 400)


def test_markdown_table():
    import polars as pl

    frame = pl.DataFrame({"a": [1, 2], "b": [0.5, float("nan")], "c": ["x|y", None], "d": [True, False]})
    assert markdown_table(frame).splitlines() == [
        "| a | b | c | d |",
        "|---|---|---|---|",
        "| 1 | 0.500 | x\\|y | yes |",
        "| 2 | n/a |  | no |",
    ]


def test_the_episodes_a_deployment_did_not_keep_its_clock_in_are_shown_beside_the_trials():
    from pipeline.analysis.gap_report import _episodes_text

    assert _episodes_text({"episodes": 50, "clock_not_kept_episodes": 1}) == (
        "50 (+1 off the clock: the host's, not the policy's; left out)"
    )
    assert _episodes_text({"episodes": 50, "clock_not_kept_episodes": 0}) == "50"
    assert _episodes_text({"episodes": 20}) == "20"  # a comparison without the column
