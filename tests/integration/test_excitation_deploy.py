"""`mrl deploy --drive excitation`: the calibration drive over an exported policy, on the twin, recorded."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.policy.excitation import STEP_SIZES
from pipeline.record import McapLog
from tests.integration.conftest import write_fleet

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
V_MAX = 0.4


def held(values: np.ndarray, at_least: int) -> set[float]:
    """Values held for at least `at_least` consecutive messages."""
    out, start = set(), 0
    for k in range(1, len(values) + 1):
        if k == len(values) or values[k] != values[start]:
            if k - start >= at_least:
                out.add(float(values[start]))
            start = k
    return out


def test_the_calibration_drive_sends_held_steps_through_the_fleet_and_records_them(tiny_policy, tmp_path):
    # 1x, the robots' own pace: 8 episodes that must all keep their clock (at 2x a 2-core host woke one of them
    # 1.4 periods late, beside a second worker and alone; at 3x some fell behind)
    fleet = write_fleet(tmp_path / "fleet.yaml", twin={"profile": "lab", "time_scale": 1.0, "seed": 2})
    out = tmp_path / "out"
    options = ["--policy", str(tiny_policy), "--fleet", str(fleet), "--drive", "excitation"]
    done = subprocess.run(
        [sys.executable, "-m", "pipeline.mrl", "deploy", *options, "--episodes", "8", "--seed", "7", "--out", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    log = McapLog(out / "session.mcap")
    session = log.metadata()["session"]
    assert session["drive"] == "excitation" and session["drive_seed"] == "7"
    topics = [t for t in log.topics() if t.endswith("/cmd_vel")]
    assert len(topics) == 3
    steps, turns = set(), set()
    for topic in topics:
        cmd = np.array([(m.msg.linear.x, m.msg.angular.z) for m in log.messages(topic)])
        # the fleet ticks every 20 ms: a phase of a second or more repeats its command 50 times, less where an episode
        # ends (or a step its room) first
        steps |= {round(v / V_MAX, 6) for v in held(np.where(cmd[:, 1] == 0, cmd[:, 0], 0.0), 25) if v > 0}
        turns |= {v for v in held(np.where(cmd[:, 0] == 0, cmd[:, 1], 0.0), 25) if v != 0}
    assert steps and steps <= set(STEP_SIZES), steps
    assert turns
