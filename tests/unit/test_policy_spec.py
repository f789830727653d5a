"""The policy spec: one typed, versioned file, read with the config's strict rules and no defaults."""

from __future__ import annotations

import json

import pytest

from pipeline.errors import ConfigError
from pipeline.mappings import to_mapping
from pipeline.mdp import MdpDefinition, mdp_parts
from pipeline.policy.errors import PolicyError
from pipeline.policy.spec import FORMAT, PolicySpec, read_policy_spec, write_policy_spec
from pipeline.sim.env import MultiRobotSim
from tests.policy_helpers import spec_mapping


def _write(path, mapping) -> None:
    path.write_text(json.dumps(mapping))


def test_a_spec_round_trips_bit_for_bit(tmp_path):
    _write(tmp_path / "a.json", spec_mapping("ab" * 32))
    spec = read_policy_spec(tmp_path / "a.json")
    assert isinstance(spec, PolicySpec) and spec.format == FORMAT
    write_policy_spec(spec, tmp_path / "b.json")
    again = read_policy_spec(tmp_path / "b.json")
    assert again == spec
    write_policy_spec(again, tmp_path / "c.json")
    assert (tmp_path / "b.json").read_bytes() == (tmp_path / "c.json").read_bytes()
    assert to_mapping(again) == spec_mapping("ab" * 32)


@pytest.mark.parametrize(
    ("drop", "key"),
    [
        (lambda m: m["world"].pop("max_steps"), "world.max_steps"),
        (lambda m: m["world"].pop("progress_distance"), "world.progress_distance"),
        (lambda m: m["world"]["reward"].pop("goal"), "world.reward.goal"),
        (lambda m: m["training"].pop("seed"), "training.seed"),
        (lambda m: m.pop("scenario"), "scenario"),
    ],
)
def test_a_spec_missing_a_key_is_refused_naming_it(tmp_path, drop, key):
    mapping = spec_mapping("ab" * 32)
    drop(mapping)
    _write(tmp_path / "policy.json", mapping)
    with pytest.raises(ConfigError) as err:
        read_policy_spec(tmp_path / "policy.json")
    text = str(err.value)
    assert str(tmp_path / "policy.json") in text and key in text and "required" in text


def test_unknown_and_mistyped_keys_are_refused_together(tmp_path):
    mapping = spec_mapping("ab" * 32)
    mapping["world"]["judge_margin"] = 0.1
    mapping["world"]["max_steps"] = "350"
    _write(tmp_path / "policy.json", mapping)
    with pytest.raises(ConfigError) as err:
        read_policy_spec(tmp_path / "policy.json")
    assert "world.judge_margin" in str(err.value) and "world.max_steps" in str(err.value)


def test_an_observation_that_disagrees_with_the_world_is_refused(tmp_path):
    mapping = spec_mapping("ab" * 32)
    mapping["observation"]["n_beams"] = 30
    _write(tmp_path / "policy.json", mapping)
    with pytest.raises(ConfigError, match="observation"):
        read_policy_spec(tmp_path / "policy.json")


def test_an_earlier_format_is_refused_with_the_command_that_exports_it_again(tmp_path):
    _write(tmp_path / "policy.json", {"format": "mrl-policy/1", "actions": {}})
    with pytest.raises(PolicyError, match=r"mrl-policy/1.*stages/export\.py"):
        read_policy_spec(tmp_path / "policy.json")
    (tmp_path / "bad.json").write_text("{nope")
    with pytest.raises(PolicyError, match="not JSON"):
        read_policy_spec(tmp_path / "bad.json")


def test_the_mdp_of_a_spec_is_the_simulators_mdp_of_the_same_world(tmp_path):
    _write(tmp_path / "policy.json", spec_mapping("ab" * 32, n_robots=3))
    spec = read_policy_spec(tmp_path / "policy.json")
    sim = MultiRobotSim(spec.scenario, spec.world)
    parts = mdp_parts(spec.scenario, spec.world)
    assert sim.mdp.definition == parts.definition == spec.mdp == MdpDefinition.of(spec.world)
    assert (sim.observer.low == parts.observer.low).all() and (sim.observer.high == parts.observer.high).all()
    assert sim.codec == parts.codec


def test_mdp_differences_name_the_params_keys():
    base = read_policy_spec_from(spec_mapping("ab" * 32))
    other = spec_mapping("ab" * 32)
    other["world"]["max_steps"] = 200
    other["world"]["actions"]["v_max_mps"] = 0.3
    other["world"]["lidar"]["noise_sigma_m"] = 0.05  # noise is the simulator's, not the MDP's
    changed = read_policy_spec_from(other)
    assert base.mdp.differences(changed.mdp) == ["world.actions.v_max_mps 0.4 vs 0.3", "world.max_steps 350 vs 200"]


def read_policy_spec_from(mapping) -> PolicySpec:
    from pipeline.mappings import from_mapping

    return from_mapping(PolicySpec, mapping, "<test>")


def test_reward_settings_can_be_left_out_of_the_comparison():
    base = read_policy_spec_from(spec_mapping("ab" * 32))
    other = spec_mapping("ab" * 32)
    other["world"]["reward"]["heading_per_rad"] = 2.0
    other["world"]["progress_distance"] = "euclidean"
    changed = read_policy_spec_from(other)
    assert len(base.mdp.differences(changed.mdp)) == 2
    assert base.mdp.differences(changed.mdp, reward=False) == []
