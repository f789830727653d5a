"""Which ROS 2 distribution is installed, and the interface packages built from schemas/ (no ROS 2 needed here)."""

from __future__ import annotations

import importlib.metadata
import re
from pathlib import Path

import pytest

from pipeline.ros import ros2_interfaces as ri
from pipeline.ros.errors import BackendUnavailableError

pytestmark = pytest.mark.ros2

JAZZY = {"ros-rclpy": "7.1.6", "ros-rcl": "9.2.8", "ros-rmw-fastrtps-cpp": "8.4.3", "ros-std-msgs": "5.3.6"}
KILTED = {"ros-rclpy": "9.1.2", "ros-rcl": "10.1.3", "ros-rmw-fastrtps-cpp": "9.3.3", "ros-std-msgs": "5.5.1"}


def wheels(monkeypatch: pytest.MonkeyPatch, versions: dict[str, str]) -> None:
    def version(name: str) -> str:
        if name in versions:
            return versions[name]
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "version", version)


@pytest.mark.parametrize(("versions", "distro"), [(JAZZY, "jazzy"), (KILTED, "kilted")])
def test_the_wheels_tell_their_distribution(monkeypatch, versions, distro):
    wheels(monkeypatch, versions)
    installation = ri.check_distribution()
    assert installation.distribution == distro and installation.source == "wheels"


def test_a_mix_of_distributions_is_named_with_each_wheel(monkeypatch):
    wheels(monkeypatch, {**JAZZY, "ros-rcl": "10.1.3"})
    with pytest.raises(BackendUnavailableError) as raised:
        ri.check_distribution()
    text = str(raised.value)
    assert "jazzy: " in text and "kilted: ros-rcl 10.1.3" in text and "ros-rclpy 7.1.6" in text
    assert "'.[ros2]'" in text and "'.[ros2-kilted]'" in text


def test_a_sourced_installation_is_used_without_wheels(monkeypatch, tmp_path):
    wheels(monkeypatch, {})
    monkeypatch.setenv("ROS_DISTRO", "jazzy")
    monkeypatch.setenv("AMENT_PREFIX_PATH", f"{tmp_path}/ws/install:/opt/ros/jazzy")
    installation = ri.check_distribution()
    assert installation == ri.Installation("jazzy", (f"{tmp_path}/ws/install", "/opt/ros/jazzy"), "sourced")


def test_no_installation_names_both_ways_to_get_one(monkeypatch):
    wheels(monkeypatch, {})
    monkeypatch.delenv("ROS_DISTRO", raising=False)
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    with pytest.raises(
        BackendUnavailableError, match=r"pip install -e '\.\[ros2\]'.*source /opt/ros/jazzy/setup\.bash"
    ):
        ri.check_distribution()


def test_a_prefix_per_distribution_installation_and_schema(monkeypatch, tmp_path):
    monkeypatch.setenv(ri.CACHE_VARIABLE, str(tmp_path))
    jazzy = ri.prefix_for(ri.Installation("jazzy", ("/venv",), "wheels"))
    assert jazzy.parent == tmp_path / "ros2-interfaces" and jazzy.name.startswith("jazzy-")
    assert ri.prefix_for(ri.Installation("kilted", ("/venv",), "wheels")) != jazzy
    assert ri.prefix_for(ri.Installation("jazzy", ("/other-venv",), "wheels")) != jazzy
    assert re.fullmatch(r"[0-9a-f]{64}", ri.schema_digest())


def test_the_environment_prepends_the_prefix_like_a_setup_script(monkeypatch, tmp_path):
    monkeypatch.setenv("LD_LIBRARY_PATH", f"/somewhere/lib:{tmp_path}/lib")
    env = ri.environment(tmp_path)
    assert env["LD_LIBRARY_PATH"] == f"{tmp_path}/lib:/somewhere/lib"
    assert env["AMENT_PREFIX_PATH"].split(":")[0] == str(tmp_path)
    assert env["PYTHONPATH"].split(":")[0].startswith(str(tmp_path)) and "site-packages" in env["PYTHONPATH"]


def test_a_package_without_a_cmakelists_gets_one_naming_its_messages_and_dependencies(tmp_path):
    folder = ri.package_sources("tf2_msgs", tmp_path)
    cmake = (folder / "CMakeLists.txt").read_text()
    assert "project(tf2_msgs)" in cmake and '"msg/TFMessage.msg"' in cmake
    assert "find_package(geometry_msgs REQUIRED)" in cmake and "DEPENDENCIES geometry_msgs" in cmake
    manifest = (folder / "package.xml").read_text()
    assert "<name>tf2_msgs</name>" in manifest and "<member_of_group>rosidl_interface_packages" in manifest
    # mrl_msgs builds from its own committed CMakeLists.txt, as colcon would
    assert ri.package_sources("mrl_msgs", tmp_path) == Path(ri.SCHEMA_ROOT) / "mrl_msgs"


def test_without_cmake_the_build_is_refused_naming_what_to_install(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(ri.shutil, "which", lambda *a, **k: None)
    with pytest.raises(BackendUnavailableError, match="needs cmake and a C\\+\\+ compiler: pip install cmake"):
        ri.build(ri.Installation("jazzy", ("/venv",), "wheels"), tmp_path / "p", ("mrl_msgs",), tmp_path / "log")
