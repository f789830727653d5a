"""One reality model: the simulator's world, the twin's profiles and calibration take each quantity's domain from
pipeline.core.quantities, so their bounds agree by construction."""

from __future__ import annotations

import dataclasses
import typing

import pytest

from pipeline.core import quantities as Q
from pipeline.core.reality import RealityProfile, profile_bounds, profile_setting
from pipeline.params import WorldConfig

BOUND_KEYS = ("ge", "gt", "le", "lt")


def _sim_setting(section: str, key: str) -> dataclasses.Field[typing.Any]:
    config = typing.get_type_hints(WorldConfig)[section]
    return next(f for f in dataclasses.fields(config) if f.name == key)


@pytest.mark.parametrize("profile_key", sorted(Q.SHARED))
def test_the_simulator_and_the_profile_take_one_domain_for_each_shared_quantity(profile_key):
    section, sim_key, quantity = Q.SHARED[profile_key]
    want = quantity.bounds()
    sim = _sim_setting(section, sim_key).metadata
    profile = profile_setting(profile_key).metadata
    assert {k: sim[k] for k in BOUND_KEYS} == want, f"world.{section}.{sim_key}"
    assert {k: profile[k] for k in BOUND_KEYS} == want, profile_key
    low, high = profile_bounds(profile_key)
    assert low >= quantity.low and high <= quantity.high  # calibration's bounds: the profile's, the quantity's
    assert (low > quantity.low) == quantity.low_open and (high < quantity.high) == quantity.high_open


def test_every_shared_key_exists_on_both_sides_and_the_bounds_that_drifted_agree():
    for profile_key, (section, sim_key, _) in Q.SHARED.items():
        assert profile_setting(profile_key) is not None
        assert _sim_setting(section, sim_key) is not None
    # the bounds that had drifted apart: the range bias (+-1 m in the simulator, +-0.5 m in a profile) and a
    # dropout of exactly 1 (allowed in the simulator, not in a profile)
    assert profile_bounds("lidar.bias_m") == (-0.5, 0.5)
    assert _sim_setting("lidar", "bias_m").metadata["le"] == 0.5
    assert _sim_setting("lidar", "dropout_prob").metadata["lt"] == 1.0
    assert profile_bounds("lidar.dropout_prob")[1] < 1.0


def test_a_quantity_s_open_end_is_an_exclusive_bound():
    assert Q.LINEAR_GAIN.bounds() == {"ge": None, "gt": 0.0, "le": 5.0, "lt": None}
    assert Q.LOSS_PROB.bounds() == {"ge": 0.0, "gt": None, "le": None, "lt": 1.0}


def test_a_world_with_a_value_outside_a_quantity_s_domain_is_refused_naming_the_key(tmp_path):
    from pipeline.errors import ConfigError
    from pipeline.params import load_params

    path = tmp_path / "params.yaml"
    path.write_text("world:\n  lidar:\n    bias_m: 0.7\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"world\.lidar\.bias_m"):
        load_params(path)


def test_every_profile_section_is_a_dataclass_of_the_reality_profile():
    groups = {key.split(".")[0] for key in Q.SHARED}
    assert groups <= set(typing.get_type_hints(RealityProfile))
