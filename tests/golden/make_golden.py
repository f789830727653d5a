"""Regenerate the golden recording and its expected decoding: ``python -m tests.golden.make_golden``.

The recording is a small session over every topic type of the contract, several chunks,
metadata records, messages written slightly out of log-time order across chunks, and no
value that depends on the machine, the clock or the installed versions, so the file is
byte-identical on every run. ``session.json`` holds what the reader must decode from it.

``session_v1.mcap`` and ``session_v1.json`` are the golden pair as it was before ``EpisodeEvent``
got its ``seed`` field (the seed of a start was the text ``seed=<n>`` of its detail): frozen, never
regenerated, so that recordings of that format are tested to read as they always did.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pipeline.record import McapLog, McapRecorder
from tests.record_helpers import contract_messages, plain, topic_table

HERE = Path(__file__).resolve().parent
GOLDEN_MCAP = HERE / "session.mcap"
GOLDEN_JSON = HERE / "session.json"
GOLDEN_V1_MCAP = HERE / "session_v1.mcap"
GOLDEN_V1_JSON = HERE / "session_v1.json"
LIBRARY = "multirobot-sim2real (golden file)"
METADATA = {
    "params": {"world.scenario": "obstacles", "eval.episodes": "2", "seed": "7"},
    "session": {"world": "sim", "profile": "", "policy_digest": "sha256:" + "0" * 64},
    "versions": {"multirobot-sim2real": "golden"},
}
STEP_NS = 100_000_000


def write_golden(path: Path) -> None:
    """The golden recording: three control steps of every contract message (45 messages, several chunks)."""
    with McapRecorder(path, topic_table(), chunk_size=3000, metadata=METADATA, library=LIBRARY, overwrite=True) as rec:
        for step in range(3):
            batch = contract_messages(t0_ns=1_700_000_000_000_000_000 + step * STEP_NS)
            # the recorder logs in arrival order; the cmd_vel of robot_2 arrives late by 50 ms
            for topic, msg, log_ns in batch:
                late = 50_000_000 if topic == "/robot_2/cmd_vel" else 0
                rec.write(topic, msg, log_ns + late, publish_time_ns=log_ns)


def decode(path: Path) -> dict[str, Any]:
    """Everything the reader reports about `path`, as JSON-ready data."""
    log = McapLog(path)
    return {
        "profile": log.profile,
        "library": log.library,
        "topics": log.topics(),
        "channel_metadata": log.channel_metadata(),
        "metadata": log.metadata(),
        "message_counts": log.message_counts(),
        "messages": [
            {
                "topic": m.topic,
                "typename": m.typename,
                "log_time_ns": m.log_time_ns,
                "publish_time_ns": m.publish_time_ns,
                "sequence": m.sequence,
                "msg": plain(m.msg),
            }
            for m in log.messages()
        ],
    }


def to_json(data: dict[str, Any]) -> str:
    return json.dumps(data, indent=1, sort_keys=True, allow_nan=False) + "\n"


def main() -> None:
    write_golden(GOLDEN_MCAP)
    GOLDEN_JSON.write_text(to_json(decode(GOLDEN_MCAP)))
    print(f"wrote {GOLDEN_MCAP} ({GOLDEN_MCAP.stat().st_size} bytes) and {GOLDEN_JSON}")


if __name__ == "__main__":
    main()
