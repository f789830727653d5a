"""What can be saved of a ROS 1 bag that was cut or damaged (a recorder killed, a copy that stopped short).

A ROS 1 bag (format 2.0) is a bag header, then chunks, each holding connection and message records,
then an index (index data, connections, chunk infos) whose position the bag header gives. rosbags
reads through the index only, so a bag without one (``rosbag record`` killed: its ``.bag.active``
file) or with a cut one cannot be opened. :func:`salvage_ros1` walks the records from the start
instead, as ``rosbag reindex`` does: every chunk that is whole (and decompresses) gives its
connections and messages, in order, and of an uncompressed chunk that is cut, every record before
the cut; the walk stops at the first record that is cut or garbled, and what lies after it is lost
and said so. The saved records go into a new, indexed bag written with rosbags, which the importer
then reads as any other.

Chunks compressed with bz2 or lz4 (``rosbag record --bz2 / --lz4``) are decompressed with Python's
``bz2`` and the ``lz4`` package's frame format, as ROS 1 writes them.
"""

from __future__ import annotations

import bz2
import io
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from rosbags.rosbag1 import Writer
from rosbags.rosbag1.reader import Header, ReaderError, RecordType, read_bytes, read_uint32

MAGIC = b"#ROSBAG V2.0\n"


@dataclass(frozen=True)
class Salvage:
    """What the walk saved and what it lost."""

    messages: int
    """Messages saved."""
    chunks: int
    """Whole chunks read (a cut chunk's whole records are saved too)."""
    connections: int
    """Topics-with-type saved (ROS 1 connections)."""
    end_ns: int
    """Receive time of the last message saved (ns; 0 without any)."""
    saved_bytes: int
    """Bytes of the file up to the end of the last whole record."""
    file_bytes: int
    stopped: str
    """Why the walk stopped ('' where it reached the end of the file)."""

    @property
    def lost(self) -> str:
        """One line on what was lost ('' where nothing was)."""
        if not self.stopped:
            return ""
        return (
            f"the bag is cut or damaged at byte {self.saved_bytes} of {self.file_bytes} ({self.stopped}): "
            f"{self.messages} messages saved, up to t = {self.end_ns} ns; everything after that is lost"
        )


@dataclass
class _Connection:
    topic: str
    msgtype: str
    md5sum: str
    msgdef: str
    callerid: str | None
    latching: int | None


def salvage_ros1(source: Path, out: Path) -> Salvage:
    """Walk the records of the ROS 1 bag `source` and write every whole chunk's messages to a new bag `out`.

    Raises:
        ReaderError: `source` is not a ROS 1 bag of format 2.0, or nothing at all can be read.
    """
    size = source.stat().st_size
    connections: dict[int, _Connection] = {}
    messages: list[tuple[int, int, bytes]] = []  # (conn id, time ns, data)
    chunks = 0
    stopped = ""
    with source.open("rb") as f:
        if f.readline() != MAGIC:
            raise ReaderError("not a ROS 1 bag of format 2.0 (its first line is not #ROSBAG V2.0)")
        saved = f.tell()
        while saved < size:
            try:
                header = Header.read(f)
                declared = read_uint32(f)
                data = f.read(declared)
                op = header.get_uint8("op")
                if op == RecordType.CHUNK:
                    whole = len(data) == declared
                    inner = _chunk_records(header, data, whole)
                    found_conns, found_msgs, consumed = _contents(inner)
                    connections.update(found_conns)
                    messages += found_msgs
                    if not whole or consumed < len(inner):
                        saved = f.tell() - len(data) + (consumed if not whole else 0)
                        stopped = f"a chunk of {declared} bytes cut after {len(data)}"
                        break
                    chunks += 1
                elif len(data) != declared:
                    raise ReaderError(f"a record of {declared} bytes cut after {len(data)}")
                elif op == RecordType.CONNECTION:
                    conn_id, conn = _connection(header, data)
                    connections.setdefault(conn_id, conn)
            except (ReaderError, struct.error, OSError, ValueError, KeyError, EOFError) as exc:
                stopped = f"{type(exc).__name__}: {exc}"
                break
            saved = f.tell()
    if not messages:
        raise ReaderError(f"no whole chunk with messages before byte {saved} of {size} ({stopped or 'no messages'})")
    _write(out, connections, messages)
    return Salvage(
        len(messages), chunks, len({c for c, _, _ in messages}), max(t for _, t, _ in messages), saved, size, stopped
    )


def _record(f: BinaryIO) -> tuple[Header, bytes]:
    header = Header.read(f)
    data = read_bytes(f, read_uint32(f))
    return header, data


def _chunk_records(header: Header, data: bytes, whole: bool) -> bytes:
    """The records of a chunk; of a cut chunk, the bytes there are where it is uncompressed (the walk keeps its
    whole records), else none."""
    compression = header.get_string("compression")
    expected = header.get_uint32("size")
    if not whole:
        if compression != "none":
            raise ReaderError(f"a {compression} chunk cut after {len(data)} bytes cannot be decompressed")
        return data
    if compression == "none":
        raw = data
    elif compression == "bz2":
        raw = bz2.decompress(data)
    elif compression == "lz4":
        import lz4.frame

        raw = lz4.frame.decompress(data)
    else:
        raise ReaderError(f"a chunk compressed with {compression!r} (none, bz2, lz4 are known)")
    if len(raw) != expected:
        raise ReaderError(f"a chunk of {len(raw)} bytes where its header says {expected}")
    return raw


def _contents(raw: bytes) -> tuple[dict[int, _Connection], list[tuple[int, int, bytes]], int]:
    """The connections and messages of a chunk's whole records, and the bytes those records take."""
    conns: dict[int, _Connection] = {}
    msgs: list[tuple[int, int, bytes]] = []
    f = io.BytesIO(raw)
    while f.tell() < len(raw):
        start = f.tell()
        try:
            header, data = _record(f)
        except (ReaderError, struct.error):
            return conns, msgs, start
        op = header.get_uint8("op")
        if op == RecordType.CONNECTION:
            conn_id, conn = _connection(header, data)
            conns[conn_id] = conn
        elif op == RecordType.MSGDATA:
            msgs.append((header.get_uint32("conn"), header.get_time("time"), data))
    return conns, msgs, f.tell()


def _connection(header: Header, data: bytes) -> tuple[int, _Connection]:
    conn_id = header.get_uint32("conn")
    inner = Header.read(io.BytesIO(len(data).to_bytes(4, "little") + data))
    latching = inner.get_string("latching") if "latching" in inner else None
    return conn_id, _Connection(
        inner.get_string("topic") if "topic" in inner else header.get_string("topic"),
        inner.get_string("type"),
        inner.get_string("md5sum"),
        inner.get_string("message_definition"),
        inner.get_string("callerid") if "callerid" in inner else None,
        int(latching) if latching not in (None, "") else None,
    )


def _write(out: Path, connections: dict[int, _Connection], messages: list[tuple[int, int, bytes]]) -> None:
    writer = Writer(out)
    writer.open()
    try:
        made = {}
        for conn_id in sorted({c for c, _, _ in messages}):
            conn = connections.get(conn_id)
            if conn is None:  # its connection record was in a lost part
                continue
            package, _, name = conn.msgtype.partition("/")
            made[conn_id] = writer.add_connection(
                conn.topic,
                f"{package}/msg/{name}",
                msgdef=conn.msgdef,
                md5sum=conn.md5sum,
                callerid=conn.callerid,
                latching=conn.latching,
            )
        for conn_id, t_ns, data in messages:
            if conn_id in made:
                writer.write(made[conn_id], t_ns, data)
    finally:
        writer.close()
