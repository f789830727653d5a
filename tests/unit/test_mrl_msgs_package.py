"""schemas/mrl_msgs is a ROS 2 interface package as colcon builds it: its manifest and CMake list every message."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET

from pipeline.messages.store import SCHEMAS_DIR, schema_files

PACKAGE = SCHEMAS_DIR / "mrl_msgs"


def test_the_manifest_is_an_interface_package_of_format_3():
    root = ET.parse(PACKAGE / "package.xml").getroot()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == "mrl_msgs"
    assert root.findtext("member_of_group") == "rosidl_interface_packages"
    tools = {e.text for e in root.findall("buildtool_depend")}
    assert {"ament_cmake", "rosidl_default_generators"} <= tools
    # every package a message refers to is a dependency
    used = {
        ref.split("/")[0]
        for path in PACKAGE.glob("msg/*.msg")
        for ref in re.findall(r"^\s*([a-z_]+/[A-Za-z0-9_]+)", path.read_text(), re.MULTILINE)
    }
    assert used - {"mrl_msgs"} <= {e.text for e in root.findall("depend")}


def test_cmake_generates_every_message_of_the_package():
    listed = set(re.findall(r'"msg/([A-Za-z0-9_]+)\.msg"', (PACKAGE / "CMakeLists.txt").read_text()))
    ours = {name.rsplit("/", 1)[1] for name in schema_files() if name.startswith("mrl_msgs/")}
    assert listed == ours and ours
