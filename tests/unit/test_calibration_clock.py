"""Clock offset and drift of robots against the host, from synthetic one-way stamps with known clocks."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.calibration.clock import MAX_QUICKEST_DELIVERY_S, ClockFit, estimate_clock
from pipeline.calibration.estimates import Estimate
from pipeline.calibration.network import StampStream
from pipeline.calibration.options import CalibrationSettings

NS = 1_000_000_000
EPOCH_NS = 1_700_000_000 * NS
"""Host time of the robots' clock reference, in Unix time like a real recording."""
SETTINGS = CalibrationSettings(bootstrap=200)


def topic(
    rng: np.random.Generator,
    name: str,
    rate_hz: float,
    seconds: float,
    clock: tuple[float, float],
    floor_s: float,
    jitter_s: float,
    kind: str = "exponential",
    loss: float = 0.05,
) -> StampStream:
    """One topic sampled at `rate_hz` from EPOCH_NS on, stamped by a robot clock (offset_s, drift_ppm) and
    received after `floor_s` plus exponential (scale) or uniform (width) `jitter_s`; messages lost at random."""
    offset_s, drift_ppm = clock
    n = int(seconds * rate_hz)
    t = np.arange(n) / rate_hz + rng.uniform(0.0, 0.2 / rate_hz, n)
    jitter = rng.exponential(jitter_s, n) if kind == "exponential" else rng.uniform(0.0, jitter_s, n)
    sample_ns = EPOCH_NS + np.round(t * NS).astype(np.int64)
    stamp_ns = sample_ns + np.round((offset_s + drift_ppm * 1e-6 * t) * NS).astype(np.int64)
    log_ns = sample_ns + np.round((floor_s + jitter) * NS).astype(np.int64)
    keep = rng.random(n) >= loss
    return StampStream(name, stamp_ns[keep], log_ns[keep])


def robot(
    rng: np.random.Generator, name: str, clock: tuple[float, float], seconds: float = 300.0, jitter_s: float = 0.005
) -> list[StampStream]:
    """Odometry at 40 Hz (2 ms floor) and scans at 8 Hz, stamped at the start of a sweep and sent at its end."""
    return [
        topic(rng, f"/{name}/odom", 40.0, seconds, clock, 0.002, jitter_s),
        topic(rng, f"/{name}/scan", 8.0, seconds, clock, 0.125 + 0.003, 2 * jitter_s, kind="uniform"),
    ]


def offset_at_t0(streams: list[StampStream], clock: tuple[float, float]) -> float:
    """The true offset (s) at the first message received, the estimate's time origin."""
    t0_ns = min(int(s.log_ns.min()) for s in streams)
    return clock[0] + clock[1] * 1e-6 * (t0_ns - EPOCH_NS) / NS


def covers(est: Estimate, truth: float) -> bool:
    assert est.ok and est.interval is not None
    return est.interval[0] <= truth <= est.interval[1]


def test_lab_clock_from_odometry_and_scans():
    rng = np.random.default_rng(0)
    clock = (0.035, 40.0)
    streams = {f"robot_{i}": robot(rng, f"robot_{i}", clock) for i in (1, 2, 3)}
    fit = estimate_clock(streams, SETTINGS)
    assert isinstance(fit, ClockFit)
    assert sorted(fit.per_robot) == ["robot_1", "robot_2", "robot_3"]
    for name, (offset, drift) in fit.per_robot.items():
        assert drift.unit == "ppm" and offset.unit == "s"
        assert drift.value == pytest.approx(40.0, rel=0.15)
        assert covers(drift, 40.0)
        truth = offset_at_t0(streams[name], clock)
        assert covers(offset, truth)
        # the value assumes the quickest delivery took no time: it lies below the truth by about that (2 ms)
        assert offset.value == pytest.approx(truth - 0.002, abs=0.0005)
        low, high = offset.interval
        assert high - low >= MAX_QUICKEST_DELIVERY_S  # the one-way ambiguity stays in the interval
        assert "/odom" in offset.method  # the quickest topic sets the bound, not the scans sent a sweep late
    assert fit.drift_ppm.value == pytest.approx(40.0, rel=0.15)
    assert covers(fit.drift_ppm, 40.0) and covers(fit.offset_s, 0.035)
    scan_notes = [n for n in fit.notes if "robot_1/scan's lowest delays lie" in n]
    assert len(scan_notes) == 1 and "0.12" in scan_notes[0]
    assert any("quickest message arrived within" in n for n in fit.notes)


def test_coverage_over_random_clocks_and_networks():
    rng = np.random.default_rng(1)
    trials = 150
    drift_hits = offset_hits = 0
    errors = []
    for i in range(trials):
        clock = (rng.uniform(-0.1, 0.1), rng.uniform(-100.0, 100.0))
        kinds = rng.choice(["exponential", "uniform"], 2)
        streams = [
            topic(rng, "/robot_1/odom", 40.0, 300.0, clock, rng.uniform(0, 0.008), rng.uniform(0, 0.02), kinds[0]),
            topic(rng, "/robot_1/scan", 8.0, 300.0, clock, rng.uniform(0, 0.008), rng.uniform(0, 0.02), kinds[1]),
        ]
        fit = estimate_clock({"robot_1": streams}, CalibrationSettings(bootstrap=200, seed=i))
        offset, drift = fit.per_robot["robot_1"]
        drift_hits += covers(drift, clock[1])
        offset_hits += covers(offset, offset_at_t0(streams, clock))
        errors.append(drift.value - clock[1])
    drift_coverage, offset_coverage = drift_hits / trials, offset_hits / trials
    print(
        f"95 % intervals over {trials} recordings: drift covers {drift_coverage:.3f}, offset covers "
        f"{offset_coverage:.3f}; drift error rms {np.sqrt(np.mean(np.square(errors))):.3f} ppm"
    )
    assert drift_coverage >= 0.9
    assert offset_coverage >= 0.9
    assert abs(float(np.mean(errors))) < 0.5  # no bias in ppm


@pytest.mark.parametrize("seed", range(4))
def test_zero_drift_intervals_hold_zero(seed):
    rng = np.random.default_rng(10 + seed)
    fit = estimate_clock({"robot_1": robot(rng, "robot_1", (-0.02, 0.0), jitter_s=0.01)}, SETTINGS)
    assert covers(fit.per_robot["robot_1"][1], 0.0)
    assert covers(fit.drift_ppm, 0.0)


def test_fleet_interval_spans_robots_that_differ():
    rng = np.random.default_rng(3)
    clocks = {"robot_1": (0.01, 20.0), "robot_2": (0.05, 60.0)}
    fit = estimate_clock({name: robot(rng, name, c) for name, c in clocks.items()}, SETTINGS)
    assert fit.drift_ppm.value == pytest.approx(40.0, abs=2.0)
    for offset, drift in fit.per_robot.values():  # the fleet's intervals hold every robot's
        assert fit.drift_ppm.interval[0] <= drift.interval[0] and drift.interval[1] <= fit.drift_ppm.interval[1]
        assert fit.offset_s.interval[0] <= offset.interval[0] and offset.interval[1] <= fit.offset_s.interval[1]
    assert fit.drift_ppm.interval[0] < 21.0 and fit.drift_ppm.interval[1] > 59.0
    assert fit.drift_ppm.std_error is not None and fit.drift_ppm.std_error > 20.0  # the robots' spread
    assert "mean over 2 robots" in fit.drift_ppm.method


def test_short_recording_has_no_drift_but_a_wider_offset():
    rng = np.random.default_rng(4)
    clock = (0.035, 40.0)
    streams = robot(rng, "robot_1", clock, seconds=15.0)
    fit = estimate_clock({"robot_1": streams}, SETTINGS)
    offset, drift = fit.per_robot["robot_1"]
    assert not drift.ok and drift.unit == "ppm" and "20 s" in drift.reason
    assert not fit.drift_ppm.ok
    assert covers(offset, offset_at_t0(streams, clock))
    assert any("+-200 ppm" in n for n in fit.notes)


def test_too_few_messages_is_unidentifiable():
    rng = np.random.default_rng(5)
    streams = [topic(rng, "/robot_1/odom", 1.0, 30.0, (0.035, 40.0), 0.002, 0.005)]
    fit = estimate_clock({"robot_1": streams}, SETTINGS)
    offset, drift = fit.per_robot["robot_1"]
    assert not offset.ok and not drift.ok
    assert offset.unit == "s" and "50 messages" in offset.reason
    assert not fit.offset_s.ok and not fit.drift_ppm.ok


def test_only_messages_inside_windows_count():
    rng = np.random.default_rng(6)
    clock = (0.035, 40.0)
    streams = robot(rng, "robot_1", clock)
    window = (EPOCH_NS + 10 * NS, EPOCH_NS + 290 * NS)
    # outside the window the robot's clock was still unset (stamps 5 s behind): these must not count
    bad = StampStream(
        "/robot_1/odom",
        np.arange(0, 5 * NS, NS // 40) + EPOCH_NS - 5 * NS,
        np.arange(0, 5 * NS, NS // 40) + EPOCH_NS + 295 * NS,
    )
    odom = StampStream(
        "/robot_1/odom",
        np.r_[streams[0].stamp_ns, bad.stamp_ns],
        np.r_[streams[0].log_ns, bad.log_ns],
        (window,),
    )
    scan = StampStream("/robot_1/scan", streams[1].stamp_ns, streams[1].log_ns, (window,))
    fit = estimate_clock({"robot_1": [odom, scan]}, SETTINGS)
    offset, drift = fit.per_robot["robot_1"]
    assert covers(drift, 40.0)
    inside = [StampStream(s.topic, s.stamp_ns[s.inside()], s.log_ns[s.inside()]) for s in (odom, scan)]
    assert covers(offset, offset_at_t0(inside, clock))


def test_corrupt_stamps_are_left_out():
    rng = np.random.default_rng(7)
    clock = (0.035, 40.0)
    odom, scan = robot(rng, "robot_1", clock)
    stamp_ns = odom.stamp_ns.copy()
    stamp_ns[[500, 4000, 9000]] += NS // 2  # three stamps half a second ahead: delays far below the envelope
    fit = estimate_clock({"robot_1": [StampStream(odom.topic, stamp_ns, odom.log_ns), scan]}, SETTINGS)
    offset, drift = fit.per_robot["robot_1"]
    assert covers(drift, 40.0)
    assert covers(offset, offset_at_t0([odom, scan], clock))
    assert any("3 far from the line left out" in n for n in fit.notes)


def test_a_topic_stamped_by_the_host_is_named():
    rng = np.random.default_rng(8)
    clock = (0.035, 40.0)
    streams = robot(rng, "robot_1", clock)
    truth = topic(rng, "/robot_1/ground_truth", 20.0, 300.0, (0.0, 0.0), 0.001, 0.003)  # host clock
    fit = estimate_clock({"robot_1": [*streams, truth]}, SETTINGS)
    assert any("/robot_1/ground_truth alone gives a drift of 0.0 ppm" in n for n in fit.notes)


def test_same_seed_same_fit():
    streams = {"robot_1": robot(np.random.default_rng(9), "robot_1", (0.035, 40.0))}
    assert estimate_clock(streams, SETTINGS) == estimate_clock(streams, SETTINGS)


CLOCK_PERIOD_S = 0.05
"""Period of the fleet's published /clock in the follower test."""


def slowdown(t_s: np.ndarray) -> np.ndarray:
    """Fraction by which a loaded fleet falls behind its nominal rate, growing over the recording (0 -> 20 %)."""
    return 0.2 * t_s / 300.0


def followed_copy(stream: StampStream) -> StampStream:
    """`stream` logged by a recorder following a published /clock: re-anchored on each /clock message (every
    `CLOCK_PERIOD_S` of fleet time) and extrapolated at the nominal rate between them, while the fleet runs
    slower by `slowdown`."""
    t = (stream.log_ns - EPOCH_NS) / NS
    since = np.mod(t, CLOCK_PERIOD_S)
    copy = t + since * slowdown(t) / (1 - slowdown(t))
    return StampStream(stream.topic, stream.stamp_ns, EPOCH_NS + np.round(copy * NS).astype(np.int64))


def published_clock(seconds: float = 300.0) -> StampStream:
    """The /clock messages (stamp: their value) logged at the copy's reading just before each re-anchors it."""
    value = np.arange(1, int(seconds / CLOCK_PERIOD_S)) * CLOCK_PERIOD_S
    log = value + CLOCK_PERIOD_S * slowdown(value) / (1 - slowdown(value)) + 0.0005
    to_ns = lambda x: EPOCH_NS + np.round(x * NS).astype(np.int64)  # noqa: E731
    return StampStream("/clock", to_ns(value), to_ns(log))


def test_a_followed_clocks_extrapolation_is_no_drift():
    """A time-scaled recording on a loaded host: the recorder's copy of /clock runs ahead of a fleet that falls
    behind its rate, by up to 10 ms just before each /clock message re-anchors it. The /clock messages, logged
    there, show an apparent drift that follows the load; the robot's envelope, read after re-anchoring, does
    only partly: the robot's drift keeps its measured value, and its interval spans none to all of the copy's."""
    rng = np.random.default_rng(3)
    clock = (0.0, 40.0)
    streams = {"robot_1": [followed_copy(s) for s in robot(rng, "robot_1", clock)]}
    fit = estimate_clock(streams, SETTINGS, {"robot_1": published_clock()})
    _, drift = fit.per_robot["robot_1"]
    alone = estimate_clock(streams, SETTINGS).per_robot["robot_1"][1]
    assert not covers(alone, 40.0)  # the copy bends the envelope a little
    assert covers(drift, 40.0) and drift.value == alone.value
    note = next(n for n in fit.notes if "copy of the published /clock" in n)
    apparent = float(note.split(" runs ")[1].split(" ppm")[0])
    assert apparent < -20.0  # the copy's error at its largest, far more than it bends the envelope
    assert drift.value - apparent == pytest.approx(drift.interval[1], abs=5.0)
