"""An interrupt at any bytecode of the recorder still leaves a complete file after close().

A trace function counts the bytecodes the recorder's own code executes and, at the n-th one,
either raises KeyboardInterrupt (what Python's SIGINT handler does) or calls close() (what a
handler that closes the recorder does). Every n over a sample of the whole run is tried.
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Callable
from pathlib import Path

import pytest

import pipeline.record.writer as writer_module
from pipeline.messages import convert as C
from pipeline.messages import message_store
from pipeline.messages import topics as T
from pipeline.record import McapLog, McapRecorder, RecordError
from tests.record_helpers import topic_table

WRITER = writer_module.__file__
N_MESSAGES = 14
DATA = [
    message_store().serialize(C.timing(i, "send", "robot_1", "/robot_1/cmd_vel", 0, i, 0), T.TIMING)
    for i in range(N_MESSAGES)
]


class _Stop(Exception):
    pass


def run_session(path: Path, at: int, action: Callable[[McapRecorder], None]) -> tuple[int, int, int]:
    """Record with `action` fired at the recorder's bytecode number `at`.

    Returns the messages and metadata records whose calls had returned when the action fired
    (all of them if it never fired), and the number of bytecodes the whole run executed.
    """
    rec = McapRecorder(path, topic_table(), chunk_size=400)
    count = 0
    done = meta = 0
    fired: tuple[int, int] | None = None

    def local(frame, event, arg):
        nonlocal count, fired
        if event == "opcode":
            count += 1
            if count == at:
                fired = (done, meta)
                action(rec)
        return local

    def tracer(frame, event, arg):
        if frame.f_code.co_filename != WRITER:
            return None
        frame.f_trace_opcodes = True
        return local

    sys.settrace(tracer)
    try:
        for i in range(N_MESSAGES):
            rec.write_cdr("/mrl/timing", DATA[i], 1000 + i)
            done += 1
            if i % 5 == 2:
                rec.add_metadata(f"m{meta}", {"i": str(i)})
                meta += 1
            if i == 8:
                rec.flush()
        rec.close()
    except (KeyboardInterrupt, RecordError):
        pass
    finally:
        sys.settrace(None)
    rec.close()  # untraced: completes whatever the interrupt left
    done, meta = fired or (done, meta)
    return done, meta, count


def check(path: Path, done: int, meta: int, fired: bool) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a salvaged file would warn
        log = McapLog(path)
    assert not log.salvaged
    seqs = [m.msg.seq for m in log.messages()]
    assert seqs == list(range(len(seqs)))  # no gap, no duplicate
    assert [m.sequence for m in log.raw()] == seqs
    assert done <= len(seqs) <= done + int(fired)  # the interrupted write may or may not be in
    names = sorted(log.metadata())
    assert names in ([f"m{k}" for k in range(meta)], [f"m{k}" for k in range(meta + int(fired))])


def _raise(rec: McapRecorder) -> None:
    raise KeyboardInterrupt


def _close(rec: McapRecorder) -> None:
    rec.close()


@pytest.mark.parametrize("action", [_raise, _close], ids=["keyboard-interrupt", "close-in-handler"])
def test_interrupt_anywhere_leaves_a_complete_file(tmp_path, action):
    done, meta, total = run_session(tmp_path / "full.mcap", at=-1, action=action)
    check(tmp_path / "full.mcap", done, meta, fired=False)
    assert (done, meta) == (N_MESSAGES, 3) and total > 500
    step = max(1, total // 150)
    for at in [*range(1, total + 1, step), total]:
        path = tmp_path / f"{at}.mcap"
        done, meta, _ = run_session(path, at, action)
        check(path, done, meta, fired=True)
