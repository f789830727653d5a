"""Bags from elsewhere import into the session layout; a session folder opens as a rosbag2 bag.

Every source bag is made here with the rosbags writers (or mcap's) from the messages of the golden
session, so the imported MCAP must decode to the golden values at the golden log times.
"""

from __future__ import annotations

import shutil
import sqlite3
import tempfile
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import pytest
import yaml
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag1.reader import Header
from rosbags.rosbag2 import Reader as Reader2
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline.errors import MrlError
from pipeline.messages import message_store
from pipeline.messages.store import schema_files
from pipeline.record import (
    BagError,
    BagImportWarning,
    BagReadError,
    EmptyBagError,
    ImportedBag,
    McapLog,
    NoRobotsError,
    NotABagError,
    RawMessage,
    RecordError,
    RemapError,
    RemapTopicMissingError,
    TopicMapError,
    TopicTypeError,
    TruncatedLogWarning,
    UnknownMessageTypeError,
    import_bag,
    parse_topic_map,
    write_rosbag2_metadata,
)
from tests.golden.make_golden import GOLDEN_MCAP
from tests.record_helpers import plain

ROBOT_KINDS = ("scan", "odom", "ground_truth", "cmd_vel")
STANDARD = [f"/{ns}/{kind}" for ns in ("robot_1", "robot_2") for kind in ROBOT_KINDS] + ["/tf", "/clock"]
SCAN_QOS = Qos(
    QosHistory.KEEP_LAST,
    7,
    QosReliability.BEST_EFFORT,
    QosDurability.VOLATILE,
    QosTime(0, 0),
    QosTime(0, 0),
    QosLiveliness.AUTOMATIC,
    QosTime(0, 0),
    False,
)
BUMPER = "spark_msgs/msg/Bumper"


# -- helpers ------------------------------------------------------------------------------------


def golden_raw(topics: Iterable[str] | None = None) -> list[RawMessage]:
    return list(McapLog(GOLDEN_MCAP).raw(topics))


def ros2_store() -> Any:
    """ROS 2 Jazzy plus schemas/ plus a robot-specific type that neither knows."""
    store = get_typestore(Stores.ROS2_JAZZY)
    for typename, path in schema_files().items():
        store.register(get_types_from_msg(path.read_text(), typename))
    store.register(get_types_from_msg("bool pressed\nfloat32 force_n", BUMPER))
    return store


def write_rosbag2(
    dest: Path,
    messages: Iterable[RawMessage],
    storage: StoragePlugin = StoragePlugin.MCAP,
    rename: Callable[[str], str] = lambda t: t,
) -> Path:
    """A rosbag2 folder of `messages` (CDR bytes as they are), /robot_1/scan offered with SCAN_QOS."""
    store = ros2_store()
    with Writer2(dest, version=9, storage_plugin=storage) as writer:
        conns: dict[str, Any] = {}
        for m in messages:
            topic = rename(m.topic)
            if topic not in conns:
                qos = [SCAN_QOS] if m.topic == "/robot_1/scan" else []
                conns[topic] = writer.add_connection(topic, m.typename, typestore=store, offered_qos_profiles=qos)
            writer.write(conns[topic], m.log_time_ns, m.data)
    return dest


def make_humble(folder: Path) -> Path:
    """Turn a rosbags sqlite3 folder into what Humble's `ros2 bag record` writes: no message definitions."""
    (db,) = folder.glob("*.db3")
    with sqlite3.connect(db) as con:
        con.execute("DROP TABLE message_definitions")
        con.execute("UPDATE schema SET schema_version = 3")
        qos = dict(con.execute("SELECT name, offered_qos_profiles FROM topics").fetchall())
    meta = folder / "metadata.yaml"
    data = yaml.safe_load(meta.read_text())
    info = data["rosbag2_bagfile_information"]
    info["version"] = 5
    info.pop("ros_distro", None)
    for entry in info["topics_with_message_count"]:
        entry["topic_metadata"].pop("type_description_hash", None)
        entry["topic_metadata"]["offered_qos_profiles"] = qos[entry["topic_metadata"]["name"]]  # as a string
    meta.write_text(yaml.safe_dump(data))
    return folder


def write_ros1(dest: Path, messages: Iterable[RawMessage]) -> Path:
    """A ROS 1 bag of `messages`, each converted from CDR to ROS 1 serialization by the type store."""
    ros2 = get_typestore(Stores.ROS2_JAZZY)
    ros1 = get_typestore(Stores.ROS1_NOETIC)
    ros1.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    with Writer1(dest) as writer:
        conns: dict[str, Any] = {}
        for m in messages:
            if m.topic not in conns:
                conns[m.topic] = writer.add_connection(m.topic, m.typename, typestore=ros1)
            writer.write(conns[m.topic], m.log_time_ns, bytes(ros2.cdr_to_ros1(m.data, m.typename)))
    return dest


def write_plain_mcap(dest: Path, messages: Iterable[RawMessage]) -> Path:
    """A ros2 MCAP as other tools write it: no session record, no QoS metadata, publish time != log time."""
    store = message_store()
    with open(dest, "wb") as f:
        writer = McapWriter(f)
        writer.start(profile="ros2", library="another-tool")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for m in messages:
            if m.typename not in schemas:
                schemas[m.typename] = writer.register_schema(m.typename, "ros2msg", store.msgdef(m.typename).encode())
            if m.topic not in channels:
                channels[m.topic] = writer.register_channel(m.topic, "cdr", schemas[m.typename])
            writer.add_message(channels[m.topic], m.log_time_ns, m.data, m.log_time_ns - 5)
        writer.finish()
    return dest


def decoded(path: Path, rename: Callable[[str], str] = lambda t: t) -> list[tuple[str, int, Any]]:
    """(topic, log time ns, plain message) of every message, topics renamed by `rename`."""
    return [(rename(m.topic), m.log_time_ns, plain(m.msg)) for m in McapLog(path).messages()]


def expected(topics: Iterable[str], rename: Callable[[str], str] = lambda t: t) -> list[tuple[str, int, Any]]:
    return [(rename(m.topic), m.log_time_ns, plain(m.msg)) for m in McapLog(GOLDEN_MCAP).messages(topics)]


def schema_texts(path: Path) -> dict[str, str]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return {s.name: bytes(s.data).decode() for s in summary.schemas.values()}


def check_import(bag: ImportedBag, topics: list[str], rename: Callable[[str], str] = lambda t: t) -> None:
    """The imported MCAP holds exactly the golden messages of `topics` (renamed), values and log times."""
    golden = McapLog(GOLDEN_MCAP)
    counts = golden.message_counts()
    want = expected(topics, rename)
    assert decoded(bag.path) == want
    assert bag.message_counts() == {rename(t): counts[t] for t in topics}
    assert bag.topic_types() == {rename(t): golden.topics()[t] for t in topics}
    assert McapLog(bag.path).message_counts() == bag.message_counts()
    assert (bag.start_ns, bag.end_ns) == (want[0][1], want[-1][1])
    assert bag.duration_ns == want[-1][1] - want[0][1]
    assert bag.converted
    store = message_store()
    for typename, text in schema_texts(bag.path).items():
        assert text == store.msgdef(typename), typename  # the recorder's definitions: same decoder as sessions


# -- formats ------------------------------------------------------------------------------------


def test_rosbag2_folder_with_mcap_storage(tmp_path):
    source = write_rosbag2(tmp_path / "fleet", golden_raw())
    bag = import_bag(source, work_dir=tmp_path / "work")
    assert bag.source_format == "rosbag2-mcap"
    assert bag.robots == ("robot_1", "robot_2")
    assert bag.path.parent.parent == tmp_path / "work"
    check_import(bag, list(McapLog(GOLDEN_MCAP).topics()))
    qos = yaml.safe_load(McapLog(bag.path).channel_metadata()["/robot_1/scan"]["offered_qos_profiles"])
    assert (qos[0]["depth"], qos[0]["reliability"]) == (7, "best_effort")  # the bag's own QoS is kept
    with Reader2(bag.path.parent) as reader:  # the output folder is itself a rosbag2 bag
        assert reader.message_count == bag.message_count


def test_rosbag2_folder_with_sqlite3_storage(tmp_path):
    source = write_rosbag2(tmp_path / "fleet", golden_raw(), StoragePlugin.SQLITE3)
    bag = import_bag(source / "metadata.yaml", work_dir=tmp_path / "work")  # the metadata file names its folder
    assert bag.source_format == "rosbag2-sqlite3"
    assert bag.path == tmp_path / "work" / "fleet" / "fleet.mcap"
    assert bag.robots == ("robot_1", "robot_2")
    check_import(bag, list(McapLog(GOLDEN_MCAP).topics()))


def test_humble_sqlite3_without_message_definitions(tmp_path):
    source = make_humble(write_rosbag2(tmp_path / "humble", golden_raw(STANDARD), StoragePlugin.SQLITE3))
    bag = import_bag(source, work_dir=tmp_path / "work")
    assert bag.source_format == "rosbag2-sqlite3"
    check_import(bag, STANDARD)
    qos = yaml.safe_load(McapLog(bag.path).channel_metadata()["/robot_2/cmd_vel"]["offered_qos_profiles"])
    assert (qos[0]["reliability"], qos[0]["depth"]) == ("reliable", 10)  # none in the bag: the contract's


def test_ros1_bag_is_converted_to_cdr(tmp_path):
    source = write_ros1(tmp_path / "fleet.bag", golden_raw(STANDARD))
    bag = import_bag(source, work_dir=tmp_path / "work")
    assert bag.source_format == "ros1"
    assert bag.robots == ("robot_1", "robot_2")
    check_import(bag, STANDARD)  # headers lose only ROS 1's seq: stamps, frames, ranges, poses, twists equal
    cdr = {(m.topic, m.log_time_ns): m.data for m in McapLog(bag.path).raw()}
    assert cdr == {(m.topic, m.log_time_ns): m.data for m in golden_raw(STANDARD)}  # byte for byte
    qos = yaml.safe_load(McapLog(bag.path).channel_metadata()["/robot_1/scan"]["offered_qos_profiles"])
    assert (qos[0]["reliability"], qos[0]["depth"]) == ("best_effort", 5)


def test_ros1_bag_without_its_suffix(tmp_path):
    source = write_ros1(tmp_path / "fleet.bag", golden_raw(STANDARD))
    renamed = source.rename(tmp_path / "fleet.recording")
    bag = import_bag(renamed, work_dir=tmp_path / "work")
    assert bag.source_format == "ros1"
    check_import(bag, STANDARD)


def _index_pos(bag: Path) -> int:
    """Where the bag header says the index starts."""
    with bag.open("rb") as f:
        f.readline()
        header = Header.read(f)
    return header.get_uint64("index_pos")


def test_a_cut_ros1_bag_is_salvaged_and_says_what_was_lost(tmp_path):
    messages = golden_raw(STANDARD)
    source = write_ros1(tmp_path / "fleet.bag", messages)
    data = source.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: _index_pos(source) * 2 // 3])  # inside the (uncompressed) chunk
    with pytest.warns(BagImportWarning, match=r"cut\.bag: the bag is cut or damaged at byte \d+ of \d+"):
        bag = import_bag(cut, work_dir=tmp_path / "work")
    assert "messages saved" in bag.salvaged and "everything after that is lost" in bag.salvaged
    got = [(m.topic, m.log_time_ns, m.data) for m in McapLog(bag.path).raw()]
    # the whole messages before the cut, in the order recorded, each byte for byte
    whole = [(m.topic, m.log_time_ns, m.data) for m in messages][: len(got)]
    assert 0 < len(got) < len(messages) and sorted(got, key=lambda g: g[1]) == sorted(whole, key=lambda g: g[1])
    # a recorder killed before it wrote the index: every message is read from the chunks
    unindexed = tmp_path / "active.bag"
    unindexed.write_bytes(data[: _index_pos(source)])
    with pytest.warns(BagImportWarning, match="no readable index"):
        whole_bag = import_bag(unindexed, work_dir=tmp_path / "work2")
    assert sum(t.message_count for t in whole_bag.topics) == len(messages)


def test_ros1_types_that_ros2_lacks_or_renamed(tmp_path):
    ros1 = get_typestore(Stores.ROS1_NOETIC)
    ros1.register(get_types_from_msg("Header header\nbool pressed\nfloat32 force_n", BUMPER))
    ros1.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf/msg/tfMessage"))
    header = ros1.types["std_msgs/msg/Header"](
        seq=4, stamp=ros1.types["builtin_interfaces/msg/Time"](3, 5), frame_id="x"
    )
    odom = golden_raw(["/robot_1/odom"])[0]
    source = tmp_path / "spark.bag"
    with Writer1(source) as writer:
        bumper = writer.add_connection("/robot_1/bumper", BUMPER, typestore=ros1)
        tf = writer.add_connection("/tf", "tf/msg/tfMessage", typestore=ros1)
        odom_conn = writer.add_connection("/robot_1/odom", odom.typename, typestore=ros1)
        writer.write(bumper, 10, ros1.serialize_ros1(ros1.types[BUMPER](header, True, 1.5), BUMPER))
        writer.write(tf, 11, ros1.serialize_ros1(ros1.types["tf/msg/tfMessage"]([]), "tf/msg/tfMessage"))
        writer.write(odom_conn, 12, get_typestore(Stores.ROS2_JAZZY).cdr_to_ros1(odom.data, odom.typename))
    bag = import_bag(source, work_dir=tmp_path / "work")
    assert bag.topic_types() == {
        "/robot_1/bumper": BUMPER,
        "/tf": "tf2_msgs/msg/TFMessage",
        "/robot_1/odom": odom.typename,
    }
    got = {m.topic: plain(m.msg) for m in McapLog(bag.path).messages()}
    assert got["/robot_1/bumper"] == {
        "header": {"stamp": {"sec": 3, "nanosec": 5}, "frame_id": "x"},
        "pressed": True,
        "force_n": 1.5,
    }
    assert got["/tf"] == {"transforms": []}
    assert got["/robot_1/odom"] == plain(next(McapLog(GOLDEN_MCAP).messages("/robot_1/odom")).msg)


def test_plain_mcap_without_session_metadata(tmp_path):
    source = write_plain_mcap(tmp_path / "robots.mcap", golden_raw())
    bag = import_bag(source)  # into a new temporary folder, left for the caller
    try:
        assert bag.path.parent.parent.parent == Path(tempfile.gettempdir())
    finally:
        shutil.rmtree(bag.path.parent.parent)
    bag = import_bag(source, work_dir=tmp_path / "work")
    assert bag.source_format == "mcap"
    assert bag.converted and bag.path != source
    check_import(bag, list(McapLog(GOLDEN_MCAP).topics()))
    qos = McapLog(bag.path).channel_metadata()
    assert all(meta["offered_qos_profiles"] for meta in qos.values())  # every channel gets one


def test_single_robot_without_namespace_and_a_remapped_scan(tmp_path):
    names = {"/robot_1/scan": "/base_scan", "/robot_1/odom": "/odom", "/robot_1/cmd_vel": "/cmd_vel"}
    topics = [*names, "/tf", "/clock"]
    source = write_rosbag2(tmp_path / "spark", golden_raw(topics), rename=lambda t: names.get(t, t))
    bag = import_bag(source, topic_map=parse_topic_map(["scan=/base_scan"]), work_dir=tmp_path / "work")
    assert bag.robots == ("robot_1",)
    check_import(bag, topics)
    sources = {t.name: t.source for t in bag.topics}
    assert sources["/robot_1/scan"] == "/base_scan"
    assert sources["/robot_1/odom"] == "/odom"
    named = import_bag(source, robots=["spark"], topic_map={"scan": "/base_scan"}, work_dir=tmp_path / "work")
    assert named.robots == ("spark",)
    assert named.path != bag.path  # a second import gets a folder of its own
    check_import(named, topics, rename=lambda t: t.replace("/robot_1/", "/spark/"))


def test_full_topic_remap_among_several_robots(tmp_path):
    source = write_rosbag2(
        tmp_path / "fleet", golden_raw(STANDARD), rename=lambda t: "/r1/base_scan" if t == "/robot_1/scan" else t
    )
    bag = import_bag(source, topic_map=parse_topic_map(["/robot_1/scan=/r1/base_scan"]), work_dir=tmp_path / "w")
    assert bag.robots == ("robot_1", "robot_2")
    check_import(bag, STANDARD)


def test_robots_restrict_and_order(tmp_path):
    source = write_rosbag2(tmp_path / "fleet", golden_raw(STANDARD))
    only = import_bag(source, robots=["robot_2"], work_dir=tmp_path / "w")
    assert only.robots == ("robot_2",)
    kept = [t for t in STANDARD if not t.startswith("/robot_1/")]
    check_import(only, kept)
    assert set(only.skipped) == {f"/robot_1/{k}" for k in ROBOT_KINDS}
    both = import_bag(source, robots=["robot_2", "robot_1"], work_dir=tmp_path / "w")
    assert both.robots == ("robot_2", "robot_1")


def test_session_recording_is_used_as_it_is(tmp_path):
    bag = import_bag(GOLDEN_MCAP)
    log = McapLog(GOLDEN_MCAP)
    assert not bag.converted
    assert bag.path == GOLDEN_MCAP
    assert bag.source_format == "mcap"
    assert bag.robots == ("robot_1", "robot_2")
    assert bag.message_counts() == log.message_counts()
    times = [m.log_time_ns for m in log.raw()]
    assert (bag.start_ns, bag.end_ns) == (times[0], times[-1])
    assert import_bag(GOLDEN_MCAP, robots=["robot_2"]).robots == ("robot_2",)
    with pytest.raises(RemapError, match="session recording"):
        import_bag(GOLDEN_MCAP, topic_map={"scan": "/base_scan"})
    folder = tmp_path / "session"
    folder.mkdir()
    shutil.copy(GOLDEN_MCAP, folder / "session.mcap")
    write_rosbag2_metadata(folder / "session.mcap")
    in_folder = import_bag(folder)
    assert (in_folder.source_format, in_folder.converted, in_folder.path) == (
        "rosbag2-mcap",
        False,
        folder / "session.mcap",
    )


# -- errors -------------------------------------------------------------------------------------


def test_error_types_share_the_root():
    for cls in (NotABagError, BagReadError, EmptyBagError, NoRobotsError, UnknownMessageTypeError, RemapError):
        assert issubclass(cls, BagError)
    assert issubclass(BagError, MrlError) and issubclass(TopicMapError, MrlError)


def test_paths_that_are_not_bags(tmp_path):
    missing = tmp_path / "nothing.bag"
    with pytest.raises(NotABagError, match="no such file") as err:
        import_bag(missing)
    assert str(missing) in str(err.value)
    text = tmp_path / "notes.txt"
    text.write_text("lidar looked fine today\n")
    with pytest.raises(NotABagError, match="not a bag") as err:
        import_bag(text)
    assert str(text) in str(err.value)
    folder = tmp_path / "logs"
    folder.mkdir()
    (folder / "run.mcap").write_bytes(b"")
    with pytest.raises(NotABagError, match=r"without metadata\.yaml.*run\.mcap"):
        import_bag(folder)
    empty = tmp_path / "empty.bag"
    empty.write_bytes(b"")
    with pytest.raises(EmptyBagError, match="empty") as err:
        import_bag(empty)
    assert str(empty) in str(err.value)


def test_unreadable_bags(tmp_path):
    source = write_ros1(tmp_path / "fleet.bag", golden_raw(STANDARD))
    cut = tmp_path / "cut.bag"
    cut.write_bytes(source.read_bytes()[:600])
    with pytest.raises(BagReadError) as err:
        import_bag(cut, work_dir=tmp_path / "work")
    assert str(cut) in str(err.value)
    folder = write_rosbag2(tmp_path / "fleet", golden_raw(STANDARD))
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    with pytest.raises(BagReadError, match=r"metadata\.yaml"):
        import_bag(folder)
    mcap = tmp_path / "cut.mcap"
    mcap.write_bytes(write_plain_mcap(tmp_path / "whole.mcap", golden_raw(STANDARD)).read_bytes()[:-200])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TruncatedLogWarning)
        with pytest.raises(BagReadError, match="no summary"):
            import_bag(mcap)


def test_bag_without_messages(tmp_path):
    source = write_rosbag2(tmp_path / "fleet", [])
    with pytest.raises(EmptyBagError, match="no messages") as err:
        import_bag(source)
    assert str(source) in str(err.value)


def test_no_robots_lists_the_topics(tmp_path):
    source = write_rosbag2(tmp_path / "fleet", golden_raw(["/tf", "/clock"]))
    with pytest.raises(NoRobotsError, match="no robot found") as err:
        import_bag(source)
    assert "/tf (tf2_msgs/msg/TFMessage)" in str(err.value) and "/clock" in str(err.value)
    fleet = write_rosbag2(tmp_path / "fleet2", golden_raw(STANDARD))
    with pytest.raises(NoRobotsError, match=r"robot_3 not found.*robots in the bag: robot_1, robot_2"):
        import_bag(fleet, robots=["robot_1", "robot_3"])
    with pytest.raises(BagError, match="not a ROS name"):
        import_bag(fleet, robots=["robot/1"])


def test_unknown_message_types(tmp_path):
    store = ros2_store()
    bumper = store.serialize_cdr(store.types[BUMPER](pressed=True, force_n=2.5), BUMPER)
    extra = [RawMessage("/bumper_raw", BUMPER, golden_raw()[0].log_time_ns, 0, 0, bytes(bumper))]
    source = make_humble(write_rosbag2(tmp_path / "humble", golden_raw(STANDARD) + extra, StoragePlugin.SQLITE3))
    with pytest.warns(BagImportWarning, match=f"/bumper_raw left out: message type {BUMPER}"):
        bag = import_bag(source, work_dir=tmp_path / "work")
    assert "/bumper_raw" in bag.skipped
    check_import(bag, STANDARD)
    with pytest.raises(UnknownMessageTypeError, match=f"/bumper_raw: message type {BUMPER} has no definition") as err:
        import_bag(source, topic_map={"/robot_1/bumper": "/bumper_raw"}, work_dir=tmp_path / "work")
    assert str(source) in str(err.value)
    with_definitions = write_rosbag2(tmp_path / "jazzy", golden_raw(STANDARD) + extra)
    kept = import_bag(with_definitions, work_dir=tmp_path / "work")  # the bag defines it: kept with its definition
    assert [plain(m.msg) for m in McapLog(kept.path).messages("/bumper_raw")] == [{"pressed": True, "force_n": 2.5}]


def test_remaps_that_do_not_apply(tmp_path):
    source = write_rosbag2(tmp_path / "fleet", golden_raw(STANDARD))
    with pytest.raises(RemapTopicMissingError, match="scan=/base_scan: the bag has no topic /base_scan") as err:
        import_bag(source, topic_map={"scan": "/base_scan"})
    assert "/robot_1/odom" in str(err.value) and str(source) in str(err.value)
    with pytest.raises(RemapError, match=r"single robot.*--topic /robot_1/scan=/tf"):
        import_bag(source, topic_map={"scan": "/tf"})
    with pytest.raises(RemapError, match="would both become /robot_1/scan"):
        import_bag(source, topic_map={"/robot_1/scan": "/robot_2/scan"})
    bare = write_rosbag2(tmp_path / "bare", golden_raw(["/robot_1/odom", "/tf"]), rename=lambda t: t[8:] or t)
    with pytest.raises(TopicTypeError, match=r"/robot_1/scan \(from /tf\) carries tf2_msgs/msg/TFMessage"):
        import_bag(bare, topic_map={"scan": "/tf"})


@pytest.mark.parametrize(
    ("item", "problem"),
    [("scan", "expected OURS=BAG"), ("lidar=/base_scan", "neither a topic kind"), ("scan=base_scan", "full topic")],
)
def test_malformed_topic_maps(item, problem):
    with pytest.raises(TopicMapError, match=problem) as err:
        parse_topic_map([item])
    assert repr(item) in str(err.value)


def test_topic_map_syntax():
    assert parse_topic_map(["scan=/base_scan", "/robot_2/odom = /r2/odom"]) == {
        "scan": "/base_scan",
        "/robot_2/odom": "/r2/odom",
    }
    with pytest.raises(TopicMapError, match="already mapped"):
        parse_topic_map(["scan=/a", "scan=/b"])


# -- rosbag2 metadata beside a session ----------------------------------------------------------


def test_session_folder_opens_as_a_rosbag2_bag(tmp_path):
    folder = tmp_path / "eval"
    folder.mkdir()
    mcap = folder / "session.mcap"
    shutil.copy(GOLDEN_MCAP, mcap)
    (folder / "episodes.csv").write_text("episode,robot\n0,robot_1\n")
    (folder / "metrics.json").write_text("{}")
    shutil.copy(GOLDEN_MCAP, folder / "older.mcap")  # not listed: must not be read
    meta = write_rosbag2_metadata(mcap)
    assert meta == folder / "metadata.yaml"
    info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
    assert (info["version"], info["storage_identifier"], info["relative_file_paths"]) == (9, "mcap", ["session.mcap"])
    assert [f["path"] for f in info["files"]] == ["session.mcap"]
    assert (info["compression_format"], info["compression_mode"]) == ("", "")

    log = McapLog(mcap)
    counts = log.message_counts()
    raw = list(log.raw())
    with Reader2(folder) as reader:
        assert reader.message_count == sum(counts.values())
        assert {c.topic: c.msgcount for c in reader.connections} == counts
        assert {c.topic: c.msgtype for c in reader.connections} == log.topics()
        assert reader.start_time == raw[0].log_time_ns
        assert reader.end_time == raw[-1].log_time_ns + 1  # rosbags' end is exclusive
        read = sorted((c.topic, t, bytes(d)) for c, t, d in reader.messages())
        assert read == sorted((m.topic, m.log_time_ns, m.data) for m in raw)
        scan = next(c for c in reader.connections if c.topic == "/robot_1/scan")
        qos = scan.ext.offered_qos_profiles[0]
        assert (qos.reliability, qos.depth) == (QosReliability.BEST_EFFORT, 5)
        assert scan.digest == message_store().rihs01("sensor_msgs/msg/LaserScan")
    with AnyReader([folder]) as reader:  # checks the type hashes against the file's definitions
        values = sorted((c.topic, t, repr(plain(reader.deserialize(d, c.msgtype)))) for c, t, d in reader.messages())
    assert values == sorted((m.topic, m.log_time_ns, repr(plain(m.msg))) for m in log.messages())
    assert write_rosbag2_metadata(mcap) == meta  # its own metadata is replaced


def test_rosbag2_metadata_refusals(tmp_path):
    folder = tmp_path / "eval"
    folder.mkdir()
    shutil.copy(GOLDEN_MCAP, folder / "a.mcap")
    shutil.copy(GOLDEN_MCAP, folder / "b.mcap")
    write_rosbag2_metadata(folder / "a.mcap")
    with pytest.raises(RecordError, match="another bag"):
        write_rosbag2_metadata(folder / "b.mcap")
    cut = tmp_path / "cut" / "session.mcap"
    cut.parent.mkdir()
    cut.write_bytes(GOLDEN_MCAP.read_bytes()[:-300])
    with pytest.warns(TruncatedLogWarning), pytest.raises(RecordError, match="no summary"):
        write_rosbag2_metadata(cut)
    assert not (cut.parent / "metadata.yaml").exists()
