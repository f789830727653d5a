"""The message store: definitions, ROS 2 type hashes and CDR for every type the pipeline records or sends."""

from __future__ import annotations

from collections.abc import Iterable
from functools import cache
from pathlib import Path
from typing import Any

from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import TypesysError
from rosbags.typesys.store import Typestore

from pipeline.messages.errors import MessageError, SchemaError

SCHEMAS_DIR = Path(__file__).resolve().parents[2] / "schemas"
"""The ``schemas/`` folder of the repository: ``<package>/msg/<Name>.msg`` files."""


def schema_files(folder: Path = SCHEMAS_DIR) -> dict[str, Path]:
    """Type names (``pkg/msg/Name``) -> their .msg files under `folder`."""
    if not folder.is_dir():
        raise SchemaError(str(folder), "the schemas folder does not exist (run from a checkout of the repository)")
    out = {}
    for path in sorted(folder.rglob("*.msg")):
        rel = path.relative_to(folder).with_suffix("")
        if len(rel.parts) != 3 or rel.parts[1] != "msg":
            raise SchemaError(str(path), "a schema file must live at <package>/msg/<Name>.msg")
        out["/".join(rel.parts)] = path
    return out


class MessageStore:
    """ROS 2 Jazzy standard types plus the definitions in ``schemas/``, checked against each other.

    Messages are the store's generated dataclasses (``store.new(typename, **fields)``); numpy
    arrays stand for ``float32[]`` and similar sequences.
    """

    def __init__(self, folder: Path = SCHEMAS_DIR) -> None:
        self.folder = folder
        self._ts = get_typestore(Stores.ROS2_JAZZY)
        self.files = schema_files(folder)
        for typename, path in self.files.items():
            try:
                defs = get_types_from_msg(path.read_text(encoding="utf-8"), typename)
            except Exception as exc:  # rosbags raises several parser errors
                raise SchemaError(str(path), f"not a valid ROS 2 message definition: {exc}") from exc
            try:
                self._ts.register(defs)
            except TypesysError as exc:
                raise SchemaError(str(path), f"disagrees with the ROS 2 Jazzy definition of {typename}: {exc}") from exc

    @property
    def typenames(self) -> tuple[str, ...]:
        """Every type defined in ``schemas/``."""
        return tuple(self.files)

    def has(self, typename: str) -> bool:
        return typename in self._ts.types

    def cls(self, typename: str) -> Any:
        """The message class of `typename`."""
        try:
            return self._ts.types[typename]
        except KeyError:
            known = ", ".join(self.typenames)
            raise MessageError(typename, f"unknown message type; schemas/ defines {known}") from None

    def new(self, typename: str, **fields: Any) -> Any:
        """A message of `typename` from its fields."""
        return self.cls(typename)(**fields)

    def field_definitions(self, typename: str) -> list[tuple[str, Any]]:
        """The fields of `typename` (constants excluded) as rosbags describes them: (name, (node type, detail))."""
        self.cls(typename)
        return list(self._ts.fielddefs[typename][1])

    def msgdef(self, typename: str) -> str:
        """The ``ros2msg`` schema text of `typename` with its dependencies, as rosbag2 stores it."""
        self.cls(typename)
        return str(self._ts.generate_msgdef(typename, ros_version=2)[0])

    def rihs01(self, typename: str) -> str:
        """The ROS 2 type hash (``RIHS01_<sha256 hex>``) that Jazzy announces for `typename`.

        rosidl describes a ``char`` field as ``uint8`` (the IDL mapping of msg ``char``), where rosbags' hash keeps a
        char: the hash is computed over the definitions with that mapping (``rmw_dds_common/msg/Gid`` has one)."""
        self.cls(typename)
        return str(self._hash_store().hash_rihs01(typename))

    @cache  # noqa: B019 - one store per process (message_store), kept for its lifetime
    def _hash_store(self) -> Typestore:
        def as_rosidl(node: Any) -> Any:
            kind, payload = node
            if kind == Nodetype.BASE and payload[0] == "char":
                return (kind, ("uint8", payload[1]))
            if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
                return (kind, (as_rosidl(payload[0]), payload[1]))
            return node

        store = get_typestore(Stores.EMPTY)
        store.register(
            {
                name: (consts, [(field, as_rosidl(node)) for field, node in fields])
                for name, (consts, fields) in self._ts.fielddefs.items()
            }
        )
        return store

    @staticmethod
    def dds_type_name(typename: str) -> str:
        """The DDS type name ROS 2 uses: ``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_``."""
        pkg, kind, name = typename.split("/")
        return f"{pkg}::{kind}::dds_::{name}_"

    def prepare(self, typenames: Iterable[str]) -> None:
        """Makes the (de)serializers of `typenames` now: the type store generates a type's code at its first use
        (milliseconds per type), and a recorder that prepares its topics' types when it opens does not spend that
        inside its first control steps."""
        for typename in dict.fromkeys(typenames):
            self.cls(typename)
            self._ts.get_msgdef(typename)

    def prepared(self, typename: str) -> bool:
        """Whether the (de)serializers of `typename` are made (:meth:`prepare`, or a message of it seen)."""
        return typename in self._ts.cache

    def serialize(self, msg: Any, typename: str) -> bytes:
        """Little-endian plain CDR (XCDR1, with the 4-byte encapsulation header) of `msg`."""
        try:
            return bytes(self._ts.serialize_cdr(msg, typename))
        except Exception as exc:  # wrong field types surface as assorted struct/attribute errors
            raise MessageError(typename, f"cannot serialize {type(msg).__name__}: {exc}") from exc

    def deserialize(self, data: bytes | memoryview, typename: str) -> Any:
        """The message of `typename` encoded in CDR `data`; malformed bytes raise MessageError."""
        self.cls(typename)
        try:
            return self._ts.deserialize_cdr(bytes(data), typename)
        except Exception as exc:  # truncated or garbled buffers surface as struct/index errors
            raise MessageError(typename, f"malformed CDR ({len(data)} bytes): {exc}") from exc

    def serialize_ros1(self, msg: Any, typename: str) -> bytes:
        """ROS 1 serialization of `msg` (a ``std_msgs/Header`` gains ``seq`` 0), as a ROS 1 node sends it."""
        try:
            # through CDR: the type store's conversion is the one that gives a Header its ROS 1 seq
            return bytes(self._ts.cdr_to_ros1(self._ts.serialize_cdr(msg, typename), typename))
        except Exception as exc:
            raise MessageError(typename, f"cannot serialize {type(msg).__name__} for ROS 1: {exc}") from exc

    def deserialize_ros1(self, data: bytes | memoryview, typename: str) -> Any:
        """The message of `typename` in ROS 1 serialization `data` (a Header's ``seq`` dropped)."""
        self.cls(typename)
        try:
            return self._ts.deserialize_cdr(self._ts.ros1_to_cdr(bytes(data), typename), typename)
        except Exception as exc:
            raise MessageError(typename, f"malformed ROS 1 message ({len(data)} bytes): {exc}") from exc


@cache
def message_store() -> MessageStore:
    """The process-wide store built from the repository's ``schemas/``."""
    return MessageStore()
