"""Bad paths, topics, values and files give typed errors that name the file (and the topic)."""

from __future__ import annotations

import os
import warnings

import pytest
from mcap.writer import Writer

from pipeline.errors import MrlError
from pipeline.messages import convert as C
from pipeline.messages import message_store
from pipeline.messages import topics as T
from pipeline.record import (
    LogDecodeError,
    LogFormatError,
    LogReadError,
    McapLog,
    McapRecorder,
    RecordError,
    TruncatedLogWarning,
    UndecodableMessageWarning,
)
from pipeline.record.errors import DamagedLogWarning
from tests.record_helpers import topic_table


def test_error_types_share_the_root():
    for cls in (RecordError, LogReadError, LogFormatError, LogDecodeError):
        assert issubclass(cls, MrlError)


# -- recorder ----------------------------------------------------------------------------------


def test_parent_that_cannot_be_created(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    path = blocker / "logs" / "s.mcap"
    with pytest.raises(RecordError, match="cannot create its folder") as err:
        McapRecorder(path, topic_table())
    assert str(path) in str(err.value)


def test_missing_parent_is_created(tmp_path):
    path = tmp_path / "logs" / "eval" / "s.mcap"
    McapRecorder(path, topic_table()).close()
    assert McapLog(path).message_counts() == {}


def test_path_is_a_folder(tmp_path):
    with pytest.raises(RecordError, match="is a folder") as err:
        McapRecorder(tmp_path, topic_table())
    assert str(tmp_path) in str(err.value)


def test_existing_file_is_not_replaced_unless_asked(tmp_path):
    path = tmp_path / "s.mcap"
    path.write_bytes(b"earlier session")
    with pytest.raises(RecordError, match="already exists"):
        McapRecorder(path, topic_table())
    assert path.read_bytes() == b"earlier session"
    McapRecorder(path, topic_table(), overwrite=True).close()
    assert McapLog(path).topics() == {}


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_folder(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(RecordError, match="cannot create the file"):
            McapRecorder(folder / "s.mcap", topic_table())
    finally:
        folder.chmod(0o700)


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_full_disk_is_reported_at_construction():
    with pytest.raises(RecordError, match="No space left") as err:
        McapRecorder("/dev/full", topic_table(), overwrite=True)
    assert "/dev/full" in str(err.value)


def test_bad_chunk_size(tmp_path):
    with pytest.raises(RecordError, match="chunk_size"):
        McapRecorder(tmp_path / "s.mcap", topic_table(), chunk_size=0)
    assert not (tmp_path / "s.mcap").exists()


def test_unknown_topic_lists_the_known_ones(tmp_path):
    with McapRecorder(tmp_path / "s.mcap", topic_table()) as rec:
        with pytest.raises(RecordError, match="unknown topic '/robot_9/odom'") as err:
            rec.write("/robot_9/odom", C.twist(0, 0), 1)
        assert "/robot_1/odom" in str(err.value) and "/mrl/episode" in str(err.value)
        assert str(tmp_path / "s.mcap") in str(err.value)


def test_wrong_message_type_for_topic(tmp_path):
    with McapRecorder(tmp_path / "s.mcap", topic_table()) as rec:
        with pytest.raises(RecordError, match=r"/robot_1/odom carries nav_msgs/msg/Odometry, got a geometry_msgs"):
            rec.write("/robot_1/odom", C.twist(0.1, 0.0), 1)
        with pytest.raises(RecordError, match="got a dict"):
            rec.write("/robot_1/cmd_vel", {"linear": 1}, 1)


def test_conflicting_topic_spec(tmp_path):
    with McapRecorder(tmp_path / "s.mcap", topic_table()) as rec:
        spec = T.TopicSpec("/robot_1/cmd_vel", T.TWIST, T.QOS_SENSOR, "robot_1")
        with pytest.raises(RecordError, match="conflicts with the topic table"):
            rec.write(spec, C.twist(0.1, 0.0), 1)


def test_bad_times(tmp_path):
    with McapRecorder(tmp_path / "s.mcap", topic_table()) as rec:
        for bad in (-1, 1.5, 2**64):
            with pytest.raises(RecordError, match="log_time_ns and publish_time_ns must be integers"):
                rec.write("/robot_1/cmd_vel", C.twist(0.1, 0.0), bad)
        rec.write("/robot_1/cmd_vel", C.twist(0.1, 0.0), 5)
    assert [m.log_time_ns for m in McapLog(tmp_path / "s.mcap").raw()] == [5]


def test_bad_metadata(tmp_path):
    with McapRecorder(tmp_path / "s.mcap", topic_table(), metadata={"params": {"a": "1"}}) as rec:
        with pytest.raises(RecordError, match="metadata 'params' was already written"):
            rec.add_metadata("params", {"b": "2"})
        with pytest.raises(RecordError, match="must be strings, got 'seed': 3"):
            rec.add_metadata("run", {"seed": 3})  # type: ignore[dict-item]
    assert McapLog(tmp_path / "s.mcap").metadata() == {"params": {"a": "1"}}


def test_message_that_cannot_be_serialized(tmp_path):
    s = message_store()
    msg = s.new(T.TWIST, linear=None, angular=None)
    with McapRecorder(tmp_path / "s.mcap", topic_table()) as rec, pytest.raises(RecordError, match="/robot_1/cmd_vel"):
        rec.write("/robot_1/cmd_vel", msg, 1)


# -- reader ------------------------------------------------------------------------------------


def test_missing_file(tmp_path):
    with pytest.raises(LogReadError, match="no such file") as err:
        McapLog(tmp_path / "nope.mcap")
    assert str(tmp_path / "nope.mcap") in str(err.value)


def test_folder_instead_of_file(tmp_path):
    with pytest.raises(LogReadError, match="is a folder"):
        McapLog(tmp_path)


def test_empty_file(tmp_path):
    path = tmp_path / "empty.mcap"
    path.write_bytes(b"")
    with pytest.raises(LogReadError, match=r"empty \(0 bytes\)"):
        McapLog(path)


def test_not_an_mcap_file(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text("world:\n  scenario: empty\n")
    with pytest.raises(LogReadError, match="not an MCAP file") as err:
        McapLog(path)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("tail", [b"", b"\x01\x05", b"\x13gE", b"\x07" * 40])
def test_truncated_garbage(tmp_path, tail):
    path = tmp_path / "g.mcap"
    path.write_bytes(b"\x89MCAP0\r\n"[: 5 if not tail else 8] + tail)
    with pytest.raises(LogReadError, match=str(path)):
        McapLog(path)


def test_garbage_after_a_valid_start_is_salvaged_to_nothing(tmp_path):
    path = tmp_path / "s.mcap"
    with McapRecorder(path, topic_table(), metadata={"params": {"a": "1"}}) as rec:
        rec.write("/clock", C.clock(1), 1)
    data = path.read_bytes()
    head = data[: data.index(b"params") + 40]  # magic, header and the metadata record
    path.write_bytes(head + b"\x06" + b"\xff" * 30)
    with pytest.warns(TruncatedLogWarning, match=r"salvaged 0 messages from 0 complete chunks"):
        log = McapLog(path)
    assert log.salvaged and log.metadata() == {"params": {"a": "1"}} and list(log.messages()) == []


def _foreign(path, encoding="cdr", schema_encoding="ros2msg", data=None):
    s = message_store()
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="other")
        sid = w.register_schema(T.TWIST, schema_encoding, s.msgdef(T.TWIST).encode())
        cid = w.register_channel("/cmd_vel", encoding, sid, {})
        w.add_message(cid, 42, data if data is not None else s.serialize(C.twist(1.0, 0.0), T.TWIST), 42)
        w.finish()


def test_non_cdr_channel_names_the_topic(tmp_path):
    path = tmp_path / "json.mcap"
    _foreign(path, encoding="json")
    with pytest.raises(LogFormatError, match=r"topic /cmd_vel: message encoding is 'json'") as err:
        McapLog(path)
    assert str(path) in str(err.value)


def test_non_ros2msg_schema_names_the_topic(tmp_path):
    path = tmp_path / "idl.mcap"
    _foreign(path, schema_encoding="ros2idl")
    with pytest.raises(LogFormatError, match=r"topic /cmd_vel: schema geometry_msgs/msg/Twist is encoded as 'ros2idl'"):
        McapLog(path)


def test_undecodable_message_raises_or_is_skipped(tmp_path):
    path = tmp_path / "s.mcap"
    good = message_store().serialize(C.twist(0.5, 0.0), T.TWIST)
    with McapRecorder(path, topic_table()) as rec:
        rec.write_cdr("/robot_1/cmd_vel", good, 10)
        rec.write_cdr("/robot_1/cmd_vel", b"\x00\x01\x00\x00\x01\x02", 20)  # cut short
        rec.write_cdr("/robot_1/cmd_vel", good, 30)
    log = McapLog(path)
    with pytest.raises(LogDecodeError, match=r"topic /robot_1/cmd_vel, message logged at 20 ns") as err:
        list(log.messages())
    assert str(path) in str(err.value)
    with pytest.warns(UndecodableMessageWarning, match="logged at 20 ns"):
        got = [m.log_time_ns for m in log.messages(skip_undecodable=True)]
    assert got == [10, 30]
    assert [m.log_time_ns for m in log.raw()] == [10, 20, 30]  # raw bytes are still there


def test_damaged_chunk_in_a_complete_file(tmp_path):
    path = tmp_path / "s.mcap"
    with McapRecorder(path, topic_table()) as rec:
        for i in range(50):
            rec.write("/robot_1/cmd_vel", C.twist(0.01 * i, 0.0), i)
    data = bytearray(path.read_bytes())
    data[120] ^= 0xFF  # inside the first chunk's compressed data
    path.write_bytes(bytes(data))
    with pytest.warns(DamagedLogWarning, match=r"1 of its 1 chunks are damaged and left out: bytes \d+-\d+ are lost"):
        log = McapLog(path)  # checked on opening: left out (tests/unit/test_record_salvage.py)
    assert list(log.raw()) == [] and log.salvaged
    log = McapLog(path, validate_crcs=False)  # not checked on opening: reading it fails
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(LogReadError, match=r"chunk at byte \d+ is damaged"):
            list(log.raw())


def test_bad_metadata_at_construction_creates_no_file(tmp_path):
    path = tmp_path / "s.mcap"
    with pytest.raises(RecordError, match=r"metadata 'params': keys and values must be strings, got 'seed': 3"):
        McapRecorder(path, topic_table(), metadata={"params": {"seed": 3}})  # type: ignore[dict-item]
    assert not path.exists()
