"""Bags recorded elsewhere, imported as a ROS 2 profile MCAP that :class:`McapLog` reads.

A bag is any of: an MCAP file; a rosbag2 folder (``metadata.yaml`` with ``mcap`` or ``sqlite3``
storage, as ``ros2 bag record`` writes on Humble and Jazzy; a bare ``.db3`` file too); a ROS 1
``.bag`` file. A session recording of this pipeline (an MCAP with a ``session`` metadata record,
alone or as the storage file of a rosbag2 folder) is used as it is. Anything else is read with
``rosbags`` and written with ``rosbags``' rosbag2 writer (storage ``mcap``, zstd chunks, version 9)
into a folder of `work_dir` that is itself a rosbag2 bag, with:

- the CDR bytes of ROS 2 bags unchanged; ROS 1 messages converted to CDR by the type store;
- each type's definition: ROS 2 Jazzy's (as the recorder writes it) where the bag's own definition
  is the same or the bag has none, else the bag's own; ROS 1 types map onto their ROS 2 namesakes;
- the robots' topics in the contract's layout ``/<robot>/scan|odom|cmd_vel|ground_truth``;
- each message's log time (the bag's receive time, integer ns) as both log and publish time;
- every channel's ``offered_qos_profiles``: the bag's, else the contract's, else reliable/volatile.

Robots are the namespaces ``ns`` with a ``/<ns>/scan`` LaserScan or ``/<ns>/odom`` Odometry topic.
Without any, the un-namespaced ``/scan``, ``/odom``, ``/cmd_vel``, ``/ground_truth`` are one robot
(``robot_1``, or the one name given) and are renamed into its namespace.

Remapping says where the bag keeps a topic of the contract: ``OURS=BAG``, OURS being a kind
(``scan``, ``odom``, ``cmd_vel``, ``ground_truth``: the topic of the single robot) or a full topic
(``/robot_1/scan``), BAG the bag's topic. On the command line: ``--topic scan=/base_scan``,
``--topic /robot_1/scan=/r1/base_scan`` (see :func:`parse_topic_map`).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import tempfile
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any, Literal, NamedTuple

import yaml
from rosbags.highlevel import AnyReader
from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag1,
    ConnectionExtRosbag2,
    MessageDefinitionFormat,
    Nodetype,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from pipeline.errors import MrlError
from pipeline.messages.store import schema_files
from pipeline.messages.topics import LASER_SCAN, ODOMETRY, QosProfile, fleet_topics, robot_topics
from pipeline.record import format as fmt
from pipeline.record.errors import (
    BagError,
    BagImportWarning,
    BagReadError,
    EmptyBagError,
    LogFormatError,
    LogReadError,
    NoRobotsError,
    NotABagError,
    RecordError,
    RemapError,
    RemapTopicMissingError,
    TopicMapError,
    TopicTypeError,
    UnknownMessageTypeError,
)
from pipeline.record.reader import McapLog
from pipeline.record.ros1_salvage import salvage_ros1
from pipeline.record.session import SESSION_META, session_info

BagFormat = Literal["mcap", "rosbag2-mcap", "rosbag2-sqlite3", "ros1"]
"""Where a bag came from: an MCAP file, a rosbag2 folder (mcap or sqlite3 storage), a ROS 1 bag."""
KINDS = ("scan", "odom", "cmd_vel", "ground_truth")
"""The per-robot topic kinds of the ROS 2 contract, in the order ``robot_topics`` lists them."""
DEFAULT_ROBOT = "robot_1"
"""The name of a single robot whose topics carry no namespace."""
"""The metadata record that marks a session recording of this pipeline."""

_MCAP_MAGIC = fmt.MAGIC
_ROS1_MAGIC = b"#ROSBAG V2.0\n"
_SQLITE_MAGIC = b"SQLite format 3\x00"
_ROBOT_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_TOPIC = re.compile(r"(/[A-Za-z0-9_]+)+")
_ROBOT_TOPIC = re.compile(r"/([^/]+)/(scan|odom)")
_ROS1_RENAMES = {"tf/msg/tfMessage": "tf2_msgs/msg/TFMessage"}
_HEADER = "std_msgs/msg/Header"
_DEFAULT_QOS = QosProfile("reliable", "volatile", 10)
_LATCHED_QOS = QosProfile("reliable", "transient_local", 1)


@dataclass(frozen=True)
class BagTopic:
    """One topic of an imported bag: its name in the MCAP, type, messages, and its name in the source bag."""

    name: str
    typename: str
    message_count: int
    source: str


@dataclass(frozen=True)
class ImportedBag:
    """A bag ready for :class:`McapLog`: open ``McapLog(bag.path)`` (or ``bag.log()``).

    Attributes:
        path: the MCAP file to read (the source itself when `converted` is False).
        source: the path that was imported.
        source_format: mcap | rosbag2-mcap | rosbag2-sqlite3 | ros1.
        converted: False for a session recording of this pipeline, used as it is.
        robots: the robots' namespaces, in the order asked for (else natural order: robot_2 < robot_10).
        topics: every topic of `path` with its type and message count.
        start_ns, end_ns: log times of the first and last message (ns, the bag's clock, usually Unix time).
        skipped: source topics left out of `path` and why.
        salvaged: for a cut or damaged ROS 1 bag read record by record, what was saved and lost ('' otherwise).
    """

    path: Path
    source: Path
    source_format: BagFormat
    converted: bool
    robots: tuple[str, ...]
    topics: tuple[BagTopic, ...]
    start_ns: int
    end_ns: int
    skipped: dict[str, str] = field(default_factory=dict)
    salvaged: str = ""

    @property
    def duration_ns(self) -> int:
        """Log time from the first to the last message (ns)."""
        return self.end_ns - self.start_ns

    @property
    def message_count(self) -> int:
        return sum(t.message_count for t in self.topics)

    def topic_types(self) -> dict[str, str]:
        """``{topic: message type}`` of the MCAP."""
        return {t.name: t.typename for t in self.topics}

    def message_counts(self) -> dict[str, int]:
        """``{topic: number of messages}`` of the MCAP."""
        return {t.name: t.message_count for t in self.topics}

    def log(self) -> McapLog:
        """The imported MCAP opened for reading."""
        return McapLog(self.path)


# -- remapping ---------------------------------------------------------------------------------


def parse_topic_map(items: Iterable[str]) -> dict[str, str]:
    """``--topic`` arguments (``OURS=BAG``) as the `topic_map` of :func:`import_bag`.

    OURS is a kind (``scan``, ``odom``, ``cmd_vel``, ``ground_truth``) of the single robot or a full
    topic of the output (``/robot_1/scan``); BAG is the bag's topic (``/base_scan``). Raises
    TopicMapError for a malformed item or an OURS given twice.
    """
    out: dict[str, str] = {}
    for item in items:
        ours, sep, theirs = item.partition("=")
        if not sep:
            raise TopicMapError(item, "expected OURS=BAG, e.g. scan=/base_scan or /robot_1/scan=/r1/base_scan")
        ours, theirs = ours.strip(), theirs.strip()
        _check_mapping(ours, theirs, item)
        if ours in out:
            raise TopicMapError(item, f"{ours} is already mapped to {out[ours]}")
        out[ours] = theirs
    return out


def _check_mapping(ours: str, theirs: str, item: str) -> None:
    if ours not in KINDS and not _TOPIC.fullmatch(ours):
        raise TopicMapError(
            item, f"{ours!r} is neither a topic kind ({', '.join(KINDS)}) nor a full topic name such as /robot_1/scan"
        )
    if not _TOPIC.fullmatch(theirs):
        raise TopicMapError(item, f"{theirs!r} is not a full topic name of the bag, such as /base_scan")


def _split_topic_map(topic_map: Mapping[str, str]) -> tuple[dict[str, str], dict[str, str]]:
    """(full topic -> bag topic, kind -> bag topic), each entry checked."""
    full: dict[str, str] = {}
    kinds: dict[str, str] = {}
    for ours, theirs in topic_map.items():
        if not isinstance(ours, str) or not isinstance(theirs, str):
            raise TopicMapError(f"{ours!r}={theirs!r}", "topic names are strings")
        _check_mapping(ours, theirs, f"{ours}={theirs}")
        (kinds if ours in KINDS else full)[ours] = theirs
    return full, kinds


def _natural(name: str) -> tuple[Any, ...]:
    """Sort key that puts robot_2 before robot_10."""
    return tuple(int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name))


def _robot_namespaces(topics: Mapping[str, str]) -> list[str]:
    """Namespaces with a ``/<ns>/scan`` LaserScan or ``/<ns>/odom`` Odometry topic, natural order."""
    wanted = {"scan": LASER_SCAN, "odom": ODOMETRY}
    found = {m.group(1) for t, ty in topics.items() if (m := _ROBOT_TOPIC.fullmatch(t)) and ty == wanted[m.group(2)]}
    return sorted(found, key=_natural)


def _robot_names(where: str, robots: Sequence[str]) -> list[str]:
    if isinstance(robots, str):
        robots = [robots]
    names = list(robots)
    for name in names:
        if not isinstance(name, str) or not _ROBOT_NAME.fullmatch(name):
            raise BagError(where, f"robot name {name!r} is not a ROS name token (letters, digits, _), e.g. robot_1")
    if len(set(names)) != len(names):
        raise BagError(where, f"robot names repeat: {', '.join(names)}")
    if not names:
        raise BagError(where, "an empty list of robots selects nothing; leave it out to take every robot")
    return names


@dataclass(frozen=True)
class _Plan:
    """Where each topic of the bag goes."""

    robots: tuple[str, ...]
    routes: dict[str, str]  # source topic -> topic of the output
    skipped: dict[str, str]  # source topic -> why it is left out
    needed: frozenset[str]  # source topics the output cannot do without


def _plan(
    where: str, topics: Mapping[str, str], robots: Sequence[str] | None, topic_map: Mapping[str, str] | None
) -> _Plan:
    """The robots and topic routes of a bag with `topics` ({name: type}); raises on anything that does not fit."""
    full, kinds = _split_topic_map(topic_map or {})
    remaps = [(ours, theirs) for ours, theirs in full.items()] + [(k, t) for k, t in kinds.items()]
    for ours, theirs in remaps:
        if theirs not in topics:
            raise RemapTopicMissingError(where, f"{ours}={theirs}", theirs, dict(topics))
    sources = [theirs for _, theirs in remaps]
    for theirs in sources:
        if sources.count(theirs) > 1:
            both = ", ".join(f"{o}={t}" for o, t in remaps if t == theirs)
            raise RemapError(where, f"bag topic {theirs} is remapped twice ({both})")
    kept = {t: ty for t, ty in topics.items() if t not in sources}
    routes = {t: t for t in kept}
    routes.update({theirs: ours for ours, theirs in full.items()})
    found = _robot_namespaces({**kept, **{ours: topics[theirs] for ours, theirs in full.items()}})
    names = _robot_names(where, robots) if robots is not None else None
    if found:
        selected = names if names is not None else found
        missing = [r for r in selected if r not in found]
        if missing:
            raise NoRobotsError(
                where,
                f"robot(s) {', '.join(missing)} not found (a robot has a /<robot>/scan LaserScan or /<robot>/odom "
                f"Odometry topic); robots in the bag: {', '.join(found)}",
                dict(topics),
            )
        if kinds:
            if len(selected) != 1:
                kind, theirs = next(iter(kinds.items()))
                raise RemapError(
                    where,
                    f"--topic {kind}={theirs} names a topic kind, which needs a single robot, and there are "
                    f"{len(selected)} ({', '.join(selected)}): give the full topic, e.g. "
                    f"--topic /{selected[0]}/{kind}={theirs}",
                )
            routes.update({theirs: f"/{selected[0]}/{kind}" for kind, theirs in kinds.items()})
    else:
        bare = [f"/{k}" for k in KINDS if f"/{k}" in kept]
        if not kinds and kept.get("/scan") != LASER_SCAN and kept.get("/odom") != ODOMETRY:
            raise NoRobotsError(
                where,
                "no robot found: no /<robot>/scan (LaserScan) or /<robot>/odom (Odometry) topic, no un-namespaced "
                "/scan or /odom; map the robot's topics with --topic, e.g. --topic scan=/base_scan",
                dict(topics),
            )
        if names is not None and len(names) != 1:
            raise NoRobotsError(
                where,
                f"the bag's robot topics carry no namespace ({', '.join(bare) or 'remapped kinds only'}), so they are "
                f"one robot, and {len(names)} robots were asked for ({', '.join(names)})",
                dict(topics),
            )
        name = names[0] if names is not None else DEFAULT_ROBOT
        selected = [name]
        for kind in KINDS:
            theirs = kinds.get(kind) or (f"/{kind}" if f"/{kind}" in kept else "")
            if theirs:
                routes[theirs] = f"/{name}/{kind}"
    skipped: dict[str, str] = {}
    others = set(found) - set(selected)
    for src, dest in list(routes.items()):
        ns = dest.split("/")[1]
        if ns in others and dest.count("/") >= 2:
            del routes[src]
            skipped[src] = f"robot {ns} was not asked for"
    taken: dict[str, str] = {}
    for src, dest in routes.items():
        if dest in taken:
            raise RemapError(
                where, f"bag topics {taken[dest]} and {src} would both become {dest}; remap one of them elsewhere"
            )
        taken[dest] = src
    robot_specs = {spec.name: spec for ns in selected for spec in robot_topics(ns).values()}
    for name, spec in robot_specs.items():
        origin = taken.get(name)
        if origin is not None and topics[origin] != spec.typename:
            raise TopicTypeError(where, name, topics[origin], spec.typename, origin)
    for ns in selected:
        if f"/{ns}/scan" not in taken and f"/{ns}/odom" not in taken:
            raise NoRobotsError(where, f"robot {ns} would have neither /{ns}/scan nor /{ns}/odom", dict(topics))
    needed = {src for src, dest in routes.items() if dest in robot_specs} | set(sources)
    return _Plan(tuple(selected), routes, skipped, frozenset(needed))


# -- message types -----------------------------------------------------------------------------


class _Codec(NamedTuple):
    """How one source type is written: output type, its ros2msg definition and hash, and a byte converter."""

    typename: str
    msgdef: str
    rihs01: str
    convert: Callable[[bytes], bytes] | None  # None: the CDR bytes pass through


@cache
def _schema_types() -> dict[str, Any]:
    """The field definitions of the types in ``schemas/`` (parsed once)."""
    types: dict[str, Any] = {}
    for typename, path in schema_files().items():
        types.update(get_types_from_msg(path.read_text(encoding="utf-8"), typename))
    return types


def _reference_store() -> Typestore:
    """A fresh ROS 2 Jazzy type store with the types of ``schemas/`` (the message store's definitions)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(_schema_types())
    return store


def _msgdef(store: Typestore, typename: str) -> str:
    return str(store.generate_msgdef(typename, ros_version=2)[0])


def _ros2_codec(bag: Typestore, ref: Typestore, conn: Connection) -> _Codec | str:
    """The codec of a ROS 2 connection (bytes pass through), or why its type cannot be defined."""
    typename = conn.msgtype
    own = typename in bag.fielddefs
    if typename in ref.fielddefs:
        reference = _msgdef(ref, typename)
        try:
            same = not own or _msgdef(bag, typename) == reference
        except Exception:  # the bag's definition lacks a dependency: take the reference one
            same = True
        if same:
            return _Codec(typename, reference, str(ref.hash_rihs01(typename)), None)
    if own:
        try:
            text = conn.msgdef.data if conn.msgdef.format == MessageDefinitionFormat.MSG else _msgdef(bag, typename)
            return _Codec(typename, text, str(bag.hash_rihs01(typename)), None)
        except Exception as exc:  # rosbags' typesys errors
            return f"has a definition in the bag that does not resolve: {exc}"
    return "has no definition in the bag and is neither a ROS 2 Jazzy type nor one of schemas/"


def _same_wire(src: Typestore, dst: Typestore, src_type: str, dst_type: str) -> bool:
    """Whether ROS 1 `src_type` and ROS 2 `dst_type` have the same fields (a Header converts by dropping seq)."""
    if src_type == _HEADER:
        return True
    src_fields = src.fielddefs[src_type][1]
    dst_fields = dst.fielddefs[dst_type][1]
    if len(src_fields) != len(dst_fields):
        return False
    for (_, a), (_, b) in zip(src_fields, dst_fields, strict=True):
        if a != b:
            return False
        inner = a[1][0] if a[0] in (Nodetype.ARRAY, Nodetype.SEQUENCE) else a
        if inner[0] == Nodetype.NAME and not _same_wire(src, dst, inner[1], inner[1]):
            return False
    return True


def _ros1_codec(bag: Typestore, dst: Typestore, conn: Connection) -> _Codec | str:
    """The codec of a ROS 1 connection (ROS 1 bytes -> CDR of the ROS 2 namesake), or why there is none."""
    src_type = conn.msgtype
    typename = _ROS1_RENAMES.get(src_type, src_type)
    try:
        if typename not in dst.fielddefs:  # a type ROS 2 lacks: its ROS 1 definition, with ROS 2's Header
            types = get_types_from_msg(_msgdef(bag, src_type), typename)
            types.pop(_HEADER, None)
            dst.register(types)
        if not _same_wire(bag, dst, src_type, typename):
            return f"has ROS 1 fields that differ from the ROS 2 definition of {typename}"
        text = _msgdef(dst, typename)
        rihs01 = str(dst.hash_rihs01(typename))
    except Exception as exc:  # rosbags' typesys errors on definitions that clash or do not parse
        return f"does not convert to a ROS 2 type: {exc}"

    def convert(data: bytes) -> bytes:
        return bytes(dst.ros1_to_cdr(data, typename))

    return _Codec(typename, text, rihs01, convert)


def _rosbags_qos(profile: QosProfile) -> Qos:
    zero = QosTime(0, 0)
    reliability = QosReliability.RELIABLE if profile.reliability == "reliable" else QosReliability.BEST_EFFORT
    durability = QosDurability.VOLATILE if profile.durability == "volatile" else QosDurability.TRANSIENT_LOCAL
    return Qos(
        QosHistory.KEEP_LAST, profile.depth, reliability, durability, zero, zero, QosLiveliness.AUTOMATIC, zero, False
    )


def _offered_qos(conn: Connection, dest: str, contract: Mapping[str, QosProfile]) -> list[Qos]:
    """The bag's QoS of a connection, else the contract's for its topic, else latched or reliable defaults."""
    ext = conn.ext
    if isinstance(ext, ConnectionExtRosbag2) and ext.offered_qos_profiles:
        return list(ext.offered_qos_profiles)
    if dest in contract:
        return [_rosbags_qos(contract[dest])]
    if isinstance(ext, ConnectionExtRosbag1) and ext.latching:
        return [_rosbags_qos(_LATCHED_QOS)]
    return [_rosbags_qos(_DEFAULT_QOS)]


# -- formats -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Source:
    format: BagFormat
    path: Path  # what rosbags opens: the folder or the file
    mcap: Path | None  # the single MCAP storage file, if any


def _detect(path: Path) -> _Source:
    """The format of `path`, from a folder's metadata.yaml or a file's first bytes."""
    where = str(path)
    if not path.exists():
        raise NotABagError(where, "no such file or folder")
    if path.is_file() and path.name == "metadata.yaml":
        return _detect(path.parent)
    if path.is_dir():
        return _detect_folder(path)
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError as exc:
        raise BagReadError(where, f"cannot open for reading: {exc.strerror}") from exc
    if not head:
        raise EmptyBagError(where, "the file is empty (0 bytes)")
    if head.startswith(_MCAP_MAGIC):
        return _Source("mcap", path, path)
    if head.startswith(_ROS1_MAGIC):
        return _Source("ros1", path, None)
    if head.startswith(_SQLITE_MAGIC):
        return _Source("rosbag2-sqlite3", path, None)
    raise NotABagError(
        where,
        f"not a bag: the file starts with {head!r}; a bag is an MCAP file, a ROS 1 .bag file or a rosbag2 folder",
    )


def _detect_folder(path: Path) -> _Source:
    where = str(path)
    meta = path / "metadata.yaml"
    if not meta.is_file():
        inside = sorted(p.name for p in path.iterdir() if p.suffix in (".mcap", ".db3", ".bag"))
        hint = f"; it holds {', '.join(inside)}: import that file instead" if inside else ""
        raise NotABagError(where, f"a folder without metadata.yaml is not a rosbag2 bag{hint}")
    try:
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
        storage = str(info["storage_identifier"])
        files = [str(f) for f in info.get("relative_file_paths") or []]
    except OSError as exc:
        raise BagReadError(str(meta), f"cannot read: {exc.strerror}") from exc
    except (UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError, AttributeError) as exc:
        raise BagReadError(str(meta), f"is not rosbag2 metadata ({type(exc).__name__}: {exc})") from exc
    if storage == "mcap":
        mcap = path / Path(files[0]).name if len(files) == 1 and files[0].endswith(".mcap") else None
        return _Source("rosbag2-mcap", path, mcap)
    if storage == "sqlite3":
        return _Source("rosbag2-sqlite3", path, None)
    raise NotABagError(where, f"rosbag2 storage {storage!r} is not supported (mcap, sqlite3)")


def _probe(source: _Source, where: str) -> McapLog | None:
    """The MCAP of `source` opened with McapLog when it is a session recording of this pipeline, else None."""
    if source.mcap is None or not source.mcap.is_file():
        return None
    try:
        log = McapLog(source.mcap)
    except LogFormatError as exc:
        raise NotABagError(where, f"not a ROS 2 MCAP: {exc.problem}") from exc
    except LogReadError as exc:
        raise BagReadError(where, exc.problem) from exc
    if SESSION_META in log.metadata():
        return log
    if log.profile != fmt.PROFILE:
        raise NotABagError(where, f"not a ROS 2 MCAP: its profile is {log.profile!r}, not {fmt.PROFILE!r}")
    if log.salvaged:
        raise BagReadError(
            where, "the MCAP file has no summary and footer (its recorder was killed); rosbags cannot read it"
        )
    return None


def _readable_path(source: _Source, links: Path) -> Path:
    """`source.path`, linked under a name whose suffix tells rosbags its format where it lacks one."""
    suffix = {"ros1": ".bag", "mcap": ".mcap", "rosbag2-sqlite3": ".db3"}.get(source.format)
    path = source.path
    if path.is_dir() or suffix is None or path.suffix == suffix:
        return path
    link = links / f"{path.stem or 'bag'}{suffix}"
    try:
        link.symlink_to(path.resolve())
    except OSError:
        shutil.copyfile(path, link)
    return link


# -- import ------------------------------------------------------------------------------------


def import_bag(
    path: str | os.PathLike[str],
    robots: Sequence[str] | None = None,
    topic_map: Mapping[str, str] | None = None,
    work_dir: str | os.PathLike[str] | None = None,
) -> ImportedBag:
    """Make the bag at `path` readable by McapLog: a session of this pipeline as it is, anything else converted.

    Args:
        path: an MCAP file, a rosbag2 folder (or its metadata.yaml), a ``.db3`` file or a ROS 1 ``.bag``.
        robots: the robots' namespaces to keep, in this order (others' topics are left out of a
            converted bag; a session is not changed); one name for a bag whose robot topics carry no
            namespace. Default: every robot found.
        topic_map: ``{OURS: BAG}`` remappings (see :func:`parse_topic_map`); refused for a session.
        work_dir: where the converted bag's folder is written (created); a new temporary folder,
            left in place for the caller, by default.

    Raises:
        NotABagError, BagReadError, EmptyBagError: the path is no bag, cannot be read, or holds nothing.
        NoRobotsError: no robot, or not the robots asked for (lists the topics seen).
        RemapError, RemapTopicMissingError, TopicMapError: a remapping that does not apply.
        TopicTypeError: a robot topic with the wrong message type.
        UnknownMessageTypeError: a robot or remapped topic whose type cannot be defined; other such
            topics are left out with a BagImportWarning.
        RecordError: the converted MCAP cannot be written.
    """
    source_path = Path(path)
    where = str(source_path)
    source = _detect(source_path)
    session = _probe(source, where)
    if session is not None:
        if topic_map:
            raise RemapError(
                where, "is a session recording of this pipeline: its topics follow the contract, nothing is remapped"
            )
        return _session_bag(source_path, source, session, robots)
    with tempfile.TemporaryDirectory(prefix="mrl-bag-links-") as links:
        readable = _readable_path(source, Path(links))
        return _convert(source_path, source, readable, robots, topic_map, work_dir, Path(links))


def _session_bag(path: Path, source: _Source, log: McapLog, robots: Sequence[str] | None) -> ImportedBag:
    where = str(path)
    types = log.topics()
    counts = log.message_counts()
    if not sum(counts.values()):
        raise EmptyBagError(where, "the recording holds no messages")
    recorded = list(session_info(log.metadata()).robots)
    found = recorded or _robot_namespaces(types)
    if not found:
        raise NoRobotsError(where, "the session recording has no robot topics", types)
    selected = found
    if robots is not None:
        selected = _robot_names(where, robots)
        missing = [r for r in selected if r not in found]
        if missing:
            raise NoRobotsError(
                where, f"robot(s) {', '.join(missing)} not in the recording; it has {', '.join(found)}", types
            )
    start_ns = end_ns = 0
    first = True
    for message in log.raw():
        if first:
            start_ns, first = message.log_time_ns, False
        end_ns = message.log_time_ns
    assert source.mcap is not None  # _probe only returns a log for an MCAP file
    topics = tuple(BagTopic(name, typename, counts[name], name) for name, typename in types.items())
    return ImportedBag(source.mcap, path, source.format, False, tuple(selected), topics, start_ns, end_ns)


def _leave_out(where: str, skipped: dict[str, str], topic: str, why: str) -> None:
    skipped[topic] = why
    warnings.warn(BagImportWarning(f"{where}: topic {topic} left out: {why}"), stacklevel=4)


def _open_reader(readable: Path, where: str) -> AnyReader:
    try:
        reader = AnyReader([readable], default_typestore=_reference_store())
        reader.open()
    except MrlError:
        raise
    except Exception as exc:  # rosbags raises its reader errors, OSError, and parser errors on damaged files
        raise BagReadError(where, f"cannot read the bag: {exc}") from exc
    return reader


def _open_or_salvage(readable: Path, source: _Source, where: str, scratch: Path) -> tuple[AnyReader, str]:
    """The bag's reader; a ROS 1 bag whose index cannot be read is walked record by record into a new bag in
    `scratch` (see :mod:`pipeline.record.ros1_salvage`) and that is read, with a line on what was saved and lost."""
    try:
        return _open_reader(readable, where), ""
    except BagReadError as exc:
        if source.format != "ros1":
            raise
        failure = exc.problem
    saved = scratch / f"{readable.stem}.salvaged.bag"
    try:
        found = salvage_ros1(source.path, saved)
    except Exception as exc:  # rosbags' ReaderError and WriterError, OSError
        raise BagReadError(where, f"{failure}; and no message could be saved from its records: {exc}") from exc
    note = found.lost or (
        f"the bag has no readable index ({failure}); all {found.messages} messages were read from its chunks"
    )
    warnings.warn(BagImportWarning(f"{where}: {note}"), stacklevel=4)
    return _open_reader(saved, where), note


def _output_dir(work_dir: str | os.PathLike[str] | None, stem: str) -> tuple[Path, bool]:
    """A new folder path for the converted bag (not created), and whether its parent is a new temp folder."""
    if work_dir is None:
        return Path(tempfile.mkdtemp(prefix="mrl-bag-")) / stem, True
    base = Path(work_dir)
    try:
        base.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecordError(str(base), f"cannot create the work folder: {exc.strerror}") from exc
    out = base / stem
    n = 1
    while out.exists():
        n += 1
        out = base / f"{stem}-{n}"
    return out, False


def _convert(
    path: Path,
    source: _Source,
    readable: Path,
    robots: Sequence[str] | None,
    topic_map: Mapping[str, str] | None,
    work_dir: str | os.PathLike[str] | None,
    scratch: Path,
) -> ImportedBag:
    where = str(path)
    reader, salvaged = _open_or_salvage(readable, source, where, scratch)
    try:
        if not reader.message_count:
            raise EmptyBagError(where, "the bag holds no messages")
        topics: dict[str, str] = {}
        for conn in reader.connections:
            topics.setdefault(conn.topic, conn.msgtype)
        plan = _plan(where, topics, robots, topic_map)
        skipped = dict(plan.skipped)
        ref = _reference_store()
        codecs: dict[str, _Codec | str] = {}
        chosen: list[tuple[Connection, str, _Codec]] = []
        for conn in reader.connections:
            dest = plan.routes.get(conn.topic)
            if dest is None:
                continue
            if conn.msgtype != topics[conn.topic]:
                why = f"its messages of type {conn.msgtype}: the topic carries {topics[conn.topic]} too"
                _leave_out(where, skipped, f"{conn.topic} [{conn.msgtype}]", why)
                continue
            codec = codecs.get(conn.msgtype)
            if codec is None:
                if reader.is2:
                    codec = _ros2_codec(reader.typestore, ref, conn)
                else:
                    codec = _ros1_codec(reader.typestore, ref, conn)
                codecs[conn.msgtype] = codec
            if isinstance(codec, str):
                if conn.topic in plan.needed:
                    raise UnknownMessageTypeError(where, conn.topic, conn.msgtype, codec)
                if conn.topic not in skipped:
                    _leave_out(where, skipped, conn.topic, f"message type {conn.msgtype} {codec}")
                continue
            chosen.append((conn, dest, codec))
        if not chosen:
            raise EmptyBagError(where, "no topic of the bag can be imported")
        stem = source.path.stem if source.path.is_file() else source.path.resolve().name
        out_dir, temporary = _output_dir(work_dir, stem or "bag")
        try:
            return _write(path, source.format, reader, plan, chosen, skipped, out_dir, salvaged)
        except BaseException:
            shutil.rmtree(out_dir.parent if temporary else out_dir, ignore_errors=True)
            raise
    finally:
        reader.close()


def _write(
    path: Path,
    source_format: BagFormat,
    reader: AnyReader,
    plan: _Plan,
    chosen: list[tuple[Connection, str, _Codec]],
    skipped: dict[str, str],
    out_dir: Path,
    salvaged: str = "",
) -> ImportedBag:
    where = str(path)
    contract = {name: spec.qos for name, spec in fleet_topics(plan.robots).items()}
    custom = {
        "mrl.source": str(path.resolve()),
        "mrl.source_format": source_format,
        "mrl.robots": ",".join(plan.robots),
        "mrl.topic_map": ",".join(f"{dest}={src}" for src, dest in plan.routes.items() if src != dest),
    }
    writer: Writer | None = None
    routes: dict[int, tuple[Connection, _Codec, str]] = {}
    outputs: dict[tuple[str, str, tuple[Qos, ...]], Connection] = {}
    sources: dict[str, str] = {}
    counts: dict[str, int] = {}
    start_ns, end_ns = 2**64, -1
    try:
        writer = Writer(out_dir, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for name, value in custom.items():
            writer.set_custom_data(name, value)
        writer.open()
        for conn, dest, codec in chosen:
            qos = tuple(_offered_qos(conn, dest, contract))
            key = (dest, codec.typename, qos)
            if key not in outputs:
                outputs[key] = writer.add_connection(
                    dest, codec.typename, msgdef=codec.msgdef, rihs01=codec.rihs01, offered_qos_profiles=qos
                )
            routes[conn.id] = (outputs[key], codec, dest)
            sources[dest] = conn.topic
            counts.setdefault(dest, 0)
        messages = reader.messages(connections=[c for c, _, _ in chosen])
        while True:
            try:
                conn, t_ns, data = next(messages)
            except StopIteration:
                break
            except Exception as exc:  # rosbags' reader and storage errors on damaged data
                raise BagReadError(where, f"reading messages failed: {exc}") from exc
            out, codec, dest = routes[conn.id]
            if codec.convert is not None:
                try:
                    data = codec.convert(data)
                except Exception as exc:  # rosbags' serde errors on bytes that do not match the definition
                    raise BagReadError(
                        where, f"topic {conn.topic}, message at {t_ns} ns: does not convert to CDR: {exc}"
                    ) from exc
            writer.write(out, t_ns, data)
            counts[dest] += 1
            start_ns, end_ns = min(start_ns, t_ns), max(end_ns, t_ns)
        writer.close()
        listed = sum(c.msgcount for c, _, _ in chosen)
        if listed != sum(counts.values()):
            warnings.warn(
                BagImportWarning(
                    f"{where}: its index lists {listed} messages on the imported topics, {sum(counts.values())} "
                    "were read (metadata.yaml and storage disagree?)"
                ),
                stacklevel=4,
            )
    except MrlError:
        if writer is not None:
            writer.abort()
        raise
    except Exception as exc:  # rosbags' WriterError, OSError
        if writer is not None:
            writer.abort()
        raise RecordError(str(out_dir), f"cannot write the imported bag: {exc}") from exc
    mcap = out_dir / f"{out_dir.name}.mcap"
    types = {dest: codec.typename for _, dest, codec in chosen}
    topics = tuple(BagTopic(dest, types[dest], n, sources[dest]) for dest, n in counts.items())
    if end_ns < 0:
        raise EmptyBagError(where, "no message of the bag could be imported")
    return ImportedBag(mcap, path, source_format, True, plan.robots, topics, start_ns, end_ns, skipped, salvaged)


def bag_files(path: Path) -> list[Path]:
    """The files of a bag: the file itself, or a bag folder's files in name order."""
    return sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]


def bag_size(path: Path) -> int:
    """Bytes of a bag file, or of all a bag folder's files."""
    return sum(f.stat().st_size for f in bag_files(path))


def bag_sha256(path: Path) -> str:
    """SHA-256 of a bag file, or of a bag folder's files (their names relative to it and their bytes, in name
    order): the user's own bag as given, whatever it was read through."""
    digest = hashlib.sha256()
    for f in bag_files(path):
        if path.is_dir():
            digest.update(str(f.relative_to(path)).encode())
        with f.open("rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()
