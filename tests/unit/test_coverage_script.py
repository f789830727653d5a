"""benchmarks/calibration_coverage.py: the truth behind each key, the summary, a kept folder it refuses."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from calibration_coverage import summary, truth_of  # noqa: E402

from pipeline.twin.draw import draw_profile_mapping  # noqa: E402


def test_the_truth_of_a_key_comes_from_the_drawn_profile() -> None:
    profile = draw_profile_mapping(7, 2)
    assert truth_of(profile, "lidar.noise_sigma_m") == pytest.approx(profile["lidar"]["noise_sigma_m"])
    assert truth_of(profile, "lidar.mount_xy_m[1]") == pytest.approx(profile["lidar"]["mount_xy_m"][1])
    assert truth_of(profile, "map.box_offsets_m[1][0]") == pytest.approx(profile["map"]["box_offsets_m"][1][0])
    base = profile["base"]
    wheels = (base["wheel_radius_left_m"] + base["wheel_radius_right_m"]) / (2 * 0.034)
    assert truth_of(profile, "actuation.linear_gain") == pytest.approx(profile["actuation"]["linear_gain"] * wheels)
    assert truth_of(profile, "lidar.no_such_key") is None


def test_the_summary_counts_only_identifiable_keys_against_the_target(capsys: pytest.CaptureFixture[str]) -> None:
    rows: list[dict[str, object]] = []
    for p in range(10):
        rows.append({"key": "lidar.bias_m", "covered": int(p < 9), "rel_error": 0.01, "low": 0.0, "high": 0.02})
        rows.append({"key": "actuation.delay_s", "covered": 0, "rel_error": 0.5, "low": 0.0, "high": 0.02})
        rows.append({"key": "base.deadband_radps"})
    summary(rows)
    out = capsys.readouterr().out
    # the effective key is shown and not counted; the deadband, never identified, is shown as 0/10 and not counted
    assert "coverage_min=0.90 keys_at_target=1/1" in out
    deadband = next(line for line in out.splitlines() if line.startswith("base.deadband_radps"))
    assert "0/10" in deadband and "effective" in out


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
