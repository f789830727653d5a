"""The files that pass between stages, each read back through its one typed reader: a session's metrics.json, the
calibration file, the policy's golden set and a recording's session metadata. Bad files are named, with the key."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.core.episode import summarize
from pipeline.errors import ConfigError
from pipeline.params import calibrated_world, read_calibration_file, world_config
from pipeline.policy.errors import PolicyError
from pipeline.policy.spec import GoldenSet, read_golden, write_golden
from pipeline.record.errors import RecordError
from pipeline.record.results import read_episodes_csv, read_session_metrics, write_episodes, write_metrics
from pipeline.record.session import session_info
from tests.unit.test_episode_summary import episode

ROOT = Path(__file__).resolve().parents[2]
LAB = ROOT / "benchmarks" / "results" / "loop" / "lab" / "logs"


def test_session_metrics_round_trip_through_their_one_writer_and_reader(tmp_path):
    results = [
        episode(0, [True, True], [False, False]),
        episode(1, [True, False], [False, True], stale=[0.5, 0.0]),
        episode(2, [True, False], [False, False], aborted=True, stale=[0.0, 5.2]),
    ]
    flat = summarize(results, prefix="real")
    write_metrics(tmp_path / "metrics.json", flat)
    m = read_session_metrics(tmp_path / "metrics.json")
    assert m.world == "real" and m.episodes == 3 and m.aborted_episodes == 1
    assert m.aborted_by_kind["outage"] == 1 and m.aborted_by_kind["fault"] == 0
    assert m.robot_success.value == pytest.approx(4 / 6) and m.robot_success.ci_low == flat["real/robot_success_ci_low"]
    assert m.robot_success_completed.value == pytest.approx(3 / 4)
    assert m.robot_success_each == pytest.approx((1.0, 1 / 3)) and m.stale_s_each == pytest.approx((0.5, 5.2))
    assert m.get("collision_rate") == pytest.approx(1 / 6) and math.isnan(m.get("no_such_figure"))


def test_a_committed_session_reads_and_a_broken_one_is_named(tmp_path):
    real = read_session_metrics(LAB / "real" / "nominal" / "metrics.json", "real")
    assert real.episodes == 50 and len(real.stale_s_each) == 3
    with pytest.raises(
        RecordError,
        match=r"metrics\.json: real/episodes, .* missing: not the metrics of a session of 'real'",
    ):
        read_session_metrics(LAB / "sim" / "nominal" / "metrics.json", "real")
    bad = tmp_path / "metrics.json"
    bad.write_text(json.dumps({"eval/robot_success": "high"}))
    with pytest.raises(RecordError, match=r"metrics\.json: eval/robot_success: 'high' is not a number"):
        read_session_metrics(bad)
    bad.write_text("{")
    with pytest.raises(RecordError, match="unreadable or not JSON"):
        read_session_metrics(bad)
    with pytest.raises(RecordError, match="missing: the session has not been run"):
        read_session_metrics(tmp_path / "none.json")


def test_the_calibration_file_is_read_with_its_format_checked(tmp_path):
    path = LAB / "calibration" / "calibration.yaml"
    cal = read_calibration_file(path)
    assert cal.scenario == "obstacles" and cal.keys["lidar.rate_hz"].ok
    low, high = cal.keys["lidar.rate_hz"].interval_95 or (0.0, 0.0)
    assert low <= (cal.keys["lidar.rate_hz"].value or 0.0) <= high
    assert all(not cal.keys[k].ok for k in cal.unidentified if k in cal.keys)
    base = world_config({})
    assert calibrated_world(base, path) == world_config(cal.world, base=base)
    data = yaml.safe_load(path.read_text())
    for name, change, message in (
        ("untagged", lambda d: d.pop("format"), r"format.*'mrl-calibration/1': calibrate again"),
        ("other", lambda d: d.update(format="mrl-calibration/9"), r"format = 'mrl-calibration/9': 'mrl-calibration/1'"),
        ("world", lambda d: d.update(world=[1, 2]), r"world = \[1, 2\]: a mapping"),
        (
            "status",
            lambda d: d["uncertainty"]["lidar"]["rate_hz"].update(status="fine"),
            r"uncertainty\.lidar\.rate_hz",
        ),
    ):
        broken = json.loads(json.dumps(data))
        change(broken)
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(broken))
        with pytest.raises(ConfigError, match=message):
            read_calibration_file(tmp_path / f"{name}.yaml")
        with pytest.raises(ConfigError, match=f"{name}.yaml"):
            calibrated_world(base, tmp_path / f"{name}.yaml")


def test_the_golden_set_round_trips_and_bad_ones_are_named(tmp_path):
    golden = GoldenSet(np.zeros((4, 3, 21), np.float32), np.full((4, 3, 2), 0.25), 1e-3, "commands")
    write_golden(golden, tmp_path / "golden.json")
    back = read_golden(tmp_path / "golden.json")
    assert json.loads((tmp_path / "golden.json").read_text())["format"] == "mrl-golden/1"
    assert np.array_equal(back.observations, golden.observations) and np.array_equal(back.actions, golden.actions)
    assert (back.tolerance, back.compared) == (1e-3, "commands")
    earlier = {"observations": golden.observations.tolist(), "actions": golden.actions.tolist(), "tolerance": 1e-5}
    (tmp_path / "earlier.json").write_text(json.dumps(earlier))
    assert read_golden(tmp_path / "earlier.json").compared == "actions"  # written before commands were compared
    for name, change, message in (
        ("format", {"format": "mrl-golden/7"}, r"format 'mrl-golden/7'"),
        ("extra", {"actionz": []}, r"unknown key\(s\) \['actionz'\]"),
        ("tolerance", {"tolerance": "tight"}, r"tolerance: 'tight'"),
        ("compared", {"compared": "vibes"}, r"compared: 'vibes'"),
        ("shape", {"actions": [[0.1]]}, r"observations have shape \(4, 3, 21\), actions \(1, 1\)"),
    ):
        (tmp_path / f"{name}.json").write_text(json.dumps({**earlier, **change}))
        with pytest.raises(PolicyError, match=f"{name}.json: {message}"):
            read_golden(tmp_path / f"{name}.json")


def test_session_metadata_is_read_the_same_way_everywhere():
    written = {
        "session": {"world": "real", "scenario": "obstacles", "robots": "robot_1,robot_2", "control_period_s": "0.1"},
        "scenario": {"text": json.dumps({"name": "my_room"})},
    }
    info = session_info(written)
    assert info.recorded and info.robots == ("robot_1", "robot_2") and info.control_period_s == 0.1
    assert info.scenario == "obstacles" and info.scenario_name() == "my_room"
    plain = session_info({})
    assert not plain.recorded and plain.robots == () and plain.control_period_s is None and plain.scenario_name() == ""
    assert session_info({"session": {"control_period_s": "nan"}}).control_period_s is None
    assert session_info({"scenario": {"text": "{"}}).scenario_name() == "(an unreadable scenario document)"


def test_a_copied_results_folder_reads_the_same(tmp_path):
    shutil.copytree(LAB / "real", tmp_path / "real")
    a = read_session_metrics(LAB / "real" / "calibrated" / "metrics.json")
    b = read_session_metrics(tmp_path / "real" / "calibrated" / "metrics.json")
    assert a == b


def test_episodes_csv_has_one_layout_written_and_read_back(tmp_path):
    results = [
        episode(0, [True, False], [False, True]),
        episode(1, [True, False], [False, False], aborted=True, stale=[0.0, 5.2]),
    ]
    write_episodes(tmp_path / "episodes.csv", results)
    rows = read_episodes_csv(tmp_path / "episodes.csv")
    assert [(r["episode"], r["robot"]) for r in rows] == [
        (0, "robot_1"),
        (0, "robot_2"),
        (1, "robot_1"),
        (1, "robot_2"),
    ]
    assert rows[3]["aborted"] == 1 and rows[3]["abort_kind"] == "outage" and rows[3]["stale_s"] == pytest.approx(5.2)
    assert math.isnan(rows[1]["time_to_goal_s"]) and rows[0]["time_to_goal_s"] == pytest.approx(1.0)
    committed = read_episodes_csv(LAB / "real" / "nominal" / "episodes.csv")
    assert len(committed) == 150 and {r["robot"] for r in committed} == {"robot_1", "robot_2", "robot_3"}
    old = tmp_path / "old.csv"
    old.write_text("episode,seed,robot,success\n0,0,robot_1,1\n")
    with pytest.raises(RecordError, match=r"old\.csv: columns \['episode', 'seed', 'robot', 'success'\]; an episodes"):
        read_episodes_csv(old)
    bad = tmp_path / "bad.csv"
    lines = (tmp_path / "episodes.csv").read_text().splitlines()
    bad.write_text("\n".join([lines[0], lines[1].replace("robot_1,", "robot_1,yes,", 1).rsplit(",", 1)[0]]) + "\n")
    with pytest.raises(RecordError, match=r"bad\.csv: line 2, success: 'yes' is not int"):
        read_episodes_csv(bad)


def test_the_session_summary_line_reads_the_metrics_through_their_reader():
    from pipeline.runs import session_summary

    results = [
        episode(0, [True, True], [False, False], stale=[0.5, 0.0]),
        episode(1, [True, False], [False, False], aborted=True, stale=[0.0, 5.2]),
    ]
    line = session_summary(summarize(results, prefix="real"), "real")
    assert line.startswith("2 episodes, 1 aborted (1 outage): robot success 0.750 [")
    assert "team success 0.500 [" in line and "completed episodes only 1.000 robot, 1.000 team" in line
    assert line.endswith("stale robot_1 0.5 s, robot_2 5.2 s")
    with pytest.raises(RecordError, match="real/episodes"):
        session_summary({"real/robot_success": 1.0}, "real")
