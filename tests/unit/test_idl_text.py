"""The IDL text of the ROS 2 contract that DDS peers built from IDL (fastddsgen) compile."""

from __future__ import annotations

import pytest

from pipeline.messages.errors import MessageError
from pipeline.messages.store import MessageStore
from pipeline.ros.idl_text import idl_document


def test_a_type_comes_after_the_types_it_uses_each_once():
    text = idl_document(["nav_msgs/msg/Odometry", "geometry_msgs/msg/Twist"])
    order = [line.split()[2] for line in text.splitlines() if "struct " in line]
    assert order.index("Time_") < order.index("Header_") < order.index("Odometry_")
    assert order.index("Vector3_") < order.index("Twist_") < order.index("TwistWithCovariance_")
    assert len(order) == len(set(order))
    assert "geometry_msgs::msg::dds_::Twist_ twist;" in text  # TwistWithCovariance's member
    assert "double covariance[36];" in text


def test_members_map_as_rosidl_maps_them(tmp_path):
    folder = tmp_path / "schemas" / "probe_msgs" / "msg"
    folder.mkdir(parents=True)
    (folder / "Probe.msg").write_text(
        "int8 small\nuint8[4] raw\nstring<=8 name\nfloat32[] values\nint64[<=3] few\nbool flag\nint32 module\n"
        "uint16 CONSTANT=3\n"
    )
    (folder / "Empty.msg").write_text("")
    store = MessageStore(tmp_path / "schemas")
    text = idl_document(["probe_msgs/msg/Probe", "probe_msgs/msg/Empty"], store)
    for line in (
        "char small;",
        "octet raw[4];",
        "string<8> name;",
        "sequence<float> values;",
        "sequence<long long, 3> few;",
        "boolean flag;",
        "long module_;",  # an IDL keyword gets a trailing underscore
        "octet structure_needs_at_least_one_member;",
    ):
        assert line in text, line
    assert "CONSTANT" not in text


def test_an_unknown_type_is_named():
    with pytest.raises(MessageError, match="nope_msgs/msg/Nope"):
        idl_document(["nope_msgs/msg/Nope"])
