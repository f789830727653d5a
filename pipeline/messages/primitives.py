"""ROS 2's primitive field types, once: what the message store's types are built of, and what each becomes in the
IDL text the interface packages are generated from (:mod:`pipeline.ros.idl_text`), in the DDS types
(:mod:`pipeline.ros.idl`) and in the columnar decoder's reads of raw CDR (:mod:`pipeline.analysis.decode`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Primitive:
    """One primitive type: its bytes on the little-endian CDR wire as a numpy type string (``bool`` as its byte),
    the numpy element type of an array of it (as rosbags deserializes one), and its IDL type."""

    wire: str
    element: type[np.generic]
    idl: str

    @property
    def octet(self) -> bool:
        """One unsigned byte each (IDL ``octet``): an array of them travels as raw bytes."""
        return self.idl == "octet"


PRIMITIVES: dict[str, Primitive] = {
    "bool": Primitive("u1", np.bool_, "boolean"),
    "byte": Primitive("u1", np.uint8, "octet"),
    "char": Primitive("u1", np.uint8, "octet"),  # ROS 2 maps msg `char` to an unsigned byte
    "int8": Primitive("i1", np.int8, "char"),  # one signed byte in plain CDR, as rosidl's int8
    "uint8": Primitive("u1", np.uint8, "octet"),
    "int16": Primitive("<i2", np.int16, "short"),
    "uint16": Primitive("<u2", np.uint16, "unsigned short"),
    "int32": Primitive("<i4", np.int32, "long"),
    "uint32": Primitive("<u4", np.uint32, "unsigned long"),
    "int64": Primitive("<i8", np.int64, "long long"),
    "uint64": Primitive("<u8", np.uint64, "unsigned long long"),
    "float32": Primitive("<f4", np.float32, "float"),
    "float64": Primitive("<f8", np.float64, "double"),
}
"""Every ROS 2 primitive field type by its ``.msg`` name (``string`` is not one: it has a length)."""
