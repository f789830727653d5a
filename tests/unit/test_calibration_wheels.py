"""True wheel radii and separation from odometry vs truth: kinematic data, the twin's MuJoCo base, coverage."""

from __future__ import annotations

import math

import numpy as np

from pipeline.calibration.odometry import OdometryEpisode
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.wheels import (
    NOMINAL_WHEEL_RADIUS_M,
    NOMINAL_WHEEL_SEPARATION_M,
    WheelFit,
    between_condition_variance,
    estimate_wheels,
    wheel_chunks,
)
from pipeline.core.scenario import load_scenario
from pipeline.twin import profile
from pipeline.twin.physics import BaseParams, FleetPhysics
from pipeline.twin.profile import OdometryProfile
from pipeline.twin.sensors import EncoderOdometry

NS = 1_000_000_000
SETTINGS = CalibrationSettings()
TRUE = {"radius_left_m": 0.0335, "radius_right_m": 0.0342, "separation_m": 0.287}
"""The lab robots' real wheels; their drivers integrate with the nominal 0.034 m and 0.281 m."""
KEYS = tuple(TRUE)
STEP_SPEEDS = (0.02, 0.03, 0.05, 0.1, 0.5)
"""Forward speeds (m/s) of a calibration drive: slow driving and a few fast steps."""
MOCAP_SIGMA_M = 0.001
MOCAP_SIGMA_RAD = 0.002
"""Noise of the twin's ground truth as the calibration sees it (a motion-capture system, smoothed)."""


def commands(
    rng: np.random.Generator, seconds: float, dt: float, speeds: tuple[float, ...] = ()
) -> tuple[np.ndarray, np.ndarray]:
    """(n,) forward speed (m/s) and yaw rate (rad/s), held 0.5-2 s: straight runs, arcs and turns on the spot; at
    0.1-0.3 m/s, or at one of `speeds` (steps of several sizes)."""
    n = round(seconds / dt)
    v, w = np.zeros(n), np.zeros(n)
    k = 0
    while k < n:
        hold = round(rng.uniform(0.5, 2.0) / dt)
        kind = rng.integers(3)
        speed = (rng.choice(speeds) if speeds else rng.uniform(0.1, 0.3)) * rng.choice([-1.0, 1.0])
        rate = rng.uniform(0.3, 1.5) * rng.choice([-1.0, 1.0])
        v[k : k + hold] = 0.0 if kind == 2 else speed
        w[k : k + hold] = 0.0 if kind == 0 else rate
        k += hold
    return v, w


def integrate(start: np.ndarray, ds: np.ndarray, dth: np.ndarray) -> np.ndarray:
    """(n + 1, 3) poses from steps of ds (m) along the mean heading and turns dth (rad), as the driver integrates."""
    yaw = start[2] + np.r_[0.0, np.cumsum(dth)]
    mid = yaw[:-1] + dth / 2
    x = start[0] + np.r_[0.0, np.cumsum(ds * np.cos(mid))]
    y = start[1] + np.r_[0.0, np.cumsum(ds * np.sin(mid))]
    return np.stack([x, y, np.angle(np.exp(1j * yaw))], axis=1)


def kinematic_episode(
    seed: int,
    slip: float = 0.0,
    seconds: float = 30.0,
    dt: float = 0.04,
    turning: bool = True,
    nominal: tuple[float, float] = (NOMINAL_WHEEL_RADIUS_M, NOMINAL_WHEEL_SEPARATION_M),
    stuck: slice | None = None,
    rolling: float = 0.0,
    drift: float = 0.0,
    speeds: tuple[float, ...] = (),
) -> OdometryEpisode:
    """A robot with the TRUE geometry driven by random commands; its odometry integrated with the `nominal` one.

    The wheels turn as the driver commands through the nominal (radius, separation); each step the
    base moves as its true wheels carry it, plus slip: each wheel loses or gains a share of its
    travel drawn once per episode (its floor and load, spread slip / 20) and noise of `slip` times
    its travel (and 1 mm per square-root second) every step. During the steps `stuck` the wheels
    turn and the base stays put (it pushes a wall). With `rolling`, a wheel's rolling radius changes with
    its speed (a tyre that deforms): TRUE at 0.2 m/s, `rolling` times more at rest, that much less at 0.4 m/s.
    With `drift`, the odometry errs as the twin's does: per episode a distance scale error, a yaw-rate scale error
    and a heading drift per metre, each drawn from N(0, drift).
    """
    rng = np.random.default_rng(seed)
    v, w = commands(rng, seconds, dt, speeds)
    if not turning:
        w[:] = 0.0
    r, b = nominal
    dphi = np.stack([(v - w * b / 2) / r, (v + w * b / 2) / r], axis=1) * dt  # wheel angles (rad) per step
    roll = 1.0 + rolling * (0.2 - np.abs(dphi) / dt * r) / 0.2
    dl, dr = dphi[:, 0] * TRUE["radius_left_m"] * roll[:, 0], dphi[:, 1] * TRUE["radius_right_m"] * roll[:, 1]
    if slip > 0:
        dl, dr = dl * (1 + rng.normal(0.0, slip / 20)), dr * (1 + rng.normal(0.0, slip / 20))
        dl = dl + rng.normal(0.0, 1.0, len(dl)) * (slip * np.abs(dl) + 1e-3 * math.sqrt(dt))
        dr = dr + rng.normal(0.0, 1.0, len(dr)) * (slip * np.abs(dr) + 1e-3 * math.sqrt(dt))
    if stuck is not None:
        dl[stuck] = dr[stuck] = 0.0
    start = np.array([rng.uniform(0, 5), rng.uniform(0, 3), rng.uniform(-3, 3)])
    truth = integrate(start, (dl + dr) / 2, (dr - dl) / TRUE["separation_m"])
    scale, yaw_scale, heading = rng.normal(0.0, drift, 3) if drift > 0 else np.zeros(3)
    ds_o = r * dphi.sum(axis=1) / 2 * (1 + scale)
    odom = integrate(np.zeros(3), ds_o, r * (dphi[:, 1] - dphi[:, 0]) / b * (1 + yaw_scale) + heading * np.abs(ds_o))
    t_ns = (np.arange(len(truth)) * dt * NS).astype(np.int64)
    return OdometryEpisode(f"robot_{seed % 3 + 1}", f"episode {seed}", t_ns, odom, truth)


def relative_errors(fit: WheelFit) -> dict[str, float]:
    """Estimate / truth - 1 of each key; every key must be identified."""
    out = {}
    for key in KEYS:
        est = getattr(fit, key)
        assert est.ok, est.reason
        assert est.unit == "m" and est.interval is not None
        out[key] = est.value / TRUE[key] - 1.0
    return out


def covers(fit: WheelFit) -> dict[str, bool]:
    """Whether each key's 95 % interval holds the truth."""
    return {key: getattr(fit, key).interval[0] <= TRUE[key] <= getattr(fit, key).interval[1] for key in KEYS}


# -- kinematic data -------------------------------------------------------------------------------


def test_the_nominal_defaults_are_the_twins_nominal_geometry():
    assert NOMINAL_WHEEL_RADIUS_M == profile.NOMINAL_WHEEL_RADIUS_M
    assert NOMINAL_WHEEL_SEPARATION_M == profile.NOMINAL_WHEEL_SEPARATION_M


def test_noise_free_data_give_the_true_geometry():
    episodes = [kinematic_episode(seed) for seed in range(4)]
    fit = estimate_wheels(episodes, SETTINGS)
    errors = relative_errors(fit)
    assert all(abs(e) < 0.005 for e in errors.values()), errors
    assert all(abs(e) < 1e-4 for e in errors.values()), errors  # the chunk model is exact to far better than that
    assert "4 robot-episodes" in fit.separation_m.method and "t interval (3 dof)" in fit.separation_m.method
    assert estimate_wheels(episodes, SETTINGS) == fit  # the same seed gives the same bootstrap


def test_other_nominal_values_are_honoured():
    episodes = [kinematic_episode(seed, nominal=(0.036, 0.27)) for seed in range(3)]
    errors = relative_errors(estimate_wheels(episodes, SETTINGS, nominal_radius_m=0.036, nominal_separation_m=0.27))
    assert all(abs(e) < 1e-3 for e in errors.values()), errors


def test_no_chunk_spans_a_gap_in_the_truth_or_a_restart_of_the_odometry():
    episodes = []
    for seed in range(3):
        e = kinematic_episode(seed)
        half = len(e.t_ns) // 2
        truth, odom = e.truth.copy(), e.odom.copy()
        truth[half:, :2] += [0.7, -0.3]  # the robot reappears elsewhere after a gap in the truth...
        piece = (np.arange(len(truth)) >= half).astype(np.int64)
        # ...and later its driver restarted: the odometry goes on from the origin, in a frame turned by its heading
        later = 3 * len(e.t_ns) // 4
        x0, y0, yaw0 = odom[later]
        c, s = math.cos(yaw0), math.sin(yaw0)
        dx, dy = odom[later:, 0] - x0, odom[later:, 1] - y0
        odom[later:] = np.stack([c * dx + s * dy, -s * dx + c * dy, np.angle(np.exp(1j * (odom[later:, 2] - yaw0)))], 1)
        episodes.append(OdometryEpisode(e.robot, e.label, e.t_ns, odom, truth, piece))
    for episode in episodes:  # every chunk moves as the true wheels say: none holds the jump
        chunks = wheel_chunks(episode)
        k = np.array([TRUE["radius_left_m"], TRUE["radius_right_m"]]) / NOMINAL_WHEEL_RADIUS_M
        assert np.abs(chunks.distance_m - chunks.travel @ k / 2).max() < 1e-4
        assert np.abs(chunks.turn_rad - chunks.travel @ (k * [-1, 1]) / TRUE["separation_m"]).max() < 1e-4
    fit = estimate_wheels(episodes, SETTINGS)
    errors = relative_errors(fit)
    assert all(abs(e) < 1e-4 for e in errors.values()), errors
    assert any(note.endswith("; 0 chunks left out as slip") for note in fit.notes)


def test_a_robot_pushing_a_wall_with_spinning_wheels_is_left_out():
    episodes = [kinematic_episode(seed, stuck=slice(200, 240)) for seed in range(4)]  # 1.6 s stuck each
    fit = estimate_wheels(episodes, SETTINGS)
    errors = relative_errors(fit)
    assert all(abs(e) < 1e-4 for e in errors.values()), errors
    left_out = [note for note in fit.notes if note.endswith("chunks left out as slip")]
    assert left_out and not left_out[0].endswith("; 0 chunks left out as slip")


def test_the_95_percent_intervals_cover_the_truth_in_at_least_90_of_100_noisy_fleets():
    """Slip noise on every step and per episode: each key's interval holds the truth in >= 90 % of fleets."""
    hits = {key: 0 for key in KEYS}
    widths = []
    for fleet in range(100):
        episodes = [kinematic_episode(1000 * fleet + k, slip=0.05, seconds=20.0) for k in range(6)]
        fit = estimate_wheels(episodes, SETTINGS)
        for key, hit in covers(fit).items():
            hits[key] += hit
        widths.append([(getattr(fit, k).interval[1] - getattr(fit, k).interval[0]) / TRUE[k] for k in KEYS])
    assert all(n >= 90 for n in hits.values()), hits
    # and they say something: about 1 % wide, not the whole range of wheels
    assert np.median(widths, axis=0).max() < 0.02


def test_episodes_whose_odometry_reads_long_or_short_are_not_slip_and_their_spread_sets_the_intervals():
    """The twin's odometry errs per episode by a few per cent (scale, yaw scale, heading drift per metre drawn from
    N(0, 3 %)), and a calibration drive holds steps of several sizes between slow driving. Every chunk of such an
    episode is off by its scale, most in its fast steps: cutting those as slip against the spread of the slow chunks
    weighs the episodes whose errors are small and leaves their spread out of the intervals (83-85 % coverage here,
    60-65 % on the twin). Bursts are told within their episode, so the intervals cover."""
    hits = {key: 0 for key in KEYS}
    cut = []
    for fleet in range(100):
        episodes = [
            kinematic_episode(1000 * fleet + k, slip=0.002, seconds=20.0, drift=0.03, speeds=STEP_SPEEDS)
            for k in range(10)
        ]
        fit = estimate_wheels(episodes, SETTINGS)
        for key, hit in covers(fit).items():
            hits[key] += hit
        cut.append(
            next(n for n in fit.notes if n.endswith("chunks left out as slip")).endswith("; 0 chunks left out as slip")
        )
    assert all(n >= 90 for n in hits.values()), hits
    assert np.mean(cut) >= 0.5  # no burst in these data: most fleets keep every chunk


def test_estimates_that_change_with_how_the_robot_drove_widen_the_intervals_to_cover_the_truth():
    """A rolling radius that changes by 1.5 % over the speed range (no single geometry explains it): slow and fast
    chunks disagree, and that disagreement, not the number of chunks, sets the intervals, which still cover."""
    hits = {key: 0 for key in KEYS}
    first: WheelFit | None = None
    for fleet in range(100):
        episodes = [kinematic_episode(1000 * fleet + k, slip=0.05, seconds=20.0, rolling=0.015) for k in range(6)]
        fit = estimate_wheels(episodes, SETTINGS)
        first = first or fit
        for key, hit in covers(fit).items():
            hits[key] += hit
    assert all(n >= 90 for n in hits.values()), hits
    assert first is not None
    note = next(n for n in first.notes if n.startswith("between conditions"))
    assert float(note.split("left ")[1].split(" mm")[0]) > 0.05, note


def test_the_between_condition_variance_recovers_a_known_spread_and_reads_none_where_there_is_none():
    """DerSimonian-Laird on groups whose true effects spread by tau: about tau^2 on average; nothing beyond the
    groups' own errors where they agree."""
    rng = np.random.default_rng(3)
    errors = np.full((4, 1), 0.5)
    for tau in (0.0, 1.0):
        reads = []
        for _ in range(4000):
            effects = rng.normal(0.0, tau, (4, 1))
            reads.append(float(between_condition_variance(effects + rng.normal(0.0, 0.5, (4, 1)), errors)[0]))
        mean = float(np.mean(reads))
        if tau == 0.0:
            # truncated at zero it reads a little on average: far below the groups' own error variance (0.25)
            assert mean < 0.1 and np.mean(np.array(reads) == 0.0) > 0.5, mean
        else:
            assert abs(mean - tau**2) < 0.1, mean


def test_the_arc_has_an_interval_of_its_own_that_covers_and_is_narrower_than_the_radii_corners():
    """The radii's errors are mostly common to both wheels and cancel in the arc (rR - rL) / (r_nominal b): its own
    interval covers the true arc in >= 90 % of noisy fleets and is far narrower than the corners of the radii's."""
    truth = (TRUE["radius_right_m"] - TRUE["radius_left_m"]) / (NOMINAL_WHEEL_RADIUS_M * TRUE["separation_m"])
    hits, ratios = 0, []
    for fleet in range(100):
        episodes = [kinematic_episode(1000 * fleet + k, slip=0.05, seconds=20.0, rolling=0.015) for k in range(6)]
        fit = estimate_wheels(episodes, SETTINGS)
        arc = fit.arc_per_m
        assert arc.ok and arc.unit == "rad/m" and arc.interval is not None
        hits += arc.interval[0] <= truth <= arc.interval[1]
        (l0, l1), (r0, r1), (b0, b1) = (getattr(fit, k).interval for k in KEYS)
        corners = [(r - left) / (NOMINAL_WHEEL_RADIUS_M * b) for left in (l0, l1) for r in (r0, r1) for b in (b0, b1)]
        ratios.append((arc.interval[1] - arc.interval[0]) / (max(corners) - min(corners)))
    assert hits >= 90, hits
    assert np.median(ratios) < 0.5, np.median(ratios)


# -- what the data cannot tell --------------------------------------------------------------------


def test_driving_straight_only_leaves_everything_unidentifiable():
    fit = estimate_wheels([kinematic_episode(seed, turning=False) for seed in range(4)], SETTINGS)
    for key in KEYS:
        est = getattr(fit, key)
        assert est.status == "unidentifiable" and est.unit == "m"
        assert "too little turning to separate the wheel separation from the ratio of the wheel radii" in est.reason


def test_one_curvature_only_leaves_everything_unidentifiable():
    episodes = []
    for seed in range(4):
        e = kinematic_episode(seed)
        # an arc of 0.2 m/s at 0.5 rad/s all along
        n = len(e.t_ns) - 1
        truth = integrate(e.truth[0], np.full(n, 0.2 * 0.04), np.full(n, 0.5 * 0.04 * 0.281 / 0.287))
        odom = integrate(np.zeros(3), np.full(n, 0.2 * 0.04 * 1.01), np.full(n, 0.5 * 0.04))
        episodes.append(OdometryEpisode(e.robot, e.label, e.t_ns, odom, truth))
    est = estimate_wheels(episodes, SETTINGS).radius_left_m
    assert est.status == "unidentifiable" and "always came in the same proportion" in est.reason


def test_too_few_robot_episodes_or_chunks_are_named():
    fit = estimate_wheels([kinematic_episode(0, seconds=4.0), kinematic_episode(1, seconds=4.0)], SETTINGS)
    reason = fit.separation_m.reason
    assert fit.separation_m.status == "unidentifiable"
    assert "only 2 robot-episodes with motion (need 3)" in reason and "only 16 chunks" in reason
    empty = estimate_wheels([], SETTINGS)
    assert not empty.radius_right_m.ok and "only 0 robot-episodes" in empty.radius_right_m.reason


# -- the twin's MuJoCo base -----------------------------------------------------------------------


def twin_episodes(n_episodes: int, seconds: float) -> list[OdometryEpisode]:
    """Three lab robots (true wheels TRUE, friction 0.8, motor lag and acceleration limit) driven by random
    commands through the nominal geometry, each staying within 0.5 m of its start; encoder odometry at 50 Hz,
    ground truth seen with motion-capture noise."""
    scenario = load_scenario("empty")
    base = BaseParams(
        wheel_radius_left_m=TRUE["radius_left_m"],
        wheel_radius_right_m=TRUE["radius_right_m"],
        wheel_separation_m=TRUE["separation_m"],
        mass_kg=6.2,
        motor_time_constant_s=0.06,
        deadband_radps=0.6,
        max_wheel_accel_radps2=25.0,
        friction=0.8,
    )
    physics = FleetPhysics(scenario, base)
    odometry = EncoderOdometry(physics.n, OdometryProfile(rate_hz=50.0, drift_per_m=0.0), np.random.default_rng(0))
    dt = 0.02
    r, b = NOMINAL_WHEEL_RADIUS_M, NOMINAL_WHEEL_SEPARATION_M
    out = []
    for episode in range(n_episodes):
        rng = np.random.default_rng(episode)
        physics.reset(scenario.starts)
        start = physics.poses()
        odometry.reset(start, physics.wheel_angles())
        drives = [commands(rng, seconds, dt) for _ in range(physics.n)]
        v, w = np.stack([d[0] for d in drives], axis=1), np.stack([d[1] for d in drives], axis=1)
        sign = np.ones(physics.n)
        truth, odom = [start], [odometry.pose.copy()]
        for k in range(len(v)):
            pose = truth[-1]
            away = pose[:, :2] - start[:, :2]
            outward = np.cos(pose[:, 2]) * away[:, 0] + np.sin(pose[:, 2]) * away[:, 1]
            sign = np.where((np.hypot(*away.T) > 0.5) & (sign * v[k] * outward > 0), -sign, sign)
            speed = sign * v[k]
            physics.set_wheel_targets(np.stack([(speed - w[k] * b / 2) / r, (speed + w[k] * b / 2) / r], axis=1))
            physics.step(round(dt / physics.timestep_s))
            odometry.update(physics.wheel_angles(), dt)
            truth.append(physics.poses())
            odom.append(odometry.pose.copy())
        t_ns = (np.arange(len(truth)) * dt * NS).astype(np.int64)
        for i in range(physics.n):
            seen = np.array([p[i] for p in truth])
            seen += rng.normal(0.0, 1.0, seen.shape) * [MOCAP_SIGMA_M, MOCAP_SIGMA_M, MOCAP_SIGMA_RAD]
            out.append(
                OdometryEpisode(f"robot_{i + 1}", f"episode {episode}", t_ns, np.array([p[i] for p in odom]), seen)
            )
    return out


def test_the_twins_mujoco_base_gives_its_true_wheels_within_the_intervals():
    episodes = twin_episodes(3, 30.0)
    for e in episodes:  # the robots stayed in the room, clear of each other
        assert np.hypot(*(e.truth[:, :2] - e.truth[0, :2]).T).max() < 0.7
    fit = estimate_wheels(episodes, SETTINGS)
    errors = relative_errors(fit)
    assert all(abs(e) < 0.15 for e in errors.values()), errors
    assert all(abs(e) < 0.003 for e in errors.values()), errors  # closer than the nominal geometry (0.6-2.1 % off)
    assert covers(fit) == {key: True for key in KEYS}, {k: getattr(fit, k).interval for k in KEYS}
