"""Reading session recordings: topics, metadata, and messages in log-time order, decoded or raw.

A complete file is read through its summary (chunk indexes, statistics). A file without a
summary, as a killed recorder leaves it, is read record by record in file order up to its last
complete chunk: mcap's indexed reader refuses such a file and its time-ordered stream reader
yields nothing, so :class:`McapLog` salvages what is there, says so with a
:class:`~pipeline.record.errors.TruncatedLogWarning`, and sets :attr:`McapLog.salvaged`.

Messages decode with the repository's message store when the file's schema text equals the
store's definition (every file the pipeline writes); other files (e.g. ``ros2 bag record -s mcap``
on robots, whose schemas keep their comments) decode with types built from the schemas stored in
the file, so their message classes differ from the store's but carry the same fields.
"""

from __future__ import annotations

import bisect
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
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline.errors import MessageError
from pipeline.messages.store import MessageStore, message_store
from pipeline.record import format as fmt
from pipeline.record.errors import (
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
    loose: tuple[tuple[int, int, int, int, bytes], ...] = field(default=(), repr=False)  # (id, seq, log, pub, data)


_Item = tuple[int, int, int, int, int, int, bytes]
"""(log time ns, segment rank, position, channel id, sequence, publish time ns, CDR data)."""


def _inflate(compression: str, data: bytes, size: int, crc: int, validate: bool) -> bytes:
    """The uncompressed records of a chunk; ValueError when they are damaged."""
    if compression == "zstd":
        try:
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


def _parse(reader: Callable[[ReadDataStream], Any], buf: bytes, start: int, end: int) -> Any:
    return reader(ReadDataStream(BytesIO(buf[start:end])))


class McapLog:
    """A recording opened for reading; cheap to open, iterators read the file on demand.

    Args:
        path: an MCAP file (ROS 2 profile: cdr messages, ros2msg schemas).
        store: the message store used to decode the pipeline's own types.
        validate_crcs: check each chunk's CRC-32 when it is read.

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
        if self._has_footer(f, size):
            try:
                f.seek(0)
                summary = SeekingReader(f, validate_crcs=False, record_size_limit=size).get_summary()
                if summary is not None and self._use_summary(f, summary, size):
                    return
                problem = ""  # complete but not indexed: read it in file order, nothing is missing
            except _PARSE_ERRORS as exc:
                problem = f"its summary section is damaged ({exc})"
        self._scan(f, size, problem)

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

    def _use_summary(self, f: IO[bytes], summary: Any, size: int) -> bool:
        """Take channels, chunks, counts and metadata from the summary; False if it lacks what reading needs."""
        stats = summary.statistics
        has_messages = stats is None or stats.message_count > 0
        if has_messages and (not summary.chunk_indexes or not summary.channels):
            return False
        for channel in summary.channels.values():
            self._add_channel(channel, summary.schemas)
        for ci in summary.chunk_indexes:
            ids = frozenset(ci.message_index_offsets) or None
            self._segments.append(_Segment(ci.chunk_start_offset, ci.message_start_time, ci.message_end_time, ids))
        if stats is not None:
            self._counts = dict(stats.channel_message_counts)
        f.seek(0)
        for record in SeekingReader(f, validate_crcs=False, record_size_limit=size).iter_metadata():
            self._metadata[record.name] = dict(record.metadata)
        return True

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

    def _scan(self, f: IO[bytes], size: int, problem: str) -> None:
        """Read records in file order; with `problem` (truncated/damaged) stop quietly at the first bad one."""
        f.seek(0)
        reader = StreamReader(f, emit_chunks=True, record_size_limit=size)
        records = reader.records
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        counts: dict[int, int] = {}
        loose: list[tuple[int, int, int, int, bytes]] = []
        loose_at = 0
        end_of_good = 0
        chunks = 0
        stop = ""
        data_complete = False
        while True:
            start = f.tell()
            try:
                record = next(records)
                if isinstance(record, Chunk):
                    self._scan_chunk(record, start, schemas, channels, counts)
                    chunks += 1
            except StopIteration:
                break
            except _PARSE_ERRORS as exc:
                stop = f"record at byte {start}: {exc or type(exc).__name__}"
                if not problem:
                    raise LogReadError(self._where, f"damaged {stop}") from exc
                break
            end_of_good = f.tell()
            if isinstance(record, Message):
                if not loose:
                    loose_at = start
                loose.append((record.channel_id, record.sequence, record.log_time, record.publish_time, record.data))
                counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
                continue
            if loose:
                self._add_loose(loose, loose_at)
                loose = []
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Metadata):
                self._metadata[record.name] = dict(record.metadata)
            elif isinstance(record, (DataEnd, Footer)):
                data_complete = True
                break
        if loose:
            self._add_loose(loose, loose_at)
        for channel in channels.values():
            self._add_channel(channel, schemas)
        missing = {cid for cid in counts if cid not in self._channels}
        if missing:
            raise LogReadError(self._where, f"messages on channel ids {sorted(missing)} that no Channel record defines")
        self._counts = {cid: counts.get(cid, 0) for cid in self._channels}
        if problem:
            self._salvaged = True
            if data_complete:
                lost = "the data section is complete, only the index is missing"
            else:
                lost = f"the last {size - end_of_good} bytes (from byte {end_of_good}) are lost ({stop or 'cut short'})"
            warnings.warn(
                TruncatedLogWarning(
                    f"{self._where}: {problem}; salvaged {sum(counts.values())} messages from {chunks} complete "
                    f"chunks; {lost}"
                ),
                stacklevel=4,
            )

    def _scan_chunk(
        self,
        chunk: Chunk,
        offset: int,
        schemas: dict[int, Schema],
        channels: dict[int, Channel],
        counts: dict[int, int],
    ) -> None:
        """Take the definitions and message counts of one complete chunk; ValueError if it is damaged."""
        buf = _inflate(chunk.compression, chunk.data, chunk.uncompressed_size, chunk.uncompressed_crc, True)
        found: dict[int, int] = {}
        new_schemas: dict[int, Schema] = {}
        new_channels: dict[int, Channel] = {}
        for op, body, end in _records(buf):
            if op == Opcode.MESSAGE:
                (cid,) = struct.unpack_from("<H", buf, body)
                found[cid] = found.get(cid, 0) + 1
            elif op == Opcode.SCHEMA:
                schema = _parse(Schema.read, buf, body, end)
                new_schemas[schema.id] = schema
            elif op == Opcode.CHANNEL:
                channel = _parse(Channel.read, buf, body, end)
                new_channels[channel.id] = channel
        # commit only once the whole chunk parsed
        schemas.update(new_schemas)
        channels.update(new_channels)
        for cid, n in found.items():
            counts[cid] = counts.get(cid, 0) + n
        start_ns, end_ns = chunk.message_start_time, chunk.message_end_time
        self._segments.append(_Segment(offset, start_ns, end_ns, frozenset(found)))

    def _add_loose(self, loose: list[tuple[int, int, int, int, bytes]], offset: int) -> None:
        times = [m[2] for m in loose]
        ids = frozenset(m[0] for m in loose)
        self._segments.append(_Segment(offset, min(times), max(times), ids, tuple(loose)))

    def _check_channels(self) -> None:
        for segment in self._segments:
            for cid in segment.channel_ids or ():
                if cid not in self._channels:
                    raise LogReadError(self._where, f"chunk at byte {segment.offset} uses undefined channel id {cid}")

    # -- queries -----------------------------------------------------------------------------

    @property
    def salvaged(self) -> bool:
        """True when the file had no usable summary and was read up to its last complete chunk."""
        return self._salvaged

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
            for item in self._ordered(None, None, None):
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
            return None
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
        buf = self._chunk_records(f, segment.offset)
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

    def _chunk_records(self, f: IO[bytes], offset: int) -> bytes:
        try:
            f.seek(offset)
            op, length = fmt.RECORD_PREFIX.unpack(f.read(fmt.RECORD_PREFIX.size))
            if op != Opcode.CHUNK:
                raise ValueError(f"expected a Chunk record, found opcode {op:#04x}")
            body = f.read(length)
            if len(body) < length:
                raise ValueError("the chunk is cut short")
            _, _, size, crc = fmt.CHUNK_FIELDS.unpack_from(body, 0)
            at = fmt.CHUNK_FIELDS.size
            (name_len,) = struct.unpack_from("<I", body, at)
            compression = body[at + 4 : at + 4 + name_len].decode("utf-8")
            at += 4 + name_len
            (data_len,) = struct.unpack_from("<Q", body, at)
            data = body[at + 8 : at + 8 + data_len]
            if len(data) < data_len:
                raise ValueError("the chunk's data are cut short")
            return _inflate(compression, data, size, crc, self._validate)
        except (struct.error, ValueError, UnicodeDecodeError) as exc:
            raise LogReadError(self._where, f"chunk at byte {offset} is damaged: {exc}") from exc

    def __repr__(self) -> str:
        extra = ", salvaged" if self._salvaged else ""
        return f"McapLog({self._where!r}, {len(self._channels)} channels, {len(self._segments)} chunks{extra})"
