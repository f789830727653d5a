"""The ROS 1 transport: the same interface over a ROS 1 master, with rospy (TCPROS between nodes).

Importing this module never needs ROS 1. :class:`Ros1Transport` imports ``rospy`` from the Python
package directory of a ROS 1 installation (Debian's ``python3-rospy`` puts it in
``/usr/lib/python3/dist-packages``; ``MRL_ROS1_PYTHONPATH`` names another), appended to
``sys.path`` so the project's own packages keep precedence. Both Pythons must be the same minor
version (Debian 12: 3.11).

Messages cross as ROS 1 serialization: a publisher sends ``typestore.serialize_ros1`` of the
message store's object (a ``std_msgs/Header`` gains ``seq`` 0) under the ROS 1 type name
(``sensor_msgs/LaserScan``), md5sum and full definition that ROS 1 Noetic gives the type, so
roscpp and rospy nodes built against the standard message packages connect; the pipeline's own
types (``mrl_msgs``, ``tf2_msgs``) get their definition and md5sum from ``schemas/`` the way genmsg
computes them. A subscription decodes the bytes back into the store's object, so the deploy runner,
the twin and the recorder see the same messages as over DDS. No message classes are generated and
nothing is unpickled.

One ROS 1 node per process (rospy's rule): every :class:`Ros1Transport` of a process shares the
node ``/mrl_<pid>_...`` of the first one, and a second master URI in one process is refused.
QoS maps onto what ROS 1 has: ``transient_local`` publishers latch, ``depth`` is the queue size,
every connection is TCP with ``TCP_NODELAY``; reliability is TCP's. Callbacks run on the
transport's dispatcher thread, one sample at a time in arrival order, as the interface requires
(rospy's own per-topic threads only stamp the receive time and queue the bytes). Each sample's
writer is the publishing node (its caller id), so :meth:`Subscription.accept_only` locks a fleet's
nodes as it locks DDS writers.

Before anything is created the master is checked: it must answer at its URI, and a topic the master
already knows under another type is refused with the topic and both types named.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import itertools
import logging
import os
import queue
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from types import ModuleType
from typing import Any
from urllib.parse import urlparse

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from pipeline.messages.errors import MessageError
from pipeline.messages.store import message_store, schema_files
from pipeline.messages.topics import TopicSpec
from pipeline.ros.errors import BackendUnavailableError, TransportError
from pipeline.ros.transport import (
    MessageCallback,
    NetworkSettings,
    Publisher,
    Subscription,
    Transport,
    check_topic,
    field_complaint,
)

log = logging.getLogger(__name__)

DEBIAN_PYTHON_PACKAGES = "/usr/lib/python3/dist-packages"
"""Where Debian's python3-rospy and the message packages live."""
PATH_VARIABLE = "MRL_ROS1_PYTHONPATH"
"""Environment variable naming the directory that holds ``rospy`` (default `DEBIAN_PYTHON_PACKAGES`)."""
MASTER_TIMEOUT_S = 3.0
"""How long the master may take to accept a connection before it counts as unreachable."""

_node_lock = threading.Lock()
_node: dict[str, str] = {}  # the process's node: {"uri": master URI, "name": caller id}
_names = itertools.count()
_UNKNOWN = "unknown"
"""rospy's name of a connection's far end before its header arrived (not yet a match)."""


def ros1_missing() -> str | None:
    """Why rospy cannot be imported here (None: it can)."""
    try:
        _import_rospy()
    except BackendUnavailableError as exc:
        return str(exc)
    return None


def _import_rospy() -> Any:
    loaded = sys.modules.get("rospy")
    if loaded is not None:
        return loaded
    folder = os.environ.get(PATH_VARIABLE, DEBIAN_PYTHON_PACKAGES)
    if folder and folder not in sys.path and os.path.isdir(folder):
        sys.path.append(folder)
    try:
        with _ros1_message_packages(folder):
            return importlib.import_module("rospy")
    except ImportError as exc:
        raise BackendUnavailableError(
            "transport 'ros1'",
            f"rospy is not importable ({exc}); install Debian's ROS 1 (apt-get install ros-core python3-rospy) or "
            f"set {PATH_VARIABLE} to the directory holding rospy (a ROS 1 of this Python's version)",
        ) from exc


def ros1_message_module(package: str) -> ModuleType:
    """ROS 1's ``<package>.msg`` (genpy classes from the ROS 1 installation), whatever ROS 2 holds under that name."""
    _import_rospy()
    folder = os.environ.get(PATH_VARIABLE, DEBIAN_PYTHON_PACKAGES)
    with _ros1_message_packages(folder):
        return importlib.import_module(f"{package}.msg")


def shared_package_names(folder: str) -> frozenset[str]:
    """The ROS 1 message packages in `folder` (``std_msgs``, ``rosgraph_msgs``, ...): names ROS 2 uses too."""
    try:
        entries = list(Path(folder).iterdir())
    except OSError:
        return frozenset()
    return frozenset(p.name for p in entries if p.name.endswith("_msgs") and (p / "msg" / "__init__.py").is_file())


class _FolderFirst(importlib.abc.MetaPathFinder):
    """Finds the top-level packages `names` in `folder` only, ahead of every other path entry."""

    def __init__(self, folder: str, names: frozenset[str]) -> None:
        self.folder = folder
        self.names = names

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if fullname not in self.names:
            return None  # submodules follow their package's own __path__
        return importlib.machinery.PathFinder.find_spec(fullname, [self.folder])


_ros1_modules: dict[str, ModuleType] = {}
"""ROS 1's message modules that rospy imported, held here instead of in ``sys.modules``."""


@contextmanager
def _ros1_message_packages(folder: str) -> Iterator[None]:
    """Imports inside the block see ROS 1's message packages of `folder`; afterwards ``sys.modules`` holds what it
    held before under those names (ROS 2's, where rclpy or the ROS 2 wheels put them there).

    ROS 1 and ROS 2 name their Python message packages alike (``std_msgs``, ``rosgraph_msgs``, ...). rospy binds the
    classes it needs (``rosgraph_msgs.msg.Log``, ``std_msgs.msg.Header``) when it is imported and never imports a
    message package later (this transport sends ready bytes), so one process can hold rospy and rclpy."""
    names = shared_package_names(folder) if folder else frozenset()
    if not names:
        yield
        return

    def shared(name: str) -> bool:
        return name.partition(".")[0] in names

    saved = {name: module for name, module in sys.modules.items() if shared(name)}
    for name in saved:
        del sys.modules[name]
    sys.modules.update(_ros1_modules)
    finder = _FolderFirst(folder, names)
    sys.meta_path.insert(0, finder)
    try:
        yield
    finally:
        sys.meta_path.remove(finder)
        for name in [name for name in sys.modules if shared(name)]:
            _ros1_modules[name] = sys.modules.pop(name)
        sys.modules.update(saved)


def ros1_typename(typename: str) -> str:
    """``pkg/msg/Name`` -> ``pkg/Name``."""
    package, _, name = typename.rpartition("/msg/")
    return f"{package}/{name}" if package else typename


@cache
def _ros1_store() -> Typestore:
    """ROS 1 Noetic's types, plus the pipeline's own types from ``schemas/`` where Noetic lacks them."""
    store = get_typestore(Stores.ROS1_NOETIC)
    for typename, path in schema_files().items():
        if typename not in store.types:
            store.register(get_types_from_msg(path.read_text(encoding="utf-8"), typename))
    return store


@dataclass(frozen=True)
class WireType:
    """A type as ROS 1 sees it: its name, md5sum and full definition (the connection header's fields)."""

    typename: str
    ros1_name: str
    md5sum: str
    definition: str
    has_header: bool


@cache
def wire_type(typename: str) -> WireType:
    store = _ros1_store()
    if typename not in store.types:
        raise TransportError(f"type {typename}", "has no ROS 1 definition (neither ROS 1 Noetic nor schemas/ has it)")
    text, md5 = store.generate_msgdef(typename, ros_version=1)
    fields = [name for name, _ in store.fielddefs[typename][1]]
    return WireType(typename, ros1_typename(typename), md5, text, "header" in fields)


def encode(msg: Any, typename: str) -> bytes:
    """ROS 1 serialization of the message store's `msg` (a Header gains seq 0)."""
    return message_store().serialize_ros1(msg, typename)


def decode(data: bytes, typename: str) -> Any:
    """The message store's object of ROS 1 bytes (a Header's seq dropped)."""
    return message_store().deserialize_ros1(data, typename)


def master_uri(settings: NetworkSettings) -> str:
    """The master of `settings` (its ``master_uri``, else ``ROS_MASTER_URI``); TransportError when neither is set."""
    uri = settings.master_uri or os.environ.get("ROS_MASTER_URI", "")
    if not uri:
        raise TransportError(
            "transport 'ros1'",
            "no ROS master: set network.master_uri in the fleet file (e.g. http://127.0.0.1:11311) or ROS_MASTER_URI",
        )
    return uri


def check_master(uri: str, timeout_s: float = MASTER_TIMEOUT_S) -> None:
    """TransportError naming `uri` unless a ROS master answers there."""
    parts = urlparse(uri)
    where = f"ROS master {uri}"
    if parts.scheme != "http" or not parts.hostname or parts.port is None:
        raise TransportError(where, "must be http://HOST:PORT, e.g. http://127.0.0.1:11311")
    try:
        with socket.create_connection((parts.hostname, parts.port), timeout=timeout_s):
            pass
    except OSError as exc:
        raise TransportError(
            where, f"does not answer ({exc.strerror or exc}); start one (roscore -p {parts.port}) or fix the URI"
        ) from None
    _import_rospy()  # puts ROS 1's package directory on the path
    rosgraph = importlib.import_module("rosgraph")
    try:
        rosgraph.Master("/mrl_check", master_uri=uri).getPid()
    except Exception as exc:  # rosgraph raises socket and xmlrpc errors alike
        raise TransportError(where, f"accepts connections but is no ROS master ({exc})") from None


def free_port() -> int:
    """A TCP port free on the loopback interface now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def ros_environment(uri: str, home: Path) -> dict[str, str]:
    """The environment of a ROS 1 process on master `uri` with its logs under `home`."""
    return {**os.environ, "ROS_MASTER_URI": uri, "ROS_HOME": str(home), "ROS_LOG_DIR": str(home / "log")}


@contextmanager
def private_master(home: Path | None = None, timeout_s: float = 15.0) -> Iterator[str]:
    """A ROS 1 master of its own (``rosmaster --core`` on a free loopback port, its logs in `home` or a temporary
    folder) while the block runs; yields its URI. BackendUnavailableError where rosmaster is not installed."""
    if shutil.which("rosmaster") is None:
        raise BackendUnavailableError(
            "transport 'ros1'", "rosmaster is not installed (apt-get install ros-core python3-rospy)"
        )
    with tempfile.TemporaryDirectory(prefix="mrl_rosmaster_") as scratch:
        folder = Path(home) if home is not None else Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        port = free_port()
        uri = f"http://127.0.0.1:{port}"
        with (folder / "rosmaster.log").open("w") as out:
            proc = subprocess.Popen(
                ["rosmaster", "--core", "-p", str(port)],
                env=ros_environment(uri, folder),
                stdout=out,
                stderr=subprocess.STDOUT,
            )
            try:
                deadline = time.monotonic() + timeout_s
                while True:
                    try:
                        check_master(uri, timeout_s=1.0)
                        break
                    except TransportError:
                        if proc.poll() is not None or time.monotonic() > deadline:
                            log_text = (folder / "rosmaster.log").read_text()
                            raise TransportError(f"ROS master {uri}", f"rosmaster did not start: {log_text}") from None
                        time.sleep(0.1)
                yield uri
            finally:
                proc.terminate()
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()


def _writer_id(caller_id: str) -> int:
    return zlib.crc32(caller_id.encode()) & 0x7FFFFFFF


class Ros1Publisher(Publisher):
    """A rospy publisher of one topic that sends the ROS 1 bytes of the store's messages."""

    def __init__(self, transport: Ros1Transport, spec: TopicSpec, publisher: Any, raw_class: type) -> None:
        super().__init__(spec)
        self._transport = transport
        self._publisher: Any | None = publisher
        self._raw_class = raw_class
        self._msg_class = message_store().cls(spec.typename)

    @property
    def closed(self) -> bool:
        return self._publisher is None

    def prepare(self, msg: Any) -> Any:
        if not isinstance(msg, self._msg_class):
            raise TransportError(
                f"topic {self.spec.name}", f"expected a {self.spec.typename} message, got {type(msg).__name__}"
            )
        raw = self._raw_class()
        try:
            raw._buff = encode(msg, self.spec.typename)
        except MessageError as exc:
            raise TransportError(f"topic {self.spec.name}", field_complaint(msg, self.spec.typename, exc)) from exc
        return raw

    def publish(self, msg: Any) -> None:
        self.publish_prepared(self.prepare(msg))

    def publish_prepared(self, prepared: Any) -> None:
        publisher = self._publisher
        if publisher is None:
            raise TransportError(f"topic {self.spec.name}", "cannot publish: the publisher is closed")
        try:
            publisher.publish(prepared)
        except Exception as exc:  # rospy raises ROSException and serialization errors
            raise TransportError(f"topic {self.spec.name}", f"rospy refused the message: {exc}") from exc

    def connections(self) -> int:
        publisher = self._publisher
        if publisher is None:
            return 0
        own = self._transport.identity()
        # a publisher's connection is named by the subscribing node's caller id
        return sum(1 for c in publisher.impl.connections if getattr(c, "endpoint_id", "") not in ("", _UNKNOWN, own))

    def close(self) -> None:
        publisher, self._publisher = self._publisher, None
        if publisher is not None:
            self._transport._forget(self)
            publisher.unregister()


class Ros1Subscription(Subscription):
    """A rospy subscription whose bytes the transport's dispatcher decodes and hands on."""

    def __init__(self, transport: Ros1Transport, spec: TopicSpec, callback: MessageCallback) -> None:
        super().__init__(spec, callback)
        self._transport = transport
        self.handle: Any | None = None
        self.malformed = 0
        """Messages whose bytes did not decode."""

    @property
    def closed(self) -> bool:
        return self.handle is None

    def on_message(self, raw: Any) -> None:
        """rospy's callback (its topic thread): stamp the receipt and queue the bytes for the dispatcher."""
        receive_time_ns = time.time_ns()
        header = getattr(raw, "_connection_header", None) or {}
        self._transport._inbox.put((self, bytes(raw._buff), _writer_id(header.get("callerid", "")), receive_time_ns))

    def deliver(self, data: bytes, writer: int, receive_time_ns: int) -> None:
        """The dispatcher's part: decode, filter by writer, call back."""
        if self.handle is None or not self._admits(writer):
            return
        try:
            msg = decode(data, self.spec.typename)
        except Exception as exc:
            self.malformed += 1
            log.warning("topic %s: cannot decode a message: %s", self.spec.name, exc)
            return
        self._hand_on(msg, receive_time_ns)

    def writers(self, participant: str = "") -> frozenset[int]:
        handle = self.handle
        if handle is None:
            return frozenset()
        own = self._transport.identity()
        ids = set()
        for c in handle.impl.connections:
            caller = getattr(c, "callerid_pub", "")  # the publishing node, from its connection header
            if caller not in ("", _UNKNOWN) and caller != own and (not participant or caller == participant):
                ids.add(_writer_id(caller))
        return frozenset(ids)

    def connections(self) -> int:
        return len(self.writers())

    def close(self) -> None:
        handle, self.handle = self.handle, None
        if handle is not None:
            self._transport._forget(self)
            handle.unregister()


class Ros1Transport(Transport):
    """This process's ROS 1 node on the master of `settings`, with a dispatcher thread for callbacks."""

    def __init__(self, settings: NetworkSettings) -> None:
        super().__init__(settings)
        rospy = _import_rospy()
        self._rospy = rospy
        uri = master_uri(settings)
        check_master(uri)
        self._master = importlib.import_module("rosgraph").Master("/mrl_transport", master_uri=uri)
        with _node_lock:
            if _node and _node["uri"] != uri:
                raise TransportError(
                    f"ROS master {uri}",
                    f"this process's ROS 1 node is already on {_node['uri']} (one node per process)",
                )
            if not _node:
                os.environ["ROS_MASTER_URI"] = uri
                if settings.loopback_only or settings.interface:  # the address the node advertises
                    os.environ["ROS_IP"] = settings.interface_address() or "127.0.0.1"
                    os.environ.pop("ROS_HOSTNAME", None)
                rospy.init_node(f"mrl_{os.getpid()}", anonymous=True, disable_signals=True, log_level=rospy.WARN)
                _node.update(uri=uri, name=rospy.get_caller_id())
        self._inbox: queue.SimpleQueue[tuple[Ros1Subscription, bytes, int, int] | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._dispatch, name=f"ros1-dispatch-{next(_names)}", daemon=True)
        self._thread.start()

    def identity(self) -> str:
        return _node.get("name", "")

    def publisher(self, spec: TopicSpec) -> Ros1Publisher:
        check_topic(spec)
        wire = self._checked(spec)
        with self._lock:
            self._check_open(spec)
            raw_class = _raw_class(wire)
            handle = self._rospy.Publisher(
                spec.name,
                raw_class,
                queue_size=spec.qos.depth,
                latch=spec.qos.durability == "transient_local",
                tcp_nodelay=True,
            )
            pub = Ros1Publisher(self, spec, handle, raw_class)
            self._keep(pub)
            return pub

    def subscribe(self, spec: TopicSpec, callback: MessageCallback) -> Ros1Subscription:
        check_topic(spec)
        self._check_callback(spec, callback)
        wire = self._checked(spec)
        with self._lock:
            self._check_open(spec)
            sub = Ros1Subscription(self, spec, callback)
            sub.handle = self._rospy.Subscriber(
                spec.name, _raw_class(wire), sub.on_message, queue_size=spec.qos.depth, tcp_nodelay=True
            )
            self._keep(sub)
            return sub

    def matched_count(self, spec: TopicSpec) -> int:
        with self._lock:
            pubs, subs = self._on_topic(spec)
            sending = max((p.connections() for p in pubs if isinstance(p, Ros1Publisher)), default=0)
            return sending + max((s.connections() for s in subs if isinstance(s, Ros1Subscription)), default=0)

    def close(self) -> None:
        endpoints = self._closing()
        if endpoints is None:
            return
        for endpoint in endpoints:
            endpoint.close()
        self._inbox.put(None)
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=5.0)

    # internals

    def _checked(self, spec: TopicSpec) -> WireType:
        """The topic's ROS 1 type; TransportError when the master already has the topic under another type."""
        wire = wire_type(spec.typename)
        try:
            known = dict(self._master.getTopicTypes())
        except Exception as exc:
            raise TransportError(f"ROS master {_node.get('uri', '')}", f"stopped answering ({exc})") from None
        other = known.get(spec.name)
        if other is not None and other not in (wire.ros1_name, "*"):
            raise TransportError(
                f"topic {spec.name}",
                f"the ROS master has it as {other}; the pipeline sends and reads {wire.ros1_name} there "
                f"(rename the robot's topic or remap it)",
            )
        return wire

    def _forget(self, endpoint: Ros1Publisher | Ros1Subscription) -> None:
        self._drop(endpoint)

    def _dispatch(self) -> None:
        while True:
            item = self._inbox.get()
            if item is None:
                return
            sub, data, writer, receive_time_ns = item
            sub.deliver(data, writer, receive_time_ns)


@cache
def _raw_class(wire: WireType) -> type:
    """A rospy message class that carries ready bytes under `wire`'s name, md5sum and definition."""
    rospy = _import_rospy()
    return type(
        wire.ros1_name.replace("/", "_"),
        (rospy.AnyMsg,),
        {
            "__slots__": (),
            "_type": wire.ros1_name,
            "_md5sum": wire.md5sum,
            "_full_text": wire.definition,
            "_has_header": False,  # rospy would set header.seq on a message object; the bytes carry seq 0
        },
    )
