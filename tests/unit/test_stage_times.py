"""Each dvc stage run writes its wall time; benchmarks/stage_table.py makes the run's stage table of them."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from pipeline.errors import ConfigError
from pipeline.stage import EXIT_BAD_INPUT, run_stage

ROOT = Path(__file__).resolve().parents[2]


def test_a_stage_run_writes_its_time_round_and_exit_code(tmp_path, monkeypatch):
    times = tmp_path / "logs" / "stages"
    monkeypatch.setattr(sys, "argv", ["stages/train.py", "--round", "calibrated"])
    assert run_stage("train", lambda: time.sleep(0.2) or 0, times) == 0
    record = json.loads((times / "train@calibrated.json").read_text())
    assert record["stage"] == "train@calibrated" and record["exit"] == 0 and 0.2 <= record["seconds"] < 5

    def refused() -> int:
        raise ConfigError("params.yaml", [])

    monkeypatch.setattr(sys, "argv", ["stages/report.py"])
    assert run_stage("report", refused, times) == EXIT_BAD_INPUT
    assert json.loads((times / "report.json").read_text())["exit"] == EXIT_BAD_INPUT
    assert run_stage("export", lambda: 0) == 0 and not (times / "export.json").exists()  # no folder: nothing written

    table = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "stage_table.py"), "--root", str(tmp_path)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.splitlines()
    assert [line.split()[0] for line in table[1:-1]] == ["train@calibrated", "report"]  # in the loop's order
    assert table[-1].startswith("stages=2 total_s=") and table[-1].endswith("slowest=train@calibrated")


def test_the_stage_table_names_an_empty_folder(tmp_path):
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "stage_table.py"), "--root", str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2 and "no stage times in" in done.stderr and str(tmp_path) in done.stderr
