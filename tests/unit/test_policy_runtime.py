"""The policy runtime refuses a policy.json, golden set or world whose action kind disagrees, saying which and how."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.core.observation import ObservationLayout
from pipeline.policy.errors import PolicyError, PolicyMismatch
from pipeline.policy.networks import ActionNetwork, Dense
from pipeline.policy.onnx_graph import policy_graph
from pipeline.policy.runtime import PolicyRuntime
from tests.policy_helpers import spec_mapping

ROBOTS = ["robot_1", "robot_2"]
LAYOUT = ObservationLayout("rich", 15)


def write_policy(folder: Path, kind: str) -> Path:
    """A shared-mode policy of one random layer for two robots, with its golden set: what export writes."""
    rng = np.random.default_rng(0)
    discrete = kind == "discrete"
    n_out = 3 if discrete else 2
    hidden = Dense(rng.normal(size=(8, LAYOUT.size)).astype(np.float32), np.zeros(8, np.float32))
    out = Dense(rng.normal(size=(n_out, 8)).astype(np.float32) * 0.1, np.zeros(n_out, np.float32))
    net = ActionNetwork((hidden,), "relu", out, "argmax" if discrete else "tanh")
    model = policy_graph([net], "shared", len(ROBOTS), LAYOUT.size, discrete, 3)
    data = model.SerializeToString()
    obs = rng.normal(size=(4, len(ROBOTS), LAYOUT.size)).astype(np.float32)
    actions = [net.forward(o).tolist() for o in obs]  # float64 reference: ONNX agrees to ~1e-7, not to the bit
    folder.mkdir()
    (folder / "policy.onnx").write_bytes(data)
    golden = {"observations": obs.tolist(), "actions": actions, "tolerance": 1e-5}
    (folder / "golden.json").write_text(json.dumps(golden))
    meta = spec_mapping(hashlib.sha256(data).hexdigest(), kind, len(ROBOTS), LAYOUT.name, LAYOUT.n_beams)
    (folder / "policy.json").write_text(json.dumps(meta))
    return folder


def edit(folder: Path, name: str, change) -> None:
    path = folder / name
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


@pytest.mark.parametrize(("trained", "edited"), [("continuous", "discrete"), ("discrete", "continuous")])
def test_an_edited_actions_kind_names_the_key_and_both_kinds(tmp_path, trained, edited):
    folder = write_policy(tmp_path / "policy", trained)
    assert PolicyRuntime(folder).codec.kind == trained
    edit(folder, "policy.json", lambda meta: meta["world"]["actions"].update(kind=edited))
    for verify in (True, False):
        with pytest.raises(PolicyError) as err:
            PolicyRuntime(folder, verify=verify)
        message = str(err.value)
        assert message.startswith(f"{folder / 'policy.json'}: world.actions.kind is {edited!r}")
        assert f"the policy was trained with {trained!r}" in message
        assert "[[" not in message and "\n" not in message  # no arrays of numbers to compare by eye


def test_a_world_of_the_other_kind_names_world_actions_kind(tmp_path):
    runtime = PolicyRuntime(write_policy(tmp_path / "policy", "continuous"))
    with pytest.raises(PolicyMismatch) as err:
        runtime.check_fits(ROBOTS, LAYOUT, "discrete")
    assert "world.actions.kind is 'discrete' but the policy was trained with 'continuous'" in str(err.value)
    runtime.check_fits(ROBOTS, LAYOUT, "continuous")


def test_golden_actions_off_by_more_than_the_tolerance_give_the_difference_not_two_arrays(tmp_path):
    folder = write_policy(tmp_path / "policy", "continuous")
    edit(folder, "golden.json", lambda g: g["actions"][2][1].__setitem__(0, g["actions"][2][1][0] + 0.01))
    with pytest.raises(PolicyError) as err:
        PolicyRuntime(folder)
    message = str(err.value)
    assert "golden observation 2" in message and "by up to 0.01, beyond its tolerance 1e-05 (robot robot_2:" in message
    assert "[[" not in message


def test_golden_actions_of_the_wrong_shape_are_a_policy_error(tmp_path):
    folder = write_policy(tmp_path / "policy", "continuous")
    edit(folder, "golden.json", lambda g: g.update(actions=[row[0] for row in g["actions"]]))
    with pytest.raises(PolicyError, match=r"golden.json: actions have shape \(4, 2\); .* need \(4, 2, 2\)"):
        PolicyRuntime(folder)


def test_an_input_scaling_folds_into_the_first_layer_or_is_refused_when_broken():
    from pipeline.policy.networks import SCALE_CENTER, SCALE_HALF_RANGE, action_network

    rng = np.random.default_rng(0)
    weights = {
        "mlp_extractor.policy_net.0.weight": rng.normal(size=(8, 5)).astype(np.float32),
        "mlp_extractor.policy_net.0.bias": rng.normal(size=8).astype(np.float32),
        "action_net.weight": rng.normal(size=(2, 8)).astype(np.float32),
        "action_net.bias": rng.normal(size=2).astype(np.float32),
    }
    center = np.array([3.0, 2.0, 0.0, 0.5, 2.5], dtype=np.float32)
    half = np.array([4.0, 3.0, 1.0, 9.2, 2.47], dtype=np.float32)
    plain = action_network("ppo_actor", weights, discrete=False)
    scaled = action_network("ppo_actor", {**weights, SCALE_CENTER: center, SCALE_HALF_RANGE: half}, discrete=False)
    x = rng.uniform(-1, 6, size=(64, 5))
    np.testing.assert_allclose(scaled.forward(x), plain.forward((x - center) / half), atol=1e-5)
    with pytest.raises(PolicyError, match=r"lack 'features_extractor.half_range'"):
        action_network("ppo_actor", {**weights, SCALE_CENTER: center}, discrete=False, where="w.pt")
    with pytest.raises(PolicyError, match=r"positive finite half ranges of 5 values"):
        action_network("ppo_actor", {**weights, SCALE_CENTER: center, SCALE_HALF_RANGE: 0 * half}, discrete=False)
