"""The roles of the package stay apart: who may import whom (docs/architecture.md)."""

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
    # the network edge: no simulator, training, recording or episode loop
    "ros": (
        "pipeline.sim",
        "pipeline.learn",
        "pipeline.twin",
        "pipeline.record",
        "pipeline.rollout",
        "torch",
        "mujoco",
    ),
    # the policy runtime needs neither the training library nor pickle
    "record": ("pipeline.sim", "pipeline.ros", "pipeline.learn", "pipeline.rollout", "cyclonedds", "rclpy"),
    # the policy runtime and its spec: onnxruntime and numpy, nothing that runs a world or trains
    "policy": ("pipeline.sim", "pipeline.learn", "pipeline.rollout", "pipeline.record", "pipeline.ros", "torch"),
    # rollouts drive exported policies: never the training library
    "rollout": ("pipeline.learn", "stable_baselines3", "torch"),
    "sim": ("pipeline.ros", "pipeline.twin", "cyclonedds", "rclpy"),
    "learn": ("pipeline.ros", "pipeline.twin", "cyclonedds", "rclpy"),
    # the twin stands for reality: physics and sensors of its own, never the training simulator
    "twin": ("pipeline.sim", "pipeline.learn", "pipeline.rollout", "pipeline.policy", "pipeline.mdp"),
    "analysis": ("pipeline.ros", "cyclonedds", "rclpy"),
    "calibration": ("pipeline.ros", "pipeline.learn", "cyclonedds", "rclpy"),
    # the benchmark trains and evaluates in the simulator: no network, no twin
    "bench": ("pipeline.ros", "pipeline.twin", "pipeline.rollout.deployment", "cyclonedds", "rclpy"),
}


@pytest.mark.parametrize("folder", sorted(FORBIDDEN))
def test_roles_do_not_import_what_they_must_not(folder):
    for module, names in imports_of(folder).items():
        bad = sorted(n for n in names if n.startswith(FORBIDDEN[folder]))
        assert not bad, f"pipeline/{module} imports {bad}"


def test_only_ros_talks_to_the_network():
    for folder in (
        "core",
        "sim",
        "learn",
        "bench",
        "policy",
        "record",
        "analysis",
        "calibration",
        "messages",
        "twin",
        "mrl",
        "",
    ):
        for module, names in imports_of(folder).items():
            assert not any(n.startswith(("cyclonedds", "rclpy")) for n in names), f"pipeline/{module} imports DDS"


def test_the_policy_runtime_loads_without_the_training_stack():
    runtime = imports_of("policy")["policy/runtime.py"]
    training = ("stable_baselines3", "torch", "pickle", "cloudpickle", "pipeline.learn")
    assert not any(n.startswith(training) for n in runtime)


LAYERS: tuple[tuple[str, ...], ...] = (
    ("errors",),
    ("mappings",),
    ("core",),
    ("params", "messages"),
    ("mdp",),
    ("sim", "policy", "record", "ros"),
    ("twin", "rollout", "analysis", "calibration"),
    ("learn",),
    ("bench",),
    ("runs",),
    ("stage",),
    ("mrl",),
)
"""Who may import whom, bottom up: a part imports only parts of lower layers (and itself). Rollouts sit
above the simulator, the policy runtime, the recorder and the transport; training runs its selection
episodes through rollouts and exports policies, so it sits above them; the benchmark runs training; the
builders of a deployment or an evaluation run, shared by the stages and the command line, sit below the stages'
plumbing; the command line is on top."""


def _layer(part: str) -> int:
    for k, parts in enumerate(LAYERS):
        if part in parts:
            return k
    raise AssertionError(f"pipeline/{part} has no layer in LAYERS; add it")


def test_no_part_imports_a_part_above_it():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        part = rel.parts[0] if len(rel.parts) > 1 else rel.stem
        if part == "__init__":
            continue
        tree = ast.parse(path.read_text())
        typing_only = {
            id(n)
            for block in ast.walk(tree)
            if isinstance(block, ast.If) and getattr(block.test, "id", "") == "TYPE_CHECKING"
            for stmt in block.body
            for n in ast.walk(stmt)
        }
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            for name in names:
                if not name.startswith("pipeline.") or name.split(".")[1] == part:
                    continue
                target = name.split(".")[1]
                assert _layer(target) < _layer(part), (
                    f"pipeline/{rel} ({part}) imports {name}, a part above or beside it"
                )
