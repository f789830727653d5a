"""Two runs started together on one DDS domain: no recording holds a message of the other run's twin.

The second run's twin keeps its robots' clock 100 s ahead, so any of its messages in the first run's recording (or
the other way round) shows in the stamps. Each run either finishes or stops with a named runtime fault (exit 3):
refused at start-up (two publishers on a topic) or aborted as a clash (a writer it did not discover)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.core.timebase import NS_PER_S
from pipeline.record import McapLog
from tests.integration.conftest import free_domain_id, write_fleet

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
AHEAD_S = 100.0


def start(policy: Path, fleet: Path, out: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "pipeline.mrl",
            "deploy",
            *("--policy", str(policy), "--fleet", str(fleet), "--out", str(out), "--episodes", "2"),
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def stamp_offsets_s(recording: Path) -> np.ndarray:
    """Header stamp minus log time (s) of every scan and odometry message the run recorded (the robots' clock; motion
    capture stamps ground truth on its own)."""
    log = McapLog(recording)
    topics = [t for t in log.topics() if t.endswith(("/scan", "/odom"))]
    return np.array(
        [(header_stamp_ns(m.msg) - m.log_time_ns) / NS_PER_S for m in log.messages(topics)], dtype=np.float64
    )


def header_stamp_ns(msg: object) -> int:
    stamp = msg.header.stamp  # type: ignore[attr-defined]
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def clash_rounds(policy: Path, tmp_path: Path, rounds: int) -> list[tuple[int, int]]:
    profile = yaml.safe_load((ROOT / "pipeline" / "twin" / "profiles" / "mild.yaml").read_text())
    profile["clock"] = {**profile.get("clock", {}), "offset_s": AHEAD_S}
    (tmp_path / "ahead.yaml").write_text(yaml.safe_dump(profile))
    codes = []
    for k in range(rounds):
        domain = free_domain_id()
        timing = {"discovery_timeout_s": 10.0}
        fleet_a = write_fleet(tmp_path / f"a{k}.yaml", network={"domain_id": domain}, timing=timing)
        fleet_b = write_fleet(
            tmp_path / f"b{k}.yaml",
            network={"domain_id": domain},
            twin={"profile": str(tmp_path / "ahead.yaml")},
            timing=timing,
        )
        out_a, out_b = tmp_path / f"out_a{k}", tmp_path / f"out_b{k}"
        a = start(policy, fleet_a, out_a)
        time.sleep(0.3 * (k % 3))  # together, and a little apart
        b = start(policy, fleet_b, out_b)
        _, err_a = a.communicate(timeout=180)
        _, err_b = b.communicate(timeout=180)
        for proc, err in ((a, err_a), (b, err_b)):
            assert proc.returncode in (0, 3), err
            assert "Traceback" not in err
            if proc.returncode == 3:
                assert "DDS domain" in err, err
        for out, expected in ((out_a, 0.0), (out_b, AHEAD_S)):
            recording = out / "session.mcap"
            if recording.exists():
                offsets = stamp_offsets_s(recording)
                assert offsets.size and np.all(np.abs(offsets - expected) < AHEAD_S / 2), (
                    f"round {k}: {out.name} holds {int(np.sum(np.abs(offsets - expected) >= AHEAD_S / 2))} "
                    "messages of the other run"
                )
        codes.append((a.returncode, b.returncode))
    return codes


@pytest.mark.alone  # two deployments at 2x at once: beside a second worker one episode woke 1.2 periods late
def test_two_runs_on_one_domain_never_mix(tiny_policy, tmp_path):
    codes = clash_rounds(tiny_policy, tmp_path, 3)
    assert all(code in ((0, 3), (3, 0), (3, 3), (0, 0)) for code in codes)


@pytest.mark.slow
def test_two_runs_on_one_domain_never_mix_ten_times(tiny_policy, tmp_path):
    clash_rounds(tiny_policy, tmp_path, 10)
