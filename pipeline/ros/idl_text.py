"""OMG IDL text of the ROS 2 contract, for DDS peers built from IDL (Fast DDS's ``fastddsgen``, OpenDDS).

One self-contained IDL document holds the requested message types and every type they use, in
dependency order, each as the DDS type a ROS 2 middleware registers: ``pkg/msg/Name`` becomes
``struct Name_`` in ``module pkg { module msg { module dds_ {...}}}``, so the generated type names
are ``pkg::msg::dds_::Name_`` without a generator's ROS 2 option. The members are those of the
message store (constants excluded), mapped to IDL as ``rosidl`` maps ``.msg`` files:
``T[N]`` -> array, ``T[]`` -> ``sequence<T>``, ``T[<=N]`` -> ``sequence<T, N>``, ``string<=N`` ->
``string<N>``; ``byte``, ``char`` and ``uint8`` are ``octet``. A struct without members gets the
``structure_needs_at_least_one_member`` octet ROS 2 adds (its plain CDR is one byte, as on the wire).
A member name that is an IDL keyword gets a trailing underscore (names do not travel in plain CDR).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from pipeline.messages.errors import MessageError
from pipeline.messages.primitives import PRIMITIVES
from pipeline.messages.store import MessageStore, message_store
from pipeline.ros.idl import _ARRAY, _BASE, _NAME, _SEQUENCE, field_definitions

IDL_PRIMITIVES: dict[str, str] = {name: p.idl for name, p in PRIMITIVES.items()}
"""ROS 2 primitive -> IDL type (``int8`` as ``char``: one signed byte in plain CDR, as rosidl's ``int8``)."""

IDL_KEYWORDS = frozenset(
    {
        "abstract",
        "any",
        "attribute",
        "boolean",
        "case",
        "char",
        "component",
        "const",
        "consumes",
        "context",
        "custom",
        "default",
        "double",
        "emits",
        "enum",
        "eventtype",
        "exception",
        "factory",
        "false",
        "finder",
        "fixed",
        "float",
        "getraises",
        "home",
        "import",
        "in",
        "inout",
        "interface",
        "local",
        "long",
        "manages",
        "map",
        "module",
        "multiple",
        "native",
        "object",
        "octet",
        "oneway",
        "out",
        "primarykey",
        "private",
        "provides",
        "public",
        "publishes",
        "raises",
        "readonly",
        "sequence",
        "setraises",
        "short",
        "string",
        "struct",
        "supports",
        "switch",
        "truncatable",
        "typedef",
        "typeid",
        "typeprefix",
        "union",
        "unsigned",
        "uses",
        "valuebase",
        "valuetype",
        "void",
        "wchar",
        "wstring",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
        "bitfield",
        "bitmask",
        "bitset",
    }
)


def idl_document(typenames: Iterable[str], store: MessageStore | None = None) -> str:
    """IDL text declaring `typenames` and their dependencies (each once, dependencies first)."""
    store = store if store is not None else message_store()
    order: list[str] = []
    for typename in typenames:
        _visit(store, typename, order, ())
    blocks = [_struct(store, typename) for typename in order]
    header = (
        "// ROS 2 message types as DDS types (pkg::msg::dds_::Name_), generated from the message store.\n"
        f"// Types: {', '.join(order)}\n"
    )
    return header + "\n".join(blocks)


def idl_type_name(typename: str) -> str:
    """The IDL scoped name of message type `typename`: ``pkg::msg::dds_::Name_``."""
    return MessageStore.dds_type_name(typename)


def _visit(store: MessageStore, typename: str, order: list[str], path: tuple[str, ...]) -> None:
    if typename in order:
        return
    if typename in path:
        raise MessageError(typename, f"recursive message definition through {' -> '.join(path)}")
    for _, (kind, payload) in field_definitions(store, typename):
        for nested in _nested_types(kind, payload):
            _visit(store, nested, order, (*path, typename))
    order.append(typename)


def _nested_types(kind: int, payload: Any) -> list[str]:
    if kind == _NAME:
        return [str(payload)]
    if kind in (_ARRAY, _SEQUENCE):
        (sub_kind, sub_payload), _ = payload
        return [str(sub_payload)] if sub_kind == _NAME else []
    return []


def _struct(store: MessageStore, typename: str) -> str:
    pkg, kind, name = typename.split("/")
    members = [_member(typename, member, desc) for member, desc in field_definitions(store, typename)]
    if not members:
        members = ["octet structure_needs_at_least_one_member;"]
    body = "\n".join(f"      {m}" for m in members)
    return (
        f"module {pkg} {{\n  module {kind} {{\n    module dds_ {{\n"
        f"    @final struct {name}_ {{\n{body}\n    }};\n"
        "    };\n  };\n};\n"
    )


def _member(typename: str, name: str, desc: tuple[int, Any]) -> str:
    ident = f"{name}_" if name in IDL_KEYWORDS else name
    kind, payload = desc
    if kind in (_BASE, _NAME):
        return f"{_element(typename, name, kind, payload)} {ident};"
    (sub_kind, sub_payload), length = payload
    element = _element(typename, name, sub_kind, sub_payload)
    if kind == _ARRAY:
        return f"{element} {ident}[{int(length)}];"
    bound = f", {int(length)}" if int(length) else ""
    return f"sequence<{element}{bound}> {ident};"


def _element(typename: str, member: str, kind: int, payload: Any) -> str:
    if kind == _NAME:
        return idl_type_name(str(payload))
    if kind == _BASE:
        basename, bound = payload[0], int(payload[1])
        if basename == "string":
            return f"string<{bound}>" if bound else "string"
        if basename in IDL_PRIMITIVES:
            return IDL_PRIMITIVES[basename]
        raise MessageError(
            typename,
            f"member {member!r} is a {basename}, which has no IDL mapping here "
            f"(supported: string, {', '.join(IDL_PRIMITIVES)})",
        )
    raise MessageError(typename, f"member {member!r} is a nested collection, which ROS 2 messages cannot declare")
