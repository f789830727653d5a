"""The roles of the package stay apart: who may import whom (DESIGN section 2)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "pipeline"


def imports_of(folder: str) -> dict[str, set[str]]:
    """Module file -> every module it imports (absolute names)."""
    out = {}
    for path in sorted((PACKAGE / folder).rglob("*.py")) if folder else sorted(PACKAGE.glob("*.py")):
        names: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module:
                names.add(node.module)
        out[str(path.relative_to(PACKAGE))] = names
    return out


FORBIDDEN = {
    # the MDP is shared by every world: it depends on nothing else of the pipeline
    "core": ("pipeline.sim", "pipeline.ros", "pipeline.learn", "pipeline.record", "pipeline.twin", "pipeline.policy"),
    # the deploy side never runs the simulator or the training library
    "ros": ("pipeline.sim", "pipeline.learn", "pipeline.twin", "stable_baselines3", "torch", "mujoco"),
    # the policy runtime needs neither the training library nor pickle
    "record": ("pipeline.sim", "pipeline.ros", "pipeline.learn", "cyclonedds", "rclpy"),
    "sim": ("pipeline.ros", "pipeline.twin", "cyclonedds", "rclpy"),
    "learn": ("pipeline.ros", "pipeline.twin", "cyclonedds", "rclpy"),
    "analysis": ("pipeline.ros", "cyclonedds", "rclpy"),
    "calibration": ("pipeline.ros", "pipeline.learn", "cyclonedds", "rclpy"),
}


@pytest.mark.parametrize("folder", sorted(FORBIDDEN))
def test_roles_do_not_import_what_they_must_not(folder):
    for module, names in imports_of(folder).items():
        bad = sorted(n for n in names if n.startswith(FORBIDDEN[folder]))
        assert not bad, f"pipeline/{module} imports {bad}"


def test_only_ros_talks_to_the_network():
    for folder in ("core", "sim", "learn", "policy", "record", "analysis", "calibration", "messages", "twin", ""):
        for module, names in imports_of(folder).items():
            assert not any(n.startswith(("cyclonedds", "rclpy")) for n in names), f"pipeline/{module} imports DDS"


def test_the_policy_runtime_loads_without_the_training_stack():
    runtime = imports_of("policy")["policy/runtime.py"]
    training = ("stable_baselines3", "torch", "pickle", "cloudpickle", "pipeline.learn")
    assert not any(n.startswith(training) for n in runtime)
