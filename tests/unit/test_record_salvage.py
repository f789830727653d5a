"""A recording cut at any byte reads back every message of every complete chunk, and nothing else."""

from __future__ import annotations

import warnings

import pytest
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from pipeline.messages import convert as C
from pipeline.record import LogReadError, McapLog, McapRecorder, TruncatedLogWarning
from tests.record_helpers import topic_table


def chunk_ends(path) -> list[tuple[int, int]]:
    """(end byte of each chunk record, messages in the file up to that end) of a complete file."""
    out = []
    total = 0
    with open(path, "rb") as f:
        for record in StreamReader(f, emit_chunks=True).records:
            if isinstance(record, Chunk):
                total += sum(isinstance(r, Message) for r in breakup_chunk(record))
                out.append((f.tell(), total))
    return out


def test_every_cut_point_salvages_exactly_the_complete_chunks(tmp_path):
    full = tmp_path / "full.mcap"
    with McapRecorder(full, topic_table(), chunk_size=700, metadata={"params": {"seed": "1"}}) as rec:
        for i in range(60):
            rec.write("/mrl/timing", C.timing(i, "tick", "", "", 0, i, i), 1000 * i)
            if i % 4 == 0:
                rec.write("/robot_1/cmd_vel", C.twist(0.01 * i, 0.0), 1000 * i + 1)
    data = full.read_bytes()
    ends = chunk_ends(full)
    assert len(ends) >= 5
    header_end = data.index(b"params") - 13  # where the metadata record starts: magic and header are whole
    cut_path = tmp_path / "cut.mcap"
    for cut in range(header_end, ends[-1][0] + 40, 11):
        cut_path.write_bytes(data[:cut])
        expected = max((n for end, n in ends if end <= cut), default=0)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            log = McapLog(cut_path)
        assert log.salvaged
        assert [type(w.message) for w in caught] == [TruncatedLogWarning]
        assert f"salvaged {expected} messages" in str(caught[0].message)
        seqs = [m.msg.seq for m in log.messages("/mrl/timing")]
        assert seqs == list(range(len(seqs)))
        assert sum(log.message_counts().values()) == expected == len(list(log.raw()))


def test_cut_inside_the_header_is_an_error(tmp_path):
    full = tmp_path / "full.mcap"
    McapRecorder(full, topic_table()).close()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[:20])
    with pytest.raises(LogReadError, match="cut short inside its MCAP header"):
        McapLog(cut)
