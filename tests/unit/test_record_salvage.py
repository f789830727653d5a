"""A recording cut at any byte reads back every message of every complete chunk, and nothing else."""

from __future__ import annotations

import struct
import warnings

import pytest
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from pipeline.messages import convert as C
from pipeline.record import LogReadError, McapLog, McapRecorder, TruncatedLogWarning
from pipeline.record.errors import DamagedLogWarning
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


# -- damaged chunks: the intact ones are kept, the lost byte ranges are reported -----------------


def chunk_spans(path) -> list[tuple[int, int, list[int]]]:
    """(start byte, end byte, log times of its messages) of each chunk record of a complete file."""
    out = []
    with open(path, "rb") as f:
        records = StreamReader(f, emit_chunks=True).records
        while True:
            start = f.tell()
            record = next(records, None)
            if record is None:
                return out
            if isinstance(record, Chunk):
                times = [r.log_time for r in breakup_chunk(record) if isinstance(r, Message)]
                out.append((start, f.tell(), times))


def recording(path, n: int = 60, cmd_from: int = 0) -> list[int]:
    """A complete file of small chunks: timing at 1000 i ns, cmd_vel at 1000 i + 1 ns (i % 4 == 0, i >= cmd_from)."""
    with McapRecorder(path, topic_table(), chunk_size=700) as rec:
        for i in range(n):
            rec.write("/mrl/timing", C.timing(i, "tick", "", "", 0, i, i), 1000 * i)
            if i % 4 == 0 and i >= cmd_from:
                rec.write("/robot_1/cmd_vel", C.twist(0.01 * i, 0.0), 1000 * i + 1)
    return [m.log_time_ns for m in McapLog(path).raw()]


def open_warned(path, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = McapLog(path, **kw)
    return log, [w.message for w in caught]


def without_summary(data: bytes, spans) -> bytes:
    """The file cut 5 bytes into the record after its last chunk: no summary, nothing after the last chunk."""
    return data[: spans[-1][1] + 5]


@pytest.mark.parametrize("indexed", [True, False], ids=["indexed", "scanned"])
def test_a_damaged_middle_chunk_is_left_out_and_reported(tmp_path, indexed):
    path = tmp_path / "s.mcap"
    everything = recording(path)
    spans = chunk_spans(path)
    assert len(spans) >= 5
    start, end, gone = spans[len(spans) // 2]
    data = bytearray(path.read_bytes())
    for k in range(end - 40, end - 30):  # inside the chunk's compressed data
        data[k] ^= 0x5A
    if not indexed:
        data = bytearray(without_summary(bytes(data), spans))
    path.write_bytes(bytes(data))
    log, caught = open_warned(path)
    assert log.salvaged
    assert [type(w) for w in caught] == [DamagedLogWarning]
    assert f"bytes {start}-{end}" in str(caught[0]) and str(path) in str(caught[0])
    lost = [(r.start_offset, r.end_offset) for r in log.lost]
    assert lost[0] == (start, end)
    assert lost[1:] == ([] if indexed else [(spans[-1][1], len(data))])  # the cut tail of the scanned file
    assert "CRC-32" in log.lost[0].reason or "decompress" in log.lost[0].reason
    kept = [t for t in everything if t not in gone]
    assert [m.log_time_ns for m in log.raw()] == kept
    assert [m.log_time_ns for m in log.messages()] == kept
    assert sum(log.message_counts().values()) == len(kept)


@pytest.mark.parametrize("indexed", [True, False], ids=["indexed", "scanned"])
@pytest.mark.parametrize("length", ["past_the_end", "into_the_next_chunk", "too_short", "zero"])
def test_a_damaged_chunk_length_does_not_hide_the_chunks_after_it(tmp_path, indexed, length):
    path = tmp_path / "s.mcap"
    everything = recording(path)
    spans = chunk_spans(path)
    start, end, _ = spans[1]
    data = bytearray(path.read_bytes())
    claimed = {
        "past_the_end": 2**40,
        "into_the_next_chunk": (spans[2][0] - start) + 100,
        "too_short": (end - start - 9) // 2,
        "zero": 0,
    }[length]
    data[start + 1 : start + 9] = struct.pack("<Q", claimed)
    if not indexed:
        data = bytearray(without_summary(bytes(data), spans))
    path.write_bytes(bytes(data))
    log, caught = open_warned(path)
    assert log.salvaged
    assert [type(w) for w in caught] == [DamagedLogWarning]
    assert f"byte {start}" in str(caught[0])
    # the chunk's own fields still say where its data end, and its data pass their CRC: nothing is lost
    assert [(r.start_offset, r.end_offset) for r in log.lost] == ([] if indexed else [(spans[-1][1], len(data))])
    assert [m.log_time_ns for m in log.raw()] == everything


def test_scanning_resumes_at_the_next_chunk_after_a_record_it_cannot_frame(tmp_path):
    path = tmp_path / "s.mcap"
    everything = recording(path)
    spans = chunk_spans(path)
    start, _, gone = spans[2]
    data = bytearray(path.read_bytes())
    data[start : start + 9] = b"\x00" + struct.pack("<Q", 2**40)  # opcode and length both garbage
    data[start + 60] ^= 0xFF
    cut = without_summary(bytes(data), spans)
    path.write_bytes(cut)
    log, caught = open_warned(path)
    assert [type(w) for w in caught] == [DamagedLogWarning]
    assert [(r.start_offset, r.end_offset) for r in log.lost] == [(start, spans[3][0]), (spans[-1][1], len(cut))]
    assert [m.log_time_ns for m in log.raw()] == [t for t in everything if t not in gone]


def test_a_lost_chunk_that_defined_channels_hides_their_later_messages_with_a_warning(tmp_path):
    path = tmp_path / "s.mcap"
    everything = recording(path, cmd_from=20)
    spans = chunk_spans(path)
    end = spans[0][1]  # the first chunk defines /mrl/timing; /robot_1/cmd_vel is defined later
    data = bytearray(path.read_bytes())
    data[end - 20] ^= 0xFF
    cut = without_summary(bytes(data), spans)
    path.write_bytes(cut)
    log, caught = open_warned(path)
    assert [type(w) for w in caught] == [DamagedLogWarning]
    assert "their Channel records were in the lost bytes" in str(caught[0])
    assert log.topics() == {"/robot_1/cmd_vel": "geometry_msgs/msg/Twist"}
    assert [m.log_time_ns for m in log.raw()] == [t for t in everything if t % 1000 == 1]
    assert log.message_counts() == {"/robot_1/cmd_vel": 10}


def test_an_intact_file_reports_nothing_lost(tmp_path):
    path = tmp_path / "s.mcap"
    recording(path)
    log, caught = open_warned(path)
    assert caught == [] and not log.salvaged and log.lost == ()
