"""A session's recorder makes its message types' serializers when it opens, not at the first message of each
type (the type store generates them at first use, and a deployment would spend that inside its first control
steps: on a 2-core host the first episode's control steps woke 1.9-5 periods late at 3x, and 0.45-0.85 with them
made at the start)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from pipeline.messages import message_store
from pipeline.messages.errors import MessageError

PROBE = """
import sys
from pipeline.messages import fleet_topics, message_store
from pipeline.record.session import SessionLog, session_metadata
store, robots = message_store(), ("robot_1", "robot_2")
types = sorted({spec.typename for spec in fleet_topics(robots).values()})
before = [t for t in types if store.prepared(t)]
log = SessionLog(sys.argv[1], robots, session_metadata("sim", "empty", robots, 0.1))
after = [t for t in types if store.prepared(t)]
log.close()
print(len(types), len(before), len(after))
"""


def test_a_session_log_prepares_every_type_it_records_when_it_opens(tmp_path):
    # a process of its own: in this one, earlier tests' sessions may have made the types already
    done = subprocess.run(
        [sys.executable, "-c", PROBE, str(tmp_path / "s.mcap")], capture_output=True, text=True, check=True
    )
    types, before, after = (int(n) for n in done.stdout.split())
    assert types >= 8 and before == 0 and after == types


def test_prepare_names_an_unknown_type():
    with pytest.raises(MessageError, match="no_pkg/msg/Nothing"):
        message_store().prepare(["std_msgs/msg/String", "no_pkg/msg/Nothing"])
