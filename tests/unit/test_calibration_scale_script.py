"""benchmarks/calibration_scale.py refuses a building it cannot make, naming the option, before it makes anything."""

from __future__ import annotations

from pathlib import Path

import pytest
from calibration_scale import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("argv", "option"),
    [(["--size", "10"], "--size"), (["--resolution", "0"], "--resolution"), (["--minutes", "-1"], "--minutes")],
)
def test_sizes_the_benchmark_cannot_build_are_refused(argv, option, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and option in err and "Traceback" not in err
