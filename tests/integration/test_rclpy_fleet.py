"""A ROS 2 fleet on rclpy: the deploy runner and the hardware twin as two rclpy nodes (Fast DDS, from the ros2 extra's
wheels), the session recorded to MCAP as over dds; and the bad inputs of that tier, each named in one line."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from pipeline.messages.convert import EVENT_NAMES
from pipeline.record import McapLog
from pipeline.ros.rclpy_transport import rclpy_missing
from tests.integration.conftest import check_twin_fleet_plays_two_episodes, free_domain_id, write_fleet
from tests.integration.test_mrl_command import MRL

pytestmark = [
    pytest.mark.integration,
    pytest.mark.ros2,
    pytest.mark.skipif(rclpy_missing() is not None, reason=str(rclpy_missing())),
]


def test_the_twin_plays_an_rclpy_fleet_through_whole_episodes(tiny_policy, tmp_path):
    fleet_file = write_fleet(tmp_path / "fleet.yaml", transport="rclpy", network={"domain_id": free_domain_id()})
    check_twin_fleet_plays_two_episodes(tiny_policy, fleet_file, tmp_path, "rclpy")


@pytest.mark.alone  # the bundled fleet's twin and runner on Fast DDS beside a second worker's test fell off its clock
def test_mrl_deploy_on_the_bundled_rclpy_twin_fleet(tiny_policy, tmp_path):
    domain = free_domain_id()
    done = subprocess.run(
        [str(MRL), "deploy", "--policy", str(tiny_policy), "--fleet", "twin_rclpy", "--episodes", "2",
         "--domain-id", str(domain), "--time-scale", "1", "--out", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    log = McapLog(tmp_path / "out" / "session.mcap")
    assert log.metadata()["session"]["transport"] == "rclpy"
    names = [EVENT_NAMES[m.msg.event] for m in log.messages(["/mrl/episode"])]
    assert names.count("start") == 2 and names.count("end") == 2


def _one_line_refusal(done: subprocess.CompletedProcess[str], *expected: str) -> None:
    assert done.returncode == 2, done.stdout + done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    for text in expected:
        assert text in lines[0], lines[0]


def test_an_rmw_implementation_that_is_not_installed_is_named_before_anything_moves(tiny_policy, tmp_path):
    env = dict(os.environ, RMW_IMPLEMENTATION="rmw_cyclonedds_cpp")
    done = subprocess.run(
        [str(MRL), "deploy", "--policy", str(tiny_policy), "--fleet", "twin_rclpy", "--episodes", "1",
         "--domain-id", str(free_domain_id()), "--out", str(tmp_path / "out")],
        env=env, capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    _one_line_refusal(done, "rmw_cyclonedds_cpp", "RMW_IMPLEMENTATION", "librmw_cyclonedds_cpp.so")
    assert not (tmp_path / "out").exists()


def test_a_distribution_mix_is_named_before_rclpy_loads(tmp_path):
    """The check reads the wheels' versions: an rcl of the other distribution beside this rclpy is named with both."""
    import importlib.metadata

    rclpy_version = importlib.metadata.version("ros-rclpy")
    other_rcl = "9.2.8" if importlib.metadata.version("ros-rcl").startswith("10.") else "10.1.3"
    code = (
        "import importlib.metadata as md, sys\n"
        "real = md.version\n"
        f"md.version = lambda name: {other_rcl!r} if name == 'ros-rcl' else real(name)\n"
        "from pipeline.ros.rclpy_transport import rclpy_missing\n"
        "print(rclpy_missing())\n"
        "print('rclpy' in sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    why, loaded = done.stdout.splitlines()
    assert "mix distributions" in why and f"ros-rcl {other_rcl}" in why and f"ros-rclpy {rclpy_version}" in why, why
    assert "'.[ros2]'" in why and loaded == "False"
