"""Calibration at building scale keeps its memory bounded: a 30 x 30 m map_server map at 5 cm with thousands of faces
and a 3-minute bag of a 720-beam lidar calibrate within 2 GiB (benchmarks/calibration_scale.py at a smaller size; its
time against the bag's duration is the benchmark's figure, not a test's)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from calibration_scale import main

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow


def test_a_building_bag_calibrates_within_the_memory_bound(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--size", "30", "--minutes", "3"]) == 0
    out = capsys.readouterr().out
    faces = int(re.search(r"(\d+) faces", out).group(1))  # type: ignore[union-attr]
    last = dict(pair.split("=") for pair in out.strip().splitlines()[-1].split())
    assert faces > 5000, out
    assert float(last["limit_ratio"]) <= 1.0, out
    assert "match score 1.00" in out or "match score 0.9" in out, out
    assert (
        "lidar.noise_sigma_m          0.0" in out and "covered" in out.split("lidar.noise_sigma_m")[1].splitlines()[0]
    )
