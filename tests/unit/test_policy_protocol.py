"""One policy protocol: the exported runtime and the calibration drives satisfy it, and its members are exactly what
sim evaluation, deployment, replay and the drives use of the policy they are given."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from pipeline.core.actions import ActionCodec
from pipeline.policy.excitation import ExcitationDrive, StillThenDrive
from pipeline.policy.protocol import Policy
from pipeline.policy.runtime import PolicyRuntime
from pipeline.policy.scripted import GoToGoalController, PathFollowingController
from tests.unit.test_policy_runtime import LAYOUT, ROBOTS, write_policy

PACKAGE = Path(__file__).resolve().parents[2] / "pipeline"

CONSUMERS = {
    "rollout/runner.py": "runtime",
    "rollout/deployment.py": "runtime",
    "rollout/sim.py": "runtime",
    "analysis/replay.py": "runtime",
    "policy/excitation.py": "policy",
}
"""The modules that take "the policy", and the name they hold it by (a parameter, or an attribute of ``self``)."""


@pytest.fixture(scope="module")
def runtime(tmp_path_factory: pytest.TempPathFactory) -> PolicyRuntime:
    return PolicyRuntime(write_policy(tmp_path_factory.mktemp("protocol") / "policy", "continuous"))


def implementations(runtime: PolicyRuntime) -> dict[str, Policy]:
    """Every kind of policy the episode loops are given, built over `runtime` (typed as the protocol, so that a type
    checker holds each to it)."""
    return {
        "runtime": runtime,
        "excitation": ExcitationDrive(runtime, seed=0),
        "still_then_drive": StillThenDrive(runtime, 0.0),
        "excitation_over_still": ExcitationDrive(StillThenDrive(runtime, 0.0), seed=1),
    }


def observations() -> np.ndarray:
    """(n_robots, layout.size) float32: two robots with every lidar range 2 m and the goal 1 m ahead."""
    obs = np.zeros((len(ROBOTS), LAYOUT.size), dtype=np.float32)
    obs[:, LAYOUT.slices["ranges"]] = 2.0
    obs[:, LAYOUT.slices["goal_in_robot"]] = (1.0, 0.0)
    return obs


def test_the_runtime_and_the_drives_are_policies(runtime: PolicyRuntime) -> None:
    obs = observations()
    for label, policy in implementations(runtime).items():
        assert isinstance(policy, Policy), label
        assert policy.robots == tuple(ROBOTS) == policy.spec.robots, label
        assert policy.layout == LAYOUT and policy.codec.kind == "continuous", label
        assert policy.document == runtime.document, label
        assert all(isinstance(k, str) and isinstance(v, str) for k, v in policy.session_extra.items()), label
        assert policy.actions(obs).shape == (len(ROBOTS), 2), label
        assert policy.commands(obs).shape == (len(ROBOTS), 2), label
        policy.check_fits(ROBOTS, LAYOUT, "continuous", (policy.codec.v_max_mps, policy.codec.w_max_radps))


def test_only_the_drives_add_session_metadata(runtime: PolicyRuntime) -> None:
    extra = {label: dict(policy.session_extra) for label, policy in implementations(runtime).items()}
    assert extra["runtime"] == {}
    assert extra["excitation"] == {"drive": "excitation", "drive_seed": "0"}
    assert extra["still_then_drive"] == {"drive": "still_then_drive", "still_s": "0"}


def test_scripted_controllers_are_action_functions_not_policies() -> None:
    codec = ActionCodec("continuous", 0.4, 0.8)
    assert not isinstance(GoToGoalController(LAYOUT, codec), Policy)
    assert not isinstance(PathFollowingController(LAYOUT, codec), Policy)


def protocol_members() -> set[str]:
    return {name for name in vars(Policy) if not name.startswith("_")}


def used_of_the_policy(module: str, name: str) -> set[str]:
    """The attributes `module` reads of the policy it holds as `name` or ``self.<name>`` (``getattr`` included)."""

    def is_policy(node: ast.expr) -> bool:
        if isinstance(node, ast.Name):
            return node.id == name
        return (
            isinstance(node, ast.Attribute)
            and node.attr == name
            and isinstance(node.value, ast.Name)
            and node.value.id == "self"
        )

    used = set()
    for node in ast.walk(ast.parse((PACKAGE / module).read_text())):
        if isinstance(node, ast.Attribute) and is_policy(node.value):
            used.add(node.attr)
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in ("getattr", "hasattr")
            and is_policy(node.args[0])
            and isinstance(node.args[1], ast.Constant)
        ):
            used.add(str(node.args[1].value))
    return used


def test_the_protocol_has_exactly_the_members_its_consumers_use() -> None:
    members = protocol_members()
    used = {module: used_of_the_policy(module, name) for module, name in CONSUMERS.items()}
    for module, names in used.items():
        assert names, f"pipeline/{module} reads nothing of {CONSUMERS[module]!r}: is it still a consumer?"
        assert names <= members, f"pipeline/{module} reads {sorted(names - members)} of the policy, not in Policy"
    unused = members - set().union(*used.values())
    assert not unused, f"Policy declares {sorted(unused)}, which no consumer reads"
    assert {"spec", "layout", "codec", "name", "actions"} <= used["rollout/runner.py"]
