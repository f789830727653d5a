"""benchmarks/teachers.py end to end: both teachers on a few held-out layouts, figures printed."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import teachers

pytestmark = pytest.mark.integration


def test_both_teachers_are_judged_on_the_same_held_out_layouts(capsys: pytest.CaptureFixture[str]) -> None:
    assert teachers.main(["--episodes", "2", "--max-steps", "60", "--scenario", "obstacles_random_in_way"]) == 0
    out = capsys.readouterr().out
    assert "obstacles_random_in_way (random layouts): 2 episodes from seed 10000, 6 s limit" in out
    rows = re.findall(
        r"^(scripted|path) +robot success ([0-9.]+) \[([0-9.]+), ([0-9.]+)\].*collisions (\d+), ([0-9.]+) ms", out, re.M
    )
    assert [r[0] for r in rows] == ["scripted", "path"]
    for _, rate, low, high, _, ms in rows:
        assert 0.0 <= float(low) <= float(rate) <= float(high) <= 1.0 and float(ms) > 0


def test_the_path_teacher_needs_continuous_actions(tmp_path: Path) -> None:
    params = (Path(__file__).resolve().parents[2] / "params.yaml").read_text()
    bad = tmp_path / "params.yaml"
    bad.write_text(params.replace("kind: continuous", "kind: discrete", 1))
    with pytest.raises(SystemExit, match=r"params\.yaml: world\.actions\.kind must be 'continuous'"):
        teachers.main(["--params", str(bad), "--episodes", "1"])
