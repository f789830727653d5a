"""The DDS types put on the wire exactly the CDR of the message store, for every type of the contract."""

from __future__ import annotations

import dataclasses
import re
import typing
from typing import Any

import numpy as np
import pytest
from cyclonedds.idl import Endianness, IdlStruct

from pipeline.messages import topics as T
from pipeline.messages.errors import MessageError
from pipeline.messages.store import message_store
from pipeline.ros.idl import DdsType, dds_type, field_definitions

CONTRACT_TYPES = sorted({spec.typename for spec in T.fleet_topics(["robot_1"]).values()})

_INT_RANGES = {
    "int8": (-(2**7), 2**7 - 1),
    "uint8": (0, 2**8 - 1),
    "byte": (0, 2**8 - 1),
    "char": (0, 2**8 - 1),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1),
}
_DTYPES = {"bool": np.bool_, "byte": np.uint8, "char": np.uint8, "float32": np.float32, "float64": np.float64}
_TEXT = list("abcxyz_/ -.0189éπ漢")


def _random_base(rng: np.random.Generator, basename: str) -> Any:
    if basename == "string":
        return "".join(rng.choice(_TEXT, size=int(rng.integers(0, 16))))
    if basename == "bool":
        return bool(rng.integers(0, 2))
    if basename in _INT_RANGES:
        lo, hi = _INT_RANGES[basename]
        return int(lo + int(rng.integers(0, 2**62)) * (hi - lo) // (2**62 - 1))
    if basename == "float32":
        return float(np.float32(rng.normal(0.0, 100.0)))
    return float(rng.normal(0.0, 1e4))


def random_message(typename: str, rng: np.random.Generator) -> Any:
    """A message of `typename` with random values in every field, sequences of random length."""
    store = message_store()
    fields: dict[str, Any] = {}
    for name, (kind, payload) in field_definitions(store, typename):
        if kind == 1:
            fields[name] = _random_base(rng, payload[0])
        elif kind == 2:
            fields[name] = random_message(payload, rng)
        else:
            (sub_kind, sub_payload), length = payload
            count = length if kind == 3 else int(rng.integers(0, 40))
            if sub_kind == 1 and sub_payload[0] != "string":
                dtype = _DTYPES.get(sub_payload[0], sub_payload[0])
                fields[name] = np.array([_random_base(rng, sub_payload[0]) for _ in range(count)], dtype=dtype)
            elif sub_kind == 1:
                fields[name] = [_random_base(rng, "string") for _ in range(count)]
            else:
                fields[name] = [random_message(sub_payload, rng) for _ in range(count)]
    return store.new(typename, **fields)


def assert_same_message(a: Any, b: Any, where: str = "msg") -> None:
    """Field-by-field equality; numpy arrays must agree in dtype and bits."""
    assert type(a) is type(b), f"{where}: {type(a).__name__} != {type(b).__name__}"
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype, f"{where}: dtype {a.dtype} != {b.dtype}"
        assert a.tobytes() == b.tobytes(), f"{where}: {a} != {b}"
    elif isinstance(a, list):
        assert len(a) == len(b), f"{where}: length {len(a)} != {len(b)}"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same_message(x, y, f"{where}[{i}]")
    elif dataclasses.is_dataclass(a):
        for field in dataclasses.fields(a):
            assert_same_message(getattr(a, field.name), getattr(b, field.name), f"{where}.{field.name}")
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


def wire_bytes(dtype: DdsType, msg: Any) -> bytes:
    """The serialized sample a cyclonedds writer pinned to XCDR1 hands to the network, before padding."""
    return dtype.to_dds(msg).serialize(endianness=Endianness.Little, use_version_2=False)


def nested_idl_classes(cls: type[IdlStruct]) -> list[type[IdlStruct]]:
    """`cls` and every struct type reachable from its members."""
    found = [cls]
    for annotation in typing.get_type_hints(cls, include_extras=True).values():
        for part in [annotation, *typing.get_args(annotation), *_annotated_subtypes(annotation)]:
            if isinstance(part, type) and issubclass(part, IdlStruct) and part not in found:
                found.extend(c for c in nested_idl_classes(part) if c not in found)
    return found


def _annotated_subtypes(annotation: Any) -> list[Any]:
    return [getattr(meta, "subtype", None) for meta in getattr(annotation, "__metadata__", ())]


@pytest.mark.parametrize("typename", CONTRACT_TYPES)
def test_wire_bytes_equal_store_cdr(typename: str) -> None:
    rng = np.random.default_rng(sum(map(ord, typename)))
    dtype = dds_type(typename)
    for _ in range(25):
        msg = random_message(typename, rng)
        expected = message_store().serialize(msg, typename)
        got = wire_bytes(dtype, msg)
        assert got[:4] == b"\x00\x01\x00\x00", "plain CDR, little endian (encapsulation 0x0001)"
        assert got == expected


@pytest.mark.parametrize("typename", CONTRACT_TYPES)
def test_round_trip_store_dds_store_is_exact(typename: str) -> None:
    rng = np.random.default_rng(7 + len(typename))
    dtype = dds_type(typename)
    for _ in range(25):
        msg = random_message(typename, rng)
        data = wire_bytes(dtype, msg)
        back = dtype.from_dds(dtype.idl_class.deserialize(data))
        assert_same_message(msg, back)
        assert message_store().serialize(back, typename) == data


@pytest.mark.parametrize("typename", CONTRACT_TYPES)
def test_types_are_final_keyless_without_optionals_and_named_like_ros(typename: str) -> None:
    cls = dds_type(typename).idl_class
    assert cls.__idl_typename__ == message_store().dds_type_name(typename)
    for struct in nested_idl_classes(cls):
        assert re.fullmatch(r"[a-z0-9_]+::msg::dds_::[A-Za-z0-9]+_", struct.__idl_typename__)
        assert struct.__idl_annotations__.get("extensibility") == "final"
        assert "keylist" not in struct.__idl_annotations__
        assert not any("key" in a for a in struct.__idl_field_annotations__.values())
        for annotation in typing.get_type_hints(struct, include_extras=True).values():
            assert type(None) not in typing.get_args(annotation), f"{struct.__idl_typename__}: optional member"
        struct.__idl__.populate()
        assert struct.__idl__.keyless


def test_twist_is_named_like_rmw_cyclonedds() -> None:
    assert dds_type(T.TWIST).dds_name == "geometry_msgs::msg::dds_::Twist_"
    assert dds_type(T.LASER_SCAN).dds_name == "sensor_msgs::msg::dds_::LaserScan_"


def test_float_sequences_come_back_as_float32_arrays() -> None:
    rng = np.random.default_rng(3)
    scan = random_message(T.LASER_SCAN, rng)
    scan.ranges = rng.uniform(0.05, 5.0, 360).astype(np.float32)
    dtype = dds_type(T.LASER_SCAN)
    back = dtype.from_dds(dtype.idl_class.deserialize(wire_bytes(dtype, scan)))
    assert back.ranges.dtype == np.float32 and back.ranges.shape == (360,)
    assert np.array_equal(back.ranges, scan.ranges)


def test_fixed_covariance_arrays_keep_their_length() -> None:
    dtype = dds_type(T.ODOMETRY)
    msg = random_message(T.ODOMETRY, np.random.default_rng(5))
    msg.pose.covariance = np.zeros(35)
    with pytest.raises(ValueError, match="'covariance' holds 35 values; its type takes exactly 36"):
        dtype.to_dds(msg)


def test_unknown_type_is_a_message_error() -> None:
    with pytest.raises(MessageError, match="unknown message type"):
        dds_type("nope_msgs/msg/Nothing")


def test_the_primitive_types_are_one_table_under_the_dds_types_the_idl_text_and_the_decoder() -> None:
    """Each primitive's bytes agree everywhere: the decoder's wire type, the array element type, the IDL type."""
    from pipeline.analysis.layouts import _ROS_DTYPES
    from pipeline.messages.primitives import PRIMITIVES
    from pipeline.ros.idl import _NUMPY, _OCTETS, _PRIMITIVES
    from pipeline.ros.idl_text import IDL_PRIMITIVES

    assert set(_ROS_DTYPES) == set(_NUMPY) == set(_PRIMITIVES) == set(IDL_PRIMITIVES) == set(PRIMITIVES)
    sizes = {"boolean": 1, "octet": 1, "char": 1, "short": 2, "long": 4, "long long": 8, "float": 4, "double": 8}
    for name, p in PRIMITIVES.items():
        wire, element = np.dtype(p.wire), np.dtype(p.element)
        assert wire.itemsize == element.itemsize == sizes[p.idl.removeprefix("unsigned ")], name
        if name != "bool":
            assert wire.kind == element.kind, name  # signed, unsigned or float alike
    assert sorted(_OCTETS) == ["byte", "char", "uint8"]
