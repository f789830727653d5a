"""Lidar noise, dropout, bias and mounting yaw from synthetic stationary scans with known parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.calibration.lidar import ScanSpan, clipped_moments, estimate_lidar
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.raycast import MapGeometry, cast_circles
from pipeline.core.scenario import load_scenario

SCENARIO = load_scenario("obstacles")
GEOMETRY = MapGeometry.from_scenario(SCENARIO)
SETTINGS = CalibrationSettings(bootstrap=60)
BEAMS = 360
ANGLES = 2 * math.pi * np.arange(BEAMS) / BEAMS
POSES = [(1.0, 1.0, 0.0), (4.0, 2.0, math.pi), (1.0, 3.0, 0.3), (3.2, 1.8, -1.2), (5.0, 3.0, 2.0), (1.6, 2.2, 0.8)]
OTHER = np.array([1.8, 1.4])
"""Another robot stands here throughout: beams that pass it must be left out."""


def spans(
    rng: np.random.Generator,
    sigma: float,
    dropout: float,
    bias: float,
    mount_yaw: float,
    scans: int = 15,
    range_max: float = 8.0,
) -> list[ScanSpan]:
    out = []
    for k, (x, y, yaw) in enumerate(POSES):
        angles = yaw + mount_yaw + ANGLES
        true = GEOMETRY.cast(np.array([x, y]), angles).range_m
        body, _ = cast_circles(np.array([x, y]), angles, OTHER[None], SCENARIO.robot.radius_m)
        true = np.minimum(true, body)
        ranges = true + bias + rng.normal(0, sigma, size=(scans, BEAMS))
        ranges[rng.random((scans, BEAMS)) < dropout] = np.inf
        ranges[:, true > range_max] = np.inf
        others = np.tile(OTHER, (scans, 1, 1))
        out.append(
            ScanSpan(
                f"robot_{k % 3 + 1}",
                f"span {k}",
                0,
                2 * 10**9,
                np.array([x, y, yaw]),
                ANGLES,
                ranges,
                0.12,
                range_max,
                others,
            )
        )
    return out


@pytest.mark.parametrize(
    ("sigma", "dropout", "bias", "mount_yaw"),
    [(0.02, 0.01, 0.01, 0.01), (0.06, 0.05, 0.03, 0.04), (0.01, 0.0, -0.02, -0.2)],
)
def test_noise_dropout_bias_and_mounting_are_recovered(sigma, dropout, bias, mount_yaw):
    rng = np.random.default_rng(0)
    fit = estimate_lidar(GEOMETRY, spans(rng, sigma, dropout, bias, mount_yaw), SETTINGS, rng)
    assert fit.noise_sigma_m.value == pytest.approx(sigma, rel=0.05)
    assert fit.bias_m.value == pytest.approx(bias, abs=max(0.1 * sigma, 0.001))
    assert fit.dropout_prob.value == pytest.approx(dropout, abs=max(0.15 * dropout, 0.002))
    assert fit.mount_yaw_rad.value == pytest.approx(mount_yaw, abs=0.002)
    for est in (fit.noise_sigma_m, fit.bias_m, fit.dropout_prob, fit.mount_yaw_rad):
        assert est.ok and est.std_error is not None and est.interval is not None
        assert est.interval[0] <= est.value <= est.interval[1]
        assert est.method == "bootstrap over 6 stationary spans"
    assert fit.spans == 6 and len(fit.residuals_m) > 5000


def test_beams_hitting_another_robot_are_left_out():
    rng = np.random.default_rng(1)
    fit = estimate_lidar(GEOMETRY, spans(rng, 0.02, 0.0, 0.0, 0.0), SETTINGS, rng)
    # the other robot stands 0.9 m from the first pose: had its beams been cast against the map, residuals
    # of about -2 m would appear
    assert fit.residuals_m.min() > -0.2
    assert fit.bias_m.value == pytest.approx(0.0, abs=0.002)


def test_without_stationary_spans_everything_is_unidentifiable():
    fit = estimate_lidar(GEOMETRY, [], SETTINGS, np.random.default_rng(0))
    for est in (fit.noise_sigma_m, fit.dropout_prob, fit.bias_m, fit.mount_yaw_rad):
        assert est.status == "unidentifiable" and est.reason == "robots never stood still for >= 1 s while scanning"


def test_clipped_moments_ignore_outliers():
    rng = np.random.default_rng(3)
    r = np.r_[rng.normal(0.03, 0.05, 50_000), rng.uniform(-3, 3, 500)]
    mean, sigma, half = clipped_moments(r)
    assert mean == pytest.approx(0.03, abs=0.001)
    assert sigma == pytest.approx(0.05, rel=0.02)
    assert half == pytest.approx(4 * sigma)
