"""Network settings, topic checks and backend choice fail with errors that name the setting and what is allowed."""

from __future__ import annotations

import importlib.util
import sys

import pytest

from pipeline.messages import topics as T
from pipeline.ros import (
    BackendUnavailableError,
    NetworkSettings,
    NetworkSettingsError,
    TransportError,
    open_transport,
)
from pipeline.ros.dds import cyclone_config, parse_type_hash, type_hash_user_data
from pipeline.ros.transport import check_topic

HAS_RCLPY = importlib.util.find_spec("rclpy") is not None


def test_defaults_are_domain_0_on_loopback() -> None:
    settings = NetworkSettings()
    assert (settings.domain_id, settings.loopback_only, settings.peers) == (0, True, ())


@pytest.mark.parametrize("domain_id", [-1, 233, 1000, "5", 3.0, True, None])
def test_bad_domain_id_names_the_setting_and_range(domain_id: object) -> None:
    with pytest.raises(NetworkSettingsError, match=r"domain_id.*0\.\.232") as info:
        NetworkSettings(domain_id=domain_id)  # type: ignore[arg-type]
    assert info.value.setting == "domain_id"
    assert info.value.value == domain_id


@pytest.mark.parametrize("domain_id", [0, 42, 101, 232])
def test_domain_ids_in_range_are_accepted(domain_id: int) -> None:
    assert NetworkSettings(domain_id=domain_id).domain_id == domain_id


@pytest.mark.parametrize(
    "peer",
    ["", "   ", "999.1.1.1", "10.0.0.1:0", "10.0.0.1:70000", "robot:abc", "a b", "-robot", "robot_1", "::1", 17, None],
)
def test_malformed_peer_names_its_index_and_the_allowed_form(peer: object) -> None:
    with pytest.raises(NetworkSettingsError, match=r"peers\[1\].*IPv4 address or host name") as info:
        NetworkSettings(loopback_only=False, peers=("10.0.0.2", peer))  # type: ignore[arg-type]
    assert info.value.setting == "peers[1]"


def test_peers_must_be_a_list_not_a_string() -> None:
    with pytest.raises(NetworkSettingsError, match=r"peers.*list of addresses"):
        NetworkSettings(loopback_only=False, peers="10.0.0.2")  # type: ignore[arg-type]


def test_a_remote_peer_needs_loopback_only_off() -> None:
    with pytest.raises(NetworkSettingsError, match=r"peers\[0\].*not a loopback address.*loopback_only"):
        NetworkSettings(peers=("192.168.1.20",))


def test_loopback_only_must_be_a_bool() -> None:
    with pytest.raises(NetworkSettingsError, match=r"loopback_only.*true or false"):
        NetworkSettings(loopback_only="yes")  # type: ignore[arg-type]


def test_valid_peers_are_kept_as_a_tuple() -> None:
    assert NetworkSettings(peers=["127.0.0.1", "localhost:7412"]).peers == ("127.0.0.1", "localhost:7412")  # type: ignore[arg-type]
    remote = NetworkSettings(domain_id=7, loopback_only=False, peers=("192.168.1.20", "robot-1.local"))
    assert remote.peers == ("192.168.1.20", "robot-1.local")


def test_loopback_config_pins_the_interface_and_discovers_by_unicast() -> None:
    config = cyclone_config(NetworkSettings(domain_id=3, peers=("127.0.0.2",)))
    assert '<NetworkInterface address="127.0.0.1"/>' in config
    assert "<AllowMulticast>false</AllowMulticast>" in config
    assert "<ParticipantIndex>auto</ParticipantIndex>" in config
    assert "<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>" in config
    assert '<Peer address="127.0.0.1"/><Peer address="127.0.0.2"/>' in config


def test_lan_config_keeps_multicast_and_adds_unicast_peers() -> None:
    config = cyclone_config(NetworkSettings(loopback_only=False, peers=("192.168.1.20",)))
    assert "AllowMulticast" not in config and "NetworkInterface" not in config
    assert '<Peer address="192.168.1.20"/>' in config
    assert "Peers" not in cyclone_config(NetworkSettings(loopback_only=False))


def test_cyclonedds_uri_is_appended_after_the_generated_fragment() -> None:
    config = cyclone_config(NetworkSettings(), "file:///etc/site.xml")
    assert config.endswith(",file:///etc/site.xml")
    assert config.startswith("<CycloneDDS>")


def test_user_data_is_the_jazzy_typehash_entry() -> None:
    # `ros2 topic info --verbose` on Jazzy shows this hash for geometry_msgs/msg/Twist
    twist = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
    assert type_hash_user_data(T.TWIST) == f"typehash={twist};".encode()
    assert parse_type_hash(type_hash_user_data(T.TWIST)) == twist
    assert parse_type_hash(b"enclave=/;typehash=RIHS01_ab;") == "RIHS01_ab"
    assert parse_type_hash(b"enclave=/;") == ""


@pytest.mark.parametrize(
    "name", ["robot_1/scan", "/robot 1/scan", "/robot_1//scan", "/robot_1/scan/", "/1robot/scan", ""]
)
def test_bad_topic_names_are_refused(name: str) -> None:
    with pytest.raises(TransportError, match="fully qualified ROS 2 name"):
        check_topic(T.TopicSpec(name, T.TWIST, T.QOS_COMMAND))


def test_unknown_type_and_bad_depth_are_refused() -> None:
    with pytest.raises(TransportError, match="/x: unknown message type 'nope/msg/X'"):
        check_topic(T.TopicSpec("/x", "nope/msg/X", T.QOS_COMMAND))
    with pytest.raises(TransportError, match="/x: history depth 0"):
        check_topic(T.TopicSpec("/x", T.TWIST, T.QosProfile("reliable", "volatile", 0)))
    with pytest.raises(TransportError, match="reliability 'sometimes'"):
        check_topic(T.TopicSpec("/x", T.TWIST, T.QosProfile("sometimes", "volatile", 1)))  # type: ignore[arg-type]


def test_every_contract_topic_passes_the_checks() -> None:
    for spec in T.fleet_topics(["robot_1", "robot_2"]).values():
        check_topic(spec)


def test_unknown_backend_lists_the_known_ones() -> None:
    with pytest.raises(TransportError, match=r"'zenoh'.*dds, rclpy"):
        open_transport("zenoh", NetworkSettings())  # type: ignore[arg-type]


def test_rclpy_backend_without_rclpy_says_so(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "rclpy", None)  # not importable, installed here or not
    with pytest.raises(
        BackendUnavailableError, match=r"transport 'rclpy'.*pip install -e '\.\[ros2\]'.*'dds' transport"
    ):
        open_transport("rclpy", NetworkSettings())


def test_rclpy_module_imports_without_rclpy() -> None:
    import pipeline.ros.rclpy_transport as module

    assert module.rclpy_available() is HAS_RCLPY


def test_an_interface_this_host_lacks_or_on_loopback_only_is_named():
    with pytest.raises(NetworkSettingsError, match=r"interface.*'lo'.*loopback_only = true uses the loopback"):
        NetworkSettings(interface="lo")
    with pytest.raises(NetworkSettingsError, match=r"'mrl-no-such-if'.*not an interface of this host.*it has: .*lo"):
        NetworkSettings(loopback_only=False, interface="mrl-no-such-if").check_host()
    assert NetworkSettings(loopback_only=False, interface="lo").interface_address() == "127.0.0.1"
    assert NetworkSettings(loopback_only=False, interface="127.0.0.1").interface_address() == "127.0.0.1"


def test_a_peer_that_does_not_resolve_is_named_before_a_transport_opens():
    settings = NetworkSettings(loopback_only=False, peers=("no-such-robot.invalid",))
    with pytest.raises(NetworkSettingsError, match=r"peers\[0\].*no-such-robot\.invalid.*does not resolve"):
        settings.check_host()


def test_dds_binds_the_interface_named():
    config = cyclone_config(NetworkSettings(loopback_only=False, interface="lo", peers=("10.231.9.2",)))
    assert '<NetworkInterface address="127.0.0.1"/>' in config and '<Peer address="10.231.9.2"/>' in config
    assert "NetworkInterface" not in cyclone_config(NetworkSettings(loopback_only=False, peers=("10.231.9.2",)))
