from __future__ import annotations

import pytest

from pipeline.errors import ConfigError
from pipeline.mappings import to_mapping
from pipeline.params import Params, WorldConfig, load_params, world_config


def test_repository_params_load_into_frozen_dataclasses(params_data, write_params):
    params = load_params(write_params(params_data))
    assert isinstance(params, Params)
    assert params.world.lidar.beams == 15
    assert params.world.substeps == 20
    with pytest.raises(AttributeError):
        params.world.max_steps = 3  # type: ignore[misc]


def test_round_trip_through_mapping(params_data, write_params):
    params = load_params(write_params(params_data))
    assert load_params(write_params(to_mapping(params), "again.yaml")) == params


def _problem_of(exc: ConfigError, key: str):
    found = [p for p in exc.problems if p.key == key]
    assert found, f"{key} not reported; got {[p.key for p in exc.problems]}"
    return found[0]


def test_unknown_key_names_file_key_and_allowed_keys(params_data, write_params):
    params_data["world"]["lidar"]["beamz"] = 15
    path = write_params(params_data)
    with pytest.raises(ConfigError) as info:
        load_params(path)
    text = str(info.value)
    assert str(path) in text and "world.lidar.beamz" in text and "beams" in text
    assert "unknown key" in _problem_of(info.value, "world.lidar.beamz").allowed


def test_missing_key_is_reported(params_data, write_params):
    del params_data["world"]["odometry"]["drift_per_m"]
    with pytest.raises(ConfigError) as info:
        load_params(write_params(params_data))
    problem = _problem_of(info.value, "world.odometry.drift_per_m")
    assert "required" in problem.allowed and "<missing>" in str(problem)


@pytest.mark.parametrize(
    ("section", "key", "value", "allowed"),
    [
        ("lidar", "beams", "fifteen", "an integer"),
        ("lidar", "beams", 15.0, "an integer"),
        ("lidar", "noise_sigma_m", "0.01", "a number"),
        ("actions", "kind", "jumpy", "'continuous'"),
        ("actions", "discrete_set", "forward", "a list"),
    ],
)
def test_wrong_type_is_reported_with_what_is_allowed(params_data, write_params, section, key, value, allowed):
    params_data["world"][section][key] = value
    with pytest.raises(ConfigError) as info:
        load_params(write_params(params_data))
    problem = _problem_of(info.value, f"world.{section}.{key}")
    assert allowed in problem.allowed
    assert repr(value) in str(info.value)


@pytest.mark.parametrize(
    ("dotted", "value", "allowed"),
    [
        ("lidar.beams", 0, ">= 1"),
        ("lidar.noise_sigma_m", -0.01, ">= 0.0"),
        ("lidar.dropout_prob", 1.5, "< 1.0"),
        ("max_steps", 0, ">= 1"),
        ("control_period_s", 0.0, "> 0.0"),
        ("reward.path_clearance_m", -0.1, ">= 0.0"),
        ("reward.path_clearance_m", 2.0, "<= 1.0"),
        ("reward.proximity", 0.5, "<= 0.0"),
        ("reward.proximity_m", 0.0, "> 0.0"),
    ],
)
def test_out_of_range_values_fail_with_bounds(params_data, write_params, dotted, value, allowed):
    *parents, leaf = dotted.split(".")
    node = params_data["world"]
    for p in parents:
        node = node[p]
    node[leaf] = value
    with pytest.raises(ConfigError) as info:
        load_params(write_params(params_data))
    assert allowed in _problem_of(info.value, f"world.{dotted}").allowed


@pytest.mark.parametrize(
    ("dotted", "value", "allowed"),
    [
        ("lidar.range_max_m", 0.05, "range_min_m"),
        ("physics_timestep_s", 0.03, "divides control_period_s"),
    ],
)
def test_cross_field_rules(params_data, write_params, dotted, value, allowed):
    *parents, leaf = dotted.split(".")
    node = params_data["world"]
    for p in parents:
        node = node[p]
    node[leaf] = value
    with pytest.raises(ConfigError) as info:
        load_params(write_params(params_data))
    assert allowed in _problem_of(info.value, f"world.{dotted}").allowed


def test_all_problems_reported_in_one_error(params_data, write_params):
    params_data["world"]["lidar"]["beams"] = -1
    params_data["world"]["reward"]["bonus"] = 1
    del params_data["scripted_eval"]["seed"]
    with pytest.raises(ConfigError) as info:
        load_params(write_params(params_data))
    assert len(info.value.problems) == 3


def test_malformed_and_missing_files(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("world: [unclosed\n")
    with pytest.raises(ConfigError, match="valid YAML"):
        load_params(bad)
    with pytest.raises(ConfigError, match="readable file"):
        load_params(tmp_path / "absent.yaml")
    top = tmp_path / "list.yaml"
    top.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="a mapping with keys world"):
        load_params(top)


def test_overrides_merge_onto_defaults_and_validate():
    cfg = world_config({"lidar": {"noise_sigma_m": 0.05}, "max_steps": 10})
    assert cfg.lidar.noise_sigma_m == 0.05 and cfg.lidar.beams == WorldConfig().lidar.beams
    assert cfg.max_steps == 10
    with pytest.raises(ConfigError, match=r"lidar.noise_sigma_m = -1"):
        world_config({"lidar": {"noise_sigma_m": -1}})
    with pytest.raises(ConfigError, match="unknown key"):
        world_config({"lidar_noise": 0.1})


def test_booleans_are_not_numbers():
    with pytest.raises(ConfigError, match="max_steps = True"):
        world_config({"max_steps": True})


@pytest.mark.parametrize(
    ("train", "world", "dotted", "allowed"),
    [
        ({"algorithm": "sac"}, {"actions": {"kind": "discrete"}}, "world.actions.kind", "'continuous' for"),
        ({"algorithm": "dqn"}, {"actions": {"kind": "continuous"}}, "world.actions.kind", "'discrete' for"),
        (
            {"algorithm": "ppo", "mode": "shared"},
            {"observation": "paper"},
            "world.observation",
            "'rich_memory' for train.mode 'shared'",
        ),
    ],
)
def test_training_that_does_not_fit_the_world_is_refused(params_data, write_params, train, world, dotted, allowed):
    params_data["train"].update(train)
    for key, value in world.items():
        if isinstance(value, dict):
            params_data["world"][key].update(value)
        else:
            params_data["world"][key] = value
    path = write_params(params_data)
    with pytest.raises(ConfigError) as info:
        load_params(path)
    assert str(path) in str(info.value)
    assert allowed in _problem_of(info.value, dotted).allowed


@pytest.mark.parametrize(("key", "value"), [("algorithm", "td3"), ("mode", "swarm")])
def test_unknown_algorithm_or_mode_lists_the_allowed_ones(params_data, write_params, key, value):
    params_data["train"][key] = value
    with pytest.raises(ConfigError) as info:
        load_params(write_params(params_data))
    allowed = _problem_of(info.value, f"train.{key}").allowed
    expected = ("'sac'", "'dqn'", "'ppo'") if key == "algorithm" else ("'independent'", "'shared'", "'centralized'")
    assert all(name in allowed for name in expected)


@pytest.mark.parametrize(
    ("section", "key", "value", "allowed"),
    [
        (("train", "sac"), "update", "fast", "'batched'"),
        (("train", "sac"), "ent_coef_init", 0.0, "> 0.0"),
        (("world", "actions"), "reverse", "sometimes", "true or false"),
    ],
)
def test_new_sac_and_action_keys_are_checked(params_data, write_params, section, key, value, allowed):
    node = params_data
    for part in section:
        node = node[part]
    node[key] = value
    with pytest.raises(ConfigError) as info:
        load_params(write_params(params_data))
    problem = _problem_of(info.value, ".".join((*section, key)))
    assert allowed in str(problem.allowed)
