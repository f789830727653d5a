"""DDS types of the ROS 2 contract, generated at run time from the message store's definitions.

Each message type ``pkg/msg/Name`` becomes a cyclonedds ``IdlStruct`` named
``pkg::msg::dds_::Name_`` (the name rmw_cyclonedds_cpp registers), ``@final``, without keys or
optional members, so its plain-CDR (XCDR1) encoding is the same byte string ROS 2 puts on the
wire and the MCAP ``cdr`` encoder writes. Constants of a definition are not members and are
ignored. Nested types become nested structs; ``T[N]`` becomes ``array[T, N]``, ``T[]`` and
``T[<=N]`` become ``sequence[T]`` and ``sequence[T, N]``, ``string<=N`` a bounded string.

A :class:`DdsType` converts both ways between the store's messages (numpy arrays for primitive
arrays and sequences, as rosbags builds them) and its DDS objects (plain lists, ``bytes`` for
one-byte elements).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
from cyclonedds.idl import IdlStruct, make_idl_struct
from cyclonedds.idl import types as idl_types
from cyclonedds.idl.annotations import final

from pipeline.messages.errors import MessageError
from pipeline.messages.primitives import PRIMITIVES
from pipeline.messages.store import MessageStore, message_store

Converter = Callable[[Any], Any]

# rosbags' field descriptions: (node type, payload); node types as in rosbags.interfaces.Nodetype.
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4

_PRIMITIVES: dict[str, Any] = {
    name: bool if name == "bool" else getattr(idl_types, "uint8" if name == "char" else name) for name in PRIMITIVES
}
"""The cyclonedds type of each primitive (:data:`pipeline.messages.primitives.PRIMITIVES`; ``char`` as IDL uint8)."""
# numpy element types of primitive arrays, as rosbags deserializes them
_NUMPY: dict[str, Any] = {name: p.element for name, p in PRIMITIVES.items()}
# one-byte elements travel as raw bytes: identical CDR, no per-element work
_OCTETS = frozenset(name for name, p in PRIMITIVES.items() if p.octet)
# cyclonedds' subscriptable IDL type constructors (untyped for mypy)
_array: Any = idl_types.array
_sequence: Any = idl_types.sequence
_bounded_str: Any = idl_types.bounded_str


def field_definitions(store: MessageStore, typename: str) -> list[tuple[str, tuple[Any, Any]]]:
    """The member definitions of `typename` (name, rosbags field description), constants excluded."""
    fields = store.field_definitions(typename)  # unknown types raise MessageError naming the known ones
    return [(name, (int(desc[0]), desc[1])) for name, desc in fields]


@dataclass(frozen=True)
class DdsType:
    """One message type as a DDS type: its IDL class and converters from and to the store's messages."""

    typename: str
    """ROS 2 type name, ``pkg/msg/Name``."""
    dds_name: str
    """DDS type name, ``pkg::msg::dds_::Name_``."""
    idl_class: type[IdlStruct]
    to_dds: Converter
    """Store message -> IDL object; a fixed array of the wrong length or a sequence over its bound raises ValueError."""
    from_dds: Converter
    """IDL object -> store message."""


class DdsTypes:
    """The DDS types of one message store, built on first use and kept (thread-safe)."""

    def __init__(self, store: MessageStore) -> None:
        self.store = store
        self._types: dict[str, DdsType] = {}
        self._lock = threading.RLock()

    def get(self, typename: str) -> DdsType:
        """The DDS type of `typename`; an unknown type raises MessageError."""
        found = self._types.get(typename)
        if found is not None:
            return found
        with self._lock:
            found = self._types.get(typename)
            if found is None:
                found = self._build(typename)
                self._types[typename] = found
            return found

    def _build(self, typename: str) -> DdsType:
        members: dict[str, Any] = {}
        to_steps: list[tuple[str, Converter | None]] = []
        from_steps: list[tuple[str, Converter | None]] = []
        for name, desc in field_definitions(self.store, typename):
            annotation, to_conv, from_conv = self._member(typename, name, desc)
            members[name] = annotation
            to_steps.append((name, to_conv))
            from_steps.append((name, from_conv))
        dds_name = MessageStore.dds_type_name(typename)
        class_name = dds_name.replace("::", "_")
        idl_class = final(make_idl_struct(class_name, dds_name, members))
        return DdsType(
            typename=typename,
            dds_name=dds_name,
            idl_class=idl_class,
            to_dds=_struct_converter(idl_class, to_steps),
            from_dds=_struct_converter(self.store.cls(typename), from_steps),
        )

    def _member(
        self, typename: str, name: str, desc: tuple[Any, Any]
    ) -> tuple[Any, Converter | None, Converter | None]:
        """IDL annotation and the two converters (None: pass the value as it is) of one member."""
        kind, payload = desc
        if kind == _BASE:
            return _base_annotation(typename, name, payload), None, None
        if kind == _NAME:
            nested = self.get(str(payload))
            return nested.idl_class, nested.to_dds, nested.from_dds
        if kind in (_ARRAY, _SEQUENCE):
            (sub_kind, sub_payload), length = payload
            length = int(length)
            if sub_kind == _BASE and sub_payload[0] in _NUMPY:
                annotation, to_conv, from_conv = _primitive_collection(kind, sub_payload[0], length)
            elif sub_kind == _BASE:
                annotation = _collection(kind, _base_annotation(typename, name, sub_payload), length)
                to_conv, from_conv = list, list
            else:
                nested = self.get(str(sub_payload))
                annotation = _collection(kind, nested.idl_class, length)
                to_conv, from_conv = _each(nested.to_dds), _each(nested.from_dds)
            return annotation, _length_checked(to_conv, kind, length, name), from_conv
        raise MessageError(typename, f"member {name!r} has a field kind the DDS types do not support: {desc!r}")


def dds_types(store: MessageStore | None = None) -> DdsTypes:
    """The DDS types of `store` (default: the process-wide store from ``schemas/``), one registry per store."""
    return _registry(store if store is not None else message_store())


@cache
def _registry(store: MessageStore) -> DdsTypes:
    return DdsTypes(store)


def dds_type(typename: str, store: MessageStore | None = None) -> DdsType:
    """The DDS type of message type `typename` (``pkg/msg/Name``)."""
    return dds_types(store).get(typename)


def _base_annotation(typename: str, name: str, payload: tuple[str, int]) -> Any:
    basename, bound = payload[0], int(payload[1])
    if basename == "string":
        return _bounded_str[bound] if bound else str
    if basename in _PRIMITIVES:
        return _PRIMITIVES[basename]
    raise MessageError(
        typename,
        f"member {name!r} is a {basename}, which the DDS transport does not carry "
        f"(supported: string, {', '.join(_PRIMITIVES)})",
    )


def _collection(kind: int, element: Any, length: int) -> Any:
    if kind == _ARRAY:
        return _array[element, length]
    return _sequence[element, length] if length else _sequence[element]


def _primitive_collection(kind: int, basename: str, length: int) -> tuple[Any, Converter, Converter]:
    dtype = _NUMPY[basename]
    if basename in _OCTETS:
        # array[uint8, N] is a raw N-byte block, `bytes` a uint32 count plus raw bytes: both are
        # exactly the CDR of octet arrays and sequences
        annotation = _array[_PRIMITIVES[basename], length] if kind == _ARRAY else bytes
        return annotation, _to_bytes, _bytes_to_array(dtype)
    annotation = _collection(kind, _PRIMITIVES[basename], length)
    return annotation, _to_list, _list_to_array(dtype)


def _length_checked(convert: Converter, kind: int, length: int, member: str) -> Converter:
    """`convert`, refusing a fixed array of another length or a bounded sequence over its bound."""
    if kind == _SEQUENCE and not length:
        return convert
    exact = kind == _ARRAY

    def checked(values: Any) -> Any:
        out = convert(values)
        if (len(out) != length) if exact else (len(out) > length):
            limit = f"exactly {length}" if exact else f"at most {length}"
            raise ValueError(f"member {member!r} holds {len(out)} values; its type takes {limit}")
        return out

    return checked


def _struct_converter(target: Any, steps: Sequence[tuple[str, Converter | None]]) -> Converter:
    """Builds `target` positionally from the attributes of a source object, converting some."""
    plan = tuple(steps)
    if all(conv is None for _, conv in plan):
        names = tuple(name for name, _ in plan)

        def copy(source: Any) -> Any:
            return target(*[getattr(source, name) for name in names])

        return copy

    def convert(source: Any) -> Any:
        return target(*[getattr(source, n) if c is None else c(getattr(source, n)) for n, c in plan])

    return convert


def _each(convert: Converter) -> Converter:
    def each(values: Any) -> list[Any]:
        return [convert(v) for v in values]

    return each


def _to_list(values: Any) -> list[Any]:
    if isinstance(values, np.ndarray):
        return list(values.tolist())
    return list(values)


def _to_bytes(values: Any) -> bytes:
    if isinstance(values, np.ndarray):
        return values.tobytes()
    return bytes(values)


def _list_to_array(dtype: Any) -> Converter:
    def to_array(values: Any) -> np.ndarray:
        return np.array(values, dtype=dtype)

    return to_array


def _bytes_to_array(dtype: Any) -> Converter:
    def to_array(values: Any) -> np.ndarray:
        return np.frombuffer(bytes(values), dtype=dtype).copy()

    return to_array
