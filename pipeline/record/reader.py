"""Reading session recordings: topics, metadata, and messages in log-time order, decoded or raw.

A complete file is read through its summary (chunk indexes, statistics). A file without a
summary, as a killed recorder leaves it, is read record by record in file order up to its last
complete chunk: mcap's indexed reader refuses such a file and its time-ordered stream reader
yields nothing, so :class:`McapLog` salvages what is there, says so with a
:class:`~pipeline.record.errors.TruncatedLogWarning`, and sets :attr:`McapLog.salvaged`.

Damage inside a file (a chunk that fails its CRC-32, a record whose length field is garbage) costs
only the records it hits: on opening, every chunk is checked (decompressed and CRC-checked, unless
``validate_crcs=False``), damaged ones are left out, and :attr:`McapLog.lost` lists the byte ranges
lost with the reason, announced by a :class:`~pipeline.record.errors.DamagedLogWarning`. Reading in
file order, a chunk is delimited by its own fields (which its CRC vouches for) rather than by its
record length, and after a record that cannot be read, reading resumes where its length points
when a record plausibly starts there, or else at the next chunk that passes its checks.

Messages decode with the repository's message store when the file's schema text equals the
store's definition (every file the pipeline writes); other files (e.g. ``ros2 bag record -s mcap``
on robots, whose schemas keep their comments) decode with types built from the schemas stored in
the file, so their message classes differ from the store's but carry the same fields.
"""

from __future__ import annotations

import bisect
import contextlib
import mmap
import os
import struct
import warnings
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import IO, Any, NamedTuple

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Header, Metadata, Schema
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline.messages.errors import MessageError
from pipeline.messages.store import MessageStore, message_store
from pipeline.record import format as fmt
from pipeline.record.errors import (
    DamagedLogWarning,
    LogDecodeError,
    LogFormatError,
    LogReadError,
    TruncatedLogWarning,
    UndecodableMessageWarning,
)

_PARSE_ERRORS = (McapError, struct.error, ValueError, EOFError, UnicodeDecodeError, IndexError, KeyError, OSError)
"""What mcap's record parsers raise on bytes that are cut short or are not MCAP."""


class LogMessage(NamedTuple):
    """One decoded message; times are nanoseconds on the recorder's clock (log) and the sender's (publish)."""

    topic: str
    typename: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    msg: Any


class RawMessage(NamedTuple):
    """One message as stored: `data` is its CDR bytes, 4-byte encapsulation header included."""

    topic: str
    typename: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes


@dataclass(frozen=True)
class _Channel:
    id: int
    topic: str
    typename: str
    schema_text: str
    metadata: dict[str, str]


@dataclass(frozen=True)
class _Segment:
    """A chunk at byte `offset` (or, with `loose`, unchunked messages held in memory)."""

    offset: int
    start_ns: int
    end_ns: int
    channel_ids: frozenset[int] | None  # None: not indexed
    length: int = 0  # bytes of the chunk record, prefix included (0 for loose messages)
    loose: tuple[tuple[int, int, int, int, bytes], ...] = field(default=(), repr=False)  # (id, seq, log, pub, data)


_Item = tuple[int, int, int, int, int, int, bytes]
"""(log time ns, segment rank, position, channel id, sequence, publish time ns, CDR data)."""


def _inflate(compression: str, data: bytes, size: int, crc: int, validate: bool) -> bytes:
    """The uncompressed records of a chunk; ValueError when they are damaged."""
    if compression == "zstd":
        try:
            claimed = zstandard.frame_content_size(data)
            if claimed > size:  # -1: not stated; a garbled frame header must not allocate gigabytes
                raise ValueError(f"zstd frame claims {claimed} bytes, the chunk header says {size}")
            records = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        except zstandard.ZstdError as exc:
            raise ValueError(f"zstd data do not decompress: {exc}") from exc
    elif compression == "lz4":
        try:
            import lz4.frame
        except ImportError as exc:
            raise ValueError("chunk is lz4-compressed and the lz4 package is not installed") from exc
        records = lz4.frame.decompress(data)
    elif compression == "":
        records = data
    else:
        raise ValueError(f"unknown chunk compression {compression!r} (known: zstd, lz4, none)")
    if len(records) != size:
        raise ValueError(f"chunk holds {len(records)} bytes of records, its header says {size}")
    if validate and crc and zlib.crc32(records) != crc:
        raise ValueError("chunk records fail their CRC-32 check")
    return bytes(records)


def _records(buf: bytes) -> Iterator[tuple[int, int, int]]:
    """(opcode, body start, body end) of each record in the uncompressed records of a chunk."""
    pos = 0
    n = len(buf)
    while pos < n:
        if pos + fmt.RECORD_PREFIX.size > n:
            raise ValueError(f"record at {pos} of the chunk is cut short")
        op, length = fmt.RECORD_PREFIX.unpack_from(buf, pos)
        body = pos + fmt.RECORD_PREFIX.size
        if body + length > n:
            raise ValueError(f"record at {pos} of the chunk claims {length} bytes, {n - body} remain")
        yield op, body, body + length
        pos = body + length


_Buffer = bytes | mmap.mmap
"""A whole file (mapped) or one record read from it."""


def _parse(reader: Callable[[ReadDataStream], Any], buf: _Buffer, start: int, end: int) -> Any:
    return reader(ReadDataStream(BytesIO(buf[start:end])))


class LostRange(NamedTuple):
    """Bytes ``[start_offset, end_offset)`` of a recording whose records could not be read, and why."""

    start_offset: int
    end_offset: int
    reason: str


class _ChunkView(NamedTuple):
    """The fields of a Chunk record in a buffer; its compressed data are ``buf[data_start:end]``."""

    start_ns: int
    end_ns: int
    size: int
    crc: int
    compression: str
    data_start: int
    end: int


_MAX_COMPRESSION_NAME = 16
_MAX_CHUNK_SIZE = 1 << 32
"""Largest uncompressed chunk accepted (mcap's record size limit): a garbled size must not allocate more."""
_FRAMEABLE = frozenset(int(op) for op in Opcode) - {Opcode.HEADER}
"""Opcodes a record after the Header may have (besides private ones, 0x80 and up)."""


def _chunk_view(buf: _Buffer, pos: int, limit: int) -> _ChunkView:
    """The Chunk record at byte `pos` of `buf` by its own fields, which end by `limit`; ValueError if they do not fit.

    The record's length field is not used: the fields say where the data end.
    """
    at = pos + fmt.RECORD_PREFIX.size
    if at + fmt.CHUNK_FIELDS.size + 4 > limit:
        raise ValueError("its header is cut short")
    start_ns, end_ns, size, crc = fmt.CHUNK_FIELDS.unpack_from(buf, at)
    at += fmt.CHUNK_FIELDS.size
    (name_len,) = struct.unpack_from("<I", buf, at)
    at += 4
    if name_len > _MAX_COMPRESSION_NAME or at + name_len + 8 > limit:
        raise ValueError(f"its compression name claims {name_len} bytes")
    compression = bytes(buf[at : at + name_len]).decode("utf-8")
    at += name_len
    (data_len,) = struct.unpack_from("<Q", buf, at)
    at += 8
    if at + data_len > limit:
        raise ValueError(f"its data claim {data_len} bytes, {limit - at} remain")
    if size > _MAX_CHUNK_SIZE:
        raise ValueError(f"it claims {size} bytes of records, more than {_MAX_CHUNK_SIZE}")
    return _ChunkView(start_ns, end_ns, size, crc, compression, at, at + data_len)


def _chunk_records(buf: _Buffer, view: _ChunkView, validate: bool) -> bytes:
    """The uncompressed records of the chunk `view` of `buf`; ValueError when they are damaged."""
    records = _inflate(view.compression, bytes(buf[view.data_start : view.end]), view.size, view.crc, validate)
    if validate and not view.crc:  # no CRC vouches for the records: their framing must hold at least
        for _ in _records(records):
            pass
    return records


def _frames(buf: _Buffer, pos: int, size: int) -> bool:
    """Whether a record plausibly starts at byte `pos`: a known (or private) opcode and a length inside the file."""
    if pos + fmt.RECORD_PREFIX.size > size:
        return False
    op, length = fmt.RECORD_PREFIX.unpack_from(buf, pos)
    known = op in _FRAMEABLE or op >= 0x80
    return bool(known and pos + fmt.RECORD_PREFIX.size + length <= size)


def _is_chunk(buf: _Buffer, pos: int, size: int) -> bool:
    """Whether a whole chunk starts at byte `pos`: length field and fields agree, records pass their checks."""
    try:
        (length,) = struct.unpack_from("<Q", buf, pos + 1)
        end = pos + fmt.RECORD_PREFIX.size + length
        if end > size:
            return False
        view = _chunk_view(buf, pos, end)
        if view.end != end:
            return False
        _chunk_records(buf, view, True)
    except (struct.error, ValueError):
        return False
    return True


def _next_chunk(buf: _Buffer, start: int, limit: int, size: int) -> int | None:
    """The first byte in ``[start, limit)`` where a whole chunk starts (see `_is_chunk`), or None."""
    pos = buf.find(bytes((Opcode.CHUNK,)), start, limit)
    while pos != -1:
        if _is_chunk(buf, pos, size):
            return pos
        pos = buf.find(bytes((Opcode.CHUNK,)), pos + 1, limit)
    return None


def _resume(buf: _Buffer, pos: int, size: int) -> int | None:
    """Where reading goes on after the unreadable record at byte `pos`; None when nothing readable follows.

    The end its length field (or, for a chunk, its fields) gives is taken when a record plausibly
    starts there, unless a whole chunk starts before it; else the next whole chunk.
    """
    ends: set[int] = set()
    if pos + fmt.RECORD_PREFIX.size <= size:
        op, length = fmt.RECORD_PREFIX.unpack_from(buf, pos)
        ends.add(pos + fmt.RECORD_PREFIX.size + length)
        if op == Opcode.CHUNK:
            with contextlib.suppress(struct.error, ValueError):
                ends.add(_chunk_view(buf, pos, size).end)
    for end in sorted(e for e in ends if pos < e <= size):
        if end == size or _frames(buf, end, size):
            found = _next_chunk(buf, pos + 1, end, size)
            return end if found is None else found
    return _next_chunk(buf, pos + 1, size, size)


def _ends_data(buf: _Buffer, pos: int, size: int) -> bool:
    """Whether a whole DataEnd or Footer record (which end the data section) starts at byte `pos`."""
    if pos + fmt.RECORD_PREFIX.size > size:
        return False
    op, length = fmt.RECORD_PREFIX.unpack_from(buf, pos)
    whole: bool = {Opcode.DATA_END: 4, Opcode.FOOTER: 20}.get(op) == length
    return whole and pos + fmt.RECORD_PREFIX.size + length <= size


_RECORD_NAMES = {int(op): op.name.replace("_", " ").title().replace(" ", "") for op in Opcode}


def _record_name(op: int) -> str:
    name = _RECORD_NAMES.get(op)
    return f"{name} record" if name else f"record with unknown opcode {op:#04x}"


@dataclass
class _Scan:
    """What reading a file in order has found so far."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)
    loose: list[tuple[int, int, int, int, bytes]] = field(default_factory=list)
    loose_at: int = 0
    chunks: int = 0


class McapLog:
    """A recording opened for reading; cheap to open, iterators read the file on demand.

    Args:
        path: an MCAP file (ROS 2 profile: cdr messages, ros2msg schemas).
        store: the message store used to decode the pipeline's own types.
        validate_crcs: check the summary's CRC-32 (a damaged summary is not trusted: the file is
            read in order) and each chunk (decompressed, CRC-32 checked) on opening, leaving damaged
            ones out (see :attr:`lost`), and again when it is read. Without, opening checks only
            where the chunks are and reading a damaged chunk raises LogReadError.

    Raises:
        LogReadError: the path is missing, unreadable, empty, not MCAP, or damaged beyond salvage.
        LogFormatError: a channel's message encoding is not cdr or its schema is not ros2msg.
    """

    def __init__(
        self, path: str | os.PathLike[str], store: MessageStore | None = None, *, validate_crcs: bool = True
    ) -> None:
        self.path = Path(path)
        self._where = str(self.path)
        self._store = store if store is not None else message_store()
        self._validate = validate_crcs
        self._channels: dict[int, _Channel] = {}
        self._segments: list[_Segment] = []
        self._metadata: dict[str, dict[str, str]] = {}
        self._counts: dict[int, int] | None = None
        self._salvaged = False
        self._salvage_note = ""
        self._lost: list[LostRange] = []
        self._hidden: frozenset[int] = frozenset()  # channel ids used in the file whose definitions were lost
        self._decoders: dict[int, Callable[[bytes], Any]] = {}
        self._foreign: Any = None
        try:
            f = open(self.path, "rb")  # noqa: SIM115 (closed below, errors mapped first)
        except FileNotFoundError:
            raise LogReadError(self._where, "no such file") from None
        except IsADirectoryError:
            raise LogReadError(self._where, "is a folder, not an MCAP file") from None
        except OSError as exc:
            raise LogReadError(self._where, f"cannot open for reading: {exc.strerror}") from exc
        with f:
            self._open(f)
        self._check_channels()

    # -- opening -----------------------------------------------------------------------------

    def _open(self, f: IO[bytes]) -> None:
        size = os.fstat(f.fileno()).st_size
        if size == 0:
            raise LogReadError(self._where, "the file is empty (0 bytes), not an MCAP recording")
        head = f.read(len(fmt.MAGIC))
        if head != fmt.MAGIC:
            if len(head) < len(fmt.MAGIC) and fmt.MAGIC.startswith(head):
                raise LogReadError(self._where, f"the file is cut short inside the MCAP magic ({size} bytes)")
            raise LogReadError(
                self._where, f"not an MCAP file: it starts with {head!r}, MCAP files start with {fmt.MAGIC!r}"
            )
        self._header = self._read_header(f, size)
        problem = "the file ends without its summary and footer, it was cut short (its recorder was killed or crashed)"
        footer = self._has_footer(f, size)
        if footer:
            try:
                if self._validate:
                    self._check_summary_crc(f, size)
                f.seek(0)
                summary = SeekingReader(f, validate_crcs=False, record_size_limit=size).get_summary()
                if summary is not None and self._use_summary(f, summary, size):
                    return
                problem = ""  # complete but not indexed: read it in file order, nothing is missing
            except _PARSE_ERRORS as exc:
                problem = f"its summary section is damaged ({exc})"
            self._channels, self._segments, self._metadata, self._counts, self._lost = {}, [], {}, None, []
        self._scan(f, size, problem, footer)

    def _read_header(self, f: IO[bytes], size: int) -> Header:
        cut = LogReadError(self._where, f"the file is cut short inside its MCAP header ({size} bytes), no data")
        prefix = f.read(fmt.RECORD_PREFIX.size)
        if len(prefix) < fmt.RECORD_PREFIX.size:
            raise cut
        op, length = fmt.RECORD_PREFIX.unpack(prefix)
        if op != Opcode.HEADER:
            raise LogReadError(self._where, f"damaged MCAP file: opcode {op:#04x} where the Header record belongs")
        body = f.read(min(length, size))
        if len(body) < length:
            raise cut
        self._data_start = f.tell()
        try:
            header: Header = Header.read(ReadDataStream(BytesIO(body)))
        except _PARSE_ERRORS as exc:
            raise LogReadError(self._where, f"damaged MCAP header: {exc}") from exc
        return header

    @staticmethod
    def _has_footer(f: IO[bytes], size: int) -> bool:
        end = fmt.FOOTER_SIZE + len(fmt.MAGIC)
        if size < len(fmt.MAGIC) + end:
            return False
        f.seek(size - end)
        tail = f.read(end)
        return tail[-len(fmt.MAGIC) :] == fmt.MAGIC and tail[: fmt.RECORD_PREFIX.size] == fmt.RECORD_PREFIX.pack(
            Opcode.FOOTER, 20
        )

    @staticmethod
    def _check_summary_crc(f: IO[bytes], size: int) -> None:
        """ValueError when the summary section (and summary offsets) fail the CRC-32 the footer gives (0: none)."""
        fields_end = size - len(fmt.MAGIC) - 4  # the footer's CRC covers everything before itself
        f.seek(fields_end - 16)
        summary_start, _, crc = struct.unpack("<QQI", f.read(20))
        if not crc or not summary_start:
            return
        if not len(fmt.MAGIC) < summary_start < fields_end:
            raise ValueError(f"the footer puts it at byte {summary_start}, outside the file")
        f.seek(summary_start)
        if zlib.crc32(f.read(fields_end - summary_start)) != crc:
            raise ValueError("it fails its CRC-32 check")

    def _use_summary(self, f: IO[bytes], summary: Any, size: int) -> bool:
        """Take channels, chunks, counts and metadata from the summary; False if it lacks what reading needs."""
        stats = summary.statistics
        has_messages = stats is None or stats.message_count > 0
        if has_messages and (not summary.chunk_indexes or not summary.channels):
            return False
        for channel in summary.channels.values():
            self._add_channel(channel, summary.schemas)
        notes: list[str] = []
        for ci in sorted(summary.chunk_indexes, key=lambda ci: ci.chunk_start_offset):
            start, length = ci.chunk_start_offset, ci.chunk_length
            try:
                note = self._check_chunk(f, start, length, size)
            except (struct.error, ValueError) as exc:
                self._lost.append(LostRange(start, start + length, f"chunk: {exc}"))
                continue
            if note:
                notes.append(note)
            ids = frozenset(ci.message_index_offsets) or None
            self._segments.append(_Segment(start, ci.message_start_time, ci.message_end_time, ids, length))
        if stats is not None and not self._lost:
            self._counts = dict(stats.channel_message_counts)  # else counted from what is left, when asked
        f.seek(0)
        for record in SeekingReader(f, validate_crcs=False, record_size_limit=size).iter_metadata():
            self._metadata[record.name] = dict(record.metadata)
        if self._lost or notes:
            self._salvaged = True
            n = len(summary.chunk_indexes)
            left = "; ".join(f"bytes {r.start_offset}-{r.end_offset} are lost ({r.reason})" for r in self._lost)
            done = f"{len(self._lost)} of its {n} chunks are damaged and left out: {left}" if self._lost else ""
            told = "; ".join(x for x in (done, *notes) if x)
            warnings.warn(DamagedLogWarning(f"{self._where}: {told}; the other chunks are read"), stacklevel=4)
        return True

    def _check_chunk(self, f: IO[bytes], offset: int, length: int, size: int) -> str:
        """'' when the chunk record the summary puts at `offset` (`length` bytes) is whole, or a note on a repair.

        Raises ValueError (or struct.error) when its messages cannot be read.
        """
        if offset + length > size:
            raise ValueError(f"the chunk index puts it past the end of the file ({size} bytes)")
        f.seek(offset)
        blob = f.read(length if self._validate else min(length, 128))  # without CRCs: only its fields
        op, declared = fmt.RECORD_PREFIX.unpack_from(blob, 0)
        if op != Opcode.CHUNK:
            raise ValueError(f"opcode {op:#04x} where the chunk index puts a Chunk record")
        view = _chunk_view(blob, 0, length)
        if view.end != length:
            raise ValueError(f"its fields take {view.end} bytes, the chunk index says {length}")
        if self._validate:
            _chunk_records(blob, view, True)
        if fmt.RECORD_PREFIX.size + declared != length:
            body = length - fmt.RECORD_PREFIX.size
            return f"the chunk at byte {offset} says it is {declared} bytes long, its fields and the index say {body}"
        return ""

    def _add_channel(self, channel: Channel, schemas: dict[int, Schema]) -> None:
        schema = schemas.get(channel.schema_id)
        if channel.message_encoding != fmt.MESSAGE_ENCODING:
            raise LogFormatError(
                self._where,
                channel.topic,
                f"message encoding is {channel.message_encoding!r}; the ROS 2 profile needs {fmt.MESSAGE_ENCODING!r}",
            )
        if schema is None:
            raise LogFormatError(self._where, channel.topic, f"has no schema (schema id {channel.schema_id})")
        if schema.encoding != fmt.SCHEMA_ENCODING:
            raise LogFormatError(
                self._where,
                channel.topic,
                f"schema {schema.name} is encoded as {schema.encoding!r}; only {fmt.SCHEMA_ENCODING!r} is read",
            )
        try:
            text = bytes(schema.data).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise LogFormatError(self._where, channel.topic, f"schema {schema.name} is not UTF-8 text") from exc
        self._channels[channel.id] = _Channel(channel.id, channel.topic, schema.name, text, dict(channel.metadata))

    def _scan(self, f: IO[bytes], size: int, problem: str, footer: bool) -> None:
        """Read records in file order from the data section, keeping every whole chunk; see the module doc.

        `problem` says why the summary is not used ('' for a complete file without chunk indexes);
        `footer` whether the file ends with a footer (a file without one is cut short, not damaged, at its end).
        """
        found = _Scan()
        notes: list[str] = []
        cut = False
        data_complete = False
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            pos = self._data_start
            while pos < size:
                op = buf[pos]
                if found.loose and op != Opcode.MESSAGE:
                    self._add_loose(found)
                if _ends_data(buf, pos, size):
                    data_complete = True
                    break
                try:
                    pos, note = self._scan_record(buf, pos, size, found)
                except _PARSE_ERRORS as exc:
                    if found.loose:
                        self._add_loose(found)
                    reason = f"{_record_name(op)} at byte {pos}: {exc or type(exc).__name__}"
                    resume = _resume(buf, pos, size)
                    cut = resume is None and not footer
                    self._lost.append(LostRange(pos, size if resume is None else resume, reason))
                    if resume is None:
                        break
                    pos = resume
                    continue
                if note:
                    notes.append(note)
            if found.loose:
                self._add_loose(found)
        for channel in found.channels.values():
            if self._lost and channel.schema_id not in found.schemas:
                continue  # its schema was in the lost bytes: its messages are left out below
            self._add_channel(channel, found.schemas)
        hidden = {cid: n for cid, n in found.counts.items() if cid not in self._channels}
        if hidden and not self._lost:
            raise LogReadError(self._where, f"messages on channel ids {sorted(hidden)} that no Channel record defines")
        if hidden:
            self._hidden = frozenset(hidden)
            notes.append(
                f"{sum(hidden.values())} messages on channel ids {sorted(hidden)} are left out: "
                "their Channel records were in the lost bytes"
            )
        self._counts = {cid: found.counts.get(cid, 0) for cid in self._channels}
        if not (problem or self._lost or notes):
            return
        self._salvaged = True
        told = [problem or "its data section is damaged"]
        told.append(f"salvaged {sum(self._counts.values())} messages from {found.chunks} complete chunks")
        for k, r in enumerate(self._lost):
            if cut and k == len(self._lost) - 1:
                tail = size - r.start_offset
                told.append(f"the last {tail} bytes (from byte {r.start_offset}) are lost ({r.reason})")
            else:
                told.append(f"bytes {r.start_offset}-{r.end_offset} are lost ({r.reason})")
        if not self._lost:
            told.append(
                "the data section is complete, only the index is missing"
                if data_complete
                else f"the file ends between two records at byte {size}, the rest was never written"
            )
        told += notes
        self._salvage_note = "; ".join(told)
        kind = TruncatedLogWarning if not notes and len(self._lost) == int(cut) else DamagedLogWarning
        warnings.warn(kind(f"{self._where}: {'; '.join(told)}"), stacklevel=4)

    def _scan_record(self, buf: _Buffer, pos: int, size: int, found: _Scan) -> tuple[int, str]:
        """Take the record at byte `pos`: (where the next one starts, a note on a repair or '').

        Raises one of _PARSE_ERRORS when the record cannot be read.
        """
        if pos + fmt.RECORD_PREFIX.size > size:
            raise ValueError("its opcode and length are cut short")
        op, length = fmt.RECORD_PREFIX.unpack_from(buf, pos)
        body = pos + fmt.RECORD_PREFIX.size
        end = body + length
        if op == Opcode.CHUNK:  # delimited by its own fields, which its CRC vouches for, not by its length
            view = _chunk_view(buf, pos, size)
            self._scan_chunk(buf, pos, view, found)
            if view.end == end:
                return end, ""
            said = view.end - body
            return view.end, f"the chunk at byte {pos} says it is {length} bytes long, its fields say {said}"
        if op not in _FRAMEABLE and op < 0x80:
            raise ValueError(f"opcode {op:#04x} is not one a record after the Header may have")
        if end > size:
            raise ValueError(f"it claims {length} bytes, {size - body} remain")
        if op == Opcode.MESSAGE:
            if length < fmt.MESSAGE_FIXED:
                raise ValueError(f"it claims {length} bytes, fewer than its {fmt.MESSAGE_FIXED} fixed ones")
            cid, seq, log, pub = fmt.MESSAGE_FIELDS.unpack_from(buf, body)
            if not found.loose:
                found.loose_at = pos
            found.loose.append((cid, seq, log, pub, bytes(buf[body + fmt.MESSAGE_FIXED : end])))
            found.counts[cid] = found.counts.get(cid, 0) + 1
        elif op == Opcode.SCHEMA:
            schema = _parse(Schema.read, buf, body, end)
            found.schemas[schema.id] = schema
        elif op == Opcode.CHANNEL:
            channel = _parse(Channel.read, buf, body, end)
            found.channels[channel.id] = channel
        elif op == Opcode.METADATA:
            record = _parse(Metadata.read, buf, body, end)
            self._metadata[record.name] = dict(record.metadata)
        return end, ""

    def _scan_chunk(self, buf: _Buffer, offset: int, view: _ChunkView, found: _Scan) -> None:
        """Take the definitions and message counts of one whole chunk; ValueError if it is damaged."""
        records = _chunk_records(buf, view, True)
        counts: dict[int, int] = {}
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        for op, body, end in _records(records):
            if op == Opcode.MESSAGE:
                (cid,) = struct.unpack_from("<H", records, body)
                counts[cid] = counts.get(cid, 0) + 1
            elif op == Opcode.SCHEMA:
                schema = _parse(Schema.read, records, body, end)
                schemas[schema.id] = schema
            elif op == Opcode.CHANNEL:
                channel = _parse(Channel.read, records, body, end)
                channels[channel.id] = channel
        # commit only once the whole chunk parsed
        found.schemas.update(schemas)
        found.channels.update(channels)
        for cid, n in counts.items():
            found.counts[cid] = found.counts.get(cid, 0) + n
        found.chunks += 1
        segment = _Segment(offset, view.start_ns, view.end_ns, frozenset(counts), view.end - offset)
        self._segments.append(segment)

    def _add_loose(self, found: _Scan) -> None:
        loose, found.loose = found.loose, []
        times = [m[2] for m in loose]
        ids = frozenset(m[0] for m in loose)
        self._segments.append(_Segment(found.loose_at, min(times), max(times), ids, 0, tuple(loose)))

    def _check_channels(self) -> None:
        for segment in self._segments:
            for cid in segment.channel_ids or ():
                if cid not in self._channels and cid not in self._hidden:
                    raise LogReadError(self._where, f"chunk at byte {segment.offset} uses undefined channel id {cid}")

    # -- queries -----------------------------------------------------------------------------

    @property
    def salvaged(self) -> bool:
        """True when the file could not be read as written: no usable summary (read up to its last
        complete chunk), or damage that :attr:`lost` lists (or that was read around)."""
        return self._salvaged

    @property
    def salvage_note(self) -> str:
        """What salvaging the file found and lost, in words ('' for a file read as written)."""
        return self._salvage_note

    @property
    def lost(self) -> tuple[LostRange, ...]:
        """Byte ranges whose records could not be read, in file order: damaged chunks, a cut-off tail."""
        return tuple(self._lost)

    @property
    def profile(self) -> str:
        return str(self._header.profile)

    @property
    def library(self) -> str:
        """The writer named in the file's header."""
        return str(self._header.library)

    def topics(self) -> dict[str, str]:
        """``{topic: message type}`` of every channel, in channel order."""
        out: dict[str, str] = {}
        for ch in self._channels.values():
            out.setdefault(ch.topic, ch.typename)
        return out

    def schemas(self) -> dict[str, str]:
        """``{topic: ros2msg schema text}`` of every channel, in channel order: the definition (dependencies
        included) its messages were written with, which may be older than ``schemas/``."""
        out: dict[str, str] = {}
        for ch in self._channels.values():
            out.setdefault(ch.topic, ch.schema_text)
        return out

    def channel_metadata(self) -> dict[str, dict[str, str]]:
        """``{topic: channel metadata}``, e.g. ``offered_qos_profiles``."""
        out: dict[str, dict[str, str]] = {}
        for ch in self._channels.values():
            out.setdefault(ch.topic, dict(ch.metadata))
        return out

    def metadata(self) -> dict[str, dict[str, str]]:
        """``{name: {key: value}}`` of the metadata records (a repeated name keeps its last record)."""
        return {name: dict(values) for name, values in self._metadata.items()}

    def message_counts(self) -> dict[str, int]:
        """``{topic: number of messages}`` for every topic of the file (0 for topics with none)."""
        if self._counts is None:
            counts: dict[int, int] = dict.fromkeys(self._channels, 0)
            for item in self._ordered(self._wanted(None), None, None):
                counts[item[3]] += 1
            self._counts = counts
        out = dict.fromkeys(self.topics(), 0)
        for cid, n in self._counts.items():
            if cid in self._channels:
                out[self._channels[cid].topic] += n
        return out

    def raw(
        self, topics: str | Iterable[str] | None = None, start_ns: int | None = None, end_ns: int | None = None
    ) -> Iterator[RawMessage]:
        """Messages as CDR bytes in log-time order (ties in file order), `start_ns` <= log time < `end_ns`.

        `topics` selects topics by name; names absent from the file select nothing.
        """
        names = {cid: (ch.topic, ch.typename) for cid, ch in self._channels.items()}
        for log_ns, _, _, cid, seq, pub_ns, data in self._ordered(self._wanted(topics), start_ns, end_ns):
            topic, typename = names[cid]
            yield RawMessage(topic, typename, log_ns, pub_ns, seq, data)

    def messages(
        self,
        topics: str | Iterable[str] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
        *,
        skip_undecodable: bool = False,
    ) -> Iterator[LogMessage]:
        """Decoded messages in log-time order (ties in file order), `start_ns` <= log time < `end_ns`.

        A message whose bytes do not decode under its schema raises LogDecodeError naming the topic
        and log time; with `skip_undecodable` it is skipped with an UndecodableMessageWarning instead.
        """
        for log_ns, _, _, cid, seq, pub_ns, data in self._ordered(self._wanted(topics), start_ns, end_ns):
            ch = self._channels[cid]
            decode = self._decoders.get(cid) or self._decoder(ch)
            try:
                msg = decode(data)
            except Exception as exc:  # CDR parsers raise assorted errors on garbled bytes
                problem = f"{len(data)} bytes do not decode as {ch.typename}: {exc}"
                error = LogDecodeError(self._where, ch.topic, log_ns, problem)
                if not skip_undecodable:
                    raise error from exc
                warnings.warn(UndecodableMessageWarning(f"skipped: {error}"), stacklevel=2)
                continue
            yield LogMessage(ch.topic, ch.typename, log_ns, pub_ns, seq, msg)

    # -- internals ---------------------------------------------------------------------------

    def _wanted(self, topics: str | Iterable[str] | None) -> set[int] | None:
        if topics is None:
            return set(self._channels) if self._hidden else None
        names = {topics} if isinstance(topics, str) else set(topics)
        return {cid for cid, ch in self._channels.items() if ch.topic in names}

    def _decoder(self, ch: _Channel) -> Callable[[bytes], Any]:
        store = self._store
        typename = ch.typename
        if store.has(typename) and store.msgdef(typename) == ch.schema_text:

            def decode(data: bytes) -> Any:
                try:
                    return store.deserialize(data, typename)
                except MessageError as exc:
                    raise ValueError(exc.problem) from exc

        else:
            typestore = self._foreign_types()

            def decode(data: bytes) -> Any:
                return typestore.deserialize_cdr(data, typename)

        self._decoders[ch.id] = decode
        return decode

    def _foreign_types(self) -> Any:
        """A type store built from the schemas stored in the file (for definitions the store lacks)."""
        if self._foreign is not None:
            return self._foreign
        types: dict[str, Any] = {}
        for ch in self._channels.values():
            try:
                found = get_types_from_msg(ch.schema_text, ch.typename)
            except Exception as exc:  # the msg parser raises its own grammar errors
                raise LogFormatError(self._where, ch.topic, f"its ros2msg schema does not parse: {exc}") from exc
            for name, definition in found.items():
                if name in types and types[name] != definition:
                    raise LogFormatError(self._where, ch.topic, f"its schema defines {name} differently from another")
                types[name] = definition
        typestore = get_typestore(Stores.EMPTY)
        try:
            typestore.register(types)
        except Exception as exc:  # rosbags reports invalid definitions with several error types
            raise LogReadError(self._where, f"the schemas in the file do not form valid types: {exc}") from exc
        self._foreign = typestore
        return typestore

    def _ordered(self, wanted: set[int] | None, start_ns: int | None, end_ns: int | None) -> Iterator[_Item]:
        """Messages of the selected channels in (log time, file position) order, one chunk in memory at a time."""
        segments = [
            s
            for s in self._segments
            if (start_ns is None or s.end_ns >= start_ns)
            and (end_ns is None or s.start_ns < end_ns)
            and (wanted is None or s.channel_ids is None or not s.channel_ids.isdisjoint(wanted))
        ]
        if not segments or (wanted is not None and not wanted):
            return
        segments.sort(key=lambda s: (s.start_ns, s.offset))
        pending: list[_Item] = []
        with open(self.path, "rb") as f:
            for rank, segment in enumerate(segments):
                if pending:
                    cut = bisect.bisect_left(pending, (segment.start_ns,))
                    if cut:
                        yield from pending[:cut]
                        del pending[:cut]
                batch = self._load(f, segment, rank, wanted, start_ns, end_ns)
                batch.sort()
                if pending:
                    pending += batch
                    pending.sort()
                else:
                    pending = batch
            yield from pending

    def _load(
        self,
        f: IO[bytes],
        segment: _Segment,
        rank: int,
        wanted: set[int] | None,
        start_ns: int | None,
        end_ns: int | None,
    ) -> list[_Item]:
        lo = -1 if start_ns is None else start_ns
        hi = 1 << 64 if end_ns is None else end_ns
        if segment.loose:
            return [
                (log, rank, k, cid, seq, pub, data)
                for k, (cid, seq, log, pub, data) in enumerate(segment.loose)
                if (wanted is None or cid in wanted) and lo <= log < hi
            ]
        buf = self._segment_records(f, segment)
        out: list[_Item] = []
        unpack_prefix = fmt.RECORD_PREFIX.unpack_from
        unpack_fields = fmt.MESSAGE_FIELDS.unpack_from
        pos = 0
        n = len(buf)
        try:
            while pos < n:
                op, length = unpack_prefix(buf, pos)
                body = pos + 9
                end = body + length
                if end > n:
                    raise ValueError(f"record at {pos} of the chunk claims {length} bytes, {n - body} remain")
                if op == 5:  # Message
                    cid, seq, log, pub = unpack_fields(buf, body)
                    if (wanted is None or cid in wanted) and lo <= log < hi:
                        out.append((log, rank, pos, cid, seq, pub, buf[body + 22 : end]))
                pos = end
        except (struct.error, ValueError) as exc:
            raise LogReadError(self._where, f"chunk at byte {segment.offset} is damaged: {exc}") from exc
        return out

    def _segment_records(self, f: IO[bytes], segment: _Segment) -> bytes:
        """The uncompressed records of the chunk `segment`; LogReadError when they are damaged."""
        try:
            f.seek(segment.offset)
            blob = f.read(segment.length)
            if len(blob) < segment.length:
                raise ValueError("the chunk is cut short")
            if blob[0] != Opcode.CHUNK:
                raise ValueError(f"expected a Chunk record, found opcode {blob[0]:#04x}")
            return _chunk_records(blob, _chunk_view(blob, 0, len(blob)), self._validate)
        except (struct.error, ValueError) as exc:
            raise LogReadError(self._where, f"chunk at byte {segment.offset} is damaged: {exc}") from exc

    def __repr__(self) -> str:
        extra = ", salvaged" if self._salvaged else ""
        extra += f", {len(self._lost)} byte ranges lost" if self._lost else ""
        return f"McapLog({self._where!r}, {len(self._channels)} channels, {len(self._segments)} chunks{extra})"
