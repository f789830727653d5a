"""The Cyclone DDS transport: plain ROS 2 Jazzy interoperability from Python, without rclpy.

What a ROS 2 node running ``rmw_cyclonedds_cpp`` expects of a peer, and what this backend does:

- topic ``rt<ROS name>`` with type ``pkg::msg::dds_::Name_`` (see :mod:`pipeline.ros.idl`): a
  final, keyless struct whose plain CDR equals the ROS 2 serialization;
- the data representation pinned to XCDR1 on every reader and writer (encapsulation 0x0001, the
  only one rmw_cyclonedds_cpp's type support allows);
- reliability, durability and keep-last depth from the :class:`~pipeline.messages.topics.TopicSpec`,
  automatic liveliness, no autodispose on writers (as rmw_cyclonedds_cpp's ``create_readwrite_qos``);
- the endpoint's USER_DATA ``typehash=RIHS01_<64 hex>;``, the text
  ``rmw_dds_common::encode_type_hash_for_user_data_qos`` builds and rmw_cyclonedds_cpp attaches
  to every reader and writer since Iron (:func:`type_hash_user_data`).

Discovery (:func:`cyclone_config`): with ``loopback_only`` the participant binds the loopback
interface and, since Linux's ``lo`` carries no multicast, finds peers by unicast: participant
index ``auto`` (at most 32 per host and domain), the peer 127.0.0.1 plus the configured peers.
This is the configuration rmw_cyclonedds_cpp builds for ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
with ``ROS_STATIC_PEERS``, so ROS 2 nodes started that way on this host see the pipeline. Without
``loopback_only`` Cyclone picks its default interface and multicast discovery, and unicast peers
are added. ``CYCLONEDDS_URI``, when set, is appended like rmw_cyclonedds_cpp does, so site
settings (interface, socket buffers) apply on top.

The participant also announces itself the way every ROS 2 RMW does: one node (``mrl_transport_<pid>_<n>`` in
``/``) on the DDS topic ``ros_discovery_info`` (``rmw_dds_common/msg/ParticipantEntitiesInfo``, reliable, transient
local, depth 1), listing the GUIDs of its readers and writers, rewritten whenever an endpoint comes or goes. So the
ROS 2 graph (``ros2 node list``, ``ros2 topic info -v``, ``get_publishers_info_by_topic``) ties the pipeline's
endpoints to a named node instead of a bare DDS participant.

Samples are delivered by one receive thread per transport that waits on the readers' read
conditions; samples without valid data (the notice DDS sends when a writer disappears) are
dropped and counted, never handed to a callback.
"""

from __future__ import annotations

import atexit
import itertools
import logging
import os
import threading
import time
import weakref
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np
from cyclonedds._clayer import ddspy_write  # the C write of serialized bytes that DataWriter.write ends in
from cyclonedds.core import (
    DDSException,
    GuardCondition,
    InstanceState,
    Policy,
    Qos,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from pipeline.messages.store import message_store
from pipeline.messages.topics import QosProfile, TopicSpec
from pipeline.ros.errors import TransportError
from pipeline.ros.idl import DdsType, dds_type
from pipeline.ros.transport import MessageCallback, NetworkSettings, Publisher, Subscription, Transport, check_topic

log = logging.getLogger(__name__)

MAX_AUTO_PARTICIPANT_INDEX = 32
"""Highest participant index probed by unicast discovery (rmw_cyclonedds_cpp's value for LOCALHOST)."""
RELIABLE_MAX_BLOCKING_S = 0.1
"""Longest a reliable ``publish`` waits for room in the writer's queue before it fails."""
TAKE_BATCH = 64
"""Samples taken from a reader per call."""
_WAIT_S = 0.5  # the receive thread re-checks for shutdown at least this often


def type_hash_user_data(typename: str) -> bytes:
    """USER_DATA of an endpoint of `typename`: ``typehash=RIHS01_<sha256 hex>;`` as ROS 2 Jazzy announces it."""
    return f"typehash={message_store().rihs01(typename)};".encode("ascii")


def parse_type_hash(user_data: bytes) -> str:
    """The ``RIHS01_...`` value of the ``typehash`` key in `user_data` (``key=value;`` pairs); '' if absent."""
    for item in user_data.decode("utf-8", "replace").split(";"):
        key, sep, value = item.partition("=")
        if sep and key.strip() == "typehash":
            return value.strip()
    return ""


READER_MIN_DEPTH = 100
"""Keep-last depth of every reader at least: a topic's depth (5 for sensors) is what its writer keeps; a reader
whose receive thread stalls for a few periods (a loaded machine, a twin at 3x) would otherwise overwrite samples
it has not taken, losses that no network made."""


def endpoint_qos(spec: TopicSpec, *, writer: bool) -> Qos:
    """The DDS QoS of a reader or writer of `spec`, as rmw_cyclonedds_cpp sets it for the same ROS QoS (a reader
    keeps at least `READER_MIN_DEPTH` samples)."""
    qos: QosProfile = spec.qos
    policies: list[Any] = [
        Policy.Reliability.Reliable(max_blocking_time=duration(seconds=RELIABLE_MAX_BLOCKING_S))
        if qos.reliability == "reliable"
        else Policy.Reliability.BestEffort,
        Policy.Durability.TransientLocal if qos.durability == "transient_local" else Policy.Durability.Volatile,
        Policy.History.KeepLast(depth=qos.depth if writer else max(qos.depth, READER_MIN_DEPTH)),
        Policy.Liveliness.Automatic(lease_duration=duration(infinite=True)),
        Policy.DataRepresentation(use_cdrv0_representation=True),
        Policy.Userdata(data=type_hash_user_data(spec.typename)),
    ]
    if writer:
        policies.append(Policy.WriterDataLifecycle(autodispose=False))
    return Qos(*policies)


def cyclone_config(settings: NetworkSettings, environ_uri: str | None = None) -> str:
    """The Cyclone DDS configuration of `settings`, then `environ_uri` (``CYCLONEDDS_URI``) if set.

    Comma-separated fragments, later ones refining earlier ones, as ``dds_create_domain`` reads them.
    """
    general = ""
    if settings.loopback_only:
        general = (
            '<General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
            "<AllowMulticast>false</AllowMulticast></General>"
        )
    elif settings.interface:  # the one of several that reaches the robots
        address = quoteattr(settings.interface_address())
        general = f"<General><Interfaces><NetworkInterface address={address}/></Interfaces></General>"
    peers = ("127.0.0.1", *settings.peers) if settings.loopback_only else settings.peers
    discovery = ""
    if peers:
        entries = "".join(f"<Peer address={quoteattr(peer)}/>" for peer in peers)
        discovery = (
            "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
            f"<MaxAutoParticipantIndex>{MAX_AUTO_PARTICIPANT_INDEX}</MaxAutoParticipantIndex>"
            f"<Peers>{entries}</Peers></Discovery>"
        )
    config = f'<CycloneDDS><Domain Id="any">{general}{discovery}</Domain></CycloneDDS>'
    if environ_uri:
        config += "," + environ_uri
    return config


class _Domains:
    """The DDS domains this process joined: one configuration per domain id, shared by its transports."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._open: dict[int, tuple[Domain, str, int]] = {}

    def acquire(self, domain_id: int, config: str) -> None:
        with self._lock:
            entry = self._open.get(domain_id)
            if entry is not None:
                domain, known, users = entry
                if known != config:
                    raise TransportError(
                        f"DDS domain {domain_id}",
                        "is already joined by this process with other network settings; "
                        "every transport of one process on one domain must use the same settings",
                    )
                self._open[domain_id] = (domain, known, users + 1)
                return
            try:
                domain = Domain(domain_id, config)
            except DDSException as exc:
                raise TransportError(
                    f"DDS domain {domain_id}",
                    f"cannot be joined with configuration {config!r}: {exc} "
                    "(a participant created outside the transport may already hold this domain)",
                ) from exc
            self._open[domain_id] = (domain, config, 1)

    def release(self, domain_id: int) -> None:
        with self._lock:
            entry = self._open.get(domain_id)
            if entry is None:
                return
            domain, config, users = entry
            if users > 1:
                self._open[domain_id] = (domain, config, users - 1)
            else:
                del self._open[domain_id]  # the last reference goes: Cyclone deletes the domain


_domains = _Domains()
_live_transports: weakref.WeakSet[DdsTransport] = weakref.WeakSet()


@atexit.register
def _close_live_transports() -> None:
    for transport in list(_live_transports):
        transport.close()


class DdsPublisher(Publisher):
    """A DDS writer of one topic; see :meth:`DdsTransport.publisher`."""

    def __init__(self, transport: DdsTransport, spec: TopicSpec, writer: DataWriter[Any], dtype: DdsType) -> None:
        super().__init__(spec)
        self._transport = transport
        self._writer: DataWriter[Any] | None = writer
        self._dtype = dtype
        self._msg_class = message_store().cls(spec.typename)

    @property
    def closed(self) -> bool:
        return self._writer is None

    @property
    def writer(self) -> DataWriter[Any]:
        """The underlying cyclonedds writer (for inspection: QoS, matches)."""
        if self._writer is None:
            raise TransportError(f"topic {self.spec.name}", "the publisher is closed")
        return self._writer

    def prepare(self, msg: Any) -> Any:
        """The wire bytes: the message store's CDR (byte-identical to the DDS encoding, tested), padded to 4."""
        if not isinstance(msg, self._msg_class):
            raise TransportError(
                f"topic {self.spec.name}", f"expected a {self.spec.typename} message, got {type(msg).__name__}"
            )
        data = message_store().serialize(msg, self.spec.typename)
        return data.ljust((len(data) + 3) & ~3, b"\0")

    def publish_prepared(self, prepared: Any) -> None:
        writer = self._writer
        if writer is None:
            raise TransportError(f"topic {self.spec.name}", "cannot publish: the publisher is closed")
        ret = ddspy_write(writer._ref, prepared)
        if ret < 0:
            raise TransportError(f"topic {self.spec.name}", f"DDS refused the sample (return code {ret})")

    def publish(self, msg: Any) -> None:
        writer = self._writer
        if writer is None:
            raise TransportError(f"topic {self.spec.name}", "cannot publish: the publisher is closed")
        if not isinstance(msg, self._msg_class):
            raise TransportError(
                f"topic {self.spec.name}", f"expected a {self.spec.typename} message, got {type(msg).__name__}"
            )
        try:
            sample = self._dtype.to_dds(msg)
            writer.write(sample)
        except DDSException as exc:
            raise TransportError(f"topic {self.spec.name}", f"DDS refused the sample: {exc}") from exc
        except Exception as exc:  # field values that do not fit their types surface as assorted errors
            detail = f"{exc}: {exc.__cause__}" if exc.__cause__ is not None else str(exc)
            raise TransportError(
                f"topic {self.spec.name}",
                f"a field of the {self.spec.typename} message does not fit its type ({detail})",
            ) from exc

    def close(self) -> None:
        if self._writer is not None:
            self._writer = None  # the last reference: cyclonedds deletes the writer
            self._transport._forget(self)


HANDLE_MASK = (1 << 64) - 1
"""DDS instance handles are 64-bit unsigned; cyclonedds hands matches out signed and sample infos unsigned."""


class DdsSubscription(Subscription):
    """A DDS reader of one topic whose samples the transport's receive thread hands to a callback."""

    def __init__(
        self,
        transport: DdsTransport,
        spec: TopicSpec,
        callback: MessageCallback,
        reader: DataReader[Any],
        condition: ReadCondition,
        dtype: DdsType,
    ) -> None:
        super().__init__(spec, callback)
        self._transport = transport
        self._reader: DataReader[Any] | None = reader
        self._condition: ReadCondition | None = condition
        self._dtype = dtype
        self._lock = threading.RLock()
        self.malformed = 0
        """Batches or samples that could not be decoded (a peer with another definition of the type name)."""

    @property
    def closed(self) -> bool:
        return self._reader is None

    @property
    def reader(self) -> DataReader[Any]:
        """The underlying cyclonedds reader (for inspection: QoS, matches)."""
        if self._reader is None:
            raise TransportError(f"topic {self.spec.name}", "the subscription is closed")
        return self._reader

    def close(self) -> None:
        with self._lock:
            if self._reader is None:
                return
            self._transport._forget(self)
            self._condition = None
            self._reader = None  # the last reference: cyclonedds deletes the reader

    def drain(self) -> None:
        """Takes every waiting sample and hands the valid ones to the callback (on the receive thread)."""
        with self._lock:
            while self._reader is not None:
                try:
                    samples = self._reader.take(N=TAKE_BATCH)
                except DDSException as exc:
                    log.warning("topic %s: take failed: %s", self.spec.name, exc)
                    return
                except Exception as exc:  # undecodable bytes; the read condition brings back any rest
                    self.malformed += 1
                    log.warning("topic %s: dropped undecodable samples: %s", self.spec.name, exc)
                    return
                if not samples:
                    return
                receive_time_ns = time.time_ns()
                for sample in samples:
                    if self.closed:  # by a callback
                        return
                    self._deliver(sample, receive_time_ns)
                if len(samples) < TAKE_BATCH:
                    return

    def writers(self, participant: str = "") -> frozenset[int]:
        """Instance handles of the remote writers matched with this reader (the publication handles of their
        samples); with `participant` (a participant GUID as text), only its writers."""
        with self._lock:
            reader = self._reader
            if reader is None:
                return frozenset()
            own = self._transport.participant.guid
            found = set()
            try:
                for handle in reader.get_matched_publications():
                    data = reader.get_matched_publication_data(handle)
                    if data is None or data.participant_key == own:
                        continue
                    if participant and str(data.participant_key) != participant:
                        continue
                    found.add(int(handle) & HANDLE_MASK)  # the matches read signed, sample infos unsigned
            except DDSException as exc:
                raise TransportError(f"topic {self.spec.name}", f"cannot read the DDS matches: {exc}") from exc
            return frozenset(found)

    def _deliver(self, sample: Any, receive_time_ns: int) -> None:
        if not sample.sample_info.valid_data:
            self.dropped_invalid += 1
            return
        if not self._admits(int(sample.sample_info.publication_handle) & HANDLE_MASK):
            return
        try:
            msg = self._dtype.from_dds(sample)
        except Exception as exc:
            self.malformed += 1
            log.warning("topic %s: cannot convert a sample: %s", self.spec.name, exc)
            return
        self._hand_on(msg, receive_time_ns)


PARTICIPANT_INFO = "rmw_dds_common/msg/ParticipantEntitiesInfo"
DISCOVERY_INFO = TopicSpec("/ros_discovery_info", PARTICIPANT_INFO, QosProfile("reliable", "transient_local", 1))
"""The graph topic of ROS 2's RMWs (its DDS name has no ``rt`` prefix: ``ros_discovery_info``)."""
DISCOVERY_INFO_DDS_NAME = "ros_discovery_info"
_node_ids = itertools.count()


class DdsTransport(Transport):
    """A Cyclone DDS participant speaking the ROS 2 contract (see the module notes)."""

    def __init__(self, settings: NetworkSettings) -> None:
        super().__init__(settings)
        self.config = cyclone_config(settings, os.environ.get("CYCLONEDDS_URI") or None)
        self._topics: dict[str, tuple[Topic[Any], str]] = {}
        _domains.acquire(settings.domain_id, self.config)
        try:
            self._participant: DomainParticipant | None = DomainParticipant(settings.domain_id)
            self._waitset: WaitSet | None = WaitSet(self._participant)
            self._wakeup: GuardCondition | None = GuardCondition(self._participant)
            self._waitset.attach(self._wakeup)
        except DDSException as exc:
            self._participant = self._waitset = self._wakeup = None
            _domains.release(settings.domain_id)
            raise TransportError(f"DDS domain {settings.domain_id}", f"cannot create a participant: {exc}") from exc
        self.node_name = f"mrl_transport_{os.getpid()}_{next(_node_ids)}"
        """The ROS 2 node this participant announces (in the namespace ``/``)."""
        self._graph: DdsPublisher | None = None
        try:
            dtype = dds_type(PARTICIPANT_INFO)
            topic = Topic(self._participant, DISCOVERY_INFO_DDS_NAME, dtype.idl_class)
            writer: DataWriter[Any] = DataWriter(
                self._participant, topic, qos=endpoint_qos(DISCOVERY_INFO, writer=True)
            )
            self._graph = DdsPublisher(self, DISCOVERY_INFO, writer, dtype)
            self._announce()
        except DDSException as exc:
            self._participant = self._waitset = self._wakeup = None
            _domains.release(settings.domain_id)
            raise TransportError(f"DDS domain {settings.domain_id}", f"cannot announce the node: {exc}") from exc
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._receive, name=f"dds-receive-{settings.domain_id}", daemon=True)
        self._thread.start()
        _live_transports.add(self)

    @property
    def participant(self) -> DomainParticipant:
        """The underlying cyclonedds participant."""
        if self._participant is None:
            raise TransportError(f"DDS domain {self.settings.domain_id}", "the transport is closed")
        return self._participant

    def publisher(self, spec: TopicSpec) -> DdsPublisher:
        check_topic(spec)
        with self._lock:
            topic, dtype = self._topic(spec)
            try:
                writer: DataWriter[Any] = DataWriter(self.participant, topic, qos=endpoint_qos(spec, writer=True))
            except DDSException as exc:
                raise TransportError(f"topic {spec.name}", f"cannot create a DDS writer: {exc}") from exc
            pub = DdsPublisher(self, spec, writer, dtype)
            self._keep(pub)
            self._announce()
            return pub

    def subscribe(self, spec: TopicSpec, callback: MessageCallback) -> DdsSubscription:
        check_topic(spec)
        self._check_callback(spec, callback)
        with self._lock:
            topic, dtype = self._topic(spec)
            try:
                reader: DataReader[Any] = DataReader(self.participant, topic, qos=endpoint_qos(spec, writer=False))
                condition = ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any)
            except DDSException as exc:
                raise TransportError(f"topic {spec.name}", f"cannot create a DDS reader: {exc}") from exc
            sub = DdsSubscription(self, spec, callback, reader, condition, dtype)
            self._keep(sub)
            assert self._waitset is not None
            self._waitset.attach(condition)
            self._wake()
            self._announce()
            return sub

    def identity(self) -> str:
        return str(self.participant.guid)

    def matched_count(self, spec: TopicSpec) -> int:
        with self._lock:
            pubs, subs = self._on_topic(spec)
            writers = [p.writer for p in pubs if isinstance(p, DdsPublisher)]
            readers = [s.reader for s in subs if isinstance(s, DdsSubscription)]
            own = self.participant.guid
        remote: set[Any] = set()
        try:
            for writer in writers:
                for handle in writer.get_matched_subscriptions():
                    data = writer.get_matched_subscription_data(handle)
                    if data is not None and data.participant_key != own:
                        remote.add(data.key)
            for reader in readers:
                for handle in reader.get_matched_publications():
                    data = reader.get_matched_publication_data(handle)
                    if data is not None and data.participant_key != own:
                        remote.add(data.key)
        except DDSException as exc:
            raise TransportError(f"topic {spec.name}", f"cannot read the DDS matches: {exc}") from exc
        return len(remote)

    def close(self) -> None:
        endpoints = self._closing()
        if endpoints is None:
            return
        with self._lock:
            self._stop.set()
            self._wake()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=5.0)
        for endpoint in endpoints:
            endpoint.close()
        with self._lock:
            if self._graph is not None:
                self._graph.close()
                self._graph = None
            if self._waitset is not None and self._wakeup is not None:
                self._waitset.detach(self._wakeup)
            self._topics.clear()
            # dropping the last references deletes the entities, the participant last
            self._waitset = self._wakeup = None
            self._participant = None
        _domains.release(self.settings.domain_id)
        _live_transports.discard(self)

    # internals

    def _topic(self, spec: TopicSpec) -> tuple[Topic[Any], DdsType]:
        dtype = dds_type(spec.typename)
        known = self._topics.get(spec.dds_name)
        if known is not None:
            topic, typename = known
            if typename != spec.typename:
                raise TransportError(
                    f"topic {spec.name}", f"already carries {typename} in this transport; asked for {spec.typename}"
                )
            return topic, dtype
        try:
            topic = Topic(self.participant, spec.dds_name, dtype.idl_class)
        except DDSException as exc:
            raise TransportError(f"topic {spec.name}", f"cannot create the DDS topic {spec.dds_name}: {exc}") from exc
        self._topics[spec.dds_name] = (topic, spec.typename)
        return topic, dtype

    def _forget(self, endpoint: DdsPublisher | DdsSubscription) -> None:
        with self._lock:
            if self._drop(endpoint):
                self._announce()
            if isinstance(endpoint, DdsPublisher):
                return
            if self._waitset is not None and endpoint._condition is not None:
                self._waitset.detach(endpoint._condition)

    def participant_info(self) -> Any:
        """This participant's ``rmw_dds_common/msg/ParticipantEntitiesInfo``: its node and the node's endpoints."""
        store = message_store()
        gid = store.cls("rmw_dds_common/msg/Gid")

        def gid_of(guid: Any) -> Any:
            return gid(data=np.frombuffer(guid.bytes, dtype=np.uint8).copy())

        with self._lock:
            subs = [s for s in self._subscriptions if isinstance(s, DdsSubscription) and not s.closed]
            pubs = [p for p in self._publishers if isinstance(p, DdsPublisher) and not p.closed]
            readers = [gid_of(s.reader.guid) for s in subs]
            writers = [gid_of(p.writer.guid) for p in pubs]
            node = store.cls("rmw_dds_common/msg/NodeEntitiesInfo")(
                node_namespace="/", node_name=self.node_name, reader_gid_seq=readers, writer_gid_seq=writers
            )
            return store.cls(PARTICIPANT_INFO)(gid=gid_of(self.participant.guid), node_entities_info_seq=[node])

    def _announce(self) -> None:
        """Writes :meth:`participant_info` on ``ros_discovery_info`` (a writer keeps the last one for late joiners)."""
        with self._lock:
            if self._graph is None or self._graph.closed or self._participant is None:
                return
            try:
                self._graph.publish_prepared(self._graph.prepare(self.participant_info()))
            except TransportError as exc:  # the graph is a courtesy to ROS 2 tools: data still flows without it
                log.warning("DDS domain %d: cannot announce the node: %s", self.settings.domain_id, exc)

    def _wake(self) -> None:
        if self._wakeup is not None:
            self._wakeup.set(True)

    def _receive(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                waitset, wakeup = self._waitset, self._wakeup
            if waitset is None or wakeup is None:
                return
            try:
                waitset.wait(duration(seconds=_WAIT_S))
                wakeup.set(False)
            except DDSException as exc:
                if self._stop.is_set():
                    return
                log.warning("DDS domain %d: wait failed: %s", self.settings.domain_id, exc)
                time.sleep(0.01)
                continue
            with self._lock:
                subscriptions = tuple(s for s in self._subscriptions if isinstance(s, DdsSubscription))
            for sub in subscriptions:
                if self._stop.is_set():
                    return
                sub.drain()
