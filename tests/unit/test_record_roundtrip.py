"""Recorder -> file -> reader: every contract message, the ROS 2 profile details, and other readers."""

from __future__ import annotations

import dataclasses
import io
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory

from pipeline.messages import convert as C
from pipeline.messages import message_store
from pipeline.messages import topics as T
from pipeline.record import LIBRARY, McapLog, McapRecorder, RecordError, versions_metadata
from tests.record_helpers import contract_messages, plain, topic_table

NS = 1_000_000_000


@pytest.fixture(autouse=True)
def _no_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def wire(msg):
    """`msg` as its CDR carries it: float32 fields rounded, everything else as built."""
    s = message_store()
    return s.deserialize(s.serialize(msg, msg.__msgtype__), msg.__msgtype__)


def record(path: Path, chunk_size: int = 1500, **kw) -> list[tuple[str, object, int]]:
    written = contract_messages()
    with McapRecorder(path, topic_table(), chunk_size=chunk_size, **kw) as rec:
        for topic, msg, log_ns in written:
            rec.write(topic, msg, log_ns, publish_time_ns=log_ns - 1000)
        assert rec.message_count == len(written)
    return written


def test_every_contract_message_round_trips_field_by_field(tmp_path):
    path = tmp_path / "s.mcap"
    written = record(path)
    got = list(McapLog(path).messages())
    assert [(m.topic, m.log_time_ns, m.publish_time_ns) for m in got] == [(t, ns, ns - 1000) for t, _, ns in written]
    for m, (_, msg, _) in zip(got, written, strict=True):
        assert m.typename == msg.__msgtype__
        assert plain(m.msg) == plain(wire(msg))
        if m.typename != T.LASER_SCAN:  # the only type with float32 scalars, built from float64 values
            assert plain(m.msg) == plain(msg)
    scan = got[0].msg
    assert scan.ranges.dtype == np.float32
    assert scan.ranges.tobytes() == written[0][1].ranges.tobytes()  # NaN and infinities bit for bit
    obs = next(m.msg for m in got if m.topic == "/mrl/observation")
    assert obs.values.tobytes() == (np.arange(17, dtype=np.float32) / 7).astype(np.float32).tobytes()
    covered = {m.typename for m in got}
    assert covered == set(message_store().typenames) & {spec.typename for spec in topic_table().values()}


def test_header_profile_schemas_channels_and_zstd_chunks(tmp_path):
    path = tmp_path / "s.mcap"
    record(path)
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        header = reader.get_header()
        summary = reader.get_summary()
    assert header.profile == "ros2"
    assert header.library == LIBRARY and LIBRARY.startswith("multirobot-sim2real/")
    assert summary is not None and summary.statistics is not None
    table = topic_table()
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        spec = table[channel.topic]
        assert channel.message_encoding == "cdr"
        assert schema.encoding == "ros2msg" and schema.name == spec.typename
        assert schema.data.decode() == message_store().msgdef(spec.typename)
        assert channel.metadata == {"offered_qos_profiles": spec.qos.rosbag2_yaml()}
    assert len(summary.schemas) == len({s.typename for s in table.values()})  # one schema per type
    with open(path, "rb") as f:
        chunks = [r for r in StreamReader(f, emit_chunks=True, validate_crcs=True).records if isinstance(r, Chunk)]
    assert len(chunks) == summary.statistics.chunk_count > 3
    assert {c.compression for c in chunks} == {"zstd"}
    assert len(summary.chunk_indexes) == len(chunks)


def test_metadata_round_trip(tmp_path):
    path = tmp_path / "s.mcap"
    params = {"params": {"world.scenario": "obstacles", "seed": "3"}, "session": {"world": "real", "profile": "spark"}}
    with McapRecorder(path, topic_table(), metadata=params) as rec:
        rec.add_metadata("versions", versions_metadata())
        rec.write("/clock", C.clock(5), 5)
        rec.add_metadata("policy", {"digest": "sha256:ab", "layout": "paper"})
    meta = McapLog(path).metadata()
    assert meta["params"] == params["params"] and meta["session"] == params["session"]
    assert meta["policy"] == {"digest": "sha256:ab", "layout": "paper"}
    assert {"python", "multirobot-sim2real", "mcap", "rosbags"} <= set(meta["versions"])


def test_sequences_counts_topics_and_filters(tmp_path):
    path = tmp_path / "s.mcap"
    with McapRecorder(path, topic_table(), chunk_size=200) as rec:
        for i in range(30):
            rec.write("/robot_1/cmd_vel", C.twist(0.01 * i, 0.0), 1000 + 10 * i)
            if i % 3 == 0:
                rec.write("/robot_2/cmd_vel", C.twist(0.0, 0.01 * i), 1005 + 10 * i)
    log = McapLog(path)
    assert log.topics() == {"/robot_1/cmd_vel": T.TWIST, "/robot_2/cmd_vel": T.TWIST}
    assert log.message_counts() == {"/robot_1/cmd_vel": 30, "/robot_2/cmd_vel": 10}
    r1 = list(log.messages("/robot_1/cmd_vel"))
    assert [m.sequence for m in r1] == list(range(30))
    assert [m.sequence for m in log.messages(["/robot_2/cmd_vel"])] == list(range(10))
    window = list(log.raw(start_ns=1100, end_ns=1200))  # inclusive start, exclusive end
    assert [m.log_time_ns for m in window] == sorted([*range(1100, 1200, 10), 1125, 1155, 1185])
    assert list(log.messages("/nowhere")) == []
    raw = next(log.raw("/robot_1/cmd_vel"))
    assert raw.data == message_store().serialize(C.twist(0.0, 0.0), T.TWIST)


def test_log_time_order_across_overlapping_chunks(tmp_path):
    path = tmp_path / "s.mcap"
    rng = np.random.default_rng(0)
    times = [int(t) for t in rng.permutation(200) * 1000]  # arrival order is not log-time order
    with McapRecorder(path, topic_table(), chunk_size=300) as rec:
        for i, t in enumerate(times):
            rec.write("/mrl/timing", C.timing(t, "send", "robot_1", "/robot_1/cmd_vel", 0, i, 0), t)
    log = McapLog(path)
    got = [m.log_time_ns for m in log.raw()]
    assert got == sorted(times)
    assert [m.msg.seq for m in log.messages(start_ns=50_000, end_ns=60_000)] == [
        times.index(t) for t in range(50_000, 60_000, 1000)
    ]


def test_write_cdr_and_flush(tmp_path):
    path = tmp_path / "s.mcap"
    s = message_store()
    data = s.serialize(C.twist(0.3, 0.1), T.TWIST)
    with McapRecorder(path, topic_table()) as rec:
        rec.write_cdr("/robot_1/cmd_vel", data, 10)
        rec.flush()
        rec.flush()  # an empty chunk is not written
        rec.write_cdr(T.TopicSpec("/extra/cmd", T.TWIST, T.QOS_COMMAND), data, 20)
    log = McapLog(path)
    assert [(m.topic, m.msg.linear.x) for m in log.messages()] == [("/robot_1/cmd_vel", 0.3), ("/extra/cmd", 0.3)]
    with open(path, "rb") as f:
        assert len(make_reader(f).get_summary().chunk_indexes) == 2


def test_empty_recording_is_valid(tmp_path):
    path = tmp_path / "s.mcap"
    McapRecorder(path, topic_table()).close()
    log = McapLog(path)
    assert (log.topics(), log.message_counts(), list(log.messages()), log.salvaged) == ({}, {}, [], False)


def test_close_is_idempotent_and_writes_after_close_fail(tmp_path):
    path = tmp_path / "s.mcap"
    rec = McapRecorder(path, topic_table())
    rec.write("/clock", C.clock(1), 1)
    rec.close()
    size = path.stat().st_size
    rec.close()
    assert path.stat().st_size == size and rec.closed
    with pytest.raises(RecordError, match="closed"):
        rec.write("/clock", C.clock(1), 2)


def test_mcap_ros2_decoder_reads_what_was_written(tmp_path):
    path = tmp_path / "s.mcap"
    written = record(path)
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        decoded = [(ch.topic, m.log_time, d) for _, ch, m, d in reader.iter_decoded_messages()]
    assert [(t, ns) for t, ns, _ in decoded] == [(t, ns) for t, _, ns in written]
    for (_, _, theirs), (_, ours, _) in zip(decoded, written, strict=True):
        assert plain(theirs) == plain(wire(ours))


def test_rosbags_storage_reader_reads_the_bare_file(tmp_path):
    """rosbags' AnyReader wants a rosbag2 folder with metadata.yaml; its MCAP storage reader takes the file."""
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    path = tmp_path / "s.mcap"
    written = record(path)
    reader = McapReader(path)
    reader.open()
    try:
        conns = {c.topic: c for c in reader.connections}
        assert {t: c.msgtype for t, c in conns.items()} == {t: m.__msgtype__ for t, m, _ in written}
        assert conns["/robot_1/scan"].ext.offered_qos_profiles[0].depth == T.QOS_SENSOR.depth
        typestore = get_typestore(Stores.ROS2_JAZZY)
        for c in reader.connections:
            typestore.register(get_types_from_msg(c.msgdef.data, c.msgtype))
        got = [
            (c.topic, ns, typestore.deserialize_cdr(data, c.msgtype))
            for c, ns, data in reader.messages(reader.connections)
        ]
    finally:
        reader.close()
    assert [(t, ns) for t, ns, _ in got] == [(t, ns) for t, _, ns in written]
    for (_, _, theirs), (_, ours, _) in zip(got, written, strict=True):
        assert plain(theirs) == plain(wire(ours))


def test_foreign_schema_text_decodes_with_types_from_the_file(tmp_path):
    """A ros2 bag keeps the comments of its .msg files: the reader then builds types from the file."""
    from mcap.writer import Writer

    path = tmp_path / "foreign.mcap"
    s = message_store()
    text = "# Velocity in free space.\n" + s.msgdef(T.TWIST)
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="other")
        sid = w.register_schema(T.TWIST, "ros2msg", text.encode())
        cid = w.register_channel("/cmd_vel", "cdr", sid, {"offered_qos_profiles": ""})
        w.add_message(cid, 7, s.serialize(C.twist(0.2, -0.1), T.TWIST), 7)
        w.finish()
    (m,) = McapLog(path).messages()
    assert (m.topic, m.msg.linear.x, m.msg.angular.z) == ("/cmd_vel", 0.2, -0.1)
    assert type(m.msg) is not s.cls(T.TWIST)


def _as_dict(value):
    """A message as nested dicts and lists, the input mcap_ros2's encoder takes."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, list):
        return [_as_dict(v) for v in value]
    if dataclasses.is_dataclass(value):
        fields = [f.name for f in dataclasses.fields(value) if not str(f.type).startswith("ClassVar")]
        return {name: _as_dict(getattr(value, name)) for name in fields}
    return value


def test_cdr_in_the_file_equals_the_mcap_ros2_encoder(tmp_path):
    from mcap_ros2.writer import Writer as Ros2Writer

    path = tmp_path / "s.mcap"
    written = record(path)
    buffer = io.BytesIO()
    writer = Ros2Writer(buffer)
    schemas = {}
    for topic, msg, log_ns in written:
        typename = msg.__msgtype__
        if typename not in schemas:
            schemas[typename] = writer.register_msgdef(typename, message_store().msgdef(typename))
        writer.write_message(topic, schemas[typename], _as_dict(msg), log_time=log_ns, publish_time=log_ns)
    writer.finish()
    buffer.seek(0)
    theirs = [m.data for _, _, m in make_reader(buffer).iter_messages()]
    ours = [m.data for m in McapLog(path).raw()]
    assert ours == theirs


@pytest.mark.parametrize("layout", ["unchunked", "no-repeated-channels"])
def test_complete_files_without_a_usable_index_are_read_in_file_order(tmp_path, layout):
    from mcap.writer import Writer

    path = tmp_path / f"{layout}.mcap"
    s = message_store()
    options = {"use_chunking": False} if layout == "unchunked" else {"repeat_channels": False, "repeat_schemas": False}
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=200, **options)
        w.start(profile="ros2", library="other")
        sid = w.register_schema(T.TWIST, "ros2msg", s.msgdef(T.TWIST).encode())
        cid = w.register_channel("/cmd_vel", "cdr", sid, {"offered_qos_profiles": ""})
        w.add_metadata("params", {"k": "v"})
        for i in (3, 1, 2, 0):
            w.add_message(cid, 100 + i, s.serialize(C.twist(0.1 * i, 0.0), T.TWIST), 100 + i, sequence=i)
        w.finish()
    log = McapLog(path)
    assert not log.salvaged
    assert [m.log_time_ns for m in log.messages()] == [100, 101, 102, 103]
    assert log.message_counts() == {"/cmd_vel": 4} and log.metadata() == {"params": {"k": "v"}}


def test_writers_on_several_threads(tmp_path):
    path = tmp_path / "s.mcap"
    data = message_store().serialize(C.twist(0.1, 0.0), T.TWIST)
    with McapRecorder(path, topic_table(), chunk_size=500) as rec:

        def run(robot: str) -> None:
            for i in range(300):
                rec.write_cdr(f"/{robot}/cmd_vel", data, i)

        threads = [threading.Thread(target=run, args=(r,)) for r in ("robot_1", "robot_2")]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    log = McapLog(path)
    assert log.message_counts() == {"/robot_1/cmd_vel": 300, "/robot_2/cmd_vel": 300}
    for topic in log.topics():
        assert sorted(m.sequence for m in log.raw(topic)) == list(range(300))
