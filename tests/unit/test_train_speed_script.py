"""benchmarks/train_speed.py refuses a device it cannot use in one line that names the option, before any timing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch as th

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(th.cuda.is_available(), reason="torch sees a CUDA GPU here: the option is usable")
def test_a_gpu_option_without_a_gpu_is_refused_by_name():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "train_speed.py"), "--gradient-only", "--gradient-devices", "cuda"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert done.returncode != 0
    assert "Traceback" not in done.stderr
    assert "--gradient-devices cuda" in done.stderr and "sees no CUDA GPU" in done.stderr
    assert done.stdout == ""
