"""benchmarks/train_speed.py: a device it cannot use is refused in one line that names the option, before any timing;
a sweep settings file is timed with the script's own budget and no stop."""

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


def test_a_sweep_settings_file_whose_stop_waits_for_convergence_is_timed_without_any_stop():
    # the script sets evaluations and stops itself: a settings file's qualified stop (dqn_nstep_converge.yaml's
    # stop_after_convergence) must not leave a stop qualifier without its stop
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    settings = ROOT / "benchmarks" / "sweeps" / "dqn_nstep_converge.yaml"
    options = [
        "--algorithms",
        "dqn",
        "--modes",
        "independent",
        "--steps",
        "64",
        "--learning-starts",
        "16",
        "--world-workers",
        "1",
    ]
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "train_speed.py"), *options, "--settings", str(settings)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    last = done.stdout.strip().splitlines()[-1]
    assert "dqn/independent=" in last and "updates bound" in last
