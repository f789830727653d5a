"""calibration.yaml: profile keys, uncertainties, simulator overrides that training accepts, unidentified keys."""

from __future__ import annotations

from dataclasses import replace

import pytest
import yaml

from pipeline.calibration import (
    Calibration,
    Estimate,
    Source,
    calibration_settings,
    write_calibration,
)
from pipeline.calibration.actuation import ActuationFit, SpeedLimit
from pipeline.errors import ConfigError
from pipeline.params import WorldConfig, calibrated_world, evaluation_world, load_params


def ok(value: float, se: float = 0.001, unit: str = "") -> Estimate:
    return Estimate.of(value, se, (value - 2 * se, value + 2 * se), unit, "test", 100)


def calibration(**changes: Estimate) -> Calibration:
    values = {
        "lidar.beams": ok(360, 0.0, "beams"),
        "lidar.rate_hz": ok(10.0, 0.01, "Hz"),
        "lidar.noise_sigma_m": ok(0.021, 0.0001, "m"),
        "lidar.dropout_prob": ok(0.011, 0.0005, "probability"),
        "lidar.bias_m": ok(0.0098, 0.0001, "m"),
        "lidar.mount_yaw_rad": ok(0.0101, 0.0002, "rad"),
        "actuation.delay_s": ok(0.04, 0.002, "s"),
        "actuation.time_constant_s": ok(0.16, 0.003, "s"),
        "actuation.linear_gain": ok(0.95, 0.005, "ratio"),
        "actuation.angular_gain": Estimate.unidentifiable("no turning commands above 0.05 rad/s", "ratio"),
        "odometry.rate_hz": ok(50.0, 0.1, "Hz"),
        "odometry.drift_per_m": ok(0.041, 0.004, "per m"),
        "network.loss_prob": ok(0.012, 0.001, "probability"),
        "network.jitter_s": ok(0.006, 0.001, "s"),
    }
    values.update(changes)
    source = Source("logs/real/nominal/session.mcap", {"world": "real", "profile": "mild", "scenario": "obstacles"}, 8)
    return Calibration("obstacles", (source,), values)


def test_the_file_holds_profile_uncertainty_world_unidentified_and_source(tmp_path):
    path = write_calibration(calibration(), tmp_path)
    text = path.read_text()
    assert path.name == "calibration.yaml"
    assert "#   actuation.angular_gain: no turning commands above 0.05 rad/s" in text
    data = yaml.safe_load(text)
    assert set(data) == {
        "format",
        "scenario",
        "profile",
        "uncertainty",
        "world",
        "unidentified",
        "effective",
        "ambiguous",
        "trade_offs",
        "gains",
        "speed_limits",
        "source",
    }
    assert data["speed_limits"] == {} and data["effective"] == {} and data["ambiguous"] == []  # no actuation fit
    assert data["trade_offs"] == []  # no lidar fit with a slope
    assert data["gains"] == {}  # no motors fit: one reading of the gains
    assert data["profile"]["lidar"] == {
        "beams": 360,
        "rate_hz": 10.0,
        "noise_sigma_m": 0.021,
        "dropout_prob": 0.011,
        "bias_m": 0.0098,
        "mount_yaw_rad": 0.0101,
    }
    assert "angular_gain" not in data["profile"]["actuation"]
    assert data["uncertainty"]["actuation"]["angular_gain"]["status"] == "unidentifiable"
    assert data["uncertainty"]["lidar"]["noise_sigma_m"] == {
        "status": "ok",
        "value": 0.021,
        "unit": "m",
        "std_error": 0.0001,
        "interval_95": [0.0208, 0.0212],
        "method": "test",
        "n": 100,
    }
    randomize = data["world"].pop("randomize")
    # each identified key is drawn from its 95 % interval, at least +-10 % of its value
    assert randomize["actuation"] == {
        "delay_s": [0.036, 0.044],
        "time_constant_s": [0.144, 0.176],
        "linear_gain": [0.855, 1.045],
    }
    assert randomize["lidar"]["noise_sigma_m"] == [0.0189, 0.0231]
    # the network's estimates (and the sensors' rates) reach the simulator, randomized within their intervals, at
    # least +-10 % of the value
    assert randomize["network"] == {
        "scan_rate_hz": [9.0, 11.0],
        "odom_rate_hz": [45.0, 55.0],
        "loss_prob": [0.01, 0.014],
        "jitter_s": [0.004, 0.008],
    }
    assert data["world"].pop("network") == {
        "scan_rate_hz": 10.0,
        "odom_rate_hz": 50.0,
        "loss_prob": 0.012,
        "jitter_s": 0.006,
    }
    assert data["world"] == {
        "lidar": {
            "noise_sigma_m": 0.021,
            "dropout_prob": 0.011,
            "bias_m": 0.0098,
            "mount_yaw_rad": 0.0101,
            "sim_beams": 360,
            "robot_radius_seen_m": 0.0,
        },
        "actuation": {"delay_s": 0.04, "time_constant_s": 0.16, "linear_gain": 0.95},
        "odometry": {"drift_per_m": 0.041},
    }
    assert data["unidentified"] == {"actuation.angular_gain": "no turning commands above 0.05 rad/s"}
    assert data["source"]["recordings"][0]["session"]["profile"] == "mild"
    assert data["source"]["settings"]["parts"] == ["lidar", "actuation", "odometry", "network"]
    # training reads the world overrides on top of params.yaml; the unidentified gain keeps its nominal value
    world = calibrated_world(WorldConfig(), path)
    assert world.lidar.sim_beams == 360 and world.lidar.noise_sigma_m == 0.021
    assert world.actuation.delay_s == 0.04 and world.actuation.angular_gain == WorldConfig().actuation.angular_gain
    assert world.odometry.drift_per_m == 0.041
    assert world.network.loss_prob == 0.012 and world.network.jitter_s == 0.006 and world.network.plays
    assert world.randomize.network.loss_prob == (0.01, 0.014)
    assert world.randomize.actuation.delay_s == (0.036, 0.044) and world.randomize.actuation.angular_gain == ()
    # the report sits next to it (no fits here: a table and no plots)
    report = (tmp_path / "calibration.md").read_text()
    assert "| `actuation.angular_gain` | unidentifiable |" in report


def test_an_estimate_outside_its_physical_range_is_unidentified_and_the_rest_is_written(tmp_path):
    bad = calibration(
        **{
            "actuation.time_constant_s": ok(3.5, 0.1, "s"),
            "actuation.angular_gain": ok(-0.753237, 0.05, "ratio"),
            "network.loss_prob": ok(0.2, 0.4, "probability"),  # an interval wider than the whole range
        }
    )
    data = yaml.safe_load(write_calibration(bad, tmp_path).read_text())
    missing = data["unidentified"]
    assert (
        "-0.753237" in missing["actuation.angular_gain"]
        and "physical range (> 0.0 and <= 5.0)" in (missing["actuation.angular_gain"])
    )
    assert "3.5 s" in missing["actuation.time_constant_s"]
    assert "wider than its whole physical range" in missing["network.loss_prob"]
    world = data["world"]
    assert "time_constant_s" not in world["actuation"] and "angular_gain" not in world["actuation"]
    assert world["actuation"]["delay_s"] == 0.04 and world["lidar"]["noise_sigma_m"] == 0.021
    assert "loss_prob" not in world["network"] and world["network"]["jitter_s"] == 0.006
    calibrated_world(WorldConfig(), tmp_path / "calibration.yaml")  # training reads it


def test_settings_from_a_mapping_name_bad_keys():
    settings = calibration_settings({"bootstrap": 50, "parts": ["lidar"]})
    assert settings.bootstrap == 50 and settings.parts == ("lidar",)
    with pytest.raises(ConfigError) as err:
        calibration_settings({"bootstrap": 5, "lidar_noise": 1}, source="params.yaml")
    text = str(err.value)
    assert "params.yaml" in text and "bootstrap = 5" in text and "lidar_noise" in text


def test_estimates_as_mappings():
    assert Estimate.unidentifiable("no data", "m").as_mapping() == {
        "status": "unidentifiable",
        "reason": "no data",
        "unit": "m",
        "n": 0,
    }


def test_pairs_are_written_in_the_profile_layout(tmp_path):
    """Mounting offsets and box offsets are estimated per component; the profile holds them as the twin's
    profile does, a box with one unidentified component keeping 0 there."""
    pairs = {
        "lidar.mount_xy_m[0]": ok(0.05, 0.001, "m"),
        "lidar.mount_xy_m[1]": ok(-0.002, 0.001, "m"),
        "map.box_offsets_m[0][0]": ok(0.03, 0.001, "m"),
        "map.box_offsets_m[0][1]": ok(-0.02, 0.001, "m"),
        "map.box_offsets_m[1][0]": Estimate.unidentifiable("seen by 3 clean beams (need 30)", "m"),
        "map.box_offsets_m[1][1]": ok(0.04, 0.001, "m"),
    }
    data = yaml.safe_load(write_calibration(calibration(**pairs), tmp_path, report=False).read_text())
    assert data["profile"]["lidar"]["mount_xy_m"] == [0.05, -0.002]
    assert data["profile"]["map"] == {"box_offsets_m": [[0.03, -0.02], [0.0, 0.04]]}
    assert data["uncertainty"]["map"]["box_offsets_m[1][0]"]["status"] == "unidentifiable"
    assert data["world"]["lidar"]["mount_xy_m"] == [0.05, -0.002]


def test_a_range_below_a_keys_bound_is_kept_inside_it(tmp_path):
    """Noise that does not grow with range can read slightly negative; its interval then lies below the simulator's
    bound of 0, and training draws it at 0 rather than being refused."""
    flat = calibration(**{"lidar.noise_per_m": ok(-0.0001, 0.00002, "m/m")})
    data = yaml.safe_load(write_calibration(flat, tmp_path, report=False).read_text())
    assert data["world"]["randomize"]["lidar"]["noise_per_m"] == [0.0, 0.0]
    assert data["world"]["lidar"]["noise_per_m"] == 0.0


def test_a_speed_limit_is_reported_and_given_to_the_simulator(tmp_path):
    limit = SpeedLimit("linear", ok(0.31, 0.002, "m/s"), commanded_max=0.5, achieved_max=0.312, saturated_share=0.2)
    below = SpeedLimit("angular", Estimate.unidentifiable("no knee", "rad/s"), commanded_max=0.2, achieved_max=0.19)
    values = calibration().values
    fit = ActuationFit(
        *(values[f"actuation.{k}"] for k in ("delay_s", "time_constant_s", "linear_gain", "angular_gain")),
        speed_limits=(limit, below),
    )
    path = write_calibration(replace(calibration(), actuation=fit), tmp_path, report=False)
    text = path.read_text()
    assert "# Saturation: linear speed limit 0.31 [0.306, 0.314] m/s: commanded up to 0.5 m/s" in text
    data = yaml.safe_load(text)
    assert data["speed_limits"]["linear"]["saturated"] is True
    assert data["speed_limits"]["linear"]["value"] == 0.31 and data["speed_limits"]["linear"]["commanded_max"] == 0.5
    assert data["speed_limits"]["angular"] == {
        "saturated": False,
        "status": "unidentifiable",
        "reason": "no knee",
        "unit": "rad/s",
        "n": 0,
        "commanded_max": 0.2,
        "achieved_max": 0.19,
        "saturated_share": 0.0,
    }
    # the simulator cuts its forward speed there; the gain stays the one fitted below the limit
    assert data["world"]["actuation"]["max_linear_mps"] == 0.31
    assert "max_angular_radps" not in data["world"]["actuation"]
    assert data["world"]["actuation"]["linear_gain"] == 0.95
    world = calibrated_world(WorldConfig(), path)
    assert world.actuation.max_linear_mps == 0.31 and world.actuation.max_angular_radps is None


def test_eval_sim_runs_a_round_at_its_values_unless_asked_for_its_randomization(tmp_path):
    """The calibrated round's sim evaluation is the simulator's prediction of the reality it was calibrated to
    (the estimates); its training ranges are what it was made robust to, evaluated only on request."""
    write_calibration(calibration(), tmp_path)
    base = load_params("params.yaml")
    params = replace(base, calibrate=replace(base.calibrate, out_dir=str(tmp_path)))
    assert not params.eval_sim.randomized  # params.yaml's default
    for round_name in ("nominal", "calibrated"):
        at_values = evaluation_world(params, round_name)
        assert at_values.randomize.ranges() == {}
        randomized = evaluation_world(replace(params, eval_sim=replace(params.eval_sim, randomized=True)), round_name)
        assert randomized.randomize.ranges()  # params.yaml's ranges / the calibration's
        assert replace(randomized, randomize=at_values.randomize) == at_values
    calibrated = evaluation_world(params, "calibrated")
    assert calibrated.actuation.delay_s == 0.04 and calibrated.odometry.drift_per_m == 0.041


def test_a_real_lidar_property_enters_the_calibrated_world_only_where_it_is_not_weak(tmp_path):
    """A weak mixed-pixel estimate (its interval wider than its value) is left out of the world and said so in the
    report; an ok one is applied."""
    weak = replace(ok(0.037, 0.01, "probability"), status="weak", interval=(0.021, 0.081), reason="wide")
    cal = calibration(**{"lidar.mixed_pixel_prob": weak, "lidar.beam_noise_spread": ok(0.1, 0.01, "log-sd")})
    lidar = cal.world_overrides()["lidar"]
    assert "mixed_pixel_prob" not in lidar and lidar["beam_noise_spread"] == pytest.approx(0.1)
    write_calibration(cal, tmp_path)
    report = (tmp_path / "calibration.md").read_text()
    assert "lidar.mixed_pixel_prob is weak: not applied to the calibrated world" in report
    assert calibrated_world(WorldConfig(), tmp_path / "calibration.yaml").lidar.mixed_pixel_prob == 0.0
    applied = calibration(**{"lidar.mixed_pixel_prob": ok(0.05, 0.005, "probability")})
    assert applied.world_overrides()["lidar"]["mixed_pixel_prob"] == pytest.approx(0.05)
