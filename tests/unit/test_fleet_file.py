"""Fleet files: the outage limit is checked against the staleness limits before anything starts."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from pipeline.errors import ConfigError
from pipeline.ros.fleet import fleet_path, load_fleet


def write(tmp_path: Path, **timing: object) -> Path:
    data = yaml.safe_load(fleet_path("twin").read_text())
    data["timing"] = {**data["timing"], **timing}
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_bundled_fleets_carry_an_outage_limit_of_several_seconds():
    for name in ("twin", "spark_lab"):
        fleet = load_fleet(name)
        assert fleet.timing.outage_limit_s == 5.0
        assert fleet.timing.outage_limit_s > fleet.timing.scan_stale_s


@pytest.mark.parametrize(
    ("timing", "needle"),
    [
        (
            {"outage_limit_s": 0.4},
            "timing.outage_limit_s = 0.4: at least the longest staleness limit (timing.scan_stale_s = 0.5 s)",
        ),
        ({"outage_limit_s": 1.0, "truth_stale_s": 2.0}, "(timing.truth_stale_s = 2 s)"),
        ({"outage_limit_s": -1.0}, "timing.outage_limit_s = -1.0"),
        ({"abort_after_s": 1.0}, "abort_after_s"),
    ],
)
def test_an_outage_limit_below_the_staleness_limits_or_negative_is_a_named_error(tmp_path, timing, needle):
    path = write(tmp_path, **timing)
    with pytest.raises(ConfigError) as err:
        load_fleet(path)
    assert str(path) in str(err.value) and needle in str(err.value)


def test_without_ground_truth_its_staleness_limit_does_not_bind():
    fleet_file = yaml.safe_load(fleet_path("twin").read_text())
    fleet_file["timing"].update(use_ground_truth=False, truth_stale_s=9.0, outage_limit_s=1.0)
    from pipeline.mappings import from_mapping
    from pipeline.ros.fleet import Fleet

    assert from_mapping(Fleet, fleet_file, "fleet").timing.outage_limit_s == 1.0


def test_the_bundled_ros1_twin_fleet_names_no_master():
    fleet = load_fleet("twin_ros1")
    assert fleet.transport == "ros1" and fleet.target == "twin"
    assert fleet.network_settings().master_uri == ""  # the deployment brings its own


@pytest.mark.parametrize(
    ("uri", "needle"),
    [
        ("127.0.0.1:11311", "network.master_uri = '127.0.0.1:11311': must be http://HOST:PORT"),
        ("http://", "network.master_uri = 'http://': must be http://HOST:PORT"),
        ("http://robot-1.local", "network.master_uri = 'http://robot-1.local': needs its port"),
        ("http://10.0.0.5:99999", "network.master_uri = 'http://10.0.0.5:99999': has a bad host or port"),
    ],
)
def test_a_bad_master_uri_names_the_key(tmp_path, uri, needle):
    data = yaml.safe_load(fleet_path("twin_ros1").read_text())
    data["network"]["master_uri"] = uri
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_fleet(path)
    assert needle in str(err.value) and str(path) in str(err.value)
