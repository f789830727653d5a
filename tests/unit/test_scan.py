from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.core.errors import ScanError
from pipeline.core.scan import ScanGeometry, reduce_scan, uncovered_beams

FULL_360 = ScanGeometry(360, 0.0, math.radians(1.0), 0.12, 12.0)


def test_pick_takes_the_beam_nearest_each_policy_angle():
    ranges = np.arange(360, dtype=float) / 100 + 1.0  # beam d degrees reads 1 + d/100
    out = reduce_scan(ranges, FULL_360, 15, 0.055, 5.0, "pick")
    expected = 1.0 + np.arange(15) * 24 / 100  # policy beam k at 24 k degrees
    np.testing.assert_allclose(out, expected)


def test_sector_min_takes_the_closest_valid_return_in_each_sector():
    ranges = np.full(360, 4.0)
    ranges[10] = 0.8  # sector 0 spans [-12, 12) degrees
    ranges[355] = 0.5  # also sector 0, across the wrap
    ranges[40] = 1.5  # sector 1 spans [12, 36), sector 2 [36, 60)
    out = reduce_scan(ranges, FULL_360, 15, 0.055, 5.0, "sector_min")
    assert out[0] == 0.5
    assert out[1] == 4.0
    assert out[2] == 1.5


def test_ros_special_values():
    ranges = np.full(360, 3.0)
    ranges[0:13] = np.inf  # no return -> range_max
    ranges[340:360] = np.inf
    ranges[24] = -np.inf  # too close -> policy range_min (sector 1 is [12, 36))
    ranges[48] = np.nan  # erroneous: ignored, sector keeps its other beams
    ranges[58:86] = np.nan  # a whole sector of errors -> nothing seen -> range_max
    ranges[120] = 0.05  # below the sensor's range_min: invalid
    ranges[144] = 20.0  # beyond the sensor's range_max: no return
    out = reduce_scan(ranges, FULL_360, 15, 0.055, 5.0, "sector_min")
    assert out[0] == 5.0
    assert out[1] == 0.055
    assert out[2] == 3.0
    assert out[3] == 5.0
    assert out[5] == 3.0 and out[6] == 3.0
    assert np.isfinite(out).all()


def test_output_is_clipped_to_policy_limits():
    ranges = np.full(360, 9.0)
    ranges[0] = 0.13
    out = reduce_scan(ranges, FULL_360, 15, 0.2, 5.0, "sector_min")
    assert out.min() == 0.2 and out.max() == 5.0


def test_partial_field_of_view_and_negative_angle_min():
    # a 270 degree scanner centred forward: -135 .. +135 degrees in 541 beams
    geom = ScanGeometry(541, -math.radians(135), math.radians(0.5), 0.1, 10.0)
    ranges = np.full(541, 2.0)
    out = reduce_scan(ranges, geom, 8, 0.1, 5.0, "sector_min")
    # policy beam 4 points backwards (180 deg): no source beam in its sector -> nothing seen
    assert out[4] == 5.0
    assert out[0] == 2.0 and out[1] == 2.0 and out[7] == 2.0


def test_batches_reduce_row_by_row():
    rng = np.random.default_rng(0)
    batch = rng.uniform(0.2, 6.0, size=(4, 360))
    out = reduce_scan(batch, FULL_360, 15, 0.055, 5.0)
    assert out.shape == (4, 15)
    for i in range(4):
        np.testing.assert_array_equal(out[i], reduce_scan(batch[i], FULL_360, 15, 0.055, 5.0))


def test_identity_when_geometries_match():
    geom = ScanGeometry(15, 0.0, 2 * math.pi / 15, 0.055, 5.0)
    ranges = np.linspace(0.5, 4.5, 15)
    for method in ("pick", "sector_min"):
        np.testing.assert_array_equal(reduce_scan(ranges, geom, 15, 0.055, 5.0, method), ranges)


@pytest.mark.parametrize(
    ("ranges", "geom", "beams", "match"),
    [
        (np.ones(10), FULL_360, 15, "10 ranges"),
        (np.ones(360), FULL_360, 0, "at least one beam"),
        (np.ones(360), ScanGeometry(360, 0.0, math.radians(1), 5.0, 1.0), 15, "range_min < range_max"),
        (np.ones(360), ScanGeometry(360, float("nan"), 0.01, 0.1, 1.0), 15, "finite"),
    ],
)
def test_bad_scans_raise_scan_error(ranges, geom, beams, match):
    with pytest.raises(ScanError, match=match):
        reduce_scan(ranges, geom, beams, 0.055, 5.0)


def test_uncovered_beams_finds_the_policy_directions_a_scan_cannot_see():
    full = ScanGeometry(360, -math.pi, 2 * math.pi / 360, 0.05, 8.0)
    assert uncovered_beams(full, 15) == []
    # 15 beams where the policy reads 15: every sector has its own beam
    assert uncovered_beams(ScanGeometry(15, 0.0, 2 * math.pi / 15, 0.05, 8.0), 15) == []
    # 10 beams 36 deg apart leave 5 of the 24 deg sectors empty
    sparse = ScanGeometry(10, 0.0, 2 * math.pi / 10, 0.05, 8.0)
    blind = uncovered_beams(sparse, 15)
    assert len(blind) == 5
    ranges = np.full(10, 1.0)
    out = reduce_scan(ranges, sparse, 15, 0.1, 3.5, "sector_min")
    assert np.all(out[blind] == 3.5) and np.all(np.delete(out, blind) == 1.0)
    # a front-facing 180 deg lidar leaves the rear half blind (policy beam 0 looks forward)
    front = ScanGeometry(181, -math.pi / 2, math.pi / 180, 0.05, 8.0)
    rear = uncovered_beams(front, 16)
    assert rear == list(range(5, 12))
