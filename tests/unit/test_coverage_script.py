"""benchmarks/calibration_coverage.py: the truth behind each key, the summary, a kept folder it refuses."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from calibration_coverage import _jumped, command_path_s, summary, truth_of

from pipeline.calibration.actuation import CommandTimeline
from pipeline.twin.draw import draw_profile_mapping

ROOT = Path(__file__).resolve().parents[2]


def test_the_truth_of_a_key_comes_from_the_drawn_profile() -> None:
    profile = draw_profile_mapping(7, 2)
    assert truth_of(profile, "lidar.noise_sigma_m") == pytest.approx(profile["lidar"]["noise_sigma_m"])
    assert truth_of(profile, "lidar.mount_xy_m[1]") == pytest.approx(profile["lidar"]["mount_xy_m"][1])
    assert truth_of(profile, "map.box_offsets_m[1][0]") == pytest.approx(profile["map"]["box_offsets_m"][1][0])
    base = profile["base"]
    wheels = (base["wheel_radius_left_m"] + base["wheel_radius_right_m"]) / (2 * 0.034)
    assert truth_of(profile, "actuation.linear_gain") == pytest.approx(profile["actuation"]["linear_gain"] * wheels)
    assert truth_of(profile, "lidar.no_such_key") is None


def test_the_summary_holds_every_key_to_the_coverage_target(capsys: pytest.CaptureFixture[str]) -> None:
    rows: list[dict[str, object]] = []
    for p in range(10):
        rows.append({"key": "lidar.bias_m", "covered": int(p < 9), "rel_error": 0.01, "low": 0.0, "high": 0.02})
        rows.append({"key": "lidar.noise_sigma_m", "covered": 1, "rel_error": 0.3, "low": 0.0, "high": 0.02})
        rows.append({"key": "effective.drive_lag_s", "covered": int(p < 5), "rel_error": 0.5, "low": 0.0, "high": 0.1})
        rows.append({"key": "base.deadband_radps"})
    summary(rows)
    out = capsys.readouterr().out
    # the effective key counts against the coverage target (scored against what it stands for), not the 15 % one;
    # the deadband, never identified, is shown as 0/10 and not counted
    assert "coverage_min=0.50 keys_at_target=2/3 identifiable_within_15pct=1/2" in out
    deadband = next(line for line in out.splitlines() if line.startswith("base.deadband_radps"))
    assert "0/10" in deadband and "effective" in out


def test_wide_ranges_span_real_robots_and_the_drawn_profiles_stay_as_committed() -> None:
    import yaml

    from pipeline.twin.draw import WIDE_RANGES

    profile = draw_profile_mapping(7, 2, WIDE_RANGES)
    delay, lag = profile["actuation"]["delay_s"], profile["actuation"]["time_constant_s"]
    assert 0.02 <= delay <= 0.15 and 0.05 <= lag <= 0.3 and -1.0 <= profile["clock"]["offset_s"] <= 1.0
    committed = ROOT / "benchmarks" / "results" / "sim2real" / "drawn_26" / "profile.yaml"
    assert draw_profile_mapping(26, 2) == yaml.safe_load(committed.read_text())


def test_recalibrating_a_folder_without_the_kept_recordings_names_what_is_missing(tmp_path: Path) -> None:
    (tmp_path / "drawn_100.yaml").write_text("{}\n")
    script = str(ROOT / "benchmarks" / "calibration_coverage.py")
    run = subprocess.run(
        [sys.executable, script, "--recalibrate", str(tmp_path), "--profiles", "2"],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert run.returncode == 2, run.stderr
    assert "drawn_100.mcap" in run.stdout and "drawn_101.yaml" in run.stdout and "drawn_100.yaml" not in run.stdout
    assert "Traceback" not in run.stderr


def test_parts_go_with_a_recalibration_only(tmp_path: Path) -> None:
    """A deployment is calibrated whole; --parts (e.g. lidar alone, seconds per recording) rescores kept ones."""
    script = str(ROOT / "benchmarks" / "calibration_coverage.py")
    run = subprocess.run(
        [sys.executable, script, "--parts", "lidar", "--keep", str(tmp_path)], capture_output=True, text=True, cwd=ROOT
    )
    assert run.returncode == 2 and "--parts goes with --recalibrate" in run.stdout, run.stdout + run.stderr
    assert not list(tmp_path.iterdir())  # nothing deployed


def test_the_progress_line_names_the_stalls_the_twin_jumped(tmp_path: Path) -> None:
    """A jumped stall freezes the twin's world but not the drive's replay: the run says so, per profile."""
    import numpy as np

    quiet, stalled, older = tmp_path / "quiet.npz", tmp_path / "stalled.npz", tmp_path / "older.npz"
    np.savez(quiet, jump_ns=np.zeros(0, np.int64), jump_skipped_ns=np.zeros(0, np.int64))
    np.savez(stalled, jump_ns=np.array([5, 9], np.int64), jump_skipped_ns=np.array([1_200_000_000, 1_050_000_000]))
    np.savez(older, cmd_ns=np.zeros(0, np.int64))  # a record from before jumps were recorded
    assert _jumped(quiet) == _jumped(older) == _jumped(tmp_path / "absent.npz") == ""
    assert _jumped(stalled) == "; the twin jumped 2 host stall(s), 2.25 s frozen"


def test_the_command_paths_latency_is_read_from_the_twins_record() -> None:
    """Held commands repeat the same values: each recorded one is matched to its own arrival, a lost one to none."""
    from types import SimpleNamespace

    import numpy as np

    rng = np.random.default_rng(3)
    n = 600
    sent_ns = np.arange(n, dtype=np.int64) * 100_000_000 + 7
    v = np.repeat(rng.uniform(-0.3, 0.3, n // 20), 20)  # held for 2 s at 10 Hz
    w = np.repeat(rng.uniform(-1.0, 1.0, n // 20), 20)
    latency = rng.exponential(0.010, n) + 0.002  # a busy host's path: mean 12 ms
    taken = np.sort(sent_ns + np.round(latency * 1e9).astype(np.int64))
    kept = np.ones(n, dtype=bool)
    kept[[40, 41, 300]] = False  # lost on the way (two inside a held block)
    applied = {"tb1": CommandTimeline(taken[kept], np.stack([v, w], axis=1)[kept])}
    robot = SimpleNamespace(name="tb1", commands=SimpleNamespace(t_ns=sent_ns, v=v, w=w))
    other = SimpleNamespace(name="tb2", commands=None)
    path = command_path_s(SimpleNamespace(robots=[robot, other]), applied)  # type: ignore[arg-type]
    assert path is not None
    mean_s, matched = path
    assert matched == n - 3
    assert mean_s == pytest.approx(float(np.mean(latency[kept])), abs=2e-6)
    assert command_path_s(SimpleNamespace(robots=[other]), applied) is None  # type: ignore[arg-type]


def test_pooled_runs_keep_a_key_scored_against_different_truths_apart(capsys: pytest.CaptureFixture[str]) -> None:
    """An identifiable key scored against what the run realized stays identifiable; runs that scored it against
    the profile and the realization are summarized apart, never mixed."""
    rows: list[dict[str, object]] = []
    for p in range(10):
        common = {"covered": 1, "low": 0.0, "high": 0.1}
        rows.append({"key": "actuation.delay_s", "truth_of": "profile", "rel_error": 0.2, **common})
        rows.append({"key": "actuation.delay_s", "truth_of": "realized", "rel_error": 0.05, **common})
        rows.append({"key": "lidar.bias_m", "truth_of": "profile", "rel_error": 0.01, **common, "covered": int(p > 0)})
    summary(rows)
    out = capsys.readouterr().out
    lines = {line.split("  ")[0]: line for line in out.splitlines()}
    assert "identif.r" in lines["actuation.delay_s (realized)"] and "0.050" in lines["actuation.delay_s (realized)"]
    assert "0.200" in lines["actuation.delay_s (profile)"] and "lidar.bias_m" in lines
    assert "keys_at_target=3/3 identifiable_within_15pct=2/3" in out


def test_pooling_refuses_a_profile_counted_twice(tmp_path: Path) -> None:
    header = "profile,key,truth,truth_of,profile_truth,value,low,high,covered,rel_error\n"
    row = "100,lidar.bias_m,0.01,profile,0.01,0.011,0.009,0.012,1,0.1\n"
    first, second = tmp_path / "a.csv", tmp_path / "b.csv"
    first.write_text(header + row)
    second.write_text(header + row.replace("100,", "101,", 1))
    script = str(ROOT / "benchmarks" / "calibration_coverage.py")
    ok = subprocess.run([sys.executable, script, "--pool", str(first), str(second)], capture_output=True, text=True)
    assert ok.returncode == 0 and "2 profiles from 2 runs" in ok.stdout, ok.stdout + ok.stderr
    again = subprocess.run([sys.executable, script, "--pool", str(first), str(first)], capture_output=True, text=True)
    assert again.returncode == 2 and "profile 100 is in both" in again.stdout and "Traceback" not in again.stderr


def test_pooling_names_a_missing_file_and_a_csv_that_is_not_a_coverage_run(tmp_path: Path) -> None:
    script = str(ROOT / "benchmarks" / "calibration_coverage.py")
    absent = subprocess.run(
        [sys.executable, script, "--pool", str(tmp_path / "none.csv")], capture_output=True, text=True
    )
    assert absent.returncode == 2 and "none.csv does not exist" in absent.stdout and "Traceback" not in absent.stderr
    other = tmp_path / "other.csv"
    other.write_text("profile,key\n100,lidar.bias_m\n")
    wrong = subprocess.run([sys.executable, script, "--pool", str(other)], capture_output=True, text=True)
    assert wrong.returncode == 2 and "other.csv is not a coverage CSV" in wrong.stdout, wrong.stdout + wrong.stderr
    assert "Traceback" not in wrong.stderr


def test_the_coverage_test_passes_exact_intervals_and_flags_too_sure_ones() -> None:
    """29 keys' intervals over 20 realities: exact 95 % intervals are called too sure in at most about 5 % of runs
    (Bonferroni over the keys), where the per-key 90 % target fails most runs; 75 % intervals are caught; the
    Clopper-Pearson interval of a key's coverage holds its true coverage at least 95 % of the time."""
    import numpy as np
    from calibration_coverage import coverage_test

    rng = np.random.default_rng(11)
    runs, keys, n = 400, 29, 20
    hits = rng.binomial(n, 0.95, size=(runs, keys))
    flagged = np.array([[coverage_test(int(h), n, keys)[3] for h in run] for run in hits])
    assert flagged.any(axis=1).mean() <= 0.07
    assert (hits < 0.9 * n).any(axis=1).mean() > 0.5  # the 90 % target: most runs of exact intervals fail it
    loose = rng.binomial(n, 0.75, size=(100, keys))
    assert np.mean([any(coverage_test(int(h), n, keys)[3] for h in run) for run in loose]) > 0.95
    bounds = np.array([coverage_test(int(h), n, keys)[:2] for h in rng.binomial(n, 0.8, size=2000)])
    assert np.mean((bounds[:, 0] <= 0.8) & (bounds[:, 1] >= 0.8)) >= 0.95
