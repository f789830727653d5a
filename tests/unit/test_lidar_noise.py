"""The lidar's range step, noise and its growth with range, spread over beams, mixed pixels and the driver's
no-return convention: recovered from synthetic still scans with known truth, intervals inside their keys' domains
and covering the truth as often as they claim."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from pipeline.calibration.estimates import Estimate
from pipeline.calibration.lidar import ScanSpan, estimate_lidar
from pipeline.calibration.lidar_noise import NoiseBins, fit_noise, profile_intervals, range_step
from pipeline.calibration.network import rate_estimate, rate_wander_estimate
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.raycast import MapGeometry
from pipeline.core.scenario import load_scenario

SCENARIO = load_scenario("obstacles")
GEOMETRY = MapGeometry.from_scenario(SCENARIO)
SETTINGS = CalibrationSettings(bootstrap=60)


def quantize(r: np.ndarray, step: float) -> np.ndarray:
    return (np.round(r / step) * step).astype(np.float32).astype(np.float64) if step > 0 else r


def still_span(
    rng: np.random.Generator,
    pose: tuple[float, float, float],
    sigma: float,
    per_m: float,
    step: float = 0.0,
    scans: int = 77,
    beams: int = 720,
    no_return: float = math.inf,
    no_return_share: float = 0.0,
    mixed: float = 0.0,
    label: str = "span",
    factor: np.ndarray | None = None,
) -> ScanSpan:
    """A robot standing still at `pose` in the obstacle room: `scans` scans of `beams` beams, noise sigma + per_m x
    range, ranges in `step` steps; `no_return_share` of the beams (a fixed set: dark or far surfaces) never return
    and read `no_return`; at depth edges a return between the two surfaces with probability `mixed`."""
    angles = 2 * math.pi * np.arange(beams) / beams
    hits = GEOMETRY.cast(np.array(pose[:2]), pose[2] + angles)
    true = hits.range_m
    scale = (sigma + per_m * true) * (1.0 if factor is None else factor)
    r = true[None, :] + rng.standard_normal((scans, beams)) * scale[None, :]
    if mixed > 0:
        before = np.roll(true, 1)
        both = np.isfinite(true) & np.isfinite(before)
        edge = both & (np.abs(np.where(both, true - before, 0.0)) > 0.1) & (hits.surface != np.roll(hits.surface, 1))
        hit = edge[None, :] & (rng.random((scans, beams)) < mixed)
        near, far = np.minimum(true, before), np.maximum(true, before)
        between = near[None, :] + rng.random((scans, beams)) * (far - near)[None, :]
        r = np.where(hit, between, r)
    r = quantize(r, step)
    dark = rng.random(beams) < no_return_share
    r[:, dark] = no_return
    return ScanSpan("robot_1", label, 0, scans * 130_000_000, np.array(pose), angles, r, 0.12, 8.0,
                    np.full((scans, 0, 2), np.nan))  # fmt: skip


# -- the range step ---------------------------------------------------------------------------------


@pytest.mark.parametrize(("step", "sigma"), [(0.002, 0.003), (0.001, 0.01), (0.00025, 0.02), (0.002, 0.0008)])
def test_the_range_step_is_found_from_the_changes_of_each_beam(step, sigma):
    rng = np.random.default_rng(1)
    r = quantize(2.0 + rng.standard_normal((60, 300)) * sigma, step)
    est = range_step(np.diff(r, axis=0).ravel())
    assert est.ok and est.interval[0] <= step <= est.interval[1], est
    assert 0 < est.interval[1] - est.interval[0] < 0.01 * step


def test_continuous_ranges_have_no_step_and_standing_ranges_say_so():
    rng = np.random.default_rng(2)
    r = (2.0 + rng.standard_normal((60, 300)) * 0.005).astype(np.float32).astype(np.float64)
    est = range_step(np.diff(r, axis=0).ravel())
    assert est.ok and est.value == 0.0 and est.interval[1] > 0 and "continuous" in est.method
    frozen = range_step(np.zeros(1000))
    assert not frozen.ok and "stand still" in frozen.reason


# -- noise against range: bounded fit, profile likelihood, coverage ---------------------------------


def bins_of(rng: np.random.Generator, a: float, b: float, step: float, ranges_m: np.ndarray, n: int) -> NoiseBins:
    """Range bins of `n` deviations each at `ranges_m`: noise a + b r, rounded to `step` (one beam's mean taken out
    as the calibration does)."""
    count, var = [], []
    for r in ranges_m:
        x = quantize(r + rng.standard_normal(n) * (a + b * r), step)
        count.append(n)
        var.append(float(np.var(x, ddof=1)))
    return NoiseBins(np.array(count, dtype=float), np.array(var), np.asarray(ranges_m, dtype=float))


@pytest.mark.parametrize(("a", "b"), [(0.0015, 0.0005), (0.0002, 0.003), (0.004, 0.0)])
def test_profile_intervals_stay_in_the_domain_and_cover_the_truth(a, b):
    """200 still spans of a lidar like a TurtleBot 4's (2 mm steps, noise of a few millimetres, ranges 0.5-3.5 m):
    the intervals of intercept, slope and the noise at the median range never leave [0, inf), are never of zero
    width, and hold the truth in at least 90 % of the spans (their nominal 95 %, less sampling)."""
    rng = np.random.default_rng(3)
    ranges = np.linspace(0.5, 3.5, 7)
    step = 0.002
    hits = np.zeros(3)
    for _ in range(200):
        bins = bins_of(rng, a, b, step, ranges, 400)
        fit = fit_noise(bins, step, slope=True)
        at = bins.median_range()
        ia, ib, ic = profile_intervals(bins, fit, step, 1.0, at)
        for k, ((lo, hi), truth) in enumerate(((ia, a), (ib, b), (ic, a + b * at))):
            assert 0.0 <= lo < hi, (k, lo, hi)
            hits[k] += lo <= truth <= hi
    assert (hits / 200 >= 0.9).all(), hits / 200


def test_a_turtlebot_like_still_span_reports_what_the_data_determine():
    """One 10 s still span (77 scans of 720 beams, a quarter without a return, reading inf), ranges in 2 mm steps,
    noise 1.5 mm + 0.5 mm/m: the step is found and taken out; both noise keys have intervals inside [0, inf) that
    hold the truth; intercept and slope are said to trade off, with the noise at the median range seen, which is
    pinned far better than either."""
    rng = np.random.default_rng(4)
    span = still_span(rng, (1.0, 1.0, 0.3), 0.0015, 0.0005, step=0.002, no_return_share=0.25)
    fit = estimate_lidar(GEOMETRY, [span], SETTINGS, rng)
    assert fit.range_step_m.interval[0] <= 0.002 <= fit.range_step_m.interval[1]
    for est, truth in ((fit.noise_sigma_m, 0.0015), (fit.noise_per_m, 0.0005)):
        assert est.ok and 0.0 <= est.interval[0] <= truth <= est.interval[1], est
        assert "profile-likelihood" in est.method
    at_m, at = fit.noise_at_range
    assert at.interval[0] <= 0.0015 + 0.0005 * at_m <= at.interval[1]
    sigma = fit.noise_sigma_m
    assert (at.interval[1] - at.interval[0]) / at.value < (sigma.interval[1] - sigma.interval[0]) / sigma.value
    assert fit.noise_correlation < -0.5
    assert any("trade off" in n for n in fit.notes) and any("steps of 2 mm" in n for n in fit.notes)
    assert fit.no_return == "inf"


def test_noise_below_the_range_step_is_bounded_not_measured():
    rng = np.random.default_rng(5)
    span = still_span(rng, (1.0, 1.0, 0.3), 0.0003, 0.0, step=0.002)
    fit = estimate_lidar(GEOMETRY, [span], SETTINGS, rng)
    est = fit.noise_sigma_m
    assert est.ok and est.interval[0] == 0.0 < est.interval[1] and est.interval[1] < 0.002
    assert any("below the range step" in n for n in fit.notes)


@pytest.mark.parametrize(("convention", "reads"), [("zero", 0.0), ("max", 8.0), ("nan", math.nan), ("inf", math.inf)])
def test_the_driver_s_no_return_convention_is_found_and_read_as_no_return(convention, reads):
    rng = np.random.default_rng(6)
    data = [still_span(rng, pose, 0.005, 0.0, no_return=reads, no_return_share=0.1, scans=20, label=f"s{k}")
            for k, pose in enumerate([(1.0, 1.0, 0.3), (4.0, 2.0, 3.0), (1.0, 3.0, -1.0)])]  # fmt: skip
    fit = estimate_lidar(GEOMETRY, data, SETTINGS, rng)
    assert fit.no_return == convention
    assert fit.noise_sigma_m.interval[0] <= 0.005 <= fit.noise_sigma_m.interval[1]  # no-returns are not ranges
    assert fit.bias_m.interval[0] <= 0.0 <= fit.bias_m.interval[1]


def test_mixed_pixels_at_depth_edges_are_rated_and_kept_out_of_the_noise():
    rng = np.random.default_rng(7)
    poses = [(1.0, 1.0, 0.3), (4.0, 2.0, 3.0), (1.0, 3.0, -1.0), (3.0, 1.2, 1.0), (5.0, 3.0, 2.0), (1.6, 2.2, 0.8)]
    data = [still_span(rng, pose, 0.004, 0.001, mixed=0.4, scans=30, label=f"s{k}") for k, pose in enumerate(poses)]
    fit = estimate_lidar(GEOMETRY, data, SETTINGS, rng)
    assert fit.mixed_pixel_prob.ok and fit.mixed_pixel_prob.interval[0] <= 0.4 <= fit.mixed_pixel_prob.interval[1]
    assert fit.noise_sigma_m.interval[0] <= 0.004 <= fit.noise_sigma_m.interval[1]
    clean = estimate_lidar(GEOMETRY, [still_span(rng, p, 0.004, 0.001, scans=30, label=f"c{k}")
                                      for k, p in enumerate(poses)], SETTINGS, rng)  # fmt: skip
    assert clean.mixed_pixel_prob.value < 0.05


def edge_beams(pose: tuple[float, float, float], beams: int = 720) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(beam indices, near, far) of the beams at the room's depth edges from `pose`, as `still_span` finds them."""
    angles = 2 * math.pi * np.arange(beams) / beams
    hits = GEOMETRY.cast(np.array(pose[:2]), pose[2] + angles)
    true, before = hits.range_m, np.roll(hits.range_m, 1)
    both = np.isfinite(true) & np.isfinite(before)
    edge = both & (np.abs(np.where(both, true - before, 0.0)) > 0.1) & (hits.surface != np.roll(hits.surface, 1))
    return np.flatnonzero(edge), np.minimum(true, before)[edge], np.maximum(true, before)[edge]


EDGE_POSES = [(1.0, 1.0, 0.3), (4.0, 2.0, 3.0), (1.0, 3.0, -1.0), (3.0, 1.2, 1.0), (5.0, 3.0, 2.0), (1.6, 2.2, 0.8)]


def edge_spans(
    rng: np.random.Generator, alter: Callable[[ScanSpan, np.ndarray, np.ndarray, np.ndarray], None]
) -> list[ScanSpan]:
    """Still spans of 30 scans at `EDGE_POSES` of a lidar without mixed pixels, each passed to `alter` with its edge
    beams and their near and far surfaces (to change those beams' returns in place)."""
    data = []
    for k, pose in enumerate(EDGE_POSES):
        span = still_span(rng, pose, 0.004, 0.001, scans=30, label=f"s{k}")
        alter(span, *edge_beams(pose))
        data.append(span)
    return data


def test_an_edge_beam_that_steadily_sees_something_the_map_lacks_is_no_mixed_pixel():
    """A lidar without mixed pixels whose edge beams see, in every scan, a surface between the two the map has there
    (another robot standing in front of a box corner, an object the map lacks): no mixed pixels are read from them
    (the interval holds 0), and the notes say why those beams were left out."""
    rng = np.random.default_rng(9)

    def steady(span: ScanSpan, cols: np.ndarray, near: np.ndarray, far: np.ndarray) -> None:
        # every other edge beam: a surface 40 % of the way into the gap, the same in every scan (the rest stay clean
        # edge beams, which tell the mixed pixels' probability)
        cols, near, far = cols[::2], near[::2], far[::2]
        surface = near + 0.4 * (far - near)
        span.ranges[:, cols] = surface[None, :] + 0.005 * rng.standard_normal((30, len(cols)))

    fit = estimate_lidar(GEOMETRY, edge_spans(rng, steady), SETTINGS, rng)
    assert fit.mixed_pixel_prob.interval is not None and fit.mixed_pixel_prob.interval[0] == 0.0
    assert fit.mixed_pixel_prob.value < 0.01
    assert any("returned mostly from neither of the map's surfaces" in n for n in fit.notes)


def test_an_edge_beam_that_now_and_then_sees_past_its_edge_is_no_mixed_pixel():
    """A lidar without mixed pixels on a robot that sways by a millimetre while still: an edge beam returns, in one
    scan of ten, from the other of the two surfaces the map has there (the edge crossed it), never from between
    them. Those returns are no mixed pixels: the interval holds 0 (counted as mixed, they read about 0.1)."""
    rng = np.random.default_rng(12)

    def crossed(span: ScanSpan, cols: np.ndarray, near: np.ndarray, far: np.ndarray) -> None:
        own = np.median(span.ranges[:, cols], axis=0)
        other = np.where(np.abs(own - near) < np.abs(own - far), far, near)
        past = rng.random((30, len(cols))) < 0.1
        seen = other[None, :] + (0.004 + 0.001 * other[None, :]) * rng.standard_normal((30, len(cols)))
        span.ranges[:, cols] = np.where(past, seen, span.ranges[:, cols])

    fit = estimate_lidar(GEOMETRY, edge_spans(rng, crossed), SETTINGS, rng)
    assert fit.mixed_pixel_prob.interval is not None and fit.mixed_pixel_prob.interval[0] == 0.0, fit.mixed_pixel_prob
    assert fit.mixed_pixel_prob.value < 0.01


def test_the_noise_s_own_tail_at_depth_edges_is_no_mixed_pixel():
    """A lidar without mixed pixels and 5 cm of noise, 200 000 still returns at depth edges 1 m deep: a few land
    beyond the 4-sigma margin toward the gap (the normal tail, about one in 50 000). They are what the noise gives,
    taken out of the count: the interval holds 0 (counted as mixed pixels, they excluded it)."""
    from pipeline.calibration.lidar import NoiseFit, _mixed_pixels

    rng = np.random.default_rng(4)
    beams, scans = 400, 500
    centre = np.repeat(rng.uniform(1.0, 3.0, beams), scans)
    near, far = centre, centre + 1.0
    r = centre + 0.05 * rng.standard_normal(centre.size)
    beam = np.repeat(np.arange(beams), scans)
    noise = NoiseFit(
        Estimate.of(0.05, 0.0005, (0.049, 0.051), "m", "test", 100_000),
        Estimate.of(0.0, 0.0001, (0.0, 0.0002), "m/m", "test", 100_000),
        beam_spread=Estimate.of(0.0, 0.001, (0.0, 0.002), "log-sd", "test", 400),
    )
    mixed = _mixed_pixels([(r, centre, near, far, beam)], noise)
    found = int(mixed.method.split(" found")[0].rsplit(" ", 1)[1])
    assert found >= 1, "no tail return: the test shows nothing"
    assert mixed.interval is not None and mixed.interval[0] == 0.0, mixed
    assert mixed.value < 1e-4


def test_a_return_far_off_its_beam_in_one_scan_does_not_inflate_the_beam_s_noise():
    """Beams of one noise (spread 0) in which, now and then (1 % of the returns), one scan returns half a metre off
    (something passing through the beam): the beam's mean is taken without it, so the noise and its spread over
    beams read what the same scans read without those returns."""
    for seed in range(200, 206):
        fits = []
        for share in (0.0, 0.01):
            rng = np.random.default_rng(seed)
            span = still_span(rng, (1.0, 1.0, 0.3), 0.004, 0.001, scans=40)
            span.ranges[rng.random(span.ranges.shape) < share] += 0.5
            fits.append(estimate_lidar(GEOMETRY, [span], SETTINGS, rng))
        clean, passed = fits
        assert passed.beam_noise_spread.value == pytest.approx(clean.beam_noise_spread.value, abs=0.01), seed
        assert passed.noise_at_range[1].value == pytest.approx(clean.noise_at_range[1].value, rel=0.01), seed


# -- weakly determined, the sweep's wander ----------------------------------------------------------


def test_an_interval_wider_than_its_value_is_weak_not_ok():
    wide = Estimate.of(0.0004, 0.001, (0.0, 0.0026), "m", "test", 100)
    assert wide.flagged(0.0).status == "weak" and wide.flagged(0.0).ok
    assert "wider than its value" in wide.flagged(0.0).as_mapping()["reason"]
    narrow = Estimate.of(0.002, 0.0001, (0.0018, 0.0022), "m", "test", 100)
    assert narrow.flagged(0.0).status == "ok"
    signed = Estimate.of(0.001, 0.01, (-0.02, 0.02), "m", "test", 100)
    assert signed.flagged(-math.inf).status == "ok"  # a signed key near zero is not weak


def test_a_key_determined_to_be_as_good_as_none_is_not_weak():
    """A sweep that does not wander, continuous ranges: 0 with an interval within what counts as none is determined."""
    from pipeline.calibration.keys import NEGLIGIBLE, _flag_weak

    still = Estimate.of(0.0, 0.0, (0.0, 0.0001), "relative", "test", 27421)
    assert _flag_weak("lidar.rate_wander", still).status == "ok"
    assert _flag_weak("lidar.range_step_m", Estimate.of(0.0, 0.0, (0.0, 1e-5), "m", "test", 9)).status == "ok"
    unsure = Estimate.of(0.0004, 0.001, (0.0, 2 * NEGLIGIBLE["lidar.rate_wander"]), "relative", "test", 50)
    assert _flag_weak("lidar.rate_wander", unsure).status == "weak"  # beyond what counts as none: weak again


@pytest.mark.parametrize("wander", [0.0, 0.005, 0.02])
def test_the_sweep_period_s_wander_is_measured_from_the_stamps(wander):
    rng = np.random.default_rng(8)
    streams = []
    for _ in range(3):
        periods = 1e8 * (1 + wander * rng.standard_normal(600))
        stamps = np.cumsum(np.round(periods)).astype(np.int64)
        keep = rng.random(len(stamps)) > 0.02  # a few scans lost
        streams.append(stamps[keep])
    est = rate_wander_estimate(streams)
    lo, hi = est.interval
    assert 0.0 <= lo <= wander <= hi and hi > lo, est


def test_the_rate_s_interval_holds_a_wandering_sweep():
    """A sweep period that wanders 2 % from one sweep to the next makes the stamps a random walk: over 100 recordings
    of three robots' 300 scans the rate's interval holds the true 7.7 Hz in at least 90 % (a line fitted to the
    stamps alone claimed a tenth of the spread)."""
    rng = np.random.default_rng(9)
    hits = 0
    for _ in range(100):
        streams = [np.cumsum(np.round(1e9 / 7.7 * (1 + 0.02 * rng.standard_normal(300)))).astype(np.int64)
                   for _ in range(3)]  # fmt: skip
        lo, hi = rate_estimate(streams).interval
        hits += lo <= 7.7 <= hi
    assert hits >= 90, hits


def test_ranges_that_never_change_leave_the_noise_unmeasured_with_the_reason():
    rng = np.random.default_rng(10)
    span = still_span(rng, (1.0, 1.0, 0.3), 0.0, 0.0, scans=30)
    fit = estimate_lidar(GEOMETRY, [span], SETTINGS, rng)
    for est in (fit.noise_sigma_m, fit.noise_per_m):
        assert not est.ok and "every beam read the same range" in est.reason
    assert not fit.range_step_m.ok and "stand still" in fit.range_step_m.reason


@pytest.mark.parametrize("spread", [0.0, 0.1, 0.25])
def test_the_beams_own_noise_spread_is_recovered_through_the_range_steps(spread):
    """Each beam's noise scaled by exp(s z - s^2), ranges in 2 mm steps, noise 2-4 mm: over 8 still spans of 720
    beams the spread's interval holds s in at least 7."""
    held = 0
    for seed in range(8):
        rng = np.random.default_rng(100 + seed)
        factor = np.exp(spread * rng.standard_normal(720) - spread**2)
        span = still_span(rng, (1.0, 1.0, 0.3), 0.002, 0.0005, step=0.002, factor=factor)
        est = estimate_lidar(GEOMETRY, [span], SETTINGS, rng).beam_noise_spread
        assert est.ok and 0.0 <= est.interval[0] <= est.interval[1]
        held += est.interval[0] <= spread <= est.interval[1]
    assert held >= 7, held


# -- a bag with nothing but scans ----------------------------------------------------------------------------------


def test_a_scan_only_recording_finds_its_still_spans_and_reads_the_noise_there():
    """A sensor still for 5 s, carried for 10 s (every range changing by centimetres), still for 5 s again: the two
    still spans are found from the scans alone, and the step, the noise at the median range and the no-return
    convention come back; a recording that never stands still says so."""
    from pipeline.calibration.scan_only import lidar_from_scans

    rng = np.random.default_rng(11)
    beams, period = 540, 100_000_000
    base = 2.5 + 1.5 * np.sin(np.linspace(0.0, 6.0, beams))  # a room: smooth surfaces
    rows = []
    for t in range(200):
        moving = 50 <= t < 150
        offset = 0.05 * np.sin(t / 3.0) + 0.03 * t / 10 if moving else (0.3 if t >= 150 else 0.0)
        true = base + offset + (0.02 * rng.standard_normal(beams) if moving else 0.0)
        r = quantize(true + rng.standard_normal(beams) * (0.002 + 0.001 * true), 0.001)
        r[::7] = 0.0  # no return reads 0
        rows.append(r)
    stamps = np.arange(200, dtype=np.int64) * period + 10**18
    fit = lidar_from_scans(np.array(rows), stamps, -2.0, 4.0 / beams, 0.05, 10.0, CalibrationSettings(bootstrap=60))
    assert len(fit.still_spans) == 2 and fit.no_return == "zero"
    assert fit.range_step_m.interval[0] <= 0.001 <= fit.range_step_m.interval[1]
    at_m, at = fit.noise.at_range
    assert at.interval[0] <= 0.002 + 0.001 * at_m <= at.interval[1], (at_m, at)
    moving = np.array(rows) + 0.05 * np.arange(200)[:, None]
    never = lidar_from_scans(moving, stamps, -2.0, 4.0 / beams, 0.05, 20.0)
    assert not never.noise.sigma.ok and "never stood still" in never.noise.sigma.reason
