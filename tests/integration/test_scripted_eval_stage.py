"""The scripted_eval stage as dvc runs it: a real subprocess writing real files."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
STAGE = ROOT / "stages" / "scripted_eval.py"

pytestmark = pytest.mark.integration


def run_stage(params: dict, cwd: Path) -> subprocess.CompletedProcess[str]:
    (cwd / "params.yaml").write_text(yaml.safe_dump(params))
    return subprocess.run([sys.executable, str(STAGE)], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_stage_writes_metrics_episodes_and_picture(params_data, tmp_path):
    params_data["scripted_eval"].update(episodes=4, seed=5, out_dir="out/scripted")
    params_data["world"]["scenario"] = "empty"
    done = run_stage(params_data, tmp_path)
    assert done.returncode == 0, done.stderr
    out = tmp_path / "out" / "scripted"
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scripted/episodes"] == 4
    low, rate, high = (metrics[f"scripted/robot_success{s}"] for s in ("_ci_low", "", "_ci_high"))
    assert 0.0 <= low <= rate <= high <= 1.0
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert len(rows) == 4 * 3
    assert {r["robot"] for r in rows} == {"robot_1", "robot_2", "robot_3"}
    successes = sum(int(r["success"]) for r in rows)
    assert successes / len(rows) == pytest.approx(rate)
    assert Image.open(out / "paths.png").size[0] > 4 * 300


def test_stage_reports_bad_params_without_traceback(params_data, tmp_path):
    params_data["world"]["lidar"]["beams"] = 0
    params_data["scripted_eval"]["episodes"] = "many"
    done = run_stage(params_data, tmp_path)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert "params.yaml" in done.stderr
    assert "world.lidar.beams = 0" in done.stderr and "scripted_eval.episodes = 'many'" in done.stderr


def test_stage_reports_impossible_scenario(params_data, tmp_path):
    scenario = yaml.safe_load((ROOT / "pipeline/core/scenarios/empty.yaml").read_text())
    scenario["robots"][1]["start"] = {"x_m": 1.1, "y_m": 1.0, "yaw_rad": 0.0}
    (tmp_path / "crowded.yaml").write_text(yaml.safe_dump(scenario))
    params_data["world"]["scenario"] = "crowded.yaml"
    done = run_stage(params_data, tmp_path)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "robot_1 and robot_2 start" in done.stderr


def test_stage_answers_help_with_its_usage(tmp_path):
    done = subprocess.run(
        [sys.executable, str(STAGE), "--help"], cwd=tmp_path, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: scripted_eval.py [-h] [--params PARAMS]")
    assert "scripted go-to-goal controller" in done.stdout and done.stderr == ""


def test_stage_reads_the_params_file_it_is_given(params_data, tmp_path):
    params_data["scripted_eval"].update(episodes=1, out_dir="elsewhere/scripted")
    params_data["world"]["scenario"] = "empty"
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(params_data))
    done = subprocess.run(
        [sys.executable, str(STAGE), "--params", "p.yaml"], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr and not (tmp_path / "params.yaml").exists()
    assert json.loads((tmp_path / "elsewhere/scripted/metrics.json").read_text())["scripted/episodes"] == 1
    done = subprocess.run(
        [sys.executable, str(STAGE), "--params", "missing.yaml"], cwd=tmp_path, capture_output=True, text=True
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr and "missing.yaml" in done.stderr
