"""The rclpy transport: the same interface over ROS 2's own client library (Jazzy or Kilted, any RMW it is set up with).

Importing this module never needs ROS 2; constructing :class:`RclpyTransport` where rclpy is not importable raises
:class:`~pipeline.ros.transport.BackendUnavailableError` with the install command. ROS 2 comes from the PyPI wheels
of the ``ros2`` extra (``pip install -e '.[ros2]'``: Jazzy's rclpy with Fast DDS) or from a sourced
``/opt/ros/<distro>``; a mix of distributions, a missing RMW library and a type without its type support are named
before anything is sent.

Messages cross as CDR: a publisher sends ``message_store().serialize(msg)`` as a serialized message and a raw
subscription hands its bytes to ``message_store().deserialize``, so no conversion to rclpy message objects happens;
rclpy's message classes only supply the type support (type name, hash and the RMW's serializer for matching). The
pipeline's own types (``mrl_msgs``) and ``tf2_msgs``, which the wheels lack, are built from ``schemas/`` at their
first use (:mod:`pipeline.ros.ros2_interfaces`).

Discovery settings reach the RMW through the variables ROS 2 Jazzy reads when a context starts:
``ROS_AUTOMATIC_DISCOVERY_RANGE`` (``LOCALHOST`` for ``loopback_only``, else ``SUBNET``) and
``ROS_STATIC_PEERS``; they are set for the initialisation only and restored afterwards.
Callbacks run on the transport's executor thread. :meth:`RclpyTransport.matched_count` counts
matched endpoints minus this transport's own endpoints on the topic.
"""

from __future__ import annotations

import importlib
import itertools
import logging
import os
import re
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from pipeline.messages.errors import MessageError
from pipeline.messages.store import message_store
from pipeline.messages.topics import QosProfile, TopicSpec
from pipeline.ros import ros2_interfaces
from pipeline.ros.errors import BackendUnavailableError, NetworkSettingsError, TransportError
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

_SPIN_S = 0.1  # the executor thread re-checks for shutdown at least this often
_node_ids = itertools.count()


RMW_VARIABLE = "RMW_IMPLEMENTATION"
DEFAULT_RMW = "rmw_fastrtps_cpp"


def rclpy_available() -> bool:
    """True when rclpy can be imported in this Python."""
    return rclpy_missing() is None


def rclpy_missing() -> str | None:
    """Why the rclpy transport cannot start here (None: it can): no ROS 2, mixed distributions, no RMW library."""
    try:
        _import_rclpy()
    except BackendUnavailableError as exc:
        return str(exc)
    return None


def _import_rclpy() -> Any:
    installation = ros2_interfaces.check_distribution()
    # before the import: rcl ends the process (exit 102) when it loads beside another RMW than the one named
    _check_rmw(installation)
    try:
        return importlib.import_module("rclpy")
    except ImportError as exc:
        raise BackendUnavailableError(
            "transport 'rclpy'",
            f"rclpy is not importable in this Python ({exc}): {ros2_interfaces.INSTALL_HINT}"
            + ("" if installation.source == "wheels" else f" (ROS 2 {installation.distribution} is sourced)"),
        ) from exc


def _rmw() -> str:
    """The RMW implementation rclpy will load."""
    return os.environ.get(RMW_VARIABLE) or DEFAULT_RMW


def _check_rmw(installation: ros2_interfaces.Installation) -> None:
    """BackendUnavailableError unless the RMW implementation rclpy will load has its library here."""
    rmw = _rmw()
    library = f"lib{rmw}.so"
    folders = [p for p in os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep) if p]
    folders += [str(Path(p) / "lib") for p in installation.prefixes]
    if not re.fullmatch(r"rmw_[a-z0-9_]+", rmw) or not any((Path(f) / library).is_file() for f in folders):
        hint = (
            "pip install ros-rmw-fastrtps-cpp (the ros2 extra pins it)"
            if rmw == DEFAULT_RMW
            else (f"install {rmw}, or unset {RMW_VARIABLE} to use {DEFAULT_RMW}")
        )
        raise BackendUnavailableError(
            "transport 'rclpy'",
            f"the RMW implementation {rmw!r} ({RMW_VARIABLE}) has no library {library} here: {hint}",
        )


FASTDDS_PROFILES_VARIABLE = "FASTDDS_DEFAULT_PROFILES_FILE"
NO_TYPE_PROPAGATION = Path(__file__).resolve().parent / "profiles" / "fastdds_no_type_propagation.xml"
"""Fast DDS 3's participant profile without type propagation, so Cyclone DDS endpoints match (see the file)."""
_FAST_DDS_2_DISTRIBUTIONS = ("humble", "iron", "jazzy")


def middleware_environment(settings: NetworkSettings) -> dict[str, str]:
    """The variables the RMW reads when a participant starts: discovery of `settings` and, on Fast DDS 3 (Kilted and
    later) where the user set no profile of their own, the profile that lets Cyclone DDS peers match."""
    wanted = {
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST" if settings.loopback_only else "SUBNET",
        "ROS_STATIC_PEERS": ";".join(settings.peers),
    }
    distribution = ros2_interfaces.check_distribution().distribution
    if (
        _rmw() == DEFAULT_RMW
        and distribution not in _FAST_DDS_2_DISTRIBUTIONS
        and not os.environ.get(FASTDDS_PROFILES_VARIABLE)
    ):
        wanted[FASTDDS_PROFILES_VARIABLE] = str(NO_TYPE_PROPAGATION)
    return wanted


@contextmanager
def middleware_variables(settings: NetworkSettings) -> Iterator[None]:
    """Sets the variables of :func:`middleware_environment` for the duration of the block."""
    wanted = middleware_environment(settings)
    saved = {key: os.environ.get(key) for key in wanted}
    os.environ.update(wanted)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def _ros_qos(qos: QosProfile) -> Any:
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=qos.depth,
        reliability=ReliabilityPolicy.RELIABLE if qos.reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if qos.durability == "transient_local"
        else DurabilityPolicy.VOLATILE,
    )


def _message_class(spec: TopicSpec) -> Any:
    """The rclpy message class of `spec`'s type, its type support loaded; TransportError naming what is missing."""
    package, _, name = spec.typename.partition("/msg/")
    if package in ros2_interfaces.BUILT_PACKAGES:
        try:
            ros2_interfaces.ensure_interfaces()
        except BackendUnavailableError as exc:
            raise TransportError(f"topic {spec.name}", f"message type {spec.typename}: {exc}") from exc
    try:
        cls = getattr(importlib.import_module(f"{package}.msg"), name)
        cls.__class__.__import_type_support__()
        if cls.__class__._TYPE_SUPPORT is None:
            raise ImportError("its type support library did not load")
    except (AttributeError, ImportError) as exc:
        raise TransportError(
            f"topic {spec.name}",
            f"message type {spec.typename} has no ROS 2 type support here ({exc}); "
            f"install the ros-{package.replace('_', '-')} wheel of your distribution or source a workspace that "
            f"builds {package}",
        ) from exc
    return cls


class RclpyPublisher(Publisher):
    """An rclpy publisher of one topic that sends the store's CDR."""

    def __init__(self, transport: RclpyTransport, spec: TopicSpec, publisher: Any) -> None:
        super().__init__(spec)
        self._transport = transport
        self._publisher: Any | None = publisher
        self._msg_class = message_store().cls(spec.typename)

    @property
    def closed(self) -> bool:
        return self._publisher is None

    def publish(self, msg: Any) -> None:
        publisher = self._publisher
        if publisher is None:
            raise TransportError(f"topic {self.spec.name}", "cannot publish: the publisher is closed")
        if not isinstance(msg, self._msg_class):
            raise TransportError(
                f"topic {self.spec.name}", f"expected a {self.spec.typename} message, got {type(msg).__name__}"
            )
        try:
            data = message_store().serialize(msg, self.spec.typename)
        except MessageError as exc:
            raise TransportError(f"topic {self.spec.name}", field_complaint(msg, self.spec.typename, exc)) from exc
        try:
            publisher.publish(data)
        except Exception as exc:  # rclpy raises RCLError and assorted runtime errors
            raise TransportError(f"topic {self.spec.name}", f"rclpy refused the message: {exc}") from exc

    def close(self) -> None:
        publisher, self._publisher = self._publisher, None
        if publisher is not None:
            self._transport._destroy(self, publisher)


class RclpySubscription(Subscription):
    """A raw rclpy subscription whose CDR the message store decodes."""

    def __init__(self, transport: RclpyTransport, spec: TopicSpec, callback: MessageCallback) -> None:
        super().__init__(spec, callback)
        self._transport = transport
        self.handle: Any | None = None
        self.malformed = 0
        """Messages whose CDR did not decode."""

    @property
    def closed(self) -> bool:
        return self.handle is None

    def on_message(self, data: bytes) -> None:
        """Executor callback of the raw subscription."""
        receive_time_ns = time.time_ns()
        if self.handle is None:
            return
        try:
            msg = message_store().deserialize(data, self.spec.typename)
        except Exception as exc:
            self.malformed += 1
            log.warning("topic %s: cannot decode a message: %s", self.spec.name, exc)
            return
        self._hand_on(msg, receive_time_ns)

    def close(self) -> None:
        handle, self.handle = self.handle, None
        if handle is not None:
            self._transport._destroy(self, handle)


class RclpyTransport(Transport):
    """One rclpy context and node in the domain of `settings`, spun by a background executor."""

    def __init__(self, settings: NetworkSettings) -> None:
        if settings.interface:
            raise NetworkSettingsError(
                "interface",
                settings.interface,
                "is not taken by the rclpy transport: its middleware binds interfaces in a profile of its own "
                f"({FASTDDS_PROFILES_VARIABLE}); leave it empty, or use the dds transport",
            )
        super().__init__(settings)
        rclpy = _import_rclpy()
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self._rclpy = rclpy
        self._context = Context()
        try:
            with middleware_variables(settings):
                rclpy.init(
                    context=self._context,
                    domain_id=settings.domain_id,
                    signal_handler_options=SignalHandlerOptions.NO,
                )
                self._node = rclpy.create_node(f"mrl_transport_{os.getpid()}_{next(_node_ids)}", context=self._context)
            self._executor = SingleThreadedExecutor(context=self._context)
            self._executor.add_node(self._node)
        except Exception as exc:
            self._context.try_shutdown()
            raise TransportError(f"ROS 2 domain {settings.domain_id}", f"rclpy cannot start: {exc}") from exc
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name=f"rclpy-spin-{settings.domain_id}", daemon=True)
        self._thread.start()

    def publisher(self, spec: TopicSpec) -> RclpyPublisher:
        check_topic(spec)
        with self._lock:
            self._check_open(spec)
            handle = self._node.create_publisher(_message_class(spec), spec.name, _ros_qos(spec.qos))
            pub = RclpyPublisher(self, spec, handle)
            self._keep(pub)
            return pub

    def subscribe(self, spec: TopicSpec, callback: MessageCallback) -> RclpySubscription:
        check_topic(spec)
        self._check_callback(spec, callback)
        with self._lock:
            self._check_open(spec)
            sub = RclpySubscription(self, spec, callback)
            sub.handle = self._node.create_subscription(
                _message_class(spec), spec.name, sub.on_message, _ros_qos(spec.qos), raw=True
            )
            self._keep(sub)
            return sub

    def matched_count(self, spec: TopicSpec) -> int:
        with self._lock:
            pubs, subs = self._on_topic(spec)
            writers: list[Any] = [p._publisher for p in pubs if isinstance(p, RclpyPublisher)]
            readers: list[Any] = [s.handle for s in subs if isinstance(s, RclpySubscription)]
            # every local endpoint also matches this transport's own endpoints of the other kind
            remote_readers = max((int(w.get_subscription_count()) for w in writers), default=0) - len(readers)
            remote_writers = max((int(r.get_publisher_count()) for r in readers), default=0) - len(writers)
        return max(remote_readers, 0) + max(remote_writers, 0)

    def close(self) -> None:
        endpoints = self._closing()
        if endpoints is None:
            return
        self._stop.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=5.0)
        for endpoint in endpoints:
            endpoint.close()
        self._executor.shutdown()
        self._node.destroy_node()
        self._context.try_shutdown()

    # internals

    def _destroy(self, endpoint: RclpyPublisher | RclpySubscription, handle: Any) -> None:
        with self._lock:
            self._drop(endpoint)
            if isinstance(endpoint, RclpyPublisher):
                self._node.destroy_publisher(handle)
            else:
                self._node.destroy_subscription(handle)

    def _spin(self) -> None:
        while not self._stop.is_set() and self._context.ok():
            try:
                self._executor.spin_once(timeout_sec=_SPIN_S)
            except Exception:
                if self._stop.is_set():
                    return
                log.exception("rclpy executor failed")
                time.sleep(_SPIN_S)
