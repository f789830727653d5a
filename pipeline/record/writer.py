"""The session recorder: every message of a session into one MCAP file in the ROS 2 profile.

Profile ``ros2``, schemas ``ros2msg`` (the definition text of ``schemas/`` with its dependencies,
as rosbag2 stores it), messages ``cdr``, zstd-compressed chunks, channel metadata
``offered_qos_profiles``. Times are integer nanoseconds; ``log_time_ns`` is the recorder's clock
(Unix epoch on robots and the twin at 1x, simulated time in sim), ``publish_time_ns`` the sender's.

Crash behaviour. Each chunk goes to the operating system the moment it is sealed (no user-space
buffer), so a recorder that crashes or is killed (SIGKILL, the OOM killer) leaves every sealed
chunk in the file: :class:`pipeline.record.reader.McapLog` salvages them. A chunk is sealed when it
holds ``chunk_size`` bytes, on :meth:`McapRecorder.flush` and on :meth:`McapRecorder.close`.

Interrupts. Every change of the recorder's state is a single step (one list append, one attribute
assignment, or a write of deterministic bytes at a fixed offset that can be repeated), so an
exception raised by a signal handler at any point of :meth:`McapRecorder.write` leaves a state
that :meth:`McapRecorder.close` turns into a complete, indexed file. Use it like this::

    signal.signal(signal.SIGTERM, signal.default_int_handler)  # SIGTERM raises KeyboardInterrupt too
    with McapRecorder(path, topics) as recorder:                 # __exit__ closes on any exception
        while running:
            recorder.write("/robot_1/odom", msg, now_ns)

Calling :meth:`McapRecorder.close` from inside a signal handler (which then exits or returns) is
safe as well: the interrupted write finds the recorder closed and writes nothing more.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import struct
import threading
import weakref
import zlib
from collections.abc import Callable, Iterable, Iterator, Mapping
from importlib import metadata as importlib_metadata
from pathlib import Path
from types import TracebackType
from typing import Any

import zstandard
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from pipeline.messages.errors import MessageError
from pipeline.messages.store import MessageStore, message_store
from pipeline.messages.topics import TopicSpec
from pipeline.record import format as fmt
from pipeline.record.errors import RecordError

DEFAULT_CHUNK_SIZE = 1024 * 1024
"""Uncompressed bytes of records after which a chunk is sealed (and becomes crash-safe)."""
_U32 = 0xFFFFFFFF
_MESSAGE = int(Opcode.MESSAGE)
_MESSAGE_FIXED = fmt.MESSAGE_FIXED
_MESSAGE_HEAD_SIZE = fmt.MESSAGE_HEAD.size
_pack_message_head = fmt.MESSAGE_HEAD.pack


def _distribution_version(name: str) -> str:
    try:
        return importlib_metadata.version(name)
    except importlib_metadata.PackageNotFoundError:
        return "unknown"


LIBRARY = f"multirobot-sim2real/{_distribution_version('multirobot-sim2real')}"
"""The Header's library string: the project and its version."""


def versions_metadata(
    distributions: Iterable[str] = ("multirobot-sim2real", "mcap", "rosbags", "zstandard", "numpy"),
) -> dict[str, str]:
    """Installed versions of `distributions` plus Python's, for a ``versions`` metadata record."""
    import platform

    out = {"python": platform.python_version()}
    out.update({name: _distribution_version(name) for name in distributions})
    return out


@dataclasses.dataclass(frozen=True)
class _Committed:
    """What is final in the file: the bytes up to `offset` and everything the summary will list."""

    offset: int
    data_crc: int
    chunk_indexes: tuple[ChunkIndex, ...] = ()
    metadata_indexes: tuple[MetadataIndex, ...] = ()
    schemas: tuple[Schema, ...] = ()
    channels: tuple[Channel, ...] = ()
    channel_counts: tuple[tuple[int, int], ...] = ()
    message_count: int = 0
    start_ns: int = 0
    end_ns: int = 0


class _State:
    """The committed file plus the open chunk: (channel id, log time ns, record head, payload) items.

    A message item's payload is its CDR bytes; a definition item has channel id 0, its Schema
    (or None when the schema is already in the file) and Channel records as payload, and their
    encoded bytes as head.
    """

    __slots__ = ("committed", "items", "size")

    def __init__(self, committed: _Committed) -> None:
        self.committed = committed
        self.items: list[tuple[int, int, bytes, Any]] = []
        self.size = 0


class _Closed(Exception):
    """The file was completed by close(); nothing more may be written."""


class McapRecorder:
    """One MCAP file per session; channels are created on the first message of each topic.

    Args:
        path: the file to create (its folder is created); an existing file is refused unless
            `overwrite`.
        topics: the topic table, ``{ROS topic name: TopicSpec}`` (e.g. ``fleet_topics(...)``);
            topics outside it can still be written by passing their TopicSpec.
        store: message definitions and CDR; the repository's ``schemas/`` by default.
        chunk_size: uncompressed bytes per chunk (> 0); smaller chunks lose less on a kill.
        metadata: metadata records written at once, ``{name: {key: value}}`` (strings only).
        compression_level: zstd level of the chunks.
        library: the Header's library string.
        overwrite: replace an existing file at `path`.

    Thread-safe: writes from several threads (e.g. DDS listeners) are serialized by a lock.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        topics: Mapping[str, TopicSpec] | None = None,
        store: MessageStore | None = None,
        *,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        metadata: Mapping[str, Mapping[str, str]] | None = None,
        compression_level: int = 3,
        library: str = LIBRARY,
        overwrite: bool = False,
    ) -> None:
        self.path = Path(path)
        where = str(self.path)
        if not isinstance(chunk_size, int) or chunk_size <= 0:
            raise RecordError(where, f"chunk_size must be a positive number of bytes, got {chunk_size!r}")
        self._store = store if store is not None else message_store()
        self._table: dict[str, TopicSpec] = dict(topics or {})
        for name, spec in self._table.items():
            if name != spec.name:
                raise RecordError(where, f"topic table key {name!r} differs from its TopicSpec name {spec.name!r}")
        self._chunk_size = chunk_size
        self._compressor = zstandard.ZstdCompressor(level=compression_level)
        self._lock = threading.RLock()
        # topic name -> (channel id, typename, sequence counter); a cache of the registered channels
        self._slots: dict[str, tuple[int, str, Iterator[int]]] = {}
        self._specs: dict[str, TopicSpec] = {}
        self._schema_ids: dict[str, int] = {}
        self._next_channel_id = itertools.count(1)
        self._next_schema_id = itertools.count(1)
        self._metadata_names: set[str] = set()
        self.taps: list[Callable[[str, str, bytes, int], None]] = []
        """Called with (topic, typename, CDR bytes, log time ns) after each message is recorded (e.g. a live view)."""
        for name, mapping in (metadata or {}).items():
            self._check_metadata(name, mapping)
        fd = self._create(overwrite)
        self._fd: int | None = fd  # None once the file is complete (or abandoned after an I/O error)
        self._finalizer = weakref.finalize(self, os.close, fd)
        head = fmt.MAGIC + fmt.encode(Header(profile=fmt.PROFILE, library=library))
        self._state = _State(_Committed(offset=0, data_crc=0))
        try:
            self._commit(head, self._state.committed.offset)
            self._state = _State(_Committed(offset=len(head), data_crc=zlib.crc32(head)))
            for name, mapping in (metadata or {}).items():
                self.add_metadata(name, mapping)
        except BaseException:
            self._release()
            raise

    # -- file --------------------------------------------------------------------------------

    def _create(self, overwrite: bool) -> int:
        where = str(self.path)
        if self.path.is_dir():
            raise RecordError(where, "is a folder; give the path of a file to create, e.g. logs/session.mcap")
        if self.path.exists() and not overwrite:
            raise RecordError(where, "already exists; refusing to replace a recording (pass overwrite=True)")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RecordError(where, f"cannot create its folder {self.path.parent}: {exc.strerror}") from exc
        flags = os.O_WRONLY | os.O_CREAT | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
        flags |= os.O_TRUNC if overwrite else os.O_EXCL
        try:
            return os.open(self.path, flags, 0o644)
        except FileExistsError as exc:
            raise RecordError(where, "already exists; refusing to replace a recording (pass overwrite=True)") from exc
        except OSError as exc:
            raise RecordError(where, f"cannot create the file for writing: {exc.strerror}") from exc

    def _put(self, blob: bytes, offset: int) -> None:
        """Write `blob` at `offset`; the same bytes at the same offset may be written twice."""
        view = memoryview(blob)
        done = 0
        while done < len(view):
            fd = self._fd
            if fd is None:
                raise _Closed
            done += os.pwrite(fd, view[done:], offset + done)

    def _commit(self, blob: bytes, offset: int) -> None:
        try:
            self._put(blob, offset)
        except OSError as exc:
            raise RecordError(
                str(self.path), f"writing {len(blob)} bytes at byte {offset} failed: {exc.strerror}"
            ) from exc

    # -- writing -----------------------------------------------------------------------------

    def write(self, topic: str | TopicSpec, msg: Any, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """Record `msg` (a message of the store) on `topic` at `log_time_ns` (publish time defaults to it)."""
        name = topic if isinstance(topic, str) else topic.name
        slot = self._slots.get(name)
        if slot is None:
            slot = self._register(topic)
        typename = slot[1]
        if getattr(msg, "__msgtype__", None) != typename:
            got = getattr(msg, "__msgtype__", type(msg).__name__)
            raise RecordError(str(self.path), f"topic {name} carries {typename}, got a {got}")
        try:
            data = self._store.serialize(msg, typename)
        except MessageError as exc:
            raise RecordError(str(self.path), f"topic {name}: {exc}") from exc
        self.write_cdr(name, data, log_time_ns, publish_time_ns)

    def write_cdr(
        self, topic: str | TopicSpec, data: bytes, log_time_ns: int, publish_time_ns: int | None = None
    ) -> None:
        """Record pre-serialized CDR `data` (with its 4-byte encapsulation header) on `topic`."""
        name = topic if isinstance(topic, str) else topic.name
        slot = self._slots.get(name)
        if slot is None:
            slot = self._register(topic)
        if type(data) is not bytes:
            data = bytes(data)  # a caller's bytearray or memoryview may change before the chunk is sealed
        channel_id, _, sequence = slot
        with self._lock:
            state = self._state
            if self._fd is None:
                raise RecordError(str(self.path), f"topic {name}: the recording is closed")
            try:
                head = _pack_message_head(
                    _MESSAGE,
                    _MESSAGE_FIXED + len(data),
                    channel_id,
                    next(sequence) & _U32,
                    log_time_ns,
                    log_time_ns if publish_time_ns is None else publish_time_ns,
                )
            except struct.error as exc:
                raise RecordError(
                    str(self.path),
                    f"topic {name}: log_time_ns and publish_time_ns must be integers in [0, 2**64), "
                    f"got {log_time_ns!r} and {publish_time_ns!r}",
                ) from exc
            state.items.append((channel_id, log_time_ns, head, data))  # the one step that records it
            state.size += _MESSAGE_HEAD_SIZE + len(data)
            if state.size >= self._chunk_size:
                self._seal_or_fail(state)
        for tap in self.taps:
            tap(name, slot[1], data, log_time_ns)

    def _spec(self, topic: str | TopicSpec) -> TopicSpec:
        where = str(self.path)
        if isinstance(topic, TopicSpec):
            listed = self._table.get(topic.name, topic)
            if listed != topic:
                raise RecordError(where, f"topic {topic.name}: {topic} conflicts with the topic table's {listed}")
            return topic
        if not isinstance(topic, str):
            raise RecordError(where, f"a topic is a name or a TopicSpec, got {type(topic).__name__}")
        spec = self._table.get(topic)
        if spec is None:
            known = ", ".join(sorted(self._table)) or "none"
            raise RecordError(
                where, f"unknown topic {topic!r}; the topic table has: {known} (pass a TopicSpec to record another)"
            )
        return spec

    def _register(self, topic: str | TopicSpec) -> tuple[int, str, Iterator[int]]:
        """Queue the Schema (first use of the type) and Channel records of a new topic into the open chunk."""
        spec = self._spec(topic)
        where = str(self.path)
        with self._lock:
            if spec.name in self._slots:  # registered by another thread meanwhile
                known = self._specs[spec.name]
                if known != spec:
                    raise RecordError(where, f"topic {spec.name}: {spec} conflicts with the recorded {known}")
                return self._slots[spec.name]
            if self._fd is None:
                raise RecordError(where, f"topic {spec.name}: the recording is closed")
            try:
                msgdef = self._store.msgdef(spec.typename)
            except MessageError as exc:
                raise RecordError(where, f"topic {spec.name}: {exc}") from exc
            schema_id = self._schema_ids.get(spec.typename)
            schema = None
            if schema_id is None:
                schema_id = next(self._next_schema_id)
                schema = Schema(
                    id=schema_id, name=spec.typename, encoding=fmt.SCHEMA_ENCODING, data=msgdef.encode("utf-8")
                )
            channel = Channel(
                id=next(self._next_channel_id),
                topic=spec.name,
                message_encoding=fmt.MESSAGE_ENCODING,
                schema_id=schema_id,
                metadata={fmt.QOS_KEY: spec.qos.rosbag2_yaml()},
            )
            records = (fmt.encode(schema) if schema is not None else b"") + fmt.encode(channel)
            state = self._state
            state.items.append((0, 0, records, (schema, channel)))
            state.size += len(records)
            self._schema_ids[spec.typename] = schema_id
            slot = (channel.id, spec.typename, itertools.count())
            self._specs[spec.name] = spec
            self._slots[spec.name] = slot
            return slot

    def add_metadata(self, name: str, mapping: Mapping[str, str]) -> None:
        """Write a metadata record `name` (unique in the file) of string keys and values now."""
        where = str(self.path)
        self._check_metadata(name, mapping)
        with self._lock:
            if self._fd is None:
                raise RecordError(where, f"metadata {name!r}: the recording is closed")
            if name in self._metadata_names:
                raise RecordError(where, f"metadata {name!r} was already written; names are unique in a recording")
            state = self._state
            done = state.committed
            blob = fmt.encode(Metadata(name=name, metadata=dict(mapping)))
            index = MetadataIndex(offset=done.offset, length=len(blob), name=name)
            committed = dataclasses.replace(
                done,
                offset=done.offset + len(blob),
                data_crc=zlib.crc32(blob, done.data_crc),
                metadata_indexes=(*done.metadata_indexes, index),
            )
            self._write_or_fail(blob, done.offset)
            moved = _State(committed)
            moved.items, moved.size = state.items, state.size
            self._state = moved
            self._metadata_names.add(name)

    def _check_metadata(self, name: str, mapping: Mapping[str, str]) -> None:
        where = str(self.path)
        if not isinstance(name, str) or not name:
            raise RecordError(where, f"a metadata name is a non-empty string, got {name!r}")
        if not isinstance(mapping, Mapping):
            raise RecordError(where, f"metadata {name!r} must be a mapping of strings, got {type(mapping).__name__}")
        bad = [(k, v) for k, v in mapping.items() if not (isinstance(k, str) and isinstance(v, str))]
        if bad:
            k, v = bad[0]
            raise RecordError(where, f"metadata {name!r}: keys and values must be strings, got {k!r}: {v!r}")

    def flush(self) -> None:
        """Seal the open chunk now so that everything written so far survives a kill."""
        with self._lock:
            if self._fd is None:
                raise RecordError(str(self.path), "the recording is closed")
            self._seal_or_fail(self._state)

    def _write_or_fail(self, blob: bytes, offset: int) -> None:
        try:
            self._commit(blob, offset)
        except _Closed:
            raise RecordError(str(self.path), "the recording was closed meanwhile") from None

    def _seal_or_fail(self, state: _State) -> None:
        try:
            self._seal(state)
        except _Closed:
            raise RecordError(str(self.path), "the recording was closed meanwhile") from None

    def _seal(self, state: _State) -> None:
        """Write the open chunk and its message indexes, then commit them in one assignment."""
        if not state.items:
            return
        blob, committed = self._encode_chunk(state)
        self._commit(blob, state.committed.offset)
        self._state = _State(committed)

    def _encode_chunk(self, state: _State) -> tuple[bytes, _Committed]:
        """The Chunk + Message Index bytes of the open chunk and the committed state after them (pure)."""
        done = state.committed
        parts: list[bytes] = []
        index: dict[int, list[int]] = {}
        schemas = list(done.schemas)
        channels = list(done.channels)
        counts = dict(done.channel_counts)
        pos = 0
        add = parts.append
        for channel_id, log_time_ns, head, payload in state.items:
            if channel_id:
                entries = index.get(channel_id)
                if entries is None:
                    entries = index[channel_id] = []
                entries += (log_time_ns, pos)
                add(head)
                add(payload)
                pos += _MESSAGE_HEAD_SIZE + len(payload)
                continue
            schema, channel = payload
            if schema is not None:
                schemas.append(schema)
            channels.append(channel)
            counts.setdefault(channel.id, 0)
            add(head)
            pos += len(head)
        times = [item[1] for item in state.items if item[0]]
        n = len(times)
        start_ns, end_ns = (min(times), max(times)) if times else (-1, -1)
        for channel_id, entries in index.items():
            counts[channel_id] = counts.get(channel_id, 0) + len(entries) // 2
        records = b"".join(parts)
        chunk_start = max(start_ns, 0)
        chunk_end = max(end_ns, 0)
        compressed = self._compressor.compress(records)
        chunk_blob = fmt.chunk(chunk_start, chunk_end, records, zlib.crc32(records), "zstd", compressed)
        offsets: dict[int, int] = {}
        index_parts: list[bytes] = []
        at = done.offset + len(chunk_blob)
        for channel_id, entries in index.items():
            offsets[channel_id] = at
            record = fmt.message_index(channel_id, entries)
            index_parts.append(record)
            at += len(record)
        index_blob = b"".join(index_parts)
        blob = chunk_blob + index_blob
        chunk_index = ChunkIndex(
            message_start_time=chunk_start,
            message_end_time=chunk_end,
            chunk_start_offset=done.offset,
            chunk_length=len(chunk_blob),
            message_index_offsets=offsets,
            message_index_length=len(index_blob),
            compression="zstd",
            compressed_size=len(compressed),
            uncompressed_size=len(records),
        )
        if n and done.message_count:
            start_ns, end_ns = min(start_ns, done.start_ns), max(end_ns, done.end_ns)
        elif not n:
            start_ns, end_ns = done.start_ns, done.end_ns
        committed = _Committed(
            offset=done.offset + len(blob),
            data_crc=zlib.crc32(blob, done.data_crc),
            chunk_indexes=(*done.chunk_indexes, chunk_index),
            metadata_indexes=done.metadata_indexes,
            schemas=tuple(schemas),
            channels=tuple(channels),
            channel_counts=tuple(counts.items()),
            message_count=done.message_count + n,
            start_ns=start_ns,
            end_ns=end_ns,
        )
        return blob, committed

    # -- closing -----------------------------------------------------------------------------

    def _tail(self, done: _Committed) -> bytes:
        """DataEnd, summary, summary offsets, footer and closing magic for the committed state (pure)."""
        data_end = fmt.encode(DataEnd(data_section_crc=done.data_crc))
        summary_start = done.offset + len(data_end)
        groups: list[tuple[Opcode, bytes]] = [
            (Opcode.SCHEMA, b"".join(fmt.encode(s) for s in done.schemas)),
            (Opcode.CHANNEL, b"".join(fmt.encode(c) for c in done.channels)),
            (
                Opcode.STATISTICS,
                fmt.encode(
                    Statistics(
                        attachment_count=0,
                        channel_count=len(done.channels),
                        channel_message_counts=dict(done.channel_counts),
                        chunk_count=len(done.chunk_indexes),
                        message_count=done.message_count,
                        message_end_time=done.end_ns,
                        message_start_time=done.start_ns,
                        metadata_count=len(done.metadata_indexes),
                        schema_count=len(done.schemas),
                    )
                ),
            ),
            (Opcode.CHUNK_INDEX, b"".join(fmt.encode(c) for c in done.chunk_indexes)),
            (Opcode.METADATA_INDEX, b"".join(fmt.encode(m) for m in done.metadata_indexes)),
        ]
        summary = b"".join(group for _, group in groups)
        offsets: list[bytes] = []
        at = summary_start
        for opcode, group in groups:
            if group:
                offsets.append(fmt.encode(SummaryOffset(group_opcode=opcode, group_start=at, group_length=len(group))))
                at += len(group)
        summary_offsets = b"".join(offsets)
        summary_offset_start = summary_start + len(summary)
        footer_fields = struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start)
        crc = zlib.crc32(footer_fields, zlib.crc32(summary_offsets, zlib.crc32(summary)))
        footer = fmt.encode(
            Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc)
        )
        return data_end + summary + summary_offsets + footer + fmt.MAGIC

    def close(self) -> None:
        """Seal the open chunk, write the summary and footer, and close the file (idempotent).

        Safe after an exception raised anywhere inside write() (e.g. KeyboardInterrupt), and from
        a signal handler that interrupted a write(). A second call does nothing.
        """
        with self._lock:
            if self.closed:  # (the property: the descriptor is tested again below, after calls)
                return
            try:
                self._seal(self._state)
                done = self._state.committed
                tail = self._tail(done)
                end = done.offset + len(tail)
                self._commit(tail, done.offset)
                # A close() run by a signal handler meanwhile has released the descriptor: read it again
                # right before each call (Python runs handlers after calls and on backward jumps, never
                # between such a test and the call that follows it).
                fd = self._fd
                if fd is None:
                    return
                os.ftruncate(fd, end)
                fd = self._fd
                if fd is None:
                    return
                os.fsync(fd)
            except _Closed:
                return  # completed by a close() that interrupted this one
            except OSError as exc:
                self._release()
                raise RecordError(str(self.path), f"cannot finish the file: {exc.strerror}") from exc
            except RecordError:
                self._release()
                raise
            self._release()

    def _release(self) -> None:
        """Mark the recording closed, then close the descriptor (once)."""
        self._fd = None
        self._finalizer()

    @property
    def closed(self) -> bool:
        return self._fd is None

    @property
    def message_count(self) -> int:
        """Messages written so far (sealed chunks plus the open one)."""
        state = self._state
        return state.committed.message_count + sum(1 for item in state.items if item[0])

    @property
    def topics(self) -> dict[str, str]:
        """Topics recorded so far and their message types."""
        return {name: slot[1] for name, slot in self._slots.items()}

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._fd is None else "open"
        return f"McapRecorder({str(self.path)!r}, {state}, {self.message_count} messages)"
