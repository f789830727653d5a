"""Column-wise CDR decoding: many messages of one type into numpy columns, without a message object each.

A ROS 2 message in plain CDR (XCDR1, little endian) is a 4-byte encapsulation header followed by
its fields in order: a primitive of size s sits at the next multiple of min(s, 8) counted from the
end of that header, a string is a uint32 length (the NUL terminator included) and its bytes, a
sequence is a uint32 count and its elements. Within one topic the strings (frame ids, robot names)
and sequence lengths (beam counts) rarely change, so most messages share one byte layout. This
module reads the layout of one message, checks every other message of the same byte length against
it with vectorised comparisons of its length fields, and then reads each field of all matching
messages as one strided numpy view. Messages that match no layout (other encodings, odd strings,
too many distinct layouts) go through the generic decoder of the message store, one at a time, and
land in the same columns, so the result is the same either way, to the bit.

Supported types: ``DECODABLE`` of :mod:`pipeline.analysis.layouts` (the pipeline's recorded sensor,
command and bookkeeping types; not ``tf2_msgs/msg/TFMessage``, a sequence of structures). Given the
definition a recording carries for a type, the layout is the one with the same fields and wire types
(its ``layout_for``), so a recording made before a field was added (its ``LEGACY_LAYOUTS``) decodes
without it.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline.analysis.layouts import Field, Fixed, Prim, Seq, Str, layout_for
from pipeline.core.timebase import NS_PER_S
from pipeline.messages.errors import MessageError
from pipeline.messages.store import message_store

_CDR_LE = (0, 1)
"""Encapsulation header bytes 0 and 1 of plain little-endian CDR (ROS 2's default)."""
MAX_LAYOUTS_PER_LENGTH = 64
"""Distinct layouts tried among messages of one byte length before the rest decode one by one."""


@dataclass(frozen=True)
class Strings:
    """`n` strings as their distinct `values` and per-message `codes` (n,) int32 indexing them."""

    values: tuple[str, ...]
    codes: np.ndarray

    def tolist(self) -> list[str]:
        return [self.values[c] for c in self.codes.tolist()]


@dataclass(frozen=True)
class Ragged:
    """`n` sequences of different lengths: `values` flat, message i owns ``values[offsets[i]:offsets[i+1]]``."""

    values: np.ndarray
    offsets: np.ndarray

    def row(self, i: int) -> np.ndarray:
        return self.values[self.offsets[i] : self.offsets[i + 1]]

    def tolist(self) -> list[np.ndarray]:
        return [self.row(i) for i in range(len(self.offsets) - 1)]


Column = np.ndarray | Strings | Ragged
"""A decoded column: numbers (n,), a sequence of one length for every message (n, k), strings, or ragged."""


@dataclass
class Decoded:
    """Columns of `n` messages of `typename`, named after the fields of its layout (wire order).

    Header stamps appear as ``stamp_ns`` (int64 ns: sec * NS_PER_S + nanosec) in place of their two fields.
    `generic` counts the messages that went through the message store's decoder.
    """

    typename: str
    n: int
    columns: dict[str, Column] = field(default_factory=dict)
    generic: int = 0


# -- layouts of single messages ---------------------------------------------------------------


@dataclass(frozen=True)
class _Layout:
    """Where each field of one message sits (absolute byte offsets, header included)."""

    size: int
    checks: tuple[tuple[int, int], ...]  # (offset of a uint32 length/count, its value)
    nuls: tuple[int, ...]  # offsets that must hold a string's NUL terminator
    prims: tuple[tuple[str, int, str], ...]  # (name, offset, dtype)
    strings: tuple[tuple[str, int, int], ...]  # (name, offset, byte count without NUL)
    seqs: tuple[tuple[str, int, int, str], ...]  # (name, offset, count, dtype)


def _align(pos: int, size: int) -> int:
    a = min(size, 8)
    return (pos + a - 1) // a * a


def _layout(data: bytes, fields: tuple[Field, ...]) -> _Layout | None:
    """The layout of one message, or None if it is not plain little-endian CDR of `fields`."""
    n = len(data)
    if n < 4 or (data[0], data[1]) != _CDR_LE:
        return None
    body = n - 4
    pos = 0
    checks: list[tuple[int, int]] = []
    nuls: list[int] = []
    prims: list[tuple[str, int, str]] = []
    strings: list[tuple[str, int, int]] = []
    seqs: list[tuple[str, int, int, str]] = []
    for f in fields:
        if isinstance(f, Prim):
            size = np.dtype(f.dtype).itemsize
            pos = _align(pos, size)
            if f.keep:
                prims.append((f.name, 4 + pos, f.dtype))
            pos += size
        elif isinstance(f, Fixed):
            size = np.dtype(f.dtype).itemsize
            pos = _align(pos, size) + size * f.count
        else:
            pos = _align(pos, 4)
            if pos + 4 > body:
                return None
            count = int.from_bytes(data[4 + pos : 8 + pos], "little")
            checks.append((4 + pos, count))
            if isinstance(f, Str):
                if count < 1 or pos + 4 + count > body or data[4 + pos + 4 + count - 1] != 0:
                    return None
                strings.append((f.name, 4 + pos + 4, count - 1))
                nuls.append(4 + pos + 4 + count - 1)
                pos += 4 + count
            else:
                size = np.dtype(f.dtype).itemsize
                if pos + 4 + size * count > body:
                    return None
                seqs.append((f.name, 4 + pos + 4, count, f.dtype))
                pos += 4 + size * count
        if pos > body:
            return None
    if not pos <= body <= pos + 3:  # CDR may pad the end to a multiple of 4
        return None
    return _Layout(n, tuple(checks), tuple(nuls), tuple(prims), tuple(strings), tuple(seqs))


# -- vectorised reading -----------------------------------------------------------------------


def _strided(
    blob: bytes | np.ndarray, n: int, size: int, offset: int, dtype: str, width: int | None = None
) -> np.ndarray:
    """A read-only view of one field in `n` rows of `size` bytes: (n,) or, with `width`, (n, width)."""
    if width is None:
        return np.ndarray((n,), dtype=np.dtype(dtype), buffer=blob, offset=offset, strides=(size,))
    if width == 0:
        return np.zeros((n, 0), dtype=np.dtype(dtype))
    shape = (n, width)
    strides = (size, np.dtype(dtype).itemsize)
    return np.ndarray(shape, dtype=np.dtype(dtype), buffer=blob, offset=offset, strides=strides)


def _matches(blob: bytes | np.ndarray, n: int, layout: _Layout) -> np.ndarray:
    """(n,) bool: rows of `blob` (n rows of layout.size bytes) whose lengths and terminators fit `layout`."""
    size = layout.size
    ok = (_strided(blob, n, size, 0, "u1") == _CDR_LE[0]) & (_strided(blob, n, size, 1, "u1") == _CDR_LE[1])
    for offset, value in layout.checks:
        ok &= _strided(blob, n, size, offset, "<u4") == value
    for offset in layout.nuls:
        ok &= _strided(blob, n, size, offset, "u1") == 0
    return np.asarray(ok)


class _Builder:
    """Collects the columns of `n` messages filled group by group."""

    def __init__(self, fields: tuple[Field, ...], n: int) -> None:
        self.n = n
        self.prims = {f.name: np.zeros(n, dtype=np.dtype(f.dtype)) for f in fields if isinstance(f, Prim) and f.keep}
        self.string_codes = {f.name: np.full(n, -1, dtype=np.int32) for f in fields if isinstance(f, Str)}
        self.string_values: dict[str, dict[str, int]] = {f.name: {} for f in fields if isinstance(f, Str)}
        self.seq_parts: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {
            f.name: [] for f in fields if isinstance(f, Seq)
        }
        self.seq_dtypes = {f.name: np.dtype(f.dtype) for f in fields if isinstance(f, Seq)}
        self.order = [f.name for f in fields if not isinstance(f, Fixed) and (not isinstance(f, Prim) or f.keep)]

    def code(self, name: str, text: str) -> int:
        table = self.string_values[name]
        code = table.get(text)
        if code is None:
            code = table[text] = len(table)
        return code

    def put_rows(self, rows: np.ndarray, blob: bytes | np.ndarray, layout: _Layout) -> bool:
        """Fill `rows` from `blob` (len(rows) rows of layout.size bytes); False if a string is not UTF-8."""
        n, size = len(rows), layout.size
        codes: dict[str, np.ndarray] = {}
        for name, offset, length in layout.strings:
            if length == 0:
                codes[name] = np.full(n, self.code(name, ""), dtype=np.int32)
                continue
            raw = _strided(blob, n, size, offset, "u1", length)
            if bool((raw == raw[0]).all()):
                uniques, inverse = raw[:1], np.zeros(n, dtype=np.intp)
            else:
                uniques, inverse = np.unique(raw, axis=0, return_inverse=True)
            try:
                texts = [bytes(u).decode("utf-8") for u in uniques]
            except UnicodeDecodeError:
                return False
            mapping = np.array([self.code(name, t) for t in texts], dtype=np.int32)
            codes[name] = mapping[inverse.reshape(-1)]
        for name, code in codes.items():
            self.string_codes[name][rows] = code
        for name, offset, dtype in layout.prims:
            self.prims[name][rows] = _strided(blob, n, size, offset, dtype)
        for name, offset, count, dtype in layout.seqs:
            self.seq_parts[name].append((rows, _strided(blob, n, size, offset, dtype, count).copy()))
        return True

    def put_message(self, row: int, msg: Any, fields: tuple[Field, ...]) -> None:
        """Fill one row from a decoded message object."""
        for f in fields:
            if isinstance(f, Fixed) or (isinstance(f, Prim) and not f.keep):
                continue
            value = _attr(msg, f.path)
            if isinstance(f, Prim):
                self.prims[f.name][row] = value
            elif isinstance(f, Str):
                self.string_codes[f.name][row] = self.code(f.name, str(value))
            else:
                values = np.asarray(value, dtype=self.seq_dtypes[f.name]).reshape(1, -1)
                self.seq_parts[f.name].append((np.array([row]), values))

    def finish(self, typename: str, generic: int) -> Decoded:
        out = Decoded(typename, self.n, generic=generic)
        for name in self.order:
            if name == "stamp_sec":
                sec = self.prims["stamp_sec"].astype(np.int64)
                out.columns["stamp_ns"] = sec * NS_PER_S + self.prims["stamp_nanosec"].astype(np.int64)
            elif name == "stamp_nanosec":
                continue
            elif name in self.prims:
                out.columns[name] = self.prims[name]
            elif name in self.string_codes:
                values = tuple(self.string_values[name])
                out.columns[name] = Strings(values, self.string_codes[name])
            else:
                out.columns[name] = self._sequence(name)
        return out

    def _sequence(self, name: str) -> np.ndarray | Ragged:
        parts = self.seq_parts[name]
        dtype = self.seq_dtypes[name]
        widths = {values.shape[1] for _, values in parts}
        if len(parts) == 1 and len(parts[0][0]) == self.n and _in_order(parts[0][0]):
            return parts[0][1]
        if len(widths) <= 1:
            width = widths.pop() if widths else 0
            dense = np.zeros((self.n, width), dtype=dtype)
            for rows, values in parts:
                dense[rows] = values
            return dense
        counts = np.zeros(self.n, dtype=np.int64)
        for rows, values in parts:
            counts[rows] = values.shape[1]
        offsets = np.zeros(self.n + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        flat = np.zeros(int(offsets[-1]), dtype=dtype)
        for rows, values in parts:
            if values.shape[1]:
                flat[(offsets[rows][:, None] + np.arange(values.shape[1])).ravel()] = values.ravel()
        return Ragged(flat, offsets)


def _in_order(rows: np.ndarray) -> bool:
    return bool(rows[0] == 0 and (np.diff(rows) == 1).all()) if len(rows) else True


def _attr(msg: Any, path: str) -> Any:
    return operator.attrgetter(path)(msg) if path else msg


def decode(
    typename: str,
    datas: Sequence[bytes],
    *,
    fast: bool = True,
    deserialize: Callable[[bytes], Any] | None = None,
    where: str = "",
    log_times_ns: Sequence[int] | np.ndarray | None = None,
    schema: str | None = None,
) -> Decoded:
    """Columns of the CDR messages `datas` (each with its 4-byte encapsulation header) of `typename`.

    `schema` is the ros2msg definition the messages were written with (an MCAP channel's schema,
    see :meth:`~pipeline.record.McapLog.schemas`); None: the one of ``schemas/`` and ROS 2 Jazzy.
    The columns are those of its layout (``layouts.layout_for``): an older definition gives fewer. With
    `fast` (the default) messages that share a byte layout are read as strided numpy views; the
    others, and every message when `fast` is False, go through `deserialize` (by default the
    repository's message store, or types built from `schema` where it differs from the store's).
    Raises MessageError naming `where` and the message (its log time when `log_times_ns` is given,
    else its index) when a message does not decode, and for a type outside ``layouts.DECODABLE`` or a
    definition that no layout fits.
    """
    try:
        fields = layout_for(typename, schema)
    except MessageError as exc:
        raise MessageError(where or typename, exc.problem) from exc.__cause__
    n = len(datas)
    builder = _Builder(fields, n)
    generic_rows: list[int] = []
    if fast and n:
        generic_rows = _decode_fast(fields, datas, builder)
    elif n:
        generic_rows = list(range(n))
    if generic_rows:
        if deserialize is not None:
            generic = deserialize
        else:
            generic = _store_decoder(typename) if schema is None else _schema_decoder(typename, schema, where)
        for row in generic_rows:
            try:
                msg = generic(datas[row])
            except Exception as exc:  # the generic decoders raise assorted errors on garbled bytes
                which = f"message {row}" if log_times_ns is None else f"message logged at {log_times_ns[row]} ns"
                where_row = f"{where}: {which}" if where else which
                raise MessageError(where_row, f"{len(datas[row])} bytes do not decode as {typename}: {exc}") from exc
            builder.put_message(row, msg, fields)
    return builder.finish(typename, len(generic_rows))


def _store_decoder(typename: str) -> Callable[[bytes], Any]:
    store = message_store()

    def deserialize(data: bytes) -> Any:
        return store.deserialize(data, typename)

    return deserialize


def _schema_decoder(typename: str, schema: str, where: str) -> Callable[[bytes], Any]:
    """Messages of `typename` as defined by `schema`: the message store's where its definition is the same."""
    store = message_store()
    if store.msgdef(typename) == schema:
        return _store_decoder(typename)
    try:
        return _schema_types(typename, schema)
    except Exception as exc:  # rosbags reports invalid definitions with several error types
        raise MessageError(where or typename, f"the recorded definition of {typename} is not a type: {exc}") from exc


@lru_cache(maxsize=64)
def _schema_types(typename: str, schema: str) -> Callable[[bytes], Any]:
    typestore = get_typestore(Stores.EMPTY)
    typestore.register(get_types_from_msg(schema, typename))

    def deserialize(data: bytes) -> Any:
        return typestore.deserialize_cdr(data, typename)

    return deserialize


def _decode_fast(fields: tuple[Field, ...], datas: Sequence[bytes], builder: _Builder) -> list[int]:
    """Fill `builder` from every message that fits a shared layout; returns the rows left for the generic decoder."""
    n = len(datas)
    lengths = np.fromiter(map(len, datas), dtype=np.int64, count=n)
    blob = b"".join(datas)
    sizes = np.unique(lengths)
    generic: list[np.ndarray] = []
    groups: list[tuple[int, np.ndarray, np.ndarray | None]]
    if len(sizes) == 1:
        groups = [(int(sizes[0]), np.arange(n), None)]
    else:
        starts = np.zeros(n, dtype=np.int64)
        np.cumsum(lengths[:-1], out=starts[1:])
        flat = np.frombuffer(blob, dtype=np.uint8)
        groups = []
        for size in sizes.tolist():
            rows = np.flatnonzero(lengths == size)
            groups.append((size, rows, flat[starts[rows][:, None] + np.arange(size)]))
    for size, rows, matrix in groups:
        source: bytes | np.ndarray = blob if matrix is None else matrix
        pending = np.ones(len(rows), dtype=bool)
        for _ in range(MAX_LAYOUTS_PER_LENGTH):
            left = np.flatnonzero(pending)
            if not len(left):
                break
            first = int(rows[left[0]])
            layout = _layout(datas[first], fields)
            if layout is None or layout.size != size:
                pending[left[0]] = False
                generic.append(rows[left[:1]])
                continue
            fit = _matches(source, len(rows), layout) & pending
            chosen = np.flatnonzero(fit)
            if len(chosen) == len(rows):
                ok = builder.put_rows(rows, source, layout)
            else:
                sub = np.ascontiguousarray(_strided(source, len(rows), size, 0, "u1", size)[chosen])
                ok = builder.put_rows(rows[chosen], sub, layout)
            if not ok:
                generic.append(rows[chosen])
            pending[chosen] = False
            if not pending[left[0]]:
                continue
            pending[left[0]] = False  # a message fits its own layout; should it not, decode it generically
            generic.append(rows[left[:1]])
        generic.append(rows[np.flatnonzero(pending)])
    if not generic:
        return []
    return sorted(int(r) for r in np.concatenate(generic).tolist())


def concat(parts: Sequence[Decoded]) -> Decoded:
    """The messages of several :class:`Decoded` of one type (e.g. batches of a topic), in order."""
    if not parts:
        raise ValueError("concat needs at least one part")
    typename = parts[0].typename
    if any(p.typename != typename for p in parts):
        raise ValueError(f"cannot concatenate decoded {sorted({p.typename for p in parts})}")
    if len(parts) == 1:
        return parts[0]
    out = Decoded(typename, sum(p.n for p in parts), generic=sum(p.generic for p in parts))
    for name, first in parts[0].columns.items():
        columns = [p.columns[name] for p in parts]
        if isinstance(first, Strings):
            out.columns[name] = _concat_strings([c for c in columns if isinstance(c, Strings)])
        elif any(isinstance(c, Ragged) for c in columns) or len({_width(c) for c in columns}) > 1:
            out.columns[name] = _concat_ragged(columns)
        else:
            out.columns[name] = np.concatenate([c for c in columns if isinstance(c, np.ndarray)])
    return out


def _width(column: Column) -> tuple[int, ...]:
    return tuple(column.shape[1:]) if isinstance(column, np.ndarray) else (-1,)


def _concat_strings(columns: list[Strings]) -> Strings:
    table: dict[str, int] = {}
    codes = []
    for column in columns:
        mapping = np.array([table.setdefault(v, len(table)) for v in column.values], dtype=np.int32)
        codes.append(mapping[column.codes] if len(mapping) else column.codes)
    return Strings(tuple(table), np.concatenate(codes))


def _concat_ragged(columns: Sequence[Column]) -> Ragged:
    values, counts = [], []
    for column in columns:
        if isinstance(column, Ragged):
            values.append(column.values)
            counts.append(np.diff(column.offsets))
        elif isinstance(column, np.ndarray):
            values.append(column.reshape(-1))
            counts.append(np.full(column.shape[0], column.shape[1] if column.ndim == 2 else 1, dtype=np.int64))
    offsets = np.zeros(sum(len(c) for c in counts) + 1, dtype=np.int64)
    np.cumsum(np.concatenate(counts), out=offsets[1:])
    return Ragged(np.concatenate(values), offsets)
