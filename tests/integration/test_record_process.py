"""Real recording processes stopped by SIGKILL, SIGINT and SIGTERM; the files read back."""

from __future__ import annotations

import signal
import struct
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, SeekingReader

from pipeline.record import McapLog, TruncatedLogWarning

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT_S = 60.0

pytestmark = pytest.mark.integration


def start(path: Path, mode: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "tests.record_session", str(path), mode],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def wait_for(proc: subprocess.Popen[str], word: str, at_least: int) -> int:
    """Read progress lines until `word N` with N >= at_least; returns N."""
    assert proc.stdout is not None
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            raise AssertionError(f"recorder exited early: {proc.wait()} {proc.stderr.read() if proc.stderr else ''}")
        kind, _, value = line.partition(" ")
        if kind == word and int(value) >= at_least:
            return int(value)
    proc.kill()
    raise AssertionError(f"no '{word} {at_least}' within {TIMEOUT_S} s")


def counters(log: McapLog) -> list[int]:
    return [m.msg.seq for m in log.messages("/mrl/timing")]


def test_killed_recorder_is_salvaged_up_to_its_last_complete_chunk(tmp_path):
    path = tmp_path / "killed.mcap"
    proc = start(path, "kill")
    try:
        wait_for(proc, "sealed", 500)
    finally:
        proc.send_signal(signal.SIGKILL)
        out, _ = proc.communicate(timeout=TIMEOUT_S)
    assert proc.returncode == -signal.SIGKILL
    sealed = max(int(line.split()[1]) for line in out.splitlines() if line.startswith("sealed ")) if out else 500
    with pytest.warns(TruncatedLogWarning, match=r"cut short .* salvaged \d+ messages from \d+ complete chunks"):
        log = McapLog(path)
    assert log.salvaged
    got = counters(log)
    assert got == list(range(len(got)))  # every message of every complete chunk, in order, no gap
    assert len(got) >= max(sealed, 500)
    assert log.message_counts() == {"/mrl/timing": len(got)}
    assert log.topics() == {"/mrl/timing": "mrl_msgs/msg/Timing"}
    # why salvaging is needed: mcap's own readers give nothing back from such a file
    for reader in (SeekingReader, NonSeekingReader):
        with open(path, "rb") as f, pytest.raises((McapError, struct.error, ValueError)):
            next(iter(reader(f).iter_messages(log_time_order=True)))


@pytest.mark.parametrize(
    ("mode", "signum"),
    [("raise", signal.SIGINT), ("raise", signal.SIGTERM), ("handler", signal.SIGINT), ("handler", signal.SIGTERM)],
    ids=["ctrl-c", "sigterm", "handler-ctrl-c", "handler-sigterm"],
)
def test_interrupted_recorder_closes_a_complete_file(tmp_path, mode, signum):
    path = tmp_path / "interrupted.mcap"
    proc = start(path, mode)
    try:
        written = wait_for(proc, "written", 1000)
        proc.send_signal(signum)
        closed = wait_for(proc, "closed", written)
        proc.wait(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, proc.stderr.read() if proc.stderr else ""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the indexed reader, no salvage
        log = McapLog(path)
    assert not log.salvaged
    assert counters(log) == list(range(closed))
    assert log.message_counts() == {"/mrl/timing": closed}
