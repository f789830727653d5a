"""Lidar noise, dropout, bias, mounting, blocked sectors and the room's true geometry from synthetic stationary
scans with known parameters."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pipeline.calibration.lidar import ScanSpan, _span_means, clipped_moments, dropout_estimate, estimate_lidar
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
    mount_xy: tuple[float, float] = (0.0, 0.0),
    per_m: float = 0.0,
    blocked: tuple[float, float] | None = None,
    room: MapGeometry = GEOMETRY,
    poses: list[tuple[float, float, float]] = POSES,
    angle_errors: np.ndarray | None = None,
) -> list[ScanSpan]:
    """Still spans at `poses`; `angle_errors` (rad, per beam) turn each beam off its stated angle in every span."""
    out = []
    for k, (x, y, yaw) in enumerate(poses):
        angles = yaw + mount_yaw + ANGLES + (0.0 if angle_errors is None else angle_errors)
        origin = np.array(
            [
                x + math.cos(yaw) * mount_xy[0] - math.sin(yaw) * mount_xy[1],
                y + math.sin(yaw) * mount_xy[0] + math.cos(yaw) * mount_xy[1],
            ]
        )
        true = room.cast(origin, angles).range_m
        body, _ = cast_circles(origin, angles, OTHER[None], SCENARIO.robot.radius_m)
        true = np.minimum(true, body)
        ranges = true + bias + rng.normal(0, 1, size=(scans, BEAMS)) * (sigma + per_m * true)
        ranges[rng.random((scans, BEAMS)) < dropout] = np.inf
        ranges[:, true > range_max] = np.inf
        if blocked is not None:
            ranges[:, (blocked[0] <= ANGLES) & (blocked[1] >= ANGLES)] = 0.04
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
    assert fit.dropout_prob.method.startswith("share of usable beams over 6 stationary spans")
    for est in (fit.noise_sigma_m, fit.bias_m, fit.mount_yaw_rad):  # noise and geometry: six spans at six poses
        assert "(5 d.o.f.) on a bootstrap over 6 viewpoints" in est.method
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
        assert est.status == "unidentifiable"
        assert est.reason.startswith("robots never stood still for >= 1 s while scanning: the bias")


def driving(
    rng: np.random.Generator,
    sigma: float,
    per_m: float,
    scans: int = 240,
    pose_error: tuple[float, float] = (0.03, 0.02),
    angle_error_rad: float = 0.0,
    episodes: int = 8,
) -> list[ScanSpan]:
    """One scan each at poses along the room, each stated with an error of the pose (m, rad) as a localization or a
    smoothed ground truth has; each beam off its stated angle by a fixed error (per lidar unit)."""
    out = []
    offsets = {f"robot_{k}": rng.normal(0.0, angle_error_rad, BEAMS) for k in (1, 2, 3)}
    while len(out) < scans:
        x, y, yaw = rng.uniform(0.4, 5.6), rng.uniform(0.4, 3.6), rng.uniform(-math.pi, math.pi)
        if GEOMETRY.clearance(np.array([[x, y]]))[0] < 0.35 or math.hypot(x - OTHER[0], y - OTHER[1]) < 0.5:
            continue
        robot = f"robot_{len(out) % 3 + 1}"
        true = GEOMETRY.cast(np.array([x, y]), yaw + ANGLES + offsets[robot]).range_m
        body, _ = cast_circles(np.array([x, y]), yaw + ANGLES, OTHER[None], SCENARIO.robot.radius_m)
        true = np.minimum(true, body)
        ranges = true + rng.normal(0, 1, BEAMS) * (sigma + per_m * true)
        stated = np.array([x + rng.normal(0, pose_error[0]), y + rng.normal(0, pose_error[0]), yaw])
        stated[2] += rng.normal(0, pose_error[1])
        label = f"{robot}/episode {len(out) % episodes}"
        out.append(ScanSpan(robot, label, 0, 0, stated, ANGLES, ranges[None], 0.12, 8.0, OTHER[None, None]))
    return out


def _driving_truth(fit, sigma: float, per_m: float) -> tuple[float, float, float, float]:
    at, est = fit.noise_driving.at_range
    lo, hi = est.interval
    return sigma + per_m * at, float(est.value), lo, hi


def test_noise_while_driving_agrees_with_the_still_spans_and_pose_errors_do_not_read_as_noise():
    rng = np.random.default_rng(3)
    still = spans(rng, 0.01, 0.0, 0.0, 0.0, per_m=0.004)
    fit = estimate_lidar(GEOMETRY, still, SETTINGS, rng, driving(rng, 0.01, 0.004))
    truth, value, lo, hi = _driving_truth(fit, 0.01, 0.004)
    # 3 cm and 1 degree of pose error move a beam's range by centimetres; against its neighbours they cancel
    assert value == pytest.approx(truth, rel=0.05)
    assert lo <= truth <= hi and lo >= 0.0
    (note,) = [n for n in fit.notes if n.startswith("noise from 240 scans while driving")]
    assert ": agrees with the still spans'" in note
    assert fit.noise_driving.at_range[0] == pytest.approx(fit.noise_at_range[0])  # compared at one range


def test_the_still_spans_disagreeing_with_the_scans_while_driving_is_named():
    rng = np.random.default_rng(4)
    still = spans(rng, 0.03, 0.0, 0.0, 0.0)  # something moving in view: the still spans read three times the noise
    fit = estimate_lidar(GEOMETRY, still, SETTINGS, rng, driving(rng, 0.01, 0.0))
    (note,) = [n for n in fit.notes if n.startswith("noise from 240 scans while driving")]
    assert "DISAGREES with the still spans'" in note and "driving reads less" in note


def test_without_still_spans_the_noise_comes_from_the_scans_while_driving():
    rng = np.random.default_rng(5)
    fit = estimate_lidar(GEOMETRY, [], SETTINGS, rng, driving(rng, 0.008, 0.005))
    assert fit.bias_m.status == "unidentifiable" and fit.mount_yaw_rad.status == "unidentifiable"
    assert fit.noise_sigma_m.ok and fit.noise_per_m.ok
    truth, value, lo, hi = _driving_truth(fit, 0.008, 0.005)
    assert lo <= truth <= hi and value == pytest.approx(truth, rel=0.05)
    assert fit.noise_sigma_m.interval[0] >= 0.0 and fit.noise_per_m.interval[0] >= 0.0
    assert any(n.startswith("no still span: the noise comes from 240 scans while driving") for n in fit.notes)


def test_beam_angle_errors_add_to_the_noise_while_driving_and_its_interval_admits_them():
    covered = 0
    for seed in range(4):
        rng = np.random.default_rng(10 + seed)
        moving = driving(rng, 0.004, 0.0, angle_error_rad=0.002)
        fit = estimate_lidar(GEOMETRY, spans(rng, 0.004, 0.0, 0.0, 0.0), SETTINGS, rng, moving)
        truth, value, lo, hi = _driving_truth(fit, 0.004, 0.0)
        assert value >= truth * 0.97  # angle errors only add
        covered += lo <= truth <= hi
    assert covered >= 3


def test_clipped_moments_ignore_outliers():
    rng = np.random.default_rng(3)
    r = np.r_[rng.normal(0.03, 0.05, 50_000), rng.uniform(-3, 3, 500)]
    mean, sigma, half = clipped_moments(r)
    assert mean == pytest.approx(0.03, abs=0.001)
    assert sigma == pytest.approx(0.05, rel=0.02)
    assert half == pytest.approx(4 * sigma)


MOVED = load_scenario("obstacles")
MOVED = dataclasses.replace(
    MOVED,
    room=dataclasses.replace(
        MOVED.room,
        x_min_m=MOVED.room.x_min_m - 0.015,
        x_max_m=MOVED.room.x_max_m + 0.015,
        y_min_m=MOVED.room.y_min_m - 0.015,
        y_max_m=MOVED.room.y_max_m + 0.015,
    ),
    obstacles=tuple(
        dataclasses.replace(box, x_m=box.x_m + dx, y_m=box.y_m + dy)
        for box, (dx, dy) in zip(MOVED.obstacles, [(0.03, -0.02), (-0.025, 0.04)], strict=False)
    ),
)
MANY_POSES = [
    (x, y, yaw)
    for x in (0.8, 1.6, 2.4, 3.6, 4.4, 5.2)
    for y, yaw in ((0.9, 0.4), (2.1, -2.0), (3.2, 1.9))
    if GEOMETRY.clearance(np.array([[x, y]]))[0] > 0.4
]


def test_a_lab_lidar_in_a_room_that_is_not_where_the_map_says():
    """The lab's lidar: 5 cm ahead of the axle, turned, noise growing with range, a mast behind it; walls 1.5 cm
    further out and boxes a few cm off: every one is recovered, with intervals that contain the truth."""
    rng = np.random.default_rng(7)
    data = spans(
        rng,
        0.01,
        0.02,
        0.01,
        0.03,
        mount_xy=(0.05, 0.0),
        per_m=0.004,
        blocked=(2.9, 3.38),
        room=MapGeometry.from_scenario(MOVED),
        poses=MANY_POSES,
    )
    fit = estimate_lidar(GEOMETRY, data, SETTINGS, rng)
    truth = {
        "noise_sigma_m": 0.01,
        "noise_per_m": 0.004,
        "dropout_prob": 0.02,
        "bias_m": 0.01,
        "mount_yaw_rad": 0.03,
        "mount_x_m": 0.05,
        "mount_y_m": 0.0,
        "wall_offset_m": 0.015,
    }
    for key, value in truth.items():
        est = getattr(fit, key)
        assert est.ok, (key, est.reason)
        assert est.interval[0] <= value <= est.interval[1], (key, est.value, est.interval)
    assert fit.noise_sigma_m.value == pytest.approx(0.01, rel=0.15)
    assert fit.noise_per_m.value == pytest.approx(0.004, rel=0.15)
    assert fit.mount_x_m.value == pytest.approx(0.05, abs=0.005)
    unseen = 0
    for (ex, ey), (dx, dy) in zip(fit.box_offsets_m, [(0.03, -0.02), (-0.025, 0.04)], strict=True):
        # about 30-70 beams see a box: millimetres; a face seen by fewer than 30 clean beams is said to be
        for est, truth in ((ex, dx), (ey, dy)):
            if not est.ok:
                assert "clean beams (need 30)" in est.reason, est
                unseen += 1
                continue
            assert est.value == pytest.approx(truth, abs=0.002)
            assert est.interval[0] <= truth <= est.interval[1], (truth, est)
    assert unseen <= 1
    (sector,) = fit.blocked_sectors_rad
    assert sector[0] == pytest.approx(2.9, abs=0.02) and sector[1] == pytest.approx(3.38, abs=0.02)
    assert fit.dropout_prob.value == pytest.approx(0.02, abs=0.004)


def test_noise_that_grows_with_distance_is_read_against_the_distance_not_the_biased_range():
    """The noise grows with the distance a beam travels; the measured range is that plus the lidar's bias. Against
    the measured range the noise line's intercept would move by -noise_per_m x bias (here 40 % of it)."""
    rng = np.random.default_rng(11)
    data = spans(rng, 0.005, 0.0, 0.2, 0.0, scans=30, per_m=0.01, poses=MANY_POSES)
    fit = estimate_lidar(GEOMETRY, data, SETTINGS, rng)
    assert fit.bias_m.ok and fit.bias_m.value == pytest.approx(0.2, abs=0.005)
    assert fit.noise_sigma_m.value == pytest.approx(0.005, rel=0.1)
    assert fit.noise_sigma_m.interval[0] <= 0.005 <= fit.noise_sigma_m.interval[1]
    assert fit.noise_per_m.value == pytest.approx(0.01, rel=0.1)


def test_static_errors_do_not_read_as_noise():
    """Noise comes from each beam's spread about its own mean: a 5 cm mounting offset and moved boxes, which
    put centimetres between the scans and the map, do not read as noise."""
    rng = np.random.default_rng(8)
    data = spans(
        rng, 0.01, 0.0, 0.0, 0.0, mount_xy=(0.05, 0.0), room=MapGeometry.from_scenario(MOVED), poses=MANY_POSES
    )
    fit = estimate_lidar(GEOMETRY, data, SETTINGS, rng)
    assert fit.noise_sigma_m.value == pytest.approx(0.01, rel=0.1)
    assert fit.noise_per_m.interval[0] <= 0.0 <= fit.noise_per_m.interval[1]
    assert fit.mount_x_m.value == pytest.approx(0.05, abs=0.002)


def test_the_residual_spectrum_is_noise_unless_the_map_has_structure_left():
    """Span means that are the fitted noise alone read as noise in every band; a 2 cm wave of 3 cycles per
    revolution (a wall the map has straight) stands out in its band only; a beam on another robot is left out."""
    from pipeline.calibration.lidar import residual_spectrum

    rng = np.random.default_rng(0)
    beams, scans, sigma = 360, 40, 0.01
    angle = 2 * np.pi * np.arange(beams) / beams
    cast = np.full(beams, 2.0)
    count = np.full(beams, scans)

    def spans(structure: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        out = []
        for _ in range(30):
            mean = structure + rng.normal(0.0, sigma / np.sqrt(scans), beams)
            mean[17] = 1.5  # a beam on another robot
            out.append((mean, count, cast))
        return out

    plain = residual_spectrum(spans(np.zeros(beams)), sigma, 0.0)
    assert plain is not None and plain.left_out == 30
    assert all(0.7 < power / noise < 1.4 for _, _, power, noise in plain.bands())
    wavy = residual_spectrum(spans(0.02 * np.sin(3 * angle)), sigma, 0.0)
    assert wavy is not None
    ratios = {(lo, hi): power / noise for lo, hi, power, noise in wavy.bands()}
    assert ratios[(2, 3)] > 50 and all(r < 1.5 for band, r in ratios.items() if band != (2, 3))


def _viewpoint_coverage(trials: int) -> dict[str, float]:
    """Share of `trials` recordings in which each geometry key's interval covers the truth: six viewpoints with five
    spans each, every viewpoint's stated pose off by an error of its own (4 mm, 3 mrad) that its spans share."""
    truth = {"bias_m": 0.01, "wall_offset_m": 0.015, "mount_yaw_rad": 0.02, "mount_x_m": 0.0, "mount_y_m": 0.0}
    covered = dict.fromkeys(truth, 0)
    for seed in range(trials):
        rng = np.random.default_rng(seed)
        data = []
        for pose in POSES:
            error = rng.normal(0.0, 1.0, 3) * np.array([0.004, 0.004, 0.003])
            room = MapGeometry.from_scenario(MOVED)
            for span in spans(rng, 0.01, 0.0, 0.01, 0.02, scans=5, poses=[pose] * 5, room=room):
                data.append(dataclasses.replace(span, pose=span.pose + error))
        fit = estimate_lidar(GEOMETRY, data, SETTINGS, rng)
        for key, value in truth.items():
            lo, hi = getattr(fit, key).interval
            covered[key] += int(lo <= value <= hi)
    return {key: n / trials for key, n in covered.items()}


def test_spans_at_one_pose_count_as_one_viewpoint(monkeypatch):
    """Errors a viewpoint's spans share (here its pose; on a robot, whatever the model leaves unexplained from that
    spot) are as many samples as viewpoints, not spans: intervals from the viewpoints cover the truth about 95 % of
    the time, intervals that took the 30 spans for independent ones cover about half."""
    coverage = _viewpoint_coverage(20)
    assert min(coverage.values()) >= 0.8 and np.mean(list(coverage.values())) >= 0.9, coverage
    monkeypatch.setattr("pipeline.calibration.lidar.VIEWPOINT_M", 0.0)  # every span a viewpoint of its own
    per_span = _viewpoint_coverage(10)
    assert np.mean(list(per_span.values())) <= 0.75, per_span


def _box_coverage(trials: int) -> float:
    """Share of the boxes' offsets whose intervals cover the truth over `trials` recordings of the lab's room (boxes
    a few cm off) through a lidar whose every beam points off its stated angle (0.002 rad, its own in every span)."""
    covered = total = 0
    room = MapGeometry.from_scenario(MOVED)
    for seed in range(trials):
        rng = np.random.default_rng(100 + seed)
        errors = rng.normal(0.0, 0.002, BEAMS)
        data = spans(rng, 0.003, 0.0, 0.0, 0.0, scans=8, room=room, poses=MANY_POSES[:6], angle_errors=errors)
        fit = estimate_lidar(GEOMETRY, data, SETTINGS, rng)
        for (ex, ey), (dx, dy) in zip(fit.box_offsets_m, [(0.03, -0.02), (-0.025, 0.04)], strict=True):
            for est, truth in ((ex, dx), (ey, dy)):
                if est.ok:
                    total += 1
                    covered += int(est.interval[0] <= truth <= est.interval[1])
    assert total >= trials, "the boxes were not seen"
    return covered / total


def test_box_offsets_admit_beams_off_their_stated_angles(monkeypatch):
    """A box seen at a slant by a few dozen beams moves by millimetres under the beams' angle errors, which no still
    scan identifies and the residuals of so few beams do not show: its interval takes them from their prior, and
    covers the truth; without that prior it is too sure."""
    coverage = _box_coverage(12)
    assert coverage >= 0.9, coverage
    monkeypatch.setattr("pipeline.calibration.lidar.BEAM_ANGLE_ERROR_RAD", 0.0)
    without = _box_coverage(12)
    assert without < coverage, (without, coverage)


def test_a_span_s_mean_range_leaves_out_returns_far_off_the_beam():
    """A mixed pixel or a robot crossing a beam, a metre off in one scan of 20, does not move the beam's mean (it
    would move it by 5 cm, and with it the walls and boxes fitted to it)."""
    rng = np.random.default_rng(3)
    (span,) = spans(rng, 0.005, 0.0, 0.0, 0.0, scans=20, poses=POSES[:1])
    clean, count = _span_means(span)
    ranges = span.ranges.copy()
    ranges[7, 10] -= 1.0
    ranges[11, 200] += 0.5
    mean, n = _span_means(dataclasses.replace(span, ranges=ranges))
    assert n[10] == count[10] - 1 and n[200] == count[200] - 1
    others = np.ones(BEAMS, dtype=bool)
    others[[10, 200]] = False
    np.testing.assert_array_equal(mean[others], clean[others])
    keep = np.ones(20, dtype=bool)
    keep[7] = False
    assert mean[10] == pytest.approx(span.ranges[keep, 10].mean(), abs=1e-12)


def test_beams_that_a_box_off_its_mapped_place_cuts_short_are_not_dropouts():
    """One of 16 viewpoints stands beside a box that is 2.5 cm west and 4 cm north of its mapped place, with the lidar
    5 cm ahead of the axle: the map sends some of its beams past the box's corner, but they meet the box closer than
    the lidar's minimum range and read invalid. Masked with the map as drawn and from the axle, they counted as
    dropouts, 0.026 for 0.02; with the room as fitted, from the fitted mounting, they are left out."""
    rng = np.random.default_rng(7)
    room = MapGeometry.from_scenario(MOVED)
    data = spans(rng, 0.01, 0.02, 0.01, 0.03, mount_xy=(0.05, 0.0), per_m=0.004, room=room,
                 poses=[*MANY_POSES, (2.24, 3.04, 0.0)])  # fmt: skip
    fit = estimate_lidar(GEOMETRY, data, SETTINGS, rng)
    assert fit.dropout_prob.value == pytest.approx(0.02, abs=0.001)
    assert fit.dropout_prob.interval[0] <= 0.02 <= fit.dropout_prob.interval[1]


@pytest.mark.parametrize("clustered", [False, True])
def test_the_dropout_interval_covers_the_truth_95_percent_of_the_time(clustered):
    """1000 calibration drives' stationary spans (70, of 2 000-30 000 usable beams each) with dropouts at a known
    probability: independent per beam, or with each span's own probability drawn about it (a beta of 20 % spread,
    dropouts that cluster in some spans). The quasi-binomial interval covers the truth on 93-97 % of the drives."""
    rng = np.random.default_rng(5 + clustered)
    truth = 0.012
    hits = 0
    for _ in range(1000):
        trials = rng.integers(2_000, 30_000, 70)
        p = rng.beta(25.0, 25.0 / truth - 25.0, 70) if clustered else np.full(70, truth)
        drops = rng.binomial(trials, p)
        est = dropout_estimate(drops.astype(float), trials.astype(float))
        hits += est.interval[0] <= truth <= est.interval[1]
    assert 0.93 <= hits / 1000 <= 0.97, hits / 1000


def test_no_beam_meets_a_moved_box_at_a_graze():
    """A step that moves a box 15 cm shows a robot at its goal the box's other face at a graze, whose range then moves
    three metres per metre of the box: such beams would hold the wrong step in place (a box read 18 cm off on the
    loop's lab recording). A beam that meets another surface in the moved room than in the mapped one, at a graze, is
    left out."""
    from pipeline.calibration.lidar import _cast_span, _Design, _normal_equations

    design = _Design.of(GEOMETRY)
    rng = np.random.default_rng(5)
    data = spans(rng, 0.005, 0.0, 0.0, 0.0, scans=4, poses=[(4.45, 3.59, -0.15), (4.3, 3.4, -0.3)])
    data = [dataclasses.replace(s, others=np.full((4, 0, 2), np.nan)) for s in data]
    p = np.zeros(design.size)
    p[5 + 2 * 1 + 1] = -0.155  # box 1 moved 15.5 cm toward -y
    means = [(np.nan_to_num(s.ranges.mean(axis=0), posinf=np.nan), np.full(BEAMS, 4)) for s in data]
    sets = [np.isfinite(m) for m, _ in means]
    faces = [_cast_span(GEOMETRY, s, np.array([0.0]))[1][0] for s in data]
    limit = 1 / math.cos(SETTINGS.lidar_max_incidence_rad)
    _, j, *_ = _normal_equations(GEOMETRY, design, data, means, sets, p, faces, SETTINGS.lidar_max_incidence_rad)
    assert np.abs(j[:, 5:]).max() <= limit + 1e-6
    _, loose, *_ = _normal_equations(GEOMETRY, design, data, means, sets, p)  # the grazing beams are there
    assert np.abs(loose[:, 5 + 2 * 1 + 1]).max() > 2.5
