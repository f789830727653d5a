"""A tiny sweep on a local Ray instance: real training, export and evaluation per trial; resumed without redoing
finished trials; its table, statistics and report through the installed command."""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys
from pathlib import Path

import polars as pl
import pytest

from pipeline.bench.sweep import run_sweep, source_commit, trial_folder
from pipeline.bench.trials import ROW_FILE, base_mapping, expand
from pipeline.params import load_params

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
MRL = Path(sys.executable).parent / "mrl"


def test_a_sweep_runs_trials_on_ray_resumes_and_reports(tiny_params, tmp_path):
    base = base_mapping(load_params(tiny_params))
    out = tmp_path / "sweep"
    lines: list[str] = []
    first = run_sweep(expand(["sac"], ["independent"], ["empty"], [0]), base, out, eval_episodes=2, say=lines.append)
    assert first.ran == 1 and first.skipped == 0 and not first.failed, (first.failed, lines)
    row0 = trial_folder(out, expand(["sac"], ["independent"], ["empty"], [0])[0]) / ROW_FILE
    before = row0.read_bytes()

    # the sweep grows by two seeds, through the installed command: the finished trial is skipped, the new ones
    # run at once on two workers of the local Ray, each showing its own progress; --set of an unchanged value
    # leaves the finished trial's settings (and so its row) as they were
    proc = subprocess.run(
        [
            str(MRL), "sweep", "--algorithms", "sac", "--modes", "independent", "--scenarios", "empty",
            "--seeds", "3", "--params", str(tiny_params), "--out", str(out), "--workers", "2", "--episodes", "2",
            "--set", "train.total_steps=600", "--bootstrap", "200",
        ],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "sweep: 3 trials, 1 finished before (skipped), 2 to run" in proc.stdout
    for seed in (1, 2):
        name = f"sac-independent-empty-seed{seed}"
        assert f"trial {name}: training 600 steps" in proc.stdout
        assert re.search(rf"trial {name}: \d+ episodes, \d+ steps, success", proc.stdout), proc.stdout
        assert re.search(rf"sweep: \[\d/2\] {name}: robot success", proc.stdout), proc.stdout
    assert row0.read_bytes() == before

    trials = expand(["sac"], ["independent"], ["empty"], [0, 1, 2])
    second = run_sweep(trials, base, out, eval_episodes=2, say=lines.append)
    assert second.skipped == 3 and second.ran == 0 and not second.failed
    rows = second.rows
    assert rows.height == 3 and rows["seed"].to_list() == [0, 1, 2]
    assert set(rows["cell"]) == {"sac/independent/empty"}
    for row in rows.iter_rows(named=True):
        assert row["train_steps"] >= 600 and row["eval_episodes"] == 2 and row["env_steps_per_s"] > 0
        assert 0.0 <= row["robot_success"] <= 1.0
        per_robot = [row[f"success_robot_{k}"] for k in (1, 2, 3)]
        assert row["robot_success"] == pytest.approx(sum(per_robot) / 3)
    for trial in trials:
        folder = trial_folder(out, trial)
        assert (folder / "policy" / "policy.json").is_file() and (folder / "run" / "curve.csv").is_file()
    assert pl.read_parquet(out / "results.parquet").equals(rows)
    assert pl.read_csv(out / "results.csv").height == 3
    # how the rows were made: every run that trained something, and each row's commit and host
    runs = json.loads((out / "sweep.json").read_text())
    assert [len(run["ran"]) for run in runs] == [1, 2], runs  # the third run trained nothing
    assert runs[1]["command"].startswith("mrl sweep --algorithms sac") and runs[1]["skipped"] == 1
    assert runs[1]["address"] == "local Ray, 2 workers" and "CPUs" in runs[1]["machine"]
    assert set(rows["commit"]) == {runs[0]["commit"]} and runs[0]["commit"] == source_commit() != "unknown"
    assert set(rows["host"]) == {socket.gethostname()}

    # the report from the finished trials, through the installed command, into a README's section of its own; the
    # table is written again from the rows
    (out / "results.csv").unlink()
    (out / "results.parquet").unlink()
    readme = tmp_path / "README.md"
    readme.write_text("# Results\n\n<!-- sweep results tiny: start -->\nold\n<!-- sweep results tiny: end -->\nrest\n")
    proc = subprocess.run(
        [
            str(MRL), "sweep", "--algorithms", "sac", "--modes", "independent", "--scenarios", "empty",
            "--seeds", "3", "--params", str(tiny_params), "--out", str(out), "--report-only", "--bootstrap", "200",
            "--readme", str(readme), "--readme-section", "tiny",
        ],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "sweep: report of 3 finished trials of 3" in proc.stdout
    assert "| sac | independent | empty | 3 |" in proc.stdout
    report = (out / "results.md").read_text()
    assert "| sac | independent | empty | 3 |" in report and "![learning curves](learning_curves.png)" in report
    assert pl.read_csv(out / "results.csv").height == 3 and pl.read_parquet(out / "results.parquet").height == 3
    assert (out / "learning_curves.png").stat().st_size > 0 and (out / "performance_profiles.png").stat().st_size > 0
    text = readme.read_text()
    assert "| sac | independent | empty | 3 |" in text and "old" not in text and text.endswith("end -->\nrest\n")
    assert "![learning curves](benchmarks/figures/tiny_learning_curves.png)" in text
    copied = tmp_path / "benchmarks" / "figures" / "tiny_learning_curves.png"
    assert copied.read_bytes() == (out / "learning_curves.png").read_bytes()

    # the folder as git keeps it under benchmarks/results/sweeps/ (rows, curves, record; no policies or
    # checkpoints), elsewhere: the sweep there finds every trial finished and trains nothing
    committed = ROOT / "benchmarks" / "results" / "sweeps" / "any"
    kept = tmp_path / "kept"
    for path in out.rglob("*"):
        relative = path.relative_to(out)
        ignored = subprocess.run(["git", "check-ignore", "-q", str(committed / relative)], cwd=ROOT, check=False)
        if path.is_file() and ignored.returncode == 1:  # 1: not ignored
            (kept / relative).parent.mkdir(parents=True, exist_ok=True)
            (kept / relative).write_bytes(path.read_bytes())
    assert not list(kept.rglob("policy.onnx")) and not list(kept.rglob("*.pt")), sorted(kept.rglob("*"))
    assert len(list(kept.rglob("row.json"))) == 3 and len(list(kept.rglob("curve.csv"))) == 3
    again = run_sweep(trials, base, kept, eval_episodes=2, say=lines.append)
    assert again.skipped == 3 and again.ran == 0 and again.rows.equals(rows)


def test_a_setting_for_every_trial_is_checked_before_anything_runs(tiny_params, tmp_path):
    proc = subprocess.run(
        [
            str(MRL), "sweep", "--algorithms", "sac", "--scenarios", "empty", "--seeds", "1",
            "--params", str(tiny_params), "--out", str(tmp_path / "sweep"),
            "--set", "train.selection.stop_at_success=2",
        ],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "train.selection.stop_at_success = 2" in proc.stderr and "<= 1.0" in proc.stderr
    assert not (tmp_path / "sweep").exists()

    # a README without the section's markers is refused before anything runs, not after hours of training
    readme = tmp_path / "README.md"
    readme.write_text("# no markers\n")
    proc = subprocess.run(
        [
            str(MRL), "sweep", "--algorithms", "sac", "--scenarios", "empty", "--seeds", "1",
            "--params", str(tiny_params), "--out", str(tmp_path / "sweep"), "--readme", str(readme),
        ],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert f"--readme: 1 invalid setting(s): {readme} = 'without the markers'" in proc.stderr
    assert "<!-- sweep results: start -->" in proc.stderr and not (tmp_path / "sweep").exists()

    # a section name that cannot name a marker or a figure file is refused the same way
    proc = subprocess.run(
        [
            str(MRL), "sweep", "--algorithms", "sac", "--scenarios", "empty", "--seeds", "1",
            "--params", str(tiny_params), "--out", str(tmp_path / "sweep"), "--readme", str(readme),
            "--readme-section", "a b",
        ],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "--readme-section: 1 invalid setting(s): name = 'a b': letters, digits, _ and -" in proc.stderr


def test_ctrl_c_stops_a_sweep_mid_trial_and_records_the_run_as_interrupted(tiny_params, tmp_path):
    """SIGINT while a trial trains: the driver stops Ray, keeps the rows it has (none here) and appends the run to
    sweep.json marked interrupted; the same command later runs the trial from the start."""
    import signal
    import time

    out = tmp_path / "sweep"
    proc = subprocess.Popen(
        [
            str(MRL), "sweep", "--algorithms", "sac", "--modes", "independent", "--scenarios", "empty",
            "--seeds", "1", "--params", str(tiny_params), "--out", str(out), "--episodes", "2",
            "--set", "train.total_steps=200000",
        ],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    seen = []
    for line in proc.stdout:
        seen.append(line)
        if "training 200000 steps" in line:
            break
    else:
        pytest.fail("the trial never started:\n" + "".join(seen))
    time.sleep(2.0)
    proc.send_signal(signal.SIGINT)
    try:
        proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("the sweep did not stop on SIGINT")
    runs = json.loads((out / "sweep.json").read_text())
    assert len(runs) == 1 and runs[0]["interrupted"] is True and runs[0]["ran"] == [], runs
    assert runs[0]["command"].startswith("mrl sweep --algorithms sac")
    assert not list(out.glob(f"trials/*/{ROW_FILE}"))
