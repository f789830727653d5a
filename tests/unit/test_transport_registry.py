"""The transports' registry: every backend kind names a Transport class, an unknown kind is refused by name, and the
bookkeeping the backends share lives in the base (an endpoint kept, matched, dropped and closed with it)."""

from __future__ import annotations

import importlib

import pytest

from pipeline.messages.topics import FLEET_TOPICS
from pipeline.ros import NetworkSettings, TransportError, open_transport
from pipeline.ros.transport import BACKEND_CLASSES, BACKENDS, Transport
from tests.unit.test_dds_endpoints import fresh_domain_id


def test_every_backend_kind_names_a_transport_class() -> None:
    assert tuple(BACKEND_CLASSES) == BACKENDS
    for kind, (module, name) in BACKEND_CLASSES.items():
        backend = getattr(importlib.import_module(module), name)
        assert issubclass(backend, Transport), kind


def test_an_unknown_kind_is_refused_naming_the_kinds() -> None:
    with pytest.raises(TransportError, match=r"'zenoh'.*must be one of dds, rclpy, ros1"):
        open_transport("zenoh", NetworkSettings())  # type: ignore[arg-type]


def test_the_base_keeps_matches_and_drops_a_backends_endpoints() -> None:
    spec = FLEET_TOPICS["episode"]
    with open_transport("dds", NetworkSettings(domain_id=fresh_domain_id())) as transport:
        with pytest.raises(TransportError, match="no publisher or subscription on it"):
            transport.matched_count(spec)
        with pytest.raises(TransportError, match="the callback must be callable"):
            transport.subscribe(spec, "not a callback")  # type: ignore[arg-type]
        pub = transport.publisher(spec)
        sub = transport.subscribe(spec, lambda *_: None)
        assert transport.matched_count(spec) == 0  # its own endpoints are not remote
        assert pub in transport._publishers and sub in transport._subscriptions
        pub.close()
        assert pub not in transport._publishers and sub in transport._subscriptions
    assert transport.closed and sub.closed and not transport._subscriptions
    with pytest.raises(TransportError, match="the transport is closed"):
        transport.publisher(spec)
