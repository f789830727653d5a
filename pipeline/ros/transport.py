"""The network transport interface shared by the Cyclone DDS, rclpy and ROS 1 (rospy) backends.

A :class:`Transport` joins one ROS 2 domain (or one ROS 1 master) and gives publishers and subscriptions for the
topics of the contract (:class:`~pipeline.messages.topics.TopicSpec`). Messages are the message
store's objects (``message_store().new(...)`` or the builders in ``pipeline.messages.convert``).

Threading: ``publish`` may be called from any thread. Subscription callbacks run on a thread
owned by the transport, one sample at a time and in arrival order per subscription; a callback
that blocks holds up every subscription of its transport, so hand work to a queue. Exceptions
raised by a callback are logged and counted (:attr:`Subscription.callback_errors`) and do not stop
delivery. Times are integer nanoseconds since the Unix epoch (``time.time_ns()``).
"""

from __future__ import annotations

import fcntl
import importlib
import ipaddress
import logging
import re
import socket
import struct
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any, Literal

from pipeline.messages.store import message_store
from pipeline.messages.topics import TopicSpec
from pipeline.ros.errors import NetworkSettingsError, TransportError

log = logging.getLogger(__name__)

BackendKind = Literal["dds", "rclpy", "ros1"]
BACKENDS: tuple[BackendKind, ...] = ("dds", "rclpy", "ros1")

MAX_DOMAIN_ID = 232
"""Largest ROS 2 domain id (ports of higher ids overflow the RTPS port mapping on Linux)."""

MessageCallback = Callable[[TopicSpec, Any, int], None]
"""``callback(spec, msg, receive_time_ns)``: one valid sample of `spec` taken at `receive_time_ns`."""


_HOSTNAME = re.compile(
    r"^(?=.{1,253}$)[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?(?:\.[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*$"
)
_PEER_FORM = "an IPv4 address or host name, optionally with :port (1..65535), e.g. '192.168.1.20' or 'robot-1.local'"


@dataclass(frozen=True)
class NetworkSettings:
    """Where a transport looks for its peers.

    `domain_id` is the ROS 2 domain (``ROS_DOMAIN_ID``), 0..232. With `loopback_only` the
    transport uses the loopback interface only and finds peers on this host by unicast (like
    ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``); `peers` are extra unicast discovery addresses
    (like ``ROS_STATIC_PEERS``), which must themselves be loopback addresses when `loopback_only`.
    `master_uri` is the ROS 1 master (``http://HOST:PORT``; empty: ``ROS_MASTER_URI``), used by the
    ros1 transport only; there `loopback_only` makes the node advertise 127.0.0.1 (``ROS_IP``).
    `interface` (a network interface of this host by name, e.g. ``eth1``, or one of its IPv4 addresses) is the one
    the transport uses where the host has several: DDS binds it (Cyclone's ``NetworkInterface``; otherwise it picks
    one "arbitrarily" and advertises that one's address), ROS 1 advertises its address (``ROS_IP``). Checked against
    the host's interfaces, and the peers against its names and routes, by :meth:`check_host` as a transport opens.
    """

    domain_id: int = 0
    loopback_only: bool = True
    peers: tuple[str, ...] = field(default=())
    master_uri: str = ""
    interface: str = ""

    def __post_init__(self) -> None:
        if isinstance(self.domain_id, bool) or not isinstance(self.domain_id, int):
            raise NetworkSettingsError("domain_id", self.domain_id, f"must be an integer in 0..{MAX_DOMAIN_ID}")
        if not 0 <= self.domain_id <= MAX_DOMAIN_ID:
            raise NetworkSettingsError("domain_id", self.domain_id, f"must be in 0..{MAX_DOMAIN_ID}")
        if not isinstance(self.loopback_only, bool):
            raise NetworkSettingsError("loopback_only", self.loopback_only, "must be true or false")
        given: object = self.peers  # settings often come from parsed YAML
        if isinstance(given, str) or not isinstance(given, Sequence):
            raise NetworkSettingsError("peers", given, f"must be a list of addresses, each {_PEER_FORM}")
        peers = tuple(given)
        for i, peer in enumerate(peers):
            host = _check_peer(f"peers[{i}]", peer)
            if self.loopback_only and not _is_loopback(host):
                raise NetworkSettingsError(
                    f"peers[{i}]",
                    peer,
                    "is not a loopback address, which loopback_only = true cannot reach; "
                    "set loopback_only to false to talk to other hosts",
                )
        object.__setattr__(self, "peers", peers)
        if not isinstance(self.master_uri, str):
            raise NetworkSettingsError("master_uri", self.master_uri, "must be a URI http://HOST:PORT or empty")
        if self.master_uri:
            scheme, _, rest = self.master_uri.partition("://")
            if scheme != "http" or not rest:
                raise NetworkSettingsError(
                    "master_uri", self.master_uri, "must be http://HOST:PORT, e.g. http://127.0.0.1:11311"
                )
            try:
                _check_peer("master_uri", rest.rstrip("/"))
            except NetworkSettingsError:
                raise NetworkSettingsError(
                    "master_uri", self.master_uri, "has a bad host or port (1..65535); must be http://HOST:PORT"
                ) from None
            if ":" not in rest:
                raise NetworkSettingsError("master_uri", self.master_uri, "needs its port, e.g. http://127.0.0.1:11311")
        if not isinstance(self.interface, str):
            raise NetworkSettingsError("interface", self.interface, "must be an interface name or IPv4 address")
        if self.interface and self.loopback_only:
            raise NetworkSettingsError(
                "interface", self.interface, "is for other hosts; loopback_only = true uses the loopback interface"
            )

    def interface_address(self) -> str:
        """The IPv4 address of `interface` on this host ('' where none is named); NetworkSettingsError where the host
        has no such interface or address, naming the interfaces it has."""
        if not self.interface:
            return ""
        found = _interface_ipv4(self.interface)
        if found:
            return found
        have = ", ".join(f"{name} ({_interface_ipv4(name) or 'no IPv4 address'})" for _, name in socket.if_nameindex())
        raise NetworkSettingsError(
            "interface", self.interface, f"is not an interface of this host with an IPv4 address; it has: {have}"
        )

    def check_host(self) -> None:
        """Before anything moves: `interface` exists here, and every peer resolves and has a route from this host
        (a UDP socket connected to it sends nothing). NetworkSettingsError naming the one that does not."""
        self.interface_address()
        for i, peer in enumerate(self.peers):
            host = _check_peer(f"peers[{i}]", peer)
            try:
                address = socket.getaddrinfo(host, None, socket.AF_INET, socket.SOCK_DGRAM)[0][4][0]
            except (socket.gaierror, UnicodeError) as exc:
                raise NetworkSettingsError(f"peers[{i}]", peer, f"does not resolve on this host ({exc})") from None
            probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                probe.connect((address, 7400))
            except OSError as exc:
                raise NetworkSettingsError(
                    f"peers[{i}]", peer, f"has no route from this host ({exc.strerror or exc})"
                ) from None
            finally:
                probe.close()


def _check_peer(setting: str, peer: object) -> str:
    """The host part of a valid peer address; anything else raises NetworkSettingsError."""
    if not isinstance(peer, str) or not peer.strip():
        raise NetworkSettingsError(setting, peer, f"must be {_PEER_FORM}")
    host, sep, port = peer.strip().rpartition(":")
    if not sep:
        host, port = port, ""
    if sep and (not port.isdigit() or not 1 <= int(port) <= 65535):
        raise NetworkSettingsError(setting, peer, f"has a bad port; must be {_PEER_FORM}")
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        if host.replace(".", "").isdigit() or not _HOSTNAME.match(host):
            raise NetworkSettingsError(setting, peer, f"must be {_PEER_FORM}") from None
        return host
    if address.version != 4:
        raise NetworkSettingsError(setting, peer, f"IPv6 peers are not supported; must be {_PEER_FORM}")
    return host


def _interface_ipv4(name_or_address: str) -> str:
    """The IPv4 address of this host's interface `name_or_address` (a name, or an address it holds: one a socket can
    bind), '' where there is none."""
    try:
        ipaddress.IPv4Address(name_or_address)
    except ValueError:
        if name_or_address not in {name for _, name in socket.if_nameindex()}:
            return ""
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            request = struct.pack("256s", name_or_address.encode()[:15])
            try:
                return socket.inet_ntoa(fcntl.ioctl(s.fileno(), SIOCGIFADDR, request)[20:24])
            except OSError:  # up without an IPv4 address
                return ""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind((name_or_address, 0))
        except OSError:
            return ""
    return name_or_address


SIOCGIFADDR = 0x8915
"""Linux's ioctl that reads an interface's IPv4 address."""


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


_ROS_NAME = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)+$")


def check_topic(spec: TopicSpec) -> None:
    """Raises TransportError unless `spec` has a fully qualified ROS name, a known type and a usable QoS."""
    if not isinstance(spec, TopicSpec):
        raise TransportError(repr(spec), "expected a TopicSpec (see pipeline.messages.topics)")
    if not _ROS_NAME.match(spec.name):
        raise TransportError(
            f"topic {spec.name!r}",
            "must be a fully qualified ROS 2 name: '/' then tokens of letters, digits and '_' "
            "separated by '/', no token starting with a digit",
        )
    store = message_store()
    if not store.has(spec.typename):
        raise TransportError(
            f"topic {spec.name}", f"unknown message type {spec.typename!r}; known: {', '.join(store.typenames)}"
        )
    if spec.qos.reliability not in ("reliable", "best_effort"):
        raise TransportError(
            f"topic {spec.name}", f"reliability {spec.qos.reliability!r}: must be 'reliable' or 'best_effort'"
        )
    if spec.qos.durability not in ("volatile", "transient_local"):
        raise TransportError(
            f"topic {spec.name}", f"durability {spec.qos.durability!r}: must be 'volatile' or 'transient_local'"
        )
    if isinstance(spec.qos.depth, bool) or not isinstance(spec.qos.depth, int) or not 1 <= spec.qos.depth <= 2**31 - 1:
        raise TransportError(f"topic {spec.name}", f"history depth {spec.qos.depth!r}: must be an integer >= 1")


def field_complaint(msg: Any, typename: str, exc: Exception) -> str:
    """The serializer's complaint `exc` about `msg`, with the member it is about where the DDS type's checks name it."""
    from pipeline.ros.idl import dds_type

    try:
        dds_type(typename).to_dds(msg)
    except Exception as found:  # the converters raise ValueError/TypeError naming the member
        return f"{exc}: {found}"
    return str(exc)


class Publisher(ABC):
    """Sends messages of one topic. Obtained from :meth:`Transport.publisher`."""

    def __init__(self, spec: TopicSpec) -> None:
        self.spec = spec

    @abstractmethod
    def publish(self, msg: Any) -> None:
        """Sends `msg`, a message of ``spec.typename``; a wrong type or a closed publisher raises TransportError."""

    def prepare(self, msg: Any) -> Any:
        """Everything of sending `msg` that can be done ahead (checks, encoding); see :meth:`publish_prepared`."""
        return msg

    def publish_prepared(self, prepared: Any) -> None:
        """Sends what :meth:`prepare` returned: time-critical senders prepare first, then send back to back."""
        self.publish(prepared)

    @abstractmethod
    def close(self) -> None:
        """Withdraws the publisher from the network; idempotent."""

    @property
    @abstractmethod
    def closed(self) -> bool: ...

    def __enter__(self) -> Publisher:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


class Subscription(ABC):
    """Receives messages of one topic and hands each valid one to a callback (see the module notes)."""

    def __init__(self, spec: TopicSpec, callback: MessageCallback) -> None:
        self.spec = spec
        self.callback = callback
        self.received = 0
        """Valid samples handed to the callback."""
        self.dropped_invalid = 0
        """Samples without valid data (e.g. the notice of a writer that vanished), never handed on."""
        self.callback_errors = 0
        """Callback calls that raised."""
        self.foreign = 0
        """Valid samples from writers outside the accepted set (:meth:`accept_only`), dropped."""
        self._accepted: frozenset[int] | None = None

    def writers(self, participant: str = "") -> frozenset[int]:
        """The writers on other participants matched with this subscription now (transport-specific handles); with
        `participant` (a :meth:`Transport.identity`), only that participant's.

        Transports that cannot tell writers apart return an empty set; their subscriptions accept every writer."""
        return frozenset()

    def accept_only(self, writers: frozenset[int]) -> None:
        """From now on hand on only samples of `writers` (from :meth:`writers`); count and drop the others."""
        self._accepted = frozenset(writers)

    @property
    def accepted(self) -> frozenset[int] | None:
        """The writers whose samples are handed on; None: every writer (nothing locked yet)."""
        return self._accepted

    def strays(self) -> frozenset[int]:
        """Writers matched now that are not accepted (empty before :meth:`accept_only`)."""
        if not self._accepted:  # nothing locked, or nothing to tell writers apart by
            return frozenset()
        return self.writers() - self._accepted

    def _hand_on(self, msg: Any, receive_time_ns: int) -> None:
        """Count a valid, decoded sample and call back; a callback that raises is counted and logged, and delivery
        goes on."""
        self.received += 1
        try:
            self.callback(self.spec, msg, receive_time_ns)
        except Exception:
            self.callback_errors += 1
            log.exception("topic %s: subscription callback raised", self.spec.name)

    def _admits(self, writer: int) -> bool:
        """Whether a sample of `writer` is handed on; counts a dropped one."""
        if self._accepted is None or not self._accepted or writer in self._accepted:
            return True
        self.foreign += 1
        return False

    @abstractmethod
    def close(self) -> None:
        """Stops delivery and withdraws the subscription from the network; idempotent."""

    @property
    @abstractmethod
    def closed(self) -> bool: ...

    def __enter__(self) -> Subscription:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


class Transport(ABC):
    """One participant in a ROS 2 domain; a context manager that closes itself.

    The base keeps what every backend keeps: its open publishers and subscriptions (under one re-entrant lock), the
    closed flag, the checks before an endpoint is made and the endpoints a match count is taken over; a backend
    adds only how its middleware makes, matches and closes endpoints (:meth:`_keep`, :meth:`_drop`,
    :meth:`_on_topic`, :meth:`_closing`)."""

    poll_interval_s = 0.01
    """How often :meth:`wait_for_match` looks at the match count."""

    def __init__(self, settings: NetworkSettings) -> None:
        self.settings = settings
        self._lock = threading.RLock()
        self._closed = False
        self._publishers: list[Publisher] = []
        self._subscriptions: list[Subscription] = []

    @abstractmethod
    def publisher(self, spec: TopicSpec) -> Publisher:
        """A publisher of `spec` with its QoS."""

    @abstractmethod
    def subscribe(self, spec: TopicSpec, callback: MessageCallback) -> Subscription:
        """Calls ``callback(spec, msg, receive_time_ns)`` on the transport's thread for every valid sample of `spec`."""

    def identity(self) -> str:
        """This participant as the others see it (a DDS participant GUID); '' where the transport cannot tell."""
        return ""

    @abstractmethod
    def matched_count(self, spec: TopicSpec) -> int:
        """Remote endpoints (other participants' readers and writers) matched with this transport's endpoints on `spec`.

        Raises TransportError when this transport has neither a publisher nor a subscription on `spec`.
        """

    @abstractmethod
    def close(self) -> None:
        """Closes every publisher and subscription and leaves the domain; idempotent."""

    @property
    def closed(self) -> bool:
        return self._closed

    # the bookkeeping every backend shares

    def _check_open(self, spec: TopicSpec) -> None:
        """TransportError where the transport is closed (an endpoint asked for on `spec` afterwards)."""
        if self._closed:
            raise TransportError(f"topic {spec.name}", "the transport is closed")

    @staticmethod
    def _check_callback(spec: TopicSpec, callback: object) -> None:
        if not callable(callback):
            raise TransportError(f"topic {spec.name}", f"the callback must be callable, got {type(callback).__name__}")

    def _keep(self, endpoint: Publisher | Subscription) -> None:
        """Count `endpoint` among the transport's own (closed with it, matched by :meth:`_on_topic`)."""
        with self._lock:
            if isinstance(endpoint, Publisher):
                self._publishers.append(endpoint)
            else:
                self._subscriptions.append(endpoint)

    def _drop(self, endpoint: Publisher | Subscription) -> bool:
        """Forget `endpoint` (it closed); whether it was the transport's."""
        with self._lock:
            kept: list[Any] = self._publishers if isinstance(endpoint, Publisher) else self._subscriptions
            if endpoint in kept:
                kept.remove(endpoint)
                return True
            return False

    def _on_topic(self, spec: TopicSpec) -> tuple[list[Publisher], list[Subscription]]:
        """The open publishers and subscriptions on `spec`; TransportError where there are none (nothing of this
        transport's to match there). Called under the lock."""
        pubs = [p for p in self._publishers if p.spec.name == spec.name and not p.closed]
        subs = [s for s in self._subscriptions if s.spec.name == spec.name and not s.closed]
        if not pubs and not subs:
            raise TransportError(f"topic {spec.name}", "this transport has no publisher or subscription on it to match")
        return pubs, subs

    def _closing(self) -> list[Publisher | Subscription] | None:
        """Mark the transport closed: its endpoints, subscriptions first, to close; None where it already was."""
        with self._lock:
            if self._closed:
                return None
            self._closed = True
            return [*self._subscriptions, *self._publishers]

    def wait_for_match(self, spec: TopicSpec, count: int = 1, timeout_s: float = 5.0) -> bool:
        """Waits until at least `count` remote endpoints match on `spec`; False after `timeout_s` seconds."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self.matched_count(spec) >= count:
                return True
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            time.sleep(min(self.poll_interval_s, remaining))

    def __enter__(self) -> Transport:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


BACKEND_CLASSES: dict[BackendKind, tuple[str, str]] = {
    "dds": ("pipeline.ros.dds", "DdsTransport"),
    "rclpy": ("pipeline.ros.rclpy_transport", "RclpyTransport"),
    "ros1": ("pipeline.ros.ros1", "Ros1Transport"),
}
"""Each backend's transport class (module, name), imported when a transport of that kind is opened: a backend's
middleware is loaded only where it is used, and the backends import this module, never the other way round."""


def open_transport(kind: BackendKind = "dds", settings: NetworkSettings | None = None) -> Transport:
    """A transport of backend `kind` ('dds': Cyclone DDS from Python; 'rclpy': a ROS 2 installation; 'ros1': a ROS 1
    master through rospy)."""
    settings = settings if settings is not None else NetworkSettings()
    settings.check_host()
    if kind not in BACKEND_CLASSES:
        raise TransportError(f"transport kind {kind!r}", f"must be one of {', '.join(BACKENDS)}")
    module, name = BACKEND_CLASSES[kind]
    backend: type[Transport] = getattr(importlib.import_module(module), name)
    return backend(settings)
