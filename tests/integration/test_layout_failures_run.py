"""benchmarks/layout_failures.py end to end on a tiny exported policy: the longer-limit replay and its refusal."""

from __future__ import annotations

from pathlib import Path

import pytest
from layout_failures import main

ROOT = Path(__file__).resolve().parents[2]


def test_a_longer_step_limit_is_replayed_and_agrees_by_the_world_limit(
    tiny_policy: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["--policy", str(tiny_policy), "--episodes", "2", "--max-steps", "60"]) == 0
    out = capsys.readouterr().out
    assert "obstacles (fixed layouts): 2 episodes, 6 robot-episodes" in out
    # the policy does not see the clock: every outcome by the world's 30 steps (3 s) is the same in both runs
    assert "with a step limit of 60 (6 s): robot success" in out
    assert "outcomes by 3 s agree in 6 of 6 robot-episodes" in out


def test_a_step_limit_not_above_the_worlds_is_refused(tiny_policy: Path) -> None:
    with pytest.raises(SystemExit, match=r"--max-steps must be above the world's step limit \(30\), got 30"):
        main(["--policy", str(tiny_policy), "--episodes", "1", "--max-steps", "30"])
