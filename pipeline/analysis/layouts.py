"""The field layouts the columnar decoder (:mod:`pipeline.analysis.decode`) reads each recorded type with: the
field kinds (primitive, string, sequence, fixed-size array), :data:`LAYOUTS` for the types of ``schemas/`` and ROS 2
Jazzy as they are today, :data:`LEGACY_LAYOUTS` for older definitions recordings still carry, and the match of a
recording's own definition against them (:func:`layout_for`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys import get_types_from_msg

from pipeline.messages.errors import MessageError
from pipeline.messages.primitives import PRIMITIVES
from pipeline.messages.store import message_store


@dataclass(frozen=True)
class Prim:
    """A primitive field: `dtype` is a little-endian numpy type string (``<f8``, ``<u4``, ``u1``, ...)."""

    name: str
    dtype: str
    path: str
    keep: bool = True


@dataclass(frozen=True)
class Str:
    """A string field (uint32 length including the NUL, bytes, NUL)."""

    name: str
    path: str


@dataclass(frozen=True)
class Seq:
    """An unbounded sequence of a primitive type with at most 4-byte elements (uint32 count, elements)."""

    name: str
    dtype: str
    path: str


@dataclass(frozen=True)
class Fixed:
    """A fixed-size array of a primitive type (no count on the wire)."""

    name: str
    dtype: str
    count: int
    path: str
    keep: bool = False


Field = Prim | Str | Seq | Fixed


def _header(prefix: str = "header") -> tuple[Field, ...]:
    return (
        Prim("stamp_sec", "<i4", f"{prefix}.stamp.sec"),
        Prim("stamp_nanosec", "<u4", f"{prefix}.stamp.nanosec"),
        Str("frame_id", f"{prefix}.frame_id"),
    )


def _pose(path: str) -> tuple[Field, ...]:
    return tuple(Prim(n, "<f8", f"{path}.position.{n}") for n in ("x", "y", "z")) + tuple(
        Prim(f"q{n}", "<f8", f"{path}.orientation.{n}") for n in ("x", "y", "z", "w")
    )


def _twist(path: str) -> tuple[Field, ...]:
    prefix = f"{path}." if path else ""
    return tuple(
        Prim(f"{part}_{axis}", "<f8", f"{prefix}{part}.{axis}") for part in ("linear", "angular") for axis in "xyz"
    )


_SCAN_FLOATS = ("angle_min", "angle_max", "angle_increment", "time_increment", "scan_time", "range_min", "range_max")
_EPISODE_EVENT_V1: tuple[Field, ...] = (
    *_header(),
    Prim("episode", "<u4", "episode"),
    Prim("step", "<u4", "step"),
    Str("robot", "robot"),
    Prim("event", "u1", "event"),
    Str("detail", "detail"),
)

LAYOUTS: dict[str, tuple[Field, ...]] = {
    "geometry_msgs/msg/PoseStamped": (*_header(), *_pose("pose")),
    "nav_msgs/msg/Odometry": (
        *_header(),
        Str("child_frame_id", "child_frame_id"),
        *_pose("pose.pose"),
        Fixed("pose_covariance", "<f8", 36, "pose.covariance"),
        *_twist("twist.twist"),
        Fixed("twist_covariance", "<f8", 36, "twist.covariance"),
    ),
    "geometry_msgs/msg/Twist": _twist(""),
    "sensor_msgs/msg/LaserScan": (
        *_header(),
        *(Prim(n, "<f4", n) for n in _SCAN_FLOATS),
        Seq("ranges", "<f4", "ranges"),
        Seq("intensities", "<f4", "intensities"),
    ),
    "mrl_msgs/msg/Timing": (
        *_header(),
        Prim("kind", "u1", "kind"),
        Str("robot", "robot"),
        Str("topic", "topic"),
        Prim("source_stamp_ns", "<i8", "source_stamp_ns"),
        Prim("local_ns", "<i8", "local_ns"),
        Prim("seq", "<u8", "seq"),
        Prim("tick", "<u4", "tick"),
    ),
    "mrl_msgs/msg/EpisodeEvent": (*_EPISODE_EVENT_V1, Prim("seed", "<i8", "seed")),
    "mrl_msgs/msg/Action": (
        *_header(),
        Prim("episode", "<u4", "episode"),
        Prim("step", "<u4", "step"),
        Str("robot", "robot"),
        Seq("policy_output", "<f4", "policy_output"),
        Prim("linear_mps", "<f8", "linear_mps"),
        Prim("angular_radps", "<f8", "angular_radps"),
    ),
    "mrl_msgs/msg/Observation": (
        *_header(),
        Prim("episode", "<u4", "episode"),
        Prim("step", "<u4", "step"),
        Str("robot", "robot"),
        Str("layout", "layout"),
        Seq("values", "<f4", "values"),
    ),
    "mrl_msgs/msg/ResetRequest": (
        *_header(),
        Prim("episode", "<u4", "episode"),
        Prim("seed", "<u8", "seed"),
        Prim("done", "u1", "done"),
    ),
    "rosgraph_msgs/msg/Clock": (
        Prim("stamp_sec", "<i4", "clock.sec"),
        Prim("stamp_nanosec", "<u4", "clock.nanosec"),
    ),
}
"""Field lists (wire order) of every type :func:`decode` reads, as ``schemas/`` and ROS 2 Jazzy define them
today; `path` is the attribute path in a decoded message."""

LEGACY_LAYOUTS: dict[str, tuple[tuple[Field, ...], ...]] = {
    "mrl_msgs/msg/EpisodeEvent": (_EPISODE_EVENT_V1,),  # before the seed field
}
"""Older definitions of a type that recordings still carry; :func:`layout_for` picks by the file's schema."""

DECODABLE: frozenset[str] = frozenset(LAYOUTS)


# -- the layout of a recorded definition ------------------------------------------------------

_ROS_DTYPES: dict[str, str] = {name: p.wire for name, p in PRIMITIVES.items()}
"""Each primitive's numpy type on the CDR wire (:data:`pipeline.messages.primitives.PRIMITIVES`)."""
Leaves = tuple[tuple[str, str], ...]
"""(attribute path, wire type) of every primitive of a message in wire order: a numpy type string
(``<u4``), ``string``, or an element type with ``[]`` (sequence) or ``[n]`` (fixed-size array)."""


def _wire(kind: str) -> str | None:
    if kind == "string":
        return "string"
    dtype = _ROS_DTYPES.get(kind)
    return None if dtype is None else np.dtype(dtype).str


def _field_leaves(fields: tuple[Field, ...]) -> Leaves:
    """The :data:`Leaves` of a layout."""
    out: list[tuple[str, str]] = []
    for f in fields:
        if isinstance(f, Str):
            out.append((f.path, "string"))
        elif isinstance(f, Seq):
            out.append((f.path, f"{np.dtype(f.dtype).str}[]"))
        elif isinstance(f, Fixed):
            out.append((f.path, f"{np.dtype(f.dtype).str}[{f.count}]"))
        else:
            out.append((f.path, np.dtype(f.dtype).str))
    return tuple(out)


def _definition_leaves(typename: str, definitions: Mapping[str, Any], prefix: str = "") -> Leaves | None:
    """The :data:`Leaves` of `typename` as rosbags parsed it into `definitions` (nested types missing there: the
    message store's); None when a field has no layout here (a sequence of structures or of strings)."""
    if typename in definitions:
        fields = definitions[typename][1]
    elif message_store().has(typename):
        fields = message_store().field_definitions(typename)
    else:
        return None
    out: list[tuple[str, str]] = []
    for name, (node, detail) in fields:
        path = f"{prefix}{name}"
        if node == Nodetype.NAME:
            inner = _definition_leaves(detail, definitions, f"{path}.")
            if inner is None:
                return None
            out += inner
            continue
        if node == Nodetype.BASE:
            kind, suffix = _wire(detail[0]), ""
        elif node in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            (element_node, element), count = detail
            if element_node != Nodetype.BASE or element[0] == "string":
                return None
            kind, suffix = _wire(element[0]), ("[]" if node == Nodetype.SEQUENCE else f"[{count}]")
        else:
            return None
        if kind is None:
            return None
        out.append((path, kind + suffix))
    return tuple(out)


@lru_cache(maxsize=256)
def layout_for(typename: str, schema: str | None = None) -> tuple[Field, ...]:
    """The fields :func:`decode` reads `typename` with.

    Without `schema`: :data:`LAYOUTS`'s (the definition of ``schemas/`` and ROS 2 Jazzy). With
    `schema`, the ros2msg text a recording carries for the type (dependencies included, as MCAP
    and rosbag2 store it): the layout of LAYOUTS or :data:`LEGACY_LAYOUTS` with the same fields
    and wire types, e.g. an ``EpisodeEvent`` without its ``seed``. Comments and constants do not
    matter. Raises MessageError for a type outside :data:`DECODABLE` or a definition no layout fits.
    """
    current = LAYOUTS.get(typename)
    if current is None:
        raise MessageError(typename, f"no column decoder for {typename} (known: {', '.join(sorted(LAYOUTS))})")
    if schema is None:
        return current
    try:
        definitions = get_types_from_msg(schema, typename)
    except Exception as exc:  # the msg parser raises its own grammar errors
        raise MessageError(typename, f"the recorded definition of {typename} does not parse: {exc}") from exc
    leaves = _definition_leaves(typename, definitions)
    for fields in (current, *LEGACY_LAYOUTS.get(typename, ())):
        if leaves == _field_leaves(fields):
            return fields
    described = ", ".join(f"{_ros_name(kind)} {path}" for path, kind in leaves) if leaves else "fields without a layout"
    raise MessageError(typename, f"no column decoder for the recorded definition of {typename} ({described})")


def _ros_name(kind: str) -> str:
    """The ROS name of a wire type of :data:`Leaves` (``<f8[]`` -> ``float64[]``), for messages."""
    base, bracket, rest = kind.partition("[")
    names = {np.dtype(v).str: k for k, v in _ROS_DTYPES.items() if k not in ("bool", "byte", "char")}
    return names.get(base, base) + bracket + rest
