"""DDS readers and writers carry the ROS 2 names, QoS, data representation and type hash."""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterator

import pytest
from cyclonedds.core import Policy

from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.ros import NetworkSettings, TransportError, open_transport
from pipeline.ros.dds import READER_MIN_DEPTH, DdsTransport, type_hash_user_data

_domains = itertools.count()


def fresh_domain_id() -> int:
    """A domain id unlikely to be in use by a parallel test run (ids 102..131 of this process)."""
    return 102 + (os.getpid() + next(_domains)) % 30


@pytest.fixture
def transport() -> Iterator[DdsTransport]:
    with open_transport("dds", NetworkSettings(domain_id=fresh_domain_id())) as t:
        assert isinstance(t, DdsTransport)
        yield t


SPECS = [*T.robot_topics("robot_1").values(), T.FLEET_TOPICS["tf"], T.FLEET_TOPICS["reset"]]


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s.name)
def test_writer_and_reader_qos_follow_the_topic_and_pin_xcdr1(transport: DdsTransport, spec: T.TopicSpec) -> None:
    writer = transport.publisher(spec).writer
    reader = transport.subscribe(spec, lambda *_: None).reader
    for entity in (writer, reader):
        qos = entity.get_qos()
        assert qos[Policy.Userdata] == Policy.Userdata(data=type_hash_user_data(spec.typename))
        assert qos[Policy.Userdata].data == f"typehash={message_store().rihs01(spec.typename)};".encode()
        assert qos[Policy.DataRepresentation] == Policy.DataRepresentation(use_cdrv0_representation=True)
    assert writer.get_qos()[Policy.History] == Policy.History.KeepLast(depth=spec.qos.depth)
    assert reader.get_qos()[Policy.History] == Policy.History.KeepLast(depth=max(spec.qos.depth, READER_MIN_DEPTH))
    for entity in (writer, reader):
        qos = entity.get_qos()
        if spec.qos.reliability == "reliable":
            assert isinstance(qos[Policy.Reliability], Policy.Reliability.Reliable)
        else:
            assert qos[Policy.Reliability] == Policy.Reliability.BestEffort
        durability = Policy.Durability.TransientLocal if spec.qos.durability == "transient_local" else None
        assert qos[Policy.Durability] == (durability or Policy.Durability.Volatile)
    assert writer.get_qos()[Policy.WriterDataLifecycle] == Policy.WriterDataLifecycle(autodispose=False)
    assert writer.topic.get_name() == "rt" + spec.name
    assert writer.topic.get_type_name() == message_store().dds_type_name(spec.typename)


def test_one_topic_name_cannot_carry_two_types(transport: DdsTransport) -> None:
    transport.publisher(T.TopicSpec("/robot_1/thing", T.TWIST, T.QOS_COMMAND))
    with pytest.raises(TransportError, match="/robot_1/thing: already carries geometry_msgs/msg/Twist"):
        transport.publisher(T.TopicSpec("/robot_1/thing", T.CLOCK, T.QOS_SENSOR))


def test_prepared_sends_are_the_bytes_the_writer_would_send():
    """publish_prepared writes the store's CDR; it must be exactly what DataWriter.write serializes."""
    from pipeline.messages import convert as C
    from pipeline.messages.topics import robot_topics
    from pipeline.ros.transport import NetworkSettings, open_transport

    with open_transport("dds", NetworkSettings(domain_id=199)) as transport:
        pub = transport.publisher(robot_topics("robot_1")["cmd_vel"])
        msg = C.twist(0.123, -0.2)
        sample = pub._dtype.to_dds(msg)  # what publish() would hand to DataWriter.write
        wire = sample.serialize(use_version_2=False)
        assert pub.prepare(msg) == wire.ljust((len(wire) + 3) & ~3, b"\0")
        pub.publish_prepared(pub.prepare(msg))
        pub.close()
        with pytest.raises(TransportError, match="closed"):
            pub.publish_prepared(pub.prepare(msg))
