"""The hardware twin as a process: ready line, clean shutdown on SIGINT and SIGTERM, clear bad-input errors."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from tests.integration.conftest import write_fleet

pytestmark = pytest.mark.integration


def start_twin(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "pipeline.twin", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_twin_reports_ready_and_stops_cleanly(tmp_path, sig):
    fleet = write_fleet(tmp_path / "fleet.yaml")
    proc = start_twin("--fleet", str(fleet), "--time-scale", "2")
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.startswith("twin: ready, profile mild, 3 robots"), line
    time.sleep(1.0)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "twin: stopped after" in out and "Traceback" not in err


def test_twin_refuses_bad_input_with_a_clear_message(tmp_path):
    fleet = write_fleet(tmp_path / "fleet.yaml")
    (tmp_path / "bad.yaml").write_text("lidar: {beams: 0}\n")
    proc = start_twin("--fleet", str(fleet), "--profile", str(tmp_path / "bad.yaml"))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "Traceback" not in err
    assert "bad.yaml" in err and "lidar.beams = 0" in err and "actuation = <missing>" in err
    proc = start_twin("--fleet", str(tmp_path / "nowhere.yaml"))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "nowhere.yaml" in err and "Traceback" not in err
    for bad in ("robot_2@soon", "robot_2@1.0+long"):
        proc = start_twin("--fleet", str(fleet), "--silence", bad)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 2 and "Traceback" not in err
        assert f"--silence {bad!r}" in err and "NAMESPACE@START[+DURATION]" in err
    proc = start_twin("--fleet", str(fleet), "--silence", "robot_9@1.0")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "no robot 'robot_9' in the fleet" in err and "Traceback" not in err
